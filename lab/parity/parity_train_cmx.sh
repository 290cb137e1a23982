#!/usr/bin/env bash
# CMX's official recipe (`rtf train --recipe cmx-mf`) against our PyTorch reference trainer
# (lab/parity/reference_train_cmx.py), step for step on real frames, full version
# (docs/src/training.md, "CMX's official recipe"): lab/parity/parity_train.sh's set-up (the 48
# MSRS scenes of ../shared/data/msrs-samples at 160×128 labelled by the published MFNet, two
# epochs of 12 batches of 4, no shuffle, no augmentation, fp32, one thread each side) with
# cmx-mit-b0 from the same officially initialised weights and a 1-epoch warm-up (the poly
# decay is reached in epoch 2) in place of the papers' networks. Prints one JSON object
# (update differences, per-step losses and rates).
#   lab/parity/parity_train_cmx.sh [WORK_DIR] [extra lab/parity/parity_train.py flags]
set -euo pipefail
cd "$(dirname "$0")/../.."
work="${1:-$(mktemp -d /tmp/rtf-parity-cmx.XXXXXX)}"
shift || true
# parity_train.py takes the last value of a repeated flag: these replace parity_train.sh's.
exec lab/parity/parity_train.sh "$work" --models "" --adversarial "" --cmx b0 --warmup-epochs 1 "$@"
