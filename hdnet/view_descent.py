"""``hd view DIR`` of an ``hd descend`` output: one self-contained page of its descents, frame by frame.

Per descent, one section: a frame stepper (a slider, step buttons, a click on a frame's row) that
shows one frame at a time; each frame's map is the mosaic so far (its hillshade, from the frame's
``heights_m``: the mosaic growing frame by frame) with the safety map, P(safe) and the predictive
entropy as layers that can be switched on and off and made more or less opaque, as the detect page
has them (the same colours, ``hdnet.view_images``, ``hdnet.figures``' safety colours), and the site
track drawn over them: the aim after every frame so far as a line of points, the current aim as a
ring of the lander's size, the frame's ranked sites as dashed rings, and each divert so far as an
arrow from the old aim to the new one labelled with its frame and distance. Under the map, the
table of frames (altitude, seconds per step, aim, sites, divert, why a frame has no map); then H_t
and the settings. A frame without a map (its mosaic had no lander-sized square of valid cells) shows
its hillshade and says why.

The images are reduced as the detect page reduces its maps, to at most :data:`DESCENT_MAX_PX` pixels a
side (less with ``--max-px``): a page holds a descent's frames times four images. Every file is
checked as it is read (``descend.json``, each track, each frame's ``.npz``): a damaged one is one error
naming it, and nothing is written. The page shows no absolute path: files and directories by name.
``hdnet.view`` recognises the output by its ``descend.json`` and writes the page.
"""

from __future__ import annotations

import io
import json
import math
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeGuard, cast

import numpy as np

from hdcore.errors import DamagedFileError, HdError
from hdcore.storage import check_regular_file, read_json, read_regular_bytes, sha256_file
from hdnet._version import __version__
from hdnet.descend_json import RECORD_NAME, DescendJson, DescentJson, FrameJson, TrackGeoJson, track_file
from hdnet.errors import HdNetError
from hdnet.results import SITE_COLUMNS
from hdnet.uncertainty import ENTROPY, recorded_score
from hdnet.view_html import (
    DESCENT_SCRIPT,
    DESCENT_STYLE,
    colour_bar,
    data_uri,
    definitions,
    esc,
    map_style,
    page,
    table,
)

DESCENT_MAX_PX = 512  # hd choice: a frame image's longest side, pixels (a page holds frames x 4 images)
NPZ_MAX_BYTES = 1 << 30  # hd choice: the largest frame file read (a 2000 x 2000 mosaic's is ~60 MB)
MAP_KEYS = ("p_safe", "entropy_nats", "safety")  # the maps of a frame the page shows
SWATCHES = ("unsafe", "safe", "uncertain")  # the safety legend's swatches, in SAFETY_HEX's order
Extent = tuple[float, float, float, float]  # left, right, bottom, top: metres


@dataclass(frozen=True)
class DescendOutput:
    """A checked ``hd descend`` output: its ``descend.json``, each descent's track and the mosaic's grid
    (rows, cols, metres per cell)."""

    directory: Path
    info: DescendJson
    tracks: dict[int, TrackGeoJson]
    rows: int
    cols: int
    spacing_m: float


def _schema_error(file: Path, what: str) -> HdNetError:
    return HdNetError(f"{file}: not an hd descend output of this schema ({what}); run hd descend again to write it")


def _finite(value: object) -> TypeGuard[float]:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _whole(value: object) -> TypeGuard[int]:
    return isinstance(value, int) and not isinstance(value, bool)


def read_descend(directory: Path) -> DescendOutput:
    """The ``hd descend`` output in ``directory``: its ``descend.json`` checked against its record
    (``hdnet.descend_json``) and each descent's track against its frames.

    Raises:
        StorageError / DamagedFileError: an unreadable or damaged ``descend.json`` or track, or a track
            that disagrees with ``descend.json``.
        HdNetError: a ``descend.json`` of another schema.
    """
    file = directory / RECORD_NAME
    info = read_json(file, RECORD_NAME)
    if not isinstance(info, dict):
        raise _schema_error(file, f"a JSON {type(info).__name__}, not an object")
    for key in ("run", "input", "settings", "threshold"):
        if not isinstance(info.get(key), dict):
            raise _schema_error(file, f"no {key!r} object")
    dem = info["input"].get("dem")
    if not (isinstance(dem, dict) and _whole(dem.get("rows")) and _whole(dem.get("cols"))):
        raise _schema_error(file, f"the mosaic grid {dem!r}")
    if not (dem["rows"] > 0 and dem["cols"] > 0 and _finite(dem.get("spacing_m")) and dem["spacing_m"] > 0):
        raise _schema_error(file, f"the mosaic grid {dem!r}")
    descents = info.get("descents")
    if not (isinstance(descents, list) and descents):
        raise _schema_error(file, "no 'descents' list")
    for descent in descents:
        _check_descent(file, descent)
    checked = cast("DescendJson", info)  # the keys read without a default checked above
    tracks = {d["descent"]: _read_track(directory, d) for d in checked["descents"]}
    return DescendOutput(directory, checked, tracks, dem["rows"], dem["cols"], float(dem["spacing_m"]))


def _check_descent(file: Path, descent: object) -> None:
    """One entry of ``descents``: its index, and its frames in order, each with its altitude, seconds,
    aim (x, y) or none and divert (old and new x, y) or none.

    Raises:
        HdNetError: an entry of another schema.
    """
    if not (isinstance(descent, dict) and _whole(descent.get("descent")) and isinstance(descent.get("frames"), list)):
        raise _schema_error(file, "a descent without its index or frames")
    frames = descent["frames"]
    where = f"descent {descent['descent']}"
    if not frames or [f.get("frame") if isinstance(f, dict) else None for f in frames] != list(range(len(frames))):
        raise _schema_error(file, f"{where}: its frames are not numbered 0, 1, ...")
    for f in frames:
        aim, divert = f.get("aim"), f.get("divert")
        if not (_finite(f.get("altitude_m")) and isinstance(f.get("timings_s"), dict)):
            raise _schema_error(file, f"{where}, frame {f['frame']}: no altitude or seconds")
        if aim is not None and not (isinstance(aim, dict) and _finite(aim.get("x")) and _finite(aim.get("y"))):
            raise _schema_error(file, f"{where}, frame {f['frame']}: an aim {aim!r}")
        if divert is not None and not (
            isinstance(divert, dict)
            and all(isinstance(divert.get(k), list) and len(divert[k]) == 2 for k in ("old", "new"))
            and all(_finite(v) for v in [*divert["old"], *divert["new"], divert.get("distance_m")])
        ):
            raise _schema_error(file, f"{where}, frame {f['frame']}: a divert {divert!r}")


def _read_track(directory: Path, descent: DescentJson) -> TrackGeoJson:
    """A descent's ``descent-KKKKK-track.geojson``: a Point per frame with an aim, at that aim.

    Raises:
        StorageError / DamagedFileError: unreadable, or not the track of ``descend.json``'s aims.
    """
    path = directory / track_file(descent["descent"])
    track = read_json(path, "site track")
    features = track.get("features") if isinstance(track, dict) else None
    if not isinstance(features, list):
        raise DamagedFileError(f"{path}: not a GeoJSON FeatureCollection; run hd descend again")
    points = [
        (f["properties"].get("frame"), f["geometry"].get("coordinates"))
        for f in features
        if isinstance(f, dict) and isinstance(f.get("geometry"), dict) and f["geometry"].get("type") == "Point"
        if isinstance(f.get("properties"), dict)
    ]
    aims = [(f["frame"], aim) for f in descent["frames"] if (aim := f.get("aim")) is not None]
    same = len(points) == len(aims) and all(
        frame == k and isinstance(xy, list) and len(xy) == 2 and all(_finite(v) for v in xy)
        and abs(xy[0] - float(aim["x"])) <= 1e-3 and abs(xy[1] - float(aim["y"])) <= 1e-3
        for (frame, xy), (k, aim) in zip(points, aims, strict=False)
    )  # fmt: skip
    if not same:
        raise DamagedFileError(
            f"{path}: its {len(points)} point(s) are not the aims of {RECORD_NAME}'s {len(aims)} frame(s) with an "
            "aim; the output is damaged: run hd descend again"
        )
    return cast("TrackGeoJson", track)


# ----------------------------------------------------------------------------------------- frames
@dataclass(frozen=True)
class _Frame:
    """One frame as the page shows it: its images (data URI, width, height pixels) by layer, the images'
    extent (metres) and its ranked sites (x, y metres)."""

    index: int
    images: dict[str, tuple[str, int, int]]
    extent: Extent
    sites: list[tuple[float, float]]


def _load_frame(path: Path, out: DescendOutput, mapped: bool) -> dict[str, np.ndarray]:
    """The arrays of a frame's ``.npz``, checked: heights and (``mapped``) the maps on the mosaic's grid,
    a north-up transform of its cells, the sites with ``SITE_COLUMNS``.

    Raises:
        DamagedFileError: a missing, unreadable or damaged file.
    """
    if not os.path.lexists(path):
        raise DamagedFileError(
            f"{path}: missing, and {RECORD_NAME} lists it; the output is incomplete: run hd descend again"
        )
    check_regular_file(path, "frame file")  # a FIFO or a device in its place is refused, never opened
    try:
        with np.load(io.BytesIO(read_regular_bytes(path, max_bytes=NPZ_MAX_BYTES)), allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise DamagedFileError(f"{path}: unreadable ({exc}); the output is damaged: run hd descend again") from exc
    needed = ["heights_m", "transform", "sites", "site_columns", *(MAP_KEYS if mapped else ())]
    missing = [k for k in needed if k not in arrays]
    shape = (out.rows, out.cols)
    bad = missing or [k for k in ("heights_m", *MAP_KEYS) if k in arrays and arrays[k].shape != shape]
    t = arrays.get("transform", np.zeros(0))
    if not bad and (t.shape != (6,) or not np.isfinite(t).all() or t[0] <= 0 or t[4] >= 0 or t[1] or t[3]):
        bad = ["transform"]
    if not bad and [str(c) for c in arrays["site_columns"]] != list(SITE_COLUMNS):
        bad = ["site_columns"]
    if bad:
        what = f"no {', '.join(missing)}" if missing else f"its {bad[0]} is not of the {shape[0]} x {shape[1]} grid"
        raise DamagedFileError(f"{path}: {what}; the output is damaged: run hd descend again")
    return arrays


def _frame(out: DescendOutput, descent: int, record: FrameJson, max_px: int) -> _Frame:
    """One frame's images: the mosaic's hillshade and (a frame with a map) the safety map, P(safe) and
    entropy, reduced to at most ``max_px`` pixels a side and coloured as the detect page colours them."""
    from hdnet.descend_json import frame_file
    from hdnet.view_images import (
        PROBABILITY_CMAP,
        UNCERTAINTY_CMAP,
        UNCERTAINTY_MAX_NATS,
        Reduction,
        colour_rgba,
        hillshade_rgba,
        png_bytes,
        reduced_array,
        reduced_codes,
        safety_rgba,
    )

    k = int(record["frame"])
    arrays = _load_frame(out.directory / frame_file(descent, k), out, record.get("no_map") is None)
    reduction = Reduction.of((out.rows, out.cols), max_px)
    h, w = reduction.shape
    a, _, c, _, e, f = (float(v) for v in arrays["transform"])
    extent = (c, c + reduction.factor * a * w, f + reduction.factor * e * h, f)
    images: dict[str, tuple[str, int, int]] = {}

    def put(key: str, rgba: np.ndarray) -> None:
        images[key] = (data_uri(png_bytes(rgba)), int(rgba.shape[1]), int(rgba.shape[0]))

    put("hillshade", hillshade_rgba(reduced_array(arrays["heights_m"], reduction), reduction.factor * a))
    if record.get("no_map") is None:
        put("safety", safety_rgba(reduced_codes(arrays["safety"], reduction)))
        put("p_safe", colour_rgba(reduced_array(arrays["p_safe"], reduction), PROBABILITY_CMAP, 0.0, 1.0))
        entropy = reduced_array(arrays["entropy_nats"], reduction)
        put("entropy", colour_rgba(entropy, UNCERTAINTY_CMAP, 0.0, UNCERTAINTY_MAX_NATS))
    x, y = SITE_COLUMNS.index("x"), SITE_COLUMNS.index("y")
    sites = [(float(row[x]), float(row[y])) for row in np.asarray(arrays["sites"]).reshape(-1, len(SITE_COLUMNS))]
    return _Frame(k, images, extent, sites)


# ---------------------------------------------------------------------------------------- the page
def descend_page(out: DescendOutput, max_px: int) -> tuple[str, dict[str, Any]]:
    """The page of a descend output and what it shows (for the summary and ``hd --json``); its images at
    most ``min(max_px, DESCENT_MAX_PX)`` pixels a side.

    Raises:
        DamagedFileError / StorageError: a missing or damaged frame file.
        HdNetError: a ``descend.json`` whose values are not of the kinds ``hd descend`` writes.
    """
    try:
        px = min(max_px, DESCENT_MAX_PX)
        sections, n_frames, image_px = [], 0, (0, 0)
        for descent in out.info["descents"]:
            frames = [_frame(out, descent["descent"], f, px) for f in descent["frames"]]
            sections.append(_descent_section(out, descent, frames))
            n_frames += len(frames)
            _, w, h = frames[0].images["hillshade"]
            image_px = (w, h)
        return _page_text(out, sections, n_frames, image_px, frames[0].extent)
    except HdError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:  # a value of another kind
        raise _schema_error(out.directory / RECORD_NAME, f"{type(exc).__name__}: {exc}") from exc


def _page_text(
    out: DescendOutput, sections: list[str], n_frames: int, image_px: tuple[int, int], extent: Extent
) -> tuple[str, dict[str, Any]]:
    """The whole page: heading, lead, a link per descent, the sections, the settings and the footer."""
    info = out.info
    descents = info["descents"]
    name = out.directory.resolve().name
    n_diverts = sum(len(d.get("diverts") or []) for d in descents)
    lead = (
        f"{len(descents)} descent(s), {n_frames} frames, {n_diverts} divert(s); H_t {_h_t(info)} "
        f"({info['threshold'].get('spec')}{recorded_score(info['threshold']).qualifier}); mosaics of "
        f"{out.rows} x {out.cols} cells of {out.spacing_m:g} m."
    )
    toc = "".join(f'<a href="#descent-{d["descent"]}">Descent {d["descent"]}</a>' for d in descents)
    body = [
        f"<header><h1>hd descend: {esc(name)}</h1>",
        f'<p id="lead">{esc(lead)}</p></header>',
        f'<nav class="toc">{toc}<a href="#settings-section">Settings</a></nav>',
        *sections,
        '<section id="settings-section"><h2>Settings</h2>',
        definitions(_settings_items(out), table_id="settings"),
        "</section>",
        _footer(out, name),
    ]
    shown = {
        "what": f"hd descend output, {len(descents)} descent(s), {n_frames} frames, images {image_px[0]} x "
        f"{image_px[1]} px",
        "descents": [d["descent"] for d in descents],
        "frames": n_frames,
        "image_px": list(image_px),
        "diverts": n_diverts,
    }
    return page(f"hd descend: {name}", "\n".join(body), lead, _style(out, extent), DESCENT_SCRIPT), shown


def _footer(out: DescendOutput, name: str) -> str:
    digest = sha256_file(out.directory / RECORD_NAME)
    return (
        f'<footer><p class="note">Made by hd view {esc(__version__)} from {esc(name)}/{RECORD_NAME} (sha256 '
        f"{digest}). Nothing on this page is fetched from a network.</p></footer>"
    )


def _h_t(info: DescendJson) -> str:
    h_t = info["threshold"].get("value_nats")
    return f"{float(h_t):.4f} nats" if _finite(h_t) else "unbounded"


def _entropy_tick(out: DescendOutput) -> float | None:
    """Where H_t stands on the entropy bar (0 to ln 2), when the threshold applies to the entropy."""
    from hdnet.view_images import UNCERTAINTY_MAX_NATS

    h_t = out.info["threshold"].get("value_nats")
    if recorded_score(out.info["threshold"]) is not ENTROPY or not _finite(h_t):
        return None
    return min(1.0, float(h_t) / UNCERTAINTY_MAX_NATS)


def _style(out: DescendOutput, extent: Extent) -> str:
    """The page's own rules: the detect page's bars, swatches and H_t tick, the maps' aspect ratio."""
    from hdnet.figures import SAFETY_HEX
    from hdnet.view_images import PROBABILITY_CMAP, UNCERTAINTY_CMAP, colour_stops

    left, right, bottom, top = extent
    rules = map_style(
        (right - left, top - bottom),
        {"probability": colour_stops(PROBABILITY_CMAP), "uncertainty": colour_stops(UNCERTAINTY_CMAP)},
        dict(zip(SWATCHES, SAFETY_HEX, strict=False)),
        _entropy_tick(out),
    )
    return rules + DESCENT_STYLE + f".descent-map {{ aspect-ratio: {right - left:.6f} / {top - bottom:.6f}; }}\n"


def _layer_controls(out: DescendOutput, index: int) -> str:
    """The layers' checkboxes, opacity sliders and legends (one set per descent, for all its frames)."""
    from hdnet.view_images import UNCERTAINTY_MAX_NATS

    score = recorded_score(out.info["threshold"])
    tick = _entropy_tick(out)
    swatches = "".join(
        f'<span class="swatch swatch-{name}"></span>{esc(word)}'
        for name, word in zip(SWATCHES, ("unsafe", "safe", f"uncertain ({score.name} ≥ H_t)"), strict=True)
    )
    track = (
        "Line: the aim after each frame so far; yellow ring: the aim now (the lander's footprint); dashed rings: "
        "this frame's ranked sites; arrows: the diverts so far (frame, distance)"
    )
    layers = (
        ("track", "Site track", True, 100, track),
        ("safety", "Safety map (uncertainty-aware)", True, 55, swatches + "; no colour: invalid"),
        ("p_safe", "P(safe), network (MC-dropout mean)", False, 85, colour_bar("probability", "0", "1")),
        (
            "entropy",
            "Predictive entropy",
            False,
            85,
            colour_bar("uncertainty", "0", f"{UNCERTAINTY_MAX_NATS:.3f} nats (ln 2)", tick, f"H_t = {_h_t(out.info)}"),
        ),
        ("hillshade", "Hillshade of the mosaic so far", True, 100, "sun NW, 45°; no shade: no height yet"),
    )  # fmt: skip
    controls = []
    for key, title, visible, opacity, legend in layers:
        ident = f"{key}-{index}"
        controls.append(
            '<div class="layer-control">'
            f'<label><input type="checkbox" class="descent-toggle" id="toggle-{ident}" data-key="{key}"'
            f"{' checked' if visible else ''}> {esc(title)}</label>"
            f'<input type="range" class="descent-opacity" id="opacity-{ident}" data-key="{key}" min="0" max="100" '
            f'value="{opacity}" aria-label="opacity of {esc(title)}"><div class="legend">{legend}</div></div>'
        )
    return "<fieldset><legend>Layers</legend>" + "".join(controls) + "</fieldset>"


def _lander_radius_m(out: DescendOutput, extent: Extent) -> float:
    """The radius (metres) the aim's ring is drawn with: the lander's (``descend.json``'s ``lander``), or
    1.5 % of the map's longer side when that is larger or the lander is not recorded."""
    left, right, bottom, top = extent
    diameter = (out.info.get("lander") or {}).get("diameter_m")
    least = 0.015 * max(right - left, top - bottom)
    return max(float(diameter) / 2.0, least) if _finite(diameter) else least


def _arrow(old: tuple[float, float], new: tuple[float, float], head_m: float) -> str:
    """An arrow from ``old`` to ``new`` (map metres; SVG y is -y): its shaft and its head, a triangle."""
    (x0, y0), (x1, y1) = (old[0], -old[1]), (new[0], -new[1])
    length = math.hypot(x1 - x0, y1 - y0)
    if length <= 0.0:
        return ""
    ux, uy = (x1 - x0) / length, (y1 - y0) / length
    head = min(head_m, 0.6 * length)
    bx, by = x1 - head * ux, y1 - head * uy
    corners = ((x1, y1), (bx - 0.5 * head * uy, by + 0.5 * head * ux), (bx + 0.5 * head * uy, by - 0.5 * head * ux))
    points = " ".join(f"{x:.3f},{y:.3f}" for x, y in corners)
    return (
        f'<line class="divert-arrow" x1="{x0:.3f}" y1="{y0:.3f}" x2="{bx:.3f}" y2="{by:.3f}" '
        'vector-effect="non-scaling-stroke"/>'
        f'<polygon class="divert-head" points="{points}"/>'
    )


def _track_svg(out: DescendOutput, descent: DescentJson, frame: _Frame) -> str:
    """The site track after ``frame``: the aims so far (the descent's track, its points up to this frame),
    the aim now, this frame's sites and the diverts so far; SVG in map metres (y up as -y)."""
    left, right, bottom, top = frame.extent
    width, height = right - left, top - bottom
    span = max(width, height)
    radius = _lander_radius_m(out, frame.extent)
    font = 0.025 * span
    stroke = 'vector-effect="non-scaling-stroke"'
    points: list[tuple[float, float]] = []
    for feature in out.tracks[descent["descent"]]["features"]:
        geometry, properties = feature.get("geometry"), feature.get("properties")
        if not (isinstance(geometry, dict) and geometry.get("type") == "Point" and isinstance(properties, dict)):
            continue
        if int(properties["frame"]) <= frame.index:
            x, y = geometry["coordinates"]
            points.append((float(x), float(y)))
    parts = [f'<circle class="site-dot" cx="{x:.3f}" cy="{-y:.3f}" r="{radius:.3f}" {stroke}/>' for x, y in frame.sites]
    line = " ".join(f"{x:.3f},{-y:.3f}" for x, y in points)
    parts += [f'<polyline class="{cls}" points="{line}" {stroke}/>' for cls in ("track-line-under", "track-line")]
    parts += [f'<circle class="track-point" cx="{x:.3f}" cy="{-y:.3f}" r="{0.25 * radius:.3f}" {stroke}/>'
              for x, y in points]  # fmt: skip
    for f in descent["frames"][: frame.index + 1]:
        d = f.get("divert")
        if d is not None:
            (ox, oy), (nx, ny) = d["old"], d["new"]
            parts.append(_arrow((ox, oy), (nx, ny), 1.5 * radius))
            parts.append(
                f'<text class="divert-label" x="{(ox + nx) / 2 + 0.5 * radius:.3f}" y="{-(oy + ny) / 2:.3f}" '
                f'font-size="{font:.3f}" stroke-width="{0.15 * font:.3f}">'
                f"frame {f['frame']}: {float(d['distance_m']):.1f} m</text>"
            )
    aim = descent["frames"][frame.index].get("aim")
    if aim is not None:
        ax, ay = float(aim["x"]), -float(aim["y"])
        parts += [f'<circle class="{cls}" cx="{ax:.3f}" cy="{ay:.3f}" r="{radius:.3f}" {stroke}/>'
                  for cls in ("aim-halo", "aim-ring")]  # fmt: skip
    view_box = f'viewBox="{left:.6f} {-top:.6f} {width:.6f} {height:.6f}" preserveAspectRatio="none"'
    return (
        f'<svg class="layer layer-track" xmlns="http://www.w3.org/2000/svg" {view_box} '
        f'aria-label="site track after frame {frame.index}">{"".join(parts)}</svg>'
    )


def _frame_label(descent: DescentJson, k: int) -> str:
    """What the stepper says of frame ``k``: its altitude, the aim after it, its divert or why no map."""
    f = descent["frames"][k]
    n = len(descent["frames"])
    aim = f.get("aim")
    words = f"frame {k} of {n - 1} (0 the highest), {float(f['altitude_m']):.1f} m above the target; "
    if aim is None:
        words += "no aim yet"
    else:
        words += f"aim ({float(aim['x']):.1f}, {float(aim['y']):.1f}) m, P(safe) {_fraction(aim.get('p_safe'))}"
    d = f.get("divert")
    if d is not None:
        words += f"; diverted {float(d['distance_m']):.1f} m"
    if f.get("no_map") is not None:
        words += f"; {f['no_map']}"
    return words


def _fraction(value: object) -> str:
    return f"{float(value):.3f}" if _finite(value) else "--"


def _frame_div(out: DescendOutput, descent: DescentJson, frame: _Frame, last: int) -> str:
    """One frame's stack: its images (bottom to top: hillshade, P(safe), entropy, safety) and its track."""
    stack = []
    for key in ("hillshade", "p_safe", "entropy", "safety"):
        if key in frame.images:
            uri, w, h = frame.images[key]
            alt = f"{key} of frame {frame.index}"
            stack.append(f'<img class="layer layer-{key}" src="{uri}" width="{w}" height="{h}" alt="{alt}">')
    stack.append(_track_svg(out, descent, frame))
    no_map = descent["frames"][frame.index].get("no_map")
    if no_map is not None:
        stack.append(f'<p class="no-map">{esc(no_map[:1].upper() + no_map[1:])}</p>')
    label = esc(_frame_label(descent, frame.index))
    hidden = "" if frame.index == last else " hidden"
    return f'<div class="frame" data-frame="{frame.index}" data-label="{label}"{hidden}>' + "".join(stack) + "</div>"


def _descent_section(out: DescendOutput, descent: DescentJson, frames: list[_Frame]) -> str:
    """One descent: its lead, the frame stepper and layers beside its map (the last frame shown first),
    and its table of frames."""
    index = descent["descent"]
    last = len(frames) - 1
    left, right, bottom, top = frames[0].extent
    diverts = descent.get("diverts") or []
    final = descent.get("final_site")
    lead = (
        f"{len(frames)} frames ({descent.get('split') or 'no'} split), {len(diverts)} divert(s); "
        + (
            f"final site ({float(final['x']):.1f}, {float(final['y']):.1f}) m, P(safe) {_fraction(final.get('p_safe'))}"
            if final
            else "no site: no lander footprint is safe and certain"
        )
        + f"; {float(descent.get('median_frame_s') or 0.0):.2f} s per frame (median)."
    )
    stepper = (
        "<fieldset><legend>Frame</legend>"
        '<div class="stepper"><button type="button" class="frame-step" data-step="-1" title="the frame before">'
        f'&#9664;</button><input type="range" class="frame-slider" id="frame-slider-{index}" min="0" max="{last}" '
        f'value="{last}" aria-label="frame of descent {index}"><button type="button" class="frame-step" data-step="1" '
        'title="the next frame">&#9654;</button></div>'
        f'<p class="frame-label" aria-live="polite">{esc(_frame_label(descent, last))}</p></fieldset>'
    )
    extent = (
        f'<p class="note">x {left:.1f} to {right:.1f} m, y {bottom:.1f} to {top:.1f} m: east and north of the '
        "descent's target, as the newest frame's navigation places it.</p><div class=\"descent-readout\"></div>"
    )
    frames_html = "\n".join(_frame_div(out, descent, f, last) for f in frames)
    return (
        f'<section class="descent" id="descent-{index}" data-frames="{len(frames)}"><h2>Descent {index}</h2>\n'
        f'<p class="note">{esc(lead)}</p>\n'
        f'<div class="layout"><div class="controls">{stepper}{_layer_controls(out, index)}{extent}</div>\n'
        f'<div class="descent-panel"><div class="map descent-map" id="descent-map-{index}" data-left="{left!r}" '
        f'data-top="{top!r}" data-width="{right - left!r}" data-height="{top - bottom!r}">\n{frames_html}\n'
        "</div></div></div>\n"
        f"<h3>Frames</h3>\n{_frames_table(descent)}</section>"
    )


FRAME_HEADER = (
    "frame",
    "altitude (m)",
    "registration (s)",
    "mosaic (s)",
    "map (s)",
    "sites (s)",
    "total (s)",
    "aim x (m)",
    "aim y (m)",
    "aim P(safe)",
    "sites",
    "divert",
)


def _frames_table(descent: DescentJson) -> str:
    """The table of frames: a row each (a click shows that frame); a frame without a map says why."""
    rows, attrs = [], []
    for f in descent["frames"]:
        t = f.get("timings_s") or {}
        seconds = [_seconds(t.get(step)) for step in ("registration", "mosaic", "map", "sites")]
        total = sum(float(v) for v in t.values() if _finite(v))
        aim = f.get("aim")
        d = f.get("divert")
        divert = (
            f"{float(d['distance_m']):.1f} m from ({float(d['old'][0]):.1f}, {float(d['old'][1]):.1f})"
            if d is not None
            else ""
        )
        if f.get("no_map") is not None:
            divert = str(f["no_map"])
        rows.append(
            [
                str(f["frame"]),
                f"{float(f['altitude_m']):.1f}",
                *seconds,
                f"{total:.3f}",
                f"{float(aim['x']):.1f}" if aim else "--",
                f"{float(aim['y']):.1f}" if aim else "--",
                _fraction(aim.get("p_safe")) if aim else "--",
                str(f.get("n_sites", "--")),
                divert,
            ]
        )
        attrs.append({"class": "frame-row", "data-frame": str(f["frame"])})
    return table(list(FRAME_HEADER), rows, table_id=f"frames-{descent['descent']}", row_attrs=attrs)


def _seconds(value: object) -> str:
    return f"{float(value):.3f}" if _finite(value) else "--"


def _name(path: object) -> str:
    """A recorded path or address by its last part (the page shows no absolute path)."""
    text = str(path or "").rstrip("/\\")
    return text.replace("\\", "/").rsplit("/", 1)[-1] if text else "--"


def _settings_items(out: DescendOutput) -> list[tuple[str, str]]:
    """The settings table: the run, the input, H_t and every setting of ``hd descend`` as recorded."""
    info = out.info
    run, src, th = info["run"], info["input"], info["threshold"]
    checkpoint = str(run.get("checkpoint", ""))
    run_name = f"{_name(checkpoint.rsplit('/', 1)[0])}/{_name(checkpoint)}" if "/" in checkpoint else _name(checkpoint)
    sigma = src.get("sigma_m")
    items = [
        ("run", f"{run_name} (trained on {_name(run.get('dataset'))}, labels {run.get('labels')})"),
        ("descent build", _name(src.get("dataset"))),
        ("frames' noise level", f"{float(sigma) * 100:.3g} cm ({float(sigma):g} m)" if _finite(sigma) else "--"),
        ("poses", str(src.get("poses"))),
        ("mosaic grid", f"{out.rows} x {out.cols} cells of {out.spacing_m:g} m ({src['dem'].get('gridding')})"),
        ("coordinates", str(info.get("frame", ""))),
        ("threshold", f"{th.get('spec')}{recorded_score(th).qualifier}: H_t = {_h_t(info)}"),
        ("uncertainty score", recorded_score(th).name),
    ]
    lander = info.get("lander")
    if isinstance(lander, dict):
        items.append(("lander", ", ".join(f"{k} {v}" for k, v in lander.items())))
    items += [(f"--{k.replace('_', '-')}", json.dumps(v)) for k, v in info["settings"].items() if k != "device"]
    items += [("hd version", str(info.get("software_version"))), ("time taken", f"{info.get('seconds', '--')} s")]
    return items
