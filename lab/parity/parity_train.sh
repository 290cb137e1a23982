#!/usr/bin/env bash
# Trajectory parity of `rtf train` with the PyTorch reference trainer on real frames, full
# version (issue 27 §3; docs/src/training.md, "Parity with the official recipe"): the 48 MSRS
# scenes of ../shared/data/msrs-samples at 160×128 labelled by the published MFNet, two epochs
# of batch 4 (24 steps) for MFNet and RTFNet-18, same starting weights, no shuffle, no
# augmentation, fp32, the official code's SGD schedule, one thread each side (another thread
# count's rounding is amplified by RTFNet-18's random-init trajectory: docs), then one HeatNet
# adversarial stage (MFNet + HeatNet's critic, 24 day and 24 night scenes, the published code's
# critic procedure: `rtf train --critic-code` against lab/parity/reference_train_heatnet.py).
# Prints one JSON object. `--models ""` skips the supervised runs, `--adversarial ""` the
# adversarial one.
#   lab/parity/parity_train.sh [WORK_DIR] [extra lab/parity/parity_train.py flags]
set -euo pipefail
cd "$(dirname "$0")/../.."
work="${1:-$(mktemp -d /tmp/rtf-parity.XXXXXX)}"
shift || true
export LIBTORCH="${LIBTORCH:-$PWD/.libtorch}"
cargo build --release -q -p rtf-cli
exec .venv/bin/python lab/parity/parity_train.py --rtf target/release/rtf --work "$work" \
    --models mfnet,rtfnet18 --adversarial mfnet --frames 48 --size 160x128 --epochs 2 --batch-size 4 --threads 1 "$@"
