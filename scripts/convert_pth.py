#!/usr/bin/env python3
"""Converts a PyTorch checkpoint (.pth) into a safetensors state_dict that rtf loads as is.

    python scripts/convert_pth.py IN.pth OUT.safetensors [--allow-pickle]

Accepts a plain state_dict, or one nested under "state_dict" / "model" (also "net",
"model_state_dict"), and strips DataParallel's "module." prefixes. Legacy (non-zip) pickles
load too. Only tensors are written; other entries are listed and skipped. By default the file
is read with torch.load(weights_only=True); checkpoints that pickle other Python objects need
--allow-pickle (runs their pickle code: only for files you trust).

Needs only torch (no numpy, no safetensors package): the safetensors layout is written here.
The output is written to a temporary file and renamed into place.
"""
import argparse
import ctypes
import json
import os
import struct
import sys

import torch

DTYPES = {
    torch.float32: "F32", torch.float64: "F64", torch.float16: "F16", torch.bfloat16: "BF16",
    torch.int64: "I64", torch.int32: "I32", torch.int16: "I16", torch.int8: "I8", torch.uint8: "U8",
    torch.bool: "BOOL",
}
NESTED_KEYS = ("state_dict", "model", "model_state_dict", "net")


def fail(message):
    sys.exit(f"convert_pth: {message}")


def unwrap(obj, path):
    """Descends into the usual checkpoint wrappers until a dict holding tensors is found."""
    for _ in range(4):
        if not isinstance(obj, dict):
            break
        if any(torch.is_tensor(v) for v in obj.values()):
            return obj
        inner = next((obj[k] for k in NESTED_KEYS if isinstance(obj.get(k), dict)), None)
        if inner is None:
            break
        obj = inner
    if hasattr(obj, "state_dict") and callable(obj.state_dict):
        return obj.state_dict()  # a whole pickled nn.Module (needs --allow-pickle)
    if not isinstance(obj, dict):
        fail(f"{path}: holds a {type(obj).__name__}, not a state_dict")
    return obj


def strip_prefix(name):
    while name.startswith("module."):
        name = name[len("module."):]
    return name


def tensor_bytes(t):
    t = t.detach().cpu().contiguous()
    return ctypes.string_at(t.data_ptr(), t.numel() * t.element_size()) if t.numel() else b""


def write_safetensors(tensors, out):
    header, offset, blobs = {}, 0, []
    for name, t in tensors:
        data = tensor_bytes(t)
        header[name] = {"dtype": DTYPES[t.dtype], "shape": list(t.shape), "data_offsets": [offset, offset + len(data)]}
        offset += len(data)
        blobs.append(data)
    raw = json.dumps(header, separators=(",", ":")).encode()
    raw += b" " * ((8 - len(raw) % 8) % 8)  # keep the data 8-byte aligned
    directory = os.path.dirname(os.path.abspath(out))
    os.makedirs(directory, exist_ok=True)
    tmp = os.path.join(directory, f".{os.path.basename(out)}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            f.write(struct.pack("<Q", len(raw)))
            f.write(raw)
            for blob in blobs:
                f.write(blob)
        os.replace(tmp, out)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("input")
    ap.add_argument("output")
    ap.add_argument("--allow-pickle", action="store_true", help="unpickle arbitrary objects (trusted files only)")
    args = ap.parse_args()
    if not os.path.isfile(args.input):
        fail(f"{args.input}: no such file")
    try:
        obj = torch.load(args.input, map_location="cpu", weights_only=not args.allow_pickle)
    except Exception as e:  # torch raises several types for corrupt / unsafe files
        hint = "" if args.allow_pickle else " (if it pickles other objects and you trust it: --allow-pickle)"
        fail(f"{args.input}: cannot load: {str(e).splitlines()[0]}{hint}")
    state = unwrap(obj, args.input)
    tensors, skipped, seen = [], [], set()
    for name, value in state.items():
        name = strip_prefix(str(name))
        if not torch.is_tensor(value):
            skipped.append(name)
            continue
        if value.dtype not in DTYPES:
            fail(f"{args.input}: tensor {name} has unsupported dtype {value.dtype}")
        if name in seen:
            fail(f"{args.input}: two tensors named {name} after stripping 'module.'")
        seen.add(name)
        tensors.append((name, value))
    if not tensors:
        fail(f"{args.input}: no tensors found")
    write_safetensors(tensors, args.output)
    print(f"convert_pth: wrote {len(tensors)} tensors to {args.output}"
          + (f"; skipped non-tensor entries: {', '.join(skipped)}" if skipped else ""))


if __name__ == "__main__":
    main()
