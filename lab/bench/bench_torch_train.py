#!/usr/bin/env python3
"""Training peer of `rtf bench train`: full training steps (forward, cross-entropy, backward,
SGD with momentum 0.9 and weight decay 5e-4, lr 0.01: MFNet's paper recipe, rtf's `sgd`) of the
same network on the same random frames in PyTorch eager: NCHW fp32, channels_last fp32, and
bf16 autocast in both layouts. Then `rtf bench train --json` in fp32 and bf16, and the ratios of
rtf's images/s to the best PyTorch configuration of the same precision, and of peak RSS.

Every configuration, PyTorch's and rtf's alike, runs in a fresh process of its own, round after
round (interleaved), so load from other processes on a shared machine hits them all alike.

Usage (from the repo root, after `cargo build --release -p rtf-cli`):
    .venv/bin/python lab/bench/bench_torch_train.py --model mfnet --batch 4 --threads 2
    .venv/bin/python lab/bench/bench_torch_train.py --model rtfnet50 --rounds 2 --steps 3

The networks are those of lab/bench/bench_torch.py (published MFNet and RTFNet code).
"""
import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time

import torch
import torch.nn.functional as F

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_torch import build  # noqa: E402

# label: (channels_last, bf16)
TORCH_CONFIGS = {
    "torch fp32 NCHW": (False, False),
    "torch fp32 channels_last": (True, False),
    "torch bf16 NCHW": (False, True),
    "torch bf16 channels_last": (True, True),
}


def torch_worker(args, channels_last, bf16):
    """Images/s and peak RSS of one configuration, in this (fresh) process."""
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    w, h = args.size
    net = build(args.model).train()
    x = torch.rand(args.batch, 4, h, w)
    y = torch.randint(0, 9, (args.batch, h, w))
    if channels_last:
        net = net.to(memory_format=torch.channels_last)
        x = x.contiguous(memory_format=torch.channels_last)
    opt = torch.optim.SGD(net.parameters(), lr=0.01, momentum=0.9, weight_decay=5e-4)
    fwd, bwd, stp, total = [], [], [], 0.0
    for i in range(args.warmup + args.steps):
        t0 = time.perf_counter()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            logits = net(x)
        loss = F.cross_entropy(logits.float(), y)
        t1 = time.perf_counter()
        opt.zero_grad(set_to_none=False)
        loss.backward()
        t2 = time.perf_counter()
        opt.step()
        loss.item()
        t3 = time.perf_counter()
        if i >= args.warmup:
            fwd.append(t1 - t0)
            bwd.append(t2 - t1)
            stp.append(t3 - t2)
            total += t3 - t0
    return {
        "images_per_s": args.steps * args.batch / total,
        "forward_s": statistics.median(fwd),
        "backward_s": statistics.median(bwd),
        "optimizer_s": statistics.median(stp),
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def run_torch(args, label):
    cmd = [sys.executable, os.path.abspath(__file__), "--worker", label, "--model", args.model,
           "--batch", str(args.batch), "--size", f"{args.size[0]}x{args.size[1]}", "--threads",
           str(args.threads), "--warmup", str(args.warmup), "--steps", str(args.steps)]
    return json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)


def run_rtf(args, precision):
    cmd = [args.rtf, "bench", "train", "--model", args.model, "--batch", str(args.batch), "--size",
           f"{args.size[0]}x{args.size[1]}", "--precision", precision, "--threads", str(args.threads),
           "--warmup", str(args.warmup), "--steps", str(args.steps), "--json"]
    return json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)


def size(text):
    w, h = text.lower().split("x")
    return int(w), int(h)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="mfnet")
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--size", type=size, default=(640, 480), help="WIDTHxHEIGHT")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--steps", type=int, default=5, help="timed steps per configuration and round")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--precisions", default="fp32,bf16")
    ap.add_argument("--rtf", default="target/release/rtf", help="the rtf binary")
    ap.add_argument("--json-out", help="also write every sample here")
    ap.add_argument("--skip", default="", help="comma-separated PyTorch configurations to leave out (e.g. "
                    "'torch bf16 NCHW', which on CPUs without native bf16 is by far the slowest)")
    ap.add_argument("--worker", choices=sorted(TORCH_CONFIGS), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(torch_worker(args, *TORCH_CONFIGS[args.worker])))
        return
    precisions = args.precisions.split(",")
    print(f"{args.model}: batch {args.batch}, {args.size[0]}x{args.size[1]}, {args.threads} threads, "
          f"PyTorch {torch.__version__}, {args.rounds} interleaved rounds of {args.steps} timed steps "
          f"after {args.warmup} warm-up, a fresh process per configuration", flush=True)
    samples = {}
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}

    def record(label, sample):
        samples.setdefault(label, []).append(sample)
        print(f"  {label}: {sample['images_per_s']:.3f} images/s, peak RSS {sample['peak_rss_mb']:.0f} MiB",
              flush=True)

    for _ in range(args.rounds):
        for label, (_, bf16) in TORCH_CONFIGS.items():
            if ("bf16" if bf16 else "fp32") in precisions and label not in skip:
                record(label, run_torch(args, label))
        for precision in precisions:
            record(f"rtf {precision}", run_rtf(args, precision))
    if args.json_out:
        with open(args.json_out, "w") as f:
            json.dump(samples, f, indent=1)
    rows = {}
    for label, runs in samples.items():
        rows[label] = {k: statistics.median(r[k] for r in runs)
                       for k in ("images_per_s", "forward_s", "backward_s", "optimizer_s", "peak_rss_mb")}
    print(f"{'':26} {'img/s':>7} {'fwd s':>7} {'bwd s':>7} {'opt s':>7} {'peak RSS MiB':>12}")
    for label, r in rows.items():
        print(f"{label:26} {r['images_per_s']:7.2f} {r['forward_s']:7.3f} {r['backward_s']:7.3f} "
              f"{r['optimizer_s']:7.3f} {r['peak_rss_mb']:12.0f}")
    for precision in precisions:
        torch_rows = {k: v for k, v in rows.items() if k.startswith("torch") and precision in k}
        best = max(torch_rows, key=lambda k: torch_rows[k]["images_per_s"])
        ours = rows[f"rtf {precision}"]
        print(f"rtf {precision} vs best PyTorch {precision} ({best}): "
              f"{ours['images_per_s'] / torch_rows[best]['images_per_s']:.2f}x images/s, "
              f"peak RSS {ours['peak_rss_mb'] / torch_rows[best]['peak_rss_mb']:.2f}x")


if __name__ == "__main__":
    main()
