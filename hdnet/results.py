"""Result types of an evaluation and of a detection: plain records, no behaviour beyond formatting.

``hdnet.evaluate`` and ``hdnet.detect`` produce them; ``hdnet.report`` and ``hdnet.figures`` read
them. This module imports nothing of hdnet but its defaults, the uncertainty scores and the report's
JSON records (``hdnet.report_json``; all leaves),
so that the writers of reports and figures never depend on the code that computes what they show.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hdnet import defaults
from hdnet.report_json import CalibrationJson, ReportRowJson, ReportRunJson, SweepRowJson, ThresholdJson
from hdnet.uncertainty import recorded_score

# The methods every table of an evaluation scores (Table 1, Table 2, the sweeps, the landing table).
METHODS: tuple[str, str, str] = ("alhat_baseline", "base_net", "uncertainty_aware")
SITE_COLUMNS = ("rank", "x", "y", "p_safe", "entropy_max", "clearance_m", "baseline_p_safe", "touchdown_p_safe")


@dataclass(frozen=True)
class SplitInference:
    """MC-dropout output and ground truth of one split at one noise level, on the DEM grid.

    Arrays are (N, H, W): ``label`` int64 (0 unsafe, 1 safe, 255 ignored: invalid cells and DEM
    holes); ``ignore`` bool (dead-pixel neighbourhoods); ``prob_safe`` float32 mean softmax of
    "safe"; ``prediction`` int64 (argmax); ``entropy_nats`` float32; ``baseline_safe`` bool
    (P(safe) >= 0.5); ``dem_clean_m`` / ``dem_noisy_m`` float32 heights (metres) for figures;
    ``baseline_p_safe`` float32, the baseline's P(safe) itself (NaN where it has none: the border band
    and footprints that touch a hole), for choosing its landing sites; ``mutual_information_nats``
    float32, the MC-dropout samples' mutual information H[mean p] - mean H[p] (nats; ``hdnet.uncertainty``).
    The last two are None in inferences made without them.
    """

    sigma_m: float
    scan_index: np.ndarray
    label: np.ndarray
    ignore: np.ndarray
    prob_safe: np.ndarray
    prediction: np.ndarray
    entropy_nats: np.ndarray
    baseline_safe: np.ndarray
    dem_clean_m: np.ndarray
    dem_noisy_m: np.ndarray
    baseline_p_safe: np.ndarray | None = None  # float32 ALHAT P(safe), NaN where the baseline has none
    mutual_information_nats: np.ndarray | None = None  # float32, nats

    @property
    def valid(self) -> np.ndarray:
        """Pixels that count in metrics: labelled and not ignored."""
        return (self.label != defaults.IGNORE_INDEX) & ~self.ignore


@dataclass(frozen=True)
class ReportRow:
    """One row of Table 1 / Table 2; fractions in [0, 1] (NaN when undefined); sigmas in metres."""

    table: str  # "noise" or "dead_pixels"
    method: str
    train_sigma_m: float | None  # None for the baseline (not trained)
    test_sigma_m: float
    vc_fraction: float | None  # None for methods without thresholding
    pixel_accuracy: float
    miou: float
    precision: float
    sensitivity: float

    @classmethod
    def from_json(cls, row: ReportRowJson) -> ReportRow:
        """A row of ``report.json``: its undefined fractions, written as null, read back as NaN."""

        def fraction(value: float | None) -> float:
            return math.nan if value is None else float(value)

        return cls(
            row["table"],
            row["method"],
            row["train_sigma_m"],
            row["test_sigma_m"],
            row["vc_fraction"],
            fraction(row["pixel_accuracy"]),
            fraction(row["miou"]),
            fraction(row["precision"]),
            fraction(row["sensitivity"]),
        )


@dataclass(frozen=True)
class ReliabilityBins:
    """Reliability of the safe probability in equal-width bins of [0, 1]."""

    edges: np.ndarray  # (B + 1,)
    count: np.ndarray  # (B,) pixels per bin
    mean_prob: np.ndarray  # (B,) mean predicted P(safe) (NaN for an empty bin)
    safe_fraction: np.ndarray  # (B,) observed fraction of truly safe pixels (NaN for an empty bin)
    ece: float  # sum_b n_b / N * |safe_fraction_b - mean_prob_b|


@dataclass(frozen=True)
class LandingSettings:
    """How the landing table is made: the dispersions (metres, 1-sigma per horizontal axis), the
    touchdowns per scene, the seed of their draws and the sites' safety margin (metres,
    ``hdnet.sites.select_sites``)."""

    nav_sigmas_m: tuple[float, ...] = defaults.NAV_SIGMAS_M
    touchdowns: int = defaults.TOUCHDOWNS
    seed: int = 0
    margin_m: float = 0.0

    def to_dict(self) -> dict[str, object]:
        """The settings as report.json records them (the margin only when there is one: reports
        written without it keep their bytes)."""
        out: dict[str, object] = {"nav_sigmas_m": list(self.nav_sigmas_m), "touchdowns": self.touchdowns}
        out["seed"] = self.seed
        if self.margin_m > 0.0:
            out["site_margin_m"] = self.margin_m
        return out


@dataclass(frozen=True)
class LandingRecord:
    """The ``landing_settings`` of report.json: how the landing table was made (``settings``), the
    labelling it was scored against per truth (``labelings``; None in reports that do not record
    them) and the truths the dataset had no labelling of (``missing_truths``)."""

    settings: LandingSettings
    labelings: dict[str, str] | None = None
    missing_truths: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, object]:
        """The record as report.json holds it (the settings' keys, then ``labelings`` and, when a
        truth is missing, ``missing_truths``)."""
        out = self.settings.to_dict()
        if self.labelings is not None:
            out["labelings"] = dict(self.labelings)
        if self.missing_truths:
            out["missing_truths"] = list(self.missing_truths)
        return out

    @classmethod
    def from_dict(cls, record: Mapping[str, Any]) -> LandingRecord:
        """The record of a report.json (``KeyError``, ``TypeError`` or ``ValueError`` when it is not one
        hd writes)."""
        settings = LandingSettings(
            nav_sigmas_m=tuple(float(s) for s in record["nav_sigmas_m"]),
            touchdowns=int(record["touchdowns"]),
            seed=int(record.get("seed", 0)),
            margin_m=float(record.get("site_margin_m", 0.0)),
        )
        labelings = record.get("labelings")
        return cls(
            settings,
            None if labelings is None else {str(k): str(v) for k, v in dict(labelings).items()},
            tuple(str(t) for t in record.get("missing_truths") or ()),
        )


@dataclass
class EvaluationResult:
    """Everything ``evaluate`` measured; ``report.json`` is ``to_json()``."""

    rows: list[ReportRow]
    threshold: ThresholdJson
    sweep: list[SweepRowJson]
    calibration: CalibrationJson
    run: ReportRunJson = field(default_factory=lambda: ReportRunJson())
    test: dict[float, SplitInference] = field(default_factory=dict, repr=False)
    validation_entropy_nats: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32), repr=False)
    landing: list[LandingRow] = field(default_factory=list)
    landing_settings: LandingRecord | None = None

    def summary(self) -> str:
        """A compact text table of the rows (for the terminal)."""
        lines = [
            (
                f"{'table':11s} {'method':18s} {'test sigma':>10s} {'V/C%':>5s} {'PA':>6s} {'mIoU':>6s} "
                f"{'prec.':>6s} {'sens.':>6s}"
            )
        ]
        for r in self.rows:
            vc = "-" if r.vc_fraction is None else f"{r.vc_fraction * 100:.0f}"
            lines.append(
                f"{r.table:11s} {r.method:18s} {r.test_sigma_m * 100:8.2f}cm {vc:>5s} "
                f"{r.pixel_accuracy:6.4f} {r.miou:6.4f} {r.precision:6.4f} {r.sensitivity:6.4f}"
            )
        value = self.threshold.get("value_nats")
        on = recorded_score(self.threshold).qualifier
        th = self.threshold
        lines.append(
            f"threshold {th.get('spec', '')}{on}: {'unbounded' if value is None else f'{value:.4f} nats'}"
            + (
                f" (unreachable with {th.get('calibration_images')} validation images: it needs "
                f"{th.get('needs_images')})"
                if th.get("unreachable")
                else ""
            )
        )
        return "\n".join(lines)

    def landing_summary(self) -> str:
        """P(safe landing) for the terminal: per truth, one line per method and test noise level, one
        cell per navigation dispersion with its 95 % Wilson interval and n = scenes landed on / scored
        ('' without a landing table)."""
        lines: list[str] = []
        for truth in dict.fromkeys(r.truth for r in self.landing):
            rows = [r for r in self.landing if r.truth == truth]
            navs = list(dict.fromkeys(r.nav_sigma_m for r in rows))
            lines.append(
                f"P(safe landing) against the {truth} truth [95 % CI] n=landed/scenes, "
                f"navigation 1σ {' | '.join(f'{n:g}' for n in navs)} m:"
            )
            cells: dict[tuple[str, float], list[str]] = {}
            for r in rows:
                cells.setdefault((r.method, r.test_sigma_m), []).append(landing_cell(r))
            lines += [f"  {method:18s} {sigma * 100:8.2f}cm  " + " | ".join(c) for (method, sigma), c in cells.items()]
        return "\n".join(lines)


def landing_cell(row: LandingRow) -> str:
    """One landing row's P(safe landing) in a line of text: ``0.950 [0.835, 0.986] n=38/40`` (n: scenes
    landed on / scored), ``-- n=0/40`` where the method never landed."""
    n = f"n={row.landed}/{row.scenes}"
    if row.landed == 0 or not math.isfinite(row.p_safe):
        return f"-- {n}"
    return f"{row.p_safe:.3f} [{row.p_safe_low:.3f}, {row.p_safe_high:.3f}] {n}"


@dataclass(frozen=True)
class Site:
    """A proposed landing site: rank (1 = best), map position of its cell centre (metres, input CRS),
    footprint-mean P(safe), footprint-max entropy (nats), clearance (metres), baseline P(safe), its
    cell (row, col) and the map's expected P(safe) at the touchdown under the navigation dispersion
    it was chosen with (``hdnet.sites.select_sites``)."""

    rank: int
    x: float
    y: float
    p_safe: float
    entropy_max: float
    clearance_m: float
    baseline_p_safe: float
    row: int
    col: int
    touchdown_p_safe: float = float("nan")

    def columns(self) -> dict[str, float | int]:
        """The ``SITE_COLUMNS`` values of the site, by name."""
        return {k: getattr(self, k) for k in SITE_COLUMNS}


@dataclass(frozen=True)
class LandingRow:
    """P(safe landing) of one method at one noise level and one navigation dispersion, against one truth
    (``hdnet.landing``; docs/evaluation.md, "Landing outcome").

    ``method``: one of the evaluation's methods; ``test_sigma_m`` and ``nav_sigma_m`` in metres;
    ``truth``: ``"terrain"`` or ``"clean-scan"``. ``scenes``: test scenes scored; ``landed``: scenes
    where the method chose a site; ``p_safe``: mean over the landed scenes of the per-scene fraction
    of touchdowns on safe ground, with its 95 % Wilson interval (``p_safe_low``, ``p_safe_high``);
    ``abstain_rate``: scenes without a site / scenes, with its interval; ``unknown_fraction``:
    touchdowns on unknown ground (outside the DEM or unlabelled; counted as not safe);
    ``clearance_m``: mean clearance of the chosen sites in the map that chose them;
    ``truth_clearance_m``: mean distance from the aim point to the truth's nearest cell that is not
    safe. Rates in [0, 1]; NaN where undefined (no landed scene).
    """

    method: str
    test_sigma_m: float
    nav_sigma_m: float
    truth: str
    scenes: int
    landed: int
    p_safe: float
    p_safe_low: float
    p_safe_high: float
    abstain_rate: float
    abstain_low: float
    abstain_high: float
    unknown_fraction: float
    clearance_m: float
    truth_clearance_m: float


def levels_without_sites(rows: Sequence[LandingRow], truth: str) -> list[float]:
    """The test noise levels (metres, ascending) at which no method chose a site in any scene against
    ``truth``: every row of that truth and level has ``landed`` = 0 (the landing figure's empty panels)."""
    levels = sorted({r.test_sigma_m for r in rows if r.truth == truth})
    return [s for s in levels if all(r.landed == 0 for r in rows if r.truth == truth and r.test_sigma_m == s)]
