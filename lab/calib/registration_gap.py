#!/usr/bin/env python3
"""How far independent_rig.py's registration of the MSRS pairs is from rtf's per-scene one
(issue 28 §2): a rig's "truth" is only as good as the registration of the real pairs it was
rendered from. independent_rig.py takes MSRS's thermal image to be magnified 1.02 − 0.02 ρ²
about the centre; rtf's `real_rig.rs` measured, per scene, a 2-D model (`MSRS_REGISTRATION`:
scale, radial terms, rotation, shift) and a per-band vertical parallax (`MSRS_PARALLAX`). Where
the two disagree, the thermal content of the independent rig sits that far from where its
truth says, in every frame: a calibration that follows the content is off the truth by the
part of that field the camera model can absorb.

Reads both tables from real_rig.rs (text, not rtf's code) and, for the scenes of a rig
(truth.json), prints the mean |difference| per scene and the field common to the rig's
scenes (mean over scenes, then mean |·| over the image), in MSRS pixels and in thermal pixels
(× thermal f / RGB f), and the part of the common field that the camera model can absorb
(least squares on the fields its parameters make at far depth). Measured with rtf's own edge features, so this is an estimate of the
registration gap, not an independent truth.

A third registration, by normalised mutual information of the intensities (no edges;
`nmi_registration.py`), is the referee: `--nmi FILE --compare nmi,generator` (or `nmi,rtf`)
measures either against it.

Usage: registration_gap.py RIG_DIR|all [--real-rig crates/rtf-calib/src/real_rig.rs]
           [--nmi nmi.json] [--compare rtf,generator]
"""
import argparse
import json
import os
import re

import numpy as np

W, H = 640, 480


def tables(path):
    text = open(path).read()
    reg = {m[0]: [float(x) for x in m[1:]] for m in re.findall(
        r'\("(\w+)",\s*([-0-9.]+),\s*([-0-9.]+),\s*([-0-9.]+),\s*([-0-9.]+),\s*([-0-9.]+),'
        r'\s*([-0-9.]+)\)', text)}
    par = {m[0]: [float(x) for x in m[1].split(",")] for m in re.findall(
        r'\("(\w+)",\s*\[([-0-9., ]+)\]\)', text)}
    return reg, par


def rtf_position(reg, bands, xs, ys):
    """Where rtf samples the MSRS ir image for vi pixel (x, y) (real_rig.rs warp_msrs_ir)."""
    s, k, k2, alpha, su, sv = reg
    t = (ys + 0.5) / 60.0 - 0.5
    i = np.clip(np.floor(t), 0, 6).astype(int)
    w = np.clip(t - i, 0, 1)
    b = np.array(bands)
    row = ys + b[i] + (b[i + 1] - b[i]) * w
    cu, cv = (W - 1) / 2, (H - 1) / 2
    x, y = xs - cu, row - cv
    r2 = (x * x + y * y) / (cu * cu)
    g = s * (1 + k * r2 + k2 * r2 * r2)
    sn, cs = np.sin(np.radians(alpha)), np.cos(np.radians(alpha))
    return cu + g * (cs * x - sn * y) + su, cv + g * (sn * x + cs * y) + sv


def generator_position(xs, ys):
    """Where independent_rig.py samples it (register_ir)."""
    c = np.array([(W - 1) / 2, (H - 1) / 2])
    rho2 = ((xs - c[0]) ** 2 + (ys - c[1]) ** 2) / (c[0] ** 2 + c[1] ** 2)
    m = 1.02 - 0.02 * rho2
    return c[0] + m * (xs - c[0]), c[1] + m * (ys - c[1])


def nmi_tables(path):
    """nmi_registration.py's answers as rtf_position's (model, bands), flat bands filled."""
    scenes = json.load(open(path))["scenes"]
    return ({k: e["model"] for k, e in scenes.items()},
            {k: e["bands_filled"] for k, e in scenes.items()})


def positions(source, scene, xs, ys, tables_rtf, tables_nmi):
    """Where registration `source` samples the MSRS ir image of `scene` for vi pixels."""
    if source == "generator":
        return generator_position(xs, ys)
    reg, par = tables_rtf if source == "rtf" else tables_nmi
    if scene not in reg:
        raise SystemExit(f"registration_gap.py: no {source} registration for scene {scene}")
    bands = par.get(scene, [0.0] * 8)
    return rtf_position(reg[scene], bands + [bands[-1]] * (9 - len(bands)), xs, ys)


def absorbable(mu, mv, xs, ys):
    """The part of a common field a calibration can absorb: least squares on the fields the
    parameters make at far depth (shift, scale, roll, k1, k2, p1, p2; square pixels)."""
    x, y = (xs - (W - 1) / 2) / 525.0, (ys - (H - 1) / 2) / 525.0
    r2 = x * x + y * y
    one, zero = np.ones_like(x), np.zeros_like(x)
    basis = [(one, zero), (zero, one), (x, y), (-y, x), (x * r2, y * r2),
             (x * r2 * r2, y * r2 * r2), (2 * x * y, r2 + 2 * y * y), (r2 + 2 * x * x, 2 * x * y)]
    A = np.stack([np.concatenate([bu.ravel(), bv.ravel()]) for bu, bv in basis], 1)
    b = np.concatenate([mu.ravel(), mv.ravel()])
    fit = A @ np.linalg.lstsq(A, b, rcond=None)[0]
    n = mu.size
    return float(np.hypot(fit[:n], fit[n:]).mean())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("rig", help="a rig directory (its truth.json's scenes and f), or 'all' "
                                "for the 48 scenes in MSRS pixels")
    ap.add_argument("--real-rig", default=os.path.join(os.path.dirname(__file__),
                                                       "../../crates/rtf-calib/src/real_rig.rs"))
    ap.add_argument("--nmi", help="nmi_registration.py's output, for --compare with nmi")
    ap.add_argument("--compare", default="rtf,generator",
                    help="two of rtf, generator, nmi: the field second − first")
    a = ap.parse_args()
    first, second = a.compare.split(",")
    tables_rtf = tables(a.real_rig)
    tables_nmi = nmi_tables(a.nmi) if a.nmi else ({}, {})
    if a.rig == "all":
        scenes, to_thermal = sorted(tables_rtf[0]), 1.0
    else:
        truth = json.load(open(os.path.join(a.rig, "truth.json")))
        scenes = [n.rsplit(".", 1)[0] for n in truth["scenes"]]
        to_thermal = truth["f"] / 525.0
    ys, xs = np.mgrid[0:H:4, 0:W:4].astype(np.float64)
    fields, per_scene = [], {}
    for scene in scenes:
        au, av = positions(first, scene, xs, ys, tables_rtf, tables_nmi)
        bu, bv = positions(second, scene, xs, ys, tables_rtf, tables_nmi)
        du, dv = bu - au, bv - av
        fields.append((du, dv))
        per_scene[scene] = float(np.hypot(du, dv).mean())
    mu = np.mean([f[0] for f in fields], 0)
    mv = np.mean([f[1] for f in fields], 0)
    common = float(np.hypot(mu, mv).mean())
    print(json.dumps({
        "compare": f"{second} - {first}",
        "scenes": len(fields),
        "per_scene_mean_px": per_scene,
        "mean_over_scenes_px": float(np.mean(list(per_scene.values()))),
        "common_field_mean_px": common,
        "common_field_mean_thermal_px": common * to_thermal,
        "common_shift_px": [float(mu.mean()), float(mv.mean())],
        "absorbable_part_thermal_px": absorbable(mu, mv, xs, ys) * to_thermal,
        "thermal_px_per_msrs_px": to_thermal,
    }, indent=1))


if __name__ == "__main__":
    main()
