"""`rtf.open_dataset` and `rtf.evaluate` against `rtf eval --json`."""

import json

import numpy as np
import torch

import rtf


def test_frames_are_read_by_the_dataset_readers(synth):
    ds = rtf.open_dataset(synth)
    assert "test" in ds.splits and len(ds.classes) == 9
    split = ds.split("test")
    assert len(split) > 0
    frame = split[0]
    assert frame.name == split.names[0]
    assert frame.rgb.dtype == np.uint8 and frame.rgb.ndim == 3 and frame.rgb.shape[2] == 3
    assert frame.thermal.dtype == np.float32 and frame.thermal.shape == frame.rgb.shape[:2]
    assert frame.label.dtype == np.uint8 and frame.label.max() < 9
    assert 0.0 <= frame.thermal.min() and frame.thermal.max() <= 1.0


def test_evaluate_equals_rtf_eval_json(synth, run_rtf, tmp_path):
    torch.manual_seed(1)
    weights = tmp_path / "mfnet.safetensors"
    rtf.load_network("mfnet").save(weights)
    out = tmp_path / "scores.json"
    run_rtf("eval", "--model", "mfnet", "--weights", weights, "--data", synth, "--json", out)
    cli = json.loads(out.read_text())
    net = rtf.load_network("mfnet", weights=weights)
    scores = rtf.evaluate(net, rtf.open_dataset(synth), split="test")
    assert scores.frames == cli["frames"] > 0
    assert scores.miou == cli["miou"] and scores.macc == cli["macc"]
    assert scores.per_class == {c["name"]: c["iou"] for c in cli["per_class"]}
    assert scores.confusion == cli["confusion"]
    assert scores.class_names == cli["class_names"]
    for part in ("day", "night"):
        mine, theirs = getattr(scores, part), cli[part]
        assert (mine is None) == (theirs is None)
        if theirs is not None:
            assert mine.json == theirs
    # The confusion matrix counts every labelled pixel: the scores are of real work.
    assert sum(map(sum, scores.confusion)) == scores.pixels > 0
