"""`rtf.load_network` and the network object against `rtf predict` (bit for bit)."""

import numpy as np
import pytest
import torch

import rtf
from conftest import MF_SAMPLES, read_png, read_rgba

FRAME = MF_SAMPLES / "01234N.png"
MFNET = MF_SAMPLES / "mfnet_final.safetensors"


def predicted(run_rtf, tmp_path, model, weights, frame, *extra):
    out = tmp_path / "pred"
    run_rtf("predict", "--model", model, "--weights", weights, "--out", out, "--logits", *extra,
            frame)
    return np.load(out / f"{frame.stem}.npy"), read_png(out / f"{frame.stem}.png")


def test_mfnet_published_weights_on_a_real_frame_equal_rtf_predict(run_rtf, tmp_path):
    net = rtf.load_network("mfnet", weights=MFNET)
    rgb, thermal = read_rgba(FRAME)
    logits = net.logits(rgb, thermal)
    cli_logits, cli_ids = predicted(run_rtf, tmp_path, "mfnet", MFNET, FRAME)
    assert logits.dtype == np.float32 and logits.shape == (9, 480, 640)
    assert np.array_equal(logits, cli_logits)
    ids = net.predict(rgb, thermal)
    assert ids.dtype == np.uint8 and np.array_equal(ids, cli_ids)
    # A real frame has more than one class in it: the comparison is not of two blanks.
    assert len(np.unique(ids)) > 1


def test_the_fp32_fast_path_equals_rtf_predict_precision_fp32(run_rtf, tmp_path):
    net = rtf.load_network("mfnet", weights=MFNET, precision="fp32")
    rgb, thermal = read_rgba(FRAME)
    cli_logits, cli_ids = predicted(
        run_rtf, tmp_path, "mfnet", MFNET, FRAME, "--precision", "fp32"
    )
    assert np.array_equal(net.logits(rgb, thermal), cli_logits)
    assert np.array_equal(net.predict(rgb, thermal), cli_ids)
    # A fast-path network keeps only its folded weights: it cannot be saved.
    with pytest.raises(rtf.InputError, match="precision=None"):
        net.save(tmp_path / "folded.safetensors")


@pytest.mark.parametrize("winograd", [None, "on", "off"])
def test_the_bf16_fast_path_takes_the_cli_kernels(winograd, run_rtf, tmp_path, monkeypatch):
    # One policy and one probe cache for both sides (the measured choice where the variable
    # is unset): the same kernels, so the same bf16 logits bit for bit.
    monkeypatch.setenv("RTF_CACHE_DIR", str(tmp_path / "cache"))
    if winograd is None:
        monkeypatch.delenv("RTF_BF16_WINOGRAD", raising=False)
    else:
        monkeypatch.setenv("RTF_BF16_WINOGRAD", winograd)
    net = rtf.load_network("mfnet", weights=MFNET, precision="bf16")
    rgb, thermal = read_rgba(FRAME)
    cli_logits, cli_ids = predicted(
        run_rtf, tmp_path, "mfnet", MFNET, FRAME, "--precision", "bf16"
    )
    assert np.array_equal(net.logits(rgb, thermal), cli_logits)
    assert np.array_equal(net.predict(rgb, thermal), cli_ids)


def test_a_bad_kernel_variable_is_refused_naming_it(monkeypatch):
    monkeypatch.setenv("RTF_BF16_WINOGRAD", "maybe")
    with pytest.raises(rtf.InputError, match="RTF_BF16_WINOGRAD"):
        rtf.load_network("mfnet", weights=MFNET, precision="bf16")


@pytest.mark.parametrize("model", ["rtfnet50", "cmx-mit-b0"])
def test_random_weights_saved_and_loaded_equal_rtf_predict(model, run_rtf, tmp_path):
    from PIL import Image

    torch.manual_seed(0)
    weights = tmp_path / f"{model}.safetensors"
    rtf.load_network(model).save(weights)
    net = rtf.load_network(model, weights=weights)
    # A 200x260 window of the real frame (not a multiple of 32: the padding is compared too),
    # a quarter of the work of the whole frame for these larger networks.
    crop = tmp_path / "crop.png"
    Image.fromarray(np.asarray(Image.open(FRAME))[100:300, 150:410]).save(crop)
    rgb, thermal = read_rgba(crop)
    cli_logits, cli_ids = predicted(run_rtf, tmp_path, model, weights, crop)
    assert np.array_equal(net.logits(rgb, thermal), cli_logits)
    assert np.array_equal(net.predict(rgb, thermal), cli_ids)


def test_the_forward_pass_takes_torch_tensors_and_matches_logits():
    net = rtf.load_network("mfnet", weights=MFNET)
    rgb, thermal = read_rgba(FRAME)
    x = torch.cat(
        [
            torch.from_numpy(rgb).permute(2, 0, 1).float() / 255.0,
            torch.from_numpy(thermal)[None].float() / 255.0,
        ]
    )[None]
    out = net(x)
    assert isinstance(out, torch.Tensor) and out.shape == (1, 9, 480, 640)
    assert torch.equal(out[0], torch.from_numpy(net.logits(rgb, thermal)))


def test_classes_colours_and_models():
    net = rtf.load_network("mfnet", weights=MFNET)
    names = [c["name"] for c in net.classes]
    assert len(names) == 9 and names[0] == "unlabeled"
    ids = np.array([[0, 1], [2, 8]], dtype=np.uint8)
    colours = net.colorize(ids)
    assert colours.shape == (2, 2, 3) and colours.dtype == np.uint8
    assert tuple(colours[0, 1]) == tuple(net.classes[1]["color"])
    records = {m["name"]: m for m in rtf.models()}
    assert records["mfnet"]["parameters"] > 0 and records["mfnet"]["classes"] == "mf"
    assert "heatnet-critic" not in records


def test_a_user_loop_trains_the_network_through_torch_autograd():
    torch.manual_seed(0)
    net = rtf.load_network("mfnet").train()
    params = net.parameters()
    opt = torch.optim.SGD(params, lr=0.01)
    x = torch.rand(2, 4, 64, 64)
    y = torch.randint(0, 9, (2, 64, 64))
    before = [p.detach().clone() for p in params]
    loss = torch.nn.functional.cross_entropy(net(x), y)
    loss.backward()
    opt.step()
    assert any(not torch.equal(a, p.detach()) for a, p in zip(before, params))


def test_the_gil_is_released_while_the_network_runs():
    """Python keeps running beside `net.logits`: the longest pause of a counting loop in
    another thread stays well below the call's length (holding the GIL, it would be all of it)."""
    import threading
    import time

    net = rtf.load_network("mfnet", weights=MFNET)
    rgb, thermal = read_rgba(FRAME)
    span = {}

    def work():
        span["start"] = time.perf_counter()
        net.logits(rgb, thermal)
        span["end"] = time.perf_counter()

    worker = threading.Thread(target=work)
    worker.start()
    stamps = []
    while worker.is_alive():
        stamps.append(time.perf_counter())
    worker.join()
    inside = [t for t in stamps if span["start"] <= t <= span["end"]]
    call = span["end"] - span["start"]
    longest = max(b - a for a, b in zip(inside, inside[1:]))
    assert len(inside) > 2 and longest < 0.5 * call, (longest, call, len(inside))
