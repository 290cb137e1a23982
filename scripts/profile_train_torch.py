#!/usr/bin/env python3
"""Op-level profile of one PyTorch training step (the step of scripts/bench_torch_train.py:
forward, cross-entropy, zero_grad, backward, SGD with momentum 0.9 and weight decay 5e-4), to
set beside `perf` on `rtf bench train` when looking for where a training-speed gap goes
(docs/src/benchmarks.md, issue 41). Prints torch.profiler's per-op self CPU time, largest
first, and writes the table as JSON with --json-out.

Usage (from the repo root):
    .venv/bin/python scripts/profile_train_torch.py --model mfnet --channels-last
    .venv/bin/python scripts/profile_train_torch.py --model rtfnet50 --warmup 1 --top 25
"""
import argparse
import json
import os
import sys

import torch
import torch.nn.functional as F
from torch.profiler import ProfilerActivity, profile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_torch import build  # noqa: E402


def step(net, opt, x, y):
    loss = F.cross_entropy(net(x), y)
    opt.zero_grad(set_to_none=False)
    loss.backward()
    opt.step()
    loss.item()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="mfnet")
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--size", default="640x480", help="WIDTHxHEIGHT")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--warmup", type=int, default=1)
    ap.add_argument("--channels-last", action="store_true")
    ap.add_argument("--top", type=int, default=20)
    ap.add_argument("--json-out")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    w, h = (int(v) for v in a.size.lower().split("x"))
    net = build(a.model).train()
    x = torch.rand(a.batch, 4, h, w)
    y = torch.randint(0, 9, (a.batch, h, w))
    if a.channels_last:
        net = net.to(memory_format=torch.channels_last)
        x = x.contiguous(memory_format=torch.channels_last)
    opt = torch.optim.SGD(net.parameters(), lr=0.01, momentum=0.9, weight_decay=5e-4)
    for _ in range(a.warmup):
        step(net, opt, x, y)
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        step(net, opt, x, y)
    events = sorted(prof.key_averages(), key=lambda e: -e.self_cpu_time_total)
    total = sum(e.self_cpu_time_total for e in events)
    rows = [{"op": e.key, "calls": e.count, "self_s": e.self_cpu_time_total / 1e6} for e in events]
    print(f"{a.model} {'channels_last' if a.channels_last else 'NCHW'}: one step, {total / 1e6:.3f} s self CPU "
          f"time in ops (torch {torch.__version__}, {a.threads} threads)")
    for r in rows[:a.top]:
        print(f"{r['op']:48} {r['calls']:6d} {r['self_s']:8.3f} s {100 * r['self_s'] * 1e6 / total:5.1f} %")
    if a.json_out:
        with open(a.json_out, "w") as f:
            json.dump({"model": a.model, "channels_last": a.channels_last, "total_s": total / 1e6, "rows": rows}, f,
                      indent=1)


if __name__ == "__main__":
    main()
