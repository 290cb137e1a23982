#!/usr/bin/env python3
"""rtf from Python, timed side by side in one run (docs/src/python.md, "Speed"):

1. rtf's loader (`Dataset.loader`) feeding a PyTorch loop against `torch.utils.data.DataLoader`
   over a PIL + NumPy dataset of the same files (JPEG RGB, 16-bit TIFF thermal mapped by the
   dataset.yaml range, PNG labels; 640x480), the same batch size, horizontal flips and
   worker count: frames/s over whole epochs.
2. `net.logits` on a 640x480 frame against `rtf bench model` for the same network and
   precision (the fast path, as `rtf bench model` runs it): median ms per frame.

Data: `lab/bench/distributed_fixture.py --out DIR` (48 real MSRS scenes in the release form).
Usage: .venv/bin/python lab/bench/bench_python.py --data DIR [--rtf target/release/rtf]
       [--workers 2] [--batch 8] [--epochs 3] [--model mfnet] [--precision fp32] [--json]
"""
import argparse
import json
import os
import platform
import re
import statistics
import subprocess
import time

import numpy as np
import torch
from PIL import Image

import rtf


class PilDataset(torch.utils.data.Dataset):
    """The same frames as rtf reads them, by PIL + NumPy (flip p=0.5, thermal range clipped)."""

    def __init__(self, root, lo, hi):
        lines = open(os.path.join(root, "splits", "train.txt")).read().split()
        self.items = []
        for line in lines:
            rgb, label = line.split(",")
            seq, n = re.match(r"color/(.+)_eo-(\d+)\.jpg", rgb).groups()
            thermal = f"thermal16/{seq}_thermal-{n}.tiff"
            self.items.append([os.path.join(root, p) for p in (rgb, thermal, label)])
        self.lo, self.hi = lo, hi

    def __len__(self):
        return len(self.items)

    def __getitem__(self, i):
        rgb_path, thermal_path, label_path = self.items[i]
        rgb = np.asarray(Image.open(rgb_path).convert("RGB"), dtype=np.float32) / 255.0
        counts = np.asarray(Image.open(thermal_path), dtype=np.float32)
        thermal = np.clip((counts - self.lo) / (self.hi - self.lo), 0.0, 1.0)
        label = np.asarray(Image.open(label_path), dtype=np.int64)
        x = np.concatenate([rgb.transpose(2, 0, 1), thermal[None]], axis=0)
        if np.random.random() < 0.5:
            x, label = x[:, :, ::-1], label[:, ::-1]
        return torch.from_numpy(x.copy()), torch.from_numpy(label.copy())


def frames_per_second(batches, epochs):
    frames, start = 0, time.perf_counter()
    for _ in range(epochs):
        for x, y in batches():
            frames += x.shape[0]
            x.sum(), y.sum()  # the consumer touches every batch
    return frames / (time.perf_counter() - start)


def bench_loader(a):
    ds = rtf.open_dataset(a.data)
    loader = ds.loader("train", a.batch, workers=a.workers, seed=0, model=a.model)
    ours = frames_per_second(lambda: loader, a.epochs)
    reference = torch.utils.data.DataLoader(
        PilDataset(a.data, 21800, 24860), batch_size=a.batch, shuffle=True,
        num_workers=a.workers, persistent_workers=a.workers > 0)
    theirs = frames_per_second(lambda: reference, a.epochs)
    return {"rtf_loader_fps": ours, "torch_dataloader_fps": theirs, "ratio": ours / theirs}


def bench_logits(a):
    net = rtf.load_network(a.model, precision=a.precision)
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
    thermal = rng.integers(0, 256, (480, 640), dtype=np.uint8)
    for _ in range(3):
        net.logits(rgb, thermal)
    samples = []
    for _ in range(a.iterations):
        start = time.perf_counter()
        net.logits(rgb, thermal)
        samples.append(1000 * (time.perf_counter() - start))
    cli = json.loads(subprocess.run(
        [a.rtf, "bench", "model", "--model", a.model, "--precision", a.precision,
         "--iterations", str(a.iterations), "--no-agreement", "--json"],
        check=True, capture_output=True, text=True).stdout)
    ours = statistics.median(samples)
    return {"net_logits_ms": ours, "rtf_bench_model_ms": cli["median_ms"],
            "logits_over_bench": ours / cli["median_ms"], "cpu": cli.get("cpu")}


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True)
    p.add_argument("--rtf", default="target/release/rtf")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--epochs", type=int, default=3)
    p.add_argument("--model", default="mfnet")
    p.add_argument("--precision", default="fp32")
    p.add_argument("--iterations", type=int, default=10)
    p.add_argument("--json", action="store_true")
    a = p.parse_args()
    result = {"model": a.model, "precision": a.precision, "workers": a.workers,
              "batch": a.batch, "machine": platform.processor() or platform.machine(),
              "torch_threads": torch.get_num_threads()}
    result.update(bench_loader(a))
    result.update(bench_logits(a))
    if a.json:
        print(json.dumps(result, indent=1))
    else:
        for k, v in result.items():
            print(f"{k}: {v:.2f}" if isinstance(v, float) else f"{k}: {v}")


if __name__ == "__main__":
    main()
