#!/bin/bash
# Interleaved rtf / PIL+NumPy loader runs on the release-form fixture (docs/src/data.md).
cd "$(dirname "$0")/../.." && DATA=${1:-/tmp/dist48}
for i in 1 2 3; do
  echo "run $i rtf: $(target/release/rtf bench data --data "$DATA" --split train --frames 192 --json 2>/dev/null)"
  echo "run $i py:  $(.venv/bin/python lab/bench/bench_data.py --data "$DATA" --frames 192 --json)"
done
