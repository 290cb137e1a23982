#!/usr/bin/env python3
"""Soak test of the release `rtf` binary (issue 30): a long `rtf train` on small synthetic
frames, then `rtf predict` over many frames and `rtf eval` over a large split, sampling the
process's resident memory, open file descriptors, threads and (training) the run folder's
size. Writes soak.csv and soak.svg (no plotting library needed) into --out and prints the
growth from step --warm-up to the end.

  .venv/bin/python lab/reliability/soak.py --out /tmp/soak --steps 2000 --every 100

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


def file_kib(path):
    """Size of a file, or of a folder's files, in KiB (0 when absent)."""
    path = Path(path)
    if path.is_dir():
        return folder_mib(path) * 1024
    try:
        return path.stat().st_size / 1024
    except FileNotFoundError:
        return 0.0


def watch(cmd, phase, progress, rows, every_s=1.0, minutes=None, finished=lambda: False):
    """Runs cmd, appending a row per sample: phase, seconds since start, then progress()
    (steps or frames, then sizes), rss, fds, threads. Once finished() says the command's work
    is written, sampling stops: what follows is the process exiting (threads joined,
    descriptors closed, memory freed), which a sample would misread as a change. After
    `minutes` the process gets SIGTERM (rtf train then checkpoints and stops); returns whether
    that happened."""
    err = open(f"/tmp/soak-{os.getpid()}-{phase}.stderr", "w+")
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, text=True)
    start, stopped = time.monotonic(), False
    while proc.poll() is None:
        s = sample(proc.pid)
        if s is not None and not finished():
            done, *sizes = progress()
            rows.append((phase, round(time.monotonic() - start, 1), done, *s, *sizes))
        if minutes is not None and not stopped and time.monotonic() - start > 60 * minutes:
            proc.terminate()
            stopped = True
        time.sleep(every_s)
    if proc.returncode != 0 and not stopped:
        err.seek(0)
        sys.exit(f"{' '.join(cmd)} failed:\n{err.read()[-4000:]}")
    return stopped


KEYS = ["phase", "seconds", "done", "rss_mib", "fds", "threads", "run_mib", "log_kib",
        "steps_kib", "tb_kib"]


def panel(out, x, y, w, h, title, series):
    """One line chart at (x, y): series is [(colour, [(x, y)])], axes from 0."""
    pad = 40
    pts = [p for _, s in series for p in s]
    if not pts:
        return
    x1 = max(p[0] for p in pts) or 1
    y1 = max(p[1] for p in pts) * 1.1 or 1
    sx = lambda v: x + pad + v / x1 * (w - 1.5 * pad)
    sy = lambda v: y + h - pad + 10 - v / y1 * (h - 2 * pad)
    out.append(f'<text x="{x + pad}" y="{y + 14}">{title}</text>')
    for colour, s in series:
        line = " ".join(f"{sx(a):.1f},{sy(b):.1f}" for a, b in s)
        out.append(f'<polyline fill="none" stroke="{colour}" points="{line}"/>')
    out.append(f'<line x1="{sx(0)}" y1="{sy(0)}" x2="{sx(x1)}" y2="{sy(0)}" stroke="#000"/>')
    out.append(f'<line x1="{sx(0)}" y1="{sy(0)}" x2="{sx(0)}" y2="{sy(y1)}" stroke="#000"/>')
    out.append(f'<text x="{sx(0) - 36}" y="{sy(y1) + 4}">{y1:.0f}</text>')
    out.append(f'<text x="{sx(0) - 12}" y="{sy(0) + 4}">0</text>')
    out.append(f'<text x="{sx(x1) - 24}" y="{sy(0) + 14}">{x1:.0f}</text>')


def svg(rows, path):
    """Top row: training against steps (RSS; fds and threads; log, steps and TensorBoard
    files). Bottom row: eval and predict against seconds (RSS; fds and threads)."""
    w, h = 360, 210
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w * 3}" height="{2 * h}" '
           'font-size="11" font-family="sans-serif"><rect width="100%" height="100%" fill="#fff"/>']
    train = [r for r in rows if r["phase"] == "train"]
    col = lambda rs, k, x="done": [(r[x], r[k]) for r in rs]
    panel(out, 0, 0, w, h, "train: RSS MiB (x: step)", [("#c33", col(train, "rss_mib"))])
    panel(out, w, 0, w, h, "train: fds (blue), threads (red)",
          [("#36c", col(train, "fds")), ("#c33", col(train, "threads"))])
    panel(out, 2 * w, 0, w, h, "train: KiB of log.jsonl (red), steps.jsonl (blue), tb/ (green)",
          [("#c33", col(train, "log_kib")), ("#36c", col(train, "steps_kib")),
           ("#393", col(train, "tb_kib"))])
    other = {p: [r for r in rows if r["phase"] == p] for p in ("eval", "predict")}
    panel(out, 0, h, w, h, "RSS MiB: eval (blue), predict (red) (x: seconds)",
          [("#36c", col(other["eval"], "rss_mib", "seconds")),
           ("#c33", col(other["predict"], "rss_mib", "seconds"))])
    panel(out, w, h, w, h, "eval, predict: fds (blue), threads (red)",
          [(c, col(other[p], k, "seconds")) for p in other for c, k in (("#36c", "fds"), ("#c33", "threads"))])
    panel(out, 2 * w, h, w, h, "predict: frames written (x: seconds)",
          [("#c33", col(other["predict"], "done", "seconds"))])
    out.append("</svg>")
    Path(path).write_text("\n".join(out))


def growth(rows, phase, warm_up):
    """The growth summary of a phase: training from step `warm_up`, others after their first
    quarter (start-up) and never from their first sample (taken as the process starts)."""
    rs = [d for d in rows if d["phase"] == phase]
    if not rs:
        return None
    later = [d for d in rs if d["done"] >= warm_up] if phase == "train" else rs[max(1, len(rs) // 4):]
    later = later or rs
    first, last = later[0], later[-1]
    summary = {"phase": phase, "samples": len(rs), "from": first["done"], "to": last["done"],
               "rss_from": round(first["rss_mib"], 1), "rss_to": round(last["rss_mib"], 1),
               "rss_peak": round(max(d["rss_mib"] for d in rs), 1),
               "rss_max_after_warm_up": round(max(d["rss_mib"] for d in later), 1),
               "fds": [min(d["fds"] for d in later), max(d["fds"] for d in later)],
               "threads": [min(d["threads"] for d in later), max(d["threads"] for d in later)],
               "growth_pct": round(100 * (last["rss_mib"] / first["rss_mib"] - 1), 2)}
    if phase == "train" and last["done"] > first["done"]:
        # Linear files: KiB per 1,000 steps over the first and the second half after warm-up.
        mid = min(later, key=lambda d: abs(d["done"] - (first["done"] + last["done"]) / 2))
        for k in ("log_kib", "steps_kib", "tb_kib"):
            rate = lambda a, b: round(1000 * (b[k] - a[k]) / max(b["done"] - a["done"], 1), 1)
            summary[k + "_per_1000_steps"] = [rate(first, mid), rate(mid, last)]
    return summary


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rtf", default="target/release/rtf")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--train-minutes", type=float, help="stop training (SIGTERM) after this long")
    ap.add_argument("--every", type=int, default=500, help="report every N steps")
    ap.add_argument("--warm-up", type=int, default=1000, help="growth is measured from this step")
    ap.add_argument("--frames", type=int, default=2000, help="frames for predict and eval")
    ap.add_argument("--size", default="64x48")
    ap.add_argument("--count", type=int, default=64, help="synthetic frames (half of them train)")
    ap.add_argument("--batch-size", type=int, default=4)
    args = ap.parse_args()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    data, run = out / "data", out / "run"
    rtf = args.rtf
    if not data.exists():
        subprocess.run([rtf, "synth", "--out", str(data), "--count", str(args.count), "--size", args.size],
                       check=True, stdout=subprocess.DEVNULL)
    # Every epoch trains on the train split and validates on the val split.
    train_frames = len((data / "train.txt").read_text().split())
    steps_per_epoch = -(-train_frames // args.batch_size)
    epochs = max(1, args.steps // steps_per_epoch)
    rows = []

    def lines(path):
        with open(path, "rb") as f:
            return sum(chunk.count(b"\n") for chunk in iter(lambda: f.read(1 << 20), b""))

    def steps_done():
        log = run / "log.jsonl"
        n = lines(log) if log.exists() else 0
        return (n * steps_per_epoch, folder_mib(run), file_kib(log), file_kib(run / "steps.jsonl"),
                file_kib(run / "tb"))

    stopped = watch([rtf, "train", "--model", "mfnet", "--data", str(data), "--out", str(run),
                     "--batch-size", str(args.batch_size), "--epochs", str(epochs)], "train",
                    steps_done, rows, minutes=args.train_minutes,
                    finished=lambda: (run / "final.safetensors").exists())
    if stopped:
        print(f"training stopped after {args.train_minutes} min (SIGTERM)", file=sys.stderr)
    # Predict and eval over many frames: a split of `--frames` names cycling over the set.
    names = (data / "train.txt").read_text().split() + (data / "val.txt").read_text().split()
    big = [names[i % len(names)] for i in range(args.frames)]
    (data / "soak.txt").write_text("\n".join(big) + "\n")
    weights = run / "final.safetensors"
    if not weights.exists():
        weights = run / "best.safetensors"
    none = lambda: (0, 0.0, 0.0, 0.0, 0.0)
    scores = out / "eval.json"
    scores.unlink(missing_ok=True)
    watch([rtf, "eval", "--weights", str(weights), "--data", str(data), "--split", "soak",
           "--json", str(scores)], "eval", none, rows, finished=scores.exists)
    preds = out / "pred"
    # `rtf predict` over a folder of `--frames` distinct names: links to the set's images.
    images = sorted((data / "images").glob("*.png"))
    links = out / "predict_in"
    links.mkdir(exist_ok=True)
    for i in range(args.frames):
        link = links / f"{i:05d}_{images[i % len(images)].name}"
        if not link.exists():
            link.symlink_to(images[i % len(images)].resolve())
    done = lambda: (len(list(preds.glob("*_color.png"))) if preds.exists() else 0, 0.0, 0.0, 0.0, 0.0)
    watch([rtf, "predict", "--weights", str(weights), "--out", str(preds), str(links)], "predict",
          done, rows, finished=lambda: done()[0] >= args.frames)
    dicts = [dict(zip(KEYS, r)) for r in rows]
    # Training: the last sample of every --every steps.
    last_of = {}
    for d in dicts:
        if d["phase"] == "train":
            last_of[d["done"] // args.every] = d
    dicts = sorted(last_of.values(), key=lambda d: d["done"]) + [d for d in dicts if d["phase"] != "train"]
    with open(out / "soak.csv", "w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=KEYS)
        wr.writeheader()
        wr.writerows(dicts)
    svg(dicts, out / "soak.svg")
    for phase in ("train", "eval", "predict"):
        summary = growth(dicts, phase, args.warm_up)
        if summary:
            print(json.dumps(summary))


if __name__ == "__main__":
    main()
