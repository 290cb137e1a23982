#!/usr/bin/env python3
"""A PyTorch reference trainer for CMX's official recipe (rtf's `cmx-mf`), written from the facts
of huaaaliu/RGBX_Semantic_Segmentation (crates/rtf-train/src/recipe.rs lists them with their
files) over the network of lab/parity/cmx_reference.py:

- network: CMX with MiT encoders in training mode (stochastic depth, Dropout2d 0.1 before the
  classifier), the decoder's BatchNorm at eps 1e-3 (`config.bn_eps`, set by `init_weight` on
  `decode_head` only), momentum 0.1;
- input: an MF-layout folder (images/NAME.png RGBA, thermal in alpha; labels/NAME.png), the
  official preprocessing (colour in B, G, R order, both modalities normalised with the ImageNet
  mean/std, thermal replicated to 3 channels; cmx_reference.official_inputs);
- loss: cross-entropy, mean over counted pixels, ignore index 255 (`config.background`);
- optimiser: torch.optim.AdamW(lr 6e-5, betas (0.9, 0.999), eps 1e-8) over two groups built as
  `group_weight` builds them, by module type: the weights of nn.Linear and nn.Conv2d with
  weight decay 0.01, their biases and every nn.BatchNorm2d / nn.LayerNorm parameter with none;
- schedule: WarmUpPolyLR per step i of N = epochs x steps per epoch, W = warm-up epochs x steps
  per epoch: lr i / W while i < W, then lr (1 - i / N) ^ 0.9, set before step i (the official
  loop sets it after each step from that step's index: rtf's documented difference);
- order of a step: seed, zero_grad, train-mode forward, loss, backward, step.

Not here: the official augmentation (mirror, random scale, crop with padding) and shuffling;
the step-for-step comparison runs rtf with --no-augment --no-shuffle and this script over the
split file's order in batches. Stochastic depth and dropout draw from libtorch's generator,
seeded before every step with rtf's per-step seed (mix(seed, epoch, step), the SplitMix mixing
of rtf_data::loader::mix), so both sides drop the same samples and channels.

    python lab/parity/reference_train_cmx.py init --size b0 --seed 0 --out init.safetensors
    python lab/parity/reference_train_cmx.py train --data ROOT --size b0 --init init.safetensors \\
        --out ref.safetensors --losses ref_losses.json --epochs 2 --batch-size 2 --warmup-epochs 1

    python lab/parity/reference_train_cmx.py inert --data ROOT --size b0 --init init.safetensors \
        --batch-size 4 --out inert.json

`train` writes the final weights (parameters and BatchNorm statistics), a JSON list of per-step
records {"epoch", "step", "lr", "loss"} (the loss before the step's update) and, with --groups,
the names of the tensors in the decayed group. `inert` lists the parameters whose exact gradient
is zero (the function's docs), which a comparison of updates may set aside.
"""
import argparse
import json
import math
import os
import sys

import torch
import torch.nn as nn
import torch.nn.functional as F

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cmx_reference  # noqa: E402
import reference_train  # noqa: E402

MASK64 = (1 << 64) - 1


def mix(a, b, c):
    """rtf_data::loader::mix: three words into one 64-bit seed (SplitMix64-style)."""
    z = (a ^ (b * 0x9E3779B97F4A7C15) ^ (c * 0xD1B54A32D192ED03)) & MASK64
    for _ in range(2):
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK64
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK64
        z ^= z >> 31
    return z


def official_init(net):
    """The official initialisation: encoder and fusion modules' Linear N(0, 0.02) (timm's
    trunc_normal_ at ±2, i.e. 100 sigma), Conv2d N(0, sqrt(2 / fan_out)), fan_out = k*k*c_out /
    groups, biases 0, LayerNorm 1 / 0; the decoder's convolutions Kaiming-normal (fan-in, ReLU)
    and BatchNorm 1 / 0, its Linear layers PyTorch's default."""
    with torch.no_grad():
        for m in net.backbone.modules():
            if isinstance(m, nn.Linear):
                nn.init.trunc_normal_(m.weight, std=0.02)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, nn.Conv2d):
                fan_out = m.kernel_size[0] * m.kernel_size[1] * m.out_channels // m.groups
                m.weight.normal_(0.0, math.sqrt(2.0 / fan_out))
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, (nn.LayerNorm, nn.BatchNorm2d)):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
        for m in net.decode_head.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_in", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)


def parameter_groups(net, weight_decay):
    """`group_weight`'s two groups, by module type; every parameter lands in one. Returns the
    groups and the names of the decayed tensors."""
    names = {id(p): n for n, p in net.named_parameters()}
    decay, no_decay = [], []
    for m in net.modules():
        if isinstance(m, (nn.Linear, nn.Conv2d)):
            decay.append(m.weight)
            if m.bias is not None:
                no_decay.append(m.bias)
        elif isinstance(m, (nn.BatchNorm2d, nn.LayerNorm, nn.GroupNorm)):
            no_decay += [p for p in (m.weight, m.bias) if p is not None]
    grouped = {id(p) for p in decay + no_decay}
    left = [n for n, p in net.named_parameters() if id(p) not in grouped]
    if left:
        sys.exit(f"reference_train_cmx: parameters in no group: {left}")
    groups = [{"params": decay, "weight_decay": weight_decay}, {"params": no_decay, "weight_decay": 0.0}]
    return groups, sorted(names[id(p)] for p in decay)


def warmup_poly(base, power, warmup, total, i):
    if i < warmup:
        return base * i / warmup
    return base * max(1.0 - i / total, 0.0) ** power


def batches(root, names, batch_size):
    for start in range(0, len(names), batch_size):
        frames = [reference_train.read_frame(root, n) for n in names[start:start + batch_size]]
        yield torch.stack([f[0] for f in frames]), torch.stack([f[1] for f in frames])


def train(args):
    torch.set_num_threads(args.threads)
    net = cmx_reference.Cmx(args.size, args.classes, decoder_bn_eps=args.decoder_bn_eps)
    reference_train.load_into(net, args.init)
    net.train()
    with open(os.path.join(args.data, args.split + ".txt")) as f:
        names = [line.strip() for line in f if line.strip()]
    groups, decayed = parameter_groups(net, args.weight_decay)
    optimizer = torch.optim.AdamW(groups, lr=args.lr, betas=(0.9, 0.999), eps=1e-8, foreach=False)
    steps_per_epoch = math.ceil(len(names) / args.batch_size)
    total, warmup = args.epochs * steps_per_epoch, args.warmup_epochs * steps_per_epoch
    records = []
    for epoch in range(args.epochs):
        for step, (x, y) in enumerate(batches(args.data, names, args.batch_size)):
            i = epoch * steps_per_epoch + step
            lr = warmup_poly(args.lr, args.power, warmup, total, i)
            for group in optimizer.param_groups:
                group["lr"] = lr
            torch.manual_seed(mix(args.seed, epoch, step))
            optimizer.zero_grad()
            logits = net(*cmx_reference.official_inputs(x))
            loss = F.cross_entropy(logits, y, ignore_index=255)
            loss.backward()
            optimizer.step()
            records.append({"epoch": epoch, "step": i, "lr": lr, "loss": loss.item()})
    reference_train.save(net, args.out)
    with open(args.losses, "w") as f:
        json.dump(records, f)
    if args.groups:
        with open(args.groups, "w") as f:
            json.dump({"decay": decayed}, f)
    print(f"reference_train_cmx: {len(records)} steps, last loss {records[-1]['loss']:.6f} -> {args.out}")


def inert(args):
    """The parameters whose gradient is zero in exact arithmetic: a bias that feeds a train-mode
    BatchNorm only through linear maps shifts every sample of a channel alike, and the batch mean
    takes the shift away. In float32 their gradient is rounding alone, which AdamW (dividing by its
    running RMS) turns into full-size steps in a direction no two implementations share. Found by
    measurement, not by name: the first batch's gradient in float64, from --init, where every
    other parameter's largest |gradient| is many orders of magnitude above the threshold."""
    torch.set_num_threads(args.threads)
    net = cmx_reference.Cmx(args.size, args.classes, decoder_bn_eps=args.decoder_bn_eps)
    reference_train.load_into(net, args.init)
    net = net.double().train()
    with open(os.path.join(args.data, args.split + ".txt")) as f:
        names = [line.strip() for line in f if line.strip()]
    x, y = next(batches(args.data, names, args.batch_size))
    torch.manual_seed(mix(args.seed, 0, 0))
    logits = net(*cmx_reference.official_inputs(x.double()))
    F.cross_entropy(logits, y, ignore_index=255).backward()
    largest = {n: float(p.grad.abs().max()) for n, p in net.named_parameters()}
    top = max(largest.values())
    found = sorted(n for n, g in largest.items() if g <= args.relative * top)
    with open(args.out, "w") as f:
        json.dump({"inert": found, "threshold": args.relative * top, "largest_gradient": top,
                   "largest_inert_gradient": max((largest[n] for n in found), default=0.0),
                   "smallest_active_gradient": min(g for n, g in largest.items() if n not in found)}, f, indent=1)
    print(f"reference_train_cmx: {len(found)} inert parameters of {len(largest)} -> {args.out}")


def init(args):
    torch.manual_seed(args.seed)
    net = cmx_reference.Cmx(args.size, args.classes)
    official_init(net)
    reference_train.save(net, args.out)
    print(f"reference_train_cmx: cmx-mit-{args.size} initial weights (seed {args.seed}) -> {args.out}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    a = sub.add_parser("init", help="write an officially initialised network's weights")
    a.add_argument("--size", required=True, choices=sorted(cmx_reference.SIZES))
    a.add_argument("--classes", type=int, default=9)
    a.add_argument("--seed", type=int, default=0)
    a.add_argument("--out", required=True)
    # What `train` and `inert` share: the data, the network and its starting weights.
    run = argparse.ArgumentParser(add_help=False)
    run.add_argument("--data", required=True, help="MF-layout root")
    run.add_argument("--split", default="train")
    run.add_argument("--size", required=True, choices=sorted(cmx_reference.SIZES))
    run.add_argument("--classes", type=int, default=9)
    run.add_argument("--init", required=True, help="starting weights (safetensors, official names)")
    run.add_argument("--batch-size", type=int, default=8)
    run.add_argument("--decoder-bn-eps", type=float, default=1e-3)
    run.add_argument("--seed", type=int, default=0, help="rtf's --seed: the per-step seeds derive from it")
    run.add_argument("--threads", type=int, default=torch.get_num_threads())
    t = sub.add_parser("train", parents=[run], help="train by the official recipe")
    t.add_argument("--out", required=True)
    t.add_argument("--losses", required=True)
    t.add_argument("--groups", help="write the decayed tensors' names here (JSON)")
    t.add_argument("--epochs", type=int, default=500)
    t.add_argument("--lr", type=float, default=6e-5)
    t.add_argument("--weight-decay", type=float, default=0.01)
    t.add_argument("--power", type=float, default=0.9)
    t.add_argument("--warmup-epochs", type=int, default=10)
    n = sub.add_parser("inert", parents=[run],
                       help="list the parameters whose exact gradient is zero (float64, first batch)")
    n.add_argument("--out", required=True, help="JSON: the inert names and the gradients' scale")
    n.add_argument("--relative", type=float, default=1e-9,
                   help="inert: largest |gradient| at most this fraction of the network's largest")
    args = ap.parse_args()
    {"init": init, "train": train, "inert": inert}[args.command](args)


if __name__ == "__main__":
    main()
