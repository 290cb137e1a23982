#!/usr/bin/env python3
"""Peer comparison for `rtf bench model`: runs the same network in PyTorch eager (the project's
.venv torch, same thread count) as NCHW fp32, channels_last fp32 and bf16 autocast (channels_last
and NCHW), then runs `rtf bench model --json` for fp32 and bf16 and prints the median, 95th
percentile and minimum ms per frame, each process's peak resident memory, and the speed ratios.

Every configuration, PyTorch's and rtf's alike, runs in a fresh process of its own (as a user
runs one of them), round after round, so load from other processes hits them all alike and no
configuration inherits another's allocator state; `--shared-process` runs the three PyTorch
configurations in this one process instead (the script's earlier behaviour).

Usage (from the repo root):
    .venv/bin/python lab/bench/bench_torch.py --model mfnet [--threads 2] [--iterations 10]
    .venv/bin/python lab/bench/bench_torch.py --model rtfnet50 --iterations 5

The PyTorch networks below follow the published MFNet, RTFNet and HeatNet (PSPNet) code
(spec §3, §4, §5); their parameter counts are printed and checked against the rtf model of the
same name. CMX (`cmx-mit-b0` … `b5`) is lab/parity/cmx_reference.py's network, which mirrors the
official code's module structure and computation (github.com/huaaaliu/RGBX_Semantic_Segmentation),
behind the official preprocessing (B, G, R order, ImageNet normalisation, thermal replicated to 3
channels) as its first step, as rtf's CMX runs it.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import time

import torch
import torch.nn as nn
import torch.nn.functional as F

HERE = os.path.dirname(os.path.abspath(__file__))
# cmx_reference in lab/parity; convert_pth (which it imports) in scripts/
sys.path[:0] = [HERE] + [os.path.join(HERE, d) for d in ("../parity", "../../scripts",)]
import cmx_reference  # noqa: E402


# ---------------------------------------------------------------- MFNet (reference layout)
class ConvBnLeakyRelu2d(nn.Module):
    def __init__(self, c_in, c_out, dilation=1):
        super().__init__()
        self.conv = nn.Conv2d(c_in, c_out, 3, padding=dilation, dilation=dilation)
        self.bn = nn.BatchNorm2d(c_out)

    def forward(self, x):
        return F.leaky_relu(self.bn(self.conv(x)), negative_slope=0.2)


class MiniInception(nn.Module):
    def __init__(self, c_in, c_out):
        super().__init__()
        h = c_out // 2
        self.conv1_left = ConvBnLeakyRelu2d(c_in, h)
        self.conv1_right = ConvBnLeakyRelu2d(c_in, h, 2)
        self.conv2_left = ConvBnLeakyRelu2d(c_out, h)
        self.conv2_right = ConvBnLeakyRelu2d(c_out, h, 2)
        self.conv3_left = ConvBnLeakyRelu2d(c_out, h)
        self.conv3_right = ConvBnLeakyRelu2d(c_out, h, 2)

    def forward(self, x):
        x = torch.cat((self.conv1_left(x), self.conv1_right(x)), 1)
        x = torch.cat((self.conv2_left(x), self.conv2_right(x)), 1)
        return torch.cat((self.conv3_left(x), self.conv3_right(x)), 1)


class MFNet(nn.Module):
    def __init__(self, n_class=9):
        super().__init__()
        r, t = [16, 48, 48, 96, 96], [16, 16, 16, 36, 36]
        for s, c_in, c in (("rgb", 3, r), ("inf", 1, t)):
            setattr(self, f"conv1_{s}", ConvBnLeakyRelu2d(c_in, c[0]))
            setattr(self, f"conv2_1_{s}", ConvBnLeakyRelu2d(c[0], c[1]))
            setattr(self, f"conv2_2_{s}", ConvBnLeakyRelu2d(c[1], c[1]))
            setattr(self, f"conv3_1_{s}", ConvBnLeakyRelu2d(c[1], c[2]))
            setattr(self, f"conv3_2_{s}", ConvBnLeakyRelu2d(c[2], c[2]))
            setattr(self, f"conv4_{s}", MiniInception(c[2], c[3]))
            setattr(self, f"conv5_{s}", MiniInception(c[3], c[4]))
        self.decode4 = ConvBnLeakyRelu2d(r[4] + t[4], r[2] + t[2])
        self.decode3 = ConvBnLeakyRelu2d(r[2] + t[2], r[1] + t[1])
        self.decode2 = ConvBnLeakyRelu2d(r[1] + t[1], 32)
        self.decode1 = ConvBnLeakyRelu2d(32, n_class)

    def encode(self, x, s):
        m = lambda n: getattr(self, f"{n}_{s}")
        x = F.max_pool2d(m("conv1")(x), 2)
        p2 = m("conv2_2")(m("conv2_1")(x))
        p3 = m("conv3_2")(m("conv3_1")(F.max_pool2d(p2, 2)))
        p4 = m("conv4")(F.max_pool2d(p3, 2))
        return m("conv5")(F.max_pool2d(p4, 2)), p2, p3, p4

    def forward(self, x):
        r5, r2, r3, r4 = self.encode(x[:, :3], "rgb")
        t5, t2, t3, t4 = self.encode(x[:, 3:], "inf")
        up = lambda y: F.interpolate(y, scale_factor=2, mode="nearest")
        x = up(torch.cat((r5, t5), 1))
        x = up(self.decode4(x + torch.cat((r4, t4), 1)))
        x = up(self.decode3(x + torch.cat((r3, t3), 1)))
        x = up(self.decode2(x + torch.cat((r2, t2), 1)))
        return self.decode1(x)


# ---------------------------------------------------------------- RTFNet (reference layout)
class Bottleneck(nn.Module):
    expansion = 4

    def __init__(self, c_in, planes, stride=1, dilation=1):
        super().__init__()
        out = planes * 4
        self.conv1 = nn.Conv2d(c_in, planes, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = nn.Conv2d(planes, planes, 3, stride, dilation, dilation, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = nn.Conv2d(planes, out, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(out)
        self.relu = nn.ReLU(inplace=True)
        self.downsample = None
        if stride != 1 or c_in != out:
            self.downsample = nn.Sequential(nn.Conv2d(c_in, out, 1, stride, bias=False), nn.BatchNorm2d(out))

    def forward(self, x):
        identity = x if self.downsample is None else self.downsample(x)
        y = self.relu(self.bn1(self.conv1(x)))
        y = self.relu(self.bn2(self.conv2(y)))
        return self.relu(self.bn3(self.conv3(y)) + identity)


class BasicBlock(nn.Module):
    expansion = 1

    def __init__(self, c_in, planes, stride=1):
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, planes, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = nn.Conv2d(planes, planes, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)
        self.downsample = None
        if stride != 1 or c_in != planes:
            self.downsample = nn.Sequential(nn.Conv2d(c_in, planes, 1, stride, bias=False), nn.BatchNorm2d(planes))

    def forward(self, x):
        identity = x if self.downsample is None else self.downsample(x)
        y = self.relu(self.bn1(self.conv1(x)))
        return self.relu(self.bn2(self.conv2(y)) + identity)


LAYOUTS = {18: (BasicBlock, [2, 2, 2, 2]), 34: (BasicBlock, [3, 4, 6, 3]), 50: (Bottleneck, [3, 4, 6, 3]),
           101: (Bottleneck, [3, 4, 23, 3]), 152: (Bottleneck, [3, 8, 36, 3])}


def resnet_parts(depth, c_in):
    """torchvision ResNet pieces without avgpool/fc: conv1, bn1, layer1..4, and the width."""
    block, blocks = LAYOUTS[depth]
    parts = {"conv1": nn.Conv2d(c_in, 64, 7, 2, 3, bias=False), "bn1": nn.BatchNorm2d(64)}
    c = 64
    for i, n in enumerate(blocks):
        planes = 64 << i
        layer = []
        for j in range(n):
            layer.append(block(c, planes, (1 if i == 0 else 2) if j == 0 else 1))
            c = planes * block.expansion
        parts[f"layer{i + 1}"] = nn.Sequential(*layer)
    return parts, c


class TransBottleneck(nn.Module):
    def __init__(self, c_in, planes, up):
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, planes, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = nn.Conv2d(planes, planes, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        if up:
            self.conv3 = nn.ConvTranspose2d(planes, planes, 2, 2, 0, bias=False)
            self.upsample = nn.Sequential(nn.ConvTranspose2d(c_in, planes, 2, 2, 0, bias=False), nn.BatchNorm2d(planes))
        else:
            self.conv3 = nn.Conv2d(planes, planes, 3, 1, 1, bias=False)
            self.upsample = None
        self.bn3 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)

    def forward(self, x):
        residual = x if self.upsample is None else self.upsample(x)
        y = self.relu(self.bn1(self.conv1(x)))
        y = self.relu(self.bn2(self.conv2(y)))
        return self.relu(self.bn3(self.conv3(y)) + residual)


class RTFNet(nn.Module):
    """Attribute names as the published code, so state_dict keys equal keys/rtfnet*.txt."""

    def __init__(self, depth, n_class=9):
        super().__init__()
        for modality, c_in in (("thermal", 1), ("rgb", 3)):
            parts, c = resnet_parts(depth, c_in)
            for name, module in parts.items():
                setattr(self, f"encoder_{modality}_{name}", module)
        widths = [c, c // 2, c // 4, c // 8, c // 16, n_class]
        for i in range(5):
            setattr(self, f"deconv{i + 1}", nn.Sequential(TransBottleneck(widths[i], widths[i], False),
                                                          TransBottleneck(widths[i], widths[i + 1], True)))
        self.maxpool = nn.MaxPool2d(3, 2, 1)

    def forward(self, x):
        e = lambda m, n: getattr(self, f"encoder_{m}_{n}")
        rgb = F.relu(e("rgb", "bn1")(e("rgb", "conv1")(x[:, :3])))
        th = F.relu(e("thermal", "bn1")(e("thermal", "conv1")(x[:, 3:])))
        rgb = self.maxpool(rgb + th)
        th = self.maxpool(th)
        for i in range(1, 5):
            rgb = e("rgb", f"layer{i}")(rgb)
            th = e("thermal", f"layer{i}")(th)
            rgb = rgb + th
        for i in range(1, 6):
            rgb = getattr(self, f"deconv{i}")(rgb)
        return rgb


def resnet50_front(c_in):
    """Stem, layer1 and layer2 of a ResNet-50: [B, c_in, H, W] -> [B, 512, H/8, W/8]."""
    def layer(c, planes, blocks, stride):
        return nn.Sequential(*[Bottleneck(c if j == 0 else planes * 4, planes, stride if j == 0 else 1)
                               for j in range(blocks)])
    return nn.Sequential(nn.Conv2d(c_in, 64, 7, 2, 3, bias=False), nn.BatchNorm2d(64), nn.ReLU(inplace=True),
                         nn.MaxPool2d(3, 2, 1), layer(64, 64, 3, 1), layer(256, 128, 4, 2))


def dilated_layer(c_in, planes, blocks, dilation):
    """HeatNet's layer3/layer4: no stride, the first block dilation 1, the others `dilation`."""
    return nn.Sequential(*[Bottleneck(c_in if j == 0 else planes * 4, planes, 1, 1 if j == 0 else dilation)
                           for j in range(blocks)])


class PSPUpsample(nn.Module):
    def __init__(self, c_in, c_out):
        super().__init__()
        self.conv = nn.Sequential(nn.Conv2d(c_in, c_out, 3, padding=1), nn.BatchNorm2d(c_out), nn.PReLU())

    def forward(self, x):
        h, w = 2 * x.size(2), 2 * x.size(3)
        return self.conv(F.interpolate(x, size=(h, w), mode="bilinear", align_corners=False))


class HeatNet(nn.Module):
    """HeatNet's segmentation network (spec §5, published models/pspnet.py): late fusion of an
    RGB and a thermal ResNet-50 front (stem, layer1, layer2), shared dilated layer3/layer4
    (output stride 8), the PSP module (bins 1, 2, 3, 6), three bilinear ×2 up blocks with
    PReLU, channel dropout 0.3 / 0.15. Input [B, 4, H, W] (RGB, T)."""

    def __init__(self, n_class=13):
        super().__init__()
        self.rgb, self.ir = resnet50_front(3), resnet50_front(1)
        self.layer3 = dilated_layer(1024, 256, 6, 2)
        self.layer4 = dilated_layer(1024, 512, 3, 4)
        self.stages = nn.ModuleList(
            nn.Sequential(nn.AdaptiveAvgPool2d(b), nn.Conv2d(2048, 2048, 1, bias=False)) for b in (1, 2, 3, 6))
        self.bottleneck = nn.Sequential(nn.Conv2d(2048 * 5, 1024, 1), nn.ReLU())
        self.drop_1, self.drop_2 = nn.Dropout2d(0.3), nn.Dropout2d(0.15)
        self.up = nn.ModuleList([PSPUpsample(1024, 256), PSPUpsample(256, 64), PSPUpsample(64, 64)])
        self.final = nn.Conv2d(64, n_class, 1)

    def forward(self, x):
        f = torch.cat([self.rgb(x[:, :3]), self.ir(x[:, 3:])], 1)
        f = self.layer4(self.layer3(f))
        h, w = f.shape[2:]
        priors = [F.interpolate(s(f), size=(h, w), mode="bilinear", align_corners=False) for s in self.stages]
        p = self.drop_1(self.bottleneck(torch.cat(priors + [f], 1)))
        for up in self.up:
            p = self.drop_2(up(p))
        return self.final(p)


class CmxPeer(nn.Module):
    """CMX as lab/parity/cmx_reference.py builds it (the official module tree), fed rtf's
    [B, 4, H, W] (R, G, B, T in [0, 1]) through the official preprocessing."""

    def __init__(self, size):
        super().__init__()
        self.net = cmx_reference.Cmx(size)

    def forward(self, x):
        return self.net(*cmx_reference.official_inputs(x))


def build(name):
    if name.startswith("cmx-mit-") and name[len("cmx-mit-"):] in cmx_reference.SIZES:
        return CmxPeer(name[len("cmx-mit-"):])
    if name == "mfnet":
        return MFNet()
    if name.startswith("rtfnet") and name[6:].isdigit():
        return RTFNet(int(name[6:]))
    if name == "heatnet":
        return HeatNet()
    sys.exit(f"bench_torch.py: no PyTorch definition for {name!r} (mfnet, rtfnet18..152, heatnet, "
             "cmx-mit-b0..b5)")


def time_torch(net, x, warmup, iterations, channels_last=False, bf16=False):
    """Milliseconds per frame of each timed pass."""
    if channels_last:
        net = net.to(memory_format=torch.channels_last)
        x = x.contiguous(memory_format=torch.channels_last)
    times = []
    with torch.inference_mode(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
        for i in range(warmup + iterations):
            start = time.perf_counter()
            net(x)
            if i >= warmup:
                times.append((time.perf_counter() - start) * 1e3 / x.shape[0])
    return times


def rtf_bench(args, precision, iterations, layout="nhwc"):
    cmd = [args.rtf, "bench", "model", "--model", args.model, "--batch", str(args.batch), "--precision", precision,
           "--layout", layout, "--threads", str(args.threads), "--warmup", str(args.warmup), "--iterations",
           str(iterations), "--json"]
    return json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)


TORCH_CONFIGS = {"torch eager fp32 NCHW": (False, False), "torch channels_last fp32": (True, False),
                 "torch bf16 autocast": (True, True), "torch bf16 autocast NCHW": (False, True)}


def peak_rss_mb():
    """This process's peak resident memory (Linux VmHWM, as `rtf bench` reads it), MiB."""
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def retain_freed_memory():
    """rtf's allocator policy (glibc: no mmap-served blocks, no heap trimming)."""
    import ctypes
    libc = ctypes.CDLL("libc.so.6")
    M_TRIM_THRESHOLD, M_MMAP_MAX = -1, -4
    if not (libc.mallopt(M_MMAP_MAX, 0) == 1 and libc.mallopt(M_TRIM_THRESHOLD, 2**31 - 1) == 1):
        sys.exit("bench_torch.py: mallopt refused the allocator policy")


def torch_times(args, label):
    """{"times": ms per frame, "peak_rss_mb": the process's peak} of one PyTorch configuration: in
    a fresh worker process, or here with --shared-process (no peak: the process is shared)."""
    if args.shared_process:
        channels_last, bf16 = TORCH_CONFIGS[label]
        times = time_torch(args.net, args.x, args.warmup, args.iterations, channels_last, bf16)
        return {"times": times, "peak_rss_mb": None}
    cmd = [sys.executable, os.path.abspath(__file__), "--worker", label, "--model", args.model, "--batch",
           str(args.batch), "--threads", str(args.threads), "--warmup", str(args.warmup), "--iterations",
           str(args.iterations)] + (["--torch-retain-memory"] if args.torch_retain_memory else [])
    return json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)


def setup(args):
    """Applies the process-wide settings and builds the network and input (seeded)."""
    if args.torch_retain_memory:
        retain_freed_memory()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    args.net = build(args.model).eval()
    args.x = torch.rand(args.batch, 4, 480, 640)


def p95(values):
    """95th percentile, nearest rank (as `rtf bench model`)."""
    ordered = sorted(values)
    return ordered[max(1, -(-95 * len(ordered) // 100)) - 1]


def measure(args, precisions):
    """{label: {"times": [...], "peaks": [...]}} over the interleaved rounds."""
    samples = {}

    def record(label, times, peak):
        entry = samples.setdefault(label, {"times": [], "peaks": []})
        entry["times"].extend(times)
        if peak is not None:
            entry["peaks"].append(peak)

    for _ in range(args.rounds):
        for label, (_, bf16) in TORCH_CONFIGS.items():
            if ("bf16" if bf16 else "fp32") in precisions and label not in args.skip:
                result = torch_times(args, label)
                record(label, result["times"], result["peak_rss_mb"])
        for precision in precisions:
            for layout in ["nhwc"] + (["nchw"] if args.nchw else []):
                report = rtf_bench(args, precision, args.iterations, layout)
                label = f"rtf fast {precision}" + (" nchw" if layout == "nchw" else "")
                record(label, report["samples_ms"], report.get("peak_rss_mb"))
    return samples


def summarise(rows, precisions):
    """Prints the rows and rtf's ratios to PyTorch's fastest configuration."""
    print(f"{'':26} {'median ms':>9} {'p95 ms':>8} {'min ms':>8} {'peak RSS MiB':>12}")
    for label, r in rows.items():
        peak = f"{r['peak_rss_mb']:12.0f}" if r["peak_rss_mb"] is not None else f"{'—':>12}"
        print(f"{label:26} {r['median_ms']:9.1f} {r['p95_ms']:8.1f} {r['min_ms']:8.1f} {peak}")
    torch_rows = {k: v for k, v in rows.items() if k.startswith("torch")}
    if not torch_rows:
        return
    fastest = min(torch_rows, key=lambda k: torch_rows[k]["median_ms"])
    for precision in precisions:
        ours = rows.get(f"rtf fast {precision}")
        same = {k: v for k, v in torch_rows.items() if (precision == "bf16") == ("bf16" in k)}
        if ours is None or not same:
            continue
        best = min(same, key=lambda k: same[k]["median_ms"])
        print(f"rtf {precision}: {same[best]['median_ms'] / ours['median_ms']:.2f}x the median of PyTorch's fastest "
              f"{precision} ({best}), {torch_rows[fastest]['median_ms'] / ours['median_ms']:.2f}x its fastest of all "
              f"({fastest})")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="mfnet")
    ap.add_argument("--batch", type=int, default=1)
    ap.add_argument("--threads", type=int, default=torch.get_num_threads())
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--iterations", type=int, default=5, help="timed passes per configuration and round")
    ap.add_argument("--rounds", type=int, default=3,
                    help="configurations are interleaved round by round, so load from other processes "
                         "hits them alike")
    ap.add_argument("--rtf", default="target/release/rtf", help="the rtf binary")
    ap.add_argument("--nchw", action="store_true", help="also time rtf's fast path with NCHW activations")
    ap.add_argument("--torch-retain-memory", action="store_true",
                    help="give PyTorch the allocator policy rtf sets for itself (glibc: no mmap-served blocks, "
                         "no heap trimming), to see how much of the gap that policy accounts for")
    ap.add_argument("--shared-process", action="store_true",
                    help="run the PyTorch configurations one after another in this process instead of a "
                         "fresh process each (they then inherit each other's allocator state)")
    ap.add_argument("--precisions", default="fp32,bf16",
                    help="comma-separated: fp32 (PyTorch NCHW and channels_last, rtf fp32), bf16 (PyTorch "
                         "autocast, rtf bf16)")
    ap.add_argument("--skip", default="", help="comma-separated PyTorch configurations to leave out")
    ap.add_argument("--json-out", help="also write the rows (median, p95 and min ms per frame, peak RSS) here, "
                    "as JSON")
    ap.add_argument("--worker", choices=sorted(TORCH_CONFIGS), help=argparse.SUPPRESS)
    args = ap.parse_args()
    args.skip = {x.strip() for x in args.skip.split(",") if x.strip()}
    if args.worker:
        setup(args)
        channels_last, bf16 = TORCH_CONFIGS[args.worker]
        times = time_torch(args.net, args.x, args.warmup, args.iterations, channels_last, bf16)
        print(json.dumps({"times": times, "peak_rss_mb": peak_rss_mb()}))
        return
    setup(args)
    params = sum(p.numel() for p in args.net.parameters())
    print(f"{args.model}: {params:,} parameters (PyTorch {torch.__version__}), batch {args.batch}, "
          f"{args.threads} threads, 480x640, {args.rounds} interleaved rounds of {args.iterations} timed passes "
          f"after {args.warmup} warm-up, "
          + ("PyTorch configurations sharing one process" if args.shared_process else "a fresh process per configuration")
          + (", PyTorch with rtf's allocator policy" if args.torch_retain_memory else ""), flush=True)
    precisions = [p for p in ("fp32", "bf16") if p in args.precisions.split(",")]
    rows = {k: {"median_ms": statistics.median(v["times"]), "p95_ms": p95(v["times"]), "min_ms": min(v["times"]),
                "peak_rss_mb": max(v["peaks"]) if v["peaks"] else None, "samples_ms": v["times"]}
            for k, v in measure(args, precisions).items()}
    if args.json_out:
        with open(args.json_out, "w") as f:
            json.dump({"model": args.model, "batch": args.batch, "threads": args.threads, "torch": torch.__version__,
                       "rounds": args.rounds, "iterations": args.iterations, "warmup": args.warmup,
                       "rows": rows}, f, indent=1)
    summarise(rows, precisions)


if __name__ == "__main__":
    main()
