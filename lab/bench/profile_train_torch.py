#!/usr/bin/env python3
"""Op-level profile of one PyTorch training step (the step of lab/bench/bench_torch_train.py:
forward, cross-entropy, zero_grad, backward, SGD with momentum 0.9 and weight decay 5e-4), to
set beside `perf` on `rtf bench train` when looking for where a training-speed gap goes
(docs/src/benchmarks.md, issue 41). Prints torch.profiler's per-op self CPU time, largest
first, and writes the table as JSON with --json-out.

With --counts it counts the step's operators part by part instead (forward+loss,
zero_grad+backward, optimiser): every event torch.profiler records (ATen operators, autograd
nodes) at the outermost level of the part and in all, the counts `rtf bench train --count-ops`
prints for rtf's step. On a GPU every operator is one or more kernel launches, so the counts are
the host's share of a step, and they do not depend on the device: --zero-grad none and --foreach
give PyTorch's CUDA defaults (gradients set to None; the multi-tensor SGD) on the CPU.

Usage (from the repo root):
    .venv/bin/python lab/bench/profile_train_torch.py --model mfnet --channels-last
    .venv/bin/python lab/bench/profile_train_torch.py --model rtfnet50 --warmup 1 --top 25
    .venv/bin/python lab/bench/profile_train_torch.py --model mfnet --batch 8 --size 160x128 --counts \
        --zero-grad none --foreach
"""
import argparse
import json
import os
import sys

import torch
import torch.nn.functional as F
from torch.profiler import ProfilerActivity, profile, record_function

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_torch import build  # noqa: E402


PARTS = ("forward+loss", "zero_grad+backward", "optimiser")


def step(net, opt, x, y, set_to_none=False):
    """One step, each part inside a profiler range named after it (the counts' parts)."""
    with record_function(PARTS[0]):
        loss = F.cross_entropy(net(x), y)
    with record_function(PARTS[1]):
        opt.zero_grad(set_to_none=set_to_none)
        loss.backward()
    with record_function(PARTS[2]):
        opt.step()
    loss.item()


# RecordScope FUNCTION and BACKWARD_FUNCTION: ATen operators and autograd nodes, what rtf's
# counter (rtf_kernels::aten::count_ops) sees. Other ranges (the parts', the optimiser's
# "Optimizer.step#SGD.step") are not counted and do not make what they enclose nested.
COUNTED_SCOPES = (0, 1)


def part_counts(prof):
    """{part: {name: [all, outermost]}} of the operators under each part's range."""
    counts = {part: {} for part in PARTS}
    for event in prof.events():
        if event.scope not in COUNTED_SCOPES or event.name in PARTS:
            continue
        chain, parent = [], event.cpu_parent
        while parent is not None:
            chain.append(parent)
            parent = parent.cpu_parent
        part = next((e.name for e in chain if e.name in PARTS), None)
        if part is None:
            continue
        nested = any(e.scope in COUNTED_SCOPES and e.name not in PARTS for e in chain)
        entry = counts[part].setdefault(event.name, [0, 0])
        entry[0] += 1
        entry[1] += 0 if nested else 1
    return counts


def print_counts(counts):
    for part, ops in counts.items():
        outermost = sum(c[1] for c in ops.values())
        every = sum(c[0] for c in ops.values())
        top = sorted(ops.items(), key=lambda kv: (-kv[1][1], kv[0]))[:8]
        print(f"{part}: {outermost} operators outermost, {every} in all; "
              + ", ".join(f"{name} {c[1]}" for name, c in top))


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
    ap.add_argument("--counts", action="store_true", help="count operators per part instead of timing them")
    ap.add_argument("--zero-grad", choices=("zeros", "none"), default="zeros",
                    help="zero the gradients in place (rtf, the papers) or set them to None (PyTorch's default)")
    ap.add_argument("--foreach", action="store_true", help="SGD's multi-tensor form (PyTorch's default on CUDA)")
    a = ap.parse_args()
    set_to_none = a.zero_grad == "none"
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    w, h = (int(v) for v in a.size.lower().split("x"))
    net = build(a.model).train()
    x = torch.rand(a.batch, 4, h, w)
    y = torch.randint(0, 9, (a.batch, h, w))
    if a.channels_last:
        net = net.to(memory_format=torch.channels_last)
        x = x.contiguous(memory_format=torch.channels_last)
    opt = torch.optim.SGD(net.parameters(), lr=0.01, momentum=0.9, weight_decay=5e-4,
                          foreach=True if a.foreach else None)
    for _ in range(a.warmup):
        step(net, opt, x, y, set_to_none)
    if a.counts:
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            step(net, opt, x, y, set_to_none)
        counts = part_counts(prof)
        print(f"{a.model} {'channels_last' if a.channels_last else 'NCHW'} batch {a.batch}: one step's operators "
              f"(torch {torch.__version__}; zero_grad: {a.zero_grad}; SGD {'foreach' if a.foreach else 'default'})")
        print_counts(counts)
        if a.json_out:
            with open(a.json_out, "w") as f:
                json.dump({"model": a.model, "zero_grad": a.zero_grad, "foreach": a.foreach, "counts": counts}, f,
                          indent=1)
        return
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        step(net, opt, x, y, set_to_none)
    # The parts' ranges are not operators (and hold no self time of their own).
    events = sorted((e for e in prof.key_averages() if e.key not in PARTS), key=lambda e: -e.self_cpu_time_total)
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
