"""Which scans ``hd eval`` scores (``--split``), and which of them also calibrated H_t or trained the run.

The paper scores the test split; ``--split val``, ``train`` or ``all`` (every scan of the dataset
once, for a dataset built for evaluation only) score another. H_t is still calibrated on validation
splits (``hdnet.evaluate.calibration_datasets``: the run's own training data when present, else the
evaluated dataset's): where the evaluated dataset is one of them (the same manifest) and the scored
split holds its validation scans, those scans are scored with a threshold chosen on them (in-sample:
the rates there are optimistic, and a ``risk:ALPHA`` bound does not cover them); where the run was
trained on the evaluated dataset and the split holds its training scans, those are scored too. hd
scores them all the same, since a dataset built for evaluation may be the only data at hand, and says
so: the counts go into ``report.json``'s ``run`` record, a warning to the terminal and a line of
``report.md`` (docs/evaluation.md, "Which split is scored").

The scan counts come from the manifest's ``splits``, before anything is inferred.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

from hdnet.data import ALL_SPLITS, SPLITS
from hdnet.errors import HdNetError
from hdnet.report_json import ReportRunJson
from hdnet.run_record import TrainingData
from lidarsim.location import manifest_sha256
from lidarsim.shards import read_manifest

DEFAULT_SPLIT = "test"  # the paper's: a report of it records no split (its bytes as before --split)


@dataclass(frozen=True)
class ScoredSplit:
    """The split an evaluation scores (``name``: ``test``, ``val``, ``train`` or ``all``) and its scans:
    ``scans`` in all, ``calibration_scans`` of them the validation scans that calibrated H_t,
    ``training_scans`` of them scans the run was trained on (counts from the manifest)."""

    name: str
    scans: int
    calibration_scans: int = 0
    training_scans: int = 0

    @property
    def is_default(self) -> bool:
        """True for the test split, whose report records no split."""
        return self.name == DEFAULT_SPLIT

    def record(self) -> ReportRunJson:
        """The entries of report.json's ``run`` record: none for the default split; else the split and
        its scans scored, and the overlaps when there are any."""
        if self.is_default:
            return {}
        out: ReportRunJson = {"split": self.name, "scored_scans": self.scans}
        if self.calibration_scans:
            out["calibration_scans_scored"] = self.calibration_scans
        if self.training_scans:
            out["training_scans_scored"] = self.training_scans
        return out

    def warnings(self) -> list[str]:
        """One sentence per overlap (none without one), for the terminal."""
        out = []
        if self.calibration_scans:
            out.append(
                f"--split {self.name} scores the {self.calibration_scans} validation scans H_t was calibrated on "
                "(of the evaluated dataset): their rates are in-sample and optimistic; --calibrate-on OTHER_DATASET "
                "calibrates elsewhere"
            )
        if self.training_scans:
            out.append(
                f"--split {self.name} scores {self.training_scans} scans the run was trained on: their scores are "
                "not those of unseen data"
            )
        return out


def scored_split(
    split: str,
    dataset_dir: str | os.PathLike,
    calibration_datasets: Sequence[str | os.PathLike],
    training: TrainingData,
) -> ScoredSplit:
    """The scans ``split`` holds in ``dataset_dir``, and which of them are validation scans of a
    calibration dataset (``calibration_datasets``) or training scans of the run (``training``);
    datasets are the same when their manifests are (a copy at another path included).

    Raises:
        HdNetError: an unknown split, or one without scans (the dataset's counts named).
    """
    if split != ALL_SPLITS and split not in SPLITS:
        raise HdNetError(f"--split must be one of {', '.join(SPLITS)} or {ALL_SPLITS}, got {split!r}.")
    splits = read_manifest(dataset_dir).get("splits", {})
    counts = {name: int(splits.get(name, 0)) if isinstance(splits, dict) else 0 for name in SPLITS}
    names = SPLITS if split == ALL_SPLITS else (split,)
    scans = sum(counts[n] for n in names)
    if scans == 0:
        held = ", ".join(f"{counts[n]} {n}" for n in SPLITS)
        raise HdNetError(f"{dataset_dir}: the {split} split is empty (the dataset holds {held} scans).")
    digest = manifest_sha256(dataset_dir)
    calibrated = "val" in names and any(manifest_sha256(d) == digest for d in calibration_datasets)
    trained_on = {training.manifest_sha256, *(a.manifest_sha256 for a in training.also)}
    trained = "train" in names and digest in trained_on
    return ScoredSplit(split, scans, counts["val"] if calibrated else 0, counts["train"] if trained else 0)
