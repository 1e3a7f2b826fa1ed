"""``hd view DIR``: one self-contained HTML page of an ``hd detect`` output or of an ``hd eval`` report.

The page (``DIR-view.html`` beside the directory, or ``--out FILE``; never inside ``DIR`` unless
``--out`` puts it there: the output stays as its command wrote and recorded it, and an ``hd detect
--overwrite`` of it cannot take the page along) needs no network: its images are PNG ``data:`` URIs,
its style and script are inline and its Content-Security-Policy lets a browser fetch nothing
(``hdnet.view_html``). Which kind ``DIR`` is comes from its marker: ``detect.json`` (``hd
detect``) or ``report.json`` (``hd eval``); a run, a dataset, an empty directory or anything else is
refused with what to give instead.

A detect output's page: the map (the terrain's hillshade, the safety map of the uncertainty-aware
network, P(safe), entropy, mutual information and the ALHAT baseline's P(safe) as layers that can
be switched on and off and made more or less opaque, the landing sites as numbered circles of the
lander's size; zoom; under the pointer its map coordinates, class and values), the table of
sites (``sites.csv`` verbatim: clicking a row marks its site), the counts per class and the settings
of the detection (run, input, sensor sigma, threshold, navigation sigma, split of a scan, lander,
grid), with ``detect.json`` whole. A map larger than ``max_px`` pixels a side is shown reduced
(``hdnet.view_images``), and the page says so. The hillshade is made from the terrain the detection
read, when it is still there with the same bytes (the DTM's sha256, the dataset's manifest and the
label shard's checksum): a DTM at another path can be given (``dtm``); without it the page says
why there is no hillshade.

A descent output's page (``hd descend``; its marker ``descend.json``): ``hdnet.view_descent``.

A report's page: ``report.md``'s content (the tables with their numbers from ``report.json``,
rendered by ``hdnet.report.report_markdown``), its figures inline, and every setting of the
report (``hdnet.compare.settings``).

Every file is checked as it is read: a damaged ``detect.json``, map, ``sites.csv``, ``report.json``
or figure is one error naming the file, and nothing is written. The page is written atomically
(``hdcore.storage.write_text_atomic``) and never over anything but an earlier page of ``hd view``;
while it is made, the directory's writer lock is held (when the page goes into it) or checked, so an
``hd detect`` or ``hd eval`` writing the directory is never read half-way.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import re
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeGuard, cast

import numpy as np

from hdcore.errors import DamagedFileError, HdError, LockedError, OutputExistsError, StorageError
from hdcore.outcome import Done
from hdcore.setting import check, setting
from hdcore.storage import (
    WriterLock,
    check_output_file,
    check_regular_file,
    lock_holder,
    read_json,
    read_regular_bytes,
    read_regular_text,
    sha256_file,
    write_text_atomic,
)
from hdlabels.store import find_labeling, open_label_shard
from hdnet import limits
from hdnet._version import __version__
from hdnet.chance import threshold_warning
from hdnet.compare import read_report
from hdnet.compare import settings as report_settings
from hdnet.descend_json import RECORD_NAME as DESCEND_MARKER
from hdnet.detect_json import DetectInfoJson, input_name
from hdnet.errors import HdNetError
from hdnet.page_values import number, readable, shown_path, without_paths
from hdnet.report import json_plain, report_markdown
from hdnet.report_json import ReportJson, recorded_noise
from hdnet.results import SITE_COLUMNS, EvaluationResult, LandingRecord, LandingRow, ReportRow
from hdnet.run_files import CONFIG, LAST
from hdnet.uncertainty import recorded_score
from hdnet.view_html import (
    anchor,
    colour_bar,
    data_uri,
    definitions,
    esc,
    is_page,
    map_style,
    markdown_html,
    page,
    table,
)
from lidarsim.shards import MANIFEST_NAME

if TYPE_CHECKING:  # hdnet.view_images imports matplotlib: only where the page is drawn
    from hdnet.view_images import Reduction

VIEW_SUFFIX = "-view.html"  # the default page of DIR: DIR-view.html beside it (default_page)
DETECT_MARKER = "detect.json"
REPORT_MARKER = "report.json"
DEFAULT_MAX_PX = 2048  # hd choice: a map image's longest side, pixels (a screen's width; ~4 MP per layer)
FIGURE_MAX_BYTES = 64 << 20  # hd choice: the largest report figure inlined (hd's own are ~100 kB)
HEAD_BYTES = 4096  # read of an existing --out file to recognise an earlier page
SWATCHES = ("unsafe", "safe", "uncertain")  # the safety legend's swatches, in hdnet.palette.SAFETY_HEX's order
# The safety layer's opacity at first, percent: opaque, so that its colours are its swatches' (a
# lower opacity blends them with the hillshade; the slider still shows the terrain through it).
SAFETY_OPACITY = 100
# The site table's headings: words and units for sites.csv's columns (the CSV keeps its names).
SITE_HEADERS = {
    "rank": "#",
    "x": "x (m)",
    "y": "y (m)",
    "p_safe": "aim P(safe)",
    "entropy_max": "max entropy (nats)",
    "clearance_m": "clearance (m)",
    "baseline_p_safe": "baseline P(safe)",
    "touchdown_p_safe": "touchdown P(safe)",
}
RANKED_MARK = " ▼ ranked by"  # after the heading of the column the sites are ranked by
SITE_DECIMALS = 3  # a site's numbers on the page (sites.csv keeps six)
SITE_TITLES = {
    "rank": "1 = best (the site rule below)",
    "x": "map x of the site's cell centre, metres (the input's CRS, or the scan frame)",
    "y": "map y of the site's cell centre, metres",
    "p_safe": "mean P(safe) over the lander's footprint at the aim point",
    "entropy_max": "largest predictive entropy over the footprint, nats",
    "clearance_m": "distance to the nearest cell that is not safe and certain, metres",
    "baseline_p_safe": "the ALHAT baseline's P(safe) at the site",
    "touchdown_p_safe": "expected P(safe) where the vehicle touches down under the navigation dispersion",
}


@dataclass(frozen=True)
class ViewSettings:
    """How ``hd view`` draws a detect output's maps."""

    max_px: int = setting(
        DEFAULT_MAX_PX,
        "Longest side of a map image, pixels: a larger map is shown at one pixel per block of cells (said on the "
        "page; the GeoTIFFs keep every cell)",
        bound=limits.VIEW_PX,
    )

    def __post_init__(self) -> None:
        check(self, HdNetError)


@dataclass
class ViewResult:
    """What ``view`` wrote: the page, its kind (``detect``, ``descend`` or ``report``), its size and what it shows."""

    path: Path
    kind: str
    source: Path
    n_bytes: int
    info: dict[str, object] = field(default_factory=dict)

    def summary(self) -> str:
        """One line for the terminal."""
        what = self.info.get("what", "")
        return f"wrote {self.path} ({self.n_bytes / 1e6:.1f} MB; {what}); open it in a browser, no network needed"


# ----------------------------------------------------------------------------------------- the kind
def source_of(path: str | os.PathLike) -> tuple[Path, str]:
    """The directory of ``path`` (a detect output or a report, or its ``detect.json`` or ``report.json``)
    and its kind, ``detect`` or ``report``.

    Raises:
        HdNetError: a missing path, a run, a dataset, an empty directory or any other directory that
            holds neither marker (each with what to give instead), or one that holds both.
    """
    p = Path(path)
    if p.name in (DETECT_MARKER, REPORT_MARKER, DESCEND_MARKER) and not p.is_dir():
        p = p.parent
    if not p.exists():
        raise HdNetError(f"{p}: no such directory; give an hd detect --out or hd eval --out directory")
    if not p.is_dir():
        raise HdNetError(f"{p} is a file, not an hd detect or hd eval output directory")
    if os.path.lexists(p / DESCEND_MARKER):
        return p, "descend"  # hd descend writes neither of the other markers
    has = {m: os.path.lexists(p / m) for m in (DETECT_MARKER, REPORT_MARKER)}
    if all(has.values()):
        raise HdNetError(f"{p} holds both {DETECT_MARKER} and {REPORT_MARKER}: hd never writes both in one directory")
    if has[DETECT_MARKER]:
        return p, "detect"
    if has[REPORT_MARKER]:
        return p, "report"
    if (p / LAST).exists() or (p / CONFIG).exists():
        raise HdNetError(
            f"{p} is a run: hd view shows what hd detect or hd eval made of it; run `hd detect {p} --dtm DTM --out "
            f"D` or `hd eval {p} --data DATASET --out R` and view D or R"
        )
    if (p / MANIFEST_NAME).exists():
        raise HdNetError(
            f"{p} is a dataset: `hd inspect {p}` describes it; hd view shows hd detect and hd eval outputs"
        )
    try:
        empty = not any(True for _ in p.iterdir())
    except OSError as exc:
        raise StorageError(f"{p}: cannot be listed ({exc.strerror or exc})") from exc
    what = "is empty" if empty else f"holds neither {DETECT_MARKER} (hd detect) nor {REPORT_MARKER} (hd eval)"
    raise HdNetError(f"{p} {what}: give an hd detect --out or hd eval --out directory")


# ----------------------------------------------------------------------------------- detect outputs
@dataclass(frozen=True)
class DetectOutput:
    """A checked ``hd detect`` output: its ``detect.json``, grid and ``sites.csv`` rows (the CSV's text)."""

    directory: Path
    info: DetectInfoJson
    rows: int
    cols: int
    transform: tuple[float, float, float, float, float, float]
    site_rows: list[list[str]]

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(left, right, bottom, top) of the grid, map metres."""
        a, _, c, _, e, f = self.transform
        return c, c + a * self.cols, f + e * self.rows, f


def _schema_error(file: Path, what: str) -> HdNetError:
    return HdNetError(f"{file}: not an hd detect output of this schema ({what}); run hd detect again to write it")


def _finite(value: object) -> TypeGuard[float]:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def read_detect(directory: Path) -> DetectOutput:
    """The detect output in ``directory``, its ``detect.json`` and ``sites.csv`` checked.

    Raises:
        StorageError / DamagedFileError: an unreadable or damaged ``detect.json`` or ``sites.csv``, or
            a ``sites.csv`` that disagrees with ``detect.json``.
        HdNetError: a ``detect.json`` of another schema.
    """
    file = directory / DETECT_MARKER
    info = read_json(file, "detect.json")
    if not isinstance(info, dict):
        raise _schema_error(file, f"a JSON {type(info).__name__}, not an object")
    for key in ("grid", "threshold", "counts", "lander", "run", "input"):
        if not isinstance(info.get(key), dict):
            raise _schema_error(file, f"no {key!r} object")
    if not isinstance(info.get("sites"), list):
        raise _schema_error(file, "no 'sites' list")
    grid = info["grid"]
    rows, cols, t = grid.get("rows"), grid.get("cols"), grid.get("transform")
    if not (isinstance(rows, int) and isinstance(cols, int) and rows > 0 and cols > 0):
        raise _schema_error(file, f"grid rows and cols {rows!r} x {cols!r}")
    if not (isinstance(t, list) and len(t) == 6 and all(_finite(v) for v in t)):
        raise _schema_error(file, f"grid transform {t!r}")
    if t[0] <= 0 or t[4] >= 0 or t[1] != 0 or t[3] != 0:
        raise _schema_error(file, f"grid transform {t!r} is not north-up")
    if not _finite(info["lander"].get("diameter_m")) or info["lander"]["diameter_m"] <= 0:
        raise _schema_error(file, "no lander diameter")
    counts = info["counts"]
    if not all(
        isinstance(counts.get(k), int) and not isinstance(counts[k], bool) for k in ("safe", "unsafe", "uncertain")
    ):
        raise _schema_error(file, f"cell counts {counts!r}")
    transform = (float(t[0]), float(t[1]), float(t[2]), float(t[3]), float(t[4]), float(t[5]))
    checked = cast("DetectInfoJson", info)  # the keys read without a default checked above
    return DetectOutput(directory, checked, rows, cols, transform, _read_sites(directory, info["sites"]))


def _read_sites(directory: Path, recorded: list[Any]) -> list[list[str]]:
    """``sites.csv``'s rows (text, as written), checked against its header and ``detect.json``'s sites."""
    file = directory / "sites.csv"
    text = read_regular_text(file)
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or tuple(rows[0]) != SITE_COLUMNS:
        raise DamagedFileError(f"{file}: its header is not {','.join(SITE_COLUMNS)}; run hd detect again")
    body = rows[1:]
    if len(body) != len(recorded):
        raise DamagedFileError(
            f"{file}: {len(body)} site(s), detect.json records {len(recorded)}; the output is damaged: run hd detect "
            "again"
        )
    for k, (row, site) in enumerate(zip(body, recorded, strict=True)):
        where = f"{file}: row {k + 2}"
        if len(row) != len(SITE_COLUMNS):
            raise DamagedFileError(f"{where} has {len(row)} values, not {len(SITE_COLUMNS)}; run hd detect again")
        try:
            rank, x, y = int(row[0]), float(row[1]), float(row[2])
        except ValueError as exc:
            raise DamagedFileError(f"{where}: rank, x or y is not a number ({exc}); run hd detect again") from exc
        if rank != k + 1 or not (math.isfinite(x) and math.isfinite(y)):
            raise DamagedFileError(f"{where}: rank {row[0]}, x {row[1]}, y {row[2]} are not a ranked site's")
        if not (
            isinstance(site, dict)
            and _finite(site.get("x"))
            and _finite(site.get("y"))
            and abs(float(site["x"]) - x) <= 1e-3
            and abs(float(site["y"]) - y) <= 1e-3
        ):
            raise DamagedFileError(
                f"{where}: site {rank} at ({row[1]}, {row[2]}) is not detect.json's site {k + 1}; the output is "
                "damaged: run hd detect again"
            )
    return body


# ----------------------------------------------------------------------------------- the terrain
def _hillshade_source(out: DetectOutput, dtm: Path | None, base: Path) -> tuple[Path | None, str]:
    """The raster to shade for a DTM detection and a note (its paths relative to the page's folder
    ``base``); (None, why not) when it cannot be used."""
    source = out.info["input"]
    if source.get("kind") != "dtm":
        return None, ""
    recorded = str(source.get("path", ""))
    path = Path(dtm) if dtm is not None else Path(recorded)
    shown = shown_path(path.absolute(), base)
    if not path.is_file():
        return None, (
            f"No hillshade: the DTM {shown_path(recorded, base)} that hd detect read is not there any more; give it "
            "with --dtm"
            if dtm is None
            else f"No hillshade: --dtm {shown} is not a file"
        )
    try:
        digest = sha256_file(path)
    except StorageError as exc:
        return None, f"No hillshade: {shown} cannot be read ({exc.__class__.__name__})"
    if digest != source.get("sha256"):
        return None, (
            f"No hillshade: {shown} is not the DTM hd detect read (its sha256 {digest[:12]}... differs from "
            f"detect.json's {str(source.get('sha256'))[:12]}...)"
        )
    return path, ""


def _scan_heights(out: DetectOutput, base: Path) -> tuple[Any, str]:
    """The scan's noisy DEM (metres, NaN holes) that a scan detection mapped, or (None, why not; its
    paths relative to the page's folder ``base``)."""
    source = out.info["input"]
    dataset = Path(str(source.get("dataset", "")))
    shown = shown_path(dataset.absolute(), base)
    name = f"{input_name(source)} of {shown}"
    if not (dataset / MANIFEST_NAME).is_file():
        return None, f"No hillshade: the dataset {shown} of the scan is not there any more"
    try:
        if sha256_file(dataset / MANIFEST_NAME) != source.get("manifest_sha256"):
            return None, f"No hillshade: the dataset {shown} has changed since hd detect read {name}"
        entry = find_labeling(dataset, str(source.get("labels")))
        shard = next(s for s in entry.shards if Path(s.path).name == source.get("label_shard"))
        with open_label_shard(dataset, shard) as reader:
            rows = np.flatnonzero(reader.h5["scan_index"][:] == source.get("scan_index"))
            k = [abs(s - float(source.get("sigma_m", -1))) <= 1e-9 for s in reader.sigmas_m].index(True)
            dem = np.asarray(reader.h5["dem_noisy"][int(rows[0]), k], np.float64)
    except (HdError, StopIteration, ValueError, IndexError, KeyError, OSError) as exc:
        why = str(exc).replace(str(dataset.absolute()), shown)
        return None, f"No hillshade: {name} cannot be read ({why})"
    if dem.shape != (out.rows, out.cols):
        return None, f"No hillshade: the DEM of {name} is {dem.shape[0]} x {dem.shape[1]}, not the maps' grid"
    return dem, ""


# ----------------------------------------------------------------------------------- detect page
@dataclass(frozen=True)
class _Layer:
    key: str
    title: str
    image: tuple[str, int, int] | None  # data URI, width, height; None for an SVG layer
    visible: bool
    opacity: int  # percent
    legend: str  # HTML
    probe: str = ""  # the data-* attributes by which the page reads the layer's value under the pointer


def _cm(sigma_m: Any) -> str:
    return f"{float(sigma_m) * 100:.3g} cm ({float(sigma_m):g} m)" if _finite(sigma_m) else "--"


def _layers(
    out: DetectOutput, settings: ViewSettings, dtm: Path | None, base: Path
) -> tuple[list[_Layer], dict[str, Any]]:
    """The map layers (images reduced and coloured) and what the page says of them."""
    from hdnet.view_images import Reduction

    reduction = Reduction.of((out.rows, out.cols), settings.max_px)
    h, w = reduction.shape
    images, extent, note = _layer_images(out, reduction, dtm, base)
    layers = _map_layers(out, images, extent)
    if "hillshade" in images:
        layers.append(_Layer("hillshade", "Hillshade of the terrain", images["hillshade"], True, 100, "sun NW, 45°"))
    facts = {
        "reduction": reduction,
        "extent": extent,
        "hillshade_note": note,
        "image_px": (w, h),
    }
    return layers, facts


def _layer_images(
    out: DetectOutput, reduction: Reduction, dtm: Path | None, base: Path
) -> tuple[dict[str, tuple[str, int, int]], tuple[float, float, float, float], str]:
    """Step 1 of ``_layers``: each map reduced and coloured as a PNG data URI (with its width and height,
    pixels), the hillshade's among them when its terrain is found; the images' map extent (left, right,
    bottom, top, metres) and what the page says of the hillshade's source."""
    from hdnet.view_images import (
        PROBABILITY_CMAP,
        UNCERTAINTY_CMAP,
        UNCERTAINTY_MAX_NATS,
        colour_rgba,
        hillshade_rgba,
        png_bytes,
        reduced_array,
        reduced_map,
        safety_rgba,
        terrain_heights,
    )

    h, w = reduction.shape
    images: dict[str, tuple[str, int, int]] = {}

    def put(key: str, rgba: np.ndarray) -> None:
        images[key] = (data_uri(png_bytes(rgba)), int(rgba.shape[1]), int(rgba.shape[0]))

    maps = out.directory
    safety = reduced_map(maps / "safety.tif", reduction, categorical=True)
    put("safety", safety_rgba(safety))
    for key in ("p_safe", "baseline_p_safe"):
        put(key, colour_rgba(reduced_map(maps / f"{key}.tif", reduction), PROBABILITY_CMAP, 0.0, 1.0))
    for key in ("entropy", "mutual_information"):
        put(key, colour_rgba(reduced_map(maps / f"{key}.tif", reduction), UNCERTAINTY_CMAP, 0.0, UNCERTAINTY_MAX_NATS))

    # The hillshade: the terrain over the image's extent (whole blocks), at the image's size.
    a, _, c, _, e, f = out.transform
    cell = reduction.factor * a
    extent = (c, c + cell * w, f + reduction.factor * e * h, f)
    note = ""
    heights = None
    if out.info["input"].get("kind") == "scan":
        dem, note = _scan_heights(out, base)
        if dem is not None:
            heights = reduced_array(dem, reduction)
    else:
        path, note = _hillshade_source(out, dtm, base)
        if path is not None:
            heights = terrain_heights(path, extent, (h, w))
    if heights is not None:
        put("hillshade", hillshade_rgba(heights, cell))

    return images, extent, note


def _probe(order: int, name: str, cmap: str, high: float, unit: str = "") -> str:
    """The attributes by which the page reads a map's value under the pointer: its colour table
    (``cmap`` from 0 to ``high``), name and ``unit``."""
    from hdnet.view_images import colour_table

    table = " ".join(colour_table(cmap))
    return (
        f' data-probe="{esc(name)}" data-order="{order}" data-lut="{table}" data-min="0" data-max="{high!r}" '
        f'data-unit="{esc(unit)}"'
    )


def _map_style(out: DetectOutput, facts: dict[str, Any]) -> str:
    """The detect page's own style rules: the map's aspect ratio, the colour bars' gradients, the safety
    swatches' colours and where H_t stands on its bar (:func:`hdnet.view_html.map_style`)."""
    from hdnet.palette import SAFETY_HEX
    from hdnet.view_images import PROBABILITY_CMAP, UNCERTAINTY_CMAP, colour_stops

    left, right, bottom, top = facts["extent"]
    tick, _ = _score_tick(True, out.info["threshold"].get("value_nats"))
    return map_style(
        (right - left, top - bottom),
        {"probability": colour_stops(PROBABILITY_CMAP), "uncertainty": colour_stops(UNCERTAINTY_CMAP)},
        dict(zip(SWATCHES, SAFETY_HEX, strict=False)),
        tick,
    )


def _score_tick(thresholded: bool, h_t: float | None) -> tuple[float | None, str]:
    """Where H_t (nats) stands on an uncertainty bar (0 to ln 2) and its label, for the score the
    threshold applies to (``thresholded``); (None, "") otherwise or for an unbounded H_t."""
    from hdnet.view_images import UNCERTAINTY_MAX_NATS

    if thresholded and h_t is not None and _finite(h_t):
        return min(1.0, float(h_t) / UNCERTAINTY_MAX_NATS), f"H_t = {float(h_t):.3g} nats"
    return None, ""


def _sites_layer(out: DetectOutput, extent: tuple[float, float, float, float]) -> _Layer:
    """The layer of the landing sites: circles of the lander's footprint (drawn larger where the map's
    ``extent``, metres, would make them too small to see)."""
    lander_m = float(out.info["lander"]["diameter_m"])
    margin_m = float(out.info.get("site_rule", {}).get("margin_m") or 0.0)
    drawn_m = marker_radius(lander_m / 2, extent)
    return _Layer(
        "sites",
        f"Landing sites ({len(out.site_rows)})",
        None,
        True,
        100,
        f"Circles: the lander's footprint ({lander_m:g} m across"
        + (f", drawn {2 * drawn_m:.3g} m across to be seen at this scale" if drawn_m > lander_m / 2 else "")
        + "), numbered by rank"
        + (f"; dashed ring: the site margin, {margin_m:g} m around it, safe and certain too" if margin_m > 0 else "")
        + "; click one to find it in the table.",
    )


def _map_layers(
    out: DetectOutput, images: dict[str, tuple[str, int, int]], extent: tuple[float, float, float, float]
) -> list[_Layer]:
    """Step 2 of ``_layers``: the sites and the five maps as layers, with their legends and probes."""
    from hdnet.view_images import PROBABILITY_CMAP, UNCERTAINTY_CMAP, UNCERTAINTY_MAX_NATS, safety_classes

    th = out.info["threshold"]
    score = recorded_score(th)
    h_t = th.get("value_nats")

    classes = esc(json.dumps(safety_classes()))
    ln2 = f"{UNCERTAINTY_MAX_NATS:.3f} nats (ln 2)"

    def score_tick(name: str) -> tuple[float | None, str]:
        return _score_tick(score.name == name, h_t)

    swatches = "".join(
        f'<span class="swatch swatch-{name}"></span>{esc(word)}'
        for name, word in zip(SWATCHES, ("unsafe", "safe", f"uncertain ({score.name} ≥ H_t)"), strict=True)
    )
    sensor = out.info.get("sensor_sigma_m", out.info.get("baseline", {}).get("sigma_m"))
    return [
        _sites_layer(out, extent),
        _Layer(
            "safety",
            "Safety map (uncertainty-aware)",
            images["safety"],
            True,
            SAFETY_OPACITY,
            swatches + "; no colour: invalid (border band, nodata)",
            f' data-probe="safety" data-order="0" data-classes="{classes}"',
        ),
        _Layer(
            "p_safe",
            "P(safe), network (MC-dropout mean)",
            images["p_safe"],
            False,
            85,
            colour_bar("probability", "0", "1"),
            _probe(1, "P(safe)", PROBABILITY_CMAP, 1.0),
        ),
        _Layer(
            "entropy",
            "Predictive entropy",
            images["entropy"],
            False,
            85,
            colour_bar("uncertainty", "0", ln2, *score_tick("entropy")),
            _probe(2, "entropy", UNCERTAINTY_CMAP, UNCERTAINTY_MAX_NATS, " nats"),
        ),
        _Layer(
            "mutual_information",
            "Mutual information",
            images["mutual_information"],
            False,
            85,
            colour_bar("uncertainty", "0", ln2, *score_tick("mutual-information")),
            _probe(3, "MI", UNCERTAINTY_CMAP, UNCERTAINTY_MAX_NATS, " nats"),
        ),
        _Layer(
            "baseline_p_safe",
            "ALHAT baseline P(safe)",
            images["baseline_p_safe"],
            False,
            85,
            colour_bar("probability", "0", "1") + f"at sensor σ {esc(_cm(sensor))}; safe where ≥ 0.5",
            _probe(4, "baseline P(safe)", PROBABILITY_CMAP, 1.0),
        ),
    ]


def _round_length(span_m: float) -> float:
    """A round length (1, 2 or 5 times a power of ten, metres) near a fifth of ``span_m``."""
    target = max(span_m / 5.0, 1e-9)
    power = 10.0 ** math.floor(math.log10(target))
    return max(m * power for m in (1.0, 2.0, 5.0) if m * power <= target)


def marker_radius(radius_m: float, extent: tuple[float, float, float, float]) -> float:
    """The radius (metres) a site's circle is drawn with: the lander's, or 0.8 % of the map's longer
    side when that is larger (a 10 m lander on a 10 km map would be a pixel)."""
    left, right, bottom, top = extent
    return max(radius_m, 0.008 * max(right - left, top - bottom))


def _sites_svg(out: DetectOutput, extent: tuple[float, float, float, float]) -> str:
    """The sites layer and the scale bar: SVG in map metres (y up as -y), stretched over the map."""
    left, right, bottom, top = extent
    width, height = right - left, top - bottom
    span = max(width, height)
    drawn = marker_radius(float(out.info["lander"]["diameter_m"]) / 2.0, extent)
    margin = float(out.info.get("site_rule", {}).get("margin_m") or 0.0)
    font = 0.018 * span
    view_box = f'viewBox="{left:.6f} {-top:.6f} {width:.6f} {height:.6f}" preserveAspectRatio="none"'
    markers = []
    for row in out.site_rows:
        rank, x, y = row[0], float(row[1]), float(row[2])
        tip = ", ".join(f"{SITE_HEADERS[k]} {v}" for k, v in zip(SITE_COLUMNS[1:], site_cells(row)[1:], strict=True))
        circles = "".join(
            f'<circle class="{cls}" cx="{x:.3f}" cy="{-y:.3f}" r="{drawn:.3f}" vector-effect="non-scaling-stroke"/>'
            for cls in ("halo", "ring")
        )
        if margin > 0.0:  # the ground --site-margin kept safe and certain around the lander's disk
            circles += (
                f'<circle class="margin" cx="{x:.3f}" cy="{-y:.3f}" r="{drawn + margin:.3f}" '
                'vector-effect="non-scaling-stroke"/>'
            )
        label = f'<text x="{x + 1.1 * drawn:.3f}" y="{-y - 1.1 * drawn:.3f}" font-size="{font:.3f}">{esc(rank)}</text>'
        markers.append(
            f'<g class="site-marker" data-rank="{esc(rank)}"><title>site {esc(rank)}: {esc(tip)}</title>'
            f"{circles}{label}</g>"
        )
    # The scale bar: a rule and its length, italic on a pale box in the map's lower left corner (not
    # the bold white-haloed callout of a site's number).
    length, thick, pad = _round_length(width), 0.006 * span, 0.01 * span
    x0, base = left + 0.03 * width, -(bottom + 0.03 * height)  # the rule's left end and lower edge (SVG y)
    box_h = thick + 1.2 * font + 2 * pad
    bar = (
        f'<g class="scale-bar"><rect class="box" x="{x0 - pad:.3f}" y="{base + pad - box_h:.3f}" '
        f'width="{length + 2 * pad:.3f}" height="{box_h:.3f}" rx="{0.3 * pad:.3f}" vector-effect="non-scaling-stroke"/>'
        f'<rect class="rule" x="{x0:.3f}" y="{base - thick:.3f}" width="{length:.3f}" height="{thick:.3f}"/>'
        f'<text x="{x0 + length / 2:.3f}" y="{base - thick - 0.3 * font:.3f}" font-size="{font:.3f}" '
        f'text-anchor="middle">{length:g} m</text></g>'
    )
    svg = 'xmlns="http://www.w3.org/2000/svg"'
    return (
        f'<svg id="layer-sites" class="layer" {svg} {view_box} aria-label="landing sites">{"".join(markers)}</svg>\n'
        f'<svg id="scale-bar" class="layer" {svg} {view_box} aria-label="scale bar">{bar}</svg>'
    )


def _map_section(out: DetectOutput, layers: list[_Layer], facts: dict[str, Any]) -> str:
    reduction = facts["reduction"]
    left, right, bottom, top = facts["extent"]
    w_px, h_px = facts["image_px"]
    a, e = out.transform[0], -out.transform[4]
    controls = []
    for layer in layers:
        ident = f"layer-{layer.key}"
        controls.append(
            '<div class="layer-control">'
            f'<label><input type="checkbox" class="layer-toggle" id="toggle-{layer.key}" data-layer="{ident}"'
            f"{' checked' if layer.visible else ''}> {esc(layer.title)}</label>"
            f'<input type="range" class="layer-opacity" id="opacity-{layer.key}" data-layer="{ident}" min="0" '
            f'max="100" value="{layer.opacity}" aria-label="opacity of {esc(layer.title)}">'
            f'<div class="legend">{layer.legend}</div></div>'
        )
    stack = []
    for key in ("hillshade", "baseline_p_safe", "p_safe", "entropy", "mutual_information", "safety"):
        shown = next((x for x in layers if x.key == key), None)
        if shown is not None and shown.image is not None:
            uri, w, h = shown.image
            stack.append(
                f'<img id="layer-{key}" class="layer" src="{uri}" width="{w}" height="{h}" alt="{esc(shown.title)}"'
                f"{shown.probe}>"
            )
    stack.append(_sites_svg(out, facts["extent"]))
    if reduction.reduced:
        f = reduction.factor
        resolution = (
            f"The map has {out.rows} x {out.cols} cells of {a:g} m; it is shown reduced to {h_px} x {w_px} pixels, one "
            f"pixel per {f} x {f} cells ({f * a:g} m): P(safe), the uncertainty scores and the baseline as the mean of "
            "each block's valid cells, the safety map as each block's worst class (unsafe over uncertain over safe), "
            "so that a pixel shown safe is safe in every cell. The GeoTIFFs beside detect.json hold every cell."
        )
    else:
        resolution = f"The map has {out.rows} x {out.cols} cells of {a:g} m x {e:g} m, one pixel per cell."
    notes = [f'<p class="note" id="resolution">{esc(resolution)}</p>']
    if facts["hillshade_note"]:
        notes.append(f'<p class="note" id="hillshade-note">{esc(facts["hillshade_note"])}</p>')
    zoom = "".join(
        f'<button type="button" class="zoom" data-zoom="{z}" title="{title}">{label}</button>'
        for z, label, title in (
            ("1", "fit", "the whole map in its panel"),
            ("2", "2x", "twice the fit"),
            ("4", "4x", "4 times the fit"),
            ("8", "8x", "8 times the fit"),
            ("pixels", "1:1", "one image pixel per screen pixel"),
        )
    )
    width_m, height_m = right - left, top - bottom
    m_left, m_right, m_bottom, m_top = out.extent  # the map's own (the image's whole blocks may reach past it)
    return (
        '<section id="map-section"><h2>Map</h2>\n'
        + "\n".join(notes)
        + '\n<div class="layout"><div class="controls"><fieldset><legend>Layers</legend>'
        + "".join(controls)
        + f'</fieldset><div>Zoom: {zoom}</div><p class="note" id="extent">x {_m(m_left)} to {_m(m_right)} m, '
        + f"y {_m(m_bottom)} to {_m(m_top)} m"
        + f" ({esc(_crs_name(out.info['grid'].get('crs_wkt', ''), out))})</p>"
        + '<div id="readout" aria-live="polite"></div>'
        + '<p class="note">Under the pointer: its map coordinates, its class and the maps\' values, read back '
        + f"from their colours (to 1/256 of each colour bar{'; block means' if reduction.reduced else ''}). "
        + "The wheel zooms about the pointer; drag to pan.</p>"
        + "</div>\n"
        + '<div class="map-scroll"><div id="map" class="map" '
        + f'data-left="{left!r}" data-top="{top!r}" data-width="{width_m!r}" data-height="{height_m!r}" '
        + f'data-px="{w_px}" data-px-height="{h_px}">\n'
        + "\n".join(stack)
        + "\n</div></div></div></section>"
    )


def _m(value: float) -> str:
    """Map metres as plain digits to the millimetre, trailing zeros dropped (``1992000``, ``1000.5``)."""
    return f"{value:.3f}".rstrip("0").rstrip(".")


def _crs_name(wkt: str, out: DetectOutput) -> str:
    """The CRS's name from its WKT (``PROJCS["Mars2000 Equirectangular"...``), or what the frame is."""
    if not wkt:
        if out.info["input"].get("kind") == "scan":
            return "scan frame: origin at the scan's nadir point, x east, y north"
        return "no CRS: local metres"
    match = re.match(r'\s*\w+\["([^"]*)"', wkt)
    return f"CRS {match.group(1)}" if match else "CRS (WKT in detect.json)"


def ranked_column(rule: Mapping[str, Any]) -> str:
    """The column of sites.csv a detection ranked its sites by: ``touchdown_p_safe`` under a navigation
    dispersion (``nav_sigma_m`` > 0), else ``p_safe`` (the aim point's footprint)."""
    return "touchdown_p_safe" if float(rule.get("nav_sigma_m") or 0.0) > 0.0 else "p_safe"


def site_cells(row: Sequence[str]) -> list[str]:
    """A sites.csv row as the page shows it: the rank as it is, every number to ``SITE_DECIMALS`` decimals."""
    cells = [row[0]]
    for value in row[1:]:
        try:
            cells.append(f"{float(value):.{SITE_DECIMALS}f}")
        except ValueError:
            cells.append(value)
    return cells


def site_headers(rule: Mapping[str, Any]) -> list[str]:
    """The site table's headings (``SITE_HEADERS``), the ranking column's marked ``RANKED_MARK``."""
    ranked = ranked_column(rule)
    return [SITE_HEADERS[c] + (RANKED_MARK if c == ranked else "") for c in SITE_COLUMNS]


def _sites_section(out: DetectOutput) -> str:
    rule = out.info.get("site_rule", {})
    rank_by = rule.get("rank_by", "")
    ranked = SITE_HEADERS[ranked_column(rule)]
    if not out.site_rows:
        body = '<p id="no-sites">No site: no lander footprint is wholly safe and certain.</p>'
    else:
        body = table(
            site_headers(rule),
            [site_cells(r) for r in out.site_rows],
            table_id="sites",
            row_attrs=[{"class": "site-row", "data-rank": r[0]} for r in out.site_rows],
            header_titles=[SITE_TITLES.get(c, "") for c in SITE_COLUMNS],
        )
    return (
        '<section id="sites-section"><h2>Landing sites</h2>\n'
        f'<p class="note" id="ranking">Ranked by {esc(ranked)} (marked ▼): {esc(rank_by)}. A site below another '
        "may have a higher value in the other columns.</p>\n"
        f'<p class="note">From sites.csv ({len(out.site_rows)} site(s); its numbers to {SITE_DECIMALS} decimals '
        "here). Hover a heading for its meaning.</p>\n"
        f"{body}</section>"
    )


def _counts_section(out: DetectOutput) -> str:
    counts = out.info["counts"]
    valid = sum(int(counts.get(k, 0)) for k in ("safe", "unsafe", "uncertain"))
    rows = []
    for key, word in (
        ("safe", "safe (certain)"),
        ("unsafe", "unsafe (certain)"),
        ("uncertain", "uncertain (discarded)"),
        ("invalid", "invalid (no label: border band, nodata)"),
        ("baseline_safe", "ALHAT baseline safe (P(safe) ≥ 0.5)"),
    ):
        n = counts.get(key)
        share = f"{100.0 * int(n) / valid:.1f} %" if isinstance(n, int) and valid and key != "invalid" else "--"
        rows.append([word, str(n), share])
    return (
        '<section id="counts-section"><h2>Cells</h2>\n'
        + table(["class", "cells", "of the valid cells"], rows, table_id="counts")
        + "</section>"
    )


def _settings_items(out: DetectOutput, base: Path) -> list[tuple[str, str]]:
    """The detection's settings as (name, value) words; paths relative to the page's folder ``base``."""
    info = out.info
    run, src, th, lander = info["run"], info["input"], info["threshold"], info["lander"]
    grid, rule = info["grid"], info.get("site_rule", {})
    range_m, levels = recorded_noise(run.get("train_noise"))
    if range_m:
        trained = f"{range_m[0] * 100:.3g} to {range_m[1] * 100:.3g} cm (drawn per sample)"
    elif levels:
        trained = ", ".join(f"{s * 100:.3g}" for s in levels) + " cm"
    else:
        trained = _cm(run.get("train_sigma_m"))
    items = [
        ("run", f"{readable(run.get('checkpoint'), base)} (epoch {run.get('epoch')}, profile {run.get('profile')})"),
        ("trained at", f"{trained}; reference {_cm(run.get('train_sigma_m'))}"),
        ("training dataset", readable(run.get("dataset"), base)),
        ("labelling", str(run.get("labels"))),
    ]
    if src.get("kind") == "scan":
        seen = " (a training scan: the network has seen it)" if src.get("seen_in_training") else ""
        items += [
            ("input", f"{input_name(src)} of {readable(src.get('dataset'), base)}"),
            ("split", f"{src.get('split')}{seen}"),
            ("scan's noise level", _cm(src.get("sigma_m"))),
            ("scan's labelling", str(src.get("labels"))),
            ("scan frame origin (map)", readable(src.get("origin_map"), base) + " m"),
        ]
    else:
        scale = "upsampled bilinearly" if src.get("upsampled") else f"scale {src.get('scale')}"
        items += [
            ("input", f"DTM {readable(src.get('path'), base)}"),
            ("DTM sha256", str(src.get("sha256"))),
            (
                "DTM cells",
                f"{_shape(src.get('source_shape'))} of {_shape(src.get('source_spacing_m'))} m, read at {scale}",
            ),
        ]
    h_t = th.get("value_nats")
    value = f"{float(h_t):.4f} nats" if _finite(h_t) else "unbounded (every cell certain)"
    calibration = (
        f"{th.get('calibration_split')} split at {_cm(th.get('calibration_sigma_m'))}, "
        f"{th.get('calibration_images')} images of "
        f"{readable(th.get('calibration_datasets') or th.get('calibration_dataset'), base)}"
        if th.get("kind") != "fixed"
        else "fixed"
    )
    items += [
        ("sensor sigma (baseline, network input)", _cm(info.get("sensor_sigma_m"))),
        ("threshold", f"{th.get('spec')}{recorded_score(th).qualifier}: H_t = {value}"),
        ("uncertainty score", recorded_score(th).name),
        ("calibration", calibration + (f"; calibrate {th['calibrate']}" if th.get("calibrate") else "")),
        ("navigation sigma", f"{float(rule.get('nav_sigma_m') or 0.0):g} m (1σ per horizontal axis)"),
        ("sites ranked by", str(rule.get("rank_by", "--"))),
        ("site margin", _margin_words(rule)),
        ("MC samples, seed", f"{info.get('mc_samples')}, {info.get('seed')}"),
        (
            "lander",
            _lander_words(lander),
        ),
        (
            "grid",
            f"{out.rows} x {out.cols} cells of {_shape(grid.get('spacing_m'))} m; {_crs_name(grid['crs_wkt'], out)}",
        ),
        ("tiling", readable(info.get("tiling"), base)),
        ("hd version", str(info.get("software_version"))),
        ("time taken", f"{readable((info.get('timings_s') or {}).get('total'), base)} s"),
    ]
    return items


def _lander_words(lander: Mapping[str, Any]) -> str:
    """The lander's size and limits as the settings table says them (numbers rounded)."""
    n = {k: number(float(lander.get(k, math.nan))) for k in ("diameter_m", "pad_diameter_m", "max_slope_deg")}
    return (
        f"{n['diameter_m']} m across, pads {n['pad_diameter_m']} m, slope ≤ {n['max_slope_deg']}°, roughness ≤ "
        f"{number(float(lander.get('max_roughness_m', math.nan)))} m, convention {lander.get('convention')}"
    )


def _margin_words(rule: Mapping[str, Any]) -> str:
    """The sites' safety margin (``--site-margin``, metres) as the settings table says it."""
    margin = float(rule.get("margin_m") or 0.0)
    if margin <= 0.0:
        return "0 m (the lander's disk alone must be safe and certain)"
    return f"{margin:g} m: the lander's disk widened by {margin:g} m all round must be safe and certain (dashed ring)"


def _shape(pair: Any) -> str:
    """``[a, b]`` as ``a x b`` (a shape or a cell size), anything else as it is."""
    if isinstance(pair, list) and len(pair) == 2:
        return f"{pair[0]:g} x {pair[1]:g}" if all(_finite(v) for v in pair) else f"{pair[0]} x {pair[1]}"
    return str(pair)


def _warnings(out: DetectOutput) -> list[str]:
    src, th = out.info["input"], out.info["threshold"]
    said = []
    if src.get("seen_in_training"):
        said.append(
            f"Scan {src.get('scan_index')} is in the training split of the run's dataset: the network has seen it, so "
            "these maps are not those of unseen terrain."
        )
    if th.get("unreachable"):
        said.append(
            f"The threshold {th.get('spec')} is unreachable with {th.get('calibration_images')} validation images (it "
            f"needs {th.get('needs_images')}): every cell is uncertain by construction."
        )
    h_t = th.get("value_nats")
    chance = threshold_warning(float(h_t) if _finite(h_t) else None, len(out.site_rows))
    if chance is not None:
        said.append(chance.removeprefix("Warning: "))
    return said


def detect_page(
    out: DetectOutput, settings: ViewSettings, dtm: Path | None = None, base: Path | None = None
) -> tuple[str, dict[str, Any]]:
    """The page of a detect output and what it shows (for the summary and ``hd --json``); ``base``: the
    folder the page goes into (default the output's), to which the paths it shows are relative.

    Raises:
        DamagedFileError / StorageError: a missing or damaged map (``hdnet.view_images.reduced_map``).
        HdNetError: a ``detect.json`` whose values are not of the kinds ``hd detect`` writes.
    """
    try:
        where = base if base is not None else out.directory
        layers, facts = _layers(out, settings, dtm, where)
        return _detect_text(out, layers, facts, where)
    except HdError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:  # a value of another kind
        raise _schema_error(out.directory / DETECT_MARKER, f"{type(exc).__name__}: {exc}") from exc


def _detect_text(
    out: DetectOutput, layers: list[_Layer], facts: dict[str, Any], base: Path
) -> tuple[str, dict[str, Any]]:
    src = out.info["input"]
    name = input_name(src) if src.get("kind") == "dtm" else f"{input_name(src)} ({src.get('split')} split)"
    counts = out.info["counts"]
    valid = sum(int(counts.get(k, 0)) for k in ("safe", "unsafe", "uncertain"))
    pct = {k: (100.0 * int(counts.get(k, 0)) / valid if valid else 0.0) for k in ("safe", "unsafe", "uncertain")}
    th = out.info["threshold"]
    h_t = th.get("value_nats")
    lead = (
        f"{pct['safe']:.1f} % safe, {pct['unsafe']:.1f} % unsafe, {pct['uncertain']:.1f} % uncertain of {valid} valid "
        f"cells; H_t {f'{float(h_t):.4f} nats' if _finite(h_t) else 'unbounded'} ({th.get('spec')}"
        f"{recorded_score(th).qualifier}); {len(out.site_rows)} landing site(s)."
    )
    raw = json.dumps(without_paths(out.info, base), indent=1)
    body = [
        f"<header><h1>hd detect: {esc(name)}</h1>",
        f'<p class="sub">{esc(_folder_words(out.directory, base))}</p>',
        f'<p id="lead">{esc(lead)}</p></header>',
        *(f'<p class="warning">{esc(w)}</p>' for w in _warnings(out)),
        (
            '<nav class="toc"><a href="#map-section">Map</a><a href="#sites-section">Landing sites</a>'
            '<a href="#counts-section">Cells</a><a href="#settings-section">Settings</a></nav>'
        ),
        _map_section(out, layers, facts),
        _sites_section(out),
        _counts_section(out),
        '<section id="settings-section"><h2>Settings</h2>',
        definitions(_settings_items(out, base), table_id="settings"),
        f"<details><summary>detect.json</summary><pre>{esc(raw)}</pre></details></section>",
        _footer(out.directory, DETECT_MARKER, base),
    ]
    reduction = facts["reduction"]
    shown = {
        "what": f"hd detect output of {name}, {out.rows} x {out.cols} cells"
        + (f" shown at 1 pixel per {reduction.factor} x {reduction.factor}" if reduction.reduced else "")
        + f", {len(layers)} layers, {len(out.site_rows)} site(s)",
        "layers": [layer.key for layer in layers],
        "image_px": list(facts["image_px"]),
        "cells_per_pixel": reduction.factor,
        "sites": len(out.site_rows),
        "hillshade": "hillshade" in [layer.key for layer in layers],
        "note": facts["hillshade_note"],
    }
    return page(f"hd detect: {name}", "\n".join(body), lead, _map_style(out, facts)), shown


def _folder_words(directory: Path, base: Path) -> str:
    """Where the output is, said relative to the page's folder ``base`` (no machine path)."""
    rel = shown_path(directory.resolve(), base)
    return "the folder of this page" if rel == "." else f"{rel} (relative to this page)"


def _footer(directory: Path, marker: str, base: Path) -> str:
    digest = sha256_file(directory / marker)
    return (
        f'<footer><p class="note">Made by hd view {esc(__version__)} from '
        f"{esc(shown_path((directory / marker).resolve(), base))} "
        f"(sha256 {digest}). Nothing on this page is fetched from a network.</p></footer>"
    )


# ------------------------------------------------------------------------------------------- reports
_FIGURE_LINE = re.compile(r"^!\[[^\]]*\]\(([^)\s/\\]+)\)\s*$")


def _result_of(file: Path, content: ReportJson) -> EvaluationResult:
    """An ``EvaluationResult`` of a report's own numbers (its ``report.json``), for ``report_markdown``."""
    landing_fields = [f.name for f in fields(LandingRow)]
    landing = []
    for i, row in enumerate(content.get("landing") or []):
        if not isinstance(row, dict) or set(row) != set(landing_fields):
            raise HdNetError(f"{file}: landing row {i} is not of this hd's report schema; re-run hd eval")
        values: dict[str, Any] = {
            k: (math.nan if v is None and k not in ("method", "truth") else v) for k, v in row.items()
        }
        landing.append(LandingRow(**values))
    for key, kind in (("sweep", list), ("calibration", dict)):
        if not isinstance(content.get(key), kind):
            raise HdNetError(
                f"{file}: no {key!r} {kind.__name__}; not an hd eval report of this schema: re-run hd eval"
            )
    return EvaluationResult(
        rows=[ReportRow.from_json(r) for r in content["rows"]],
        threshold=content["threshold"],
        sweep=content["sweep"],
        calibration=content["calibration"],
        run=content["run"],
        landing=landing,
        landing_settings=_landing_record(file, content.get("landing_settings")),
    )


def _landing_record(file: Path, record: object) -> LandingRecord | None:
    """The ``landing_settings`` of a report (None when it has none)."""
    if not record:
        return None
    try:
        if not isinstance(record, dict):
            raise TypeError("not a JSON object")
        return LandingRecord.from_dict(record)
    except (KeyError, TypeError, ValueError) as exc:
        raise HdNetError(
            f"{file}: its landing_settings are not of this hd's report schema ({exc}); re-run hd eval"
        ) from exc


def _figure_names(directory: Path) -> list[str]:
    """The figures ``report.md`` shows (``![name](file.png)`` lines, file names inside the report)."""
    text = read_regular_text(directory / "report.md")
    return [m.group(1) for line in text.splitlines() if (m := _FIGURE_LINE.match(line.strip()))]


def report_page(directory: Path, base: Path | None = None) -> tuple[str, dict[str, Any]]:
    """The page of the report in ``directory`` and what it shows; ``base``: the folder the page goes
    into (default the report's), to which the paths it shows are relative."""
    from hdnet.view_images import check_png

    directory, content = read_report(directory)
    file = directory / REPORT_MARKER
    where = base if base is not None else directory
    # The page's numbers are report.json's; the paths it records, relative to the page's folder.
    result = _result_of(file, cast("ReportJson", without_paths(content, where)))
    names = _figure_names(directory)
    images: dict[str, tuple[str, int, int]] = {}
    for name in names:
        path = directory / name
        if not path.exists():
            raise DamagedFileError(
                f"{path}: missing, and report.md shows it; the report is incomplete: run hd eval again"
            )
        data = read_regular_bytes(path, max_bytes=FIGURE_MAX_BYTES)
        w, h = check_png(data, path)
        images[name] = (data_uri(data), w, h)
    try:
        markdown = report_markdown(result, names)
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise HdNetError(
            f"{file}: not an hd eval report of this schema ({type(exc).__name__}: {exc}); re-run hd eval to write it"
        ) from exc
    # The page's own heading replaces report.md's title line.
    body_html, headings = markdown_html(markdown.removeprefix("# hd evaluation report\n"), images)
    settings_rows = [(name, readable(json_plain(value), where)) for name, value in report_settings(content).items()]
    toc = "".join(f'<a href="#{anchor(h)}">{esc(h)}</a>' for h in [*headings, "Settings"])
    title = f"hd eval report: {directory.resolve().name}"
    body = [
        f"<header><h1>{esc(title)}</h1>",
        f'<p class="sub">{esc(_folder_words(directory, where))}</p></header>',
        f'<nav class="toc">{toc}</nav>',
        f'<article id="report">{body_html}</article>',
        f'<section id="settings-section"><h2 id="{anchor("Settings")}">Settings</h2>',
        (
            '<p class="note">Every setting report.json records (its run, threshold and landing settings), by the '
            "dotted names hd compare uses.</p>"
        ),
        definitions(settings_rows, table_id="settings"),
        "</section>",
        _footer(directory, REPORT_MARKER, where),
    ]
    shown = {
        "what": f"hd eval report, {len(content['rows'])} table rows, {len(images)} figure(s)",
        "figures": names,
        "sections": headings,
    }
    return page(title, "\n".join(body), title), shown


# ------------------------------------------------------------------------------------------- writing
def check_out(out: Path) -> Path:
    """Check that the page can be written at ``out``: its directory exists and is writable, and ``out``
    is missing or an earlier page of ``hd view``; returns its absolute path.

    Raises:
        StorageError: an unusable place (see ``hdcore.storage.check_output_file``).
        OutputExistsError: ``out`` is anything else (an input, a user's file, a FIFO).
    """
    path = check_output_file(out, "--out")
    if os.path.lexists(path):
        head = b""
        try:
            check_regular_file(path)  # never opens a FIFO or a device
            with open(path, "rb") as fh:
                head = fh.read(HEAD_BYTES)
        except (HdError, OSError):
            pass
        if not is_page(head):
            raise OutputExistsError(
                f"--out {path} exists and is not a page of hd view; hd view replaces only its own pages: choose "
                "another --out or remove the file"
            )
    return path


def default_page(directory: Path) -> Path:
    """The page ``hd view DIRECTORY`` writes without ``--out``: ``DIRECTORY-view.html`` beside the
    directory (``site-7/`` -> ``site-7-view.html``), so that a finished output keeps the files its
    command wrote and recorded, and the page, self-contained, can be shared on its own.

    Raises:
        HdNetError: a directory without a name (the file system's root): give ``--out``.
    """
    full = Path(os.path.abspath(directory))
    if not full.name:
        raise HdNetError(f"{directory} has no name to put the page beside it; give --out FILE")
    return full.parent / f"{full.name}{VIEW_SUFFIX}"


@contextmanager
def _reading(directory: Path, out: Path) -> Iterator[None]:
    """While the page is made: the directory's writer lock when the page goes into it, else a check
    that no hd process writes the directory."""
    if out.parent.resolve() == directory.resolve():
        with WriterLock(directory, "view"):
            yield
        return
    holder = lock_holder(directory)
    if holder is not None:
        raise LockedError(
            f"{directory} is being written by another hd process (PID {holder}); wait for it to finish, then run "
            "hd view again"
        )
    yield


def view(
    directory: str | os.PathLike,
    out: str | os.PathLike | None = None,
    settings: ViewSettings | None = None,
    dtm: str | os.PathLike | None = None,
) -> ViewResult:
    """Write the page of the detect output, descend output or report ``directory`` to ``out`` (default
    :func:`default_page`: ``DIRECTORY-view.html`` beside the directory, which is left as it is).

    ``dtm``: the DTM a detection read, when it is no longer at the path ``detect.json`` records
    (used only when its sha256 is the recorded one).

    Raises:
        HdNetError: ``directory`` is neither kind (see :func:`source_of`), or of another schema.
        StorageError / DamagedFileError: a missing, unreadable or damaged file of it; an unusable
            ``out``. OutputExistsError: ``out`` exists and is not a page of ``hd view``. LockedError:
            another hd process writes ``directory``. Nothing is written then.
    """
    cfg = settings if settings is not None else ViewSettings()
    source, kind = source_of(directory)
    target = check_out(Path(out) if out is not None else default_page(source))
    if dtm is not None and kind != "detect":
        what = "an hd descend output (its hillshades are its mosaics')" if kind == "descend" else "an hd eval report"
        raise HdNetError(f"--dtm goes with an hd detect output; {source} is {what}")
    with _reading(source, target):
        if kind == "detect":
            text, shown = detect_page(read_detect(source), cfg, Path(dtm) if dtm is not None else None, target.parent)
        elif kind == "descend":
            from hdnet.view_descent import descend_page, read_descend

            text, shown = descend_page(read_descend(source), cfg.max_px)
        else:
            text, shown = report_page(source, target.parent)
        check_out(target)  # once more, now that the page is made
        write_text_atomic(target, text)
    return ViewResult(target, kind, source, len(text.encode("utf-8")), shown)


def view_job(directory: Path, out: Path | None, settings: ViewSettings, dtm: Path | None = None) -> Done:
    """``hd view``: write the page and say where it is (``hd --json``: the page, its kind and what it shows)."""
    result = view(directory, out, settings, dtm)
    lines = [result.summary()]
    if result.info.get("note"):
        lines.append(str(result.info["note"]))
    record = {
        "command": "view",
        "kind": result.kind,
        "directory": str(result.source.resolve()),
        "out": str(result.path),
        "bytes": result.n_bytes,
        **{k: v for k, v in result.info.items() if k != "what"},
    }
    return Done(lines, json_plain(record))
