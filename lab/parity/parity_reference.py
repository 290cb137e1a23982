#!/usr/bin/env python3
"""Writes a PyTorch reference for rtf's parity test: a randomly initialised network of the
published layout (lab/bench/bench_torch.py) with non-trivial BatchNorm statistics, saved as a
checkpoint the way published weights come (nested under "state_dict", DataParallel "module."
prefixes; MFNet as a legacy non-zip pickle), plus an input and the eval-mode output.

    python lab/parity/parity_reference.py OUT_DIR MODEL [--size 64x96]

Writes OUT_DIR/MODEL.pth and OUT_DIR/MODEL_io.safetensors (tensors "input", "output").
"""
import argparse
import collections
import os
import sys

import torch

HERE = os.path.dirname(os.path.abspath(__file__))
# bench_torch in lab/bench; convert_pth in scripts/
sys.path[:0] = [HERE] + [os.path.join(HERE, d) for d in ("../bench", "../../scripts",)]
import bench_torch  # noqa: E402
import convert_pth  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out_dir")
    ap.add_argument("model")
    ap.add_argument("--size", default="64x96", help="WIDTHxHEIGHT of the input")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    torch.manual_seed(0)
    net = bench_torch.build(args.model)
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.2, 0.2)
                m.running_var.uniform_(0.5, 1.5)
                m.weight.uniform_(0.5, 1.5)
                m.bias.uniform_(-0.2, 0.2)
    net.eval()
    x = torch.rand(2, 4, h, w)
    with torch.no_grad():
        y = net(x)
    os.makedirs(args.out_dir, exist_ok=True)
    state = collections.OrderedDict(("module." + k, v) for k, v in net.state_dict().items())
    checkpoint = {"epoch": 80, "state_dict": state}
    path = os.path.join(args.out_dir, f"{args.model}.pth")
    torch.save(checkpoint, path, _use_new_zipfile_serialization=args.model != "mfnet")
    convert_pth.write_safetensors([("input", x), ("output", y)], os.path.join(args.out_dir, f"{args.model}_io.safetensors"))
    print(f"parity_reference: {path}, output {list(y.shape)}")


if __name__ == "__main__":
    main()
