#!/usr/bin/env bash
# Validation curves of every network of the quick reproduction tables, on the quick budget's
# own synthetic data, to size the quick budget per network (issue 27 §4; the chosen epochs are
# in xtask/src/reproduce/budget.rs, the curves' summary in docs/src/reproduction.md).
#
# Each network trains EPOCHS epochs of batch 4 with its paper's SGD schedule (MFNet's tables:
# lr 0.01 ×0.94 per epoch; RTFNet's: ×0.95), validating every epoch; each HeatNet Tab. II
# recipe runs with MFNet in every role, EPOCHS per stage, RMSprop lr 1e-3 (the CPU budgets'
# recipe flags). An exponential schedule per epoch does not depend on the number of epochs,
# so epoch k of these curves is what a k-epoch budget trains.
#
# Usage: scripts/quick_budget_curves.sh RTF OUT [EPOCHS] [DEVICE] [PARALLEL]
#   then: python3 scripts/quick_budget_curves.py OUT
set -euo pipefail
rtf=$(realpath "$1")
out=$2
epochs=${3:-50}
device=${4:-cpu}
parallel=${5:-1}
mkdir -p "$out"
cd "$out"
[ -d mf ] || "$rtf" synth --out mf --count 160 --size 96x64 --seed 0 --format mf
[ -d fr ] || "$rtf" synth --out fr --count 120 --size 192x96 --seed 0 --format freiburg

jobs=()
for m in segnet-3c segnet-4c enet-3c mfnet mfnet-{b..n}; do jobs+=("model $m 0.94"); done
for m in rtfnet50-nre rtfnet50-nte rtfnet152-nre rtfnet152-nte rtfnet50 rtfnet152 fusenet \
    mfnet segnet-3c segnet-4c erfnet-3c erfnet-4c unet-3c unet-4c pspnet-3c pspnet-4c \
    duchdc-3c duchdc-4c; do jobs+=("model $m 0.95"); done
for v in 1 2 3 4 5 6; do jobs+=("recipe heatnet-v$v -"); done

one() { # kind name decay
    local dir="$1-$2-$3" args
    if [ -f "$dir/done" ]; then return 0; fi
    rm -rf "$dir"
    if [ "$1" = model ]; then
        args=(--model "$2" --data mf --batch-size 4 --lr-decay "$3")
    else
        args=(--recipe "$2" --data fr --model mfnet --resize 192x96 --lr 1e-3)
    fi
    if "$rtf" train "${args[@]}" --out "$dir" --epochs "$epochs" --seed 0 --device "$device" \
        >"$dir.log" 2>&1; then
        touch "$dir/done"
        echo "done $dir"
    else
        echo "FAILED $dir (see $out/$dir.log)"
    fi
}
export -f one
export rtf epochs device
printf '%s\n' "${jobs[@]}" | xargs -P "$parallel" -I{} bash -c 'one {}'
