"""The keys of a checkpoint (``last.pt``, ``best.pt``) and of its rows as typed records.

A checkpoint is a dictionary that ``torch.save`` writes (weights only: tensors and plain types) and
``hdnet.train.load_checkpoint`` reads back and checks; its rows go to ``metrics.csv`` and to
``hd train``'s progress. They are ``TypedDict``: at run time the dictionaries the file holds, for
mypy records whose keys and value types are checked. docs/hdnet.md ("Checkpoints") describes them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NotRequired, TypedDict

if TYPE_CHECKING:  # annotations only: hd --help imports no PyTorch
    import torch

__all__ = [
    "CheckpointJson",
    "EpochProgress",
    "EpochRow",
    "EpochTiming",
    "JsonObject",
    "NumpyRngState",
    "PythonRngState",
    "RngState",
]

# ``extra_config``: the JSON object ``hdnet.train.train`` is given to record (``hdnet.fit``'s is a
# ``hdnet.run_record.TrainingData``); its readers check what they read of it.
JsonObject = dict[str, object]


class EpochRow(TypedDict):
    """One epoch's metrics (a row of ``metrics.csv`` and of the checkpoint's ``history``)."""

    epoch: int
    train_loss: float
    val_loss: float
    val_pixel_accuracy: float
    val_miou: float
    lr: float
    train_images_per_s: NotRequired[float]  # the row given to a progress callback


# Training progress: bars (True), nothing (False), or a function given each epoch's row and the
# number of epochs planned (``hd train``'s lines, ``--json``'s records).
EpochProgress = bool | Callable[[EpochRow, int], None]


class EpochTiming(TypedDict):
    """One epoch's wall-clock figures (the checkpoint's ``timing``, apart from the history)."""

    epoch: int
    train_seconds: float
    train_images_per_s: float


class NumpyRngState(TypedDict):
    """NumPy's legacy global state (``np.random.get_state()``), its key as a tensor."""

    name: str
    key: torch.Tensor
    pos: int
    has_gauss: int
    cached_gaussian: float


class PythonRngState(TypedDict):
    """Python's ``random`` state (``random.getstate()``), its Mersenne Twister state as a tensor."""

    version: int
    state: torch.Tensor
    gauss_next: float | None


class RngState(TypedDict):
    """One process's random number generators, as a resumed run restores them."""

    torch: torch.Tensor
    cuda: torch.Tensor | None
    numpy: NumpyRngState
    python: PythonRngState


class CheckpointJson(TypedDict):
    """A checkpoint (schema ``hdnet.checkpoint``); the training state keys are absent in checkpoints
    written by other tools of hd (a benchmark's untrained network) and in schema 1."""

    schema: str
    schema_version: int
    model_name: str
    model_config: dict[str, float | int]  # hdnet.model.ModelConfig
    profile: NotRequired[dict[str, object]]  # hdnet.profiles.TrainingProfile.to_dict
    epoch: int
    seed: NotRequired[int]
    model: dict[str, torch.Tensor]  # the state dict
    optimizer: NotRequired[dict[str, Any]]  # torch.optim.Optimizer.state_dict: PyTorch's own structure
    rng: NotRequired[list[RngState]]  # one per process
    history: NotRequired[list[EpochRow]]
    timing: NotRequired[list[EpochTiming]]
    extra_config: NotRequired[JsonObject]
    hd_version: NotRequired[str]
    content_sha256: NotRequired[str]  # schema 2: the digest of everything else
