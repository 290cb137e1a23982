#!/usr/bin/env bash
# Every command on every dataset layout rtf reads, end to end: for each layout a root is made,
# then `rtf data check`, `data stats`, `data fingerprint`, `train` (MFNet, a few steps at a
# small size), `train --resume --epochs 2`, `eval --json --figure`, `predict --data`,
# `report` and `export --format torchscript` run on it, and each command's exit status and
# the files it must write are checked. Last, the Python package (installed in PYTHON's
# environment) opens the root, loads the run's weights and evaluates them: its scores must
# equal `rtf eval --json`'s, and both must name the dataset's classes, one per network output. A line per layout and command goes to OUT/summary.txt;
# the script exits 1 if any failed.
#
# The roots, from real imagery where the layout allows:
#   msrs, pst900, fmb   the 48 real MSRS scenes (RGB and thermal as shipped), labelled with the
#                       published MFNet's predictions (as scripts/walkthrough_msrs.sh does), laid
#                       out in each layout's folders. PST900 has 5 classes: MF ids above 4 become
#                       background (0). FMB has 15: MF's ids 0..8 are used as they are. The
#                       classes' names then do not match the scenes; that does not matter here,
#                       because the walk checks that the commands work, not what they score.
#   mf, freiburg, plain `rtf synth --format ...` (synthetic: those layouts' formats, 16-bit
#                       thermal included, have no real sample here).
#
# Usage: lab/reliability/every_layout.sh OUT
# Environment (defaults): RTF (target/release/rtf), PYTHON (.venv/bin/python, with numpy,
# Pillow and the rtf package: `cargo xtask wheel`, then pip install the wheel), SAMPLES
# (../shared/data/msrs-samples), WEIGHTS (../shared/data/mf-samples/mfnet_final.safetensors),
# SIZE (160x128), STEPS (4).
set -uo pipefail

OUT=${1:?usage: lab/reliability/every_layout.sh OUT}
REPO=$(cd "$(dirname "$0")/../.." && pwd)
RTF=${RTF:-$REPO/target/release/rtf}
PYTHON=${PYTHON:-$REPO/.venv/bin/python}
SAMPLES=${SAMPLES:-$REPO/../shared/data/msrs-samples}
WEIGHTS=${WEIGHTS:-$REPO/../shared/data/mf-samples/mfnet_final.safetensors}
SIZE=${SIZE:-160x128}
STEPS=${STEPS:-4}

for f in "$RTF" "$PYTHON" "$WEIGHTS" "$SAMPLES/frames.txt"; do
    [ -e "$f" ] || { echo "every_layout: $f does not exist" >&2; exit 1; }
done
if [ -e "$OUT" ]; then
    echo "every_layout: $OUT exists; give a new folder" >&2
    exit 1
fi
mkdir -p "$OUT/roots" "$OUT/labels"
SUMMARY=$OUT/summary.txt
FAILED=0

# step LAYOUT NAME MUST_WRITE COMMAND...: runs COMMAND, logs it, and records ok or failed
# (a non-zero exit, or MUST_WRITE, when not "-", missing afterwards).
step() {
    local layout=$1 name=$2 must=$3
    shift 3
    local log=$OUT/logs/$layout-$name.log
    mkdir -p "$OUT/logs"
    echo "\$ $*" >"$log"
    if "$@" >>"$log" 2>&1 && { [ "$must" = - ] || [ -e "$must" ]; }; then
        printf '%-9s %-12s ok\n' "$layout" "$name" | tee -a "$SUMMARY"
    else
        printf '%-9s %-12s FAILED (%s)\n' "$layout" "$name" "$log" | tee -a "$SUMMARY"
        FAILED=1
    fi
}

# The real scenes labelled by the published MFNet, once.
while read -r name _; do
    "$RTF" predict --model mfnet --weights "$WEIGHTS" --classes mf \
        --rgb "$SAMPLES/vi/$name.png" --thermal "$SAMPLES/ir/$name.png" \
        --out "$OUT/labels" >>"$OUT/label.log" 2>&1 ||
        { echo "every_layout: labelling $name failed ($OUT/label.log)" >&2; exit 1; }
done <"$SAMPLES/frames.txt"

# The three real-imagery layouts: day and night scenes alternate between train and test.
"$PYTHON" - "$SAMPLES" "$OUT/labels" "$OUT/roots" <<'EOF' || exit 1
import shutil, sys
from pathlib import Path
import numpy as np
from PIL import Image

samples, labels, roots = map(Path, sys.argv[1:])
# layout: (rgb folder, thermal folder, label folder, map of MF ids to the layout's)
layouts = {
    "msrs": ("vi", "ir", "Label", lambda ids: ids),
    "pst900": ("rgb", "thermal", "labels", lambda ids: np.where(ids > 4, 0, ids)),
    "fmb": ("Visible", "Infrared", "Label", lambda ids: ids),
}
seen = {}
for line in (samples / "frames.txt").read_text().split("\n"):
    if not line.strip():
        continue
    name = line.split()[0]
    n = seen.setdefault(name[-1], 0)
    seen[name[-1]] += 1
    split = "train" if n % 2 == 0 else "test"
    ids = np.array(Image.open(labels / f"{name}.png"))
    for layout, (rgb, thermal, label, mapped) in layouts.items():
        at = roots / layout / split
        for sub in (rgb, thermal, label):
            (at / sub).mkdir(parents=True, exist_ok=True)
        shutil.copy(samples / "vi" / f"{name}.png", at / rgb / f"{name}.png")
        shutil.copy(samples / "ir" / f"{name}.png", at / thermal / f"{name}.png")
        Image.fromarray(mapped(ids).astype(np.uint8)).save(at / label / f"{name}.png")
EOF

"$RTF" synth --format mf --out "$OUT/roots/mf" --count 24 --seed 0 >"$OUT/synth-mf.log" 2>&1 &&
"$RTF" synth --format freiburg --out "$OUT/roots/freiburg" --count 24 --seed 0 \
    >"$OUT/synth-freiburg.log" 2>&1 &&
"$RTF" synth --format plain --out "$OUT/roots/plain" --count 24 --seed 0 \
    >"$OUT/synth-plain.log" 2>&1 ||
    { echo "every_layout: rtf synth failed (logs in $OUT)" >&2; exit 1; }

for layout in msrs pst900 fmb mf freiburg plain; do
    root=$OUT/roots/$layout
    [ "$layout" = plain ] && root=$root/dataset.yaml
    run=$OUT/runs/$layout
    w=$run/final.safetensors
    step "$layout" check - "$RTF" data check "$root"
    step "$layout" stats - "$RTF" data stats "$root"
    step "$layout" fingerprint - "$RTF" data fingerprint "$root"
    step "$layout" train "$w" "$RTF" train --data "$root" --out "$run" --model mfnet \
        --epochs 1 --max-steps "$STEPS" --batch-size 2 --resize "$SIZE" --workers 1 --seed 0
    step "$layout" resume "$w" "$RTF" train --resume "$run" --epochs 2
    step "$layout" eval "$OUT/eval/$layout.json" "$RTF" eval --model mfnet --weights "$w" \
        --data "$root" --resize "$SIZE" --json "$OUT/eval/$layout.json" \
        --figure "$OUT/eval/$layout.png"
    step "$layout" predict "$OUT/pred/$layout" "$RTF" predict --model mfnet --weights "$w" \
        --data "$root" --split test --out "$OUT/pred/$layout"
    step "$layout" report "$OUT/report/$layout.html" "$RTF" report "$run" \
        --eval "$OUT/eval/$layout.json" --out "$OUT/report/$layout.html"
    step "$layout" export "$OUT/export/$layout.pt" "$RTF" export --model mfnet --weights "$w" \
        --format torchscript --size 128x160 --out "$OUT/export/$layout.pt"
    step "$layout" python - "$PYTHON" - "$root" "$w" "$OUT/eval/$layout.json" "$SIZE" <<'EOF'
import json, sys
import rtf

root, weights, cli_json, size = sys.argv[1:]
cli = json.load(open(cli_json))
ds = rtf.open_dataset(root)
names = [c["name"] for c in ds.classes]
net = rtf.load_network("mfnet", weights=weights)
w, h = map(int, size.split("x"))
scores = rtf.evaluate(net, ds, split=cli["split"], resize=(w, h))
assert cli["class_names"] == names, (cli["class_names"], names)
assert len(cli["confusion"]) == len(names) == len(cli["per_class"]), cli_json
assert scores.frames == cli["frames"] > 0, (scores.frames, cli["frames"])
assert scores.miou == cli["miou"] and scores.confusion == cli["confusion"], cli_json
print(f"{len(names)} classes, {scores.frames} frames, mIoU {scores.miou:.4f} as rtf eval")
EOF
done
echo "every_layout: summary in $SUMMARY"
exit "$FAILED"
