"""PNG figures (matplotlib, Agg): an evaluation's reliability, threshold sweep and qualitative panels,
and a detection's overview.

Every evaluation figure takes an ``EvaluationResult`` (``hdnet.results``) and a file path, draws one
figure and closes it. Colours of safety maps: ``hdnet.palette``'s colour-blind-safe set (unsafe
vermillion, safe blue, uncertain yellow, invalid dark grey), the same in every figure and on ``hd
view``'s pages.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from hdnet import defaults
from hdnet.palette import SAFETY_HEX, SAFETY_NAMES
from hdnet.report_json import PerSigmaThresholdJson, ThresholdJson, recorded_noise
from hdnet.results import levels_without_sites
from hdnet.threshold_spec import RULES
from hdnet.uncertainty import ENTROPY, UncertaintyScore, recorded_score

if TYPE_CHECKING:
    from hdnet.results import EvaluationResult, Site, SplitInference

# Offsets (points) of a site's rank label: upper right, lower right, upper left, lower left.
LABEL_OFFSETS_PT = ((5, 5), (5, -13), (-13, 5), (-13, -13))
SAFETY_COLOURS = ListedColormap(list(SAFETY_HEX))
UNCERTAIN_CODE, INVALID_CODE = 2, 3
OVERVIEW_ALPHA = 1.0  # the safety map over overview.png's hillshade: opaque, its colours the legend's
DPI = 110


def sigma_label(sigma_m: float) -> str:
    """A noise level for titles and file names, in centimetres (0.0167 -> '1.67cm')."""
    return f"{sigma_m * 100:.2f}cm"


def reliability_diagram(result: EvaluationResult, path: Path) -> None:
    """:func:`reliability_figure` saved to ``path`` (PNG)."""
    fig = reliability_figure(result)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def reliability_figure(result: EvaluationResult) -> Figure:
    """Observed safe fraction vs mean predicted P(safe) per bin, one line per test σ with its ECE;
    beneath it, the pixels in each bin (bars per test σ, log scale), so that a point made of a few
    pixels is seen as such. The legend lies right of the panels, over no curve."""
    fig, (ax, counts) = plt.subplots(
        2, 1, figsize=(7.0, 6.2), sharex=True, gridspec_kw={"height_ratios": (3, 1)}, layout="constrained"
    )
    ax.plot([0, 1], [0, 1], "k--", lw=1, label="perfect calibration")
    rows = result.calibration["per_sigma"]
    bins = int(result.calibration["bins"])
    width = 1.0 / bins / max(len(rows), 1)
    for k, row in enumerate(rows):
        p = np.asarray(row["bin_mean_prob"], float)
        y = np.asarray(row["bin_safe_fraction"], float)
        ok = np.isfinite(p) & np.isfinite(y)
        words = f"test σ {sigma_label(row['test_sigma_m'])}"
        (line,) = ax.plot(p[ok], y[ok], "o-", ms=4, label=f"{words} (ECE {row['ece']:.3f})")
        n = np.asarray(row.get("bin_count", []), float)
        left = np.arange(n.size) / bins + k * width  # each σ's bar side by side within its bin
        counts.bar(left, n, width=width, align="edge", color=line.get_color(), label=f"{words}: pixels per bin")
    ax.set(xlim=(0, 1), ylim=(0, 1), ylabel="observed safe fraction", title=f"Reliability ({bins} bins)")
    counts.set(xlabel="mean predicted P(safe)", ylabel="pixels")
    if any(np.any(np.asarray(r.get("bin_count", []), float) > 0) for r in rows):
        counts.set_yscale("log")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    return fig


def threshold_sweep(result: EvaluationResult, path: Path) -> None:
    """:func:`threshold_sweep_figure` saved to ``path`` (PNG)."""
    fig = threshold_sweep_figure(result)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def used_threshold(threshold: ThresholdJson, sigma_m: float) -> tuple[str, float] | None:
    """The threshold that scored the test split at ``sigma_m`` metres, as (label, validation quantile):
    the report's own rule (``mean-entropy threshold`` for the paper's, ``threshold risk:0.05``...), its
    own calibration at that noise level with ``--calibrate each`` (``(guarded)`` when the precision
    guard lowered it). None when the report does not record where a rule other than the mean lies
    (reports written before ``value_quantile``)."""
    spec, rule = str(threshold.get("spec", "mean")), RULES.get(str(threshold.get("kind", "mean")))
    by_mean = rule is not None and rule.is_mean  # the paper's rule: labelled by the score it averages
    entry: ThresholdJson | PerSigmaThresholdJson = threshold
    for own in threshold.get("per_sigma") or []:
        if math.isclose(float(own.get("calibration_sigma_m", math.nan)), sigma_m, abs_tol=1e-12):
            entry = own
    guarded = bool(entry.get("guarded", False))
    quantile = entry.get("value_quantile")
    if quantile is None and by_mean and not guarded:
        quantile = threshold.get("mean_quantile")
    if quantile is None:
        return None
    if by_mean and not guarded:
        return f"mean-{recorded_score(threshold).short} threshold", float(quantile)
    return f"threshold {spec}" + (" (guarded)" if guarded else ""), float(quantile)


def threshold_sweep_figure(result: EvaluationResult) -> Figure:
    """Precision and sensitivity of the uncertainty-aware map vs the threshold's validation quantile.

    One panel per test sigma; dashed line: the threshold the report used at that sigma, labelled with
    its rule (:func:`used_threshold`; the mean validation score, entropy or mutual information,
    ``hdnet.uncertainty``, for the paper's rule); dotted lines with a diamond at quantile 1: the ALHAT
    baseline's precision and sensitivity at that sigma (it has no threshold). The legend lies below the
    panel (below each panel when their thresholds differ), over no curve.
    """
    short = recorded_score(result.threshold).short
    sigmas = sorted({row["test_sigma_m"] for row in result.sweep})
    fig, axes = plt.subplots(1, len(sigmas), figsize=(4.2 * len(sigmas), 4.6), squeeze=False)
    for ax, sigma in zip(axes[0], sigmas, strict=True):
        pts = [r for r in result.sweep if r["test_sigma_m"] == sigma]
        q = [r["quantile"] for r in pts]
        ax.plot(q, [r["precision"] for r in pts], "o-", color="tab:blue", label="precision")
        ax.plot(q, [r["sensitivity"] for r in pts], "s-", color="tab:orange", label="sensitivity")
        used = used_threshold(result.threshold, sigma)
        if used is not None:
            ax.axvline(used[1], color="k", ls="--", lw=1, label=used[0])
        base = [
            r for r in result.rows if r.table == "noise" and r.method == "alhat_baseline" and r.test_sigma_m == sigma
        ]
        if base:  # dotted across the panel, its diamond at quantile 1 (every pixel certain): one entry each
            b = base[0]
            for value, colour, words in (
                (b.precision, "tab:blue", "precision"),
                (b.sensitivity, "tab:orange", "sensitivity"),
            ):
                label = f"ALHAT baseline {words} (◆)"
                ax.plot(
                    [0.0, 1.0, 1.05], [value] * 3, ls=":", lw=1, marker="D", markevery=[1], color=colour, label=label
                )
        ax.set(
            xlim=(0, 1.05),
            ylim=(0, 1.02),
            xlabel=f"threshold quantile (validation {short})",
            title=f"test σ {sigma_label(sigma)}",
        )
    axes[0][0].set_ylabel("fraction")
    own = {str(used_threshold(result.threshold, sigma)) for sigma in sigmas}
    for ax in axes[0] if len(own) > 1 else axes[0][-1:]:  # a legend per panel when their thresholds differ
        # Below the panel, never over its curves.
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.18), frameon=False, ncol=2)
    fig.tight_layout()
    return fig


def noise_sweep(result: EvaluationResult, path: Path) -> None:
    """:func:`noise_sweep_figure` saved to ``path`` (PNG)."""
    fig = noise_sweep_figure(result)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def noise_sweep_figure(result: EvaluationResult) -> Figure:
    """PA, precision, sensitivity and V/C % against the test noise level (``sigma_sweep`` rows) for
    the ALHAT baseline, the base net and the uncertainty-aware map; the training noise range shaded
    (or its levels marked). The legend names every line of every panel (a method whose accuracy is
    undefined everywhere, every pixel uncertain, is still drawn in the V/C panel)."""
    rows = [r for r in result.rows if r.table == "sigma_sweep"]
    methods = [
        ("alhat_baseline", "ALHAT baseline", "tab:gray"),
        ("base_net", "base net", "tab:blue"),
        ("uncertainty_aware", "uncertainty-aware", "tab:red"),
    ]
    panels = [
        ("pixel_accuracy", "pixel accuracy"),
        ("precision", "precision (safe)"),
        ("sensitivity", "sensitivity (safe)"),
        ("vc_fraction", "V/C pixels"),
    ]
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.8))
    range_m, levels = recorded_noise(result.run.get("train_noise"))
    for ax, (key, title) in zip(axes, panels, strict=True):
        if range_m:
            lo, hi = range_m
            ax.axvspan(lo * 100, hi * 100, color="tab:green", alpha=0.12, label="training range")
        for level in levels:
            ax.axvline(level * 100, color="tab:green", lw=1, ls="--", label="training level")
        for method, label, colour in methods:
            pts = sorted((r.test_sigma_m, getattr(r, key)) for r in rows if r.method == method)
            pts = [(s, v) for s, v in pts if v is not None and math.isfinite(v)]
            if pts:
                ax.plot([s * 100 for s, _ in pts], [v for _, v in pts], "o-", ms=3, color=colour, label=label)
        ax.set(xlabel="test noise 1σ (cm)", title=title, ylim=(0, 1.02))
    unique: dict[str, Any] = {}
    for ax in axes:
        handles, labels = ax.get_legend_handles_labels()
        for label, handle in zip(labels, handles, strict=True):
            unique.setdefault(label, handle)
    order = ["training range", "training level", *(label for _, label, _ in methods)]
    names = sorted(unique, key=lambda name: order.index(name) if name in order else len(order))
    axes[-1].legend([unique[n] for n in names], names, fontsize=7, loc="lower left")
    fig.tight_layout()
    return fig


def safety_legend_handles() -> list[Patch]:
    """One legend patch per safety-map colour (unsafe, safe, uncertain, invalid), as the maps draw them."""
    return [
        Patch(facecolor=colour, edgecolor="#555555", linewidth=0.5, label=name)
        for colour, name in zip(SAFETY_HEX, SAFETY_NAMES, strict=True)
    ]


def _safety_codes(safe: np.ndarray, label: np.ndarray, uncertain: np.ndarray | None = None) -> np.ndarray:
    codes = safe.astype(np.int64)
    if uncertain is not None:
        codes[uncertain] = UNCERTAIN_CODE
    codes[label == defaults.IGNORE_INDEX] = INVALID_CODE
    return codes


def representative_scan(inf: SplitInference) -> int:
    """Row of the test scan whose valid pixels are closest to half safe (ties: the first)."""
    valid = inf.label != defaults.IGNORE_INDEX
    n_valid = valid.sum(axis=(1, 2))
    safe = ((inf.label == defaults.CLASS_SAFE) & valid).sum(axis=(1, 2))
    frac = np.where(n_valid > 0, safe / np.maximum(n_valid, 1), -1.0)
    return int(np.argmin(np.abs(frac - 0.5)))


def qualitative_panel(
    inf: SplitInference, row: int, threshold_nats: float | None, path: Path, uncertainty: UncertaintyScore = ENTROPY
) -> None:
    """True DEM, label, noisy DEM, uncertainty, uncertainty-aware prediction, baseline for one scan,
    saved to ``path`` (PNG); ``uncertainty``: the score shown and thresholded."""
    fig = qualitative_figure(inf, row, threshold_nats, uncertainty)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def qualitative_figure(
    inf: SplitInference, row: int, threshold_nats: float | None, uncertainty: UncertaintyScore = ENTROPY
) -> Figure:
    """The figure of ``qualitative_panel``: six panels, safety maps explained by a colour legend."""
    label = inf.label[row]
    t = math.inf if threshold_nats is None else threshold_nats
    values = uncertainty.of(inf)[row]
    uncertain = values >= t
    panels: list[tuple[str, np.ndarray, dict[str, Any]]] = [
        ("true DEM (m)", inf.dem_clean_m[row], {"cmap": "terrain"}),
        ("label", _safety_codes(label == defaults.CLASS_SAFE, label), {"cmap": SAFETY_COLOURS, "vmin": 0, "vmax": 3}),
        ("noisy DEM (m)", inf.dem_noisy_m[row], {"cmap": "terrain"}),
        ("uncertainty (nats)", values, {"cmap": "viridis", "vmin": 0.0, "vmax": math.log(2)}),
        (
            "uncertainty-aware",
            _safety_codes(inf.prediction[row] == defaults.CLASS_SAFE, label, uncertain),
            {"cmap": SAFETY_COLOURS, "vmin": 0, "vmax": 3},
        ),
        (
            "ALHAT baseline",
            _safety_codes(inf.baseline_safe[row], label),
            {"cmap": SAFETY_COLOURS, "vmin": 0, "vmax": 3},
        ),
    ]
    fig, axes = plt.subplots(1, len(panels), figsize=(3.0 * len(panels), 3.3))
    for ax, (title, img, kw) in zip(axes, panels, strict=True):
        im = ax.imshow(img, interpolation="nearest", **kw)
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        if title.endswith(")"):
            fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02)
    fig.suptitle(f"scan {int(inf.scan_index[row])}, test sigma {sigma_label(inf.sigma_m)}", fontsize=9)
    fig.legend(handles=safety_legend_handles(), loc="lower center", ncol=len(SAFETY_NAMES), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0.0, 0.07, 1.0, 1.0))
    return fig


LANDING_METHODS = (  # (method, name, colour, marker): markers tell the lines apart where they overlap
    ("alhat_baseline", "ALHAT baseline", "tab:gray", "s"),
    ("base_net", "base net", "tab:orange", "^"),
    ("uncertainty_aware", "uncertainty-aware", "tab:blue", "o"),
)


LANDING_DODGE = 0.025  # hd choice: each method's points shifted by this fraction of the dispersions' span
NO_SITE_WORDS = "no method chose a site\nin any scene"


def landing_figure(result: EvaluationResult, path: Path) -> None:
    """:func:`landing_figure_of` saved to ``path`` (PNG)."""
    fig = landing_figure_of(result)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def landing_figure_of(result: EvaluationResult) -> Figure:
    """P(safe landing) against the navigation dispersion, one panel per truth and test noise level
    (its scenes scored in the title), one line per method with its 95 % Wilson interval; the methods'
    points dodged sideways so that equal values stay visible; the y-axis holds every interval; a panel
    where no method chose a site in any scene says so instead of drawing an empty axis. The legend
    says in how many scenes each method chose no site."""
    truths = list(dict.fromkeys(r.truth for r in result.landing))
    sigmas = sorted({r.test_sigma_m for r in result.landing})
    fig, axes = plt.subplots(
        len(truths), len(sigmas), figsize=(3.4 * len(sigmas), 3.6 * len(truths)), squeeze=False, sharey=True
    )
    navs = sorted({r.nav_sigma_m for r in result.landing})
    dodge = LANDING_DODGE * max(navs[-1] - navs[0], 1.0) if navs else 0.0
    for i, truth in enumerate(truths):
        silent = levels_without_sites(result.landing, truth)
        for k, sigma in enumerate(sigmas):
            ax = axes[i][k]
            if sigma in silent:
                ax.text(0.5, 0.5, NO_SITE_WORDS, ha="center", va="center", transform=ax.transAxes, fontsize=8)
                ax.tick_params(left=False, labelleft=k == 0, bottom=False, labelbottom=False)
            else:
                _landing_panel(ax, result, truth, sigma, dodge)
            scenes = max((r.scenes for r in result.landing if r.truth == truth and r.test_sigma_m == sigma), default=0)
            ax.set_title(f"{truth} truth, test σ {sigma_label(sigma)}, {scenes} scenes", fontsize=8)
            if k == 0:
                ax.set_ylabel("P(safe landing)", fontsize=8)
    low, high = _landing_limits(result.landing)
    axes[0][0].set_ylim(low, high)  # shared by every panel
    fig.tight_layout()
    return fig


def _landing_limits(rows: list[Any]) -> tuple[float, float]:
    """y-limits that hold every drawn P(safe landing) and its interval, with a margin, within [0, 1.02]."""
    ends = [v for r in rows if r.landed > 0 for v in (r.p_safe_low, r.p_safe, r.p_safe_high) if math.isfinite(v)]
    if not ends:
        return 0.0, 1.02
    low, high = min(ends), max(ends)
    pad = max(0.03, 0.08 * (high - low))
    return max(0.0, low - pad), min(1.02, high + pad)


def _landing_panel(ax: Any, result: EvaluationResult, truth: str, sigma: float, dodge: float) -> None:
    """One panel of :func:`landing_figure_of`: each method's line, shifted by ``dodge`` metres per method."""
    for m, (method, name, colour, marker) in enumerate(LANDING_METHODS):
        rows = sorted(
            (r for r in result.landing if r.truth == truth and r.test_sigma_m == sigma and r.method == method),
            key=lambda r: r.nav_sigma_m,
        )
        if not rows:
            continue
        x = np.array([r.nav_sigma_m for r in rows]) + (m - (len(LANDING_METHODS) - 1) / 2) * dodge
        y = np.array([r.p_safe for r in rows])
        # Wilson's interval holds the rate, but its ends may fall a rounding error inside it;
        # a method that never landed has no rate (NaN, not drawn).
        err = np.nan_to_num(
            np.array([[r.p_safe - r.p_safe_low for r in rows], [r.p_safe_high - r.p_safe for r in rows]])
        ).clip(min=0.0)
        abstain = max(r.abstain_rate for r in rows)
        words = "a site in every scene" if abstain <= 0.0 else f"no site in up to {100 * abstain:.0f} % of scenes"
        ax.errorbar(x, y, yerr=err, color=colour, marker=marker, ms=4, capsize=2, label=f"{name}: {words}")
    ax.set_xlabel("navigation dispersion 1σ (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)
    # Below the panel, never over its points and intervals.
    ax.legend(fontsize=6, loc="upper center", bbox_to_anchor=(0.5, -0.22), frameon=False)


def write_figures(result: EvaluationResult, out_dir: Path) -> list[Path]:
    """All figures of a result into ``out_dir``; returns their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / "reliability.png", out_dir / "threshold_sweep.png"]
    reliability_diagram(result, paths[0])
    threshold_sweep(result, paths[1])
    if any(r.table == "sigma_sweep" for r in result.rows):
        paths.append(out_dir / "noise_sweep.png")
        noise_sweep(result, paths[-1])
    if result.landing:
        paths.append(out_dir / "landing.png")
        landing_figure(result, paths[-1])
    if result.test:
        first = next(iter(result.test.values()))
        row = representative_scan(first)
        for sigma, inf in result.test.items():
            p = out_dir / f"qualitative_{sigma_label(sigma)}.png"
            qualitative_panel(inf, row, result.threshold["value_nats"], p, recorded_score(result.threshold))
            paths.append(p)
    return paths


def detect_overview(
    heights_m: np.ndarray,
    cell_m: float,
    safety: np.ndarray,
    extent: tuple[float, float, float, float],
    sites: list[Site],
    lander_radius_m: float,
    title: str,
    path: Path,
) -> None:
    """Hillshade of the terrain, the safety map over it and the numbered sites (circles of the lander's size).

    ``heights_m`` (NaN invalid) and ``safety`` (codes 0 unsafe, 1 safe, 2 uncertain, 255 invalid) share
    one grid of ``cell_m``-metre cells covering ``extent`` = (left, right, bottom, top), map metres.
    """
    from matplotlib.colors import LightSource
    from matplotlib.patches import Circle, Patch

    z = np.asarray(heights_m, np.float64)
    finite = np.isfinite(z)
    filled = np.where(finite, z, np.nanmean(z) if finite.any() else 0.0)
    shade = LightSource(azdeg=315, altdeg=45).hillshade(filled, vert_exag=1.0, dx=cell_m, dy=cell_m)
    shade = np.where(finite, shade, np.nan)
    colours = SAFETY_HEX
    rgba = np.zeros((*safety.shape, 4))
    for code in (0, 1, 2):  # opaque, so that the map's colours are the legend's
        rgba[safety == code] = (*matplotlib.colors.to_rgb(colours[code]), OVERVIEW_ALPHA)
    left, right, bottom, top = extent
    aspect = (top - bottom) / max(right - left, 1e-9)
    fig, ax = plt.subplots(figsize=(8.0, float(np.clip(8.0 * aspect, 3.0, 10.0)) + 1.0))
    gray = plt.get_cmap("gray").with_extremes(bad="white")
    ax.imshow(shade, cmap=gray, extent=extent, interpolation="nearest", vmin=0, vmax=1)
    ax.imshow(rgba, extent=extent, interpolation="nearest")
    placed: list[tuple[float, float, int]] = []
    for s in sites:
        ax.add_patch(Circle((s.x, s.y), lander_radius_m, fill=False, ec="black", lw=1.6))
        ax.add_patch(Circle((s.x, s.y), lander_radius_m, fill=False, ec="white", lw=0.7))
        # Neighbours closer than three lander radii take the label corners their neighbours left free.
        taken = {k for (x, y, k) in placed if math.hypot(s.x - x, s.y - y) < 3.0 * lander_radius_m}
        corner = next((k for k in range(len(LABEL_OFFSETS_PT)) if k not in taken), len(placed) % len(LABEL_OFFSETS_PT))
        placed.append((s.x, s.y, corner))
        ax.annotate(
            str(s.rank),
            (s.x, s.y),
            xytext=LABEL_OFFSETS_PT[corner],
            textcoords="offset points",
            fontsize=8,
            fontweight="bold",
            color="black",
            bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.8},
        )
    ax.set_xlim(left, right)
    ax.set_ylim(bottom, top)
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set(xlabel="x (m)", ylabel="y (m)", title=title)
    ax.title.set_fontsize(9)
    handles = [
        Patch(color=colours[0], alpha=OVERVIEW_ALPHA, label="unsafe"),
        Patch(color=colours[1], alpha=OVERVIEW_ALPHA, label="safe"),
        Patch(color=colours[2], alpha=OVERVIEW_ALPHA, label="uncertain"),
        Patch(fc="white", ec="0.6", label="no colour: invalid (border, nodata; hillshade shows)"),
        Patch(fc="none", ec="black", label="landing site (lander size)"),
    ]
    ax.legend(
        handles=handles, fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=len(handles), frameon=False
    )
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
