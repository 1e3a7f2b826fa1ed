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
  (registration, mosaic, map, sites), its aim and its counts, and every divert.

The last frame's mosaic and maps are ``hd mosaic``'s mosaic of the same frames and ``hd detect``'s
maps of it (the same bytes; docs/hdnet.md, "Descending").
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hdcore.storage import OutputDir, write_json_atomic
from hdlabels.mosaic import POSES, Poses, descent_frames
from hdlabels.store import DemSpec
from hdnet._version import __version__
from hdnet.data import sigma_index
from hdnet.descend_settings import DescendSettings
from hdnet.descent_flight import FrameStep, fly
from hdnet.detect import MAPS, DetectRun, detect_threshold, load_run
from hdnet.errors import HdNetError
from hdnet.report import json_plain
from hdnet.results import SITE_COLUMNS, Site
from lidarsim.location import dataset_key, has_manifest
from lidarsim.shards import MANIFEST_KIND_MOSAICS, MANIFEST_NAME, ManifestJson, iter_descents, read_manifest

RECORD_NAME = "descend.json"
TIMING_STEPS = ("registration", "mosaic", "map", "sites")  # the seconds recorded per frame


def frame_file(descent: int, frame: int) -> str:
    """The name of one frame's maps (``descent-KKKKK-frame-NN.npz``)."""
    return f"descent-{descent:05d}-frame-{frame:02d}.npz"


def track_file(descent: int) -> str:
    """The name of one descent's site track (``descent-KKKKK-track.geojson``)."""
    return f"descent-{descent:05d}-track.geojson"


def is_descend_file(name: str) -> bool:
    """True for the names of the files ``hd descend`` writes (its output's own files)."""
    if name == RECORD_NAME:
        return True
    head, _, tail = name.partition("-")
    parts = tail.split("-")
    return head == "descent" and len(parts) >= 2 and parts[0].isdigit() and name.endswith((".npz", ".geojson"))


@dataclass
class DescendResult:
    """What :func:`descend` flew and wrote (``descend.json`` holds ``record``)."""

    out_dir: Path
    descents: dict[int, list[FrameStep]] = field(repr=False)
    record: dict[str, object] = field(repr=False)

    def summary(self) -> list[str]:
        """One line per descent (frames, diverts, final aim, median seconds per frame) and where the files are."""
        lines = []
        for index, steps in self.descents.items():
            totals = [s.timing.total_s for s in steps]
            diverts = [s.divert for s in steps if s.divert is not None]
            aim = steps[-1].aim
            final = (
                f"final site ({aim.x:.1f}, {aim.y:.1f}) m from the target, P(safe) {aim.p_safe:.3f}"
                if aim is not None
                else "no site: no lander footprint is safe and certain"
            )
            moved = f" ({', '.join(f'{d.distance_m:.1f} m after frame {d.frame}' for d in diverts)})" if diverts else ""
            lines.append(
                f"descent {index}: {len(steps)} frames, {len(diverts)} divert(s){moved}; {final}; "
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
            _write_descent(tmp, index, steps)
            if progress:
                progress(frames_per_descent * len(flown), total)
        record = _record(run, data, sigmas[k], dem, poses, settings, threshold[1], flown, splits)
        record["seconds"] = round(time.perf_counter() - t_start, 3)
        record = json_plain(record)
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


def _write_descent(tmp: Path, index: int, steps: list[FrameStep]) -> None:
    """Step 3: one descent's per-frame maps (``.npz``) and its site track (GeoJSON) into ``tmp``."""
    for step in steps:
        maps = step.maps
        arrays = {spec.field: getattr(maps, spec.field) for spec in MAPS}
        sites = np.array([[s.columns()[c] for c in SITE_COLUMNS] for s in maps.sites], dtype=np.float64)
        with open(tmp / frame_file(index, step.frame), "wb") as f:
            np.savez_compressed(
                f,
                heights_m=step.heights,
                transform=np.array(list(maps.transform)[:6], dtype=np.float64),
                sites=sites.reshape(len(maps.sites), len(SITE_COLUMNS)),
                site_columns=np.array(SITE_COLUMNS),
                **arrays,
            )
    write_json_atomic(tmp / track_file(index), track_geojson(steps), indent=1)


def track_geojson(steps: list[FrameStep]) -> dict[str, object]:
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
    track = {"type": "Feature", "geometry": {"type": "LineString", "coordinates": line}, "properties": {"aim": "track"}}
    return {"type": "FeatureCollection", "features": [*points, track]}


def _aim(site: Site | None) -> dict[str, object] | None:
    return None if site is None else json_plain(site.columns())


def frame_record(step: FrameStep) -> dict[str, object]:
    """One frame's row of ``descend.json``: its seconds per step, its aim, its counts and its divert."""
    t = step.timing
    seconds = (t.registration_s, t.mosaic_s, t.map_s, t.sites_s)
    row: dict[str, object] = {
        "frame": step.frame,
        "altitude_m": round(step.altitude_m, 3),
        "timings_s": {name: round(v, 4) for name, v in zip(TIMING_STEPS, seconds, strict=True)},
        "aim": _aim(step.aim),
        "n_sites": len(step.maps.sites),
        "counts": step.maps.counts,
        "divert": None if step.divert is None else json_plain(dataclasses.asdict(step.divert)),
    }
    if step.registration is not None:
        row["registration_fitness"] = [float(v) for v in step.registration.fitness]
    return row


def _record(
    run: DetectRun,
    data: str | os.PathLike,
    sigma_m: float,
    dem: DemSpec,
    poses: str,
    settings: DescendSettings,
    threshold: dict[str, object] | object,
    flown: dict[int, list[FrameStep]],
    splits: dict[int, str],
) -> dict[str, object]:
    """Step 4: ``descend.json``'s record."""
    descents = []
    for index, steps in flown.items():
        totals = [s.timing.total_s for s in steps]
        descents.append(
            {
                "descent": index,
                "split": splits.get(index),
                "frames": [frame_record(s) for s in steps],
                "diverts": [dataclasses.asdict(s.divert) for s in steps if s.divert is not None],
                "final_site": _aim(steps[-1].aim),
                "median_frame_s": round(float(np.median(totals)), 4),
                "files": [frame_file(index, s.frame) for s in steps] + [track_file(index)],
            }
        )
    return {
        "software": "hd",
        "software_version": __version__,
        "run": {"checkpoint": str(run.checkpoint.resolve()), "dataset": run.recorded_dataset, "labels": run.labels},
        "input": {"dataset": dataset_key(data), "sigma_m": sigma_m, "poses": poses, "dem": dem.to_entry()},
        "settings": dataclasses.asdict(settings),
        "threshold": threshold,
        "frame": "metres east and north of each descent's target, as its newest frame's navigation places it",
        "timing_steps": list(TIMING_STEPS),
        "descents": descents,
    }
