"""Evaluation of a trained run (``hd eval``): thresholds, three methods per noise level, sweep, calibration.

Protocol (docs/evaluation.md; paper, "Results & Discussion"):

1. the threshold H_t of the uncertainty score (predictive entropy, the paper's, or mutual
   information: ``hdnet.uncertainty``) is calibrated on the validation split's scores at the
   training noise level (``mean``, ``quantile:Q`` or ``risk:ALPHA``, ``hdnet.thresholds``);
2. for every noise level of the dataset, the test split (``--split``: val, train or every scan once,
   ``hdnet.scored_split``) is run once through MC dropout; the mean
   softmax is brought back to the DEM grid (``HazardDataset.to_dem_grid``) and every method is
   scored from one confusion matrix over the whole split (``hdnet.metrics``):
   ``alhat_baseline`` (P(safe) >= 0.5 of the label shard), ``base_net`` (argmax of the mean
   softmax) and ``uncertainty_aware`` (base net without the pixels whose score is >= H_t);
3. the same inference serves the precision/sensitivity sweep over threshold quantiles, the expected
   calibration error of the safe probability and, for ``risk:ALPHA``, the false-safe rate achieved;
4. ``drop_pixels=K`` repeats step 2 with K dead pixels per test DEM, repaired bilinearly, the
   baseline recomputed on the repaired DEM and the lander-size neighbourhoods ignored for every
   method (table ``dead_pixels``, the paper's Table 2).

Inputs are prepared exactly as in training: ``hdnet.inputs.network_input`` with the run's
``InputSpec`` (from the checkpoint; runs older than input specs read as the paper's min-max).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hdcore.errors import HdError, HdWarning
from hdcore.storage import read_regular_text
from hdlabels import defaults as label_defaults
from hdlabels.alhat import safety_probability
from hdlabels.defaults import TRUTHS
from hdlabels.store import find_labeling, labelings_by_truth
from hdnet import defaults
from hdnet.data import (
    HazardDataset,
    dataset_sigmas,
    open_labeling,
    split_labels,
    stored_sigma_index,
)
from hdnet.errors import HdNetError
from hdnet.eval_settings import EvalConfig
from hdnet.infer import mc_dropout_predict
from hdnet.inputs import InputSpec
from hdnet.landing_table import landing_rows
from hdnet.metrics import ConfusionAccumulator, SegmentationMetrics
from hdnet.model import BayesianSegNet
from hdnet.noise_levels import TrainingNoise
from hdnet.preflight import check_inputs, check_run
from hdnet.report_json import (
    AchievedRiskJson,
    CalibrationRowJson,
    PerSigmaThresholdJson,
    ReportRunJson,
    SweepRowJson,
    ThresholdJson,
)
from hdnet.results import (
    METHODS,
    EvaluationResult,
    LandingRecord,
    LandingRow,
    LandingSettings,
    ReliabilityBins,
    ReportRow,
    SplitInference,
)
from hdnet.run_record import TrainingData
from hdnet.scored_split import ScoredSplit, scored_split
from hdnet.thresholds import (
    EntropyCalibration,
    ThresholdSpec,
    precision_threshold,
    select_threshold,
    warn_if_unreachable,
)
from hdnet.trained_run import TrainedRun, recorded_training_data
from hdnet.uncertainty import ENTROPY, UncertaintyScore, recorded_score, with_score
from lidarsim.location import dataset_key, dataset_label, dataset_location, manifest_sha256
from lidarsim.shards import read_manifest, sha256_file

# Where H_t is calibrated: once at the run's reference noise level (the paper), or at each test level.
# hd choice: above a run's training noise levels, `--calibrate each` calls a pixel certain-safe only
# where the validation split at that noise level shows at least this precision (the "above the
# training range" target of docs/results.md, "One network for all noise levels").
PRECISION_GUARD = 0.95
ECE_BINS = 15  # hd choice: bins of the reliability diagram (the common choice since Guo et al. 2017)
# The ALHAT baseline is safe where P(safe) >= this (paper, "Label generation"; one source: hdlabels.defaults).
BASELINE_THRESHOLD = label_defaults.SAFE_PROBABILITY_THRESHOLD


# --- pure scoring --------------------------------------------------------------------------------
def score(
    truth: np.ndarray, prediction: np.ndarray, ignore: np.ndarray | None = None, uncertain: np.ndarray | None = None
) -> SegmentationMetrics:
    """Dataset-level metrics from one confusion matrix (``hdnet.metrics``) over arrays of any shape."""
    acc = ConfusionAccumulator(uncertainty_aware=uncertain is not None)
    t = torch.from_numpy(np.ascontiguousarray(truth)).long()
    acc.update(
        t,
        torch.from_numpy(np.ascontiguousarray(prediction)).long(),
        ignore=None if ignore is None else torch.from_numpy(np.ascontiguousarray(ignore)),
        uncertain=None if uncertain is None else torch.from_numpy(np.ascontiguousarray(uncertain)),
    )
    return acc.compute()


def reliability(prob_safe: np.ndarray, truth_safe: np.ndarray, n_bins: int = ECE_BINS) -> ReliabilityBins:
    """Reliability bins and expected calibration error of P(safe) against the truth (1-D arrays).

    Bin b holds probabilities in [b/B, (b+1)/B) (the last bin includes 1).
    """
    p = np.asarray(prob_safe, np.float64).ravel()
    y = np.asarray(truth_safe, bool).ravel()
    edges = np.linspace(0.0, 1.0, n_bins + 1)
    b = np.clip((p * n_bins).astype(np.int64), 0, n_bins - 1)
    count = np.bincount(b, minlength=n_bins)
    sum_p = np.bincount(b, weights=p, minlength=n_bins)
    sum_y = np.bincount(b, weights=y.astype(np.float64), minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_p = np.where(count > 0, sum_p / count, np.nan)
        frac = np.where(count > 0, sum_y / count, np.nan)
    n = int(count.sum())
    ece = float(np.abs(sum_y - sum_p).sum() / n) if n else float("nan")
    return ReliabilityBins(edges, count, mean_p, frac, ece)


def method_rows(
    inf: SplitInference,
    table: str,
    train_sigma_m: float,
    threshold_nats: float,
    uncertainty: UncertaintyScore = ENTROPY,
) -> list[ReportRow]:
    """The three methods' rows for one split inference (uncertain: ``uncertainty`` >= ``threshold_nats``)."""
    out = []
    uncertain = uncertainty.of(inf) >= threshold_nats
    for method in METHODS:
        if method == "alhat_baseline":
            m = score(inf.label, inf.baseline_safe.astype(np.int64), inf.ignore)
        elif method == "base_net":
            m = score(inf.label, inf.prediction, inf.ignore)
        else:
            m = score(inf.label, inf.prediction, inf.ignore, uncertain)
        out.append(
            ReportRow(
                table,
                method,
                None if method == "alhat_baseline" else train_sigma_m,
                inf.sigma_m,
                m.vc_fraction,
                m.pixel_accuracy,
                m.miou,
                m.precision_safe,
                m.sensitivity_safe,
            )
        )
    return out


def false_safe_rate(inf: SplitInference, threshold_nats: float, uncertainty: UncertaintyScore = ENTROPY) -> float:
    """Mean over images of (certain false-safe pixels / valid pixels): the loss risk control bounds
    (certain: ``uncertainty`` < ``threshold_nats``)."""
    cal = EntropyCalibration()
    cal.update(
        torch.from_numpy(uncertainty.of(inf)),
        torch.from_numpy(inf.prediction),
        torch.from_numpy(inf.label),
        torch.from_numpy(inf.ignore),
    )
    return cal.risk(threshold_nats)


# --- inference -----------------------------------------------------------------------------------
def infer_split(
    model: BayesianSegNet,
    ds: HazardDataset,
    mc_samples: int,
    batch_size: int,
    seed: int,
    device: torch.device,
    recompute_baseline: bool = False,
    progress: Callable[[int], None] | None = None,
) -> SplitInference:
    """MC dropout over a whole split, brought back to the DEM grid; dropout masks seeded by ``seed``.

    ``recompute_baseline``: the ALHAT P(safe) is recomputed on the (repaired) noisy DEM instead of
    read from the label shard (needed with dead pixels). ``progress`` is called with the number of
    images of each batch done.
    """
    torch.manual_seed(seed)
    n = len(ds)
    h, w = ds.dem_shape
    arrays = {k: np.zeros((n, h, w), np.float32) for k in ("prob", "entropy", "mi", "clean", "noisy", "baseline")}
    label = np.zeros((n, h, w), np.int64)
    pred = np.zeros((n, h, w), np.int64)
    ignore = np.zeros((n, h, w), bool)
    base = np.zeros((n, h, w), bool)
    scans = np.zeros(n, np.int64)
    for start in range(0, n, batch_size):
        idx = range(start, min(n, start + batch_size))
        samples = [ds.dem_sample(i) for i in idx]
        x = torch.stack([ds.prepare(s)["image"] for s in samples]).to(device)
        out = mc_dropout_predict(model, x, n_samples=mc_samples).on_grid(lambda t: ds.to_dem_grid(t).cpu())
        sl = slice(idx.start, idx.stop)
        arrays["prob"][sl] = out.mean_probs[:, defaults.CLASS_SAFE].numpy()
        arrays["entropy"][sl] = out.entropy_nats.numpy()
        arrays["mi"][sl] = out.mutual_information_nats.numpy()
        pred[sl] = out.prediction.numpy()
        for j, s in zip(idx, samples, strict=True):
            scans[j], label[j], ignore[j] = s.scan_index, s.label, s.ignore
            arrays["clean"][j], arrays["noisy"][j] = s.dem_clean_m, s.dem_noisy_m
            p_safe = (
                safety_probability(s.dem_noisy_m, ds.spacing_m, ds.sigma_m, ds.lander)
                if recompute_baseline
                else ds.baseline_p_safe(s)
            )
            arrays["baseline"][j] = p_safe
            base[j] = np.nan_to_num(p_safe, nan=0.0) >= BASELINE_THRESHOLD
        if progress is not None:
            progress(len(idx))
    return SplitInference(
        ds.sigma_m,
        scans,
        label,
        ignore,
        arrays["prob"],
        pred,
        arrays["entropy"],
        base,
        arrays["clean"],
        arrays["noisy"],
        arrays["baseline"],
        arrays["mi"],
    )


def concat_inference(parts: Sequence[SplitInference]) -> SplitInference:
    """Inferences of several splits at one noise level as one (images one after the other)."""
    if len(parts) == 1:
        return parts[0]
    arrays: dict[str, Any] = {
        f.name: None
        if any(getattr(p, f.name) is None for p in parts)
        else np.concatenate([getattr(p, f.name) for p in parts])
        for f in dataclasses.fields(SplitInference)
        if f.name != "sigma_m"
    }
    return SplitInference(sigma_m=parts[0].sigma_m, **arrays)


# --- the run and its threshold ---------------------------------------------------------------------
def checkpoint_path(run_dir: str | os.PathLike) -> Path:
    """The checkpoint of a run: ``RUN/last.pt`` for a run directory, else the path itself (a checkpoint file).

    Raises:
        HdNetError: as ``hdnet.preflight.check_run``: nothing there, a dataset, a run without a
            checkpoint yet, a directory that is no run.
    """
    return check_run(run_dir)


def split_dataset(
    dataset_dir: str | os.PathLike,
    split: str,
    sigma_m: float,
    *,
    labels: str | None,
    input_spec: InputSpec,
    dead_pixels: int = 0,
    seed: int = 0,
) -> HazardDataset:
    """One split of a labelled dataset prepared as the run's training inputs were; HdNetError when empty."""
    ds = HazardDataset(
        dataset_dir, split, sigma_m, labels=labels, input_spec=input_spec, dead_pixels=dead_pixels, seed=seed
    )
    if len(ds) == 0:
        raise HdNetError(f"{dataset_label(dataset_dir)}: the {split} split is empty.")
    return ds


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


@dataclass(frozen=True)
class ValidationThreshold:
    """H_t (nats; +inf = every pixel certain) calibrated on a validation split, and how it was obtained.

    ``info`` is the ``threshold`` entry of ``report.json`` (spec, value, mean, calibration split and
    sizes; the uncertainty score when it is not the default, ``hdnet.uncertainty.with_score``).
    """

    value_nats: float
    info: ThresholdJson
    calibration: EntropyCalibration
    inference: SplitInference


def validation_threshold(
    model: BayesianSegNet,
    val_ds: HazardDataset | Sequence[HazardDataset],
    spec: ThresholdSpec,
    *,
    mc_samples: int,
    batch_size: int,
    seed: int,
    device: torch.device,
    progress: Callable[[int], None] | None = None,
    uncertainty: UncertaintyScore = ENTROPY,
) -> ValidationThreshold:
    """Step 1 of the protocol: MC dropout over the validation split, its ``uncertainty`` (predictive entropy
    or mutual information, nats) collected, H_t selected.

    Several validation splits (one noise level, several datasets) calibrate together.
    """
    parts = [val_ds] if isinstance(val_ds, HazardDataset) else list(val_ds)
    val = concat_inference(
        [infer_split(model, ds, mc_samples, batch_size, seed, device, progress=progress) for ds in parts]
    )
    cal = EntropyCalibration()
    cal.update(torch.from_numpy(uncertainty.of(val)), torch.from_numpy(val.prediction), torch.from_numpy(val.label))
    h_t = select_threshold(spec, cal)
    h_mean = cal.mean()
    val_scores = uncertainty.of(val)[val.valid]
    info: ThresholdJson = {
        "spec": str(spec),
        "kind": spec.kind,
        "parameter": spec.value,
        "value_nats": _finite_or_none(h_t),
        "mean_nats": h_mean,
        "mean_quantile": float(np.mean(val_scores < h_mean)),
        # where another rule's H_t lies among the validation scores (the threshold sweep's axis)
        **spec.rule.quantile_entry(cal, h_t),
        "calibration_split": "val",
        "calibration_sigma_m": val.sigma_m,
        "calibration_images": cal.n_images,
        "calibration_pixels": int(val_scores.size),
    }
    info |= spec.reach(cal.n_images)  # risk:ALPHA with alpha < 1/(n+1) leaves every pixel uncertain: said
    return ValidationThreshold(h_t, with_score(info, uncertainty), cal, val)


# --- the evaluation --------------------------------------------------------------------------------
def _check_drop_pixels(drop_pixels: int, n_pixels: int) -> None:
    """Fewer dropped pixels than a DEM has (their kind and range are EvalConfig's own checks)."""
    if drop_pixels >= n_pixels:
        raise HdNetError(
            f"--drop-pixels must be an integer in [0, {n_pixels - 1}] for {n_pixels}-pixel DEMs, got {drop_pixels!r}."
        )


@dataclass(frozen=True)
class _Setup:
    """What every step of an evaluation shares: the model and its run, the labelling, the noise levels."""

    run: TrainedRun
    device: torch.device
    labels: str
    sigmas_m: tuple[float, ...]
    calibration: Calibration
    scored: ScoredSplit

    @property
    def model(self) -> BayesianSegNet:
        return self.run.model

    @property
    def train_sigma_m(self) -> float:
        """The run's reference training noise level, metres."""
        return self.run.data.train_sigma_m

    @property
    def input_spec(self) -> InputSpec:
        return self.run.data.input

    @property
    def train_noise(self) -> TrainingNoise:
        """The run's training noise levels (one level for runs that do not record them)."""
        return self.run.data.train_noise

    def dataset(
        self,
        dataset_dir: str | os.PathLike,
        split: str,
        sigma: float,
        seed: int,
        dead: int = 0,
        labels: str | None = None,
    ) -> HazardDataset:
        """One split at one noise level (metres), prepared as the run's inputs; ``dead`` dead pixels per
        DEM; ``labels`` the labelling (default: the evaluated one)."""
        return split_dataset(
            dataset_dir,
            split,
            sigma,
            labels=self.labels if labels is None else labels,
            input_spec=self.input_spec,
            dead_pixels=dead,
            seed=seed,
        )


@dataclass(frozen=True)
class Calibration:
    """Where H_t is calibrated: the validation splits of ``datasets`` (resolved paths, or URLs with their
    secrets: :func:`lidarsim.location.dataset_location`; :attr:`recorded` is how reports name them) under the
    labelling ``labels``; ``source`` says why (``calibrate-on``, ``run`` for the run's own training
    data, ``evaluated`` for the evaluated dataset) and ``note`` why the run's data was not used."""

    datasets: tuple[str, ...]
    labels: str
    source: str
    note: str = ""

    @property
    def recorded(self) -> list[str]:
        """The datasets as a report records them (:func:`lidarsim.location.dataset_key`: no URL's secrets)."""
        return [dataset_key(d) for d in self.datasets]


def calibration_datasets(
    data: TrainingData, dataset_dir: str | os.PathLike, cfg: EvalConfig, labels: str, run_labels: str | None
) -> Calibration:
    """The validation splits that calibrate H_t: ``cfg.calibrate_on``; else the run's training
    datasets (its ``dataset`` and every ``--also`` one) when all are present with the run's labelling
    ``run_labels``; else the evaluated dataset ``dataset_dir`` (labelling ``labels``), with the reason."""
    if cfg.calibrate_on:
        return Calibration(tuple(dataset_location(d) for d in cfg.calibrate_on), labels, "calibrate-on")
    recorded = data.datasets
    evaluated = dataset_location(dataset_dir)
    note = "the run does not record its training data"
    if recorded:
        missing = data.missing_datasets()
        note = f"the run's training data {missing[0]} is not present" if missing else ""
        if not missing:
            try:
                for d in recorded:
                    open_labeling(d, run_labels)
            except HdError:
                note = f"the run's training data {recorded[0]} lacks the run's labelling"
        if not note:
            resolved = tuple(dataset_location(d) for d in recorded)
            return Calibration(resolved, run_labels or labels, "run")
    return Calibration((evaluated,), labels, "evaluated", note)


def evaluate(
    run_dir: str | os.PathLike,
    dataset_dir: str | os.PathLike,
    config: EvalConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> EvaluationResult:
    """Evaluate the run at ``run_dir`` (its ``last.pt``, or a checkpoint file) on ``dataset_dir``.

    ``progress`` is called with (images inferred, images to infer) over every pass of the
    evaluation (validation calibrations, test split per noise level, dead pixels, sweep).

    Returns the result; writing it is the caller's (``hdnet.report.write_report``, after checking
    the report directory with ``check_report_dir`` before the evaluation runs, as
    ``hdnet.evaluate.evaluate_to_report`` does).

    Raises:
        HdNetError: a dataset without labels, a training sigma not in the dataset, a checkpoint of
            another model or schema, ``drop_pixels`` outside [0, DEM pixels), ``mc_samples`` < 1,
            an empty validation or test split.
    """
    cfg = config if config is not None else EvalConfig()
    spec = cfg.threshold_spec
    setup = _open_evaluation(run_dir, dataset_dir, cfg)
    counter = _ImageCounter(_planned_images(setup, dataset_dir, cfg), progress) if progress is not None else None

    # 1. threshold from the validation split at the reference sigma (and, with calibrate=each, at every test sigma)
    thresholds = _Thresholds(setup, dataset_dir, cfg, counter)
    th = thresholds.reference
    warn_if_unreachable(th.info)  # before the test split is inferred
    # 2-3. every sigma: the three methods, the sweep, calibration
    tests, rows, sweep, cal_rows, achieved = _noise_table(setup, dataset_dir, cfg, thresholds)
    # 4. dead pixels
    if cfg.drop_pixels:
        dead_rows, dead_achieved = _dead_pixel_table(setup, dataset_dir, cfg, thresholds)
        rows += dead_rows
        achieved += dead_achieved
    # 5. the noise sweep
    if cfg.sigma_sweep:
        sweep_rows, sweep_achieved = _sigma_sweep(setup, dataset_dir, cfg, thresholds)
        rows += sweep_rows
        achieved += sweep_achieved
    # 6. landing outcomes: each method's best site per test scene, landed on and scored against the truths
    landing, landing_info = _landing_table(setup, dataset_dir, cfg, thresholds, tests)
    threshold_info = th.info
    threshold_info["calibrate"] = cfg.calibrate
    threshold_info["calibration_datasets"] = setup.calibration.recorded
    threshold_info["calibration_source"] = setup.calibration.source
    if setup.calibration.note:
        threshold_info["calibration_note"] = setup.calibration.note
    if cfg.calibrate == "each":
        threshold_info["per_sigma"] = thresholds.per_sigma_info()
    if spec.rule.certifies_risk:
        threshold_info["alpha"] = spec.value
        threshold_info["achieved_risk"] = achieved
    val = th.inference
    return EvaluationResult(
        rows,
        threshold_info,
        sweep,
        {"bins": ECE_BINS, "per_sigma": cal_rows},
        _run_info(setup, dataset_dir, cfg, tests, val),
        tests,
        val.entropy_nats[val.valid],
        landing,
        landing_info,
    )


class _ImageCounter:
    """Images inferred so far against the plan; reports (done, total) to a progress callback."""

    def __init__(self, total: int, report: Callable[[int, int], None]) -> None:
        self.total, self.done, self.report = total, 0, report
        report(0, total)

    def __call__(self, n: int) -> None:
        self.done += n
        self.total = max(self.total, self.done)  # a plan that fell short never reports past 100 %
        self.report(self.done, self.total)


def _planned_images(setup: _Setup, dataset_dir: str | os.PathLike, cfg: EvalConfig) -> int:
    """Images an evaluation infers: validation splits once per calibration level, the scored split
    (the test split by default) per noise level of Table 1, of Table 2 (with dead pixels) and of the
    sweep (split sizes from the manifests)."""

    def split_size(d: str | os.PathLike, split: str) -> int:
        splits = read_manifest(d).get("splits", {})
        return int(splits.get(split, 0)) if isinstance(splits, dict) else 0

    n_val = sum(split_size(d, "val") for d in setup.calibration.datasets)
    n_test = setup.scored.scans
    levels = {round(float(setup.train_sigma_m), 12)}
    if cfg.calibrate == "each":
        levels |= {round(float(s), 12) for s in (*setup.sigmas_m, *cfg.sigma_sweep)}
    passes = len(setup.sigmas_m) * (2 if cfg.drop_pixels else 1) + len(cfg.sigma_sweep)
    return n_val * len(levels) + n_test * passes


def guard_above_training(th: ValidationThreshold, sigma_m: float, noise: TrainingNoise) -> ValidationThreshold:
    """``th`` (calibrated at ``sigma_m`` metres), capped by the precision guard when ``sigma_m`` lies
    above the training noise levels ``noise``: H_t = min(H_t, the loosest threshold whose validation
    precision is >= ``PRECISION_GUARD``). Unchanged inside the training levels, or when already guarded."""
    if sigma_m <= noise.high_m + 1e-9 or th.info.get("guarded"):
        return th
    guard = precision_threshold(th.calibration, PRECISION_GUARD)
    value = min(th.value_nats, guard)
    info: ThresholdJson = {
        **th.info,
        "guarded": True,
        "guard_precision": PRECISION_GUARD,
        "guard_nats": _finite_or_none(guard),
    }
    info["value_nats"] = _finite_or_none(value)
    info["value_quantile"] = th.calibration.fraction_below(value)
    return ValidationThreshold(value, info, th.calibration, th.inference)


class _Thresholds:
    """H_t for every test noise level: the reference calibration (validation split at the run's
    reference sigma), or with ``calibrate="each"`` one calibration per test sigma (cached)."""

    def __init__(
        self,
        setup: _Setup,
        dataset_dir: str | os.PathLike,
        cfg: EvalConfig,
        progress: Callable[[int], None] | None = None,
    ) -> None:
        self.setup, self.dataset_dir, self.cfg, self.progress = setup, dataset_dir, cfg, progress
        self._by_sigma: dict[float, ValidationThreshold] = {}
        self.reference = self._calibrate(setup.train_sigma_m)

    def _calibrate(self, sigma_m: float) -> ValidationThreshold:
        key = round(float(sigma_m), 12)
        th = self._by_sigma.get(key)
        if th is None:
            cfg = self.cfg
            cal = self.setup.calibration
            th = self._by_sigma[key] = validation_threshold(
                self.setup.model,
                [self.setup.dataset(d, "val", sigma_m, cfg.seed, labels=cal.labels) for d in cal.datasets],
                cfg.threshold_spec,
                mc_samples=cfg.mc_samples,
                batch_size=cfg.batch_size,
                seed=cfg.seed,
                device=self.setup.device,
                progress=self.progress,
                uncertainty=cfg.uncertainty_score,
            )
        return th

    def at(self, test_sigma_m: float) -> ValidationThreshold:
        """The calibration that scores the test split at ``test_sigma_m`` metres.

        With ``calibrate="each"``, above the run's training noise levels the threshold is also capped
        by the precision guard (``PRECISION_GUARD``, ``hdnet.thresholds.precision_threshold``).
        """
        if self.cfg.calibrate == "reference":
            return self.reference
        th = self._calibrate(test_sigma_m)
        if self.cfg.threshold_spec.rule.calibrated:  # a fixed threshold stays what the user fixed
            th = guard_above_training(th, test_sigma_m, self.setup.train_noise)
        self._by_sigma[round(float(test_sigma_m), 12)] = th
        return th

    def per_sigma_info(self) -> list[PerSigmaThresholdJson]:
        return [
            {
                "calibration_sigma_m": s,
                "value_nats": th.info["value_nats"],
                "mean_nats": th.info["mean_nats"],
                "value_quantile": th.info.get("value_quantile", th.info["mean_quantile"]),
                "guarded": bool(th.info.get("guarded", False)),
            }
            for s, th in sorted(self._by_sigma.items())
        ]


def _open_evaluation(run_dir: str | os.PathLike, dataset_dir: str | os.PathLike, cfg: EvalConfig) -> _Setup:
    """Step 0: the checks that need the dataset or the run (before the model is loaded), then the model
    and the labelling: ``cfg.labels``, else the one the run was trained on when the dataset has it.
    An unfinished run is evaluated with a warning."""
    # The clear "no such dataset", "no labels" or "no labelling named" error before the model is loaded.
    ckpt_path = check_inputs(run_dir, dataset_dir, cfg.labels, calibration=cfg.calibrate_on)
    dev = torch.device(cfg.device) if cfg.device else torch.device("cuda" if torch.cuda.is_available() else "cpu")
    run = TrainedRun.load(ckpt_path, dev)
    if run.unfinished is not None:
        warnings.warn(run.unfinished, HdWarning, stacklevel=3)
    run_labels = run.data.labels
    entry, paths = open_labeling(
        dataset_dir, cfg.labels if cfg.labels is not None else preferred_labeling(dataset_dir, run_labels)
    )
    _check_drop_pixels(cfg.drop_pixels, entry.dem.rows * entry.dem.cols)
    sigmas = dataset_sigmas(paths, entry.first_sha256)
    stored_sigma_index(sigmas, run.data.train_sigma_m)  # stored, or made at from the clean points
    labels = entry.name
    calibration = calibration_datasets(run.data, dataset_dir, cfg, labels, run_labels)
    scored = scored_split(cfg.split, dataset_dir, calibration.datasets, run.data)
    for words in scored.warnings():
        warnings.warn(words, HdWarning, stacklevel=3)
    return _Setup(run, dev, labels, tuple(sigmas), calibration, scored)


def _noise_table(
    setup: _Setup, dataset_dir: str | os.PathLike, cfg: EvalConfig, thresholds: _Thresholds
) -> tuple[
    dict[float, SplitInference], list[ReportRow], list[SweepRowJson], list[CalibrationRowJson], list[AchievedRiskJson]
]:
    """Steps 2-3: the test split at every noise level: the three methods (Table 1), the sweep over
    threshold quantiles, the calibration of P(safe) and, for ``risk:ALPHA``, the false-safe rate."""
    uncertainty = cfg.uncertainty_score
    rows: list[ReportRow] = []
    sweep: list[SweepRowJson] = []
    cal_rows: list[CalibrationRowJson] = []
    tests: dict[float, SplitInference] = {}
    achieved: list[AchievedRiskJson] = []
    for sigma in setup.sigmas_m:
        th = thresholds.at(sigma)
        h_t, val_sigma = th.value_nats, setup.train_sigma_m
        quantile_thresholds = [(q, th.calibration.quantile(q)) for q in defaults.QUANTILE_SWEEP]
        inf = infer_split(
            setup.model,
            setup.dataset(dataset_dir, cfg.split, sigma, cfg.seed),
            cfg.mc_samples,
            cfg.batch_size,
            cfg.seed,
            setup.device,
            progress=thresholds.progress,
        )
        tests[sigma] = inf
        rows += method_rows(inf, "noise", val_sigma, h_t, uncertainty)
        u = uncertainty.of(inf)
        for q, t in quantile_thresholds:
            m = score(inf.label, inf.prediction, inf.ignore, u >= t)
            sweep.append(
                {
                    "test_sigma_m": sigma,
                    "quantile": q,
                    "threshold_nats": t,
                    "vc_fraction": m.vc_fraction,
                    "pixel_accuracy": m.pixel_accuracy,
                    "miou": m.miou,
                    "precision": m.precision_safe,
                    "sensitivity": m.sensitivity_safe,
                }
            )
        v = inf.valid
        rel = reliability(inf.prob_safe[v], inf.label[v] == defaults.CLASS_SAFE)
        cal_rows.append(
            {
                "test_sigma_m": sigma,
                "ece": rel.ece,
                "bin_edges": rel.edges.tolist(),
                "bin_count": rel.count.tolist(),
                "bin_mean_prob": rel.mean_prob.tolist(),
                "bin_safe_fraction": rel.safe_fraction.tolist(),
            }
        )
        if cfg.threshold_spec.rule.certifies_risk:
            rate = false_safe_rate(inf, h_t, uncertainty)
            achieved.append({"test_sigma_m": sigma, "table": "noise", "false_safe_rate": rate})
    return tests, rows, sweep, cal_rows, achieved


def _dead_pixel_table(
    setup: _Setup, dataset_dir: str | os.PathLike, cfg: EvalConfig, thresholds: _Thresholds
) -> tuple[list[ReportRow], list[AchievedRiskJson]]:
    """Step 4: the test split again with ``drop_pixels`` dead pixels per DEM, repaired, the baseline
    recomputed on the repaired DEM (Table 2); the false-safe rate for ``risk:ALPHA``."""
    rows: list[ReportRow] = []
    achieved: list[AchievedRiskJson] = []
    val_sigma = setup.train_sigma_m
    for sigma in setup.sigmas_m:
        h_t = thresholds.at(sigma).value_nats
        inf = infer_split(
            setup.model,
            setup.dataset(dataset_dir, cfg.split, sigma, cfg.seed, cfg.drop_pixels),
            cfg.mc_samples,
            cfg.batch_size,
            cfg.seed,
            setup.device,
            recompute_baseline=True,
            progress=thresholds.progress,
        )
        rows += method_rows(inf, "dead_pixels", val_sigma, h_t, cfg.uncertainty_score)
        if cfg.threshold_spec.rule.certifies_risk:
            rate = false_safe_rate(inf, h_t, cfg.uncertainty_score)
            achieved.append({"test_sigma_m": sigma, "table": "dead_pixels", "false_safe_rate": rate})
    return rows, achieved


def _sigma_sweep(
    setup: _Setup, dataset_dir: str | os.PathLike, cfg: EvalConfig, thresholds: _Thresholds
) -> tuple[list[ReportRow], list[AchievedRiskJson]]:
    """Step 5: the test split at every level of ``cfg.sigma_sweep`` (stored, or made from the clean
    points), the three methods (table ``sigma_sweep``); the false-safe rate for ``risk:ALPHA``."""
    rows: list[ReportRow] = []
    achieved: list[AchievedRiskJson] = []
    for sigma in cfg.sigma_sweep:
        h_t = thresholds.at(sigma).value_nats
        inf = infer_split(
            setup.model,
            setup.dataset(dataset_dir, cfg.split, sigma, cfg.seed),
            cfg.mc_samples,
            cfg.batch_size,
            cfg.seed,
            setup.device,
            progress=thresholds.progress,
        )
        rows += method_rows(inf, "sigma_sweep", setup.train_sigma_m, h_t, cfg.uncertainty_score)
        if cfg.threshold_spec.rule.certifies_risk:
            rate = false_safe_rate(inf, h_t, cfg.uncertainty_score)
            achieved.append({"test_sigma_m": inf.sigma_m, "table": "sigma_sweep", "false_safe_rate": rate})
    return rows, achieved


def _landing_table(
    setup: _Setup,
    dataset_dir: str | os.PathLike,
    cfg: EvalConfig,
    thresholds: _Thresholds,
    tests: dict[float, SplitInference],
) -> tuple[list[LandingRow], LandingRecord]:
    """Step 6: the landing table at every noise level of Table 1, against each truth the dataset has
    for the evaluated labelling's lander and DEM (``hdnet.landing_table``)."""
    entry, _ = open_labeling(dataset_dir, setup.labels)
    names = labelings_by_truth(dataset_dir, entry)
    truths = {truth: split_labels(dataset_dir, cfg.split, name) for truth, name in sorted(names.items(), reverse=True)}
    settings = LandingSettings(nav_sigmas_m=cfg.nav_sigma_m, seed=cfg.seed, margin_m=cfg.site_margin_m)
    rows: list[LandingRow] = []
    for sigma, inf in tests.items():
        rows += landing_rows(
            inf,
            thresholds.at(sigma).value_nats,
            truths,
            entry.lander,
            entry.spacing_m,
            settings,
            uncertainty=cfg.uncertainty_score,
        )
    missing = tuple(t for t in TRUTHS if t not in truths)
    return rows, LandingRecord(settings, {t: names[t] for t in truths}, missing)


def _run_info(
    setup: _Setup,
    dataset_dir: str | os.PathLike,
    cfg: EvalConfig,
    tests: dict[float, SplitInference],
    val: SplitInference,
) -> ReportRunJson:
    """Step 5: the ``run`` entry of the report: checkpoint, run settings, dataset and evaluation settings."""
    root = dataset_key(dataset_dir)
    digest = manifest_sha256(dataset_dir)
    run = setup.run
    data = run.data
    return {
        "checkpoint": str(run.checkpoint.resolve()),
        "checkpoint_sha256": sha256_file(run.checkpoint),
        "batch_size": cfg.batch_size,
        **run.header.to_dict(),
        "train_sigma_m": setup.train_sigma_m,
        "train_noise": data.train_noise.to_dict(),
        "sigma_sweep_m": list(cfg.sigma_sweep),
        "input_size": setup.input_spec.input_size,
        "input": setup.input_spec.to_dict(),
        "dataset": root,
        "manifest_sha256": digest,
        "labels": setup.labels,
        "truth": open_labeling(dataset_dir, setup.labels)[0].truth,
        "same_dataset_as_training": data.manifest_sha256 == digest,
        "sigmas_m": list(setup.sigmas_m),
        "mc_samples": cfg.mc_samples,
        "drop_pixels": cfg.drop_pixels,
        "seed": cfg.seed,
        **_scored_scans(setup.scored, len(next(iter(tests.values())).scan_index), len(val.scan_index)),
        "paper_dataset": is_paper_dataset(dataset_dir),
        **setup.scored.record(),
    }


def _scored_scans(scored: ScoredSplit, n_scored: int, n_val: int) -> ReportRunJson:
    """The scans counts of the ``run`` record: the test scans scored (the default split; another
    split's count is its ``scored_scans``) and the validation scans that calibrated H_t."""
    if scored.is_default:
        return {"test_scans": n_scored, "val_scans": n_val}
    if n_scored != scored.scans:
        raise HdNetError(
            f"the {scored.name} split holds {scored.scans} scans by its manifest but {n_scored} were read."
        )
    return {"val_scans": n_val}


def report_is_current(
    report_dir: str | os.PathLike, run_dir: str | os.PathLike, dataset_dir: str | os.PathLike, cfg: EvalConfig
) -> bool:
    """True when ``report_dir`` holds the report this evaluation would write (``hd eval`` run again):
    the same checkpoint bytes, dataset manifest, labelling (the one asked for, by name or alias, else
    the run's) and evaluation settings (the uncertainty score included)."""
    try:
        report = json.loads(read_regular_text(Path(report_dir) / "report.json"))
        run, th = report["run"], report["threshold"]
        same_score = recorded_score(th) is cfg.uncertainty_score
        ckpt = checkpoint_path(run_dir)
        same_inputs = (
            run.get("checkpoint_sha256") == sha256_file(ckpt)
            and run.get("dataset") == dataset_key(dataset_dir)
            and run.get("manifest_sha256") == manifest_sha256(dataset_dir)
        )
        recorded = recorded_training_data(ckpt)
        run_labels = recorded.labels
        calibration = calibration_datasets(recorded, dataset_dir, cfg, str(run.get("labels")), run_labels).recorded
        # The labelling this evaluation would score against: asked for (a name or an alias), else the run's.
        asked = cfg.labels if cfg.labels is not None else preferred_labeling(dataset_dir, run_labels)
        labels = find_labeling(dataset_dir, asked).name
    except (OSError, ValueError, KeyError, TypeError, HdNetError):
        return False
    return bool(
        same_inputs
        and run.get("labels") == labels
        and run.get("mc_samples") == cfg.mc_samples
        and run.get("drop_pixels") == cfg.drop_pixels
        and run.get("seed") == cfg.seed
        and run.get("split", "test") == cfg.split
        and run.get("batch_size") == cfg.batch_size
        and run.get("sigma_sweep_m") == list(cfg.sigma_sweep)
        and report.get("landing_settings", {}).get("nav_sigmas_m") == list(cfg.nav_sigma_m)
        and th.get("spec") == str(cfg.threshold_spec)
        and same_score
        and th.get("calibrate") == cfg.calibrate
        and th.get("calibration_datasets") == calibration
    )


def is_paper_dataset(dataset_dir: str | os.PathLike) -> bool:
    """True when the dataset was built with the settings of the paper's recipe (``datasets/mars-paper``:
    the paper's three noise levels, 1000 scans, sensor and altitude, on hd's procedural Mars): the
    only dataset whose scores sit beside the paper's numbers."""
    from lidarsim import defaults as lidar_defaults
    from lidarsim.build import BuildConfig
    from lidarsim.trajectory import TrajectoryConfig

    paper = BuildConfig(
        sigmas_m=lidar_defaults.PAPER_SIGMAS_M,
        seed=0,
        trajectory=TrajectoryConfig(n_scans=lidar_defaults.N_SCANS),
    )
    return read_manifest(dataset_dir).get("config_sha256") == paper.fingerprint()


def validation_summary(
    run_dir: str | os.PathLike,
    dataset_dir: str | os.PathLike,
    mc_samples: int = defaults.MC_SAMPLES,
    labels: str | None = None,
    seed: int = 0,
    batch_size: int = 8,
    quantile: float = 0.5,
    other_sigmas_m: tuple[float, ...] = (),
    risk_alpha: float = 0.05,
) -> dict[str, float]:
    """Validation-split numbers of a run (for choosing settings without ever reading the test split).

    MC dropout over the validation split at the training noise level, then: the base net's
    ``base_pa``, ``base_miou``, ``base_precision``, ``base_sensitivity``; the uncertainty-aware map at
    the mean validation entropy (``ua_vc``, ``ua_pa``, ``ua_miou``, ``ua_precision``,
    ``ua_sensitivity``, ``threshold_nats``); at the ``quantile`` of the validation entropies (V/C =
    ``quantile`` by construction): ``q_precision``, ``q_sensitivity``, ``q_vc``; at the conformal
    ``risk:risk_alpha`` threshold chosen on these same images (in-sample, so an optimistic
    estimate): ``risk_false_safe``, ``risk_sensitivity``, ``risk_vc``. For each of
    ``other_sigmas_m`` (metres), the validation split at that noise level with the same two
    thresholds: ``base_pa@S``, ``ua_vc@S``, ``ua_precision@S``, ``ua_sensitivity@S``,
    ``q_precision@S`` with S the sigma in cm (e.g. ``ua_precision@7cm``). Fractions in [0, 1].
    """
    ckpt_path = checkpoint_path(run_dir)
    dev = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    run = TrainedRun.load(ckpt_path, dev)
    model, train_sigma, input_spec, run_labels = run.model, run.data.train_sigma_m, run.data.input, run.data.labels
    entry, _ = open_labeling(dataset_dir, labels if labels is not None else preferred_labeling(dataset_dir, run_labels))

    def val_at(sigma: float) -> SplitInference:
        ds = split_dataset(dataset_dir, "val", sigma, labels=entry.name, input_spec=input_spec)
        return infer_split(model, ds, mc_samples, batch_size, seed, dev)

    inf = val_at(train_sigma)
    cal = EntropyCalibration()
    cal.update(torch.from_numpy(inf.entropy_nats), torch.from_numpy(inf.prediction), torch.from_numpy(inf.label))
    h_mean, h_q = cal.mean(), cal.quantile(quantile)
    h_risk = select_threshold(f"risk:{risk_alpha}", cal)
    base = score(inf.label, inf.prediction, inf.ignore)
    ua = score(inf.label, inf.prediction, inf.ignore, inf.entropy_nats >= h_mean)
    q = score(inf.label, inf.prediction, inf.ignore, inf.entropy_nats >= h_q)
    risk = score(inf.label, inf.prediction, inf.ignore, inf.entropy_nats >= h_risk)
    out = {
        "base_pa": base.pixel_accuracy,
        "base_miou": base.miou,
        "base_precision": base.precision_safe,
        "base_sensitivity": base.sensitivity_safe,
        "threshold_nats": h_mean,
        "ua_vc": float(ua.vc_fraction or 0.0),
        "ua_pa": ua.pixel_accuracy,
        "ua_miou": ua.miou,
        "ua_precision": ua.precision_safe,
        "ua_sensitivity": ua.sensitivity_safe,
        "q_precision": q.precision_safe,
        "q_sensitivity": q.sensitivity_safe,
        "q_vc": float(q.vc_fraction or 0.0),
        "risk_false_safe": cal.risk(h_risk),
        "risk_sensitivity": risk.sensitivity_safe,
        "risk_vc": float(risk.vc_fraction or 0.0),
    }
    for sigma in other_sigmas_m:
        other = val_at(sigma)
        tag = f"@{sigma * 100:.3g}cm"
        b = score(other.label, other.prediction, other.ignore)
        u = score(other.label, other.prediction, other.ignore, other.entropy_nats >= h_mean)
        qq = score(other.label, other.prediction, other.ignore, other.entropy_nats >= h_q)
        out.update(
            {
                f"base_pa{tag}": b.pixel_accuracy,
                f"ua_vc{tag}": float(u.vc_fraction or 0.0),
                f"ua_precision{tag}": u.precision_safe,
                f"ua_sensitivity{tag}": u.sensitivity_safe,
                f"q_precision{tag}": qq.precision_safe,
            }
        )
    return out


def preferred_labeling(dataset_dir: str | os.PathLike, run_labels: str | None) -> str | None:
    """The run's labelling name when the dataset has a labelling of that name, else None (the dataset's only one)."""
    names = [lab.get("name") for lab in read_manifest(dataset_dir).get("labelings", [])]
    return run_labels if run_labels in names else None


def evaluate_to_report(
    run_dir: str | os.PathLike,
    dataset_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    config: EvalConfig | None = None,
    *,
    figures: bool = True,
    overwrite: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> EvaluationResult:
    """``hd eval``: the report directory checked, the run evaluated, the report written; returns the result.

    ``progress`` is called with (images inferred, images to infer).

    ``out_dir`` is checked before the evaluation runs (a bad or occupied directory fails at once);
    an existing report, or a non-empty directory that is not a report, is replaced only with
    ``overwrite``. The report is ``report.json``, ``report.md`` and, with ``figures``, the PNGs.

    Raises:
        HdNetError: see ``hdnet.report.check_report_dir``, ``hdnet.evaluate.evaluate`` and
            ``hdnet.report.write_report``.
    """
    from hdnet.report import check_report_dir, write_report

    inputs: dict[str, str | os.PathLike | None] = {"the run": run_dir, "the dataset": dataset_dir}
    check_report_dir(out_dir, overwrite, inputs)  # before the evaluation runs
    result = evaluate(run_dir, dataset_dir, config, progress=progress)
    write_report(result, Path(out_dir), figures=figures, overwrite=overwrite, inputs=inputs)
    return result
