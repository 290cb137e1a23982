#!/usr/bin/env python3
"""Interleaved A/B of training speed: PyTorch workers of lab/bench/bench_torch_train.py and `rtf bench train`
variants that differ only by environment (e.g. RTF_TRAIN_LAYOUT=nchw, MIMALLOC_PURGE_DELAY=20000), each in a
fresh process, round after round; prints every sample and the medians (docs/src/benchmarks.md, issue 41).

Usage (from the repo root): .venv/bin/python lab/bench/train_ab.py MODEL ROUNDS STEPS "VARIANT;VARIANT;..."
    e.g. lab/bench/train_ab.py rtfnet50 2 1 "torch fp32 channels_last;rtf;rtf RTF_TRAIN_LAYOUT=nchw"
"""
import json, os, statistics, subprocess, sys
model, rounds, steps = sys.argv[1], int(sys.argv[2]), sys.argv[3]
variants = sys.argv[4].split(";")  # e.g. "torch fp32 channels_last;rtf;rtf RTF_TRAIN_LAYOUT=nchw"
common = ["--model", model, "--batch", "4", "--size", "640x480", "--threads", "2", "--warmup", "1", "--steps", steps]
res = {}
for r in range(rounds):
    for v in variants:
        if v.startswith("torch"):
            cmd = [".venv/bin/python", "lab/bench/bench_torch_train.py", "--worker", v] + common
            env = os.environ
        else:
            cmd = ["target/release/rtf", "bench", "train", "--json"] + common
            env = dict(os.environ)
            for kv in v.split()[1:]:
                k, val = kv.split("=", 1); env[k] = val
        out = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout)
        res.setdefault(v, []).append(out)
        print(f"{v}: {out['images_per_s']:.3f} img/s fwd {out['forward_s']:.3f} bwd {out['backward_s']:.3f} opt {out['optimizer_s']:.3f} rss {out['peak_rss_mb']:.0f}", flush=True)
print("median:")
for v, runs in res.items():
    m = {k: statistics.median(x[k] for x in runs) for k in ("images_per_s", "forward_s", "backward_s", "optimizer_s", "peak_rss_mb")}
    print(f"  {v:40} {m['images_per_s']:.3f} img/s fwd {m['forward_s']:.3f} bwd {m['backward_s']:.3f} opt {m['optimizer_s']:.3f} rss {m['peak_rss_mb']:.0f}")
json.dump(res, open(os.environ.get("TRAIN_AB_JSON", os.devnull), "w"))
