"""Train Bayesian SegNet on a labelled dataset (``hd train``): datasets, input spec, run config.

``fit`` builds the run's ``InputSpec`` from the profile (the paper's min-max heights take the
training split's min and max at the training noise level), the training and validation
``HazardDataset`` at that noise level (D4 augmentation on the training split only, when the profile
asks for it), and hands them to ``hdnet.train.train``. What evaluation and inference need to
prepare new inputs exactly like the training inputs is stored in the run's ``config.json`` and in
every checkpoint under ``extra_config`` (see ``RUN_DATA_KEYS``; ``input`` is the ``InputSpec``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from hdnet import defaults
from hdnet.augment import check_augment
from hdnet.data import (
    HazardDataset,
    compute_normalisation,
    dem_spacing_m,
    lander_of,
    open_labeling,
)
from hdnet.errors import HdNetError
from hdnet.inputs import InputSpec, Normalisation
from hdnet.profiles import TrainingProfile, get_profile
from hdnet.train import train
from lidarsim.shards import MANIFEST_NAME, sha256_file

RUN_DATA_KEYS = ("dataset", "manifest_sha256", "labels", "train_sigma_m", "normalisation", "input_size", "input_rule",
                 "dem_shape", "input")


def input_rule(input_size: int | None, size_multiple: int = defaults.SIZE_MULTIPLE_PX) -> str:
    """How DEMs reach the network: ``resize:N`` (bilinear to N x N) or ``pad:M`` (edge padding to a multiple of M)."""
    return f"resize:{input_size}" if input_size is not None else f"pad:{size_multiple}"


def input_spec_for(profile: TrainingProfile, spacing_m: float, normalisation: Normalisation | None) -> InputSpec:
    """The ``InputSpec`` a profile asks for on DEMs of ``spacing_m`` metres per pixel."""
    return InputSpec(
        heights=profile.heights,
        normalisation=normalisation,
        height_scale_m=profile.height_scale_m,
        extra_channels=tuple(profile.extra_channels),
        spacing_m=spacing_m,
        input_size=profile.input_size,
        size_multiple=2**profile.depth,
    )


def run_data_config(
    dataset_dir: str | os.PathLike, labels: str, sigma_m: float, spec: InputSpec, dem_shape: tuple[int, int],
) -> dict[str, Any]:
    """The ``extra_config`` of a run: the data a model was trained on and how inputs were prepared.

    ``input`` is the full ``InputSpec``; ``normalisation``, ``input_size`` and ``input_rule`` repeat
    parts of it for readers of older runs (``normalisation`` is None unless the heights are min-max).
    """
    root = Path(dataset_dir).resolve()
    return {
        "dataset": str(root),
        "manifest_sha256": sha256_file(root / MANIFEST_NAME),
        "labels": labels,
        "train_sigma_m": float(sigma_m),
        "normalisation": None if spec.normalisation is None else spec.normalisation.to_dict(),
        "input_size": spec.input_size,
        "input_rule": spec.rule,
        "dem_shape": list(dem_shape),
        "input": spec.to_dict(),
    }


def fit(
    dataset_dir: str | os.PathLike,
    run_dir: str | os.PathLike,
    profile_name: str | TrainingProfile = "cpu",
    epochs: int | None = None,
    train_sigma_m: float = defaults.TRAIN_SIGMA_M,
    seed: int = 0,
    resume: bool = False,
    labels: str | None = None,
    progress: bool = True,
    num_workers: int = 0,
    stop_after: int | None = None,
) -> Path:
    """Train a model on ``dataset_dir`` at noise level ``train_sigma_m`` (metres); returns ``last.pt``.

    ``profile_name`` is a profile's name or a ``TrainingProfile`` (e.g. a variant in an ablation);
    ``stop_after`` ends this call after that many epochs of the ``epochs``-long schedule (resume later).

    Raises:
        HdNetError: a dataset without labels, a sigma not in the dataset, an empty training or
            validation split, an unknown profile, or anything ``hdnet.train.train`` refuses.
    """
    profile = profile_name if isinstance(profile_name, TrainingProfile) else get_profile(profile_name)
    entry, _ = open_labeling(dataset_dir, labels)  # the clear "no labels" error first
    check_augment(profile.augment, lander_of(entry))
    normalisation = compute_normalisation(dataset_dir, train_sigma_m, labels) if profile.heights == "minmax" else None
    spec = input_spec_for(profile, dem_spacing_m(entry), normalisation)
    common = {"sigma_m": train_sigma_m, "labels": labels, "input_spec": spec}
    train_ds = HazardDataset(dataset_dir, "train", augment=profile.augment, **common)  # type: ignore[arg-type]
    val_ds = HazardDataset(dataset_dir, "val", **common)  # type: ignore[arg-type]
    for name, ds in (("train", train_ds), ("val", val_ds)):
        if len(ds) == 0:
            raise HdNetError(f"{dataset_dir}: the {name} split is empty; build a dataset with more scans.")
    extra = run_data_config(dataset_dir, train_ds.labels, train_ds.sigma_m, spec, train_ds.dem_shape)
    return train(run_dir, train_ds, val_ds, profile, epochs=epochs, seed=seed, resume=resume, progress=progress,
                 extra_config=extra, num_workers=num_workers, stop_after=stop_after)
