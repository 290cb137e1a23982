"""Python on the other layouts: Freiburg Thermal (16-bit IR, 13 classes) and a described
dataset (dataset.yaml, 16-bit radiometric thermal with its range), each read by the readers
`rtf train` uses, batched by the trainer's loader, and scored equal to `rtf eval --json`."""

import json

import numpy as np
import pytest
import torch

import rtf


@pytest.fixture(scope="module", params=["freiburg", "plain"])
def layout(request, run_rtf, tmp_path_factory):
    out = tmp_path_factory.mktemp(request.param) / "data"
    run_rtf("synth", "--out", out, "--format", request.param, "--count", 8, "--seed", 4,
            "--size", "160x128")
    return request.param, out


def test_frames_loader_and_scores_of_another_layout(layout, run_rtf, tmp_path):
    kind, root = layout
    ds = rtf.open_dataset(root)
    classes = len(ds.classes)
    assert classes == (13 if kind == "freiburg" else 9), ds.classes
    test = next(s for s in ds.splits if "test" in s)
    frame = ds.split(test)[0]
    assert frame.rgb.dtype == np.uint8 and frame.rgb.shape[2] == 3
    assert frame.thermal.dtype == np.float32 and frame.thermal.shape == frame.rgb.shape[:2]
    assert 0.0 <= frame.thermal.min() and frame.thermal.max() <= 1.0
    train = next(s for s in ds.splits if "train" in s)
    x, y = next(iter(ds.loader(train, 2, seed=1, workers=1)))
    assert x.dtype == torch.float32 and x.shape[:2] == (2, 4) and y.shape == (2, *x.shape[2:])
    assert y.max() < classes or y.max() == 255
    torch.manual_seed(2)
    weights = tmp_path / "mfnet.safetensors"
    classes = None if kind == "plain" else "freiburg"
    rtf.load_network("mfnet", classes=classes).save(weights)
    out = tmp_path / "scores.json"
    run_rtf("eval", "--model", "mfnet", "--weights", weights, "--data", root, "--split", test,
            "--json", out)
    cli = json.loads(out.read_text())
    net = rtf.load_network("mfnet", weights=weights, classes=classes)
    scores = rtf.evaluate(net, ds, split=test)
    assert scores.frames == cli["frames"] > 0
    assert scores.miou == cli["miou"] and scores.confusion == cli["confusion"]
    assert sum(map(sum, scores.confusion)) == scores.pixels > 0


def test_a_dataset_yaml_given_as_the_file_is_its_folder(run_rtf, tmp_path):
    root = tmp_path / "data"
    run_rtf("synth", "--out", root, "--format", "plain", "--count", 6, "--seed", 1,
            "--size", "64x48")
    ds = rtf.open_dataset(root / "dataset.yaml")
    assert str(ds.root) == str(root)
    assert ds.splits == rtf.open_dataset(root).splits
