"""Descent hazard detection as a lander runs it (``hd descend``): the descents of a descent build
flown frame by frame (``hdnet.descent_flight``) by a run trained on descent mosaics, and what they
leave behind.

Input: a descent build (``hd build-dataset --descent-frames K``), the frames' points at one stored
noise level, and a run trained on mosaics of such builds (``hd mosaic`` then ``hd label``, ``hd
train``): the mosaics are made on that run's mosaic grid (its dataset's ``mosaic.dem``). Output, into
a new or empty directory or over an earlier ``hd descend`` output (``hdcore.storage.OutputDir``:
staged, moved into place with ``descend.json`` last, so the output is complete when ``descend.json``
is there):

* ``descent-KKKKK-frame-NN.npz``, one per frame of each descent flown (NumPy, ``numpy.load``): the
  mosaic so far (``heights_m``, float32 metres, NaN where none) and its maps as ``hd detect`` writes
  them (``p_safe``, ``entropy_nats``, ``mutual_information_nats``, ``safety`` uint8 codes,
  ``baseline_p_safe``), the grid's ``transform`` (six numbers: column, row -> x, y in metres from the
  target) and the ranked ``sites`` (one row each, ``SITE_COLUMNS``);
* ``descent-KKKKK-track.geojson``: the aim after each frame (a Point per frame, with its frame,
  altitude and whether it diverted) and the aims as one LineString, in the mosaic frame's metres;
* ``descend.json``: the run, the input, the settings, H_t, and per descent every frame's seconds
  (registration, mosaic, map, sites), its aim and its counts, and every divert (the records:
  ``hdnet.descend_json``).

A frame whose mosaic has no lander-sized square of valid cells is recorded without a map (its ``.npz``
holds the heights, the transform and no sites; its row says why) and the descent goes on.

The last frame's mosaic and maps are ``hd mosaic``'s mosaic of the same frames and ``hd detect``'s
maps of it (the same bytes; docs/hdnet.md, "Descending").
"""

from __future__ import annotations

import dataclasses
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hdcore.errors import HdWarning
from hdcore.storage import OutputDir, write_json_atomic
from hdlabels.mosaic import POSES, Poses, descent_frames
from hdlabels.store import DemSpec
from hdnet._version import __version__
from hdnet.data import sigma_index
from hdnet.descend_json import (
    RECORD_NAME,
    TIMING_STEPS,
    AimJson,
    DescendJson,
    DescentJson,
    DivertJson,
    FrameJson,
    TrackGeoJson,
    frame_file,
    is_descend_file,
    track_file,
)
from hdnet.descend_settings import DescendSettings
from hdnet.descent_flight import FrameStep, fly
from hdnet.detect import MAPS, DetectRun, centred_transform, detect_threshold, load_run
from hdnet.errors import HdNetError
from hdnet.report import json_plain
from hdnet.report_json import ThresholdJson
from hdnet.results import SITE_COLUMNS, Site
from hdnet.run_record import unfinished_training
from lidarsim.location import dataset_key, has_manifest
from lidarsim.shards import MANIFEST_KIND_MOSAICS, MANIFEST_NAME, ManifestJson, iter_descents, read_manifest


@dataclass
class DescendResult:
    """What :func:`descend` flew and wrote (``descend.json`` holds ``record``)."""

    out_dir: Path
    descents: dict[int, list[FrameStep]] = field(repr=False)
    record: DescendJson = field(repr=False)

    def summary(self) -> list[str]:
        """One line per descent (frames, those without a map, diverts, final aim, median seconds per frame)
        and where the files are."""
        lines = []
        for index, steps in self.descents.items():
            totals = [s.timing.total_s for s in steps]
            diverts = [s.divert for s in steps if s.divert is not None]
            unmapped = [s.frame for s in steps if s.maps is None]
            without = f" ({len(unmapped)} without a map: {', '.join(map(str, unmapped))})" if unmapped else ""
            aim = steps[-1].aim
            final = (
                f"final site ({aim.x:.1f}, {aim.y:.1f}) m from the target, P(safe) {aim.p_safe:.3f}"
                if aim is not None
                else "no site: no lander footprint is safe and certain"
            )
            moved = f" ({', '.join(f'{d.distance_m:.1f} m after frame {d.frame}' for d in diverts)})" if diverts else ""
            lines.append(
                f"descent {index}: {len(steps)} frames{without}, {len(diverts)} divert(s){moved}; {final}; "
                f"{float(np.median(totals)):.2f} s per frame (median)"
            )
        lines.append(f"per-frame maps (.npz), site tracks (.geojson) and {RECORD_NAME} in {self.out_dir}")
        return lines


def descend(
    run_dir: str | os.PathLike,
    data: str | os.PathLike,
    out_dir: str | os.PathLike,
    settings: DescendSettings,
    progress: Callable[[int, int], None] | None = None,
) -> DescendResult:
    """Fly the descents ``settings`` names (``descent``, ``split``) of the descent build ``data`` with the
    run ``run_dir`` into ``out_dir`` (the module docstring); ``progress`` is called with (frames flown,
    frames in all).

    Raises:
        HdNetError: ``data`` is not a descent build, a descent that is not in it, a split without
            descents, a noise level it does not store, a run not trained on descent mosaics, a calibrated
            threshold whose data is not present. Nothing is written then.
        StorageError / OutputExistsError: an ``out_dir`` that is or holds an input, holds anything but an
            earlier output (replaced only with ``settings.overwrite``), or that another process writes.
    """
    t_start = time.perf_counter()
    manifest, frames_per_descent = _descent_build(data)
    wanted = _check_selection(data, manifest, settings)
    output = OutputDir(out_dir, what="descend", marker=RECORD_NAME, owns=is_descend_file, inputs={"the run": run_dir})
    output.add_inputs({"the descent build": data})
    output.check_place()
    run = load_run(run_dir, settings.device or None)
    dem = _mosaic_grid(run, run_dir)
    unfinished = unfinished_training(run.checkpoint, run.header.epoch)
    if unfinished is not None:  # as hd detect says it
        warnings.warn(unfinished, HdWarning, stacklevel=2)
    output.add_inputs({"the checkpoint": run.checkpoint, "the run's dataset": run.dataset})
    out = output.check(settings.overwrite)
    sigmas = tuple(float(s) for s in manifest["sigmas_m"])
    if not sigmas:
        raise HdNetError(f"{data}: its frames have no noisy points (no --sigmas); a lander maps what it measures.")
    k = sigma_index(sigmas, run.train_sigma_m if settings.sigma_m is None else float(settings.sigma_m))
    mapping = settings.detect_settings(sigmas[k])
    threshold = detect_threshold(run, mapping)
    poses: Poses = next(p for p in POSES if p == settings.poses)
    flown: dict[int, list[FrameStep]] = {}
    splits: dict[int, str] = {}
    total = frames_per_descent * (len(wanted) if wanted is not None else _n_selected(manifest, settings.split))
    if progress:
        progress(0, total)
    with output.open(settings.overwrite) as tmp:
        for scans in iter_descents(data, settings.split):
            index = int(scans[0].descent.descent_index)  # type: ignore[union-attr]  # iter_descents checks it
            if wanted is not None and index not in wanted:
                continue
            frames, target = descent_frames(scans, k)
            steps = fly(run, frames, target, dem, poses, mapping, threshold)
            flown[index], splits[index] = steps, scans[0].split
            write_descent(tmp, index, steps, dem.spacing_m)
            if progress:
                progress(frames_per_descent * len(flown), total)
        record = _record(run, data, sigmas[k], dem, poses, settings, threshold[1], flown, splits)
        record["seconds"] = round(time.perf_counter() - t_start, 3)
        write_json_atomic(tmp / RECORD_NAME, record)
        output.commit()
    return DescendResult(out, flown, record)


def _descent_build(data: str | os.PathLike) -> tuple[ManifestJson, int]:
    """Step 1: the descent build's manifest and its frames per descent.

    Raises:
        HdNetError: no dataset, a mosaic dataset, or a dataset of single scans.
    """
    if not has_manifest(data, MANIFEST_NAME):
        raise HdNetError(f"{data} is not a dataset (no {MANIFEST_NAME}); give a descent build (--descent-frames K).")
    manifest = read_manifest(data)
    if manifest.get("kind") == MANIFEST_KIND_MOSAICS:
        raise HdNetError(
            f"{data} is a mosaic dataset; hd descend flies the frames of the descent build it was made from "
            "(hd build-dataset --descent-frames K)."
        )
    frames = manifest.get("descent_frames")
    if not isinstance(frames, int):
        raise HdNetError(
            f"{data} is not a descent build (its manifest records no descent_frames); build one with "
            "hd build-dataset --descent-frames K."
        )
    return manifest, frames


def _check_selection(data: str | os.PathLike, manifest: ManifestJson, settings: DescendSettings) -> set[int] | None:
    """Step 1b: the one descent asked for (None: every descent, of the split when given), checked
    against the build's descents and splits before anything is loaded.

    Raises:
        HdNetError: a descent index past the build's, a split without descents.
    """
    n = int(manifest.get("n_descents", 0))
    index = settings.descent_index()
    if index is not None and index >= n:
        raise HdNetError(f"descent {index} is not in {data}: it holds descents 0..{n - 1}.")
    if settings.split is not None and not _n_selected(manifest, settings.split):
        raise HdNetError(f"{data} has no descent in the {settings.split} split.")
    return None if index is None else {index}


def _n_selected(manifest: ManifestJson, split: str | None) -> int:
    """Descents of ``split`` (all when None) in a descent build."""
    n = int(manifest.get("n_descents", 0))
    if split is None:
        return n
    frames = int(manifest.get("descent_frames") or 1)
    return int(manifest.get("splits", {}).get(split, 0)) // frames


def _mosaic_grid(run: DetectRun, run_dir: str | os.PathLike) -> DemSpec:
    """Step 2: the grid the run's mosaics were made on (its dataset's ``mosaic.dem``; the run's labelling
    grid when that dataset is not present any more).

    Raises:
        HdNetError: the run was trained on a dataset of single scans, not of descent mosaics.
    """
    if run.dataset is None:
        return run.labeling.dem
    manifest = read_manifest(run.dataset)
    mosaic: object = manifest.get("mosaic")
    dem: object = mosaic.get("dem") if isinstance(mosaic, dict) else None
    if manifest.get("kind") != MANIFEST_KIND_MOSAICS or not isinstance(dem, dict):
        raise HdNetError(
            f"run {run_dir} was trained on {run.dataset}, which holds single scans, not descent mosaics; "
            "hd descend maps mosaics: train a run on hd mosaic's output."
        )
    return DemSpec(int(dem["rows"]), int(dem["cols"]), float(dem["spacing_m"]), str(dem["gridding"]))


def write_descent(tmp: Path, index: int, steps: list[FrameStep], spacing_m: float) -> None:
    """Step 3: one descent's per-frame maps (``.npz``) and its site track (GeoJSON) into ``tmp``; a frame
    without a map has its heights, transform (the scan frame of ``spacing_m``-metre cells centred on
    the mosaic, as its maps would have) and no sites."""
    for step in steps:
        maps = step.maps
        arrays = {} if maps is None else {spec.field: getattr(maps, spec.field) for spec in MAPS}
        transform = centred_transform(step.heights.shape, spacing_m) if maps is None else maps.transform
        sites = np.array([[s.columns()[c] for c in SITE_COLUMNS] for s in step.sites], dtype=np.float64)
        with open(tmp / frame_file(index, step.frame), "wb") as f:
            np.savez_compressed(
                f,
                heights_m=step.heights,
                transform=np.array(list(transform)[:6], dtype=np.float64),
                sites=sites.reshape(len(step.sites), len(SITE_COLUMNS)),
                site_columns=np.array(SITE_COLUMNS),
                **arrays,
            )
    write_json_atomic(tmp / track_file(index), track_geojson(steps), indent=1)


def track_geojson(steps: list[FrameStep]) -> TrackGeoJson:
    """The aim after each frame as GeoJSON: a Point per frame with an aim (its frame, altitude, site and
    whether it diverted there) and the aims in order as one LineString (mosaic-frame metres)."""
    points: list[dict[str, object]] = []
    line: list[list[float]] = []
    for step in steps:
        if step.aim is None:
            continue
        xy = [round(step.aim.x, 3), round(step.aim.y, 3)]
        line.append(xy)
        properties = {"frame": step.frame, "altitude_m": round(step.altitude_m, 3), "diverted": step.divert is not None}
        points.append(
            {
                "type": "Feature",
                "geometry": {"type": "Point", "coordinates": xy},
                "properties": json_plain({**properties, **step.aim.columns()}),
            }
        )
    track: dict[str, object] = {
        "type": "Feature",
        "geometry": {"type": "LineString", "coordinates": line},
        "properties": {"aim": "track"},
    }
    return {"type": "FeatureCollection", "features": [*points, track]}


def _aim(site: Site | None) -> AimJson | None:
    return None if site is None else json_plain(site.columns())


def _divert(step: FrameStep) -> DivertJson | None:
    if step.divert is None:
        return None
    d = step.divert
    return {
        "frame": d.frame,
        "elapsed_s": d.elapsed_s,
        "altitude_m": d.altitude_m,
        "old": [float(v) for v in d.old],
        "new": [float(v) for v in d.new],
        "distance_m": d.distance_m,
        "reason": d.reason,
    }


def frame_record(step: FrameStep) -> FrameJson:
    """One frame's row of ``descend.json``: its seconds per step, its aim, its counts, its divert and why
    it has no map (None: it has one)."""
    t = step.timing
    seconds = (t.registration_s, t.mosaic_s, t.map_s, t.sites_s)
    row: FrameJson = {
        "frame": step.frame,
        "altitude_m": round(step.altitude_m, 3),
        "timings_s": {name: round(v, 4) for name, v in zip(TIMING_STEPS, seconds, strict=True)},
        "aim": _aim(step.aim),
        "n_sites": len(step.sites),
        "counts": None if step.maps is None else step.maps.counts,
        "divert": _divert(step),
        "no_map": step.no_map,
    }
    if step.registration is not None:
        row["registration_fitness"] = [float(v) for v in step.registration.fitness]
    return row


def descent_record(index: int, split: str | None, steps: list[FrameStep]) -> DescentJson:
    """One descent's entry of ``descend.json``: its frames, diverts, final aim, median seconds and files."""
    totals = [s.timing.total_s for s in steps]
    return {
        "descent": index,
        "split": split,
        "frames": [frame_record(s) for s in steps],
        "diverts": [d for s in steps if (d := _divert(s)) is not None],
        "final_site": _aim(steps[-1].aim),
        "median_frame_s": round(float(np.median(totals)), 4),
        "files": [frame_file(index, s.frame) for s in steps] + [track_file(index)],
    }


def _record(
    run: DetectRun,
    data: str | os.PathLike,
    sigma_m: float,
    dem: DemSpec,
    poses: str,
    settings: DescendSettings,
    threshold: ThresholdJson,
    flown: dict[int, list[FrameStep]],
    splits: dict[int, str],
) -> DescendJson:
    """Step 4: ``descend.json``'s record (``seconds`` 0 until the caller sets it)."""
    return {
        "software": "hd",
        "software_version": __version__,
        "run": {"checkpoint": str(run.checkpoint.resolve()), "dataset": run.recorded_dataset, "labels": run.labels},
        "input": {"dataset": dataset_key(data), "sigma_m": sigma_m, "poses": poses, "dem": dem.to_entry()},
        "lander": json_plain(dataclasses.asdict(run.lander)),
        "settings": json_plain(dataclasses.asdict(settings)),
        "threshold": json_plain(threshold),
        "frame": "metres east and north of each descent's target, as its newest frame's navigation places it",
        "timing_steps": list(TIMING_STEPS),
        "descents": [json_plain(descent_record(i, splits.get(i), steps)) for i, steps in flown.items()],
        "seconds": 0.0,
    }
