#!/usr/bin/env python3
"""The checks of scripts/gpu_check.sh's `correct` phase, on the files it wrote under WORK:

1. The published MFNet on the real MF frames (mf_<device>_<precision>/*.npy logits): each GPU
   variant's arg-max labels against the CPU's plain path. Bounds: plain and fast fp32 ≥ 99.9 %
   (the issue's), fp16 ≥ 99.9 %, bf16 ≥ 99 % (8 mantissa bits move border pixels).
2. One SGD step of MFNet from the published weights (step_cpu, step_cuda: final.safetensors):
   the GPU's weight update against the CPU's, ‖Δgpu − Δcpu‖ / ‖Δcpu‖ over every float tensor,
   and over the learnable parameters alone. Bound 1e-2: the GPU's fp32 convolutions run on
   TF32 tensor cores by default (10 mantissa bits, ~5e-4 relative per product), in PyTorch and
   rtf alike.

Usage: gpu_correctness.py WORK INIT_WEIGHTS   (exit 1 when a bound is missed)
"""
import glob
import os
import sys

import numpy as np
from safetensors.numpy import load_file

work, init_path = sys.argv[1:]
failed = []


def check(ok, text):
    print(("ok   " if ok else "FAIL ") + text)
    if not ok:
        failed.append(text)


cpu_files = sorted(glob.glob(f"{work}/mf_cpu_plain/*.npy"))
check(len(cpu_files) == 2, f"{len(cpu_files)} CPU logit files of the real MF frames")
for variant, bound in (("plain", 0.999), ("fp32", 0.999), ("fp16", 0.999), ("bf16", 0.99)):
    same = total = 0
    worst = 0.0
    for cpu_file in cpu_files:
        a = np.load(cpu_file)
        b = np.load(f"{work}/mf_cuda_{variant}/{os.path.basename(cpu_file)}")
        assert a.shape == b.shape, (cpu_file, a.shape, b.shape)
        assert np.isfinite(b).all(), f"non-finite GPU logits ({variant})"
        worst = max(worst, float(np.abs(a - b).max()))
        same += int((a.argmax(0) == b.argmax(0)).sum())
        total += a[0].size
    check(same / total >= bound, f"real MF frames, GPU {variant} vs CPU plain: labels agree on "
          f"{100 * same / total:.3f} % of {total} pixels (bound {100 * bound:.1f} %), "
          f"max |logit difference| {worst:.3g}")

init = load_file(init_path)
after = {d: load_file(f"{work}/step_{d}/final.safetensors") for d in ("cpu", "cuda")}
names = sorted(k for k in init if k in after["cpu"] and k in after["cuda"]
               and np.issubdtype(init[k].dtype, np.floating))
check(len(names) > 0, f"{len(names)} float tensors shared by the initial and trained weights")


def update_difference(keep):
    num = den = 0.0
    for k in filter(keep, names):
        d_cpu = after["cpu"][k].astype(np.float64) - init[k]
        d_gpu = after["cuda"][k].astype(np.float64) - init[k]
        num += float(((d_gpu - d_cpu) ** 2).sum())
        den += float((d_cpu ** 2).sum())
    return (num / den) ** 0.5, den ** 0.5


moved, norm = update_difference(lambda k: True)
check(norm > 0, f"the CPU step moved the weights (‖Δcpu‖ = {norm:.3g})")
check(moved <= 1e-2, f"one SGD step, GPU vs CPU: update difference {moved:.2e} over every float tensor "
      "(bound 1e-2, TF32)")
params, _ = update_difference(lambda k: "running_" not in k)
check(params <= 1e-2, f"one SGD step, GPU vs CPU: update difference {params:.2e} over the learnable "
      "parameters (bound 1e-2, TF32)")
sys.exit(1 if failed else 0)
