#!/usr/bin/env python3
"""rtf against PyTorch on one CUDA GPU, same libtorch for both (issue 40): inference and training
speed and peak GPU memory, written as JSON and as Markdown tables.

    python3 lab/gpu/gpu_bench.py infer --rtf RTF --models mfnet,rtfnet50 --batches 1,8 --json OUT.json
    python3 lab/gpu/gpu_bench.py train --rtf RTF --models mfnet:8,rtfnet50:4 --json OUT.json
    python3 lab/gpu/gpu_bench.py table OUT.json [...]        # Markdown tables and ratios

Inference, 480x640: rtf's fast path (`rtf bench model --device cuda`) in fp32, fp16 and bf16,
each in a process of its own, against PyTorch eager on the published networks of
lab/bench/bench_torch.py: fp32 NCHW and channels_last; fp16 and bf16 as autocast and as a cast
network (`.half()`, `.bfloat16()`), channels_last; `torch.compile` (default mode) where asked.
Every pass is synchronised before the clock is read (as rtf does); median and p95 ms per frame.
Training: full steps (forward, cross-entropy, backward, optimiser: `rtf bench train`'s recipes,
SGD momentum 0.9 and weight decay 5e-4, or for CMX its AdamW, fused on CUDA) in fp32, fp16
(autocast + GradScaler; rtf scales its loss the same way) and bf16 (autocast), NCHW and
channels_last, and with --compile also `torch.compile`d (channels_last); images/s. With
--count-ops both sides count one more step's operators (the host's work; on a GPU each is one or
more kernel launches), outermost and in all, as `rtf bench train --count-ops` and
lab/bench/profile_train_torch.py --counts do.

Both sides set cuDNN's autotuner (`cudnn.benchmark`; rtf turns it on for CUDA) and keep
libtorch's default TF32 convolutions. Peak GPU memory is read the same way for both: NVML's
device-wide used memory, sampled every 5 ms while a configuration runs, less the idle reading
taken before any process touched the GPU (one process at a time, so it is that process's; it
includes the CUDA context and libraries). The PyTorch configurations of one network and batch
share a process (empty_cache between them), rtf's each run in a fresh one; PyTorch's allocator
peak (max_memory_allocated) is recorded beside.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
# bench_torch in lab/bench
sys.path[:0] = [HERE] + [os.path.join(HERE, d) for d in ("../bench",)]


# ------------------------------------------------------------------ GPU memory, read by NVML
class MemorySampler:
    """Peak of NVML's device-wide used memory (MiB) between start() and stop(); always 0 with
    --device cpu (the dry run of this script on a machine without a GPU)."""

    def __init__(self, device):
        self.nvml = None
        if device == "cuda":
            import pynvml
            pynvml.nvmlInit()
            self.nvml = pynvml
            self.handle = pynvml.nvmlDeviceGetHandleByIndex(0)

    def used_mb(self):
        return self.nvml.nvmlDeviceGetMemoryInfo(self.handle).used / 2**20 if self.nvml else 0.0

    def start(self):
        self.peak, self.running = self.used_mb(), True
        self.thread = threading.Thread(target=self._poll, daemon=True)
        self.thread.start()

    def _poll(self):
        while self.running:
            self.peak = max(self.peak, self.used_mb())
            time.sleep(0.005)

    def stop(self):
        self.running = False
        self.thread.join()
        return max(self.peak, self.used_mb())


# ------------------------------------------------------------------ PyTorch workers
INFER_CONFIGS = [  # label, precision, channels_last, how (eager / autocast / cast / compile)
    ("torch fp32 NCHW", "fp32", False, "eager"),
    ("torch fp32 channels_last", "fp32", True, "eager"),
    ("torch fp16 autocast channels_last", "fp16", True, "autocast"),
    ("torch fp16 .half() channels_last", "fp16", True, "cast"),
    ("torch bf16 autocast channels_last", "bf16", True, "autocast"),
    ("torch bf16 .bfloat16() channels_last", "bf16", True, "cast"),
]
COMPILE_CONFIGS = [
    ("torch.compile fp32 channels_last", "fp32", True, "compile"),
    ("torch.compile fp16 .half() channels_last", "fp16", True, "compile"),
]
TRAIN_CONFIGS = [(f"torch {p} {layout}", p, layout == "channels_last", "eager")
                 for p in ("fp32", "fp16", "bf16") for layout in ("NCHW", "channels_last")]
TRAIN_COMPILE_CONFIGS = [(f"torch.compile {p} channels_last", p, True, "compile") for p in ("fp32", "fp16", "bf16")]
DTYPES = {"fp32": "float32", "fp16": "float16", "bf16": "bfloat16"}


def synchronizer(torch, device):
    return torch.cuda.synchronize if device == "cuda" else (lambda: None)


def infer_config(torch, args, cfg):
    model, batch, device = args.model, args.batch, args.device
    label, precision, channels_last, how = cfg
    from bench_torch import build
    sync = synchronizer(torch, device)
    torch.manual_seed(0)
    net = build(model).eval().to(device)
    x = torch.rand(batch, 4, args.height, args.width, device=device)
    dtype = getattr(torch, DTYPES[precision])
    if how in ("cast", "compile") and precision != "fp32":
        net, x = net.to(dtype), x.to(dtype)
    if channels_last:
        net = net.to(memory_format=torch.channels_last)
        x = x.contiguous(memory_format=torch.channels_last)
    if how == "compile":
        net = torch.compile(net)
    times = []
    with torch.inference_mode(), torch.autocast(device, dtype=dtype, enabled=how == "autocast"):
        for i in range(args.warmup + args.iterations):
            sync()
            start = time.perf_counter()
            net(x)
            sync()
            if i >= args.warmup:
                times.append((time.perf_counter() - start) * 1e3 / batch)
    return {"samples_ms": times}


def optimizer_of(model):
    """The recipe `rtf bench train --optimizer` is given: CMX's AdamW for CMX, else SGD."""
    return "adamw" if model.startswith("cmx-") else "sgd"


def torch_optimizer(torch, net, model, device):
    """rtf's recipes (rtf-config `OptimizerConfig::paper_default`): SGD momentum 0.9, weight
    decay 5e-4 on every tensor; CMX's AdamW, lr 6e-5, weight decay 0.01 on the weights of two
    or more dimensions only (CMX's `group_weight`), the fused kernel on CUDA (PyTorch's fastest)."""
    if optimizer_of(model) == "sgd":
        return torch.optim.SGD(net.parameters(), lr=0.01, momentum=0.9, weight_decay=5e-4)
    params = [p for p in net.parameters() if p.requires_grad]
    groups = [{"params": [p for p in params if p.dim() >= 2]},
              {"params": [p for p in params if p.dim() < 2], "weight_decay": 0.0}]
    return torch.optim.AdamW(groups, lr=6e-5, weight_decay=0.01, fused=device == "cuda")


def train_config(torch, args, cfg):
    import torch.nn.functional as F
    from bench_torch import build
    from profile_train_torch import PARTS, part_counts
    from torch.profiler import ProfilerActivity, profile, record_function
    model, batch, device, steps = args.model, args.batch, args.device, args.iterations
    label, precision, channels_last, how = cfg
    sync = synchronizer(torch, device)
    torch.manual_seed(0)
    net = build(model).train().to(device)
    x = torch.rand(batch, 4, args.height, args.width, device=device)
    y = torch.randint(0, 9, (batch, args.height, args.width), device=device)
    if channels_last:
        net = net.to(memory_format=torch.channels_last)
        x = x.contiguous(memory_format=torch.channels_last)
    opt = torch_optimizer(torch, net, model, device)
    forward = torch.compile(net) if how == "compile" else net
    scaler = torch.amp.GradScaler(device, enabled=precision == "fp16")
    dtype = getattr(torch, DTYPES[precision])

    def step():  # the parts in profiler ranges, as profile_train_torch.py counts them
        with record_function(PARTS[0]), torch.autocast(device, dtype=dtype, enabled=precision != "fp32"):
            loss = F.cross_entropy(forward(x).float(), y)
        with record_function(PARTS[1]):
            opt.zero_grad(set_to_none=True)
            scaler.scale(loss).backward()
        with record_function(PARTS[2]):
            scaler.step(opt)
            scaler.update()
        loss.item()

    step_s = []
    for i in range(args.warmup + steps):
        sync()
        start = time.perf_counter()
        step()
        if i >= args.warmup:
            step_s.append(time.perf_counter() - start)
    row = {"images_per_s": steps * batch / sum(step_s), "step_s": statistics.median(step_s),
           "optimizer": optimizer_of(model)}
    if args.count_ops:
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            step()
        row["op_counts"] = part_counts(prof)
    return row


def worker(args):
    """Runs this network's PyTorch configurations in this process, one after another."""
    import torch
    torch.backends.cudnn.benchmark = True
    cuda = args.device == "cuda"
    sampler = MemorySampler(args.device)
    if args.kind == "infer":
        configs = INFER_CONFIGS + (COMPILE_CONFIGS if args.compile else [])
        run = lambda cfg: infer_config(torch, args, cfg)
    else:
        configs = TRAIN_CONFIGS + (TRAIN_COMPILE_CONFIGS if args.compile else [])
        run = lambda cfg: train_config(torch, args, cfg)
    rows = []
    for cfg in configs:
        if cfg[1] not in args.precisions.split(","):
            continue
        if cuda:
            torch.cuda.empty_cache()
            torch.cuda.reset_peak_memory_stats()
        sampler.start()
        try:
            row = run(cfg)
        except Exception as err:  # torch.compile may not work for every network: say so
            sampler.stop()
            rows.append({"label": cfg[0], "precision": cfg[1], "error": f"{type(err).__name__}: {err}"[:300]})
            continue
        row["peak_gpu_mb"] = sampler.stop() - args.idle_mb
        if cuda:
            row["torch_allocated_mb"] = torch.cuda.max_memory_allocated() / 2**20
        rows.append({"label": cfg[0], "precision": cfg[1], **row})
        if cfg[-1] == "compile":
            torch._dynamo.reset()
    print(json.dumps(rows))


# ------------------------------------------------------------------ the harness
def run_torch_worker(args, kind, model, batch, idle_mb, compile_):
    cmd = [sys.executable, os.path.abspath(__file__), "worker", "--kind", kind, "--model", model, "--batch",
           str(batch), "--warmup", str(args.warmup), "--iterations", str(args.iterations), "--precisions",
           args.precisions, "--idle-mb", str(idle_mb), "--device", args.device, "--size", args.size]
    cmd += (["--compile"] if compile_ else []) + (["--count-ops"] if kind == "train" and args.count_ops else [])
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        return [{"label": f"torch ({kind})", "error": done.stderr[-600:]}]
    return json.loads(done.stdout.strip().splitlines()[-1])


def run_rtf(args, sampler, idle_mb, cmd, env=None):
    sampler.start()
    done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    peak = sampler.stop() - idle_mb
    if done.returncode != 0:
        return {"error": done.stderr[-600:]}
    report = json.loads(done.stdout.strip().splitlines()[-1])
    report["peak_gpu_mb"] = peak
    return report


def harness(args):
    sampler = MemorySampler(args.device)
    idle_mb = sampler.used_mb()
    compiled = set(filter(None, args.compile.split(",")))
    results = {"kind": args.kind, "size": args.size, "idle_mb": idle_mb, "rows": []}
    for spec in args.models.split(","):
        model, _, batches = spec.partition(":")
        for batch in [int(b) for b in (batches or args.batches).split("/")]:
            key = {"model": model, "batch": batch}
            for row in run_torch_worker(args, args.kind, model, batch, idle_mb, model in compiled):
                results["rows"].append({**key, **row})
            for precision in args.precisions.split(","):
                for suffix, flags, env in rtf_variants(args, model, precision):
                    report = run_rtf(args, sampler, idle_mb, rtf_command(args, model, batch, precision) + flags, env)
                    row = {**key, "label": f"rtf {precision}{suffix}", "precision": precision, **report}
                    row.pop("cpu", None)
                    results["rows"].append(row)
            print(summary_line(results["rows"], model, batch), flush=True)
            with open(args.json, "w") as f:  # after every network, so a cut-off run keeps its part
                json.dump(results, f, indent=1)


def rtf_command(args, model, batch, precision):
    common = [args.rtf, "bench", "model" if args.kind == "infer" else "train", "--model", model, "--batch", str(batch),
              "--precision", precision, "--device", args.device, "--size", args.size, "--warmup", str(args.warmup),
              "--json"]
    if args.kind == "infer":
        return common + ["--iterations", str(args.iterations), "--no-agreement"]
    return common + ["--steps", str(args.iterations), "--optimizer", optimizer_of(model)] + (
        ["--count-ops"] if args.count_ops else [])


def rtf_variants(args, model, precision):
    """(label suffix, extra flags, environment) of each rtf run: the default, and for the
    --diagnose networks in fp32 also cuDNN's heuristics and (inference) the plain NCHW path."""
    yield "", [], None
    if model in args.diagnose.split(",") and precision == "fp32":
        yield " (cuDNN heuristics)", [], {**os.environ, "RTF_CUDNN_BENCHMARK": "0"}
        if args.kind == "infer":
            yield " plain NCHW path", ["--plain"], None


def summary_line(rows, model, batch):
    mine = [r for r in rows if r["model"] == model and r["batch"] == batch]
    return f"{model} batch {batch}: " + "; ".join(
        f"{r['label']} {'ERROR' if 'error' in r else speed(r)}" for r in mine)


def speed(row):
    if "samples_ms" in row:
        return f"{statistics.median(row['samples_ms']):.2f} ms"
    return f"{row['images_per_s']:.1f} img/s"


# ------------------------------------------------------------------ tables
def table(paths):
    from bench_torch import p95  # nearest rank, as `rtf bench model`
    for path in paths:
        results = json.load(open(path))
        infer = results["kind"] == "infer"
        groups = {}
        for r in results["rows"]:
            groups.setdefault((r["model"], r["batch"]), []).append(r)
        for (model, batch), rows in groups.items():
            size = results.get("size", "640x480").split("x")
            print(f"\n**{model}, batch {batch}** ({'inference' if infer else 'training'}, {size[1]}×{size[0]})\n")
            if infer:
                print("| configuration | median ms/frame | p95 ms/frame | images/s | peak GPU MiB | PyTorch allocator MiB |")
                print("| --- | ---: | ---: | ---: | ---: | ---: |")
            else:
                print("| configuration | images/s | step ms (median) | peak GPU MiB | PyTorch allocator MiB | "
                      "operators a step (outermost / all) |")
                print("| --- | ---: | ---: | ---: | ---: | ---: |")
            for r in rows:
                if "error" in r:
                    print(f"| {r['label']} | failed: {r['error'].splitlines()[-1][:120]} |")
                    continue
                alloc = f"{r['torch_allocated_mb']:.0f}" if "torch_allocated_mb" in r else "—"
                if infer:
                    med = statistics.median(r["samples_ms"])
                    print(f"| {r['label']} | {med:.2f} | {p95(r['samples_ms']):.2f} | {1e3 / med:.1f} | "
                          f"{r['peak_gpu_mb']:.0f} | {alloc} |")
                else:
                    print(f"| {r['label']} | {r['images_per_s']:.1f} | {1e3 * r['step_s']:.1f} | "
                          f"{r['peak_gpu_mb']:.0f} | {alloc} | {op_totals(r.get('op_counts'))} |")
            print()
            for line in ratios(rows, infer):
                print(f"- {line}")


def op_totals(counts):
    """'outermost / all' of {part: {name: [all, outermost]}} (`rtf bench train --count-ops`,
    profile_train_torch.part_counts), or — when the operators were not counted."""
    if not counts:
        return "—"
    every = [c for part in counts.values() for c in part.values()]
    return f"{sum(c[1] for c in every)} / {sum(c[0] for c in every)}"


def ratios(rows, infer):
    """rtf against PyTorch's best configuration of the same precision: speed and memory."""
    rate = (lambda r: 1e3 / statistics.median(r["samples_ms"])) if infer else (lambda r: r["images_per_s"])
    ok = [r for r in rows if "error" not in r]
    for precision in ("fp32", "fp16", "bf16"):
        ours = next((r for r in ok if r["label"] == f"rtf {precision}"), None)
        peers = [r for r in ok if r["label"].startswith("torch") and r["precision"] == precision]
        if ours is None or not peers:
            continue
        best = max(peers, key=rate)
        memory = ours["peak_gpu_mb"] / best["peak_gpu_mb"] if best["peak_gpu_mb"] > 0 else float("nan")
        yield (f"rtf {precision}: **{rate(ours) / rate(best):.2f}×** the speed of PyTorch's best {precision} "
               f"({best['label']}), peak GPU memory {memory:.2f}× its")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    for name in ("infer", "train", "worker"):
        p = sub.add_parser(name)
        p.add_argument("--warmup", type=int, default=5)
        p.add_argument("--iterations", type=int, default=20, help="timed passes (inference) or steps (training)")
        p.add_argument("--precisions", default="fp32,fp16,bf16")
        p.add_argument("--device", default="cuda", help="cuda; cpu for a dry run of this script (no memory)")
        p.add_argument("--size", default="640x480", help="WIDTHxHEIGHT (smaller for a dry run on the CPU)")
        p.add_argument("--count-ops", action="store_true",
                       help="training: count one more step's operators on both sides (rtf bench train --count-ops)")
        if name == "worker":
            p.add_argument("--kind", choices=("infer", "train"), required=True)
            p.add_argument("--model", required=True)
            p.add_argument("--batch", type=int, required=True)
            p.add_argument("--idle-mb", type=float, required=True)
            p.add_argument("--compile", action="store_true")
        else:
            p.add_argument("--rtf", required=True)
            p.add_argument("--models", required=True, help="NAME[:B1/B2],... (batches override --batches)")
            p.add_argument("--batches", default="1/8" if name == "infer" else "4")
            p.add_argument("--compile", default="", help="networks also timed under torch.compile")
            p.add_argument("--diagnose", default="",
                           help="networks whose rtf fp32 is also timed with cuDNN's heuristics "
                                "(RTF_CUDNN_BENCHMARK=0) and, for inference, on the plain NCHW path")
            p.add_argument("--json", required=True)
    p = sub.add_parser("table")
    p.add_argument("paths", nargs="+")
    args = ap.parse_args()
    if args.cmd != "table":
        args.width, args.height = (int(v) for v in args.size.lower().split("x"))
    if args.cmd == "table":
        table(args.paths)
    elif args.cmd == "worker":
        worker(args)
    else:
        args.kind = args.cmd
        harness(args)


if __name__ == "__main__":
    main()
