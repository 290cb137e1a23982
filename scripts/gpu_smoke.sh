#!/usr/bin/env bash
# CUDA check of the rtf binary, for a machine with an NVIDIA GPU (CI has none, so this is not
# part of `cargo xtask test`). Every command that takes --device runs on the GPU:
#   synthetic data -> train MFNet on the GPU, resume, train RTFNet-18 -> evaluate the same
#   weights on the GPU (plain, fast fp32, fast bf16) and on the CPU, comparing mIoU ->
#   predict on both, comparing logits -> Freiburg training with RMSprop, interrupted by
#   Ctrl-C and resumed, evaluated on both -> `rtf bench model --device cuda`.
# Usage: scripts/gpu_smoke.sh [RTF_BINARY] [WORK_DIR]
# Exit 0 only if every step ran and the GPU results match the CPU's. RTF_SMOKE_DEVICE=cpu runs
# the same steps on the CPU (to check the script itself on a machine without a GPU);
# RTF_SMOKE_EPOCHS sets the MFNet schedule (default 40, the demo's).
set -euo pipefail
rtf=${1:-target/release/rtf}
work=${2:-$(mktemp -d)}
gpu=${RTF_SMOKE_DEVICE:-cuda}
python=${PYTHON:-python3} # with numpy
mkdir -p "$work"
step() { echo; echo "\$ rtf $*"; "$rtf" "$@"; }

# The demo's data and schedule (cargo xtask demo), so the scores compared are not trivial.
step synth --out "$work/data" --count 240 --size 160x128 --seed 0
step train --model mfnet --data "$work/data" --out "$work/mfnet" --epochs 2 --batch-size 6 \
    --lr-decay 0.94 --device "$gpu"
step train --resume "$work/mfnet" --epochs "${RTF_SMOKE_EPOCHS:-40}"
step train --model rtfnet18 --data "$work/data" --out "$work/rtfnet18" --epochs 1 --batch-size 4 \
    --device "$gpu"
weights="$work/mfnet/final.safetensors"

eval_on() { # device precision json
    local extra=()
    [ "$2" = plain ] || extra=(--precision "$2")
    step eval --model mfnet --weights "$weights" --data "$work/data" --split test --device "$1" \
        "${extra[@]}" --json "$3"
}
eval_on cpu plain "$work/eval_cpu.json"
eval_on "$gpu" plain "$work/eval_gpu.json"
eval_on "$gpu" fp32 "$work/eval_gpu_fp32.json"
eval_on "$gpu" bf16 "$work/eval_gpu_bf16.json"
"$python" - "$work" <<'PY'
import json, sys
work = sys.argv[1]
miou = {k: json.load(open(f"{work}/eval_{k}.json"))["miou"] for k in ("cpu", "gpu", "gpu_fp32", "gpu_bf16")}
print("mIoU:", {k: round(100 * v, 2) for k, v in miou.items()})
assert miou["cpu"] > 0.2, "training did not learn: comparing its scores would prove nothing"
# Same weights, same frames: fp32 on the GPU must give the CPU's scores up to rounding; bf16
# may move a few border pixels.
for k, tol in (("gpu", 0.002), ("gpu_fp32", 0.002), ("gpu_bf16", 0.02)):
    assert abs(miou[k] - miou["cpu"]) <= tol, f"{k}: mIoU {miou[k]:.4f} vs CPU {miou['cpu']:.4f}"
print("GPU scores match the CPU's")
PY

# Logits of the same frames on the CPU (plain path) and on the GPU (plain, fast fp32, fast bf16).
mapfile -t frames < <(head -n 4 "$work/data/test.txt" | tr -d '\r' | sed "s|^|$work/data/images/|; s|\$|.png|")
predict_on() { # device precision folder
    local extra=()
    [ "$2" = plain ] || extra=(--precision "$2")
    step predict --model mfnet --weights "$weights" --out "$3" --device "$1" "${extra[@]}" \
        --logits "${frames[@]}"
}
predict_on cpu plain "$work/logits_cpu"
predict_on "$gpu" plain "$work/logits_gpu"
predict_on "$gpu" fp32 "$work/logits_gpu_fp32"
predict_on "$gpu" bf16 "$work/logits_gpu_bf16"
"$python" - "$work" "$(dirname "$0")" <<'PY'
import sys
work = sys.argv[1]
sys.path.insert(0, sys.argv[2])
from logit_agreement import agreement
for variant, min_agreement in (("gpu", 0.999), ("gpu_fp32", 0.999), ("gpu_bf16", 0.99)):
    same, total, worst = agreement(f"{work}/logits_cpu", f"{work}/logits_{variant}")
    print(f"{variant}: arg-max agreement with the CPU {100 * same / total:.3f} % of {total} pixels, "
          f"max |logit difference| {worst:.2e}")
    assert same / total >= min_agreement, variant
PY

# Freiburg Thermal, HeatNet's optimiser, and a Ctrl-C inside an epoch, resumed to the end.
step synth --format freiburg --out "$work/fr" --count 40 --size 320x160 --seed 2
"$rtf" train --data "$work/fr" --out "$work/fr_run" --optimizer rmsprop --momentum 0.5 \
    --epochs 400 --batch-size 2 --checkpoint-every 3 --device "$gpu" >"$work/fr_train.log" 2>&1 &
trainer=$!
while [ ! -f "$work/fr_run/config.json" ]; do sleep 0.2; done
sleep 4
kill -INT "$trainer"
status=0
wait "$trainer" || status=$?
[ "$status" = 130 ] || { echo "expected exit 130 after Ctrl-C, got $status"; exit 1; }
grep -q -- "--resume" "$work/fr_train.log"
step train --resume "$work/fr_run" --epochs 3
for target in cpu "$gpu"; do
    step eval --model mfnet --weights "$work/fr_run/final.safetensors" --data "$work/fr" \
        --device "$target" --json "$work/fr_eval_$target.json"
done
"$python" - "$work" "$gpu" <<'PY'
import json, sys
work, gpu = sys.argv[1:]
a, b = (json.load(open(f"{work}/fr_eval_{d}.json"))["heatnet"]["miou"] for d in ("cpu", gpu))
assert abs(a - b) <= 0.002, f"Freiburg HeatNet mIoU: CPU {a} vs {gpu} {b}"
print(f"Freiburg: HeatNet-convention mIoU CPU {100 * a:.2f} = {gpu} {100 * b:.2f}")
PY

# HeatNet's adversarial procedure on the GPU (teacher on the labelled day frames, then the
# student with the day/night critic), resumed after a stop, and scored on CPU and GPU alike.
step train --recipe heatnet-v5 --model mfnet --data "$work/fr" --out "$work/v5" --epochs 2 \
    --batch-size 4 --resize 320x160 --lr 1e-3 --device "$gpu"
grep -q '"critic_acc_night"' "$work/v5/v5/log.jsonl"
step train --resume "$work/v5" --epochs 3
for target in cpu "$gpu"; do
    step eval --model mfnet --weights "$work/v5/final.safetensors" --data "$work/fr" \
        --resize 320x160 --device "$target" --json "$work/v5_eval_$target.json"
done
"$python" - "$work" "$gpu" <<'PY'
import json, sys
work, gpu = sys.argv[1:]
a, b = (json.load(open(f"{work}/v5_eval_{d}.json"))["heatnet"]["miou"] for d in ("cpu", gpu))
assert abs(a - b) <= 0.002, f"adversarial HeatNet mIoU: CPU {a} vs {gpu} {b}"
print(f"adversarial (heatnet-v5, mfnet): HeatNet-convention mIoU CPU {100 * a:.2f} = {gpu} {100 * b:.2f}")
PY

for model in mfnet rtfnet50 heatnet; do
    for precision in fp32 bf16; do
        step bench model --model "$model" --device "$gpu" --precision "$precision" --iterations 20
    done
done
step bench model --model rtfnet50 --device "$gpu" --batch 8 --precision bf16 --iterations 10
echo; echo "gpu_smoke: all steps passed ($work)"
