#!/usr/bin/env bash
# HeatNet's training procedures measured on a synthetic Freiburg-format day/night set (no night
# label is read in training; the test layout's night labels only score). Per seed: the RGB
# teacher, the thermal teacher, Tab. II V2, V3, V5, V6 and the RGB-only distilled model, each a
# recipe of `rtf train`, then `rtf eval` on the test layout (HeatNet's mIoU convention).
#
# CPU budget (stated in the results): every role is MFNet (`--model mfnet`; the recipes' input
# masks make the RGB-only and thermal-only variants), frames resized to SIZE, EPOCHS per stage,
# LR instead of the paper's 1e-4 (RMSprop, halved every 30 epochs, batch 8 as the paper).
#
# usage: lab/training/heatnet_procedures.sh OUT [SEEDS] ; then
#        .venv/bin/python lab/training/heatnet_procedures_summary.py OUT
set -euo pipefail
out=${1:?usage: heatnet_procedures.sh OUT [SEEDS]}
seeds=${2:-"0 1 2"}
rtf=${RTF:-target/release/rtf}
frames=${FRAMES:-240}
size=${SIZE:-128x64}
epochs=${EPOCHS:-12}
lr=${LR:-1e-3}
mkdir -p "$out"
data="$out/data"
[ -d "$data" ] || "$rtf" synth --format freiburg --out "$data" --count "$frames" --size 192x64 --seed 0
common=(--model mfnet --data "$data" --resize "$size" --epochs "$epochs" --lr "$lr" --workers 1)

train() { # RUN, then rtf train arguments; resumes an interrupted run, skips a finished one
  local run=$1; shift
  if [ -f "$run/final.safetensors" ]; then return; fi
  if [ -d "$run" ]; then "$rtf" train --resume "$run"; else "$rtf" train --out "$run" "$@"; fi
}
evaluate() { # RUN INPUTS
  local run=$1 inputs=$2
  [ -f "$run/test.json" ] || "$rtf" eval --model mfnet --weights "$run/final.safetensors" \
    --data "$data" --split test --resize "$size" --inputs "$inputs" --json "$run/test.json" >/dev/null
}

for seed in $seeds; do
  s="$out/seed$seed"
  t=(--seed "$seed" "${common[@]}")
  train "$s/teacher-rgb" --recipe heatnet-teacher-rgb "${t[@]}"
  train "$s/teacher-ir" --recipe heatnet-teacher-ir --teacher "$s/teacher-rgb" "${t[@]}"
  train "$s/v2" --recipe heatnet-v2 --teacher "$s/teacher-rgb" "${t[@]}"
  train "$s/v3" --recipe heatnet-v3 --teacher "$s/teacher-rgb" "${t[@]}"
  train "$s/v5" --recipe heatnet-v5 --teacher "$s/teacher-rgb" "${t[@]}"
  train "$s/v6" --recipe heatnet-v6 --teacher "$s/teacher-rgb" --night-teacher "$s/teacher-ir" "${t[@]}"
  train "$s/distill" --recipe heatnet-distill --teacher "$s/teacher-rgb" --night-teacher "$s/v6" "${t[@]}"
  evaluate "$s/teacher-rgb" rgb
  evaluate "$s/teacher-ir" thermal
  for v in v3 v5 v6; do evaluate "$s/$v" rgb_t; done
  evaluate "$s/v2" rgb
  evaluate "$s/distill" rgb
done
