#!/usr/bin/env bash
# CMX's official recipe (`rtf train --recipe cmx-mf`) against our PyTorch reference trainer
# (scripts/reference_train_cmx.py), step for step on real frames, full version
# (docs/src/training.md, "CMX's official recipe"): the 48 MSRS scenes of
# ../shared/data/msrs-samples at 160×128 labelled by the published MFNet, cmx-mit-b0 from the
# same officially initialised weights, two epochs of 12 batches of 4 (24 steps) with a 1-epoch
# warm-up (the poly decay is reached in epoch 2), no shuffle, no augmentation, fp32, one thread
# each side. Prints one JSON object (update differences, per-step losses and rates).
#   scripts/parity_train_cmx.sh [WORK_DIR] [extra scripts/parity_train.py flags]
set -euo pipefail
cd "$(dirname "$0")/.."
work="${1:-$(mktemp -d /tmp/rtf-parity-cmx.XXXXXX)}"
shift || true
export LIBTORCH="${LIBTORCH:-$PWD/.libtorch}"
cargo build --release -q -p rtf-cli
exec .venv/bin/python scripts/parity_train.py --rtf target/release/rtf --work "$work" \
    --models "" --cmx b0 --frames 48 --size 160x128 --epochs 2 --batch-size 4 --threads 1 \
    --warmup-epochs 1 "$@"
