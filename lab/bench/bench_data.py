#!/usr/bin/env python3
"""Reference input pipeline for `rtf bench data`: PIL + NumPy doing the same work per frame
(decode RGBA image + label PNG, random horizontal flip, RTFNet random crop resized back with
bicubic image / nearest label, float32 [0, 1] CHW, batches of 8 stacked), single process as in
the MFNet/RTFNet reference loaders with num_workers=0.

A root with a dataset.yaml (the plain layout, e.g. `rtf synth --format plain`) is read as
`SPLIT/{rgb,thermal,labels}/NAME.png`: 8-bit RGB, 16-bit thermal mapped to [0, 1] by the
yaml's `thermal: range: [lo, hi]` (clipped), the same crop resizing thermal bicubically as a
float image; the default split is `train`.

A root in the form public releases ship (`lab/bench/distributed_fixture.py`: a `color/` folder of
JPEGs `SEQ_eo-N.jpg`, `thermal16/SEQ_thermal-N.tiff` 16-bit LZW TIFFs, `annotations/SEQ_mask-N.png`)
is read the same way from those files (PIL decodes JPEG and TIFF).

Usage: .venv/bin/python lab/bench/bench_data.py --data DIR [--split test] [--frames 96] [--json]
"""
import argparse
import json
import os
import random
import re
import time

import numpy as np
from PIL import Image


def load_mf(root, name, rng):
    img = Image.open(os.path.join(root, "images", name + ".png"))
    img.load()
    lab = Image.open(os.path.join(root, "labels", name + ".png"))
    lab.load()
    w, h = img.size
    if rng.random() < 0.5:
        img = img.transpose(Image.FLIP_LEFT_RIGHT)
        lab = lab.transpose(Image.FLIP_LEFT_RIGHT)
    # RTFNet crop: each edge trimmed by up to 10 %, resized back.
    x0 = rng.randrange(0, int(0.1 * w))
    y0 = rng.randrange(0, int(0.1 * h))
    x1 = rng.randrange(int(0.9 * w + 0.999), w + 1)
    y1 = rng.randrange(int(0.9 * h + 0.999), h + 1)
    img = img.crop((x0, y0, x1, y1)).resize((w, h), Image.BICUBIC)
    lab = lab.crop((x0, y0, x1, y1)).resize((w, h), Image.NEAREST)
    x = np.asarray(img, dtype=np.float32).transpose(2, 0, 1) / 255.0
    y = np.asarray(lab, dtype=np.int64)
    return x, y


def thermal_range(root):
    """`range: [lo, hi]` of dataset.yaml's thermal rule (the only rule this reference reads)."""
    with open(os.path.join(root, "dataset.yaml")) as f:
        m = re.search(r"range:\s*\[\s*([0-9.]+)\s*,\s*([0-9.]+)\s*\]", f.read())
    if not m:
        raise SystemExit(f"{root}/dataset.yaml: no `thermal: range: [lo, hi]`")
    return float(m.group(1)), float(m.group(2))


def load_plain(root, split, name, rng, lo, hi):
    """One plain-layout frame: RGB, 16-bit thermal through the range, labels; flip and crop."""
    files = [os.path.join(root, split, d, name + ".png") for d in ("rgb", "thermal", "labels")]
    return load_files(files, rng, lo, hi)


def load_distributed(root, name, rng, lo, hi):
    """One frame of a release-form root: JPEG RGB, 16-bit LZW TIFF thermal, PNG labels."""
    seq, n = name.rsplit("/", 1)
    files = [os.path.join(root, "color", f"{seq}_eo-{n}.jpg"),
             os.path.join(root, "thermal16", f"{seq}_thermal-{n}.tiff"),
             os.path.join(root, "annotations", f"{seq}_mask-{n}.png")]
    return load_files(files, rng, lo, hi)


def load_files(files, rng, lo, hi):
    """RGB, thermal (through the range) and label files; flip and crop."""
    rgb = Image.open(files[0]).convert("RGB")
    th = Image.open(files[1])
    th.load()
    lab = Image.open(files[2])
    lab.load()
    t = (np.asarray(th, dtype=np.float32) - lo) / (hi - lo)
    th = Image.fromarray(np.clip(t, 0.0, 1.0), mode="F")
    w, h = rgb.size
    if rng.random() < 0.5:
        rgb, th, lab = (im.transpose(Image.FLIP_LEFT_RIGHT) for im in (rgb, th, lab))
    x0 = rng.randrange(0, int(0.1 * w))
    y0 = rng.randrange(0, int(0.1 * h))
    x1 = rng.randrange(int(0.9 * w + 0.999), w + 1)
    y1 = rng.randrange(int(0.9 * h + 0.999), h + 1)
    box = (x0, y0, x1, y1)
    rgb = rgb.crop(box).resize((w, h), Image.BICUBIC)
    th = th.crop(box).resize((w, h), Image.BICUBIC)
    lab = lab.crop(box).resize((w, h), Image.NEAREST)
    x = np.empty((4, h, w), dtype=np.float32)
    x[:3] = np.asarray(rgb, dtype=np.float32).transpose(2, 0, 1) / 255.0
    x[3] = np.asarray(th, dtype=np.float32)
    y = np.asarray(lab, dtype=np.int64)
    return x, y


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", required=True)
    ap.add_argument("--split", default=None)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--frames", type=int, default=96)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    split = args.split
    if os.path.isdir(os.path.join(args.data, "color")):
        lo, hi = thermal_range(args.data)
        names = sorted(f[:-4].replace("_eo-", "/") for f in os.listdir(os.path.join(args.data, "color"))
                       if f.endswith(".jpg"))
        load = lambda root, name, rng: load_distributed(root, name, rng, lo, hi)  # noqa: E731
    elif os.path.exists(os.path.join(args.data, "dataset.yaml")):
        split = split or "train"
        lo, hi = thermal_range(args.data)
        folder = os.path.join(args.data, split, "rgb")
        names = sorted(f[:-4] for f in os.listdir(folder) if f.endswith(".png"))
        load = lambda root, name, rng: load_plain(root, split, name, rng, lo, hi)  # noqa: E731
    else:
        if split is None:
            split = sorted(f[:-4] for f in os.listdir(args.data) if f.endswith(".txt"))[0]
        with open(os.path.join(args.data, split + ".txt")) as f:
            names = [line.strip() for line in f if line.strip()]
        load = load_mf
    rng = random.Random(0)
    load(args.data, names[0], rng)  # warm-up, not timed
    frames = 0
    start = time.perf_counter()
    while frames < args.frames:
        order = names[:]
        rng.shuffle(order)
        for i in range(0, len(order), args.batch):
            batch = [load(args.data, n, rng) for n in order[i:i + args.batch]]
            xs = np.stack([b[0] for b in batch])
            ys = np.stack([b[1] for b in batch])
            frames += xs.shape[0]
            if frames >= args.frames:
                break
    secs = time.perf_counter() - start
    fps = frames / secs
    if args.json:
        print(json.dumps({"frames_per_s": fps, "frames": frames, "seconds": secs, "batch": args.batch}))
    else:
        print(f"{frames} frames (batch {args.batch}, PIL + NumPy) in {secs:.2f} s: {fps:.1f} frames/s")


if __name__ == "__main__":
    main()
