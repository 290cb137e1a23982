"""Arg-max agreement of two folders of `rtf predict --logits` files ([classes, H, W] .npy, same
names): used by scripts/gpu_smoke.sh and lab/gpu/gpu_correctness.py to compare a GPU's logits
with the CPU's."""
import glob
import os

import numpy as np


def agreement(reference_dir, other_dir):
    """(pixels whose arg-max agrees, pixels, largest |logit difference|) over the reference
    folder's files; every file must exist in both with one shape, and finite in `other_dir`."""
    files = sorted(glob.glob(os.path.join(reference_dir, "*.npy")))
    assert files, f"no logits in {reference_dir}"
    same = total = 0
    worst = 0.0
    for path in files:
        a = np.load(path)
        b = np.load(os.path.join(other_dir, os.path.basename(path)))
        assert a.shape == b.shape, (path, a.shape, b.shape)
        assert np.isfinite(b).all(), f"non-finite logits in {other_dir}"
        worst = max(worst, float(np.abs(a - b).max()))
        same += int((a.argmax(0) == b.argmax(0)).sum())
        total += a[0].size
    return same, total, worst


def relative_difference(reference_dir, other_dir):
    """‖other − reference‖ / ‖reference‖ over all logits of the reference folder's files (the
    same files as `agreement`): a measure that does not hang on arg-max ties, for networks
    without trained weights."""
    num = den = 0.0
    for path in sorted(glob.glob(os.path.join(reference_dir, "*.npy"))):
        a = np.load(path).astype(np.float64)
        b = np.load(os.path.join(other_dir, os.path.basename(path))).astype(np.float64)
        assert a.shape == b.shape, (path, a.shape, b.shape)
        num += float(((b - a) ** 2).sum())
        den += float((a ** 2).sum())
    assert den > 0, f"no logits in {reference_dir}"
    return (num / den) ** 0.5
