#!/usr/bin/env python3
"""A PyTorch reference for one HeatNet adversarial stage, written from the published training
loop as the project's spec states it (../shared/spec/README.md §5; issue 27), for parity runs
against `rtf train --critic-code`. The segmentation network is any of lab/bench/bench_torch.py's
(procedures are network-agnostic; parity runs use a light one), the critic HeatNet's.

- data: an MF-layout folder (reference_train.read_frame); the day frames are the split's names
  ending in D, the night frames those ending in N, each in split order; an epoch is one pass
  over the day batches, the night batches continue across epochs and cycle (no shuffle, no
  augmentation, the last partial batch kept: use counts divisible by the batch size);
- day targets: the day teacher's labels, its eval-mode arg-max on each day batch;
- critic: five 4×4 stride-2 convolutions with bias (in→64→128→256→512→1), LeakyReLU(0.2)
  after the first four, bilinear ×32 (`conv1` … `classifier`, the published names); it reads
  the segmentation network's raw logits (the code's choice; the paper's softmax is rtf's
  default);
- the loop, as the published code runs it with phases of one step: every iteration takes the
  next day and night batch, runs the segmentation network in training mode on both (day first),
  scores both outputs with the critic, and then
  * critic step (first, and every other iteration): MSE(C(day), 1) + MSE(C(night), 0) — the
    code's targets, flipped from the paper's — with the segmentation network frozen;
  * segmentation step: CE(day logits, teacher labels) + λ·[MSE(C(night), 1) + MSE(C(day), 1)]
    — night outputs pushed to the day side and, as the code does without --multidir, day
    outputs kept there — with the critic frozen;
  phases switch by `requires_grad`, one RMSprop (PyTorch defaults: alpha 0.99, eps 1e-8, no
  momentum) over both networks at one learning rate (PyTorch ≥ 2 leaves the frozen network's
  parameters and state alone: their gradients are None);
- λ = 0.01 (the spec's; the code's default --conf_weight is 0.1).

    python lab/parity/reference_train_heatnet.py init-critic --classes 9 --seed 0 --out critic.safetensors
    python lab/parity/reference_train_heatnet.py train --data ROOT --model mfnet --init S.safetensors \\
        --critic-init critic.safetensors --teacher T.safetensors --teacher-model mfnet \\
        --out ref.safetensors --critic-out ref_critic.safetensors --losses ref_losses.json \\
        --epochs 2 --batch-size 2 --threads 1

`train` writes both networks' final weights (parameters and BatchNorm statistics) and a JSON
list of per-step records {"epoch", "step", "phase", "loss"} (critic steps: the critic's loss;
segmentation steps: the segmentation network's whole objective; before the step's update).
"""
import argparse
import json
import os
import sys

import torch
import torch.nn as nn
import torch.nn.functional as F

HERE = os.path.dirname(os.path.abspath(__file__))
# bench_torch in lab/bench
sys.path[:0] = [HERE] + [os.path.join(HERE, d) for d in ("../bench",)]
import bench_torch  # noqa: E402
import reference_train  # noqa: E402


class Critic(nn.Module):
    """HeatNet's critic (spec §5), published parameter names."""

    def __init__(self, n_class):
        super().__init__()
        self.conv1 = nn.Conv2d(n_class, 64, 4, stride=2, padding=1)
        self.conv2 = nn.Conv2d(64, 128, 4, stride=2, padding=1)
        self.conv3 = nn.Conv2d(128, 256, 4, stride=2, padding=1)
        self.conv4 = nn.Conv2d(256, 512, 4, stride=2, padding=1)
        self.classifier = nn.Conv2d(512, 1, 4, stride=2, padding=1)

    def forward(self, x):
        for conv in (self.conv1, self.conv2, self.conv3, self.conv4):
            x = F.leaky_relu(conv(x), 0.2)
        return F.interpolate(self.classifier(x), scale_factor=32, mode="bilinear", align_corners=False)


def set_learning(net, on):
    for p in net.parameters():
        p.requires_grad = on


def split_names(args):
    with open(os.path.join(args.data, args.split + ".txt")) as f:
        names = [line.strip() for line in f if line.strip()]
    day = [n for n in names if n.endswith("D")]
    night = [n for n in names if n.endswith("N")]
    if not day or not night:
        sys.exit(f"reference_train_heatnet: {args.split}.txt needs day (…D) and night (…N) frames")
    return day, night


def batch_of(args, names):
    return torch.stack([reference_train.read_frame(args.data, n)[0] for n in names])


def batches(names, size):
    return [names[i:i + size] for i in range(0, len(names), size)]


def step_losses(args, net, critic, teacher, day, night, critic_turn):
    """The iteration's forward passes and the loss of its phase."""
    day_logits, night_logits = net(day), net(night)
    day_scores, night_scores = critic(day_logits), critic(night_logits)
    if critic_turn:
        return F.mse_loss(day_scores, torch.ones_like(day_scores)) + \
            F.mse_loss(night_scores, torch.zeros_like(night_scores))
    with torch.no_grad():
        labels = teacher(day).argmax(1)
    adversarial = F.mse_loss(night_scores, torch.ones_like(night_scores)) + \
        F.mse_loss(day_scores, torch.ones_like(day_scores))
    return F.cross_entropy(day_logits, labels) + args.lam * adversarial


def train(args):
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    net = bench_torch.build(args.model)
    reference_train.load_into(net, args.init)
    teacher = bench_torch.build(args.teacher_model)
    reference_train.load_into(teacher, args.teacher)
    teacher.eval()
    set_learning(teacher, False)
    critic = Critic(args.classes)
    reference_train.load_into(critic, args.critic_init)
    net.train()
    critic.train()
    optimizer = torch.optim.RMSprop(list(net.parameters()) + list(critic.parameters()), lr=args.lr)
    day_names, night_names = split_names(args)
    day_batches, night_batches = batches(day_names, args.batch_size), batches(night_names, args.batch_size)
    records, step = [], 0
    for epoch in range(args.epochs):
        for i, day in enumerate(day_batches):
            critic_turn = step % 2 == 0
            set_learning(critic, critic_turn)
            set_learning(net, not critic_turn)
            night = night_batches[step % len(night_batches)]
            optimizer.zero_grad()
            loss = step_losses(args, net, critic, teacher, batch_of(args, day), batch_of(args, night), critic_turn)
            loss.backward()
            optimizer.step()
            records.append({"epoch": epoch, "step": step, "phase": "critic" if critic_turn else "segmentation",
                            "loss": loss.item()})
            step += 1
    set_learning(net, True)
    set_learning(critic, True)
    reference_train.save(net, args.out)
    reference_train.save(critic, args.critic_out)
    with open(args.losses, "w") as f:
        json.dump(records, f)
    print(f"reference_train_heatnet: {step} steps, last loss {records[-1]['loss']:.6f} -> {args.out}, {args.critic_out}")


def init_critic(args):
    torch.manual_seed(args.seed)
    reference_train.save(Critic(args.classes), args.out)
    print(f"reference_train_heatnet: critic for {args.classes} classes (seed {args.seed}) -> {args.out}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    a = sub.add_parser("init-critic", help="write a PyTorch-initialised critic's weights")
    a.add_argument("--classes", type=int, required=True)
    a.add_argument("--seed", type=int, default=0)
    a.add_argument("--out", required=True)
    t = sub.add_parser("train", help="one adversarial stage as the published code runs it")
    t.add_argument("--data", required=True, help="MF-layout root")
    t.add_argument("--split", default="train")
    t.add_argument("--model", required=True, help="the segmentation network (mfnet, rtfnet18, ...)")
    t.add_argument("--init", required=True, help="its starting weights (safetensors, reference names)")
    t.add_argument("--critic-init", required=True, help="the critic's starting weights")
    t.add_argument("--classes", type=int, default=9, help="the network's classes, the critic's inputs")
    t.add_argument("--teacher", required=True, help="the day teacher's weights")
    t.add_argument("--teacher-model", required=True)
    t.add_argument("--out", required=True)
    t.add_argument("--critic-out", required=True)
    t.add_argument("--losses", required=True)
    t.add_argument("--epochs", type=int, default=2)
    t.add_argument("--batch-size", type=int, default=2)
    t.add_argument("--lr", type=float, default=1e-4)
    t.add_argument("--lambda", dest="lam", type=float, default=0.01)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--threads", type=int, default=torch.get_num_threads())
    args = ap.parse_args()
    {"init-critic": init_critic, "train": train}[args.command](args)


if __name__ == "__main__":
    main()
