#!/usr/bin/env bash
# Validation curves of the networks of the quick reproduction tables, on the quick budget's own
# synthetic data, to size the quick budget per network (issue 27 §4; the chosen epochs are in
# xtask/src/reproduce/budget.rs, the results in docs/src/quick-budget.md).
#
# MODE curves (default): each network trains EPOCHS epochs of batch 4 with its paper's SGD
#   schedule (MFNet's tables: lr 0.01 ×0.94 per epoch; RTFNet's: ×0.95), validating every
#   epoch; each HeatNet Tab. II recipe runs with MFNet in every role, EPOCHS per stage,
#   RMSprop lr 1e-3 (the CPU budgets' recipe flags). An exponential schedule per epoch does not
#   depend on the number of epochs, so epoch k of these curves is what a k-epoch budget trains.
# MODE sweep: the levers for the networks that do not learn that way, EPOCHS epochs each under
#   rms   RMSprop lr 1e-3, 96×64 frames;
#   sgd5  SGD lr 0.05 (momentum 0.9, weight decay 5e-4, ×0.95 per epoch), 96×64 frames;
#   big   SGD lr 0.01 ×0.95, 160×128 frames (the demo's size, 3.3× the pixels);
#   base  SGD lr 0.01 ×0.95, 96×64 (the curves' schedule, for networks they did not reach).
# MODE frames: 8× the training frames (`rtf synth --count 1280`: 640 training frames at 96×64,
#   validated on 80 of the 320 validation frames, half day, half night), RMSprop lr 1e-3, for
#   every network of the quick tables (MFNet as the reference).
#
# Usage: lab/training/quick_budget_curves.sh RTF OUT [EPOCHS] [DEVICE] [PARALLEL] [MODE]
#   then: python3 lab/training/quick_budget_curves.py OUT   (numpy and Pillow)
set -euo pipefail
rtf=$(realpath "$1")
out=$2
epochs=${3:-50}
device=${4:-cpu}
parallel=${5:-1}
mode=${6:-curves}
mkdir -p "$out"
cd "$out"
[ -d mf ] || "$rtf" synth --out mf --count 160 --size 96x64 --seed 0 --format mf

# One job a line: run folder, then its `rtf train` flags.
jobs=()
if [ "$mode" = curves ]; then
    [ -d fr ] || "$rtf" synth --out fr --count 120 --size 192x96 --seed 0 --format freiburg
    for m in segnet-3c segnet-4c enet-3c mfnet mfnet-{b..n}; do
        jobs+=("model-$m-0.94 --model $m --data mf --batch-size 4 --lr-decay 0.94")
    done
    for m in rtfnet50-nre rtfnet50-nte rtfnet152-nre rtfnet152-nte rtfnet50 rtfnet152 fusenet \
        mfnet segnet-3c segnet-4c erfnet-3c erfnet-4c unet-3c unet-4c pspnet-3c pspnet-4c \
        duchdc-3c duchdc-4c; do
        jobs+=("model-$m-0.95 --model $m --data mf --batch-size 4 --lr-decay 0.95")
    done
    for v in 1 2 3 4 5 6; do
        jobs+=("recipe-heatnet-v$v --recipe heatnet-v$v --data fr --model mfnet --resize 192x96 --lr 1e-3")
    done
elif [ "$mode" = frames ]; then
    if [ ! -d mf1280 ]; then
        "$rtf" synth --out mf1280 --count 1280 --size 96x64 --seed 0 --format mf
        awk 'NR % 8 == 1 || NR % 8 == 2' mf1280/val.txt >mf1280/val80.txt
    fi
    for m in ${FRAMES_NETS:-mfnet mfnet-b mfnet-h mfnet-i mfnet-j mfnet-m segnet-3c segnet-4c \
        enet-3c erfnet-3c erfnet-4c unet-3c pspnet-3c duchdc-3c fusenet rtfnet50 rtfnet152}; do
        jobs+=("frames-rms-$m --model $m --data mf1280 --val-split val80 --batch-size 4 \
            --optimizer rmsprop --lr 1e-3")
    done
else
    [ -d mf160 ] || "$rtf" synth --out mf160 --count 160 --size 160x128 --seed 0 --format mf
    nets="rtfnet50 rtfnet50-nre segnet-3c unet-3c pspnet-3c duchdc-3c fusenet erfnet-3c enet-3c
        mfnet-h mfnet-j mfnet-m"
    for m in $nets; do jobs+=("sweep-big-$m --model $m --data mf160 --batch-size 4 --lr-decay 0.95"); done
    for m in $nets; do
        jobs+=("sweep-rms-$m --model $m --data mf --batch-size 4 --optimizer rmsprop --lr 1e-3")
    done
    for m in $nets; do
        jobs+=("sweep-sgd5-$m --model $m --data mf --batch-size 4 --lr 0.05 --lr-decay 0.95")
    done
    for m in unet-3c pspnet-3c duchdc-3c; do
        jobs+=("sweep-base-$m --model $m --data mf --batch-size 4 --lr-decay 0.95")
    done
fi

one() { # run-folder flags...
    local dir=$1
    shift
    if [ -f "$dir/done" ]; then return 0; fi
    rm -rf "$dir"
    if "$rtf" train "$@" --out "$dir" --epochs "$epochs" --seed 0 --device "$device" \
        >"$dir.log" 2>&1; then
        touch "$dir/done"
        echo "done $dir"
    else
        echo "FAILED $dir (see $out/$dir.log)"
    fi
}
export -f one
export rtf epochs device out
printf '%s\n' "${jobs[@]}" | xargs -P "$parallel" -I{} bash -c 'one {}'
