"""The evaluation's figures: the qualitative panel explains its colours with a legend."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import math
from typing import Any, cast

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle

from hdnet import defaults
from hdnet.figures import (
    NO_SITE_WORDS,
    SAFETY_HEX,
    SAFETY_NAMES,
    _safety_codes,
    landing_figure_of,
    noise_sweep_figure,
    qualitative_figure,
    qualitative_panel,
    reliability_figure,
    threshold_sweep_figure,
)
from hdnet.report_json import SweepRowJson, ThresholdJson
from hdnet.results import EvaluationResult, LandingRow, ReportRow, SplitInference


def _inference(n: int = 2, size: int = 8) -> SplitInference:
    rng = np.random.default_rng(0)
    label = rng.integers(0, 2, (n, size, size)).astype(np.int64)
    label[:, 0, :] = defaults.IGNORE_INDEX
    heights = rng.normal(0.0, 0.1, (n, size, size)).astype(np.float32)
    return SplitInference(
        sigma_m=0.0167,
        scan_index=np.arange(n),
        label=label,
        ignore=np.zeros((n, size, size), bool),
        prob_safe=rng.random((n, size, size)).astype(np.float32),
        prediction=rng.integers(0, 2, (n, size, size)).astype(np.int64),
        entropy_nats=rng.random((n, size, size)).astype(np.float32) * 0.69,
        baseline_safe=rng.random((n, size, size)) > 0.5,
        dem_clean_m=heights,
        dem_noisy_m=heights + 0.01,
    )


def test_the_safety_maps_are_explained_by_a_legend_not_by_the_title(tmp_path):
    fig = qualitative_figure(_inference(), 1, threshold_nats=0.3)
    try:
        (legend,) = fig.legends
        assert [t.get_text() for t in legend.get_texts()] == list(SAFETY_NAMES)
        faces = [matplotlib.colors.to_hex(h.get_facecolor()) for h in legend.legend_handles if isinstance(h, Patch)]
        assert faces == [c.lower() for c in SAFETY_HEX]
        title = fig.get_suptitle()
        assert "scan 1" in title and "1.67cm" in title and "green" not in title
    finally:
        plt.close(fig)
    qualitative_panel(_inference(), 0, None, tmp_path / "p.png")
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_safety_codes_put_uncertain_over_the_prediction_and_invalid_over_both():
    label = np.array([[0, 1, 255]], np.int64)
    safe = np.array([[True, True, True]])
    uncertain = np.array([[False, True, True]])
    assert _safety_codes(safe, label, uncertain).tolist() == [[1, 2, 3]]
    assert _safety_codes(~safe, label).tolist() == [[0, 0, 3]]


def _legend_labels(fig) -> list[str]:
    return [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]


def test_the_noise_sweep_legend_names_every_line_drawn_also_one_missing_from_the_first_panel():
    nan = float("nan")
    rows = [
        ReportRow("sigma_sweep", "alhat_baseline", None, s, None, 0.9, 0.8, 0.95, 0.7) for s in (0.0, 0.05, 0.1)
    ] + [ReportRow("sigma_sweep", "base_net", 0.05, s, None, 0.9, 0.8, 0.9, 0.8) for s in (0.0, 0.05, 0.1)]
    # every pixel uncertain (V/C 0): the uncertainty-aware map has no accuracy, only its V/C line
    rows += [ReportRow("sigma_sweep", "uncertainty_aware", 0.05, s, 0.0, nan, nan, nan, nan) for s in (0.0, 0.05, 0.1)]
    result = EvaluationResult(
        rows,
        {},
        [],
        {"bins": 10, "per_sigma": []},
        run={"train_noise": {"kind": "range", "range_m": [0.0, 0.1], "levels_m": []}},
    )
    fig = noise_sweep_figure(result)
    try:
        assert _legend_labels(fig) == ["training range", "ALHAT baseline", "base net", "uncertainty-aware"]
    finally:
        plt.close(fig)


def _sweep_result(threshold: ThresholdJson) -> EvaluationResult:
    sweep = [  # the keys the figure reads
        cast(SweepRowJson, {"test_sigma_m": s, "quantile": q, "precision": 0.9, "sensitivity": 0.5})
        for s in (0.0167, 0.07)
        for q in defaults.QUANTILE_SWEEP
    ]
    base = [ReportRow("noise", "alhat_baseline", None, s, None, 0.8, 0.7, 0.6, 0.3) for s in (0.0167, 0.07)]
    return EvaluationResult(base, {"mean_quantile": 0.62, **threshold}, sweep, {"bins": 10, "per_sigma": []})


def _threshold_lines(fig) -> list[tuple[str, float]]:
    return [
        (line.get_label(), float(line.get_xdata()[0]))
        for ax in fig.axes
        for line in ax.get_lines()
        if "threshold" in line.get_label()
    ]


@pytest.mark.parametrize(
    ("threshold", "expected"),
    [
        ({"spec": "mean", "kind": "mean"}, [("mean-entropy threshold", 0.62)] * 2),
        ({"spec": "risk:0.05", "kind": "risk", "value_quantile": 0.97}, [("threshold risk:0.05", 0.97)] * 2),
        (  # calibrated at each test noise level: each panel its own threshold
            {
                "spec": "quantile:0.68",
                "kind": "quantile",
                "value_quantile": 0.68,
                "per_sigma": [
                    {"calibration_sigma_m": 0.0167, "value_quantile": 0.68, "guarded": False},
                    {"calibration_sigma_m": 0.07, "value_quantile": 0.31, "guarded": True},
                ],
            },
            [("threshold quantile:0.68", 0.68), ("threshold quantile:0.68 (guarded)", 0.31)],
        ),
        ({"spec": "risk:0.05", "kind": "risk"}, []),  # a report made before the quantile was recorded
    ],
)
def test_the_threshold_sweep_marks_the_threshold_of_the_rule_used(threshold, expected):
    fig = threshold_sweep_figure(_sweep_result(threshold))
    try:
        assert _threshold_lines(fig) == expected
    finally:
        plt.close(fig)


def _overlaps(a: Any, b: Any) -> bool:
    """Whether two window extents (display pixels) share an area."""
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


def _inside(fig: Any, legend: Any) -> bool:
    """Whether the legend lies wholly on the figure (not cut off by its edge)."""
    ext = legend.get_window_extent()
    return ext.x0 >= 0 and ext.y0 >= 0 and ext.x1 <= fig.bbox.x1 and ext.y1 <= fig.bbox.y1


def test_the_threshold_sweep_legend_covers_no_panel_and_names_the_baseline_diamonds():
    fig = threshold_sweep_figure(_sweep_result({"spec": "mean", "kind": "mean"}))
    try:
        fig.canvas.draw()
        (legend,) = [legend for ax in fig.axes if (legend := ax.get_legend()) is not None]
        assert _inside(fig, legend)
        for ax in fig.axes:
            assert not _overlaps(legend.get_window_extent(), ax.get_window_extent())
            assert "sigma" not in ax.get_title() and ax.get_title().startswith("test σ ")
        entries = dict(zip([t.get_text() for t in legend.get_texts()], legend.legend_handles, strict=True))
        for words, value in (("precision", 0.6), ("sensitivity", 0.3)):
            handle = entries[f"ALHAT baseline {words} (◆)"]
            assert isinstance(handle, Line2D) and handle.get_marker() == "D" and handle.get_linestyle() == ":"
            (drawn,) = [line for line in fig.axes[0].get_lines() if line.get_label() == f"ALHAT baseline {words} (◆)"]
            x, y = np.asarray(drawn.get_xdata(), float), np.asarray(drawn.get_ydata(), float)
            assert drawn.get_markevery() == [1] and x[1] == 1.0  # the diamond at quantile 1
            assert set(y.tolist()) == {value}
    finally:
        plt.close(fig)


def _reliability_result() -> EvaluationResult:
    per_sigma = [
        {
            "test_sigma_m": sigma,
            "ece": 0.05,
            "bin_count": [0, 3, 40, 500] if k == 0 else [10, 0, 7, 2000],
            "bin_mean_prob": [math.nan, 0.4, 0.6, 0.9] if k == 0 else [0.1, math.nan, 0.7, 0.95],
            "bin_safe_fraction": [math.nan, 0.9, 0.1, 0.95] if k == 0 else [0.05, math.nan, 0.9, 0.92],
        }
        for k, sigma in enumerate((0.0167, 0.07))
    ]
    return EvaluationResult([], {}, [], cast(Any, {"bins": 4, "per_sigma": per_sigma}))


def test_the_reliability_diagram_shows_bin_counts_and_its_legend_covers_no_curve():
    fig = reliability_figure(_reliability_result())
    try:
        curves, counts = fig.axes
        fig.canvas.draw()
        legend = curves.get_legend()
        assert legend is not None and _inside(fig, legend)
        for ax in fig.axes:
            assert not _overlaps(legend.get_window_extent(), ax.get_window_extent())
        labels = [t.get_text() for t in legend.get_texts()]
        assert labels == ["perfect calibration", "test σ 1.67cm (ECE 0.050)", "test σ 7.00cm (ECE 0.050)"]
        # The pixels per bin beneath: each σ's bars side by side in its bin, in its curve's colour.
        bars = [b for b in counts.patches if isinstance(b, Rectangle)]
        assert len(bars) == len(counts.patches)
        assert [b.get_height() for b in bars] == [0, 3, 40, 500, 10, 0, 7, 2000]
        assert [round(b.get_x(), 6) for b in bars] == [0.0, 0.25, 0.5, 0.75, 0.125, 0.375, 0.625, 0.875]
        colours = [line.get_color() for line in curves.get_lines()[1:]]
        assert {matplotlib.colors.to_hex(b.get_facecolor()) for b in bars[:4]} == {matplotlib.colors.to_hex(colours[0])}
        assert counts.get_yscale() == "log" and counts.get_ylabel() == "pixels"
        assert "sigma" not in " ".join([*labels, curves.get_title()])
    finally:
        plt.close(fig)


def _landing(method: str, sigma: float, nav: float, landed: int, p: float, low: float, high: float) -> LandingRow:
    nan = float("nan")
    abstain = 1.0 - landed / 20
    return LandingRow(method, sigma, nav, "terrain", 20, landed, p, low, high, abstain, 0.0, 1.0, 0.0, nan, nan)


def _landing_result() -> EvaluationResult:
    nan = float("nan")
    rows = []
    for method in ("alhat_baseline", "base_net", "uncertainty_aware"):
        for nav in (0.0, 1.0, 3.0):
            rows.append(_landing(method, 0.0167, nav, 20, 0.8, 0.62, 0.91))  # the three methods equal
            rows.append(_landing(method, 0.07, nav, 0, nan, nan, nan))  # every method abstained
    return EvaluationResult([], {}, [], {"bins": 10, "per_sigma": []}, landing=rows)


def test_the_landing_figure_says_when_no_method_chose_a_site_and_dodges_equal_lines():
    fig = landing_figure_of(_landing_result())
    try:
        full, empty = fig.axes
        # The panel where every method abstained says so, and draws no line.
        assert [t.get_text() for t in empty.texts] == [NO_SITE_WORDS] and not empty.get_lines()
        assert "7.00cm" in empty.get_title() and not full.texts
        # Equal values: the three methods' points side by side, each with its own marker.
        lines = [line for line in full.get_lines() if line.get_linestyle() == "-"]
        xs = [tuple(np.round(np.asarray(line.get_xdata(), dtype=float), 6)) for line in lines]
        assert len(lines) == 3 and len(set(xs)) == 3
        assert len({line.get_marker() for line in lines}) == 3
        # The y-axis holds every interval (0.62 to 0.91), not 0.70 upwards.
        low, high = full.get_ylim()
        assert low <= 0.62 and high >= 0.91 and high <= 1.02
        legend = full.get_legend()
        assert legend is not None
        labels = [t.get_text() for t in legend.get_texts()]
        assert labels[0] == "ALHAT baseline: a site in every scene" and not any("≤" in t for t in labels)
        fig.canvas.draw()  # the legend below the panel, over none of its points
        assert legend.get_window_extent().y1 <= full.get_window_extent().y0
    finally:
        plt.close(fig)


def test_the_report_says_at_which_noise_level_no_method_chose_a_site():
    from hdnet.report import _landing_section

    text = "\n".join(_landing_section(_landing_result()))
    assert "At 7 cm no method chose a site in any scene" in text
    assert "At 1.67 cm no method" not in text
