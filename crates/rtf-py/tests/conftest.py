"""Shared fixtures: the release `rtf` binary (the CLI side of every comparison), the shared
real data, and small synthetic datasets made by `rtf synth`."""

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[3]
# The project's shared real data sits beside the repository (../shared/data), as the Rust
# tests find it; RTF_SHARED_DATA points elsewhere.
SHARED = Path(os.environ.get("RTF_SHARED_DATA", ROOT.parent / "shared" / "data"))
MF_SAMPLES = SHARED / "mf-samples"


@pytest.fixture(scope="session")
def rtf_bin():
    path = Path(os.environ.get("RTF_BIN", ROOT / "target/release/rtf"))
    if not path.exists():
        pytest.fail(f"{path} missing: build it with `cargo build --release -p rtf-cli`")
    return path


@pytest.fixture(scope="session")
def run_rtf(rtf_bin):
    def run(*args):
        done = subprocess.run(
            [str(rtf_bin), *map(str, args)], capture_output=True, text=True
        )
        assert done.returncode == 0, f"rtf {' '.join(map(str, args))}:\n{done.stderr}"
        return done.stdout

    return run


@pytest.fixture(scope="session")
def synth(run_rtf, tmp_path_factory):
    """A small MF-layout synthetic dataset with labels (day and night frames)."""
    out = tmp_path_factory.mktemp("synth") / "data"
    run_rtf("synth", "--out", out, "--count", 12, "--seed", 3, "--size", "160x128")
    return out


def read_rgba(path):
    """An MF frame as the dataset holds it: (RGB H×W×3 uint8, thermal H×W uint8)."""
    from PIL import Image

    rgba = np.asarray(Image.open(path))
    assert rgba.dtype == np.uint8 and rgba.shape[2] == 4, rgba.shape
    return np.ascontiguousarray(rgba[..., :3]), np.ascontiguousarray(rgba[..., 3])


def read_png(path):
    from PIL import Image

    return np.asarray(Image.open(path))


def read_safetensors(path):
    """The tensors of a safetensors file as {name: (dtype, shape, raw bytes)} and its
    metadata (the format: an 8-byte little-endian header length, a JSON header, the data)."""
    import json
    import struct

    blob = Path(path).read_bytes()
    (n,) = struct.unpack("<Q", blob[:8])
    header = json.loads(blob[8 : 8 + n])
    data = blob[8 + n :]
    meta = header.pop("__metadata__", {})
    tensors = {
        name: (h["dtype"], tuple(h["shape"]), data[h["data_offsets"][0] : h["data_offsets"][1]])
        for name, h in header.items()
    }
    return tensors, meta


def write_safetensors(path, tensors, meta):
    """Writes {name: (dtype, shape, raw bytes)} and metadata as a safetensors file."""
    import json
    import struct

    header, offset, chunks = {}, 0, []
    for name, (dtype, shape, raw) in sorted(tensors.items()):
        header[name] = {"dtype": dtype, "shape": list(shape), "data_offsets": [offset, offset + len(raw)]}
        offset += len(raw)
        chunks.append(raw)
    header["__metadata__"] = meta
    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 8)
    Path(path).write_bytes(struct.pack("<Q", len(text)) + text + b"".join(chunks))
