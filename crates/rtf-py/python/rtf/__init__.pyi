"""Type stubs of the package `rtf` (the extension rtf._rtf and the Python layer)."""

from os import PathLike
from pathlib import Path
from typing import Any, Callable, Iterator, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt
import torch

_Path = Union[str, "PathLike[str]"]

__version__: str
TORCH_VERSION: str

class Error(Exception): ...
class DataError(Error): ...
class ModelError(Error): ...
class EvalError(Error): ...
class InputError(Error): ...
class TorchError(Error): ...
class CalibrationError(Error): ...
class TrainError(Error): ...

class Run:
    dir: Path
    config: Optional[dict[str, Any]]
    epochs: list[dict[str, Any]]
    stages: list[str]
    best: Optional[Path]
    final: Optional[Path]
    weights: Optional[Path]
    def __init__(self, path: _Path) -> None:
        """A training run folder read back: config, per-epoch log, stages, weights files."""
    def stage(self, name: str) -> "Run": ...

class Progress:
    kind: str
    stage: str
    epoch: int
    step: Optional[int]
    loss: float
    losses: dict[str, float]
    record: dict[str, Any]

def train(
    out: Optional[_Path] = None,
    model: Optional[str] = None,
    data: Optional[_Path] = None,
    recipe: Optional[str] = None,
    epochs: Optional[int] = None,
    progress: Optional[Callable[[Progress], None]] = None,
    resume: Optional[_Path] = None,
    **options: Any,
) -> Run:
    """Trains as `rtf train` does with the same options by name (`-` as `_`, flags True,
    `resize=(w, h)`); `progress` gets every step and epoch; Ctrl-C checkpoints and raises
    KeyboardInterrupt, `resume=` continues. The run folder, read back."""

class Calibration:
    yaml: str
    json: dict[str, Any]
    K: list[list[float]]
    distortion: list[float]
    rotation: list[list[float]]
    translation: list[float]
    loss: Optional[float]
    verdict: Optional[str]
    reason: Optional[str]
    map_error_bound_px: Optional[float]
    assessment: Optional[dict[str, Any]]

def calibrate(
    rig: _Path,
    out: Optional[_Path] = None,
    recipe: str = "default",
    iterations: Optional[int] = None,
    batch_size: Optional[int] = None,
    learning_rate: Optional[float] = None,
    seed: int = 0,
    threads: int = 1,
) -> Calibration:
    """Calibrates the rig's thermal camera as `rtf calibrate --rig RIG` does; the calib.yaml it
    writes (to `out` too, if given)."""

def models() -> list[dict[str, Any]]:
    """One record per network: name, parameters, megabytes, inputs, classes."""

def load_network(
    name: str,
    weights: Optional[_Path] = None,
    classes: Optional[str] = None,
    device: str = "cpu",
    precision: Optional[str] = None,
) -> Network:
    """Loads network `name` with `weights` as `rtf predict` does (None: random weights)."""

class Network:
    name: str
    weights: Optional[str]
    inputs: str
    training: bool
    @property
    def classes(self) -> list[dict[str, Any]]: ...
    @property
    def device(self) -> str: ...
    def logits(
        self,
        rgb: npt.NDArray[np.uint8],
        thermal: npt.NDArray[Any],
        thermal_range: Optional[tuple[float, float]] = None,
    ) -> npt.NDArray[np.float32]:
        """Logits [classes, H, W] of one frame, equal to `rtf predict --logits`."""
    def predict(
        self,
        rgb: npt.NDArray[np.uint8],
        thermal: npt.NDArray[Any],
        thermal_range: Optional[tuple[float, float]] = None,
    ) -> npt.NDArray[np.uint8]:
        """Class ids H×W in the dataset's own label values."""
    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """Logits [B, classes, H, W] of a tensor [B, 4, H, W] on the network's device."""
    def colorize(self, ids: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]: ...
    def parameters(self) -> list[torch.Tensor]: ...
    def save(self, path: _Path, overwrite: bool = False) -> None: ...
    def train(self, mode: bool = True) -> Network: ...
    def eval(self) -> Network: ...

def open_dataset(root: _Path) -> Dataset:
    """Opens a dataset root as `rtf train` and `rtf eval` do."""

class Dataset:
    root: str
    @property
    def classes(self) -> list[dict[str, Any]]: ...
    @property
    def ignore_id(self) -> Optional[int]: ...
    @property
    def layout(self) -> str: ...
    @property
    def splits(self) -> list[str]: ...
    def split(self, name: str, labels: bool = True) -> Split: ...
    def loader(
        self,
        split: str,
        batch_size: int,
        shuffle: bool = True,
        augment: bool = True,
        workers: int = 2,
        seed: int = 0,
        size: Optional[tuple[int, int]] = None,
        model: Optional[str] = None,
        epoch: int = 0,
        recipe: Optional[str] = None,
    ) -> Loader:
        """The training batches `rtf train --data ROOT --train-split SPLIT` makes with these
        options (the trainer's own loader); each iteration is the next epoch."""

class Split:
    name: str
    @property
    def names(self) -> list[str]: ...
    def __len__(self) -> int: ...
    def __getitem__(self, index: int) -> Frame: ...

class Frame:
    name: str
    daytime: Optional[str]
    rgb: npt.NDArray[np.uint8]
    thermal: npt.NDArray[np.float32]
    label: Optional[npt.NDArray[np.uint8]]

class Loader:
    def __len__(self) -> int: ...
    def __iter__(self) -> Epoch: ...
    def epoch(self, epoch: int) -> Epoch: ...

class Epoch:
    epoch: int
    def __iter__(self) -> Iterator[tuple[torch.Tensor, torch.Tensor]]: ...
    def __next__(self) -> tuple[torch.Tensor, torch.Tensor]: ...

class Scores:
    json: dict[str, Any]
    frames: int
    class_names: list[str]
    confusion: list[list[int]]
    day: Optional[Scores]
    night: Optional[Scores]
    miou: float
    macc: float
    miou_mfnet: float
    pixel_acc: float
    pixels: int
    per_class: dict[str, Optional[float]]
    per_class_acc: dict[str, Optional[float]]

def evaluate(
    net: Network,
    data: Dataset,
    split: str = "test",
    sliding: bool = False,
    scales: Optional[Sequence[float]] = None,
    flip: bool = False,
    batch_size: int = 4,
    resize: Optional[tuple[int, int]] = None,
) -> Scores:
    """Scores `net` on `split` of `data` as `rtf eval` does (equal to `rtf eval --json`)."""
