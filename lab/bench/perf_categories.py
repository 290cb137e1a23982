#!/usr/bin/env python3
"""Shares of a `perf record` profile (no call graphs) by kind of work: oneDNN convolution kernels, the
kernel's page zeroing, BatchNorm, OpenMP waits, pointwise ops, ...: to set rtf's and PyTorch's training steps
side by side where their symbols differ (docs/src/benchmarks.md, issue 41).

Usage: lab/bench/perf_categories.py A.perf [B.perf ...]  (prints one Markdown row per kind, a column per file)
"""
import subprocess, sys, re, collections
CATS = [("convolution (oneDNN JIT kernels)", lambda d, s: d.startswith("[JIT]") or "dnnl::" in s),
        ("page faults (kernel zeroing fresh pages)", lambda d, s: d == "[kernel.kallsyms]" and ("clear_page" in s or "fault" in s or "folio" in s or "memcg" in s)),
        ("other kernel", lambda d, s: d == "[kernel.kallsyms]"),
        ("BatchNorm fwd+bwd", lambda d, s: "batch_norm" in s),
        ("OpenMP runtime (libgomp waits)", lambda d, s: "libgomp" in d),
        ("max pool", lambda d, s: "max_pool" in s),
        ("leaky_relu / relu / threshold", lambda d, s: "leaky" in s or "threshold" in s or "relu" in s or "clamp" in s),
        ("upsample", lambda d, s: "upsample" in s),
        ("loss (log_softmax, nll)", lambda d, s: "softmax" in s or "nll" in s),
        ("SGD update", lambda d, s: "sgd" in s.lower()),
        ("copies / fills / cat", lambda d, s: "copy" in s or "fill" in s or "cat" in s.lower() or "memset" in s or "memcpy" in s or "memmove" in s),
        ("elementwise (add, mul, …)", lambda d, s: "VectorizedLoop" in s or "cpu_kernel" in s or "binary" in s),
        ("python", lambda d, s: "python" in d),
        ]
def cats(path):
    out = subprocess.run(["perf", "report", "-i", path, "--no-children", "--sort", "dso,sym", "--stdio", "-g", "none"], capture_output=True, text=True).stdout
    agg = collections.Counter(); other = collections.Counter()
    for line in out.splitlines():
        m = re.match(r"\s+([\d.]+)%\s+(\S.*?)\s{2,}\[[.k]\]\s+(.*)", line)
        if not m: continue
        pct, dso, sym = float(m.group(1)), m.group(2).strip(), m.group(3)
        for name, f in CATS:
            if f(dso, sym):
                agg[name] += pct; break
        else:
            agg["other"] += pct; other[(dso, sym[:90])] += pct
    return agg, other
res = [cats(p) for p in sys.argv[1:]]
names = [n for n, _ in CATS] + ["other"]
for n in names:
    print(f"| {n} | " + " | ".join(f"{r[0][n]:.1f} %" for r in res) + " |")
for r in res:
    print([f"{k}: {v:.1f}" for k, v in r[1].most_common(6)])
