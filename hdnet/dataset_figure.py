"""The dataset at a glance (``hd inspect DIR --plot FILE``): one figure of four panels.

(a) every scan's footprint (the detector's corners on its reference plane) and centre, coloured by
    split, over a hillshade of the terrain the dataset was built on (the manifest's DTM, when the
    file is there with the bytes the build read; else the footprints alone, and the panel says why);
(b) the safe fraction of the labelled pixels per split: the labels' (one per split, the same at
    every noise level) and the ALHAT baseline's at each noise level, of the labelling ``--labels``
    names, or the dataset's only one, or of one convention's two truths the terrain's
    (:func:`chosen_labeling`); "not labelled" without one;
(c) the heights of the clean points of a few scans per split (scan frame: metres above each scan's
    reference height), as density histograms;
(d) the sensor altitude of every scan per split (the scans per split, titled so, when every scan
    flew at one altitude).

What it reads (:func:`dataset_overview`): the small per-scan arrays of the scan shards
(``lidarsim.scan_summary``), the clean points of at most ``HEIGHT_SAMPLE_SCANS`` scans per split,
the labels and baseline P(safe) of the label shards (``hdlabels.split_summary``), and the DTM
decimated to at most ``PREVIEW_PX`` cells a side in one read (``lidarsim.terrain.DTM.preview``),
so that a 1000-scan dataset takes seconds, not the time of reading every point. The figure is
written atomically (:func:`write_dataset_figure`), never inside the dataset (:func:`check_figure_path`).
"""

from __future__ import annotations

import contextlib
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hdcore.errors import HdError, OutputExistsError
from hdcore.storage import atomic_path, check_not_input, check_output_file
from hdlabels.split_summary import SplitSummary, split_summary
from hdlabels.store import LabelingEntry, LabelStoreError, find_labeling, labeling_aliases
from hdlabels.truth import build_terrain_path
from hdnet.errors import HdNetError
from lidarsim.map_window import MapWindow, window_cells
from lidarsim.scan_summary import HEIGHT_SAMPLE_SCANS, ScanSummary, height_sample, scan_summary
from lidarsim.shards import SPLIT_NAMES, read_manifest
from lidarsim.terrain import DTM, dtm_sha256

if TYPE_CHECKING:
    from matplotlib.figure import Figure

FIGURE_SUFFIXES = (".png", ".pdf", ".svg")
PREVIEW_PX = 600  # hd choice: longest side of the terrain's hillshade, cells
MARGIN = 0.08  # hd choice: the terrain shown reaches this fraction of the scans' extent beyond them
SPLIT_COLOURS = {"train": "#1f77b4", "val": "#ff7f0e", "test": "#2ca02c"}
# Panel (b): each split's points shifted sideways by this much (in σ slots) and drawn with its own
# marker, so that splits of equal fractions stay apart (hd choice).
SPLIT_DODGE = {"train": -0.12, "val": 0.0, "test": 0.12}
SPLIT_MARKERS = {"train": "o", "val": "s", "test": "^"}
DPI = 110
PANELS = ("footprints", "safe fraction", "heights", "altitude")


@dataclass(frozen=True)
class Backdrop:
    """The terrain under the footprints: ``heights_m`` (NaN invalid) on cells of about ``cell_m``
    metres covering ``extent`` = (left, right, bottom, top), map metres, of the DTM ``name``."""

    heights_m: np.ndarray
    extent: tuple[float, float, float, float]
    cell_m: float
    name: str


@dataclass(frozen=True)
class DatasetOverview:
    """What the figure shows (each panel's data), and what it could not show, in words.

    ``terrain``: what panel (a) draws the footprints on (``hillshade of NAME``) or why it draws them
    alone; ``labels``: the counts per split of the chosen labelling, None when the dataset has none;
    ``heights``: per split the clean points' heights (metres, scan frame) of ``height_scans`` scans.
    """

    dataset: Path
    scans: ScanSummary
    backdrop: Backdrop | None
    terrain: str
    labels: SplitSummary | None
    heights: dict[str, np.ndarray]
    height_scans: dict[str, int]

    def split_counts(self) -> dict[str, int]:
        """Scans per split, as the footprint panel counts them."""
        return self.scans.split_counts()

    def record(self, path: Path) -> dict[str, object]:
        """The figure's JSON summary (``hd --json inspect DIR --plot FILE``)."""
        labels: dict[str, Any] | None = None
        if self.labels is not None:
            sigmas = [f"{s:g}" for s in self.labels.sigmas_m]
            labels = {
                "labelling": self.labels.labeling,
                "truth": self.labels.truth,
                "safe_fraction": {
                    name: {
                        "labels": c.safe_fraction,
                        "baseline": dict(zip(sigmas, c.baseline_fractions(), strict=True)),
                        "labelled_pixels": c.labelled,
                    }
                    for name, c in self.labels.splits.items()
                },
            }
        altitude = self.scans.altitude_m
        return {
            "path": str(path.resolve()),
            "panels": list(PANELS),
            "scans_per_split": self.split_counts(),
            "terrain": self.terrain,
            "labels": labels,
            "height_sample_scans": self.height_scans,
            "altitude_m": [float(altitude.min()), float(altitude.max())] if altitude.size else None,
        }

    def summary(self, path: Path) -> str:
        """One line for ``hd inspect``: where the figure is and what it shows."""
        n = self.scans.scan_index.size
        where = f"on the {self.terrain}" if self.backdrop is not None else f"({self.terrain})"
        labels = f"safe fraction per σ of {self.labels.labeling}" if self.labels is not None else "not labelled"
        a = self.scans.altitude_m
        altitude = ""
        if a.size:
            altitude = f"; altitude {a.min():g} m" if a.min() == a.max() else f"; altitude {a.min():g} to {a.max():g} m"
        return (
            f"figure    {path}: footprints of {n} scans {where}; {labels}; "
            f"heights of {sum(self.height_scans.values())} scans{altitude}"
        )


# --- checks before any work ----------------------------------------------------------------------------
def check_figure_path(dataset: str | os.PathLike, path: str | os.PathLike, overwrite: bool = False) -> Path:
    """The figure's path, checked before anything is read: a ``.png``, ``.pdf`` or ``.svg`` file in
    a writable directory, never inside the dataset or the DTM it was built on, and no existing file
    unless ``overwrite``.

    Raises:
        HdNetError: another suffix. StorageError: an unwritable place, or a path inside the dataset.
        OutputExistsError: an existing file without ``overwrite``.
    """
    target = Path(path)
    if target.suffix.lower() not in FIGURE_SUFFIXES:
        raise HdNetError(
            f"--plot {target}: give a file name ending in {', '.join(FIGURE_SUFFIXES[:-1])} or {FIGURE_SUFFIXES[-1]} "
            "(the figure's format)"
        )
    inputs: dict[str, str | os.PathLike | None] = {"the dataset": dataset}
    with contextlib.suppress(HdError, OSError):  # no terrain recorded (a bad dataset is refused where it is read)
        inputs["the dataset's terrain"] = build_terrain_path(Path(dataset), read_manifest(dataset))[0]
    check_not_input(target, inputs, flag="--plot")
    check_output_file(target, flag="--plot")
    if os.path.lexists(target) and not overwrite:
        raise OutputExistsError(f"--plot {target} exists; pass --overwrite to replace it, or choose another file")
    return target


TERRAIN_TRUTH = "terrain"  # the truth of the labels the DTM gives (hdlabels.defaults.TRUTHS)


def chosen_labeling(dataset: str | os.PathLike, labels: str | None) -> LabelingEntry | None:
    """The labelling the figure shows: the one ``labels`` names (a name or an alias, as ``hd eval``
    takes it), else the dataset's only one, else, of one convention's two truths (clean scan and
    terrain), the terrain's (what the ground is); None for a dataset without labels.

    Raises:
        LabelStoreError: an unknown labelling, or ``labels`` for a dataset without any.
        HdNetError: several labellings that are not one convention's two truths, and none named (one
            line with their aliases).
        StorageError: not a dataset.
    """
    labelings = read_manifest(dataset).get("labelings") or []
    if labels is None and not labelings:
        return None
    if labels is None and len(labelings) > 1:
        terrain = [lab for lab in labelings if lab.get("truth") == TERRAIN_TRUTH]
        if len(terrain) == 1 and len(labelings) == 2 and len({lab.get("convention") for lab in labelings}) == 1:
            labels = str(terrain[0]["name"])
        else:
            aliases = {name: alias for alias, name in reversed(labeling_aliases(labelings).items())}  # shortest
            shortest = {str(lab["name"]): aliases.get(str(lab["name"]), str(lab["name"])) for lab in labelings}
            raise HdNetError(
                f"{dataset} has {len(labelings)} labellings: choose the figure's with --labels "
                f"({', '.join(shortest.values())})"
            )
    return find_labeling(dataset, labels)


# --- what the panels show ---------------------------------------------------------------------------------
def dataset_overview(directory: str | os.PathLike, labeling: LabelingEntry | None) -> DatasetOverview:
    """Every panel's data for the dataset at ``directory`` and the labelling entry ``labeling``
    (:func:`chosen_labeling`; None: not labelled).

    Raises:
        ShardFormatError / LabelStoreError: a shard that is missing, damaged or not as hd writes it.
    """
    root = Path(directory)
    scans = scan_summary(root)
    backdrop, terrain = _backdrop(root, scans)
    heights, height_scans = height_sample(root, scans, HEIGHT_SAMPLE_SCANS)
    labels = split_summary(root, labeling) if labeling is not None else None
    return DatasetOverview(root, scans, backdrop, terrain, labels, heights, height_scans)


def _backdrop(root: Path, scans: ScanSummary) -> tuple[Backdrop | None, str]:
    """The terrain around the scans' footprints, decimated, and the words for it; or None and why."""
    manifest = read_manifest(root)
    try:
        path, recorded, _ = build_terrain_path(root, manifest)
    except (LabelStoreError, HdError):
        return None, "terrain not shown: the manifest records none"
    if not path.is_file():
        return None, f"terrain not shown: {path} is not there"
    try:
        if dtm_sha256(path) != recorded:
            return None, f"terrain not shown: {path.name} changed since the build (its sha256 is not the manifest's)"
        with DTM.open(path) as dtm:
            info = dtm.info
            corners = scans.footprints_map[np.isfinite(scans.footprints_map).all(axis=(1, 2))]
            cells = window_cells(_around(corners), info.transform, info.rows, info.cols, info.name)
            heights = dtm.preview(PREVIEW_PX, cells.row0, cells.col0, cells.rows, cells.cols)
    except HdError as exc:  # an unreadable DTM, or footprints off it: the footprints alone
        return None, f"terrain not shown: {exc}"
    b = cells.bounds(info.transform)
    cell = float(np.mean(info.spacing_m)) * cells.rows / heights.shape[0]
    return Backdrop(heights, (b.xmin, b.xmax, b.ymin, b.ymax), cell, info.name), f"hillshade of {info.name}"


def _around(corners: np.ndarray) -> MapWindow:
    """The map rectangle of the footprints' corners (K, 4, 2), widened by ``MARGIN`` of its size."""
    if not corners.size:
        raise HdNetError("no footprint lies on the reference plane")
    lo, hi = corners.reshape(-1, 2).min(axis=0), corners.reshape(-1, 2).max(axis=0)
    pad = MARGIN * max(float((hi - lo).max()), 1.0)
    return MapWindow(float(lo[0] - pad), float(lo[1] - pad), float(hi[0] + pad), float(hi[1] + pad))


# --- the figure -------------------------------------------------------------------------------------------
def dataset_figure(overview: DatasetOverview) -> Figure:
    """The four panels of ``overview`` (:data:`PANELS`, in that order) on one matplotlib figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(12.5, 10.0))
    _footprints(axes[0, 0], overview)
    _safe_fraction(axes[0, 1], overview)
    _heights(axes[1, 0], overview)
    _altitude(axes[1, 1], overview)
    counts = overview.split_counts()
    fig.suptitle(
        f"{overview.dataset.name}: {sum(counts.values())} scans, " + ", ".join(f"{counts[s]} {s}" for s in SPLIT_NAMES),
        fontsize=11,
    )
    fig.tight_layout()
    return fig


def write_dataset_figure(overview: DatasetOverview, path: str | os.PathLike) -> Path:
    """:func:`dataset_figure` written to ``path`` atomically (its format from the suffix); returns the path.

    Raises:
        StorageError: the file cannot be written (a full disk); nothing is left at ``path`` then.
    """
    import matplotlib.pyplot as plt

    target = Path(path)
    fig = dataset_figure(overview)
    try:
        with atomic_path(target) as tmp:
            fig.savefig(tmp, format=target.suffix.lower().lstrip("."), dpi=DPI)
    finally:
        plt.close(fig)
    return target


def _footprints(ax: Any, overview: DatasetOverview) -> None:
    from matplotlib.collections import PolyCollection
    from matplotlib.colors import LightSource

    s = overview.scans
    b = overview.backdrop
    if b is not None:
        z = b.heights_m
        finite = np.isfinite(z)
        filled = np.where(finite, z, np.nanmean(z) if finite.any() else 0.0)
        shade = LightSource(azdeg=315, altdeg=45).hillshade(filled, vert_exag=1.0, dx=b.cell_m, dy=b.cell_m)
        import matplotlib.pyplot as plt

        ax.imshow(
            np.where(finite, shade, np.nan),
            cmap=plt.get_cmap("gray").with_extremes(bad="white"),
            extent=b.extent,
            interpolation="nearest",
            vmin=0,
            vmax=1,
        )
    # hd choice: outlines fade as scans add up (0.6 for a few dozen, 0.25 for 1000), so the terrain shows through
    alpha = float(np.clip(8.0 / math.sqrt(max(s.split.size, 1)), 0.25, 0.6))
    for code, name in enumerate(SPLIT_NAMES):
        rows = s.split == code
        colour = SPLIT_COLOURS[name]
        outlines = PolyCollection(list(s.footprints_map[rows]), facecolors="none", edgecolors=colour, linewidths=0.6)
        outlines.set_alpha(alpha)
        ax.add_collection(outlines)
        ax.plot(s.origin_map[rows, 0], s.origin_map[rows, 1], "o", ms=2.5, color=colour, label=f"{name} ({rows.sum()})")
    corners = s.footprints_map[np.isfinite(s.footprints_map).all(axis=(1, 2))]
    if b is not None:
        ax.set_xlim(b.extent[0], b.extent[1])
        ax.set_ylim(b.extent[2], b.extent[3])
    elif corners.size:
        window = _around(corners)
        ax.set_xlim(window.xmin, window.xmax)
        ax.set_ylim(window.ymin, window.ymax)
    if b is None:
        ax.text(
            0.02,
            0.98,
            overview.terrain,
            transform=ax.transAxes,
            va="top",
            fontsize=8,
            wrap=True,
            bbox={"fc": "white", "ec": "0.7", "alpha": 0.9},
        )
    ax.set_aspect("equal")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set(xlabel="x (m)", ylabel="y (m)", title=f"(a) scan footprints and centres by split ({overview.terrain})")
    ax.title.set_fontsize(9)
    ax.legend(fontsize=8, loc="lower right", markerscale=2)


def _safe_fraction(ax: Any, overview: DatasetOverview) -> None:
    lab = overview.labels
    if lab is None:
        ax.text(
            0.5,
            0.5,
            f"not labelled\n(run `hd label {overview.dataset}`)",
            ha="center",
            va="center",
            transform=ax.transAxes,
            fontsize=11,
        )
        ax.set_axis_off()
        ax.set_title("(b) safe fraction per σ and split", fontsize=9)
        return
    x = np.arange(len(lab.sigmas_m))
    for name in SPLIT_NAMES:  # each split shifted sideways, with its own marker: equal values stay apart
        c = lab.splits[name]
        colour, marker, at = SPLIT_COLOURS[name], SPLIT_MARKERS[name], x + SPLIT_DODGE[name]
        base = [math.nan if v is None else v for v in c.baseline_fractions()]
        ax.plot(at, base, ls="-", marker=marker, color=colour, label=f"{name}: ALHAT baseline, P(safe) ≥ 0.5")
        if c.safe_fraction is not None:  # one value at every σ: a dashed line of hollow markers
            ax.plot(
                at, [c.safe_fraction] * x.size, ls="--", lw=1.2, marker=marker, mfc="none", color=colour,
                label=f"{name}: labels ({_truth(lab.truth)})",
            )  # fmt: skip
    ax.set_xticks(x, [f"{s * 100:.2f}" for s in lab.sigmas_m])
    ax.set_xlim(-0.5, x.size - 0.5)
    ax.set(xlabel="σ (cm)", ylabel="safe fraction of labelled pixels", ylim=(0.0, 1.0))
    ax.set_title(f"(b) safe fraction per σ and split\n{lab.labeling}", fontsize=8)
    ax.legend(fontsize=7, loc="lower left")


def _truth(truth: str) -> str:
    return "the terrain's" if truth == "terrain" else "the clean scan's"


def _heights(ax: Any, overview: DatasetOverview) -> None:
    values = [v for v in overview.heights.values() if v.size]
    if not values:
        ax.text(0.5, 0.5, "no returns in the sampled scans", ha="center", va="center", transform=ax.transAxes)
        ax.set_axis_off()
        return
    edges = np.histogram_bin_edges(np.concatenate(values), bins=60)
    for name in SPLIT_NAMES:
        v = overview.heights[name]
        if v.size:
            ax.hist(
                v,
                bins=edges,
                density=True,
                histtype="step",
                lw=1.4,
                color=SPLIT_COLOURS[name],
                label=f"{name} ({overview.height_scans[name]} scans)",
            )
    ax.set(xlabel="height above the scan's reference (m)", ylabel="density")
    ax.set_title(
        f"(c) clean point heights, scan frame (at most {HEIGHT_SAMPLE_SCANS} scans per split, spread evenly)",
        fontsize=9,
    )
    ax.legend(fontsize=8)


def _altitude(ax: Any, overview: DatasetOverview) -> None:
    s = overview.scans
    if not s.altitude_m.size:
        ax.set_axis_off()
        return
    lo, hi = float(s.altitude_m.min()), float(s.altitude_m.max())
    colours = [SPLIT_COLOURS[name] for name in SPLIT_NAMES]
    if hi - lo <= 1e-6 * max(abs(hi), 1.0):  # one altitude: nothing to spread; the scans per split at it
        counts = overview.split_counts()
        bars = ax.bar(list(SPLIT_NAMES), [counts[n] for n in SPLIT_NAMES], color=colours)
        ax.bar_label(bars, fontsize=8)
        ax.set(xlabel=f"split (every scan at {lo:.4g} m)", ylabel="scans")
        ax.set_title(f"(d) scans per split, all at one altitude: {lo:.4g} m above the reference", fontsize=9)
        return
    per_split = [s.altitude_m[s.split == code] for code in range(len(SPLIT_NAMES))]
    ax.hist(per_split, bins=30, stacked=True, color=colours, label=list(SPLIT_NAMES))
    ax.set(xlabel="sensor altitude above the scan's reference (m)", ylabel="scans")
    ax.set_title(f"(d) altitude per split: {lo:.4g} to {hi:.4g} m", fontsize=9)
    ax.legend(fontsize=8)
