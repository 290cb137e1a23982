#!/usr/bin/env python3
"""Regenerates the speed tables of docs/src/models.md ("Speed against PyTorch") in one command:
runs lab/bench/bench_torch.py (inference, batch 1, 480x640) and lab/bench/bench_torch_train.py
(training steps) for each network, PyTorch and `rtf bench` side by side in fresh processes,
and writes a Markdown block and a JSON file in which every row names the CPU it was measured
on (`lscpu` model, family/model, and the flags that decide the kernels: avx2, avx512f,
avx512_bf16, amx_bf16), with the date, the PyTorch version and the rtf commit.

Usage (from the repo root, after `cargo build --release -p rtf-cli`):
    .venv/bin/python lab/bench/speed_tables.py --out target/speed
    .venv/bin/python lab/bench/speed_tables.py --kind-dir lab/measurements/speed-kinds   # this CPU kind's page
    .venv/bin/python lab/bench/speed_tables.py --models rtfnet50 --train-models "" --out target/speed \\
        --prefix "flock /tmp/bench.lock lab/quiet.sh nice -n -15"

`--prefix` is put before every benchmark command (each network's run is one command, so a lock
taken that way is held for one network at a time). Writes OUT/speed_tables.md and
OUT/speed_tables.json; `--from-json OUT/speed_tables.json` rewrites the Markdown without
running anything. `--page NAME` writes the kind page as DIR/<kind>-NAME.md (a second page of
one CPU kind, e.g. `cmx`, leaving the kind's main page as it is).

Inference rows list every configuration with its median, 95th-percentile and minimum ms per
frame and its process's peak resident memory (reports written before those were recorded show
the median table of the time).
"""
import argparse
import datetime
import json
import os
import shlex
import statistics
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
FLAGS = ("avx2", "avx512f", "avx512_bf16", "avx512_fp16", "amx_bf16")


def cpu():
    """Model name, family/model and the kernel-deciding flags of this machine (lscpu)."""
    fields = {}
    for line in subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout.splitlines():
        key, _, value = line.partition(":")
        fields[key.strip()] = value.strip()
    flags = set(fields.get("Flags", "").split())
    return {"vendor": fields.get("Vendor ID", "?"), "model": fields.get("Model name", "?"),
            "family": fields.get("CPU family", "?"),
            "model_number": fields.get("Model", "?"), "cpus": fields.get("CPU(s)", "?"),
            "flags": [f for f in FLAGS if f in flags], "flags_absent": [f for f in FLAGS if f not in flags]}


def cpu_label(c):
    flags = " ".join(c["flags"]) or "none of " + ", ".join(FLAGS)
    vendor = f"{c['vendor']} " if "vendor" in c else ""
    return f"{vendor}{c['model']} (family {c['family']}, model {c['model_number']}, {c['cpus']} CPUs): {flags}"


def git_commit():
    out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True)
    return out.stdout.strip() + ("+changes" if dirty.stdout.strip() else "")


def run(prefix, script, args, json_path):
    cmd = shlex.split(prefix) + [sys.executable, os.path.join(HERE, script)] + args + ["--json-out", json_path]
    print("+", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True)
    with open(json_path) as f:
        return json.load(f), " ".join(shlex.quote(x) for x in [os.path.join("lab", "bench", script)] + args)


def inference(a, model, out):
    args = ["--model", model, "--rounds", str(a.rounds), "--iterations", str(a.iterations), "--warmup",
            str(a.warmup), "--threads", str(a.threads), "--precisions", a.precisions, "--rtf", a.rtf]
    result, command = run(a.prefix, "bench_torch.py", args, os.path.join(out, f"infer_{model}.json"))
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return {"model": model, "finished": stamp, "command": command, "rows": result["rows"], "torch": result["torch"]}


def training(a, model, out):
    args = ["--model", model, "--batch", str(a.train_batch), "--size", a.train_size, "--threads", str(a.threads),
            "--rounds", str(a.train_rounds), "--warmup", "1", "--steps", str(a.train_steps), "--precisions", a.train_precisions,
            "--rtf", a.rtf] + (["--skip", a.train_skip] if a.train_skip else [])
    samples, command = run(a.prefix, "bench_torch_train.py", args, os.path.join(out, f"train_{model}.json"))
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return {"model": model, "finished": stamp, "command": command, "rows": training_rows(samples)}


def training_rows(samples):
    """Per configuration, the median over its rounds (each round a fresh process: the median of its
    timed steps) of the speed and of the peak RSS."""
    return {label: {k: statistics.median(r[k] for r in runs) for k in ("images_per_s", "peak_rss_mb")}
            for label, runs in samples.items()}


def ratio(x):
    """A speed ratio (rtf over PyTorch), bold where rtf is ahead."""
    return f"**{x:.2f}×**" if x >= 1 else f"{x:.2f}×"


def inference_rows_table(results, label):
    """One row per configuration: median, p95, min, peak RSS, and rtf's ratios to PyTorch's fastest
    configuration of the same precision and of any."""
    lines = ["| network | configuration | median ms | p95 ms | min ms | peak RSS MiB | rtf vs fastest torch, same "
             "precision | rtf vs fastest torch, any | measured | CPU |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- | --- |"]
    for r in results:
        rows = r["rows"]
        torch_rows = {k: v for k, v in rows.items() if k.startswith("torch")}
        fastest = min((v["median_ms"] for v in torch_rows.values()), default=None)
        for name, v in rows.items():
            same = any_ = ""
            if name.startswith("rtf") and fastest is not None:
                bf16 = "bf16" in name
                same_rows = [t["median_ms"] for k, t in torch_rows.items() if ("bf16" in k) == bf16]
                same = ratio(min(same_rows) / v["median_ms"]) if same_rows else "—"
                any_ = ratio(fastest / v["median_ms"])
            peak = f"{v['peak_rss_mb']:.0f}" if v.get("peak_rss_mb") is not None else "—"
            lines.append(f"| {r['model']} | {name} | {v['median_ms']:.1f} | {v['p95_ms']:.1f} | {v['min_ms']:.1f} | "
                         f"{peak} | {same} | {any_} | {r['finished']} | {label} |")
    return lines


def inference_table(results, label):
    if results and isinstance(next(iter(results[0]["rows"].values())), dict):
        return inference_rows_table(results, label)
    head = ("| network | torch eager NCHW | torch channels_last | torch bf16 autocast | rtf fp32 | rtf bf16 "
            "| rtf fp32 vs fastest torch fp32 | rtf bf16 vs torch bf16 | measured | CPU |")
    lines = [head, "| --- " + "| ---: " * 7 + "| --- | --- |"]
    for r in results:
        rows = r["rows"]
        cell = lambda k: f"{rows[k]:.1f}" if k in rows else "—"  # noqa: E731
        fastest = min(rows.get("torch eager fp32 NCHW", float("inf")), rows.get("torch channels_last fp32", float("inf")))
        fp32 = ratio(fastest / rows["rtf fast fp32"]) if "rtf fast fp32" in rows and fastest < float("inf") else "—"
        bf16 = (ratio(rows["torch bf16 autocast"] / rows["rtf fast bf16"])
                if "rtf fast bf16" in rows and "torch bf16 autocast" in rows else "—")
        lines.append(f"| {r['model']} | {cell('torch eager fp32 NCHW')} | {cell('torch channels_last fp32')} | "
                     f"{cell('torch bf16 autocast')} | {cell('rtf fast fp32')} | {cell('rtf fast bf16')} | {fp32} | "
                     f"{bf16} | {r['finished']} | {label} |")
    return lines


def training_table(results, label):
    lines = ["| network | configuration | images/s | peak RSS MiB | rtf vs best torch, same precision | measured "
             "| CPU |", "| --- | --- | ---: | ---: | ---: | --- | --- |"]
    for r in results:
        rows = r["rows"]
        for name, v in rows.items():
            vs = ""
            if name.startswith("rtf"):
                precision = name.split()[1]
                torch_rows = [t for k, t in rows.items() if k.startswith("torch") and precision in k]
                if torch_rows:
                    vs = ratio(v["images_per_s"] / max(t["images_per_s"] for t in torch_rows))
            lines.append(f"| {r['model']} | {name} | {v['images_per_s']:.3f} | {v['peak_rss_mb']:.0f} | {vs} | "
                         f"{r['finished']} | {label} |")
    return lines


def markdown(report):
    c = report["cpu"]
    vendor = f"{c['vendor']} " if "vendor" in c else ""
    label = f"{vendor}{c['model']} fam {c['family']}/{c['model_number']}: {' '.join(c['flags'])}"
    out = [f"Generated by `{report['command']}` on {report['date']}, rtf {report['rtf_commit']}, "
           f"PyTorch {report['torch']}, {report['threads']} threads.",
           f"CPU: {cpu_label(c)}" + (f"; absent: {' '.join(c['flags_absent'])}." if c["flags_absent"] else "."), ""]
    if report["inference"]:
        long = isinstance(next(iter(report["inference"][0]["rows"].values())), dict)
        out += [f"Inference, batch 1, 480×640, {'' if long else 'median '}ms per frame (fresh process per "
                "configuration, interleaved rounds; commands: " + "; ".join(f"`{r['command']}`" for r in report["inference"]) + "):", ""]
        out += inference_table(report["inference"], label) + [""]
    if report["training"]:
        out += ["Training steps (forward, loss, backward, SGD), median of the timed steps (with several rounds, "
                "the median of the rounds' medians; commands: "
                + "; ".join(f"`{r['command']}`" for r in report["training"]) + "):", ""]
        out += training_table(report["training"], label) + [""]
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", default="mfnet,rtfnet18,rtfnet50,rtfnet152,heatnet",
                    help="inference comparisons (comma-separated; empty for none)")
    ap.add_argument("--train-models", default="rtfnet50", help="training comparisons (comma-separated)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--precisions", default="fp32,bf16", help="inference precisions")
    ap.add_argument("--train-precisions", default="fp32")
    ap.add_argument("--train-batch", type=int, default=4)
    ap.add_argument("--train-size", default="640x480")
    ap.add_argument("--train-steps", type=int, default=2)
    ap.add_argument("--train-rounds", type=int, default=1, help="interleaved training rounds (fresh processes each)")
    ap.add_argument("--train-skip", default="", help="PyTorch training configurations to leave out (bench_torch_train.py "
                    "--skip)")
    ap.add_argument("--rtf", default="target/release/rtf")
    ap.add_argument("--prefix", default="", help="command prefix for every benchmark (e.g. a lock)")
    ap.add_argument("--out", default="target/speed")
    ap.add_argument("--from-json", help="rewrite the Markdown from this JSON report, running nothing")
    ap.add_argument("--kind-dir", help="also write the tables as this CPU kind's page, DIR/<kind>.md and .json "
                    "(lab/measurements/speed-kinds: the speed matrix by CPU kind; other kinds' pages are left as they are)")
    ap.add_argument("--page", default="", help="with --kind-dir: write DIR/<kind>-PAGE.md and .json instead (a "
                    "further page of this kind, e.g. cmx)")
    a = ap.parse_args()
    if a.from_json:
        with open(a.from_json) as f:
            report = json.load(f)
    else:
        os.makedirs(a.out, exist_ok=True)
        report = {"command": "lab/bench/speed_tables.py " + " ".join(shlex.quote(x) for x in sys.argv[1:]),
                  "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
                  "cpu": cpu(), "rtf_commit": git_commit(), "threads": a.threads,
                  "inference": [inference(a, m, a.out) for m in a.models.split(",") if m],
                  "training": [training(a, m, a.out) for m in a.train_models.split(",") if m]}
        report["torch"] = report["inference"][0]["torch"] if report["inference"] else "see the commands"
        write(os.path.join(a.out, "speed_tables.json"), json.dumps(report, indent=1))
    text = markdown(report)
    if not a.from_json:
        write(os.path.join(a.out, "speed_tables.md"), text + "\n")
    if a.kind_dir:
        os.makedirs(a.kind_dir, exist_ok=True)
        slug = kind_slug(report["cpu"]) + (f"-{a.page}" if a.page else "")
        write(os.path.join(a.kind_dir, slug + ".md"), text + "\n")
        write(os.path.join(a.kind_dir, slug + ".json"), json.dumps(report, indent=1))
        print(f"wrote {os.path.join(a.kind_dir, slug)}.md (include it in docs/src/speed-by-kind.md if it is new)")
    print(text)


def kind_slug(c):
    """A file name for a CPU kind: model name, family, model and the kernel-deciding flags."""
    name = "".join(ch if ch.isalnum() else "-" for ch in c["model"].lower().replace("(r)", ""))
    name = "-".join(part for part in name.split("-") if part)
    return f"{name}-fam{c['family']}-model{c['model_number']}-" + "-".join(c["flags"]).replace("_", "")


def write(path, text):
    """Atomic: a temporary file beside `path`, renamed over it."""
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, path)


if __name__ == "__main__":
    main()
