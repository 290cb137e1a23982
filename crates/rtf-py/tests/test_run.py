"""`rtf.Run` reads a run folder `rtf train` wrote: its config, log and weights."""

import json

import pytest

import rtf


def test_a_run_folder_reads_back_as_rtf_train_wrote_it(run_rtf, synth, tmp_path):
    out = tmp_path / "run"
    run_rtf("train", "--model", "mfnet", "--data", synth, "--out", out, "--epochs", "2",
            "--batch-size", "2", "--max-steps", "1")
    run = rtf.Run(out)
    assert run.config == json.loads((out / "config.json").read_text())
    lines = (out / "log.jsonl").read_text().splitlines()
    assert [e["epoch"] for e in run.epochs] == [json.loads(l)["epoch"] for l in lines]
    assert len(run.epochs) == 2 and run.stages == []
    assert run.final == out / "final.safetensors"
    assert run.weights in (run.best, run.final)
    net = rtf.load_network("mfnet", weights=run.weights)
    assert net.weights == run.weights
    with pytest.raises(rtf.DataError, match="no stage"):
        run.stage("teacher")


def test_a_folder_that_is_no_run_is_refused(tmp_path):
    with pytest.raises(rtf.DataError):
        rtf.Run(tmp_path / "missing")
