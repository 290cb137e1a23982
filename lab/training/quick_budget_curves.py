#!/usr/bin/env python3
"""Summary of lab/training/quick_budget_curves.sh: for every network (or recipe), the validation
mIoU per epoch against twice the all-unlabelled answer's (every pixel the most frequent class
of the validation labels: its IoU is its pixel share, every other class's 0; the threshold of
`xtask reproduce`'s `learned`), and the first epoch from which the curve stays above it.

Usage: python3 lab/training/quick_budget_curves.py OUT [--json FILE]
"""
import glob
import json
import os
import sys

import numpy as np
from PIL import Image


def trivial(label_files, classes):
    counts = np.zeros(256, dtype=np.int64)
    for f in label_files:
        labels = np.load(f) if f.endswith(".npy") else np.asarray(Image.open(f))
        counts += np.bincount(labels.ravel(), minlength=256)[:256]
    counts = counts[:classes]
    return counts.max() / counts.sum() / classes


def curve(run):
    """(epoch, val mIoU) of a run folder; a recipe's last stage (its last sub-folder with a log)."""
    logs = sorted(glob.glob(f"{run}/log.jsonl")) or sorted(glob.glob(f"{run}/*/log.jsonl"),
                                                          key=os.path.getmtime)
    if not logs:
        return []
    points = []
    for line in open(logs[-1]):
        r = json.loads(line)
        if r.get("val_miou") is not None:
            points.append((r["epoch"] + 1, r["val_miou"]))
    return points


def first_stable(points, threshold):
    """The first epoch from which every later epoch's mIoU is at least `threshold`."""
    first = None
    for epoch, miou in points:
        if miou >= threshold:
            first = first or epoch
        else:
            first = None
    return first


def main():
    out = sys.argv[1]
    mf_val = [f"{out}/mf/labels/{n.strip()}.png" for n in open(f"{out}/mf/val.txt") if n.strip()]
    mf160 = f"{out}/mf160"
    big_val = [f"{mf160}/labels/{n.strip()}.png" for n in open(f"{mf160}/val.txt") if n.strip()] \
        if os.path.isdir(mf160) else []
    mf1280 = f"{out}/mf1280"
    frames_val = [f"{mf1280}/labels/{n.strip()}.png" for n in open(f"{mf1280}/val80.txt")
                  if n.strip()] if os.path.isdir(mf1280) else []
    thresholds = {
        "frames": 2 * trivial(frames_val, 9) if frames_val else float("nan"),
        "model": 2 * trivial(mf_val, 9),
        "sweep": 2 * trivial(mf_val, 9),
        "sweep-big": 2 * trivial(big_val, 9) if big_val else float("nan"),
        "recipe": 2 * trivial(sorted(glob.glob(f"{out}/fr/val/*/SegmentationClass/*")), 12),
    }
    rows = []
    for run in sorted(d for d in glob.glob(f"{out}/*-*") if os.path.isdir(d)):
        name = os.path.basename(run)
        kind = "sweep-big" if name.startswith("sweep-big-") else name.split("-")[0]
        if kind not in thresholds:
            continue
        points = curve(run)
        t = thresholds[kind]
        best = max((m for _, m in points), default=float("nan"))
        rows.append({"run": name, "epochs": len(points), "threshold": t, "best": best,
                     "first_stable": first_stable(points, t),
                     "curve": [round(m, 4) for _, m in points]})
        at = {e: round(100 * m, 1) for e, m in points if e in (5, 10, 15, 20, 30, 40, 50)}
        print(f"{name:28s} 2x trivial {100 * t:5.1f}  best {100 * best:5.1f}  "
              f"stays above from epoch {rows[-1]['first_stable']}  {at}")
    if "--json" in sys.argv:
        json.dump(rows, open(sys.argv[sys.argv.index("--json") + 1], "w"), indent=1)


if __name__ == "__main__":
    main()
