#!/usr/bin/env python3
"""A third registration of the MSRS pairs, by normalised mutual information (issue 28 §3).

Two registrations of the pairs exist and disagree by 1.5–2.2 thermal px in the part a
calibration absorbs (`registration_gap.py`): independent_rig.py's global model
(m = 1.02 − 0.02 ρ²) and rtf's per-scene one (`MSRS_REGISTRATION` and `MSRS_PARALLAX` in
real_rig.rs), which was measured with the calibrator's own edge features. This one shares
nothing with either: the objective is the normalised mutual information (Studholme's
(H(A) + H(B)) / H(A, B), 32 bins) of the *intensities* of the RGB luma and of the thermal
image sampled at the model's positions — no edges, no gradients, blind to MSRS's contrast
remapping.

Per scene, NMI is too weak to fit a model: in a first run (per scene, Nelder–Mead), 10 of 29
scenes ran to the edge of the search (s 0.90, shifts of 12–20 px; night scenes score NMI
1.01–1.03) and most bands' peaks failed a split-half check. So the registration is fitted
*pooled* over the scenes — one model, the one thing a rig's common field depends on —, by
maximising the mean NMI over the 48 scenes:

- **referee**: the mean NMI (and per-scene wins) of the two existing registrations, each as
  it stands: the generator's 2 % model, rtf's per-scene models with their parallax bands,
  and rtf's median model alone (one global model, as the generator's);
- **pooled model**: the thermal position of RGB pixel (x, y),
      c + s·(1 + k r² + k₂ r⁴)·R(α)·((x, y + b(y)) − c) + (u, v),  r = |· − c| / half the width,
  (rtf's family, so the answers compare term by term) by Nelder–Mead from three starts
  (identity, the 2 % model's family, rtf's medians), the best kept, within s 0.9–1.1,
  |k|, |k₂| ≤ 0.1, |α| ≤ 3°, shifts ≤ 20 px (outside, NMI has degenerate maxima: a shrunken,
  near-constant patch);
- **pooled bands**: with that model, each 60-row band's vertical shift b by a ±8 px search
  (0.25 px steps, parabolic refinement) of the mean NMI over the scenes; reported with the
  left/right split-half difference, and null where flat or split (> 1 px); null bands are
  interpolated between the measured ones in "bands_filled".

Usage: nmi_registration.py OUT.json [--data ../shared/data] [--stride 4]
Writes {"objective", "referee", "pooled": {"model", "bands"}, "scenes": {name: {"model",
"bands_filled"}}} — every scene the pooled registration, in the form independent_rig.py
--registration and registration_gap.py --nmi read.
"""
import argparse
import json
import os
import sys

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import registration_gap  # noqa: E402  (the model's form and rtf's tables, read as text)

W, H = 640, 480
BINS = 32
BORDER = 16
BAND_ROWS = 60
# The models searched: s 0.9–1.1, k and k₂ within ±0.1, roll within ±3°, shifts within ±20 px.
CENTRE = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
SPAN = np.array([0.1, 0.1, 0.1, 3.0, 20.0, 20.0])


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
    """The thermal position of RGB pixels (xs, ys) under model p = (s, k, k2, alpha, u, v):
    registration_gap.py's form of rtf's model, without band shifts."""
    return registration_gap.rtf_position(p, [0.0] * 8, xs, ys)


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


def peak(offsets, scores):
    """The sub-pixel argmax of scores over offsets, or None where the peak is flat (less than
    0.001 above the scores 4 px or more away) or at the edge of the search."""
    i = int(np.argmax(scores))
    near = scores[np.abs(offsets - offsets[i]) >= 4]
    if i in (0, len(offsets) - 1) or scores[i] - (near.max() if near.size else 0) < 0.001:
        return None
    s0, s1, s2 = scores[i - 1], scores[i], scores[i + 1]
    den = s0 - 2 * s1 + s2
    frac = 0.5 * (s0 - s2) / den if den < 0 else 0.0
    return float(offsets[i] + (offsets[1] - offsets[0]) * np.clip(frac, -0.5, 0.5))


def grid(stride):
    """Sample positions over the image less the border."""
    return np.mgrid[BORDER:H - BORDER:stride, BORDER:W - BORDER:stride].astype(np.float64)


def referee(pairs, stride):
    """Mean NMI of each existing registration, and in how many scenes rtf's beats the 2 %."""
    gap = registration_gap
    reg, par = gap.tables(os.path.join(os.path.dirname(__file__), "../../crates/rtf-calib/src/real_rig.rs"))
    ys, xs = grid(stride)
    gen, rtf, med = [], [], []
    median = [1.030, -0.031, 0.0, 0.0, -0.1, 2.3]  # real_rig.rs: the medians over the 48
    for scene, (luma, ir) in pairs.items():
        a = luma[ys.astype(int), xs.astype(int)]
        gen.append(nmi(a, bilinear(ir, *gap.generator_position(xs, ys))))
        rtf.append(nmi(a, bilinear(ir, *gap.rtf_position(reg[scene], par[scene], xs, ys))))
        med.append(nmi(a, bilinear(ir, *position(median, xs, ys))))
    gen, rtf, med = map(np.array, (gen, rtf, med))
    return {"mean_nmi": {"generator_2pc": float(gen.mean()), "rtf_per_scene": float(rtf.mean()),
                         "rtf_median_model": float(med.mean())},
            "scenes_rtf_per_scene_beats_generator": int((rtf > gen).sum()),
            "scenes_rtf_median_beats_generator": int((med > gen).sum()),
            "scenes": len(gen)}


def fit_pooled(pairs, stride):
    ys, xs = grid(stride)
    samples = [(luma[ys.astype(int), xs.astype(int)], ir) for luma, ir in pairs.values()]

    def cost(p):
        if np.any(np.abs(np.asarray(p) - CENTRE) > SPAN):
            return 0.0
        u, v = position(p, xs, ys)
        return -float(np.mean([nmi(a, bilinear(ir, u, v)) for a, ir in samples]))

    starts = [[1.0, 0.0, 0.0, 0.0, 0.0, 0.0], [1.02, -0.0128, 0.0, 0.0, 0.0, 0.0],
              [1.030, -0.031, 0.0, 0.0, -0.1, 2.3]]
    steps = [0.01, 0.01, 0.005, 0.3, 2.0, 2.0]
    best = None
    for x0 in starts:
        p, c = nelder_mead(cost, x0, steps)
        p, c = nelder_mead(cost, p, [s / 10 for s in steps])  # restart: a collapsed simplex
        print("start", x0, "->", " ".join(f"{x:.4f}" for x in p), f"nmi {-c:.5f}",
              file=sys.stderr, flush=True)
        if best is None or c < best[1]:
            best = (p, c)
    return [float(x) for x in best[0]], -best[1]


def pooled_bands(pairs, model, stride):
    """Each band's shift maximising the mean NMI over the scenes, with its split-half check."""
    offsets = np.arange(-8, 8.001, 0.25)
    out = []
    for band in range(H // BAND_ROWS):
        lo, hi = max(band * BAND_ROWS, 8), min((band + 1) * BAND_ROWS, H - 8)
        ys, xs = np.mgrid[lo:hi:2, BORDER:W - BORDER:2].astype(np.float64)
        left = xs < W / 2
        scores = np.zeros((3, len(offsets)))
        for luma, ir in pairs.values():
            a = luma[ys.astype(int), xs.astype(int)]
            for j, d in enumerate(offsets):
                b = bilinear(ir, *position(model, xs, ys + d))
                scores[:, j] += [nmi(a, b), nmi(a[left], b[left]), nmi(a[~left], b[~left])]
        whole, l, r = (peak(offsets, sc / len(pairs)) for sc in scores)
        split = None if l is None or r is None else abs(l - r)
        ok = whole is not None and split is not None and split <= 1.0
        out.append({"shift": whole if ok else None, "split_half_px": split})
        print("band", band, out[-1], file=sys.stderr, flush=True)
    return out


def fill_bands(bands):
    """Unmeasured bands interpolated linearly between the measured ones (the nearest beyond
    them; 0 when none is measured)."""
    known = [(i, b["shift"]) for i, b in enumerate(bands) if b["shift"] is not None]
    if not known:
        return [0.0] * len(bands)
    xs, ys = zip(*known)
    return [float(x) for x in np.interp(np.arange(len(bands)), xs, ys)]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--data", default=os.path.join(os.path.dirname(__file__),
                                                   "../../../shared/data"))
    ap.add_argument("--stride", type=int, default=4, help="pixel stride of the model's samples")
    a = ap.parse_args()
    names = open(os.path.join(a.data, "msrs-samples/frames.txt")).read().split()
    pairs = {n.rsplit(".", 1)[0]: load(a.data, n if n.endswith(".png") else n + ".png")
             for n in names}
    result = {"objective": f"NMI, {BINS} bins, border {BORDER}, stride {a.stride}, pooled "
                           f"over {len(pairs)} scenes"}
    result["referee"] = referee(pairs, a.stride)
    print(json.dumps(result["referee"]), file=sys.stderr, flush=True)
    model, score = fit_pooled(pairs, a.stride)
    bands = pooled_bands(pairs, model, a.stride)
    filled = fill_bands(bands)
    result["pooled"] = {"model": model, "mean_nmi": score, "bands": bands}
    result["scenes"] = {n: {"model": model, "bands_filled": filled} for n in pairs}
    tmp = a.out + ".tmp"
    with open(tmp, "w") as f:
        json.dump(result, f, indent=1)
    os.replace(tmp, a.out)


if __name__ == "__main__":
    main()
