"""`rtf.train`: `rtf train` from Python — the same final weights, the loader's batches the
trainer's, Ctrl-C checkpointed and resumed exactly, options checked by name."""

import os
import signal

import numpy as np
import pytest

import rtf
from conftest import read_safetensors, write_safetensors

# A short run: 3 steps of 3 frames, no validation, a fixed seed.
OPTIONS = dict(model="mfnet", epochs=1, max_steps=3, batch_size=3, seed=5, workers=2,
               val_split="none")


def cli_args(options):
    args = []
    for name, value in options.items():
        flag = "--" + name.replace("_", "-")
        args += [flag] if value is True else [flag, value]
    return args


def tensors(path):
    return read_safetensors(path)[0]


@pytest.fixture(scope="module")
def cli_run(run_rtf, synth, tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "run"
    run_rtf("train", "--data", synth, "--out", out, *cli_args(OPTIONS))
    return out


def test_a_train_from_python_equals_the_command(cli_run, synth, tmp_path):
    seen = []
    run = rtf.train(out=tmp_path / "run", data=synth, progress=seen.append, **OPTIONS)
    assert isinstance(run, rtf.Run) and run.final == tmp_path / "run" / "final.safetensors"
    ours, theirs = tensors(run.final), tensors(cli_run / "final.safetensors")
    assert ours.keys() == theirs.keys() and len(ours) > 10
    assert all(ours[k] == theirs[k] for k in ours), "final weights differ from rtf train's"
    steps = [p for p in seen if p.kind == "step"]
    epochs = [p for p in seen if p.kind == "epoch"]
    assert [p.step for p in steps] == [0, 1, 2] and len(epochs) == 1
    assert all(p.epoch == 0 and np.isfinite(p.loss) for p in seen)
    assert epochs[0].loss == pytest.approx(np.mean([p.loss for p in steps]))
    assert run.epochs[0]["train_loss"] == epochs[0].loss


def test_ctrl_c_checkpoints_and_a_resume_finishes_as_an_uninterrupted_run(cli_run, synth, tmp_path):
    out = tmp_path / "run"

    def ctrl_c_after_the_first_step(p):
        if p.kind == "step" and p.step == 0:
            os.kill(os.getpid(), signal.SIGINT)

    # Python's default handler, or SIG_IGN where the process started with SIGINT ignored (a
    # background job of a non-interactive shell, as some CI runners start the tests).
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt, match="after batch 1: checkpoint written"):
        rtf.train(out=out, data=synth, progress=ctrl_c_after_the_first_step, **OPTIONS)
    assert not (out / "final.safetensors").exists()
    # The process's Ctrl-C handling is back as it was once rtf.train returns.
    assert signal.getsignal(signal.SIGINT) is before
    steps = []
    run = rtf.train(resume=out, progress=steps.append)
    assert [p.step for p in steps if p.kind == "step"] == [1, 2]
    ours, theirs = tensors(run.final), tensors(cli_run / "final.safetensors")
    assert all(ours[k] == theirs[k] for k in ours), "the resumed run differs"
    # Nothing left to do: the same run back, nothing trained.
    assert rtf.train(resume=out).final == run.final


def test_an_exception_in_the_callback_stops_the_run_and_is_raised(synth, tmp_path):
    def fail(p):
        raise ValueError("stop here")

    with pytest.raises(ValueError, match="stop here"):
        rtf.train(out=tmp_path / "run", data=synth, progress=fail, **OPTIONS)
    assert (tmp_path / "run" / "checkpoint.safetensors").exists() or any(
        (tmp_path / "run").glob("checkpoint*")
    )


def test_options_are_rtf_trains_and_bad_ones_are_refused(synth, tmp_path):
    with pytest.raises(TypeError, match="unknown option 'epoch'.*epochs"):
        rtf.train(out=tmp_path / "a", data=synth, epoch=1)
    with pytest.raises(TypeError, match="no_flip is a flag"):
        rtf.train(out=tmp_path / "a", data=synth, no_flip="yes")
    with pytest.raises(rtf.InputError, match="--batch-size"):
        rtf.train(out=tmp_path / "a", data=synth, batch_size="three")
    with pytest.raises(rtf.InputError, match="inside the dataset"):
        rtf.train(out=synth / "run", data=synth, **OPTIONS)
    with pytest.raises(rtf.Error, match="model"):
        rtf.train(out=tmp_path / "b", data=synth, model="no-such-net")
    assert not (tmp_path / "a").exists() and not (synth / "run").exists()


def bn_stats(path):
    return {k: v for k, v in tensors(path).items() if k.endswith(("running_mean", "running_var"))}


def test_the_loader_gives_the_trainers_batches_for_a_seed(synth, tmp_path):
    """The trainer's batch order and augmentation, seen through BatchNorm: a run whose
    weights do not move (lr 1e-30) leaves in its running statistics the batches it saw, in
    order; the same network fed rtf's loader from Python (same seed, batch size, flips) must
    end with the same statistics."""
    options = dict(OPTIONS, optimizer="sgd", lr=1e-30, momentum=0, weight_decay=0)
    run = rtf.train(out=tmp_path / "run", data=synth, **options)
    trained = bn_stats(run.final)
    assert trained, "MFNet has BatchNorm statistics"
    # The same weights with fresh statistics (mean 0, variance 1), fed from Python.
    weights, meta = read_safetensors(run.final)
    for name, (dtype, shape, raw) in list(weights.items()):
        if name.endswith(("running_mean", "running_var")):
            fresh = np.full(shape, 1.0 if name.endswith("var") else 0.0, np.float32)
            weights[name] = (dtype, shape, fresh.tobytes())
    start = tmp_path / "start.safetensors"
    write_safetensors(start, weights, meta)

    def stats_after(seed):
        net = rtf.load_network("mfnet", weights=start).train()
        loader = rtf.open_dataset(synth).loader("train", 3, seed=seed, workers=2)
        for step, (x, _) in enumerate(loader.epoch(0)):
            if step == 3:
                break
            net(x)
        path = tmp_path / f"python-{seed}.safetensors"
        net.save(path, overwrite=True)
        return bn_stats(path)

    def gap(a, b):
        return max(
            np.abs(np.frombuffer(a[k][2], np.float32) - np.frombuffer(b[k][2], np.float32)).max()
            / (np.abs(np.frombuffer(b[k][2], np.float32)).max() + 1e-6)
            for k in b
        )

    same, other = stats_after(5), stats_after(6)
    assert same.keys() == trained.keys()
    # The trainer may lay its maps out channels-last (AVX-512 CPUs) where Python's forward
    # runs NCHW: float sums in another order, which after a few layers move a statistic near
    # zero by up to ~5e-4 of the tensor's largest (measured: 4.9e-4; 0 with
    # RTF_TRAIN_LAYOUT=nchw). Another seed's batches move them by ~0.1.
    assert gap(same, trained) < 5e-3, gap(same, trained)
    assert gap(other, trained) > 3e-2, gap(other, trained)
