#!/usr/bin/env python3
"""A PyTorch reference trainer for MFNet and RTFNet, written from the official training
scripts' recipe as the project's spec states it (../shared/spec/README.md §3, §4; issue 27):

- data: an MF-layout folder (images/NAME.png RGBA with thermal in alpha, labels/NAME.png class
  ids, SPLIT.txt), pixels / 255, channels R, G, B, T, no mean/std normalisation;
- loss: plain cross-entropy over all 9 classes, mean over pixels, no ignore index, no weights;
- optimiser: torch.optim.SGD over every parameter, momentum 0.9, weight decay 5e-4 (the code's
  defaults; flags change them), lr = lr0 * decay ** epoch set at the start of each epoch
  (the code's ×0.95; the MFNet paper's ×0.94 through --lr-decay);
- order of a step: zero_grad, train-mode forward (BatchNorm on batch statistics, running
  statistics updated with momentum 0.1), loss, backward, step;
- augmentation (unless --no-augment): horizontal flip p 0.5 and RTFNet's random crop (each edge
  trimmed by up to 10 %, resized back: bicubic image, nearest label); a new random order each
  epoch unless --no-shuffle (then the order of the split file).

The networks are those of lab/bench/bench_torch.py (the published layouts, reference names).
Weights are read and written as safetensors under the reference names, so `rtf train --init`
and this script can start from the same file.

    python lab/parity/reference_train.py init --model mfnet --seed 0 --out init.safetensors
    python lab/parity/reference_train.py train --data ROOT --model mfnet --init init.safetensors \\
        --out ref.safetensors --losses ref_losses.json --epochs 2 --batch-size 2 \\
        --no-shuffle --no-augment

`train` writes the final weights (parameters and BatchNorm statistics) and a JSON list of
per-step records {"epoch", "step", "loss"} (the loss before the step's update).
"""
import argparse
import json
import os
import struct
import sys

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))
# bench_torch in lab/bench; convert_pth in scripts/
sys.path[:0] = [HERE] + [os.path.join(HERE, d) for d in ("../bench", "../../scripts",)]
import bench_torch  # noqa: E402
import convert_pth  # noqa: E402

SAFETENSORS_DTYPES = {"F32": torch.float32, "F64": torch.float64, "F16": torch.float16,
                      "BF16": torch.bfloat16, "I64": torch.int64, "I32": torch.int32}


def read_safetensors(path):
    """Named tensors of a safetensors file (no dependency on the safetensors package)."""
    with open(path, "rb") as f:
        raw = f.read()
    (n,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8:8 + n])
    data = raw[8 + n:]
    out = {}
    for name, info in header.items():
        if name == "__metadata__":
            continue
        begin, end = info["data_offsets"]
        dtype = SAFETENSORS_DTYPES.get(info["dtype"])
        if dtype is None:
            sys.exit(f"{path}: tensor {name}: unsupported dtype {info['dtype']}")
        t = torch.frombuffer(bytearray(data[begin:end]), dtype=dtype) if end > begin else torch.empty(0, dtype=dtype)
        out[name] = t.reshape(info["shape"]).clone()
    return out


def load_into(net, path):
    """Every parameter and buffer of `net` from `path`; a clear error names what does not fit."""
    file = read_safetensors(path)
    state = net.state_dict()
    missing = [k for k in state if k not in file and not k.endswith("num_batches_tracked")]
    unexpected = [k for k in file if k not in state]
    shapes = [f"{k} (network {list(state[k].shape)}, file {list(file[k].shape)})"
              for k in state if k in file and state[k].shape != file[k].shape]
    if missing or unexpected or shapes:
        sys.exit(f"{path}: weights do not match the network: missing {missing}, unexpected "
                 f"{unexpected}, shape mismatch {shapes}")
    with torch.no_grad():
        for k, v in state.items():
            if k in file:
                v.copy_(file[k].to(v.dtype))


def save(net, path):
    tensors = [(k, v.detach().contiguous()) for k, v in net.state_dict().items()
               if not k.endswith("num_batches_tracked")]
    convert_pth.write_safetensors(tensors, path)


def read_frame(root, name):
    rgba = np.asarray(Image.open(os.path.join(root, "images", name + ".png")).convert("RGBA"))
    x = torch.from_numpy(rgba.astype(np.float32) / np.float32(255.0)).permute(2, 0, 1).contiguous()
    label = np.asarray(Image.open(os.path.join(root, "labels", name + ".png")))
    return x, torch.from_numpy(label.astype(np.int64))


def augment(x, y, gen):
    """RTFNet's flip and random crop (spec §4)."""
    if torch.rand((), generator=gen) < 0.5:
        x, y = x.flip(-1), y.flip(-1)
    h, w = y.shape
    u = torch.rand(4, generator=gen).tolist()
    top, left = int(u[0] * 0.1 * h), int(u[1] * 0.1 * w)
    bottom, right = h - int(u[2] * 0.1 * h), w - int(u[3] * 0.1 * w)
    x = F.interpolate(x[None, :, top:bottom, left:right], size=(h, w), mode="bicubic", align_corners=False)[0]
    y = F.interpolate(y[None, None, top:bottom, left:right].float(), size=(h, w), mode="nearest")[0, 0].long()
    return x, y


def batches(root, names, args, epoch, gen):
    order = list(range(len(names)))
    if not args.no_shuffle:
        order = torch.randperm(len(names), generator=gen).tolist()
    for start in range(0, len(order), args.batch_size):
        frames = [read_frame(root, names[i]) for i in order[start:start + args.batch_size]]
        if not args.no_augment:
            frames = [augment(x, y, gen) for x, y in frames]
        yield torch.stack([f[0] for f in frames]), torch.stack([f[1] for f in frames])


def train(args):
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    gen = torch.Generator().manual_seed(args.seed)
    net = bench_torch.build(args.model)
    load_into(net, args.init)
    net.train()
    if args.channels_last:
        net = net.to(memory_format=torch.channels_last)
    with open(os.path.join(args.data, args.split + ".txt")) as f:
        names = [line.strip() for line in f if line.strip()]
    optimizer = torch.optim.SGD(net.parameters(), lr=args.lr, momentum=args.momentum,
                                weight_decay=args.weight_decay)
    records, step = [], 0
    for epoch in range(args.epochs):
        lr = args.lr * args.lr_decay ** epoch
        for group in optimizer.param_groups:
            group["lr"] = lr
        for i, (x, y) in enumerate(batches(args.data, names, args, epoch, gen)):
            if args.max_steps is not None and i >= args.max_steps:
                break
            optimizer.zero_grad()
            if args.channels_last:
                x = x.contiguous(memory_format=torch.channels_last)
            loss = F.cross_entropy(net(x), y)
            loss.backward()
            optimizer.step()
            records.append({"epoch": epoch, "step": step, "loss": loss.item()})
            step += 1
    save(net, args.out)
    with open(args.losses, "w") as f:
        json.dump(records, f)
    print(f"reference_train: {step} steps, last loss {records[-1]['loss']:.6f} -> {args.out}")


def init(args):
    torch.manual_seed(args.seed)
    net = bench_torch.build(args.model)
    save(net, args.out)
    print(f"reference_train: {args.model} initial weights (seed {args.seed}) -> {args.out}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    a = sub.add_parser("init", help="write a PyTorch-initialised network's weights")
    a.add_argument("--model", required=True)
    a.add_argument("--seed", type=int, default=0)
    a.add_argument("--out", required=True)
    t = sub.add_parser("train", help="train as the official scripts do")
    t.add_argument("--data", required=True, help="MF-layout root")
    t.add_argument("--split", default="train")
    t.add_argument("--model", required=True, help="mfnet, rtfnet18..rtfnet152")
    t.add_argument("--init", required=True, help="starting weights (safetensors, reference names)")
    t.add_argument("--out", required=True)
    t.add_argument("--losses", required=True)
    t.add_argument("--epochs", type=int, default=2)
    t.add_argument("--batch-size", type=int, default=8)
    t.add_argument("--max-steps", type=int, default=None, help="steps per epoch at most")
    t.add_argument("--lr", type=float, default=0.01)
    t.add_argument("--lr-decay", type=float, default=0.95)
    t.add_argument("--momentum", type=float, default=0.9)
    t.add_argument("--weight-decay", type=float, default=5e-4)
    t.add_argument("--channels-last", action="store_true",
                   help="network and inputs channels_last (as rtf trains fp32 on AVX-512 CPUs), so both sides "
                        "run the same kernels")
    t.add_argument("--no-shuffle", action="store_true")
    t.add_argument("--no-augment", action="store_true")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--threads", type=int, default=torch.get_num_threads())
    args = ap.parse_args()
    {"init": init, "train": train}[args.command](args)


if __name__ == "__main__":
    main()
