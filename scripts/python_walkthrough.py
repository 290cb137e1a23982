#!/usr/bin/env python3
"""The Python page's walkthrough (docs/src/python.md), end to end: open a dataset, take rtf's
loader into a few steps of one's own PyTorch loop with an rtf network, evaluate it, then
predict and colourise a real MSRS frame.

The shared MSRS samples carry no labels, so the training and evaluation half runs on a labelled
synthetic MF-layout set (`rtf synth`, made into --out unless --data names a labelled root); the
prediction half runs on the MSRS pair (vi/NAME.png RGB, ir/NAME.png 8-bit thermal).

Usage: .venv/bin/python scripts/python_walkthrough.py --out DIR [--data ROOT] [--rtf target/release/rtf]
       [--msrs ../shared/data/msrs-samples] [--steps 4]
Needs the wheel installed (`cargo xtask wheel`, `pip install target/wheels/rtf-*.whl`).
"""
import argparse
import os
import subprocess
import sys
import time

import numpy as np
import torch
from PIL import Image

import rtf


def args():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="new folder for the outputs")
    p.add_argument("--data", help="a labelled dataset root (default: rtf synth into --out)")
    p.add_argument("--rtf", default="target/release/rtf", help="the rtf binary (for rtf synth)")
    shared = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared")
    p.add_argument("--msrs", default=os.path.join(shared, "data", "msrs-samples"))
    p.add_argument("--steps", type=int, default=4)
    return p.parse_args()


def save_png(path, array):
    """Writes a PNG whole (temp + rename); never over an existing file."""
    if os.path.exists(path):
        sys.exit(f"{path} exists: give a new --out")
    tmp = f"{path}.tmp-{os.getpid()}.png"
    Image.fromarray(array).save(tmp)
    os.replace(tmp, path)


def train_a_few_steps(net, ds, steps):
    """`steps` SGD steps of a plain PyTorch loop over rtf's loader (epoch after epoch)."""
    net.train()
    opt = torch.optim.SGD(net.parameters(), lr=0.01, momentum=0.9)
    ignore = ds.ignore_id if ds.ignore_id is not None else -100
    loader = ds.loader("train", 4, seed=0, size=(320, 240))
    step = 0
    while step < steps:
        for x, y in loader:
            loss = torch.nn.functional.cross_entropy(net(x), y, ignore_index=ignore)
            opt.zero_grad()
            loss.backward()
            opt.step()
            print(f"step {step}: loss {loss.item():.4f}")
            step += 1
            if step == steps:
                break
    net.eval()


def main():
    a = args()
    os.makedirs(a.out, exist_ok=False)
    data = a.data
    if data is None:
        data = os.path.join(a.out, "synth")
        subprocess.run([a.rtf, "synth", "--out", data, "--count", "24", "--seed", "0",
                        "--size", "320x240"], check=True, stdout=subprocess.DEVNULL)
    ds = rtf.open_dataset(data)
    print(ds, ds.splits, [c["name"] for c in ds.classes])
    torch.manual_seed(0)
    net = rtf.load_network("mfnet")
    start = time.perf_counter()
    train_a_few_steps(net, ds, a.steps)
    print(f"{a.steps} steps in {time.perf_counter() - start:.1f} s")
    scores = rtf.evaluate(net, ds, split="test")
    print(scores, {k: v for k, v in scores.per_class.items() if v is not None})
    name = open(os.path.join(a.msrs, "frames.txt")).read().split()[0]
    rgb = np.asarray(Image.open(os.path.join(a.msrs, "vi", name + ".png")).convert("RGB"))
    thermal = np.asarray(Image.open(os.path.join(a.msrs, "ir", name + ".png")))
    ids = net.predict(rgb, thermal)
    save_png(os.path.join(a.out, name + "_ids.png"), ids)
    save_png(os.path.join(a.out, name + "_color.png"), net.colorize(ids))
    print(f"{name}: classes {np.unique(ids).tolist()} -> {a.out}")


if __name__ == "__main__":
    main()
