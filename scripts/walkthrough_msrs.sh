#!/usr/bin/env bash
# The "Your own data" walk-through (docs/src/data.md, issue 26 §5), on real imagery:
#
#   1. copy the 48 real MSRS scenes of ../shared/data/msrs-samples into an MSRS-layout root
#      OUT/msrs/{train,test}/{vi,ir}, alternating the day scenes and the night scenes between
#      train and test (24 + 24);
#   2. label every scene with the published MFNet (`rtf predict`, at 640x480) and put the ids
#      as MSRS `Label/NAME.png`;
#   3. read them back through the MSRS layout (`rtf data check`), and evaluate the published
#      MFNet against its own labels at full size (must agree 100 %: the labels went through
#      the layout intact);
#   4. fine-tune the published MFNet on the train scenes at a small size (this CPU), and
#      evaluate it and the published network on the test scenes at that size.
#
# The labels are the published MFNet's predictions, so every score is *agreement with the
# published MFNet*, not accuracy. Results: OUT/summary.json (and the eval JSONs beside it).
#
# Usage: scripts/walkthrough_msrs.sh OUT
# Environment (defaults): RTF (target/release/rtf), SCENES (48, the first N of frames.txt),
# SIZE (320x240, training and evaluation), EPOCHS (5), MAX_STEPS (none: full epochs),
# SAMPLES (../shared/data/msrs-samples), WEIGHTS (../shared/data/mf-samples/
# mfnet_final.safetensors, the published MFNet converted to safetensors).
set -euo pipefail

OUT=${1:?usage: scripts/walkthrough_msrs.sh OUT}
REPO=$(cd "$(dirname "$0")/.." && pwd)
RTF=${RTF:-$REPO/target/release/rtf}
SAMPLES=${SAMPLES:-$REPO/../shared/data/msrs-samples}
WEIGHTS=${WEIGHTS:-$REPO/../shared/data/mf-samples/mfnet_final.safetensors}
SCENES=${SCENES:-48}
SIZE=${SIZE:-320x240}
EPOCHS=${EPOCHS:-5}

for f in "$RTF" "$WEIGHTS" "$SAMPLES/frames.txt"; do
    [ -e "$f" ] || { echo "walkthrough: $f does not exist" >&2; exit 1; }
done
if [ -e "$OUT" ]; then
    echo "walkthrough: $OUT exists; give a new folder" >&2
    exit 1
fi
ROOT=$OUT/msrs
mkdir -p "$OUT/pred"
for split in train test; do
    mkdir -p "$ROOT/$split/vi" "$ROOT/$split/ir" "$ROOT/$split/Label"
done

# 1. Day scenes alternate train/test, and so do night scenes.
head -n "$SCENES" "$SAMPLES/frames.txt" | awk '
    { daytime = substr($1, length($1)); n = count[daytime]++;
      print $1, (n % 2 == 0) ? "train" : "test" }' >"$OUT/splits.txt"

# 2. Label with the published MFNet; its ids become MSRS Label PNGs.
while read -r name split; do
    cp "$SAMPLES/vi/$name.png" "$ROOT/$split/vi/"
    cp "$SAMPLES/ir/$name.png" "$ROOT/$split/ir/"
    "$RTF" predict --model mfnet --weights "$WEIGHTS" --classes mf \
        --rgb "$SAMPLES/vi/$name.png" --thermal "$SAMPLES/ir/$name.png" \
        --out "$OUT/pred" >>"$OUT/predict.log" 2>&1
    cp "$OUT/pred/$name.png" "$ROOT/$split/Label/$name.png"
done <"$OUT/splits.txt"
echo "labelled $(wc -l <"$OUT/splits.txt") scenes with the published MFNet"

# 3. Read back through the MSRS layout.
"$RTF" data check "$ROOT" | tee "$OUT/check.txt"
"$RTF" eval --model mfnet --weights "$WEIGHTS" --data "$ROOT" --split test \
    --json "$OUT/published_full.json" >"$OUT/published_full.txt" 2>&1

# 4. Fine-tune at SIZE, then score the published and the fine-tuned network at SIZE.
"$RTF" train --data "$ROOT" --out "$OUT/run" --model mfnet --init "$WEIGHTS" \
    --epochs "$EPOCHS" --batch-size 4 --resize "$SIZE" --val-split none --workers 1 \
    ${MAX_STEPS:+--max-steps "$MAX_STEPS"} 2>&1 | tee "$OUT/train.log"
for who in published finetuned; do
    w=$WEIGHTS
    [ "$who" = finetuned ] && w=$OUT/run/final.safetensors
    "$RTF" eval --model mfnet --weights "$w" --data "$ROOT" --split test --resize "$SIZE" \
        --json "$OUT/${who}_test.json" | tee "$OUT/${who}_test.txt"
done

python3 - "$OUT" "$SIZE" "$EPOCHS" <<'EOF'
import json, sys
out, size, epochs = sys.argv[1:4]
def scores(name):
    j = json.load(open(f"{out}/{name}.json"))
    pick = lambda s: None if s is None else {
        "pixel_agreement": s["pixel_acc"], "miou": s["miou"], "miou_mfnet": s["miou_mfnet"]}
    return {"frames": j["frames"], "all": pick(j), "day": pick(j["day"]), "night": pick(j["night"])}
summary = {
    "meaning": "agreement with the published MFNet's own labels, not accuracy",
    "size": size, "epochs": int(epochs),
    "published_full_size": scores("published_full"),
    "published_at_size": scores("published_test"),
    "finetuned_at_size": scores("finetuned_test"),
}
json.dump(summary, open(f"{out}/summary.json", "w"), indent=2)
for key in ["published_full_size", "published_at_size", "finetuned_at_size"]:
    a = summary[key]["all"]
    print(f"{key:20s} pixel agreement {100*a['pixel_agreement']:.1f} %  "
          f"mIoU {100*a['miou']:.1f}  mIoU(MFNet) {100*a['miou_mfnet']:.1f}")
EOF
