"""The keys of ``report.json``'s (and ``detect.json``'s) JSON sections as typed records.

``hd eval`` writes ``report.json`` and ``hd view``, ``hd compare`` and the figures read it back;
``hd detect`` records the same threshold record in ``detect.json``, and the threshold cache keeps it.
These sections are ``TypedDict``: at run time the dictionaries the file holds (keys in the order hd
writes them), for mypy records whose every key a reader names is checked with its type.
docs/evaluation.md describes the report.
"""

from __future__ import annotations

from typing import NotRequired, TypedDict

from hdnet.run_json import InputSpecJson, TrainingNoiseJson

__all__ = [
    "AchievedRiskJson",
    "CalibrationJson",
    "CalibrationRowJson",
    "PerSigmaThresholdJson",
    "ReportJson",
    "ReportRowJson",
    "ReportRunJson",
    "SweepRowJson",
    "ThresholdJson",
    "recorded_noise",
]


class PerSigmaThresholdJson(TypedDict):
    """H_t calibrated at one noise level (``--calibrate each``)."""

    calibration_sigma_m: float
    value_nats: float | None  # None: unbounded
    mean_nats: float
    value_quantile: float
    guarded: bool


class AchievedRiskJson(TypedDict):
    """The false-safe rate a ``risk:ALPHA`` threshold achieved on one test table and noise level."""

    test_sigma_m: float
    table: str
    false_safe_rate: float | None


class ThresholdJson(TypedDict, total=False):
    """The threshold record: the rule, H_t (nats) and how it was calibrated. A record holds the keys
    its rule and calibration give (``hdnet.evaluate.validation_threshold``, ``hdnet.detect``)."""

    spec: str  # mean, quantile:Q, risk:ALPHA, nats:H
    kind: str  # the rule's name; "fixed" for nats:H in hd detect
    parameter: float | None
    value_nats: float | None  # None: unbounded (every pixel certain)
    mean_nats: float
    mean_quantile: float
    value_quantile: float
    calibration_split: str
    calibration_sigma_m: float
    calibration_images: int
    calibration_pixels: int
    unreachable: bool  # risk:ALPHA: too few calibration images for alpha
    needs_images: int
    uncertainty: str  # the score (absent: predictive entropy)
    guarded: bool  # capped by the precision guard above the training noise levels
    guard_precision: float
    guard_nats: float | None
    calibrate: str  # reference or each
    calibration_dataset: str
    calibration_datasets: list[str]
    calibration_labels: str
    calibration_source: str
    calibration_note: str
    per_sigma: list[PerSigmaThresholdJson]
    alpha: float | None
    achieved_risk: list[AchievedRiskJson]
    cached: str  # hd detect: the threshold cache it was read from


class SweepRowJson(TypedDict):
    """One row of the threshold sweep: the test split at one noise level thresholded at one quantile
    of the validation scores."""

    test_sigma_m: float
    quantile: float
    threshold_nats: float
    vc_fraction: float | None
    pixel_accuracy: float
    miou: float
    precision: float
    sensitivity: float


class CalibrationRowJson(TypedDict):
    """The reliability of P(safe) at one noise level: expected calibration error and its bins."""

    test_sigma_m: float
    ece: float
    bin_edges: list[float]
    bin_count: list[int]
    bin_mean_prob: list[float]
    bin_safe_fraction: list[float]


class CalibrationJson(TypedDict):
    """``calibration``: the number of bins and one row per noise level."""

    bins: int
    per_sigma: list[CalibrationRowJson]


class ReportRunJson(TypedDict, total=False):
    """``run``: the checkpoint evaluated, how it was trained, the dataset and the evaluation's settings
    (``hdnet.evaluate``; reports written by earlier versions lack the later keys)."""

    checkpoint: str
    checkpoint_sha256: str
    batch_size: int
    epoch: int  # the checkpoint's header (hdnet.run_record.CheckpointHeader)
    profile: str | None
    model_config: dict[str, float | int] | None
    train_sigma_m: float
    train_noise: TrainingNoiseJson
    sigma_sweep_m: list[float]
    input_size: int | None
    input: InputSpecJson
    dataset: str
    manifest_sha256: str
    labels: str
    truth: str
    same_dataset_as_training: bool
    sigmas_m: list[float]
    mc_samples: int
    drop_pixels: int
    seed: int
    test_scans: int  # the test split's scans scored (the default split only)
    val_scans: int
    paper_dataset: bool
    split: str  # --split other than test: the split scored (hdnet.scored_split), and its scans
    scored_scans: int
    calibration_scans_scored: int  # of them, validation scans that calibrated H_t (only when any)
    training_scans_scored: int  # of them, scans the run was trained on (only when any)


class ReportRowJson(TypedDict):
    """One row of Table 1, Table 2 or the noise sweep (``hdnet.results.ReportRow``; NaN written as null)."""

    table: str
    method: str
    train_sigma_m: float | None
    test_sigma_m: float
    vc_fraction: float | None
    pixel_accuracy: float | None
    miou: float | None
    precision: float | None
    sensitivity: float | None


class ReportJson(TypedDict):
    """``report.json`` (``hdnet.report.report_dict``; ``hd compare`` and ``hd view`` read it back after
    ``hdnet.compare``'s structure check, which requires the rows, threshold and run only)."""

    rows: list[ReportRowJson]
    threshold: ThresholdJson
    sweep: NotRequired[list[SweepRowJson]]
    calibration: NotRequired[CalibrationJson]
    run: ReportRunJson
    landing: NotRequired[list[dict[str, object]]]  # hdnet.results.LandingRow, one per row
    landing_settings: NotRequired[dict[str, object]]  # hdnet.results.LandingRecord


def recorded_noise(noise: TrainingNoiseJson | None) -> tuple[tuple[float, float] | None, list[float]]:
    """The training noise a report records (``run.train_noise``): its range (lo, hi metres; None for
    levels) and its levels (metres); neither in a report that records none."""
    if not noise:
        return None, []
    range_m = noise.get("range_m")
    return (None if not range_m else (float(range_m[0]), float(range_m[1]))), list(noise.get("levels_m") or [])
