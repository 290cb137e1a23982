#!/usr/bin/env python3
"""Summarises lab/training/heatnet_procedures.sh: day / night mIoU (HeatNet's convention, test
layout) per model, mean ± std over seeds, and whether each claim of the HeatNet paper holds in
the measured numbers. Writes OUT/summary.md and OUT/summary.json; prints the markdown."""
import json
import statistics
import sys
from pathlib import Path

MODELS = [
    ("teacher-rgb", "RGB teacher (supervised, day labels)"),
    ("teacher-ir", "Thermal teacher (RGB teacher's day labels)"),
    ("v2", "V2: RGB only"),
    ("v3", "V3: RGB-T"),
    ("v5", "V5: RGB-T + critic"),
    ("v6", "V6: RGB-T + critic + two-stage"),
    ("distill", "Distilled RGB-only (V6 by night)"),
]


def main(out: Path) -> None:
    seeds = sorted(p for p in out.glob("seed*") if p.is_dir())
    scores = {}
    for key, _ in MODELS:
        for seed in seeds:
            path = seed / key / "test.json"
            if path.is_file():
                h = json.loads(path.read_text())["heatnet"]
                scores.setdefault(key, []).append((seed.name, 100 * h["day_miou"], 100 * h["night_miou"]))
    def stat(key, i):
        values = [s[i] for s in scores.get(key, [])]
        if not values:
            return None
        return (statistics.mean(values), statistics.stdev(values) if len(values) > 1 else 0.0, values)
    lines = [
        "| Model | Day mIoU | Night mIoU | Day − night | seeds (day / night) |",
        "|---|---|---|---|---|",
    ]
    table = {}
    for key, label in MODELS:
        day, night = stat(key, 1), stat(key, 2)
        if day is None:
            lines.append(f"| {label} | not run | | | |")
            continue
        per_seed = ", ".join(f"{d:.1f} / {n:.1f}" for _, d, n in scores[key])
        gap = [d - n for _, d, n in scores[key]]
        lines.append(
            f"| {label} | {day[0]:.1f} ± {day[1]:.1f} | {night[0]:.1f} ± {night[1]:.1f} | "
            f"{statistics.mean(gap):.1f} | {per_seed} |"
        )
        table[key] = {"label": label, "day": day[0], "day_std": day[1], "night": night[0],
                      "night_std": night[1], "gap": statistics.mean(gap), "seeds": scores[key]}
    def mean(key, field):
        return table[key][field] if key in table else None
    claims = [
        ("V5 night > V3 night (the critic helps at night)", mean("v5", "night"), mean("v3", "night"), ">"),
        ("V6 ≥ V5 (two-stage, day/night mean)",
         None if "v6" not in table else (mean("v6", "day") + mean("v6", "night")) / 2,
         None if "v5" not in table else (mean("v5", "day") + mean("v5", "night")) / 2, ">="),
        ("thermal teacher's day−night gap < RGB teacher's", mean("teacher-ir", "gap"), mean("teacher-rgb", "gap"), "<"),
        ("distilled RGB-only night > RGB teacher night", mean("distill", "night"), mean("teacher-rgb", "night"), ">"),
    ]
    lines += ["", "| Claim (HeatNet) | measured | holds? |", "|---|---|---|"]
    verdicts = []
    for text, a, b, op in claims:
        if a is None or b is None:
            lines.append(f"| {text} | not run | – |")
            verdicts.append({"claim": text, "holds": None})
            continue
        holds = {">": a > b, ">=": a >= b, "<": a < b}[op]
        lines.append(f"| {text} | {a:.1f} {op} {b:.1f} | {'yes' if holds else 'no'} |")
        verdicts.append({"claim": text, "left": a, "right": b, "holds": holds})
    md = "\n".join(lines) + "\n"
    (out / "summary.md").write_text(md)
    (out / "summary.json").write_text(json.dumps({"seeds": [s.name for s in seeds], "models": table, "claims": verdicts}, indent=2))
    print(md)


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "results/heatnet-procedures"))
