#!/usr/bin/env python3
"""Soak test of the release `rtf` binary (issue 30): a long `rtf train` on small synthetic
frames, then `rtf predict` over many frames and `rtf eval` over a large split, sampling the
process's resident memory, open file descriptors, threads and (training) the run folder's
size. Writes soak.csv and soak.svg (no plotting library needed) into --out and prints the
growth from step --warm-up to the end.

  .venv/bin/python scripts/soak.py --out /tmp/soak --steps 2000 --every 100

Standard library only; Linux (/proc).
"""
import argparse
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path


def sample(pid):
    """(rss MiB, fds, threads) of a live process, or None once it is gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        fds = len(os.listdir(f"/proc/{pid}/fd"))
    except (FileNotFoundError, ProcessLookupError):
        return None
    field = {l.split(":")[0]: l.split()[1] for l in status.splitlines() if ":" in l and len(l.split()) > 1}
    if "VmRSS" not in field:  # exiting (a zombie has no memory left)
        return None
    return int(field["VmRSS"]) / 1024, fds, int(field["Threads"])


def folder_mib(path):
    total = 0
    for root, _, files in os.walk(path):
        for f in files:
            try:
                total += os.path.getsize(os.path.join(root, f))
            except FileNotFoundError:
                pass
    return total / 2**20


def watch(cmd, phase, progress, rows, every_s=0.5):
    """Runs cmd, appending a row per sample: phase, progress() (steps or frames), rss, fds,
    threads, folder size."""
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    while proc.poll() is None:
        s = sample(proc.pid)
        if s is not None:
            done, size = progress()
            rows.append((phase, done, *s, size))
        time.sleep(every_s)
    if proc.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{proc.stderr.read()}")


def svg(rows, path):
    """One panel per measure, training steps on x, a line per phase."""
    measures = ["rss_mib", "fds", "threads", "run_mib"]
    w, h, pad = 360, 200, 40
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w * 4}" height="{h + 20}" font-size="11">']
    for i, m in enumerate(measures):
        pts = [(r["done"], r[m]) for r in rows if r["phase"] == "train"]
        if not pts:
            continue
        x0, x1 = min(p[0] for p in pts), max(p[0] for p in pts) or 1
        y0, y1 = 0, max(p[1] for p in pts) * 1.1 or 1
        sx = lambda x: i * w + pad + (x - x0) / max(x1 - x0, 1) * (w - 2 * pad)
        sy = lambda y: h - pad + 20 - (y - y0) / (y1 - y0) * (h - 2 * pad)
        line = " ".join(f"{sx(x):.1f},{sy(y):.1f}" for x, y in pts)
        out.append(f'<text x="{i * w + pad}" y="14">{m} (train, x: step)</text>')
        out.append(f'<polyline fill="none" stroke="#c33" points="{line}"/>')
        out.append(f'<line x1="{sx(x0)}" y1="{sy(y0)}" x2="{sx(x1)}" y2="{sy(y0)}" stroke="#000"/>')
        out.append(f'<line x1="{sx(x0)}" y1="{sy(y0)}" x2="{sx(x0)}" y2="{sy(y1)}" stroke="#000"/>')
        out.append(f'<text x="{sx(x0) - 35}" y="{sy(y1) + 4}">{y1:.0f}</text>')
        out.append(f'<text x="{sx(x0) - 10}" y="{sy(y0) + 14}">{x0:.0f}</text>')
        out.append(f'<text x="{sx(x1) - 20}" y="{sy(y0) + 14}">{x1:.0f}</text>')
    out.append("</svg>")
    Path(path).write_text("\n".join(out))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rtf", default="target/release/rtf")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--every", type=int, default=500, help="report every N steps")
    ap.add_argument("--warm-up", type=int, default=1000, help="growth is measured from this step")
    ap.add_argument("--frames", type=int, default=2000, help="frames for predict and eval")
    ap.add_argument("--size", default="64x48")
    args = ap.parse_args()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    data, run = out / "data", out / "run"
    rtf = args.rtf
    if not data.exists():
        subprocess.run([rtf, "synth", "--out", str(data), "--count", "64", "--size", args.size], check=True)
    # 32 training frames at batch 4: 8 steps an epoch, validation on 16 frames every epoch.
    steps_per_epoch = 8
    epochs = max(1, args.steps // steps_per_epoch)
    rows = []

    def steps_done():
        log = run / "log.jsonl"
        n = log.read_text().count("\n") if log.exists() else 0
        return n * steps_per_epoch, folder_mib(run)

    watch([rtf, "train", "--model", "mfnet", "--data", str(data), "--out", str(run),
           "--batch-size", "4", "--epochs", str(epochs)], "train", steps_done, rows)
    # Predict and eval over many frames: a split of `--frames` names cycling over the set.
    names = (data / "train.txt").read_text().split() + (data / "val.txt").read_text().split()
    big = [names[i % len(names)] for i in range(args.frames)]
    (data / "soak.txt").write_text("\n".join(big) + "\n")
    weights = run / "final.safetensors"
    watch([rtf, "eval", "--weights", str(weights), "--data", str(data), "--split", "soak"],
          "eval", lambda: (0, 0.0), rows)
    preds = out / "pred"
    # `rtf predict` takes files with distinct names: links to the set's images up to --frames.
    images = sorted((data / "images").glob("*.png"))
    links = out / "predict_in"
    links.mkdir(exist_ok=True)
    files = []
    for i in range(args.frames):
        link = links / f"{i:05d}_{images[i % len(images)].name}"
        if not link.exists():
            link.symlink_to(images[i % len(images)].resolve())
        files.append(str(link))
    watch([rtf, "predict", "--weights", str(weights), "--out", str(preds), *files], "predict",
          lambda: (len(list(preds.glob("*"))) if preds.exists() else 0, 0.0), rows)
    keys = ["phase", "done", "rss_mib", "fds", "threads", "run_mib"]
    dicts = [dict(zip(keys, r)) for r in rows]
    # Training: the last sample of every --every steps (the samples are taken twice a second).
    last_of = {}
    for d in dicts:
        if d["phase"] == "train":
            last_of[d["done"] // args.every] = d
    dicts = sorted(last_of.values(), key=lambda d: d["done"]) + [d for d in dicts if d["phase"] != "train"]
    with open(out / "soak.csv", "w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=keys)
        wr.writeheader()
        wr.writerows(dicts)
    svg(dicts, out / "soak.svg")
    for phase in ("train", "eval", "predict"):
        rs = [d for d in dicts if d["phase"] == phase]
        if not rs:
            continue
        later = [d for d in rs if d["done"] >= args.warm_up] if phase == "train" else rs[len(rs) // 4:]
        later = later or rs
        first, last = later[0], later[-1]
        print(json.dumps({"phase": phase, "samples": len(rs), "rss_from": round(first["rss_mib"], 1),
                          "rss_to": round(last["rss_mib"], 1), "rss_peak": round(max(d["rss_mib"] for d in rs), 1),
                          "fds": [first["fds"], last["fds"]], "threads": [first["threads"], last["threads"]],
                          "growth_pct": round(100 * (last["rss_mib"] / first["rss_mib"] - 1), 2)}))


if __name__ == "__main__":
    main()
