#!/usr/bin/env python3
"""Trajectory parity of `rtf train` with the PyTorch reference trainer (lab/parity/reference_train.py)
on real frames (issue 27 §3).

1. An MF-layout folder from the MSRS scenes of ../shared/data/msrs-samples (RGB from vi/, the
   8-bit thermal from ir/ in the alpha channel), resized to --size, in frames.txt order; the
   labels are the published MFNet's predictions (`rtf predict` with
   ../shared/data/mf-samples/mfnet_final.safetensors), so nothing large is stored.
2. Per network, one set of starting weights: the published MFNet for mfnet, PyTorch's own
   initialisation (seed 0) for the others.
3. `rtf train --init W --no-shuffle --no-augment --precision fp32` and the reference trainer
   from W, same batches, same schedule: the official code's SGD (momentum 0.9, weight decay
   5e-4) and its ×0.95 per epoch, where rtf's mfnet default is the paper's ×0.94 (set with
   --lr-decay: the code's behaviour through an option). Both sides run on --threads threads:
   a different thread count changes the order of floating-point sums, and a randomly
   initialised RTFNet-18 on small frames amplifies that rounding over a few steps (the
   reference against itself, 1 thread vs 2: 6.5 % after 4 steps at 96×64), which would
   hide what the comparison is for. Likewise the layout: rtf trains fp32 channels-last on
   AVX-512 CPUs, and the reference then runs channels_last too (--layout auto); --layout nchw
   (the test's) runs both sides NCHW, where rtf's RTFNet-18 rounds bit for bit as the
   reference's; channels-last kernels round otherwise, and its 4-step updates then drift
   2.3 % apart even against a channels_last reference (1 thread, 96×64).
4. Prints one JSON object per network: the relative difference of the weight updates
   ‖Δrtf − Δref‖ / ‖Δref‖ over every parameter and BatchNorm statistic, and the largest
   relative difference of the per-step losses.

5. With --adversarial NETS: one HeatNet adversarial stage per network (scripts/
   reference_train_heatnet.py against `rtf train --recipe heatnet-v5 --critic-code`, the
   published code's critic procedure through an option), on --frames/2 day and --frames/2
   night scenes, from the same network and critic weights (--init, --critic-init), the
   published MFNet as the day teacher, RMSprop 1e-4, λ 0.01: the update differences of the
   segmentation network (with and without BatchNorm statistics) and of the critic, and the
   per-step losses (critic steps: the critic's loss).

6. With --cmx SIZES: CMX's official recipe per MiT size (`rtf train --recipe cmx-mf --model
   cmx-mit-SIZE` against lab/parity/reference_train_cmx.py), from the same officially initialised
   weights, no shuffle, no augmentation, fp32: AdamW with weight decay on convolution and linear
   weights only, --warmup-epochs of linear warm-up then poly 0.9 per step, training-mode
   stochastic depth and dropout drawn from the same per-step seeds, the decoder's BatchNorm at
   eps 1e-3: the update differences (with and without BatchNorm statistics), the per-step
   losses and learning rates, and whether both sides decay the same tensors.

    .venv/bin/python lab/parity/parity_train.py --rtf target/release/rtf --work /tmp/parity \\
        --models mfnet,rtfnet18 --frames 48 --size 160x128 --epochs 2 --batch-size 4 \\
        --adversarial mfnet --cmx b0
"""
import argparse
import json
import os
import subprocess
import sys

import numpy as np
import torch
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import reference_train  # noqa: E402

SHARED = os.path.join(HERE, "..", "..", "shared", "data")
MFNET_WEIGHTS = "mf-samples/mfnet_final.safetensors"


def build_dataset(args, root, balanced=False):
    """MF layout from the first --frames MSRS scenes (balanced: the first --frames/2 day and
    night scenes, in frames.txt order), resized, labelled by the published MFNet."""
    msrs = os.path.join(args.shared, "msrs-samples")
    with open(os.path.join(msrs, "frames.txt")) as f:
        names = [line.strip() for line in f if line.strip()]
    if balanced:
        half = args.frames // 2
        chosen = set([n for n in names if n.endswith("D")][:half] + [n for n in names if n.endswith("N")][:half])
        names = [n for n in names if n in chosen]
    else:
        names = names[: args.frames]
    w, h = args.size
    os.makedirs(os.path.join(root, "images"), exist_ok=True)
    for name in names:
        rgb = Image.open(os.path.join(msrs, "vi", name + ".png")).convert("RGB").resize((w, h), Image.BILINEAR)
        ir = Image.open(os.path.join(msrs, "ir", name + ".png")).convert("L").resize((w, h), Image.BILINEAR)
        rgba = np.concatenate([np.asarray(rgb), np.asarray(ir)[:, :, None]], axis=2)
        Image.fromarray(rgba, "RGBA").save(os.path.join(root, "images", name + ".png"))
    images = [os.path.join(root, "images", n + ".png") for n in names]
    run([args.rtf, "predict", "--weights", os.path.join(args.shared, MFNET_WEIGHTS),
         "--out", os.path.join(root, "predicted"), *images])
    os.makedirs(os.path.join(root, "labels"), exist_ok=True)
    for name in names:
        os.replace(os.path.join(root, "predicted", name + ".png"), os.path.join(root, "labels", name + ".png"))
    for split in ["train", "val", "test"]:
        with open(os.path.join(root, split + ".txt"), "w") as f:
            f.write("".join(n + "\n" for n in names))
    return names


def rtf_fp32_channels_last():
    """Whether rtf trains fp32 channels-last here (rtf_train::procedure::fp32_channels_last_here:
    RTF_TRAIN_LAYOUT=nchw/nhwc, else where the CPU has avx512f): the reference then runs
    channels_last too, so both sides take the same kernels and round alike (a randomly initialised
    RTFNet-18 amplifies any difference in rounding, see docs/src/training.md)."""
    layout = os.environ.get("RTF_TRAIN_LAYOUT")
    if layout in ("nchw", "nhwc"):
        return layout == "nhwc"
    with open("/proc/cpuinfo") as f:
        flags = next((line.split(":", 1)[1].split() for line in f if line.startswith("flags")), [])
    return "avx512f" in flags


def run(cmd, threads=None):
    env = dict(os.environ)
    if threads is not None:
        # libtorch reads it at start-up (rtf); the reference calls torch.set_num_threads.
        env["OMP_NUM_THREADS"] = str(threads)
    done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if done.returncode != 0:
        sys.exit(f"parity_train: {' '.join(cmd)} failed ({done.returncode}):\n{done.stderr[-4000:]}")
    return done.stdout


def relative_update_difference(init, rtf, ref, parameters_only=False, leave_out=()):
    """‖Δrtf − Δref‖ / ‖Δref‖ over every tensor of the reference (num_batches_tracked aside;
    parameters_only: BatchNorm's running statistics aside too; leave_out: these names aside)."""
    diff, norm = 0.0, 0.0
    for name, w0 in init.items():
        if name.endswith("num_batches_tracked") or name in leave_out:
            continue
        if parameters_only and name.endswith(("running_mean", "running_var")):
            continue
        d_rtf = rtf[name].double() - w0.double()
        d_ref = ref[name].double() - w0.double()
        diff += float(((d_rtf - d_ref) ** 2).sum())
        norm += float((d_ref ** 2).sum())
    return (diff / norm) ** 0.5


def one_network(args, data, model):
    work = os.path.join(args.work, model)
    os.makedirs(work, exist_ok=True)
    init = os.path.join(work, "init.safetensors")
    if model == "mfnet":
        init = os.path.join(args.shared, MFNET_WEIGHTS)
    else:
        run([sys.executable, os.path.join(HERE, "reference_train.py"), "init", "--model", model, "--out", init])
    schedule = ["--epochs", str(args.epochs), "--batch-size", str(args.batch_size), "--lr", "0.01",
                "--lr-decay", "0.95", "--momentum", "0.9", "--weight-decay", "5e-4"]
    rtf_run = os.path.join(work, "rtf")
    final = run([args.rtf, "train", "--data", data, "--out", rtf_run, "--model", model, "--init", init,
                 "--no-shuffle", "--no-augment", "--precision", "fp32", "--val-split", "none",
                 "--tb-images-every", "0", "--workers", "1", *schedule], args.threads).strip()
    ref_weights, ref_losses = os.path.join(work, "ref.safetensors"), os.path.join(work, "ref_losses.json")
    run([sys.executable, os.path.join(HERE, "reference_train.py"), "train", "--data", data, "--model", model,
         "--init", init, "--out", ref_weights, "--losses", ref_losses, "--no-shuffle", "--no-augment",
         "--threads", str(args.threads), *schedule] + (["--channels-last"] if rtf_fp32_channels_last() else []),
        args.threads)
    with open(os.path.join(rtf_run, "steps.jsonl")) as f:
        rtf_steps = [json.loads(line)["loss"] for line in f]
    with open(ref_losses) as f:
        ref_steps = [r["loss"] for r in json.load(f)]
    if len(rtf_steps) != len(ref_steps):
        sys.exit(f"parity_train: {model}: rtf took {len(rtf_steps)} steps, the reference {len(ref_steps)}")
    loss_rel = max(abs(a - b) / abs(b) for a, b in zip(rtf_steps, ref_steps))
    update_rel = relative_update_difference(
        reference_train.read_safetensors(init), reference_train.read_safetensors(final),
        reference_train.read_safetensors(ref_weights))
    return {"model": model, "steps": len(ref_steps), "update_rel_diff": update_rel,
            "max_loss_rel_diff": loss_rel, "rtf_losses": rtf_steps, "ref_losses": ref_steps,
            "init": init, "rtf_final": final, "ref_final": ref_weights}


def adversarial(args, data, model):
    """One HeatNet adversarial stage: `rtf train --recipe heatnet-v5 --critic-code` (the
    published code's critic procedure, where rtf's default is the paper's) against
    lab/parity/reference_train_heatnet.py, both from the same network and critic weights, the
    published MFNet as the day teacher, RMSprop 1e-4, λ 0.01."""
    work = os.path.join(args.work, "adversarial-" + model)
    os.makedirs(work, exist_ok=True)
    ref_script = os.path.join(HERE, "reference_train_heatnet.py")
    init, critic_init = os.path.join(work, "init.safetensors"), os.path.join(work, "critic_init.safetensors")
    run([sys.executable, os.path.join(HERE, "reference_train.py"), "init", "--model", model, "--out", init])
    run([sys.executable, ref_script, "init-critic", "--classes", "9", "--out", critic_init])
    teacher = os.path.join(args.shared, MFNET_WEIGHTS)
    schedule = ["--epochs", str(args.epochs), "--batch-size", str(args.batch_size), "--lr", "1e-4",
                "--lambda", "0.01"]
    rtf_run = os.path.join(work, "rtf")
    run([args.rtf, "train", "--recipe", "heatnet-v5", "--model", model, "--data", data, "--out", rtf_run,
         "--teacher", teacher, "--teacher-model", "mfnet", "--init", init, "--critic-init", critic_init,
         *(["--critic-code"] if args.rtf_critic == "code" else []), "--no-shuffle", "--no-augment", "--precision", "fp32", "--val-split", "none",
         "--tb-images-every", "0", "--workers", "1", *schedule], args.threads)
    stage = os.path.join(rtf_run, "v5")
    ref = {k: os.path.join(work, f) for k, f in
           [("net", "ref.safetensors"), ("critic", "ref_critic.safetensors"), ("losses", "ref_losses.json")]}
    run([sys.executable, ref_script, "train", "--data", data, "--model", model, "--init", init,
         "--critic-init", critic_init, "--teacher", teacher, "--teacher-model", "mfnet", "--out", ref["net"],
         "--critic-out", ref["critic"], "--losses", ref["losses"], "--threads", str(args.threads), *schedule],
        args.threads)
    with open(os.path.join(stage, "steps.jsonl")) as f:
        rtf_steps = [json.loads(line)["loss"] for line in f]
    with open(ref["losses"]) as f:
        ref_records = json.load(f)
    ref_steps = [r["loss"] for r in ref_records]
    if len(rtf_steps) != len(ref_steps) and args.rtf_critic == "code":
        sys.exit(f"parity_train: adversarial: rtf took {len(rtf_steps)} steps, the reference {len(ref_steps)}")
    checkpoint = reference_train.read_safetensors(os.path.join(stage, "checkpoint.safetensors"))
    rtf_critic = {k[len("critic/w/"):]: v for k, v in checkpoint.items() if k.startswith("critic/w/")}
    read = reference_train.read_safetensors
    weights = (read(init), read(os.path.join(stage, "final.safetensors")), read(ref["net"]))
    return {"model": model, "procedure": "adversarial", "rtf_critic": args.rtf_critic, "steps": len(ref_steps),
            "update_rel_diff": relative_update_difference(*weights),
            "update_rel_diff_parameters": relative_update_difference(*weights, parameters_only=True),
            "critic_update_rel_diff": relative_update_difference(read(critic_init), rtf_critic, read(ref["critic"])),
            "max_loss_rel_diff": max(abs(a - b) / abs(b) for a, b in zip(rtf_steps, ref_steps)),
            "phases": [r["phase"] for r in ref_records], "rtf_losses": rtf_steps, "ref_losses": ref_steps,
            "init": init, "critic_init": critic_init, "rtf_run": stage, "ref_final": ref["net"],
            "ref_critic": ref["critic"]}


def inert_parameters(args, data, size, init, work):
    """The parameters whose exact gradient is zero (reference_train_cmx.py inert): their updates
    are rounding that AdamW scales to full steps, on either side."""
    out = os.path.join(work, "inert.json")
    run([sys.executable, os.path.join(HERE, "reference_train_cmx.py"), "inert", "--data", data, "--size", size,
         "--init", init, "--batch-size", str(args.batch_size), "--out", out], args.threads)
    with open(out) as f:
        return json.load(f)["inert"]


def largest_differences(init, rtf, ref, top=6):
    """The tensors with the largest share of ‖Δrtf − Δref‖², with their own relative difference."""
    rows = []
    for name, w0 in init.items():
        if name.endswith("num_batches_tracked"):
            continue
        d_rtf, d_ref = rtf[name].double() - w0.double(), ref[name].double() - w0.double()
        diff, norm = float(((d_rtf - d_ref) ** 2).sum()), float((d_ref ** 2).sum())
        rows.append((diff, name, (diff / norm) ** 0.5 if norm > 0 else float("inf")))
    total = sum(r[0] for r in rows) or 1.0
    return [{"name": n, "share": d / total, "rel_diff": r} for d, n, r in sorted(rows, reverse=True)[:top]]


def cmx(args, data, size):
    """CMX's official recipe, rtf (`--recipe cmx-mf`) against lab/parity/reference_train_cmx.py."""
    work = os.path.join(args.work, "cmx-" + size)
    os.makedirs(work, exist_ok=True)
    ref_script = os.path.join(HERE, "reference_train_cmx.py")
    init = os.path.join(work, "init.safetensors")
    run([sys.executable, ref_script, "init", "--size", size, "--out", init])
    schedule = ["--epochs", str(args.epochs), "--batch-size", str(args.batch_size),
                "--warmup-epochs", str(args.warmup_epochs)]
    rtf_run = os.path.join(work, "rtf")
    final = run([args.rtf, "train", "--recipe", "cmx-mf", "--model", "cmx-mit-" + size, "--data", data,
                 "--out", rtf_run, "--init", init, "--no-shuffle", "--no-augment", "--precision", "fp32",
                 "--val-split", "none", "--tb-images-every", "0", "--workers", "1", "--seed", "0", *schedule],
                args.threads).strip()
    ref = {k: os.path.join(work, f) for k, f in
           [("net", "ref.safetensors"), ("losses", "ref_losses.json"), ("groups", "ref_groups.json")]}
    run([sys.executable, ref_script, "train", "--data", data, "--size", size, "--init", init, "--out", ref["net"],
         "--losses", ref["losses"], "--groups", ref["groups"], "--seed", "0", "--threads", str(args.threads),
         *schedule], args.threads)
    with open(os.path.join(rtf_run, "steps.jsonl")) as f:
        rtf_steps = [json.loads(line)["loss"] for line in f]
    with open(ref["losses"]) as f:
        ref_records = json.load(f)
    ref_steps = [r["loss"] for r in ref_records]
    if len(rtf_steps) != len(ref_steps):
        sys.exit(f"parity_train: cmx-{size}: rtf took {len(rtf_steps)} steps, the reference {len(ref_steps)}")
    read = reference_train.read_safetensors
    weights = (read(init), read(final), read(ref["net"]))
    inert = inert_parameters(args, data, size, init, work)
    return {"model": "cmx-mit-" + size, "recipe": "cmx-mf", "steps": len(ref_steps),
            "update_rel_diff": relative_update_difference(*weights),
            "update_rel_diff_parameters": relative_update_difference(*weights, parameters_only=True),
            "inert_parameters": inert,
            "update_rel_diff_active": relative_update_difference(*weights, leave_out=set(inert)),
            "largest_differences": largest_differences(*weights),
            "max_loss_rel_diff": max(abs(a - b) / abs(b) for a, b in zip(rtf_steps, ref_steps)),
            "rtf_losses": rtf_steps, "ref_losses": ref_steps, "ref_lrs": [r["lr"] for r in ref_records],
            "init": init, "rtf_final": final, "ref_final": ref["net"], "ref_groups": ref["groups"],
            "rtf_config": os.path.join(rtf_run, "config.json")}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rtf", required=True, help="the rtf binary")
    ap.add_argument("--work", required=True, help="scratch folder (created)")
    ap.add_argument("--shared", default=SHARED, help="the shared data folder")
    ap.add_argument("--models", default="mfnet,rtfnet18")
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--size", default="160x128", type=lambda s: tuple(int(v) for v in s.lower().split("x")))
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--batch-size", type=int, default=4)
    ap.add_argument("--threads", type=int, default=torch.get_num_threads())
    ap.add_argument("--layout", choices=["auto", "nchw", "nhwc"], default="auto",
                    help="fp32 training layout of both sides: auto = rtf's on this CPU (channels-last "
                         "with AVX-512), the reference matched")
    ap.add_argument("--adversarial", default="",
                    help="segmentation networks for one HeatNet adversarial stage each (e.g. mfnet), "
                         "on --frames/2 day and --frames/2 night scenes")
    ap.add_argument("--cmx", default="", help="MiT sizes (e.g. b0) for one run of CMX's official recipe each")
    ap.add_argument("--warmup-epochs", type=int, default=1, help="CMX's warm-up (the recipe's: 10)")
    ap.add_argument("--rtf-critic", choices=["code", "paper"], default="code",
                    help="rtf's critic procedure: the published code's (--critic-code, the parity run) or the "
                         "paper's (rtf's default; a control: it should not agree)")
    args = ap.parse_args()
    if args.layout != "auto":
        # rtf reads it (rtf_train::procedure::fp32_channels_last_here); so does the reference's flag.
        os.environ["RTF_TRAIN_LAYOUT"] = args.layout
    data = os.path.join(args.work, "data")
    names = build_dataset(args, data) if args.models or args.cmx else []
    results = [one_network(args, data, m) for m in args.models.split(",") if m]
    results += [cmx(args, data, size) for size in args.cmx.split(",") if size]
    if args.adversarial:
        balanced = os.path.join(args.work, "data-day-night")
        names = build_dataset(args, balanced, balanced=True)
        results += [adversarial(args, balanced, m) for m in args.adversarial.split(",")]
    print(json.dumps({"frames": len(names), "size": list(args.size), "epochs": args.epochs,
                      "batch_size": args.batch_size, "results": results}))


if __name__ == "__main__":
    main()
