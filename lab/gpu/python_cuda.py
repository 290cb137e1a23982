#!/usr/bin/env python3
"""The Python package on a CUDA GPU (issue 60, item 4): `net(x)` with a CUDA tensor, against
`rtf bench model` for the same network, batch and precision in the same run.

For each network and precision (the fast path, as `rtf bench model` runs it):
1. **Stays on the device:** `net(x)` takes a torch tensor on the GPU and returns one there, and
   the forward pass copies nothing to the host: torch's profiler, over one call, records no
   device-to-host or host-to-device copy (the extension runs on the process's own libtorch, so
   torch's profiler sees rtf's kernels and copies too). The same for one training step
   (`net.train()`, forward, cross-entropy, backward): a copy from pageable host memory waits
   for the device's queue to drain, which a host-bound step cannot afford.
2. **Same numbers:** on a real MF frame with the published MFNet weights (`--frames`,
   `--weights`), `net(x)` equals `net.logits(rgb, thermal)` (the NumPy path, which is
   `rtf predict --logits`'s) for MFNet, bit for bit in fp32 and within a tolerance in half
   precision (checked on MFNet only: the other networks have no published weights).
3. **Same speed:** the median ms per frame of `net(x)` (synchronised before each clock read, as
   `rtf bench model` does) within 5 % of `rtf bench model --no-agreement --json` (run in its own
   process just before, with the same warm-up and passes). cuDNN's autotuner is on in both
   (torch.backends.cudnn.benchmark here: the setting is the process's libtorch's, which `rtf`
   turns on for CUDA).
4. **Where the memory goes** (reported, not bounded): rtf runs on the process's libtorch, so
   its GPU memory comes from torch's caching allocator and torch's statistics count it. Per
   network and precision: what the loaded network holds (`memory_allocated` after
   `load_network`, less before: the folded weights, with the plain ones released), the
   allocator's peak over the calls (`max_memory_allocated`, less before) and what it reserved
   from the device (`memory_reserved`); the allocator view that `rtf bench model`'s NVML peak
   (context and libraries included) cannot give (docs/src/gpu.md, "Peak GPU memory").

Usage, on the GPU machine with the GPU build of the wheel installed (scripts/gpu_check.sh's
`python` phase; docs/src/gpu.md):
    python3 lab/gpu/python_cuda.py --rtf RTF --frames MF_SAMPLES --weights MFNET.safetensors \
        [--models mfnet,rtfnet50] [--precisions fp32,fp16,bf16] [--json OUT]
`--device cpu` (fp32 and bf16) runs it here as a dry run of the script. Exit 1 when a check fails.
"""
import argparse
import glob
import json
import os
import statistics
import subprocess
import sys
import time

import numpy as np
import torch
from PIL import Image

import rtf

# Largest |logit difference| allowed between `net(x)` and `net.logits` of one frame on CUDA:
# the same folded network on the same input, so equal but for cuDNN's autotuner, which may
# time its way to another algorithm (another rounding) on a later call. On the CPU: equal.
CUDA_TOLERANCE = {"fp32": 1e-4, "fp16": 1e-2, "bf16": 1e-2}


def frame(path):
    """(rgb H×W×3 uint8, thermal H×W uint8, x [1, 4, H, W] float in [0, 1]) of an MF PNG."""
    rgba = np.asarray(Image.open(path))
    rgb, thermal = np.ascontiguousarray(rgba[..., :3]), np.ascontiguousarray(rgba[..., 3])
    x = torch.from_numpy(rgba.copy()).permute(2, 0, 1).float().div(255.0)[None]
    return rgb, thermal, x


def host_copies(run, device):
    """Names of the memory copies between host and device that `run()` makes (torch's profiler
    with its CUDA activity; none on the CPU)."""
    from torch.profiler import ProfilerActivity, profile
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device == "cuda" else [])
    with profile(activities=activities) as prof:
        run()
        if device == "cuda":
            torch.cuda.synchronize()
    return sorted({e.name for e in prof.events() if "HtoD" in e.name or "DtoH" in e.name})


def allocator_reader(device):
    """MiB of one of torch.cuda's allocator statistics (0 on the CPU); the peak reset first."""
    if device != "cuda":
        return lambda name: 0.0
    torch.cuda.synchronize()
    torch.cuda.empty_cache()
    torch.cuda.reset_peak_memory_stats()
    return lambda name: getattr(torch.cuda, name)() / 2**20


def training_copies(a, model):
    """Host-device copies of one training step of `model` from Python (after one untimed step,
    which makes cuDNN's plans): forward in training mode, cross-entropy, backward."""
    net = rtf.load_network(model, device=a.device).train()
    x = torch.rand(2, 4, 256, 320, device=a.device)
    y = torch.randint(0, len(net.classes), (2, 256, 320), device=a.device)

    def step():
        torch.nn.functional.cross_entropy(net(x), y).backward()

    step()
    return host_copies(step, a.device)


def time_forward(net, x, warmup, iterations, device):
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    times = []
    for i in range(warmup + iterations):
        sync()
        start = time.perf_counter()
        net(x)
        sync()
        if i >= warmup:
            times.append((time.perf_counter() - start) * 1e3 / x.shape[0])
    return statistics.median(times)


def bench_model(a, model, precision):
    cmd = [a.rtf, "bench", "model", "--model", model, "--precision", precision, "--device", a.device,
           "--batch", str(a.batch), "--warmup", str(a.warmup), "--iterations", str(a.iterations),
           "--no-agreement", "--json"]
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])["median_ms"]


def check_network(a, model, precision, real):
    """The three checks of one network and precision: (row, failures)."""
    failed = []
    weights = a.weights if model == "mfnet" else None
    mib = allocator_reader(a.device)
    before = mib("memory_allocated")
    net = rtf.load_network(model, weights=weights, device=a.device, precision=precision)
    held = mib("memory_allocated") - before
    x = torch.rand(a.batch, 4, 480, 640, device=a.device)
    out = net(x)
    if out.device.type != a.device or tuple(out.shape) != (a.batch, len(net.classes), 480, 640):
        failed.append(f"net(x) gave {tuple(out.shape)} on {out.device}")
    copies = host_copies(lambda: net(x), a.device)
    if copies:
        failed.append(f"net(x) copied between host and device: {copies}")
    row = {"model": model, "precision": precision, "batch": a.batch, "host_copies": copies}
    if model == "mfnet":
        rgb, thermal, x1 = real
        worst = float((net(x1.to(a.device))[0].float().cpu() - torch.from_numpy(net.logits(rgb, thermal))).abs().max())
        bound = CUDA_TOLERANCE[precision] if a.device == "cuda" else 0.0
        row["max_logit_difference"] = worst
        if worst > bound:
            failed.append(f"net(x) and net.logits differ by {worst:.3g} (bound {bound})")
    cli = bench_model(a, model, precision)
    ours = time_forward(net, x, a.warmup, a.iterations, a.device)
    row.update({"net_call_ms": ours, "rtf_bench_model_ms": cli, "ratio": ours / cli, "network_held_mib": held,
                "peak_allocated_mib": mib("max_memory_allocated") - before, "reserved_mib": mib("memory_reserved")})
    if ours > 1.05 * cli:
        failed.append(f"net(x) {ours:.2f} ms against rtf bench model {cli:.2f} ms (over 5 %)")
    return row, failed


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rtf", required=True)
    ap.add_argument("--frames", required=True, help="folder of real MF frames (4-channel PNG)")
    ap.add_argument("--weights", required=True, help="the published MFNet weights (safetensors)")
    ap.add_argument("--models", default="mfnet,rtfnet50,cmx-mit-b2")
    ap.add_argument("--precisions", default="fp32,fp16,bf16")
    ap.add_argument("--batch", type=int, default=1)
    ap.add_argument("--warmup", type=int, default=5)
    ap.add_argument("--iterations", type=int, default=20)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--json")
    a = ap.parse_args()
    torch.backends.cudnn.benchmark = True
    real = frame(sorted(glob.glob(os.path.join(a.frames, "*.png")))[0])
    rows, failures = [], []
    for model in a.models.split(","):
        copies = training_copies(a, model)
        rows.append({"model": model, "training_step_host_copies": copies})
        if copies:
            failures.append(f"{model}: one training step copied between host and device: {copies}")
        print(("ok   " if not copies else "FAIL ") + json.dumps(rows[-1]), flush=True)
        for precision in a.precisions.split(","):
            row, failed = check_network(a, model, precision, real)
            rows.append(row)
            failures += [f"{model} {precision}: {f}" for f in failed]
            print(("ok   " if not failed else "FAIL ") + json.dumps(row), flush=True)
        if a.json:  # after every network, so a run cut off keeps its part
            with open(a.json, "w") as f:
                json.dump({"torch": torch.__version__, "device": a.device, "rows": rows, "failures": failures}, f,
                          indent=1)
    for f in failures:
        print("FAIL " + f)
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
