#!/bin/bash
# Interleaved rtf / PIL+NumPy loader runs on the release-form fixture (docs/src/data.md).
cd /work/main
for i in 1 2 3; do
  echo "run $i rtf: $(target/release/rtf bench data --data /tmp/dist48 --split train --frames 192 --json 2>/dev/null)"
  echo "run $i py:  $(.venv/bin/python scripts/bench_data.py --data /tmp/dist48 --frames 192 --json)"
done
