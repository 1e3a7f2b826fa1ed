"""Train Bayesian SegNet on a labelled dataset (``hd train``): datasets, normalisation, run config.

``fit`` builds the training and validation ``HazardDataset`` at the training noise level, both
normalised with the training split's min and max, and hands them to ``hdnet.train.train``. What
evaluation needs to prepare new inputs exactly like the training inputs is stored in the run's
``config.json`` and in every checkpoint under ``extra_config`` (see ``RUN_DATA_KEYS``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from hdnet import defaults
from hdnet.data import (
    HazardDataset,
    Normalisation,
    compute_normalisation,
    open_labeling,
)
from hdnet.errors import HdNetError
from hdnet.profiles import TrainingProfile, get_profile
from hdnet.train import train
from lidarsim.shards import MANIFEST_NAME, sha256_file

RUN_DATA_KEYS = ("dataset", "manifest_sha256", "labels", "labeling", "train_sigma_m", "normalisation", "input_size",
                 "input_rule", "dem_shape")


def input_rule(input_size: int | None) -> str:
    """How DEMs reach the network: ``resize:N`` (bilinear to N x N) or ``pad:32`` (edge padding)."""
    return f"resize:{input_size}" if input_size is not None else f"pad:{defaults.SIZE_MULTIPLE_PX}"


def run_data_config(
    dataset_dir: str | os.PathLike, labels: str, sigma_m: float, normalisation: Normalisation,
    profile: TrainingProfile, dem_shape: tuple[int, int], labeling: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The ``extra_config`` of a run: the data a model was trained on and how inputs were prepared.

    ``labeling`` is the dataset manifest's entry of the labelling trained on (lander, DEM grid, label
    convention); it is kept without its shard list, so a run can be used without its dataset.
    """
    root = Path(dataset_dir).resolve()
    return {
        "dataset": str(root),
        "manifest_sha256": sha256_file(root / MANIFEST_NAME),
        "labels": labels,
        "labeling": {k: v for k, v in (labeling or {}).items() if k != "shards"},
        "train_sigma_m": float(sigma_m),
        "normalisation": normalisation.to_dict(),
        "input_size": profile.input_size,
        "input_rule": input_rule(profile.input_size),
        "dem_shape": list(dem_shape),
    }


def fit(
    dataset_dir: str | os.PathLike,
    run_dir: str | os.PathLike,
    profile_name: str = "cpu",
    epochs: int | None = None,
    train_sigma_m: float = defaults.TRAIN_SIGMA_M,
    seed: int = 0,
    resume: bool = False,
    labels: str | None = None,
    progress: bool = True,
    num_workers: int = 0,
) -> Path:
    """Train a model on ``dataset_dir`` at noise level ``train_sigma_m`` (metres); returns ``last.pt``.

    Raises:
        HdNetError: a dataset without labels, a sigma not in the dataset, an empty training or
            validation split, an unknown profile, or anything ``hdnet.train.train`` refuses.
    """
    profile = get_profile(profile_name)
    open_labeling(dataset_dir, labels)  # the clear "no labels" error first
    normalisation = compute_normalisation(dataset_dir, train_sigma_m, labels)
    common = {"sigma_m": train_sigma_m, "input_size": profile.input_size, "labels": labels, "normalisation": normalisation}
    train_ds = HazardDataset(dataset_dir, "train", **common)  # type: ignore[arg-type]
    val_ds = HazardDataset(dataset_dir, "val", **common)  # type: ignore[arg-type]
    for name, ds in (("train", train_ds), ("val", val_ds)):
        if len(ds) == 0:
            raise HdNetError(f"{dataset_dir}: the {name} split is empty; build a dataset with more scans.")
    extra = run_data_config(dataset_dir, train_ds.labels, train_ds.sigma_m, normalisation, profile, train_ds.dem_shape,
                            labeling=train_ds.entry)
    return train(run_dir, train_ds, val_ds, profile, epochs=epochs, seed=seed, resume=resume, progress=progress,
                 extra_config=extra, num_workers=num_workers)
