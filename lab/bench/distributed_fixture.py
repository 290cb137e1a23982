#!/usr/bin/env python3
"""Writes a dataset in the form public RGB-T releases ship (docs/src/bring-your-data.md) from
the real MSRS scenes in ../shared/data/msrs-samples: RGB as JPEG (quality 95), thermal as
16-bit LZW TIFF of raw-count-like values (21800 + 12 x MSRS's 8-bit thermal), labels as PNG
with ids 1-9 in row bands and 0 (ignored) on the first rows, file names per modality with
two fields ({seq}, {n}), a split file of two paths a line, hex colours. For `rtf bench data`
against `lab/bench/bench_data.py` on those formats (JPEG and TIFF decoding at real content).

Usage: .venv/bin/python lab/bench/distributed_fixture.py --out /tmp/dist48 [--msrs DIR]
"""
import argparse
import os

import numpy as np
from PIL import Image

COLOURS = ["#000000", "#400080", "#404000", "#0080C0", "#0000C0", "#808000", "#404080",
           "#C08080", "#C04000"]
NAMES = ["unlabeled", "car", "person", "bike", "curve", "car_stop", "guardrail", "color_cone",
         "bump"]


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--msrs", default=os.path.join(here, "../../../shared/data/msrs-samples"))
    args = ap.parse_args()
    names = sorted(f[:-4] for f in os.listdir(os.path.join(args.msrs, "vi")) if f.endswith(".png"))
    for d in ["color", "thermal16", "annotations", "splits"]:
        os.makedirs(os.path.join(args.out, d), exist_ok=True)
    lines = []
    for n, name in enumerate(names, 1):
        rgb = Image.open(os.path.join(args.msrs, "vi", name + ".png")).convert("RGB")
        rgb.save(os.path.join(args.out, "color", f"msrs_eo-{n}.jpg"), quality=95)
        ir = np.asarray(Image.open(os.path.join(args.msrs, "ir", name + ".png")).convert("L"))
        counts = (21800 + 12 * ir.astype(np.uint32)).astype(np.uint16)
        Image.fromarray(counts).save(
            os.path.join(args.out, "thermal16", f"msrs_thermal-{n}.tiff"), compression="tiff_lzw")
        h, w = ir.shape
        ids = (np.arange(h)[:, None] * 9 // h + 1).repeat(w, axis=1).astype(np.uint8)
        ids[:8] = 0
        Image.fromarray(ids).save(os.path.join(args.out, "annotations", f"msrs_mask-{n}.png"))
        lines.append(f"color/msrs_eo-{n}.jpg,annotations/msrs_mask-{n}.png")
    with open(os.path.join(args.out, "splits", "train.txt"), "w") as f:
        f.write("\n".join(lines) + "\n")
    classes = "\n".join(f"  - {{id: {i + 1}, name: {nm}, color: \"{c}\"}}"
                        for i, (nm, c) in enumerate(zip(NAMES, COLOURS)))
    with open(os.path.join(args.out, "dataset.yaml"), "w") as f:
        f.write(f"""name: msrs-distributed
classes:
{classes}
ignore_id: 0
thermal:
  range: [21800, 24860]
splits:
  train:
    rgb: "color/{{seq}}_eo-{{n}}.jpg"
    thermal: "thermal16/{{seq}}_thermal-{{n}}.tiff"
    labels: "annotations/{{seq}}_mask-{{n}}.png"
    list: splits/train.txt
""")
    print(f"{len(names)} frames in {args.out}")


if __name__ == "__main__":
    main()
