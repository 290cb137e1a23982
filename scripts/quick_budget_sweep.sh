#!/usr/bin/env bash
# The levers for networks that do not leave the all-unlabelled answer on the quick budget's
# data with their paper's SGD schedule (scripts/quick_budget_curves.sh; issue 27 §4): each
# network trains EPOCHS epochs of batch 4 under
#   rms   RMSprop lr 1e-3 (the HeatNet recipes' CPU flags), 96×64 frames;
#   sgd5  SGD lr 0.05 (momentum 0.9, weight decay 5e-4, ×0.95 per epoch), 96×64 frames;
#   big   SGD lr 0.01 ×0.95, 160×128 frames (the demo's size, 3.3× the pixels);
#   base  SGD lr 0.01 ×0.95, 96×64 (the curves' schedule, for networks they did not reach).
# The summary: python3 scripts/quick_budget_curves.py OUT (it reads these folders too).
#
# Usage: scripts/quick_budget_sweep.sh RTF OUT [EPOCHS] [DEVICE] [PARALLEL]
set -euo pipefail
rtf=$(realpath "$1")
out=$2
epochs=${3:-20}
device=${4:-cpu}
parallel=${5:-1}
mkdir -p "$out"
cd "$out"
[ -d mf ] || "$rtf" synth --out mf --count 160 --size 96x64 --seed 0 --format mf
[ -d mf160 ] || "$rtf" synth --out mf160 --count 160 --size 160x128 --seed 0 --format mf

nets="rtfnet50 rtfnet50-nre segnet-3c unet-3c pspnet-3c duchdc-3c fusenet erfnet-3c enet-3c \
mfnet-h mfnet-j mfnet-m"
jobs=()
for cfg in big rms sgd5; do for m in $nets; do jobs+=("$cfg $m"); done; done
for m in unet-3c pspnet-3c duchdc-3c; do jobs+=("base $m"); done

one() { # config network
    local dir="sweep-$1-$2" args
    if [ -f "$dir/done" ]; then return 0; fi
    rm -rf "$dir"
    case $1 in
    rms) args=(--data mf --optimizer rmsprop --lr 1e-3) ;;
    sgd5) args=(--data mf --lr 0.05 --lr-decay 0.95) ;;
    big) args=(--data mf160 --lr-decay 0.95) ;;
    base) args=(--data mf --lr-decay 0.95) ;;
    esac
    if "$rtf" train --model "$2" "${args[@]}" --batch-size 4 --out "$dir" --epochs "$epochs" \
        --seed 0 --device "$device" >"$dir.log" 2>&1; then
        touch "$dir/done"
        echo "done $dir"
    else
        echo "FAILED $dir (see $out/$dir.log)"
    fi
}
export -f one
export rtf epochs device
printf '%s\n' "${jobs[@]}" | xargs -P "$parallel" -I{} bash -c 'one {}'
