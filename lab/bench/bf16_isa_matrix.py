#!/usr/bin/env python3
"""bf16 against fp32 inference, rtf and PyTorch side by side, under each oneDNN instruction-set
cap this CPU can stand in for (issue 41): which convolution kernels a CPU kind gets decides
whether bf16 pays, and a machine with AMX can also show what the kinds without it get.

For each cap (none, i.e. what oneDNN picks here, then every cap below it that changes the
kernels on this CPU), runs lab/bench/bench_torch.py (PyTorch eager NCHW / channels_last fp32 and
bf16 autocast, `rtf bench model` fp32 and bf16, a fresh process each, interleaved rounds) with
`ONEDNN_MAX_CPU_ISA` set, and writes one Markdown table and the JSON rows, naming the CPU (lscpu
model, family/model, flags) and the oneDNN ISA each cap gave (ONEDNN_VERBOSE).

Usage (from the repo root, after `cargo build --release -p rtf-cli`, on a quiet machine):
    .venv/bin/python lab/bench/bf16_isa_matrix.py --models mfnet,rtfnet50 --out target/bf16-isa
"""
import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from speed_tables import cpu, cpu_label, git_commit  # noqa: E402

# oneDNN caps, highest first, with the /proc/cpuinfo flag above which each one changes kernels.
CAPS = [
    ("AVX512_CORE_FP16", "amx_tile", "AVX-512 with bf16 and fp16, no AMX (Intel without AMX exposed)"),
    ("AVX512_CORE_BF16", "avx512_fp16", "AVX-512 with bf16 (AMD EPYC Zen 4/5 kind)"),
]


def onednn_isa(env):
    """The ISA line oneDNN prints for one bf16 convolution under `env`."""
    code = ("import torch; x = torch.randn(1, 16, 8, 8).bfloat16(); "
            "torch.nn.functional.conv2d(x, torch.randn(16, 16, 3, 3).bfloat16())")
    out = subprocess.run([sys.executable, "-c", code], env={**env, "ONEDNN_VERBOSE": "1"},
                         capture_output=True, text=True).stdout
    for line in out.splitlines():
        if ",isa:" in line:
            return line.split(",isa:", 1)[1].strip()
    return "?"


def caps_here(flags):
    caps = [(None, "", "as oneDNN picks on this CPU")]
    return caps + [c for c in CAPS if c[1] in flags]


def row(model, cap, isa, rows):
    ms = {k: v["median_ms"] for k, v in rows.items()}
    torch_fp32 = min(ms["torch eager fp32 NCHW"], ms["torch channels_last fp32"])
    torch_bf16 = ms.get("torch bf16 autocast")
    rtf_fp32, rtf_bf16 = ms["rtf fast fp32"], ms.get("rtf fast bf16")
    cells = [model, cap or "none", isa, f"{torch_fp32:.1f}", f"{torch_bf16:.1f}", f"{rtf_fp32:.1f}",
             f"{rtf_bf16:.1f}", f"{torch_fp32 / rtf_fp32:.2f}×", f"{torch_bf16 / rtf_bf16:.2f}×", f"{min(torch_fp32, torch_bf16) / rtf_bf16:.2f}×",
             f"{rtf_fp32 / rtf_bf16:.2f}×"]
    return "| " + " | ".join(cells) + " |"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", default="mfnet,rtfnet50")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--warmup", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default="target/bf16-isa")
    ap.add_argument("--caps", default=None,
                    help="comma-separated caps to run ('none' for oneDNN's own pick); default: every one "
                         "that changes the kernels here")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    machine = cpu()
    flags = open("/proc/cpuinfo").read().split()
    header = ("| network | oneDNN cap | oneDNN ISA | PyTorch fp32 best ms | PyTorch bf16 ms | rtf fp32 ms | rtf bf16 ms "
              "| rtf fp32 vs PyTorch fp32 | rtf bf16 vs PyTorch bf16 | rtf bf16 vs PyTorch's fastest "
              "| rtf bf16 vs rtf fp32 |")
    lines = [f"CPU: {cpu_label(machine)}; rtf {git_commit()}; 480×640, batch 1, {a.threads} threads, median of "
             f"{a.rounds} interleaved rounds × {a.iterations} passes; "
             f"`.venv/bin/python lab/bench/bf16_isa_matrix.py --models {a.models}"
             f"{' --caps ' + a.caps if a.caps else ''}`", "", header,
             "|" + " --- |" * 11]
    report = {"cpu": machine, "commit": git_commit(), "rows": []}
    caps = caps_here(flags)
    if a.caps:
        wanted = a.caps.split(",")
        caps = [c for c in caps if (c[0] or "none") in wanted]
    for cap, _, kind in caps:
        env = dict(os.environ)
        if cap:
            env["ONEDNN_MAX_CPU_ISA"] = cap
        isa = onednn_isa(env)
        for model in a.models.split(","):
            path = os.path.join(a.out, f"{model}-{cap or 'none'}.json")
            cmd = [sys.executable, os.path.join(HERE, "bench_torch.py"), "--model", model, "--threads", str(a.threads),
                   "--rounds", str(a.rounds), "--iterations", str(a.iterations), "--warmup", str(a.warmup),
                   "--json-out", path]
            print("+", f"ONEDNN_MAX_CPU_ISA={cap}" if cap else "", " ".join(cmd), flush=True)
            subprocess.run(cmd, env=env, check=True)
            with open(path) as f:
                rows = json.load(f)["rows"]
            report["rows"].append({"model": model, "cap": cap, "kind": kind, "isa": isa, "rows": rows})
            lines.append(row(model, cap, isa, rows))
            print(lines[-1], flush=True)
    with open(os.path.join(a.out, "bf16_isa_matrix.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    with open(os.path.join(a.out, "bf16_isa_matrix.json"), "w") as f:
        json.dump(report, f, indent=1)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
