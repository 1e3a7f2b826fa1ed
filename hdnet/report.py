"""Report files of an evaluation: ``report.json`` (machine-readable) and ``report.md`` (the paper's layout).

``report.json`` = ``{"rows": [...], "threshold": {...}, "sweep": [...], "calibration": {...},
"run": {...}}``; every row has exactly the keys of ``ROW_KEYS``. Non-finite numbers (an undefined
ratio, an unbounded threshold) are written as ``null``. ``report.md`` prints Table 1 (noise levels)
and Table 2 (dead pixels) in the paper's column order, each followed by the paper's values for the
same rows (``hdnet.paper_results``), then the threshold, the sweep and the calibration errors.

Writing (``write_report``): every file is first written into a hidden staging directory inside
``out_dir`` and moved into place only when all are complete, ``report.json`` last; a failure (a
full disk included) removes the staging directory, so a report directory never holds half a
report. The directory's writer lock keeps two evaluations from writing the same report. An
existing report is replaced only with ``overwrite``; a non-empty directory that is not a report,
and a directory that is, holds or lies inside the run or the dataset, are never written
(``hdcore.storage.OutputDir``; ``check_report_dir`` is also called before an evaluation starts).
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hdcore.storage import (
    OutputDir,
    write_json_atomic,
    write_text_atomic,
)
from hdnet.chance import threshold_warning
from hdnet.paper_results import paper_row
from hdnet.report_json import ReportJson, ReportRunJson, ThresholdJson, recorded_noise
from hdnet.results import LandingRecord, LandingSettings, levels_without_sites
from hdnet.run_files import checkpoint_reason
from hdnet.run_json import TrainingNoiseJson
from hdnet.threshold_spec import unreachable_risk_words
from hdnet.uncertainty import recorded_score

if TYPE_CHECKING:
    from hdnet.results import EvaluationResult, ReportRow

ROW_KEYS = (
    "table",
    "method",
    "train_sigma_m",
    "test_sigma_m",
    "vc_fraction",
    "pixel_accuracy",
    "miou",
    "precision",
    "sensitivity",
)
METHOD_NAMES = {
    "alhat_baseline": "Baseline (replicated ALHAT)",
    "base_net": "Base Net.",
    "uncertainty_aware": "Uncertainty-Aware",
}
TABLE_TITLES = {"noise": "Table 1: noise levels", "dead_pixels": "Table 2: dead pixels"}


def json_plain(obj: Any) -> Any:
    """JSON-safe copy: NaN/inf -> None, tuples -> lists, numpy scalars -> Python numbers."""
    if isinstance(obj, dict):
        return {str(k): json_plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_plain(v) for v in obj]
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def report_dict(result: EvaluationResult) -> ReportJson:
    """The content of ``report.json``."""
    rows = [{k: asdict(r)[k] for k in ROW_KEYS} for r in result.rows]
    return json_plain(
        {
            "rows": rows,
            "threshold": result.threshold,
            "sweep": result.sweep,
            "calibration": result.calibration,
            "run": result.run,
            "landing": [asdict(r) for r in result.landing],
            "landing_settings": {} if result.landing_settings is None else result.landing_settings.to_dict(),
        }
    )


def _cm(sigma_m: float | None) -> str:
    return "--" if sigma_m is None else f"{sigma_m * 100:.2f} cm"


def _num(x: float | None, digits: int = 4) -> str:
    return "--" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def _pct(x: float | None) -> str:
    return "--" if x is None or not math.isfinite(x) else f"{100 * x:.0f} %"


HEADER = (
    "| Method | Train noise 1σ | Test noise 1σ | V/C Pix. % | Pix. Acc. | mIoU | Precision | Sensitivity |\n"
    "|---|---|---|---|---|---|---|---|"
)


def _trained_on(row: ReportRow, run: ReportRunJson) -> str:
    """A row's "Train noise 1σ": the run's training noise as recorded (one level, the levels, or the
    range drawn from, ``0 to 10 cm``); ``--`` for the baseline, which is not trained."""
    if row.train_sigma_m is None:
        return "--"
    range_m, levels = recorded_noise(run.get("train_noise"))
    if range_m:
        lo, hi = range_m
        return f"{lo * 100:.3g} to {hi * 100:.3g} cm"
    if len(levels) > 1:
        return ", ".join(f"{s * 100:.3g}" for s in levels) + " cm"
    return _cm(row.train_sigma_m)


def _table(rows: list[ReportRow], run: ReportRunJson) -> list[str]:
    return [
        HEADER,
        *(
            f"| {METHOD_NAMES.get(r.method, r.method)} | {_trained_on(r, run)} | {_cm(r.test_sigma_m)} | "
            f"{_pct(r.vc_fraction)} | {_num(r.pixel_accuracy)} | {_num(r.miou)} | {_num(r.precision)} | "
            f"{_num(r.sensitivity)} |"
            for r in rows
        ),
    ]


def _paper_table(rows: list[ReportRow]) -> list[str]:
    lines = []
    for r in rows:
        p = paper_row(r.table, r.method, r.test_sigma_m)
        if p is not None:
            train = "--" if r.method == "alhat_baseline" else "1.67 cm"
            lines.append(
                f"| {METHOD_NAMES.get(p.method, p.method)} | {train} | {_cm(p.test_sigma_m)} | "
                f"{_pct(p.vc_fraction)} | {_num(p.pixel_accuracy)} | {_num(p.miou)} | {_num(p.precision)} | "
                f"{_num(p.sensitivity)} |"
            )
    return [HEADER, *lines] if lines else []


# What a run was scored against, per labelling truth (report.json's run.truth; reports written before
# the terrain truth existed have none and were scored against the clean scan).
TRUTH_WORDS = {
    "clean-scan": "the clean-scan truth: labels of the clean scan's DEM",
    "terrain": "the terrain truth: labels of the DTM on each scan's DEM grid",
}

# hd choice: below this many test scans the report says that its decimals overstate the precision.
FEW_TEST_SCANS = 20
DECIMALS = 4


def report_markdown(result: EvaluationResult, figures: list[str] | None = None) -> str:
    """The content of ``report.md``."""
    out = _header_lines(result)
    out += _table_sections(result)
    out += _sweep_section(result)
    out += _landing_section(result)
    out += _risk_section(result)
    out += _sweep_and_calibration_sections(result)
    if figures:
        out += ["", "## Figures", ""] + [f"![{Path(f).stem}]({Path(f).name})" for f in figures]
    return "\n".join(out) + "\n"


def _header_lines(result: EvaluationResult) -> list[str]:
    """Step 1 of ``report_markdown``: the title and the run's, the data's and the threshold's lines."""
    run, th = result.run, result.threshold
    score = recorded_score(th)
    out = ["# hd evaluation report", ""]
    chance = threshold_warning(th["value_nats"])
    if chance is not None:  # a run that learnt nothing: said first
        out += [f"**{chance}**", ""]
    h_t = "unbounded (every pixel certain)" if th["value_nats"] is None else f"{_num(th['value_nats'])} nats"
    out += [
        (
            f"- checkpoint: `{run.get('checkpoint')}` (epoch {run.get('epoch')}, profile `{run.get('profile')}`; "
            f"{checkpoint_reason(str(run.get('checkpoint', '')))})"
        ),
        (
            f"- dataset: `{run.get('dataset')}`, labelling `{run.get('labels')}` "
            f"(scored against {TRUTH_WORDS.get(str(run.get('truth', 'clean-scan')), run.get('truth'))}), "
            + _scans_words(run)
        ),
        *_overlap_lines(run),
        (
            f"- trained at {_train_noise_words(run.get('train_noise'), run.get('train_sigma_m'))}"
            f" (reference {_cm(run.get('train_sigma_m'))}); MC samples M = {run.get('mc_samples')}; "
            f"seed {run.get('seed')}"
        ),
        *([] if score.is_default else [f"- uncertainty score `{score.name}`: the {score.description}"]),
        (
            f"- threshold `{th['spec']}`: H_t = {h_t}, calibrated on the {th['calibration_split']} split at "
            f"{_cm(th['calibration_sigma_m'])} (mean {score.noun} {_num(th['mean_nats'])} nats = validation quantile "
            f"{_num(th['mean_quantile'], 3)})"
            + _calibration_words(th, run)
            + (
                "; recalibrated on the validation split at each test noise level (--calibrate each)"
                if th.get("calibrate") == "each"
                else ""
            )
        ),
        *(
            [f"- **unreachable risk level**: {_unreachable(th)}"]
            if th.get("unreachable")  # risk:ALPHA below 1/(n+1): H_t = 0 whatever the network
            else []
        ),
        "",
    ]
    return out


def _scans_words(run: ReportRunJson) -> str:
    """The scans scored and calibrated on, for the dataset's line: ``N test / M validation scans`` (the
    default split) or ``N scans of the S split scored / M validation scans``; few scans said."""
    split = run.get("split")
    scored = run.get("test_scans") if split is None else run.get("scored_scans")
    words = "test" if split is None else f"scans of {'all splits' if split == 'all' else f'the {split} split'} scored"
    few = "test scans" if split is None else "scored scans"
    return f"{scored} {words} / {run.get('val_scans')} validation scans" + (
        f" (few {few}: the metrics below vary by far more than their {DECIMALS} decimals)"
        if isinstance(scored, int) and scored < FEW_TEST_SCANS
        else ""
    )


def _split_title(run: ReportRunJson) -> str:
    """A section title's split: ``test split`` as before ``--split``, ``val split``, ``all splits``."""
    split = run.get("split", "test")
    return "all splits" if split == "all" else f"{split} split"


def _scene_word(run: ReportRunJson) -> str:
    """What a scored scene is called: ``test`` (the default split), else ``scored``."""
    return "test" if run.get("split", "test") == "test" else "scored"


def _overlap_lines(run: ReportRunJson) -> list[str]:
    """The header's warnings where scored scans also calibrated H_t or trained the run (``--split``
    other than test on the run's own or calibration data; ``hdnet.scored_split``)."""
    out = []
    n = run.get("calibration_scans_scored")
    if n:
        out.append(
            f"- **scored scans calibrated H_t**: {n} of the {run.get('scored_scans')} scored scans are the validation "
            "scans H_t was calibrated on: their rates are in-sample and optimistic (a `risk:ALPHA` bound does not "
            "cover them); `--calibrate-on OTHER_DATASET` calibrates elsewhere"
        )
    n = run.get("training_scans_scored")
    if n:
        out.append(
            f"- **scored scans trained the run**: {n} of the {run.get('scored_scans')} scored scans are scans the "
            "run was trained on: their scores are not those of unseen data"
        )
    return out


def _table_sections(result: EvaluationResult) -> list[str]:
    """Step 2 of ``report_markdown``: the noise and dead-pixel tables, with the paper's rows beside them."""
    run = result.run
    out: list[str] = []
    for table in ("noise", "dead_pixels"):
        rows = [r for r in result.rows if r.table == table]
        if not rows:
            continue
        out += [f"## {TABLE_TITLES[table]}", ""]
        if table == "dead_pixels":
            out += [
                (
                    f"{run.get('drop_pixels')} random pixels of every {_scene_word(run)} DEM dropped and refilled "
                    "bilinearly; every "
                    "pixel whose lander footprint contains a dropped pixel is ignored for all methods."
                ),
                "",
            ]
        out += [*_table(rows, run), ""]
        paper = _paper_table(rows) if run.get("paper_dataset", True) else []
        if paper:
            which = "Table 1" if table == "noise" else "Table 2"
            out += [f"The paper's values for the same rows (Tomita et al., {which}):", "", *paper, ""]
    return out


def _risk_section(result: EvaluationResult) -> list[str]:
    """Step 3 of ``report_markdown``: ``## Risk control`` (a ``risk:ALPHA`` threshold's achieved false-safe
    rates), or nothing."""
    th = result.threshold
    out: list[str] = []
    if th.get("achieved_risk"):
        out += [
            "## Risk control",
            "",
            (
                f"Target: expected false-safe rate <= {th['alpha']} per image "
                "(certain truly-unsafe pixels predicted safe / valid pixels)."
            ),
            "",
            "| Table | Test noise 1σ | Achieved false-safe rate |",
            "|---|---|---|",
        ]
        out += [
            f"| {a['table']} | {_cm(a['test_sigma_m'])} | {_num(a['false_safe_rate'])} |" for a in th["achieved_risk"]
        ]
        out.append("")
    return out


def _sweep_and_calibration_sections(result: EvaluationResult) -> list[str]:
    """Step 4 of ``report_markdown``: the threshold sweep and the calibration of P(safe) (ECE)."""
    out: list[str] = []
    out += [
        "## Threshold sweep (uncertainty-aware)",
        "",
        "| Test noise 1σ | Quantile | H_t (nats) | V/C Pix. % | Precision | Sensitivity |",
        "|---|---|---|---|---|---|",
    ]
    out += [
        f"| {_cm(s['test_sigma_m'])} | {s['quantile']:.1f} | {_num(s['threshold_nats'])} | {_pct(s['vc_fraction'])} | "
        f"{_num(s['precision'])} | {_num(s['sensitivity'])} |"
        for s in result.sweep
    ]
    out += [
        "",
        f"## Calibration of P(safe) ({result.calibration['bins']} bins)",
        "",
        "| Test noise 1σ | ECE |",
        "|---|---|",
    ]
    out += [f"| {_cm(c['test_sigma_m'])} | {_num(c['ece'])} |" for c in result.calibration["per_sigma"]]
    return out


def _sweep_section(result: EvaluationResult) -> list[str]:
    """``## Noise sweep``: per test sigma, the three methods in one line; training levels marked."""
    rows = [r for r in result.rows if r.table == "sigma_sweep"]
    if not rows:
        return []
    range_m, levels = recorded_noise(result.run.get("train_noise"))
    lo, hi = range_m or (None, None)

    def trained(sigma: float) -> str:
        if lo is not None and hi is not None:
            return "in range" if lo - 1e-9 <= sigma <= hi + 1e-9 else ("above" if sigma > hi else "below")
        return "level" if any(abs(sigma - s) <= 1e-9 for s in levels) else "--"

    by_sigma: dict[float, dict[str, ReportRow]] = {}
    for r in rows:
        by_sigma.setdefault(r.test_sigma_m, {})[r.method] = r
    out = [
        f"## Noise sweep ({_split_title(result.run)})",
        "",
        (
            f"Trained at {_train_noise_words(result.run.get('train_noise'))}. Levels the dataset does not store are "
            "made from its clean "
            "points with the factory's noise model and the labelling's gridding."
        ),
        "",
        (
            "| Test noise 1σ | Training | ALHAT PA / prec. / sens. | Base net PA / prec. / sens. | "
            "Uncertainty-aware V/C % / PA / prec. / sens. |"
        ),
        "|---|---|---|---|---|",
    ]
    for sigma in sorted(by_sigma):
        m = by_sigma[sigma]
        cells = []
        for method in ("alhat_baseline", "base_net", "uncertainty_aware"):
            row = m.get(method)
            if row is None:
                cells.append("--")
                continue
            vc = f"{_pct(row.vc_fraction)} / " if method == "uncertainty_aware" else ""
            cells.append(f"{vc}{_num(row.pixel_accuracy, 3)} / {_num(row.precision, 3)} / {_num(row.sensitivity, 3)}")
        out.append(f"| {_cm(sigma)} | {trained(sigma)} | " + " | ".join(cells) + " |")
    return [*out, ""]


METHOD_WORDS = {"alhat_baseline": "ALHAT baseline", "base_net": "base net", "uncertainty_aware": "uncertainty-aware"}


def _landing_section(result: EvaluationResult) -> list[str]:
    """``## Landing outcome``: P(safe landing) per truth, method, noise level and navigation dispersion."""
    if not result.landing:
        return []
    record = result.landing_settings or LandingRecord(LandingSettings())  # a report without one: the defaults
    settings = record.settings
    out = [
        f"## Landing outcome ({_split_title(result.run)})",
        "",
        (
            f"Each method picks its best landing site in every {_scene_word(result.run)} scene (`hd detect`'s rule; "
            "ranked with the "
            f"navigation dispersion), the vehicle touches down {settings.touchdowns} times around it "
            "(1σ per horizontal axis as in the table; seeded), and each touchdown is judged by the truth's label "
            "of the cell it lands in (a lander centred there is safe or not); ground outside the DEM or without a "
            "label counts as not safe. P(safe landing): mean over the scenes where the method chose a site, with "
            "its 95 % Wilson interval over those scenes; a scene without a site is an abstention, never a safe "
            "landing. Clearance: distance from the aim point to the nearest cell that is not safe, in the "
            "method's map and in the truth."
            + (
                f" Every site keeps a safety margin of {settings.margin_m:g} m: its lander disk widened by it "
                "all round is safe and certain in the method's map."
                if settings.margin_m > 0.0
                else ""
            )
        ),
        "",
    ]
    missing = record.missing_truths
    if missing:
        words = " and ".join(TRUTH_WORDS.get(t, t) for t in missing)
        out += [
            (
                f"The dataset has no labelling against {words} for this lander and DEM; "
                "`hd label DATASET --truth terrain` adds the terrain's."
            ),
            "",
        ]
    truths = list(dict.fromkeys(r.truth for r in result.landing))
    for truth in truths:
        out += [
            f"### Against {TRUTH_WORDS.get(truth, truth)}",
            "",
            (
                "| Method | Test noise 1σ | Nav. 1σ | Scenes | P(safe landing) [95 % CI] | Abstain % [95 % CI] | "
                "Unknown ground % | Clearance map / truth (m) |"
            ),
            "|---|---|---|---|---|---|---|---|",
        ]
        for r in result.landing:
            if r.truth != truth:
                continue
            p = "--" if r.landed == 0 else f"{r.p_safe:.4f} [{r.p_safe_low:.4f}, {r.p_safe_high:.4f}]"
            out.append(
                f"| {METHOD_WORDS.get(r.method, r.method)} | {_cm(r.test_sigma_m)} | {r.nav_sigma_m:g} m | "
                f"{r.scenes} | {p} | {100 * r.abstain_rate:.1f} [{100 * r.abstain_low:.1f}, "
                f"{100 * r.abstain_high:.1f}] | {_pct1(r.unknown_fraction)} | "
                f"{_num(r.clearance_m, 1)} / {_num(r.truth_clearance_m, 1)} |"
            )
        out.append("")
        silent = levels_without_sites(result.landing, truth)
        if silent:
            out += [no_site_sentence(silent), ""]
    return out


def no_site_sentence(levels_m: list[float]) -> str:
    """The report's sentence for test noise levels (metres) at which no method chose a site in any scene."""
    words = " and ".join(f"{100 * s:.3g} cm" for s in levels_m)
    return (
        f"At {words} no method chose a site in any scene: P(safe landing) is undefined there (every method "
        "abstained), and the landing figure's panel says so."
    )


def _pct1(x: float | None) -> str:
    return "--" if x is None or not math.isfinite(x) else f"{100 * x:.1f}"


def _calibration_words(th: ThresholdJson, run: ReportRunJson) -> str:
    """Which validation splits calibrated H_t, and why, for the report's threshold line ('' when
    it was the evaluated dataset's own, as in the paper)."""
    datasets = th.get("calibration_datasets") or []
    names = ", ".join(f"`{d}`" for d in datasets)
    source = th.get("calibration_source")
    if source == "evaluated" and th.get("calibration_note"):
        return f" of the evaluated dataset ({th['calibration_note']})"
    if not datasets or datasets == [run.get("dataset")]:
        return ""
    return f" of the run's training data {names}" if source == "run" else f" of {names}"


def _unreachable(th: ThresholdJson) -> str:
    """The sentence of a risk level its calibration images cannot reach (``hdnet.thresholds.risk_reach``)."""
    return unreachable_risk_words(str(th["spec"]), int(th["calibration_images"]), int(th["needs_images"]))


def _train_noise_words(noise: TrainingNoiseJson | None, reference_m: float | None = None) -> str:
    """The training noise in words; a report that records none, its reference level ``reference_m``."""
    range_m, levels = recorded_noise(noise)
    if not noise and reference_m is not None:
        levels = [reference_m]
    if range_m:
        lo, hi = range_m
        return f"noise levels drawn uniformly from {lo * 100:.3g} to {hi * 100:.3g} cm per sample"
    return ", ".join(f"{s * 100:.3g}" for s in levels) + " cm" if levels else "an unrecorded noise level"


REPORT_FILES = ("report.json", "report.md")


def _is_report_file(name: str) -> bool:
    return (
        name in REPORT_FILES
        or name in ("reliability.png", "threshold_sweep.png", "noise_sweep.png", "landing.png")
        or (name.startswith("qualitative_") and name.endswith(".png"))
    )


def report_output(out_dir: str | os.PathLike, inputs: dict[str, str | os.PathLike | None] | None = None) -> OutputDir:
    """The output transaction of a report (``report.json`` marks it); ``inputs``: the run, the dataset."""
    return OutputDir(out_dir, what="report", marker="report.json", owns=_is_report_file, inputs=inputs)


def check_report_dir(
    out_dir: str | os.PathLike, overwrite: bool = False, inputs: dict[str, str | os.PathLike | None] | None = None
) -> Path:
    """Check a report directory before an evaluation runs; returns its absolute path.

    Raises:
        HdNetError: an unwritable place (``/proc``, under a regular file, read-only...), a directory
            that is, holds or lies inside one of ``inputs``, an existing report without
            ``overwrite``, or a non-empty directory that is not a report.
    """
    return report_output(out_dir, inputs).check(overwrite)


def write_report(
    result: EvaluationResult,
    out_dir: str | os.PathLike,
    figures: bool = True,
    overwrite: bool = False,
    inputs: dict[str, str | os.PathLike | None] | None = None,
) -> list[Path]:
    """Write ``report.json``, ``report.md`` and (``figures=True``) the PNGs; returns the paths written.

    Raises:
        HdNetError: see ``check_report_dir``; a full disk or another OS error (nothing is left
            half-written), or another evaluation writing the same directory.
    """
    output = report_output(out_dir, inputs)
    with output.open(overwrite) as staging:
        _stage(result, staging, figures)
        final = output.commit()
    out = output.path
    return [out / "report.json", out / "report.md", *[p for p in final if p.suffix == ".png"]]


def _stage(result: EvaluationResult, staging: Path, figures: bool) -> list[Path]:
    """Every report file, complete, in ``staging``; returns their paths."""
    pngs: list[Path] = []
    if figures:
        from hdnet.figures import write_figures

        pngs = write_figures(result, staging)
    write_json_atomic(staging / "report.json", report_dict(result))
    write_text_atomic(staging / "report.md", report_markdown(result, [str(p) for p in pngs]))
    return [*pngs, staging / "report.md", staging / "report.json"]
