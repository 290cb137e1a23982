"""Every bad input raises the named exception, naming what was given and what was
expected, before anything runs."""

import numpy as np
import pytest
import torch

import rtf
from conftest import MF_SAMPLES

MFNET = MF_SAMPLES / "mfnet_final.safetensors"


@pytest.fixture(scope="module")
def net():
    return rtf.load_network("mfnet", weights=MFNET)


def test_the_hierarchy():
    for kind in (rtf.DataError, rtf.ModelError, rtf.EvalError, rtf.InputError, rtf.TorchError):
        assert issubclass(kind, rtf.Error)


def test_rgb_of_the_wrong_dtype_or_shape(net):
    thermal = np.zeros((32, 32), np.uint8)
    with pytest.raises(rtf.InputError, match=r"rgb: expected .*uint8.*\(H, W, 3\), got dtype float32"):
        net.logits(np.zeros((32, 32, 3), np.float32), thermal)
    with pytest.raises(rtf.InputError, match=r"shape \(32, 32, 4\)"):
        net.logits(np.zeros((32, 32, 4), np.uint8), thermal)
    with pytest.raises(rtf.InputError, match="numpy array"):
        net.logits([[1, 2, 3]], thermal)


def test_thermal_with_three_channels_that_differ(net):
    rgb = np.zeros((32, 32, 3), np.uint8)
    thermal = np.zeros((32, 32, 3), np.uint8)
    thermal[..., 1] = 7
    with pytest.raises(rtf.InputError, match="3 channels that differ"):
        net.logits(rgb, thermal)
    # Grey stored as three equal channels is read as grey.
    assert net.logits(rgb, np.zeros((32, 32, 3), np.uint8)).shape == (9, 32, 32)


def test_thermal_of_another_size_or_dtype(net):
    rgb = np.zeros((32, 32, 3), np.uint8)
    with pytest.raises(rtf.InputError, match="same size"):
        net.logits(rgb, np.zeros((16, 32), np.uint8))
    with pytest.raises(rtf.InputError, match="got dtype int64"):
        net.logits(rgb, np.zeros((32, 32), np.int64))
    with pytest.raises(rtf.InputError, match="lo < hi"):
        net.logits(rgb, np.zeros((32, 32), np.uint16), thermal_range=(5, 5))


def test_float_thermal_needs_a_rule(net):
    rgb = np.zeros((32, 32, 3), np.uint8)
    with pytest.raises(rtf.DataError, match="needs a rule"):
        net.logits(rgb, np.full((32, 32), 21.5, np.float32))
    assert net.logits(rgb, np.full((32, 32), 21.5, np.float32), thermal_range=(0, 40)).shape[0] == 9


def test_tensors_of_another_shape_kind_or_device(net):
    with pytest.raises(rtf.InputError, match=r"shape \[B, 4, H, W\]"):
        net(torch.zeros(1, 3, 32, 32))
    with pytest.raises(rtf.InputError, match="floating-point"):
        net(torch.zeros(1, 4, 32, 32, dtype=torch.uint8))
    with pytest.raises(rtf.InputError, match="x is on meta but the network is on cpu"):
        net(torch.zeros(1, 4, 32, 32, device="meta"))
    with pytest.raises(rtf.InputError, match="torch.Tensor"):
        net(np.zeros((1, 4, 32, 32), np.float32))


def test_weights_of_another_network():
    with pytest.raises(rtf.ModelError, match="mfnet_final.safetensors"):
        rtf.load_network("rtfnet50", weights=MFNET)


def test_unknown_network_device_or_precision():
    with pytest.raises(rtf.ModelError, match="nonet"):
        rtf.load_network("nonet")
    with pytest.raises(rtf.InputError, match="device"):
        rtf.load_network("mfnet", device="tpu")
    with pytest.raises(rtf.InputError, match="precision"):
        rtf.load_network("mfnet", precision="int3")
    with pytest.raises(rtf.ModelError, match="fp16"):
        rtf.load_network("mfnet", precision="fp16")


def test_a_dataset_path_that_is_not_one(tmp_path):
    with pytest.raises(rtf.DataError, match=str(tmp_path)):
        rtf.open_dataset(tmp_path)


def test_save_never_replaces_a_file(tmp_path):
    path = tmp_path / "mine.bin"
    path.write_bytes(b"user data")
    with pytest.raises(rtf.InputError, match="exists"):
        rtf.load_network("mfnet").save(path)
    assert path.read_bytes() == b"user data"


def test_a_torch_of_another_version_is_refused_naming_both(monkeypatch):
    monkeypatch.setattr(torch, "__version__", "2.12.1+cpu")
    with pytest.raises(ImportError, match=r"built for torch 2\.13\.0 but torch 2\.12\.1\+cpu"):
        rtf._check_torch()
    monkeypatch.setattr(torch, "__version__", "2.13.0+cu130")
    rtf._check_torch()

