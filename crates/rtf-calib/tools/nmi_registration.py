#!/usr/bin/env python3
"""A third registration of the MSRS pairs, by normalised mutual information (issue 28 §3).

Two registrations of the pairs exist and disagree by 1.5–2.2 thermal px in the part a
calibration absorbs (`registration_gap.py`): independent_rig.py's global model
(m = 1.02 − 0.02 ρ²) and rtf's per-scene one (`MSRS_REGISTRATION` and `MSRS_PARALLAX` in
real_rig.rs), which was measured with the calibrator's own edge features. This one shares
nothing with either: the objective is the normalised mutual information (Studholme's
(H(A) + H(B)) / H(A, B)) of the *intensities* of the RGB image (luma) and of the thermal image
sampled at the model's positions — no edges, no gradients, invariant to MSRS's contrast
remapping —, the optimiser a Nelder–Mead simplex started from both earlier answers' family
(identity and the 2 % model) and from rtf's medians, the best kept.

Per scene it fits, in rtf's parametrisation so the answers compare term by term, the thermal
position of RGB pixel (x, y):
    row' = y + b(y)                      (per-band vertical shift, 8 bands of 60 rows)
    c + s·(1 + k r² + k₂ r⁴)·R(α)·((x, row') − c) + (u, v),  r = |· − c| / half the width
first the 2-D model with b = 0 over the image less a 16 px border, then each band's shift by
a search of ±8 px (0.25 px steps, parabolic refinement of the NMI peak) with the model fixed;
a band whose NMI peak is flat (less than 0.002 above its ±4 px neighbours) is reported as
null (sky, dark night areas) and, in "bands_filled", follows the scenes' common profile.

Usage: nmi_registration.py OUT.json [--data ../shared/data] [--scenes N] [--stride 2]
       nmi_registration.py OUT.json --refill   # recompute bands_filled only
       nmi_registration.py OUT.json --merge A.json B.json   # runs split with --scenes/--skip
Writes {"scenes": {name: {"model": [s, k, k2, alpha_deg, u, v], "nmi": x, "bands": [...],
"bands_filled": [...]}}}.
"""
import argparse
import json
import os
import sys

import numpy as np
from PIL import Image

W, H = 640, 480
CU, CV = (W - 1) / 2, (H - 1) / 2
BINS = 32
BORDER = 16
BAND_ROWS = 60


def load(data, name):
    vi = np.asarray(Image.open(os.path.join(data, "msrs-samples/vi", name)).convert("RGB"),
                    dtype=np.float64)
    luma = vi @ np.array([0.299, 0.587, 0.114])
    ir = np.asarray(Image.open(os.path.join(data, "msrs-samples/ir", name)).convert("L"),
                    dtype=np.float64)
    return luma, ir


def bilinear(img, x, y):
    """Samples img at float coordinates (pixel centres at integers); NaN outside."""
    h, w = img.shape
    inside = (x >= 0) & (x <= w - 1.001) & (y >= 0) & (y <= h - 1.001)
    xc, yc = np.clip(x, 0, w - 1.001), np.clip(y, 0, h - 1.001)
    x0, y0 = np.floor(xc).astype(int), np.floor(yc).astype(int)
    fx, fy = xc - x0, yc - y0
    v = (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x0 + 1] * fx * (1 - fy)
         + img[y0 + 1, x0] * (1 - fx) * fy + img[y0 + 1, x0 + 1] * fx * fy)
    return np.where(inside, v, np.nan)


def position(p, xs, ys):
    """The thermal position of RGB pixels (xs, ys) under model p = (s, k, k2, alpha, u, v)."""
    s, k, k2, alpha, u, v = p
    x, y = xs - CU, ys - CV
    r2 = (x * x + y * y) / (CU * CU)
    g = s * (1 + k * r2 + k2 * r2 * r2)
    sn, cs = np.sin(np.radians(alpha)), np.cos(np.radians(alpha))
    return CU + g * (cs * x - sn * y) + u, CV + g * (sn * x + cs * y) + v


def nmi(a, b):
    """Studholme's normalised mutual information of two samples (NaNs in b dropped)."""
    keep = ~np.isnan(b)
    if keep.sum() < 1000:
        return 0.0
    ia = np.clip((a[keep] * (BINS / 256.0)).astype(int), 0, BINS - 1)
    ib = np.clip((b[keep] * (BINS / 256.0)).astype(int), 0, BINS - 1)
    joint = np.bincount(ia * BINS + ib, minlength=BINS * BINS).astype(np.float64)
    joint /= joint.sum()
    pa, pb = joint.reshape(BINS, BINS).sum(1), joint.reshape(BINS, BINS).sum(0)

    def entropy(p):
        p = p[p > 0]
        return float(-(p * np.log(p)).sum())

    return (entropy(pa) + entropy(pb)) / entropy(joint)


def nelder_mead(f, x0, steps, iters=400, tol=1e-7):
    """Minimises f from x0 with an initial simplex of the given steps (standard coefficients)."""
    n = len(x0)
    pts = [np.array(x0, dtype=np.float64)]
    for i in range(n):
        p = pts[0].copy()
        p[i] += steps[i]
        pts.append(p)
    vals = [f(p) for p in pts]
    for _ in range(iters):
        order = np.argsort(vals)
        pts, vals = [pts[i] for i in order], [vals[i] for i in order]
        if vals[-1] - vals[0] < tol:
            break
        centroid = np.mean(pts[:-1], 0)
        xr = centroid + (centroid - pts[-1])
        fr = f(xr)
        if fr < vals[0]:
            xe = centroid + 2 * (centroid - pts[-1])
            fe = f(xe)
            pts[-1], vals[-1] = (xe, fe) if fe < fr else (xr, fr)
        elif fr < vals[-2]:
            pts[-1], vals[-1] = xr, fr
        else:
            xc = centroid + 0.5 * (pts[-1] - centroid)
            fc = f(xc)
            if fc < vals[-1]:
                pts[-1], vals[-1] = xc, fc
            else:
                pts = [pts[0] + 0.5 * (p - pts[0]) for p in pts]
                vals = [vals[0]] + [f(p) for p in pts[1:]]
    best = int(np.argmin(vals))
    return pts[best], vals[best]


def fit_model(luma, ir, stride):
    ys, xs = np.mgrid[BORDER:H - BORDER:stride, BORDER:W - BORDER:stride].astype(np.float64)
    a = luma[ys.astype(int), xs.astype(int)]

    def cost(p):
        return -nmi(a, bilinear(ir, *position(p, xs, ys)))

    # Starts: identity, the 2 % model's family (s 1.02, k −0.02·(half width/corner)²), and
    # rtf's medians; the steps span a few pixels at the border.
    starts = [[1.0, 0.0, 0.0, 0.0, 0.0, 0.0], [1.02, -0.0128, 0.0, 0.0, 0.0, 0.0],
              [1.030, -0.031, 0.0, 0.0, -0.1, 2.3]]
    steps = [0.01, 0.01, 0.005, 0.3, 2.0, 2.0]
    best = None
    for x0 in starts:
        p, c = nelder_mead(cost, x0, steps)
        p, c = nelder_mead(cost, p, [s / 10 for s in steps])  # restart: a collapsed simplex
        if best is None or c < best[1]:
            best = (p, c)
    return best[0], -best[1]


def band_shifts(luma, ir, p, stride):
    """Each band's vertical shift (added to the row before the model), or None if flat."""
    out = []
    offsets = np.arange(-8, 8.001, 0.25)
    for band in range(H // BAND_ROWS):
        lo, hi = band * BAND_ROWS, (band + 1) * BAND_ROWS
        lo, hi = max(lo, 8), min(hi, H - 8)  # the outer bands 8 px inside, as rtf's
        ys, xs = np.mgrid[lo:hi:1, BORDER:W - BORDER:stride].astype(np.float64)
        a = luma[ys.astype(int), xs.astype(int)]
        scores = np.array([nmi(a, bilinear(ir, *position(p, xs, ys + d))) for d in offsets])
        i = int(np.argmax(scores))
        near = scores[np.abs(offsets - offsets[i]) >= 4]
        if scores[i] - (near.max() if near.size else 0) < 0.002 or i in (0, len(offsets) - 1):
            out.append(None)
            continue
        s0, s1, s2 = scores[i - 1], scores[i], scores[i + 1]
        den = s0 - 2 * s1 + s2
        frac = 0.5 * (s0 - s2) / den if den < 0 else 0.0
        out.append(float(offsets[i] + 0.25 * np.clip(frac, -0.5, 0.5)))
    return out


def fill_flat_bands(scenes):
    """Adds "bands_filled": a flat band takes the median over the scenes of that band's shift
    relative to the mean of the scene's measured bands, offset by that mean (the pairs'
    parallax has one profile: near ground at the bottom, far street in the middle)."""
    rel = []
    for entry in scenes.values():
        got = [b for b in entry["bands"] if b is not None]
        if got:
            rel.append([np.nan if b is None else b - np.mean(got) for b in entry["bands"]])
    rel = np.array(rel, dtype=np.float64)
    measured = ~np.isnan(rel).all(0)  # a band flat in every scene: no shift of its own
    profile = np.zeros(rel.shape[1])
    profile[measured] = np.nanmedian(rel[:, measured], 0)
    for entry in scenes.values():
        got = [(i, b) for i, b in enumerate(entry["bands"]) if b is not None]
        offset = float(np.mean([b - profile[i] for i, b in got])) if got else 0.0
        entry["bands_filled"] = [b if b is not None else float(profile[i] + offset)
                                 for i, b in enumerate(entry["bands"])]


def write(result, path):
    fill_flat_bands(result["scenes"])
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(result, f, indent=1)
    os.replace(tmp, path)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--data", default=os.path.join(os.path.dirname(__file__),
                                                   "../../../../shared/data"))
    ap.add_argument("--scenes", type=int, default=0, help="only the first N (0: all)")
    ap.add_argument("--skip", type=int, default=0, help="leave out the first N (to split a run)")
    ap.add_argument("--merge", nargs="*", default=[],
                    help="only merge these outputs of split runs into OUT.json")
    ap.add_argument("--stride", type=int, default=2, help="pixel stride of the samples")
    ap.add_argument("--refill", action="store_true",
                    help="only recompute bands_filled of an existing OUT.json")
    a = ap.parse_args()
    if a.refill:
        write(json.load(open(a.out)), a.out)
        return
    if a.merge:
        parts = [json.load(open(p)) for p in a.merge]
        merged = {"objective": parts[0]["objective"], "scenes": {}}
        for part in parts:
            merged["scenes"].update(part["scenes"])
        write(merged, a.out)
        return
    names = open(os.path.join(a.data, "msrs-samples/frames.txt")).read().split()
    names = [n if n.endswith(".png") else n + ".png" for n in names]
    if a.scenes:
        names = names[:a.scenes]
    names = names[a.skip:]
    result = {"objective": f"NMI, {BINS} bins, border {BORDER}, stride {a.stride}",
              "scenes": {}}
    if os.path.exists(a.out):  # resume: scenes already written are kept
        result = json.load(open(a.out))
    for name in names:
        if name.rsplit(".", 1)[0] in result["scenes"]:
            continue
        luma, ir = load(a.data, name)
        p, score = fit_model(luma, ir, a.stride)
        bands = band_shifts(luma, ir, p, a.stride)
        scene = name.rsplit(".", 1)[0]
        result["scenes"][scene] = {"model": [float(x) for x in p], "nmi": score,
                                   "bands": bands}
        print(scene, " ".join(f"{x:.4f}" for x in p), f"nmi {score:.4f}",
              "bands", " ".join("-" if b is None else f"{b:+.2f}" for b in bands),
              file=sys.stderr, flush=True)
        write(result, a.out)  # after every scene: a stopped run resumes


if __name__ == "__main__":
    main()
