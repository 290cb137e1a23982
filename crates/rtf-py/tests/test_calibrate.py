"""`rtf.calibrate` against `rtf calibrate`: the same calib.yaml, and the same refusals."""

import pytest
import torch

import rtf


def test_calibrate_writes_what_rtf_calibrate_writes(run_rtf, tmp_path):
    rig = tmp_path / "rig"
    run_rtf("synth", "--format", "calibration-rig", "--out", rig, "--size", "64x48",
            "--count", "2", "--rig-depth", "given", "--seed", "1")
    cli = tmp_path / "cli.yaml"
    run_rtf("calibrate", "--rig", rig / "rig.yaml", "--out", cli, "--iterations", "3")
    ours = tmp_path / "py.yaml"
    threads = torch.get_num_threads()
    result = rtf.calibrate(rig / "rig.yaml", out=ours, iterations=3)
    assert torch.get_num_threads() == threads, "the process's thread count is restored"
    assert result.yaml == cli.read_text() == ours.read_text()
    assert result.verdict in ("ok", "uncertain", "failed") and result.reason
    assert result.verdict in cli.read_text()
    assert result.K[2] == [0.0, 0.0, 1.0] and len(result.rotation) == 3
    rig_text = (rig / "rig.yaml").read_text()
    with pytest.raises(rtf.CalibrationError, match="refusing to overwrite"):
        rtf.calibrate(rig / "rig.yaml", out=rig / "rig.yaml", iterations=3)
    assert (rig / "rig.yaml").read_text() == rig_text
    with pytest.raises(rtf.InputError, match="recipe"):
        rtf.calibrate(rig / "rig.yaml", recipe="fast")
