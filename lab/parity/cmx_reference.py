#!/usr/bin/env python3
"""PyTorch reference of CMX (Zhang et al., IEEE T-ITS 2023) for rtf's parity test: the RGB-X
dual SegFormer (MiT-B0…B5) with the Feature Rectify and Feature Fusion modules at every stage
and the MLP decoder, as the official repository huaaaliu/RGBX_Semantic_Segmentation builds it
for MF (9 classes, decoder width 512, BatchNorm2d), with its state_dict names. Written here
from that code's facts; needs torch only.

    python lab/parity/cmx_reference.py --count
    python lab/parity/cmx_reference.py OUT_DIR b0 [--frame PNG] [--crop HxW] [--seed N]

--count prints every size's trainable parameter count for 9 classes (the numbers in
crates/rtf-models/src/cmx.rs). Otherwise: a seeded random network (PyTorch's default init, the
decoder's convolutions Kaiming-normal as the official trainer initialises them, then random
LayerNorm/BatchNorm affines and BatchNorm running statistics, so no parameter is left at a
neutral value) in eval mode, saved as the official trainer saves checkpoints
(OUT_DIR/cmx-mit-SIZE.pth, the state_dict under "model"), and OUT_DIR/cmx-mit-SIZE_io.safetensors:
"input" = the frame as rtf feeds networks ([1, 4, H, W]: R, G, B, T in [0, 1]) and "output" =
the logits. The frame goes through the official pipeline's preprocessing first: OpenCV reads the
colour image in B, G, R order (cv2.imread with flag 4), both modalities are scaled to [0, 1] and
normalised with the ImageNet mean/std per channel, the thermal image replicated to 3 channels.

Training mode (lab/parity/reference_train_cmx.py) has the official stochastic depth (per-block
rates `linspace(0, 0.1, Σ depths)`, stage 2's RGB blocks all at the stage's first rate and its
thermal blocks at the second, as the official `dual_segformer.py` indexes `dpr`) and Dropout2d
(0.1) before the classifier; eval mode has neither. The drop-path mask is drawn as
`torch.empty(B, 1, 1).bernoulli_(keep)` (timm floors `keep + rand`: the same distribution), the
draw rtf makes, so that both sides seeded alike drop the same samples. `decoder_bn_eps` sets the
decoder's BatchNorm eps (the official training's `config.bn_eps = 1e-3`).

Differences from the official code: mit_b1 is SegFormer's B1 (the official builder's mit_b1
branch builds B0's encoder with B1's channel list, which cannot run).

The module tree mirrors the official code's (same modules, same computation order, same
state_dict names), so lab/bench/bench_torch.py and lab/bench/bench_torch_train.py time it as the
official network's PyTorch peer; the official code's extra `.contiguous()` copies in the
cross-attention are left out (they change no value).
"""
import argparse
import os
import struct
import sys
import zlib

import torch
import torch.nn as nn
import torch.nn.functional as F

HERE = os.path.dirname(os.path.abspath(__file__))
# convert_pth in scripts/
sys.path[:0] = [HERE] + [os.path.join(HERE, d) for d in ("../../scripts",)]
import convert_pth  # noqa: E402

# SegFormer MiT layouts: embed dims and blocks per stage.
SIZES = {
    "b0": ([32, 64, 160, 256], [2, 2, 2, 2]),
    "b1": ([64, 128, 320, 512], [2, 2, 2, 2]),
    "b2": ([64, 128, 320, 512], [3, 4, 6, 3]),
    "b3": ([64, 128, 320, 512], [3, 4, 18, 3]),
    "b4": ([64, 128, 320, 512], [3, 8, 27, 3]),
    "b5": ([64, 128, 320, 512], [3, 6, 40, 3]),
}
HEADS = [1, 2, 5, 8]
SR_RATIOS = [8, 4, 2, 1]
MLP_RATIO = 4
DECODER_DIM = 512
IMAGENET_MEAN = [0.485, 0.456, 0.406]
IMAGENET_STD = [0.229, 0.224, 0.225]
DROP_PATH_RATE = 0.1
DECODER_DROPOUT = 0.1


def tokens(x):
    """[B, C, H, W] -> [B, H*W, C]"""
    return x.flatten(2).transpose(1, 2)


def feature_map(x, h, w):
    """[B, H*W, C] -> [B, C, H, W]"""
    return x.transpose(1, 2).reshape(x.shape[0], -1, h, w)


class PatchEmbed(nn.Module):
    """Overlapping patch embedding: strided conv, then LayerNorm (eps 1e-5) over tokens."""

    def __init__(self, c_in, dim, kernel, stride):
        super().__init__()
        self.proj = nn.Conv2d(c_in, dim, kernel, stride, kernel // 2)
        self.norm = nn.LayerNorm(dim)

    def forward(self, x):
        x = self.proj(x)
        h, w = x.shape[2:]
        return self.norm(tokens(x)), h, w


class EfficientAttention(nn.Module):
    """Multi-head attention whose keys/values come from a map reduced by a stride-sr conv."""

    def __init__(self, dim, heads, sr):
        super().__init__()
        self.heads = heads
        self.q = nn.Linear(dim, dim)
        self.kv = nn.Linear(dim, 2 * dim)
        self.proj = nn.Linear(dim, dim)
        self.sr_ratio = sr
        if sr > 1:
            self.sr = nn.Conv2d(dim, dim, sr, sr)
            self.norm = nn.LayerNorm(dim)

    def forward(self, x, h, w):
        b, n, c = x.shape
        d = c // self.heads
        q = self.q(x).reshape(b, n, self.heads, d).transpose(1, 2)
        src = x
        if self.sr_ratio > 1:
            src = self.norm(tokens(self.sr(feature_map(x, h, w))))
        k, v = self.kv(src).reshape(b, -1, 2, self.heads, d).permute(2, 0, 3, 1, 4)
        attn = torch.softmax(q @ k.transpose(-2, -1) * d ** -0.5, dim=-1)
        return self.proj((attn @ v).transpose(1, 2).reshape(b, n, c))


class DepthWise(nn.Module):
    def __init__(self, dim):
        super().__init__()
        self.dwconv = nn.Conv2d(dim, dim, 3, 1, 1, groups=dim)

    def forward(self, x, h, w):
        return tokens(self.dwconv(feature_map(x, h, w)))


class MixFfn(nn.Module):
    def __init__(self, dim, hidden):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.dwconv = DepthWise(hidden)
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x, h, w):
        return self.fc2(F.gelu(self.dwconv(self.fc1(x), h, w)))


def drop_path(x, rate, training):
    """Stochastic depth on a residual branch [B, N, C]: each sample's branch dropped with
    probability `rate` in training, the kept ones scaled by 1 / (1 - rate)."""
    if not training or rate <= 0.0:
        return x
    keep = 1.0 - rate
    mask = torch.empty(x.shape[0], 1, 1, dtype=x.dtype).bernoulli_(keep)
    return x * (mask / keep)


def drop_path_rates(depths, stage, thermal):
    """The official per-block rates of one stream's stage (0-based)."""
    total = sum(depths)
    rate = lambda i: DROP_PATH_RATE * i / max(total - 1, 1)  # noqa: E731
    first = sum(depths[:stage])
    if stage == 1:
        return [rate(first + (1 if thermal else 0))] * depths[stage]
    return [rate(first + j) for j in range(depths[stage])]


class Block(nn.Module):
    """Pre-norm transformer block, LayerNorm eps 1e-6."""

    def __init__(self, dim, heads, sr, drop_path_rate=0.0):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=1e-6)
        self.attn = EfficientAttention(dim, heads, sr)
        self.norm2 = nn.LayerNorm(dim, eps=1e-6)
        self.mlp = MixFfn(dim, dim * MLP_RATIO)
        self.drop_path_rate = drop_path_rate

    def forward(self, x, h, w):
        x = x + drop_path(self.attn(self.norm1(x), h, w), self.drop_path_rate, self.training)
        return x + drop_path(self.mlp(self.norm2(x), h, w), self.drop_path_rate, self.training)


class ChannelWeights(nn.Module):
    def __init__(self, dim):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(4 * dim, 4 * dim), nn.ReLU(), nn.Linear(4 * dim, 2 * dim), nn.Sigmoid())

    def forward(self, x1, x2):
        x = torch.cat([x1, x2], 1)
        pooled = torch.cat([x.mean((2, 3)), x.amax((2, 3))], 1)
        return self.mlp(pooled).view(x.shape[0], 2, -1, 1, 1).unbind(1)


class SpatialWeights(nn.Module):
    def __init__(self, dim):
        super().__init__()
        self.mlp = nn.Sequential(nn.Conv2d(2 * dim, dim, 1), nn.ReLU(), nn.Conv2d(dim, 2, 1), nn.Sigmoid())

    def forward(self, x1, x2):
        return self.mlp(torch.cat([x1, x2], 1)).unsqueeze(2).unbind(1)


class Rectify(nn.Module):
    """FRM: each stream gains the other weighted by channel and spatial weights (λ = 0.5)."""

    def __init__(self, dim):
        super().__init__()
        self.channel_weights = ChannelWeights(dim)
        self.spatial_weights = SpatialWeights(dim)

    def forward(self, x1, x2):
        c0, c1 = self.channel_weights(x1, x2)
        s0, s1 = self.spatial_weights(x1, x2)
        return x1 + 0.5 * c1 * x2 + 0.5 * s1 * x2, x2 + 0.5 * c0 * x1 + 0.5 * s0 * x1


class CrossAttention(nn.Module):
    """Each stream's queries read the other stream's global context softmax(Kᵀ V · d^-½) (softmax
    over the key dimension); key/value projections without bias."""

    def __init__(self, dim, heads):
        super().__init__()
        self.heads = heads
        self.kv1 = nn.Linear(dim, 2 * dim, bias=False)
        self.kv2 = nn.Linear(dim, 2 * dim, bias=False)

    def forward(self, x1, x2):
        b, n, c = x1.shape
        d = c // self.heads

        def heads(x):
            return x.reshape(b, n, self.heads, d).transpose(1, 2)

        def context(kv, x):
            k, v = kv(x).reshape(b, n, 2, self.heads, d).permute(2, 0, 3, 1, 4)
            return torch.softmax(k.transpose(-2, -1) @ v * d ** -0.5, dim=-2)

        ctx1, ctx2 = context(self.kv1, x1), context(self.kv2, x2)
        merge = lambda y: y.transpose(1, 2).reshape(b, n, c)  # noqa: E731
        return merge(heads(x1) @ ctx2), merge(heads(x2) @ ctx1)


class CrossPath(nn.Module):
    def __init__(self, dim, heads):
        super().__init__()
        self.channel_proj1 = nn.Linear(dim, 2 * dim)
        self.channel_proj2 = nn.Linear(dim, 2 * dim)
        self.cross_attn = CrossAttention(dim, heads)
        self.end_proj1 = nn.Linear(2 * dim, dim)
        self.end_proj2 = nn.Linear(2 * dim, dim)
        self.norm1 = nn.LayerNorm(dim)
        self.norm2 = nn.LayerNorm(dim)

    def forward(self, x1, x2):
        y1, u1 = F.relu(self.channel_proj1(x1)).chunk(2, -1)
        y2, u2 = F.relu(self.channel_proj2(x2)).chunk(2, -1)
        v1, v2 = self.cross_attn(u1, u2)
        out1 = self.norm1(x1 + self.end_proj1(torch.cat([y1, v1], -1)))
        out2 = self.norm2(x2 + self.end_proj2(torch.cat([y2, v2], -1)))
        return out1, out2


class ChannelEmbed(nn.Module):
    def __init__(self, c_in, c_out):
        super().__init__()
        self.residual = nn.Conv2d(c_in, c_out, 1, bias=False)
        self.channel_embed = nn.Sequential(
            nn.Conv2d(c_in, c_out, 1),
            nn.Conv2d(c_out, c_out, 3, 1, 1, groups=c_out),
            nn.ReLU(),
            nn.Conv2d(c_out, c_out, 1),
            nn.BatchNorm2d(c_out),
        )
        self.norm = nn.BatchNorm2d(c_out)

    def forward(self, x):
        return self.norm(self.residual(x) + self.channel_embed(x))


class Fuse(nn.Module):
    """FFM: cross-attention path on tokens, then the channel embedding of both streams."""

    def __init__(self, dim, heads):
        super().__init__()
        self.cross = CrossPath(dim, heads)
        self.channel_emb = ChannelEmbed(2 * dim, dim)

    def forward(self, x1, x2):
        h, w = x1.shape[2:]
        t1, t2 = self.cross(tokens(x1), tokens(x2))
        return self.channel_emb(feature_map(torch.cat([t1, t2], -1), h, w))


class DualMiT(nn.Module):
    def __init__(self, dims, depths):
        super().__init__()
        for i in range(4):
            c_in = 3 if i == 0 else dims[i - 1]
            kernel, stride = (7, 4) if i == 0 else (3, 2)
            for prefix in ("", "extra_"):
                setattr(self, f"{prefix}patch_embed{i + 1}", PatchEmbed(c_in, dims[i], kernel, stride))
                rates = drop_path_rates(depths, i, prefix == "extra_")
                blocks = nn.ModuleList(Block(dims[i], HEADS[i], SR_RATIOS[i], r) for r in rates)
                setattr(self, f"{prefix}block{i + 1}", blocks)
                setattr(self, f"{prefix}norm{i + 1}", nn.LayerNorm(dims[i], eps=1e-6))
        self.FRMs = nn.ModuleList(Rectify(d) for d in dims)
        self.FFMs = nn.ModuleList(Fuse(d, h) for d, h in zip(dims, HEADS))

    def stream(self, prefix, i, x):
        x, h, w = getattr(self, f"{prefix}patch_embed{i}")(x)
        for block in getattr(self, f"{prefix}block{i}"):
            x = block(x, h, w)
        return feature_map(getattr(self, f"{prefix}norm{i}")(x), h, w)

    def forward(self, rgb, other):
        outs = []
        for i in range(4):
            rgb, other = self.stream("", i + 1, rgb), self.stream("extra_", i + 1, other)
            rgb, other = self.FRMs[i](rgb, other)
            outs.append(self.FFMs[i](rgb, other))
        return outs


class Mlp(nn.Module):
    def __init__(self, c_in, dim):
        super().__init__()
        self.proj = nn.Linear(c_in, dim)


class MlpDecoder(nn.Module):
    def __init__(self, dims, num_classes, bn_eps=1e-5):
        super().__init__()
        for i, c in enumerate(dims):
            setattr(self, f"linear_c{i + 1}", Mlp(c, DECODER_DIM))
        self.linear_fuse = nn.Sequential(nn.Conv2d(4 * DECODER_DIM, DECODER_DIM, 1),
                                         nn.BatchNorm2d(DECODER_DIM, eps=bn_eps), nn.ReLU())
        self.linear_pred = nn.Conv2d(DECODER_DIM, num_classes, 1)

    def forward(self, feats):
        size = feats[0].shape[2:]
        maps = []
        for i in (3, 2, 1, 0):
            f = feats[i]
            m = feature_map(getattr(self, f"linear_c{i + 1}").proj(tokens(f)), *f.shape[2:])
            if i > 0:
                m = F.interpolate(m, size=size, mode="bilinear", align_corners=False)
            maps.append(m)
        fused = F.dropout2d(self.linear_fuse(torch.cat(maps, 1)), DECODER_DROPOUT, self.training)
        return self.linear_pred(fused)


class Cmx(nn.Module):
    def __init__(self, size, num_classes=9, decoder_bn_eps=1e-5):
        super().__init__()
        dims, depths = SIZES[size]
        self.backbone = DualMiT(dims, depths)
        self.decode_head = MlpDecoder(dims, num_classes, decoder_bn_eps)

    def forward(self, rgb, other):
        logits = self.decode_head(self.backbone(rgb, other))
        return F.interpolate(logits, size=rgb.shape[2:], mode="bilinear", align_corners=False)


def official_inputs(rgbt):
    """rtf's [B, 4, H, W] (R, G, B, T in [0, 1]) -> the official pipeline's network inputs."""
    # On the input's device; in its type where that is half-width (a cast network), else fp32
    # as the official pipeline's constants (a float64 reference keeps them so).
    half = rgbt.dtype in (torch.float16, torch.bfloat16)
    like = {"device": rgbt.device, "dtype": rgbt.dtype if half else torch.float32}
    mean = torch.tensor(IMAGENET_MEAN, **like).view(1, 3, 1, 1)
    std = torch.tensor(IMAGENET_STD, **like).view(1, 3, 1, 1)
    bgr = rgbt[:, [2, 1, 0]]
    thermal = rgbt[:, 3:4].expand(-1, 3, -1, -1)
    return (bgr - mean) / std, (thermal - mean) / std


def read_png(path):
    """An 8-bit, non-interlaced PNG as a uint8 tensor [H, W, C] (zlib + the five row filters)."""
    data = open(path, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path}: not a PNG"
    pos, idat, header = 8, b"", None
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        pos += 12 + length
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
    width, height, depth, colour, _, _, interlace = header
    channels = {0: 1, 2: 3, 4: 2, 6: 4}[colour]
    assert depth == 8 and interlace == 0, f"{path}: only 8-bit non-interlaced PNGs"
    raw, stride = zlib.decompress(idat), width * channels
    out, prev = bytearray(), bytearray(stride)
    for y in range(height):
        kind, row = raw[y * (stride + 1)], bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for i in range(stride):
            a = row[i - channels] if i >= channels else 0
            b = prev[i]
            c = prev[i - channels] if i >= channels else 0
            if kind == 1:
                row[i] = (row[i] + a) & 255
            elif kind == 2:
                row[i] = (row[i] + b) & 255
            elif kind == 3:
                row[i] = (row[i] + (a + b) // 2) & 255
            elif kind == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                row[i] = (row[i] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        out += row
        prev = row
    return torch.frombuffer(out, dtype=torch.uint8).view(height, width, channels)


def randomise(net):
    """The official decoder's training init (Kaiming-normal fan-in convolutions), then every
    normalisation layer moved off its neutral init, BatchNorm statistics included."""
    with torch.no_grad():
        for m in net.decode_head.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_in", nonlinearity="relu")
        for m in net.modules():
            if isinstance(m, (nn.LayerNorm, nn.BatchNorm2d)):
                m.weight.uniform_(0.5, 1.5)
                m.bias.uniform_(-0.2, 0.2)
            if isinstance(m, nn.BatchNorm2d):
                m.running_mean.uniform_(-0.2, 0.2)
                m.running_var.uniform_(0.5, 1.5)


def count(size, num_classes=9):
    return sum(p.numel() for p in Cmx(size, num_classes).parameters())


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out_dir", nargs="?")
    ap.add_argument("size", nargs="?", choices=sorted(SIZES))
    ap.add_argument("--count", action="store_true", help="print the parameter counts and exit")
    ap.add_argument("--frame", default=os.path.join(os.path.dirname(__file__), "../../../shared/data/mf-samples/01234N.png"))
    ap.add_argument("--crop", default=None, help="HxW centre crop of the frame (default: whole frame)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if args.count:
        for size in sorted(SIZES):
            print(f"cmx-mit-{size}\t{count(size)}")
        return
    if args.out_dir is None or args.size is None:
        ap.error("OUT_DIR and SIZE are required without --count")
    torch.manual_seed(args.seed)
    net = Cmx(args.size)
    randomise(net)
    net.eval()
    pixels = read_png(args.frame).permute(2, 0, 1).float() / 255.0  # [4, H, W]: R, G, B, T
    assert pixels.shape[0] == 4, f"{args.frame}: expected RGBA (thermal in alpha)"
    if args.crop:
        ch, cw = (int(v) for v in args.crop.lower().split("x"))
        top, left = (pixels.shape[1] - ch) // 2, (pixels.shape[2] - cw) // 2
        pixels = pixels[:, top:top + ch, left:left + cw]
    x = pixels.unsqueeze(0).contiguous()
    with torch.no_grad():
        y = net(*official_inputs(x))
    os.makedirs(args.out_dir, exist_ok=True)
    name = f"cmx-mit-{args.size}"
    path = os.path.join(args.out_dir, f"{name}.pth")
    torch.save({"model": net.state_dict(), "epoch": 1, "iteration": 1}, path)
    convert_pth.write_safetensors([("input", x), ("output", y)], os.path.join(args.out_dir, f"{name}_io.safetensors"))
    print(f"cmx_reference: {path}, output {list(y.shape)}, max |logit| {y.abs().max().item():.3f}")


if __name__ == "__main__":
    main()
