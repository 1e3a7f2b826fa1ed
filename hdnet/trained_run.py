"""One trained run as ``hd eval`` and ``hd detect`` read it: the checkpoint file, its network, what the
checkpoint says of its training (``CheckpointHeader``) and the data it was trained on (``TrainingData``).

The checkpoint dictionary is read here once and not passed on: everything after this reads the typed
record (``hdnet.run_record``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import torch

from hdnet.model import BayesianSegNet
from hdnet.run_record import CheckpointHeader, TrainingData, checkpoint_data, unfinished_training
from hdnet.train import load_checkpoint, load_trained_model


@dataclass(frozen=True)
class TrainedRun:
    """A loaded run: ``checkpoint`` (the file), ``model`` (in eval mode, on the device it was loaded
    to), ``header`` (epoch, profile, model config) and ``data`` (its training data and input
    preparation; ``data.labeling`` the labelling entry it was trained on, when recorded)."""

    checkpoint: Path
    model: BayesianSegNet = field(repr=False)
    header: CheckpointHeader
    data: TrainingData

    @classmethod
    def load(cls, path: str | os.PathLike, device: torch.device | str = "cpu") -> TrainedRun:
        """The run of the checkpoint at ``path``, its model on ``device``.

        Raises:
            HdNetError: a damaged checkpoint, one of another model or schema, or one not trained by
                ``hdnet.fit`` (no training data record); the message names ``path``.
        """
        model, ckpt = load_trained_model(Path(path), map_location=device)
        return cls(Path(path), model, CheckpointHeader.of(ckpt), checkpoint_data(ckpt, path))

    @property
    def unfinished(self) -> str | None:
        """A sentence with the epochs done and planned when the run's training has not finished, else
        None (``hdnet.run_record.unfinished_training``)."""
        return unfinished_training(self.checkpoint, self.header.epoch)


def recorded_training_data(path: str | os.PathLike) -> TrainingData:
    """The training data a checkpoint records, without building its network (a report checked for reuse).

    Raises:
        HdNetError: as :meth:`TrainedRun.load`.
    """
    return checkpoint_data(load_checkpoint(Path(path)), path)
