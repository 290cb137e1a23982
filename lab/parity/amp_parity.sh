#!/usr/bin/env bash
# bf16 vs fp32 accuracy parity (project issue 13): the demo's MFNet (`cargo xtask demo`: a
# synthetic MF-layout dataset, batch 6, SGD with lr decay 0.94) trained in fp32 and in bf16
# mixed precision (`rtf train --precision bf16`) from the same data and seeds, each scored on
# the test split; prints test mIoU per seed and precision, the means and the bf16 − fp32 gap.
#
# Usage (repo root, after `cargo build --release -p rtf-cli`):
#   lab/parity/amp_parity.sh                      # the demo's schedule: 240 frames, 160x128, 40 epochs
#   FRAMES=120 SIZE=96x64 EPOCHS=12 lab/parity/amp_parity.sh   # a smaller, faster variant
# Environment: FRAMES, SIZE, EPOCHS, SEEDS (default "0 1 2"), THREADS (default 2),
# OUT (default target/amp-parity), RTF (default target/release/rtf).
set -euo pipefail
FRAMES=${FRAMES:-240}
SIZE=${SIZE:-160x128}
EPOCHS=${EPOCHS:-40}
SEEDS=${SEEDS:-"0 1 2"}
OUT=${OUT:-target/amp-parity}
RTF=${RTF:-target/release/rtf}
export OMP_NUM_THREADS=${THREADS:-2}
mkdir -p "$OUT"
[ -f "$OUT/data/test.txt" ] || "$RTF" synth --out "$OUT/data" --count "$FRAMES" --seed 0 --size "$SIZE"
for seed in $SEEDS; do
  for precision in fp32 bf16; do
    run="$OUT/$precision-seed$seed"
    if [ ! -f "$run/eval_test.json" ]; then
      rm -rf "$run"
      start=$(date +%s)
      "$RTF" train --model mfnet --data "$OUT/data" --out "$run" --epochs "$EPOCHS" --batch-size 6 \
        --lr-decay 0.94 --seed "$seed" --precision "$precision" --tb-images-every 0 > "$run.log" 2>&1
      echo "$(( $(date +%s) - start ))" > "$run.seconds"
      "$RTF" eval --model mfnet --weights "$run/final.safetensors" --data "$OUT/data" --split test \
        --json "$run/eval_test.json" > /dev/null
    fi
  done
done
python3 - "$OUT" "$SEEDS" <<'PY'
import json, sys, statistics
out, seeds = sys.argv[1], sys.argv[2].split()
def miou(path):
    d = json.load(open(path))
    for key in ("miou", "mIoU"):
        if key in d:
            return d[key]
    return d["overall"]["miou"]
rows = {p: [100 * miou(f"{out}/{p}-seed{s}/eval_test.json") for s in seeds] for p in ("fp32", "bf16")}
secs = {p: [float(open(f"{out}/{p}-seed{s}.seconds").read()) for s in seeds] for p in ("fp32", "bf16")}
print("seed  " + "  ".join(f"{s:>6}" for s in seeds) + "    mean  train s (mean)")
for p, v in rows.items():
    print(f"{p:5} " + "  ".join(f"{x:6.2f}" for x in v) + f"  {statistics.mean(v):6.2f}  {statistics.mean(secs[p]):8.0f}")
gap = statistics.mean(rows["bf16"]) - statistics.mean(rows["fp32"])
print(f"bf16 - fp32 mean test mIoU: {gap:+.2f} points (target: within 1)")
PY
