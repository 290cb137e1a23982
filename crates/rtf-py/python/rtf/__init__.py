"""rtf from Python: RGB-thermal segmentation networks, datasets and evaluation on the same
library as the ``rtf`` command (numbers equal to the CLI's, bit for bit).

    import rtf
    net = rtf.load_network("mfnet", weights="mfnet.safetensors")
    logits = net.logits(rgb, thermal)          # numpy [classes, H, W] float32
    ds = rtf.open_dataset("data/msrs")
    scores = rtf.evaluate(net, ds, split="test")
"""

import json as _json
import os as _os
import pathlib as _pathlib

# The extension links libtorch of exactly this version (tch 0.26): another torch crashes
# inside libtorch rather than failing, so it is refused here, before the extension loads.
TORCH_VERSION = "2.13.0"


def _check_torch():
    try:
        import torch
    except ImportError as err:  # pragma: no cover - torch is a dependency of the wheel
        raise ImportError(
            f"rtf needs torch=={TORCH_VERSION} (pip install torch=={TORCH_VERSION}): {err}"
        ) from err
    found = torch.__version__.split("+")[0]
    if found != TORCH_VERSION:
        raise ImportError(
            f"rtf was built for torch {TORCH_VERSION} but torch {torch.__version__} is "
            f"installed ({torch.__file__}); install torch=={TORCH_VERSION} or rebuild the "
            "wheel against this torch"
        )


_check_torch()

from ._rtf import (  # noqa: E402  (torch first: it loads the libraries the extension links)
    CalibrationError,
    DataError,
    Dataset,
    Error,
    EvalError,
    Epoch,
    Frame,
    InputError,
    Loader,
    ModelError,
    Network,
    Split,
    TorchError,
    TrainError,
    __version__,
    models,
    open_dataset,
)
from . import _rtf  # noqa: E402

# Freed memory stays in the process for reuse, as the `rtf` binary keeps it: a network's
# activations are not page-faulted in again on every pass (MFNet fp32 at 640x480 here: 122 ->
# 96 ms per frame, docs/src/python.md "Speed"). The resident size stays at its peak;
# RTF_RETAIN_FREED_MEMORY=0 keeps the C library's own policy.
if _os.environ.get("RTF_RETAIN_FREED_MEMORY") != "0":
    _rtf.retain_freed_memory()


def load_network(name, weights=None, classes=None, device="cpu", precision=None):
    """Loads network ``name`` (see ``rtf.models()``) with ``weights`` (a safetensors file,
    reference names; None: random weights, seeded by ``torch.manual_seed``) as ``rtf predict``
    loads it: ``classes`` (a class set's name, else the weights' record), ``device``,
    ``precision`` (None: the plain path; "fp32", "bf16", "fp16" on CUDA: the fast path, its
    kernels chosen as ``rtf predict`` chooses them under ``RTF_WINOGRAD``,
    ``RTF_BF16_WINOGRAD``, ``RTF_BF16_CONVOLUTIONS``, oneDNN's ``ONEDNN_MAX_CPU_ISA`` and the
    measurement cache ``RTF_CACHE_DIR``, read here, with ``rtf predict``'s warning where bf16
    is slow or emulated on this CPU)."""
    return _rtf.load_network(name, weights, classes, device, precision, dict(_os.environ))


class Scores:
    """What ``rtf eval --json`` writes: ``miou``, ``macc``, ``miou_mfnet``, ``pixel_acc``,
    ``per_class`` (name -> IoU, None for a class without pixels), ``day`` / ``night`` (the
    same for the day and night frames, None where the split has none), ``confusion`` (rows =
    truth, columns = prediction), ``class_names``, ``frames``; ``json`` is the whole record."""

    def __init__(self, record):
        self.json = record
        self._all = record["all"]
        self.frames = record["frames"]
        self.class_names = record["class_names"]
        self.confusion = record["confusion"]
        self.day = Scores._part(record["day"])
        self.night = Scores._part(record["night"])

    @staticmethod
    def _part(scores):
        if scores is None:
            return None
        return _Part(scores)

    def __getattr__(self, name):
        return getattr(_Part(self._all), name)

    def __repr__(self):
        return f"rtf.Scores(miou={self._all['miou']:.4f}, frames={self.frames})"


class _Part:
    """One set of scores (all frames, day or night)."""

    def __init__(self, scores):
        self.json = scores
        self.miou = scores["miou"]
        self.macc = scores["macc"]
        self.miou_mfnet = scores["miou_mfnet"]
        self.pixel_acc = scores["pixel_acc"]
        self.pixels = scores["pixels"]
        self.per_class = {c["name"]: c["iou"] for c in scores["per_class"]}
        self.per_class_acc = {c["name"]: c["acc"] for c in scores["per_class"]}

    def __repr__(self):
        return f"rtf.Scores(miou={self.miou:.4f})"


def evaluate(net, data, split="test", sliding=False, scales=None, flip=False,
             batch_size=4, resize=None):
    """Scores ``net`` on ``split`` of ``data`` (``rtf.open_dataset``) as ``rtf eval`` does
    (``sliding``: 480x640 windows at stride rate 2/3; ``scales``: e.g. [0.75, 1, 1.25];
    ``flip``; ``resize``: (width, height)). Returns :class:`Scores`, equal to
    ``rtf eval --json``."""
    record = _rtf.evaluate_json(net, data, split, sliding, scales, flip, batch_size, resize)
    return Scores(_json.loads(record))


class Run:
    """A training run folder read back (``rtf train --out DIR``): ``dir``, ``config`` (its
    config.json, None before the first step), ``epochs`` (log.jsonl: one dict per epoch with
    every loss term and the validation scores), ``stages`` (a multi-stage recipe's stage
    names; ``run.stage(name)`` is that stage's Run), and the weights files ``best``,
    ``final`` and ``weights`` (the validated best where there is one, else the final)."""

    def __init__(self, path):
        record = _json.loads(_rtf.read_run(str(path)))
        path_of = lambda p: None if p is None else _pathlib.Path(p)  # noqa: E731
        self.dir = _pathlib.Path(record["dir"])
        self.config = record["config"]
        self.epochs = record["epochs"]
        self.stages = record["stages"]
        self.best = path_of(record["weights"]["best"])
        self.final = path_of(record["weights"]["final"])
        self.weights = path_of(record["weights"]["selected"])

    def stage(self, name):
        """The Run of stage ``name`` of a multi-stage recipe."""
        if name not in self.stages:
            raise DataError(f"{self.dir}: no stage {name!r} (stages: {', '.join(self.stages)})")
        return Run(self.dir / name)

    def __repr__(self):
        return f"rtf.Run({self.dir!r}, epochs={len(self.epochs)})"


class Progress:
    """What ``rtf.train``'s ``progress`` callback receives after every step and epoch:
    ``kind`` ("step" or "epoch"), ``stage`` (a multi-stage recipe's stage, "" otherwise),
    ``epoch`` (0-based, as log.jsonl counts), ``step`` (a step's 0-based index over the run;
    None for an epoch), ``loss`` (the step's total loss, or the epoch's mean), ``losses`` (every
    loss term by name) and ``record`` (the step as steps.jsonl holds it, the epoch as
    log.jsonl holds it: learning rate, images/s, validation scores)."""

    def __init__(self, kind, stage, record):
        self.kind = kind
        self.stage = stage
        self.record = record
        self.epoch = record["epoch"]
        self.step = record.get("step") if kind == "step" else None
        self.loss = record["loss"] if kind == "step" else record["train_loss"]
        self.losses = record.get("losses", {})

    def __repr__(self):
        where = f"step {self.step}" if self.kind == "step" else "end"
        return f"rtf.Progress(epoch={self.epoch}, {where}, loss={self.loss:.4f})"


def _train_argv(options):
    """``rtf train``'s command line for ``options`` (names with ``_`` for ``-``): True is a
    flag given, False / None an option left out, (w, h) a size, a list repeated values."""
    known = dict(_rtf.train_options())
    argv = []
    for name, value in options.items():
        if name not in known:
            raise TypeError(
                f"rtf.train() got an unknown option {name!r}; rtf train's options are: "
                + ", ".join(sorted(known))
            )
        if value is None or value is False:
            continue
        flag = "--" + name.replace("_", "-")
        if not known[name]:
            if value is not True:
                raise TypeError(f"rtf.train(): {name} is a flag: True or False, got {value!r}")
            argv.append(flag)
        elif isinstance(value, tuple) and len(value) == 2:
            argv += [flag, f"{value[0]}x{value[1]}"]
        else:
            argv += [flag, str(value)]
    return argv


def train(out=None, model=None, data=None, recipe=None, epochs=None, progress=None,
          resume=None, **options):
    """Trains as ``rtf train`` does, with every option of the command by name (``-`` as
    ``_``; a flag is True; ``resize=(w, h)``): ``out`` (the run folder), ``model``, ``data``,
    ``recipe``, ``epochs``, ``resume`` (a run folder to continue exactly; ``epochs`` then
    extends it), and the others (``batch_size``, ``lr``, ``optimizer``, ``seed``,
    ``no_augment``, ``precision``, ``teacher``, ...: ``rtf train --help``). ``progress`` is
    called with a :class:`Progress` after every step and every epoch; an exception it raises
    stops the run (checkpointed) and is raised here. Ctrl-C stops the run after the step in
    flight, writes its checkpoint and raises KeyboardInterrupt; ``rtf.train(resume=out)``
    continues it. Returns the run folder as :class:`Run`; its final weights are equal to
    the command's for the same options."""
    options = dict(out=out, model=model, data=data, recipe=recipe, epochs=epochs,
                   resume=resume, **options)
    argv = _train_argv(options)

    def report(kind, stage, record):
        progress(Progress(kind, stage, _json.loads(record)))

    run_dir, _ = _rtf.train(argv, dict(_os.environ), None if progress is None else report)
    return Run(run_dir)


class Calibration:
    """The calib.yaml ``rtf calibrate`` writes: ``yaml`` (its text, byte for byte), ``K`` (the
    thermal camera's 3x3 intrinsics), ``distortion``, ``rotation`` (3x3, RGB to thermal),
    ``translation`` (metres), ``loss``, ``verdict`` (``ok``, ``uncertain`` or ``failed``) and
    its ``reason``, ``map_error_bound_px`` (the error bound, pixels; None where the data leave
    the map free) and ``assessment`` (the whole quality record); ``json`` is the whole file as
    values."""

    def __init__(self, yaml, record):
        self.yaml = yaml
        self.json = record
        t = record["thermal"]
        self.K = [[t["fx"], 0.0, t["cx"]], [0.0, t["fy"], t["cy"]], [0.0, 0.0, 1.0]]
        self.distortion = t["distortion"]
        self.rotation = record["extrinsic"]["rotation"]
        self.translation = record["extrinsic"]["translation"]
        # calib.yaml's `quality`: the solver's figures and, flattened in, the assessment.
        quality = record.get("quality") or {}
        self.loss = quality.get("loss")
        self.assessment = quality or None
        self.verdict = quality.get("verdict")
        self.reason = quality.get("reason")
        self.map_error_bound_px = quality.get("map_error_bound_px")

    def __repr__(self):
        return f"rtf.Calibration(verdict={self.verdict!r}, loss={self.loss})"


def calibrate(rig, out=None, recipe="default", iterations=None, batch_size=None,
              learning_rate=None, seed=0, threads=1):
    """Calibrates the thermal camera of the rig described by ``rig`` (a rig.yaml) against its
    RGB camera, without a target, as ``rtf calibrate --rig RIG`` does with the same options
    (``recipe``: "default" or "paper"; ``iterations``, ``batch_size``, ``learning_rate``
    override the recipe's and the rig file's; ``seed``; ``threads``: libtorch CPU threads).
    Writes calib.yaml to ``out`` if given (atomically; never over the rig or an input it
    lists). Returns :class:`Calibration`, equal to the file the command writes."""
    yaml, record = _rtf.calibrate_yaml(str(rig), None if out is None else str(out), recipe,
                                       iterations, batch_size, learning_rate, seed, threads)
    return Calibration(yaml, _json.loads(record))


__all__ = [
    "Calibration",
    "CalibrationError",
    "DataError",
    "Dataset",
    "Error",
    "EvalError",
    "Epoch",
    "Frame",
    "InputError",
    "Loader",
    "ModelError",
    "Network",
    "Progress",
    "Run",
    "Scores",
    "Split",
    "TORCH_VERSION",
    "TorchError",
    "TrainError",
    "__version__",
    "calibrate",
    "evaluate",
    "load_network",
    "models",
    "open_dataset",
    "train",
]
