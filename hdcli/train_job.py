"""``hd train``: the noise levels asked for, the training (or "done already"), and what to say.

The settings are :class:`hdnet.fit.FitConfig`'s fields and :class:`TrainingNoiseOptions`' (each
described once, as field metadata); :func:`train_job` makes the configuration and trains.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hdcore.outcome import Done
from hdcore.setting import check, setting, settings_from_options
from hdnet import limits
from hdnet.checkpoint_json import EpochProgress
from hdnet.errors import HdNetError


@dataclass(frozen=True)
class TrainingNoiseOptions:
    """``hd train``'s noise levels of the training inputs, as typed: levels or a ``LOW:HIGH`` range."""

    train_sigma: tuple[float, ...] = setting(
        (),
        "Noise level of the training inputs, {unit}; repeat it to train on several (one drawn per sample and "
        "epoch; levels the dataset does not store are made from its clean points). Default: the profile's "
        "range, else the dataset's noise level when it has only one, else 1.67 cm, the paper's.",
        unit="metres",
        bound=limits.NOISE_SIGMA_M,
    )
    train_sigma_range: str | None = setting(
        None,
        "Train across noise levels from LOW to HIGH {unit} (e.g. 0:0.10), drawn uniformly per sample and "
        "epoch, the noisy DEMs made from the dataset's clean points.",
        unit="metres",
        kind=str,
        metavar="LOW:HIGH",
    )

    def __post_init__(self) -> None:
        check(self, HdNetError)

    def fit_settings(self) -> dict[str, Any]:
        """``train_sigma_m`` and ``train_noise`` of a :class:`~hdnet.fit.FitConfig`.

        Raises:
            HdNetError: both forms given, or a malformed range.
        """
        from hdnet.noise_levels import TrainingNoise, parse_sigma_range

        if self.train_sigma and self.train_sigma_range is not None:
            raise HdNetError("--train-sigma and --train-sigma-range exclude each other")
        noise = None
        if self.train_sigma_range is not None:
            noise = TrainingNoise(range_m=parse_sigma_range(self.train_sigma_range))
        elif len(self.train_sigma) > 1:
            noise = TrainingNoise(levels_m=tuple(self.train_sigma))
        one = self.train_sigma[0] if len(self.train_sigma) == 1 else None
        return {"train_sigma_m": one, "train_noise": noise}


def train_job(
    dataset: Path | str,
    run_dir: Path,
    options: dict[str, Any],
    progress: EpochProgress,
) -> Done:
    """Train on ``dataset`` into ``run_dir`` with the command line's ``options`` (FitConfig's fields
    and TrainingNoiseOptions'), unless the same training is finished there already.

    Raises:
        HdNetError: options that exclude each other, bad values, and whatever ``fit`` refuses.
        StorageError / LabelStoreError: no dataset, no labels, an unknown labelling (before anything
            else is read or written).
    """
    from hdcli.pipeline import training_done_message
    from hdnet.chance import loss_warning
    from hdnet.fit import FitConfig, already_trained, check_distinct_datasets, fit
    from hdnet.preflight import check_dataset
    from hdnet.run_summary import run_record

    if options.get("resume") and options.get("overwrite"):
        raise HdNetError("--resume and --overwrite exclude each other")
    noise = settings_from_options(TrainingNoiseOptions, options).fit_settings()
    options["also"] = tuple(str(d) for d in options.get("also", ()))
    config = settings_from_options(FitConfig, options, progress=progress, **noise)
    check_dataset(dataset, config.labels)  # the dataset and its labelling before any run or data is touched
    check_distinct_datasets(dataset, config.also)
    if already_trained(dataset, run_dir, config):
        n = config.epochs if config.epochs is not None else config.training_profile().epochs
        said = (
            f"{run_dir} already holds this training, finished after {n} epochs with the same data, profile, seed "
            "and noise: nothing to do (--overwrite trains it again)"
        )
        return Done([said], {"command": "train", "already_done": True, **run_record(run_dir)})
    checkpoint = fit(dataset, run_dir, config)
    summary = run_record(run_dir)
    record = {"command": "train", "already_done": False, **summary}
    best = summary["best_epoch"]
    chance = loss_warning([best["val_loss"]] if best and "val_loss" in best else [])
    return Done([training_done_message(checkpoint, run_dir), *([chance] if chance else [])], record)
