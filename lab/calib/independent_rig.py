#!/usr/bin/env python3
"""Real-imagery calibration rigs built independently of rtf-calib (issue 28 §3).

Shares no code with the solver or with rtf's rig writers (`synth_rig.rs`, `real_rig.rs`):
numpy and Pillow only, its own registration of the MSRS pairs, depth, camera and renderer.

- Registration: MSRS's thermal image is taken to be magnified 2 % at the centre relative to
  the RGB one, falling to 0 % at the corners (m(ρ) = 1.02 − 0.02 ρ², ρ = radius / corner
  radius); the thermal image is resampled onto the RGB grid with that model. (rtf's own
  writer measures a per-scene model with its edge features plus per-band parallax.) With
  `--registration`, a model measured by nmi_registration.py (intensities, not rtf's edge
  features), applied in the form it was fitted in (registration_gap.py's).
- Depth: a ground plane (camera 1.3–1.9 m above it, pitched ±2°) meeting a slanted back wall
  at 8–40 m; every pixel has depth. (rtf's writer: a street corridor.)
- Camera: RGB f = 525 px; thermal 480×384, f = ratio × 525 · (480/640), a *division-model*
  lens (r_u = r_d / (1 + λ r_d²)), which rtf's k1, k2, p1, p2 model approximates (to
  0.0002 px mean on seed 101, 0.0007 px on 202: `--fit-lens` measures it), or with `--lens radial` a radial lens r_d = r_u(1 + k1 r_u²
  + k2 r_u⁴) that rtf's model contains exactly (k1 drawn over the division λ's range, k2
  ±0.02, from a separate random stream: the same seed gives the same scenes, depth, pose and
  focal length with either lens); rotation up to 2.5°, thermal centre up to 15 cm from the RGB
  one.
- Rendering: every RGB pixel, supersampled 2×2, is moved into the thermal image with its
  depth and splatted bilinearly (weighted mean), then vignetting and noise.

Usage: independent_rig.py OUT --seed S [--frames 20] [--data ../shared/data]
           [--lens division|radial]       # the thermal lens (default division)
           [--source ir|rgb]              # rgb: the control, the RGB image rendered as the
                                          # thermal one (no pair registration in the truth)
           [--prior-offset-m 0.02]        # also write rig_prior.yaml, a prior that far off
           [--registration nmi.json]      # register each pair with its own model measured
                                          # by nmi_registration.py (normalised mutual
                                          # information) instead of the global 2 % one
       independent_rig.py --evaluate OUT CALIB.yaml   # the map error of a calib.yaml
       independent_rig.py --fit-lens OUT --seed S [--frames 20] [--lens ...]
           # the best k1, k2, p1, p2 (and fx, fy, cx, cy) for the truth's lens, with the pose
           # at the truth, over the evaluator's pixels: how far rtf's lens model can follow
           # it (nothing is rendered; OUT is not written)

Writes OUT/rig.yaml, OUT/f/NNN_{rgb,thermal,depth}.png and OUT/truth.json (the division-model
truth; the true map is computed from it, not from a calib.yaml).
"""
import argparse
import json
import math
import os
import sys

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import registration_gap  # noqa: E402  (the form of a measured registration; a tool, not rtf)

RGB_W, RGB_H, RGB_F = 640, 480, 525.0
TH_W, TH_H = 480, 384
PITCH_MM = 0.017


def rodrigues(w):
    t = np.linalg.norm(w)
    if t < 1e-12:
        return np.eye(3)
    k = w / t
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(t) * K + (1 - math.cos(t)) * K @ K


def bilinear(img, x, y):
    """Samples img (H, W) at float coordinates (pixel centres at integers), clamped."""
    h, w = img.shape
    x = np.clip(x, 0, w - 1.001)
    y = np.clip(y, 0, h - 1.001)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    return (img[y0, x0] * (1 - fx) * (1 - fy) + img[y0, x0 + 1] * fx * (1 - fy)
            + img[y0 + 1, x0] * (1 - fx) * fy + img[y0 + 1, x0 + 1] * fx * fy)


def register_ir(ir):
    """The thermal image on the RGB grid: content at RGB pixel x sits in MSRS's thermal image
    at c + m(ρ)(x − c), m = 1.02 − 0.02 ρ²."""
    c = np.array([(RGB_W - 1) / 2, (RGB_H - 1) / 2])
    ys, xs = np.mgrid[0:RGB_H, 0:RGB_W].astype(np.float64)
    rho2 = ((xs - c[0]) ** 2 + (ys - c[1]) ** 2) / (c[0] ** 2 + c[1] ** 2)
    m = 1.02 - 0.02 * rho2
    return bilinear(ir, c[0] + m * (xs - c[0]), c[1] + m * (ys - c[1]))


def register_ir_measured(ir, entry):
    """The thermal image on the RGB grid under a per-scene measured registration (an entry of
    nmi_registration.py's output), applied with the very function the registration was fitted
    with (registration_gap.py's form of the model: per-band vertical shifts, then scale, two
    radial terms, roll and shift)."""
    ys, xs = np.mgrid[0:RGB_H, 0:RGB_W].astype(np.float64)
    return bilinear(ir, *registration_gap.rtf_position(entry["model"], entry["bands_filled"],
                                                       xs, ys))


def depth_model(rng, xs, ys):
    """Ground plane and a slanted back wall; depth z (m) at RGB pixel coordinates."""
    height = rng.uniform(1.3, 1.9)
    pitch = math.radians(rng.uniform(-2, 2))
    wall = rng.uniform(8, 40)
    slant = rng.uniform(-0.4, 0.4)
    cx, cy = (RGB_W - 1) / 2, (RGB_H - 1) / 2
    dx, dy = (xs - cx) / RGB_F, (ys - cy) / RGB_F
    # Ray (dx, dy, 1); ground: y·cos p + z·sin p... plane n·X = height with n = (0, cos, -sin).
    denom = dy * math.cos(pitch) - math.sin(pitch)
    with np.errstate(divide="ignore", invalid="ignore"):
        ground = np.where(denom > 1e-4, height / denom, np.inf)
    back = wall / np.maximum(1 + slant * dx, 0.2)
    return np.minimum(np.minimum(ground, back), 80.0)


def draw_truth(rng, seed=0, lens="division"):
    ratio = rng.uniform(0.8, 1.3)
    f = ratio * RGB_F * TH_W / RGB_W
    truth = {
        "f": f,
        "nominal_f": f * rng.uniform(0.96, 1.04),
        "cx": (TH_W - 1) / 2 + rng.uniform(-0.03, 0.03) * TH_W,
        "cy": (TH_H - 1) / 2 + rng.uniform(-0.03, 0.03) * TH_W,
        "division_lambda": rng.uniform(-0.12, 0.02),
        "rotation_vector": list(rng.normal(size=3) * math.radians(2.5) / math.sqrt(3)),
        "centre_m": list(rng.uniform(-1, 1, size=3) * np.array([0.15, 0.08, 0.05])),
    }
    truth["lens"] = lens
    if lens == "radial":
        # A separate stream, so the scenes and the pose match the division rig of this seed.
        lr = np.random.default_rng(seed + 5000)
        truth["radial_k"] = [lr.uniform(-0.12, 0.02), lr.uniform(-0.02, 0.02)]
        del truth["division_lambda"]  # drawn all the same, to keep the stream aligned
    return truth


def distort_radius(truth, ru):
    """Undistorted normalised radius → distorted one, for the truth's lens."""
    if truth.get("lens", "division") == "radial":
        k1, k2 = truth["radial_k"]
        return ru * (1 + k1 * ru ** 2 + k2 * ru ** 4)
    lam = truth["division_lambda"]
    # r_u = r_d / (1 + λ r_d²)  ⇒  λ r_u r_d² − r_d + r_u = 0.
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(np.abs(lam * ru) > 1e-9,
                        (1 - np.sqrt(np.maximum(1 - 4 * lam * ru * ru, 0))) / (2 * lam * ru), ru)


def project_thermal(truth, X):
    """RGB-frame points X (N, 3) → thermal pixels (u, v) through the truth's lens."""
    R = rodrigues(np.array(truth["rotation_vector"]))
    C = np.array(truth["centre_m"])
    P = (X - C) @ R.T  # X_T = R (X − C)
    z = P[:, 2]
    xu, yu = P[:, 0] / z, P[:, 1] / z
    ru = np.hypot(xu, yu)
    rd = distort_radius(truth, ru)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(ru > 1e-12, rd / ru, 1.0)
    return truth["f"] * xu * s + truth["cx"], truth["f"] * yu * s + truth["cy"], z


def back_project(xs, ys, z):
    cx, cy = (RGB_W - 1) / 2, (RGB_H - 1) / 2
    return np.stack([(xs - cx) / RGB_F * z, (ys - cy) / RGB_F * z, z], axis=-1).reshape(-1, 3)


def render(truth, registered, rng_depth):
    """Thermal image (TH_H, TH_W) and the RGB depth (m) of one frame."""
    ys, xs = np.mgrid[0:RGB_H, 0:RGB_W].astype(np.float64)
    state = rng_depth.bit_generator.state
    depth = depth_model(rng_depth, xs, ys)
    acc = np.zeros(TH_H * TH_W)
    wsum = np.zeros(TH_H * TH_W)
    for oy in (-0.25, 0.25):
        for ox in (-0.25, 0.25):
            rng_depth.bit_generator.state = state
            sx, sy = xs + ox, ys + oy
            z = depth_model(rng_depth, sx, sy)
            u, v, zt = project_thermal(truth, back_project(sx, sy, z))
            val = bilinear(registered, sx, sy).ravel()
            ok = (zt > 0.1) & (u > -1) & (v > -1) & (u < TH_W) & (v < TH_H)
            u, v, val = u[ok], v[ok], val[ok]
            x0, y0 = np.floor(u).astype(int), np.floor(v).astype(int)
            fx, fy = u - x0, v - y0
            for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                              (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
                xi, yi = x0 + dx, y0 + dy
                inside = (xi >= 0) & (yi >= 0) & (xi < TH_W) & (yi < TH_H)
                idx = yi[inside] * TH_W + xi[inside]
                np.add.at(acc, idx, w[inside] * val[inside])
                np.add.at(wsum, idx, w[inside])
    img = np.where(wsum > 1e-6, acc / np.maximum(wsum, 1e-6), 0.0).reshape(TH_H, TH_W)
    yy, xx = np.mgrid[0:TH_H, 0:TH_W]
    r2 = ((xx - TH_W / 2) ** 2 + (yy - TH_H / 2) ** 2) / (TH_W / 2) ** 2
    img = img * (1 - 0.12 * r2) + rng_depth.normal(0, 1.5, img.shape)
    return img, depth


def write_rig(out, seed, frames, data, lens, source="ir", registration=None):
    rng = np.random.default_rng(seed)
    truth = draw_truth(rng, seed, lens)
    msrs = os.path.join(data, "msrs-samples")
    names = sorted(os.listdir(os.path.join(msrs, "vi")))
    chosen = [names[i] for i in rng.choice(len(names), size=frames, replace=False)]
    os.makedirs(os.path.join(out, "f"), exist_ok=True)
    entries = []
    for i, name in enumerate(chosen):
        vi = Image.open(os.path.join(msrs, "vi", name)).convert("RGB")
        if source == "rgb":  # the control: the RGB image itself, which needs no registration
            src = np.asarray(vi.convert("L"), np.float64)
        else:
            ir = np.asarray(Image.open(os.path.join(msrs, "ir", name)).convert("L"), np.float64)
            scene = name.rsplit(".", 1)[0]
            src = (register_ir(ir) if registration is None
                   else register_ir_measured(ir, registration["scenes"][scene]))
        img, depth = render(truth, src, np.random.default_rng(seed * 1000 + i))
        vi.save(os.path.join(out, "f", f"{i:03}_rgb.png"))
        Image.fromarray(np.clip(img * 256, 0, 65535).astype(np.uint16)).save(
            os.path.join(out, "f", f"{i:03}_thermal.png"))
        Image.fromarray(np.clip(depth * 1000, 0, 65535).astype(np.uint16)).save(
            os.path.join(out, "f", f"{i:03}_depth.png"))
        entries.append(f"  - {{ rgb: f/{i:03}_rgb.png, thermal: f/{i:03}_thermal.png, "
                       f"depth: f/{i:03}_depth.png }}")
    cx, cy = (RGB_W - 1) / 2, (RGB_H - 1) / 2
    head = (f"rgb: {{ width: {RGB_W}, height: {RGB_H}, fx: {RGB_F}, fy: {RGB_F}, cx: {cx}, "
            f"cy: {cy} }}\nthermal: {{ width: {TH_W}, height: {TH_H}, "
            f"focal_length_mm: {truth['nominal_f'] * PITCH_MM:.6f}, pixel_pitch_mm: {PITCH_MM} }}\n"
            "frames:\n" + "\n".join(entries) + "\n")
    with open(os.path.join(out, "rig.yaml"), "w") as fh:
        fh.write(head)
    truth["scenes"] = chosen
    truth["registration"] = registration["objective"] if registration else "1.02 - 0.02 rho^2"
    with open(os.path.join(out, "truth.json"), "w") as fh:
        json.dump(truth, fh, indent=1)
    return truth, head


def write_prior_rig(out, truth, head, offset, seed):
    """rig_prior.yaml: a translation prior `offset` m off the truth (σ 2 cm), rotation prior
    at the truth rounded to 1° (σ 2°), as a user who measured the mount would write."""
    rng = np.random.default_rng(seed + 7)
    d = rng.normal(size=3)
    c = np.array(truth["centre_m"]) + offset * d / np.linalg.norm(d)
    r = [round(math.degrees(x)) for x in truth["rotation_vector"]]
    prior = ("prior:\n"
             f"  translation_m: [{c[0]:.4f}, {c[1]:.4f}, {c[2]:.4f}]\n"
             "  translation_sigma_m: 0.02\n"
             f"  rotation_deg: [{r[0]}, {r[1]}, {r[2]}]\n"
             "  rotation_sigma_deg: 2.0\n")
    with open(os.path.join(out, "rig_prior.yaml"), "w") as fh:
        fh.write(head + prior)


def read_calib(path):
    """rtf's calib.yaml (block style), read by hand: only the fields needed."""
    import re
    lines = open(path).read().splitlines()

    def block(key, count):
        i = next(i for i, l in enumerate(lines) if l.strip() == key + ":")
        vals = []
        for l in lines[i + 1:]:
            m = re.fullmatch(r"\s*(?:-\s+)*([-0-9.eE+]+)", l)
            if not m:
                break
            vals.append(float(m.group(1)))
        return vals[:count]

    def num(key):
        for l in lines:
            m = re.fullmatch(r"\s*" + key + r":\s*([-0-9.eE+]+)", l)
            if m:
                return float(m.group(1))
        return None
    verdict = next((l.split(":")[1].strip() for l in lines if l.strip().startswith("verdict:")), "?")
    return {
        "fx": num("fx"), "fy": num("fy"), "cx": num("cx"), "cy": num("cy"),
        "distortion": block("distortion", 4), "R": np.array(block("rotation", 9)).reshape(3, 3),
        "t": np.array(block("translation", 3)), "bound": num("map_error_bound_px"),
        "verdict": verdict,
    }


def evaluate(out, calib_path):
    """Mean distance between the true map and calib.yaml's (rtf's published conventions,
    spec §6), over RGB pixels with depth whose true image lies inside the thermal image."""
    truth = json.load(open(os.path.join(out, "truth.json")))
    c = read_calib(calib_path)
    total, count = 0.0, 0
    for i in range(len(truth["scenes"])):
        depth = np.asarray(Image.open(os.path.join(out, "f", f"{i:03}_depth.png")), np.float64) / 1000
        ys, xs = np.mgrid[0:RGB_H, 0:RGB_W].astype(np.float64)
        X = back_project(xs[::2, ::2], ys[::2, ::2], depth[::2, ::2])
        ut, vt, _ = project_thermal(truth, X)
        P = X @ c["R"].T + c["t"]
        x, y = P[:, 0] / P[:, 2], P[:, 1] / P[:, 2]
        k1, k2, p1, p2 = c["distortion"]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 * r2
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        ue, ve = c["fx"] * xd + c["cx"], c["fy"] * yd + c["cy"]
        ok = (X[:, 2] > 0) & (ut >= 0) & (vt >= 0) & (ut <= TH_W - 1) & (vt <= TH_H - 1)
        total += np.hypot(ue - ut, ve - vt)[ok].sum()
        count += ok.sum()
    err = total / max(count, 1)
    print(json.dumps({"map_error_px": float(err), "bound_px": c["bound"], "verdict": c["verdict"],
                      "covered": bool(c["bound"] is not None and err <= c["bound"])}))


def radtan(q, x, y):
    """rtf's lens (spec §6) at normalised undistorted (x, y): q = fx, fy, cx, cy, k1, k2, p1, p2."""
    fx, fy, cx, cy, k1, k2, p1, p2 = q
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return fx * xd + cx, fy * yd + cy


def fit_lens(seed, frames, lens, square):
    """The best rtf lens for the truth's (least squares over the evaluator's pixels, pose at
    the truth, Gauss-Newton with a numerical Jacobian): mean and largest residual in px."""
    rng = np.random.default_rng(seed)
    truth = draw_truth(rng, seed, lens)
    ys, xs = np.mgrid[0:RGB_H:2, 0:RGB_W:2].astype(np.float64)
    pts = []
    for i in range(frames):  # the depth render() draws for frame i (same stream)
        z = depth_model(np.random.default_rng(seed * 1000 + i), xs, ys)
        pts.append(back_project(xs, ys, np.round(z * 1000) / 1000))  # as the 16-bit PNG
    X = np.concatenate(pts)
    ut, vt, _ = project_thermal(truth, X)
    ok = (X[:, 2] > 0) & (ut >= 0) & (vt >= 0) & (ut <= TH_W - 1) & (vt <= TH_H - 1)
    X, ut, vt = X[ok], ut[ok], vt[ok]
    P = (X - np.array(truth["centre_m"])) @ rodrigues(np.array(truth["rotation_vector"])).T
    x, y = P[:, 0] / P[:, 2], P[:, 1] / P[:, 2]
    q = np.array([truth["f"], truth["f"], truth["cx"], truth["cy"], 0, 0, 0, 0], float)
    free = [i for i in range(8) if not (square and i == 1)]

    def resid(q):
        qq = q.copy()
        if square:
            qq[1] = qq[0]
        u, v = radtan(qq, x, y)
        return np.concatenate([u - ut, v - vt])
    for _ in range(20):
        r = resid(q)
        J = np.stack([(resid(q + 1e-6 * np.eye(8)[i]) - r) / 1e-6 for i in free], 1)
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        q[free] += step
        if np.abs(step).max() < 1e-10:
            break
    if square:
        q[1] = q[0]
    r = resid(q).reshape(2, -1)
    d = np.hypot(r[0], r[1])
    u0, v0 = radtan(np.array([truth["f"], truth["f"], truth["cx"], truth["cy"], 0, 0, 0, 0]), x, y)
    return {"seed": seed, "lens": lens, "square_pixels": square,
            "best_fit": dict(zip(["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"], q.tolist())),
            "mean_residual_px": float(d.mean()), "p95_residual_px": float(np.percentile(d, 95)),
            "max_residual_px": float(d.max()),
            "no_distortion_mean_px": float(np.hypot(u0 - ut, v0 - vt).mean()),
            "points": int(d.size)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("calib", nargs="?")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--data", default=os.path.join(os.path.dirname(__file__), "../../../shared/data"))
    ap.add_argument("--prior-offset-m", type=float, default=0.02)
    ap.add_argument("--lens", choices=["division", "radial"], default="division")
    ap.add_argument("--source", choices=["ir", "rgb"], default="ir")
    ap.add_argument("--registration", help="nmi_registration.py's output: register each pair "
                    "with its measured model instead of the 2 %% one")
    ap.add_argument("--evaluate", action="store_true")
    ap.add_argument("--fit-lens", action="store_true")
    a = ap.parse_args()
    if a.evaluate:
        evaluate(a.out, a.calib)
        return
    if a.fit_lens:
        for square in (True, False):
            print(json.dumps(fit_lens(a.seed, a.frames, a.lens, square)))
        return
    registration = json.load(open(a.registration)) if a.registration else None
    truth, head = write_rig(a.out, a.seed, a.frames, a.data, a.lens, a.source, registration)
    write_prior_rig(a.out, truth, head, a.prior_offset_m, a.seed)
    print(json.dumps({k: v for k, v in truth.items() if k != "scenes"}))


if __name__ == "__main__":
    sys.exit(main())
