"""A dataset of descent mosaics (``hd mosaic``): one DEM per descent, stored as one "scan" each.

A descent build (``hd build-dataset --descent-frames K``) holds K frames per descent. ``hd mosaic``
turns every descent into one mosaic DEM (``hdlabels.mosaic``) and writes a new dataset in which
each descent is one scan, so that ``hd label`` (either truth), ``hd train``, ``hd eval`` and
``hd detect --data`` work on mosaics exactly as they work on single frames:

* a mosaic "scan" holds the DEM's cell centres (x east, y north, metres from the descent's target)
  with the mosaic's heights: ``points_clean`` the clean mosaic, ``points_noisy[s]`` the mosaic of the
  frames' noisy points at the s-th noise level; NaN where the mosaic has no height. Gridding such
  points on the same grid (any gridding) gives the mosaic back, so the labelling's DEMs *are* the
  mosaics;
* the noisy mosaics are placed by the chosen poses (``true``, ``nav`` or ``registered``; the
  registration runs on each noise level's noisy frames, as a lander registers what it measures);
* the clean mosaic is the clean frames placed with their true relative poses and moved, all
  together, by the lowest frame's navigation error: it lies where the noisy mosaics lie (the
  lowest frame's navigation frame), so the clean-scan truth labels the same ground. Each mosaic's
  ``frame_to_map`` (the inverse of that error) takes it to the true map: the terrain truth reads
  the ground there (``hdlabels.truth``);
* ``origin_map`` is the descent's target; ``sensor_position`` and ``sensor_attitude`` are the lowest
  frame's, as its poses place it; the registration's corrections, fits and each frame's residual to
  the lowest frame are stored per noise level (``lidarsim.shards.MosaicRecord``).

The dataset's files: ``manifest.json`` (kind ``descent-mosaics``, schema 1.3, with its ``mosaic``
record: the source dataset, poses, DEM grid and registration settings), ``mosaics-NNNNN.h5`` (scan
shards of schema 1.4, one per source shard) and ``mosaic-terrain.tif``, a copy of the source's
procedural terrain (a user DTM is recorded by its absolute path, as in the source). Splits are the
descents'. The output is written like every hd output (``hdcore.storage.OutputDir``): staged and
moved into place with the manifest last, so an interrupted run leaves nothing half-written; each
descent mosaicked is kept as it is made (``hdlabels.mosaic_resume``), so that the same call resumes
an interrupted run to the bytes of an uninterrupted one. The same settings over a finished mosaic
dataset leave it as it is; one of other settings, finished or not, is replaced only with
``overwrite``. Noise levels cannot be made on the fly
for a mosaic dataset: its noisy mosaics come from registering noisy frames.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hdcore.bounds import parse_integer
from hdcore.outcome import counted
from hdcore.setting import check, described_as, setting
from hdcore.storage import OutputDir, confine, read_regular_text, write_json_atomic
from hdlabels import mosaic_resume
from hdlabels.errors import HdLabelsError
from hdlabels.grid import cell_centres
from hdlabels.mosaic import (
    ICP_VOXELS_M,
    POSES,
    Mosaic,
    MosaicFrame,
    apply,
    combine_grids,
    descent_frames,
    frame_grids,
    mosaic_frames,
    navigation_error,
    placed_points,
)
from hdlabels.settings import LabelSettings
from hdlabels.store import DemSpec
from lidarsim._version import __version__
from lidarsim.manifest_json import DtmJson, ManifestJson, MosaicJson, ScanShardJson
from lidarsim.parallel import run_tasks
from lidarsim.shards import (
    MANIFEST_KIND_MOSAICS,
    MANIFEST_NAME,
    MANIFEST_SCHEMA,
    MANIFEST_SCHEMA_VERSION_SIZES,
    MOSAIC_ATTR,
    SPLIT_NAMES,
    MosaicRecord,
    Scan,
    ScanShardWriter,
    ShardFormatError,
    open_scan_shard,
    read_manifest,
    scan_schema_version,
    validate_manifest,
)

MOSAIC_SHARD_PREFIX = "mosaics-"
# The copy of a source's own (procedural) terrain in a mosaic dataset.
MOSAIC_TERRAIN_NAME = "mosaic-terrain.tif"
STATUS_RETURN, STATUS_MISS = 0, 1  # lidarsim.scan's codes: a cell with a height, one without


@dataclass(frozen=True)
class MosaicSettings:
    """Settings of ``hd mosaic``, each described once as field metadata (options and checks)."""

    poses: str = setting(
        "registered",
        "How the frames are placed: the navigation estimates corrected by registration to the lowest frame "
        "(registered), the estimates alone (nav), or the true poses (true, the reference)",
        choices=POSES,
    )
    dem_size: int = described_as(LabelSettings, "dem_size")
    dem_spacing_m: float = described_as(LabelSettings, "dem_spacing_m")
    convention: str = described_as(LabelSettings, "convention")
    gridding: str | None = described_as(LabelSettings, "gridding")
    frames: str | None = setting(
        None,
        "Frames of each descent to use: 8 (one frame alone), 4-8, 0,4,8 (frame 0 the highest; the last one "
        "named is the anchor the others are registered to). Default: all",
        kind=str,
        metavar="LIST",
    )

    def __post_init__(self) -> None:
        check(self, HdLabelsError)

    def frame_indices(self, k: int) -> tuple[int, ...]:
        """The frames used of a descent of ``k`` frames, ascending (all of them by default).

        Raises:
            HdLabelsError: indices or ranges outside frames 0 .. k - 1, or an entry that is not a whole
                number (``hdcore.bounds.parse_integer``), naming the list.
        """
        if self.frames is None:
            return tuple(range(k))
        where = f"--frames {self.frames!r}"
        usage = f"use frame indices and ranges of 0..{k - 1}, e.g. {k - 1} or 0,{k // 2},{k - 1}"
        used: set[int] = set()
        for part in self.frames.split(","):
            lo, sep, hi = part.strip().partition("-")
            first = parse_integer(lo, f"{where}: frame", hint=usage, error=HdLabelsError)
            last = parse_integer(hi, f"{where}: frame", hint=usage, error=HdLabelsError) if sep else first
            if not 0 <= first <= last < k:
                raise HdLabelsError(f"{where}: {part.strip()} is not frames of a descent of {k} frames; {usage}")
            used.update(range(first, last + 1))
        return tuple(sorted(used))

    def to_dem_spec(self) -> DemSpec:
        """The mosaic's square grid, centred at the descent's target."""
        return DemSpec.for_convention(self.convention, self.dem_size, self.dem_size, self.dem_spacing_m, self.gridding)


@dataclass(frozen=True)
class DescentMosaics:
    """The mosaics of one descent, as one mosaic dataset scan (see the module docstring).

    Attributes:
        points_clean: float32 (rows, cols, 3) cell centres with the clean mosaic's heights, metres.
        points_noisy: float32 (S, rows, cols, 3) the same for each noise level's mosaic.
        origin_map: (3,) the descent's target, map metres.
        sensor_position: (3,) the lowest frame's sensor in the mosaic frame, metres.
        sensor_attitude: (3, 3) the lowest frame's attitude, as its poses place it.
        record: how the mosaics were placed.
    """

    points_clean: np.ndarray
    points_noisy: np.ndarray
    origin_map: np.ndarray
    sensor_position: np.ndarray
    sensor_attitude: np.ndarray
    record: MosaicRecord

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Every array, by name (the record's fields flat beside the mosaics: ``DESCENT_ARRAYS``)."""
        plain = {name: getattr(self, name) for name in DESCENT_ARRAYS[:5]}
        return {**plain, **{k: np.asarray(v) for k, v in asdict(self.record).items()}}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> DescentMosaics:
        """The mosaics of :meth:`to_arrays`' arrays."""
        record = MosaicRecord(**{name: arrays[name] for name in DESCENT_ARRAYS[5:]})
        return cls(**{name: arrays[name] for name in DESCENT_ARRAYS[:5]}, record=record)


# A descent's arrays as a resumed run keeps them (``hdlabels.mosaic_resume``): the mosaics, then the record.
DESCENT_ARRAYS = (
    "points_clean",
    "points_noisy",
    "origin_map",
    "sensor_position",
    "sensor_attitude",
    "frame_to_map",
    "registration_correction",
    "registration_fitness",
    "registration_rmse_m",
    "frame_residual_m",
)


def in_mosaic_frame(transform: np.ndarray, target_map: np.ndarray) -> np.ndarray:
    """A map transform (4 x 4, metres) as it acts on points given relative to ``target_map``."""
    shift = np.eye(4)
    shift[:3, 3] = np.asarray(target_map, dtype=np.float64)
    back = np.eye(4)
    back[:3, 3] = -shift[:3, 3]
    return back @ transform @ shift


def cell_points(heights: np.ndarray, spacing_m: float) -> np.ndarray:
    """A DEM as an organised point cloud: float32 (rows, cols, 3) cell centres (x east, y north,
    metres from the grid's centre) with their heights; all three NaN where the height is."""
    rows, cols = heights.shape
    xc, yc = cell_centres((rows, cols), spacing_m)
    points = np.empty((rows, cols, 3), dtype=np.float32)
    points[..., 0] = xc[None, :]
    points[..., 1] = yc[:, None]
    points[..., 2] = heights
    points[~np.isfinite(heights)] = np.nan
    return points


def clean_mosaic(frames: list[MosaicFrame], target_map: np.ndarray, dem: DemSpec, error: np.ndarray) -> np.ndarray:
    """The clean mosaic: the clean frames with their true relative poses, all moved by ``error`` (the
    lowest frame's navigation error, a 4 x 4 map transform; the identity for the true poses), gridded
    and combined as every mosaic is (float32 metres)."""
    placed = [placed_points(f, target_map, "true") for f in frames]
    if not np.array_equal(error, np.eye(4)):
        moved = in_mosaic_frame(error, target_map)
        placed = [apply(moved, p) for p in placed]
    return combine_grids(*frame_grids(placed, dem), dem.spacing_m)


def descent_mosaics(scans: list[Scan], dem: DemSpec, poses: str) -> DescentMosaics:
    """The clean mosaic and one mosaic per stored noise level of one descent's frames.

    Raises:
        HdLabelsError: a scan without its descent record, or frames that cannot be placed or registered.
    """
    clean, target = descent_frames(scans, None)
    anchor = clean[-1]
    error = np.eye(4) if poses == "true" else navigation_error(anchor)
    heights_clean = clean_mosaic(clean, target, dem, error)
    n_sigma, k = scans[0].points_noisy.shape[0], len(scans)
    correction = np.tile(np.eye(4), (n_sigma, k, 1, 1))
    fitness, rmse, residual = np.ones((n_sigma, k)), np.zeros((n_sigma, k)), np.zeros((n_sigma, k))
    noisy = np.empty((n_sigma, dem.rows, dem.cols, 3), dtype=np.float32)
    for s in range(n_sigma):
        frames, _ = descent_frames(scans, s)
        mosaic: Mosaic = mosaic_frames(frames, target, dem, poses)  # type: ignore[arg-type]  # checked by MosaicSettings
        noisy[s] = cell_points(mosaic.heights, dem.spacing_m)
        residual[s] = mosaic.frame_residual_m
        if mosaic.registration is not None:
            correction[s] = mosaic.registration.corrections
            fitness[s], rmse[s] = mosaic.registration.fitness, mosaic.registration.rmse_m
    use_nav = poses != "true"
    position = anchor.nav_sensor_position if use_nav else anchor.sensor_position
    return DescentMosaics(
        points_clean=cell_points(heights_clean, dem.spacing_m),
        points_noisy=noisy,
        origin_map=target,
        sensor_position=anchor.origin_map + position - target,
        sensor_attitude=anchor.nav_attitude if use_nav else anchor.attitude,
        record=MosaicRecord(
            frame_to_map=np.linalg.inv(error) if use_nav else np.eye(4),
            registration_correction=correction,
            registration_fitness=fitness,
            registration_rmse_m=rmse,
            frame_residual_m=residual,
        ),
    )


@dataclass(frozen=True)
class MosaicTask:
    """Mosaic every descent of one source shard into one mosaic shard."""

    source: str  # the source dataset directory
    entry: ScanShardJson  # the source shard's manifest entry
    out_file: str  # where to write the mosaic shard (in the staging directory)
    frames: int  # frames per descent in the source
    used: tuple[int, ...]  # the frames mosaicked, ascending (the last is the anchor)
    poses: str
    dem: DemSpec
    attrs: dict[str, object]  # file attributes of the mosaic shard
    resume_dir: str | None = None  # where each finished descent is kept (``hdlabels.mosaic_resume``)
    fingerprint: str = ""  # the settings' fingerprint the kept descents carry


@dataclass(frozen=True)
class MosaicShardRecord:
    """What one task wrote: the manifest entry of its shard and its registration fit."""

    entry: ScanShardJson
    corrections_m: np.ndarray  # (n_descents, S, K) translation of every frame's correction, metres


def run_mosaic_task(task: MosaicTask) -> MosaicShardRecord:
    """Mosaic one source shard (worker side): read its descents, write the mosaic shard."""
    with open_scan_shard(task.source, task.entry) as reader:
        if not reader.is_descent or len(reader) % task.frames:
            raise HdLabelsError(f"{reader.what}: does not hold whole descents of {task.frames} frames")
        n = len(reader) // task.frames
        sigmas = reader.sigmas_m
        splits = np.zeros(n, dtype=np.uint8)
        moved = np.zeros((n, len(sigmas), len(task.used)))
        first = None
        with ScanShardWriter(Path(task.out_file), n, task.dem.rows, task.dem.cols, sigmas, task.attrs) as writer:
            for d in range(n):
                scans = [reader[d * task.frames + k] for k in range(task.frames)]
                index = _descent_index(scans, reader.what, d * task.frames)
                first = index if first is None else first
                m = _mosaics_of(task, d, index, scans, reader.what)
                finite = np.isfinite(m.points_clean[..., 2])
                splits[d] = SPLIT_NAMES.index(scans[0].split)
                writer.write_scan(
                    d,
                    index,
                    int(splits[d]),
                    m.origin_map,
                    m.sensor_position,
                    m.sensor_attitude,
                    m.points_clean,
                    m.points_noisy,
                    np.where(finite, STATUS_RETURN, STATUS_MISS).astype(np.uint8),
                    finite.astype(np.uint8),
                    mosaic=m.record,
                )
                moved[d] = np.linalg.norm(m.record.registration_correction[..., :3, 3], axis=-1)
            sha256 = writer.commit()
    counts = {name: int((splits == i).sum()) for i, name in enumerate(SPLIT_NAMES)}
    present = [name for name, c in counts.items() if c]
    entry: ScanShardJson = {
        "path": Path(task.out_file).name,
        "sha256": sha256,
        "size_bytes": Path(task.out_file).stat().st_size,
        "n_scans": n,
        "first_scan": int(first or 0),
        "split": present[0] if len(present) == 1 else "mixed",
        "split_counts": counts,
        "schema": "hd.lidar-scans",
        "schema_version": scan_schema_version(task.attrs),
    }
    return MosaicShardRecord(entry, moved)


def _mosaics_of(task: MosaicTask, row: int, index: int, scans: list[Scan], what: str) -> DescentMosaics:
    """The mosaics of the descent at ``row`` of the task's shard: kept by an earlier run of the same
    settings, else made (and kept, with a resume directory)."""
    kept_at = None if task.resume_dir is None else mosaic_resume.descent_path(task.resume_dir, task.out_file, row)
    if kept_at is not None:
        kept = mosaic_resume.load_descent(kept_at, task.fingerprint, ("descent_index", *DESCENT_ARRAYS))
        if kept is not None and int(kept["descent_index"]) == index:
            return DescentMosaics.from_arrays(kept)
    try:
        m = descent_mosaics([scans[k] for k in task.used], task.dem, task.poses)
    except HdLabelsError as exc:
        raise HdLabelsError(f"{what} descent {index}: {exc}") from exc
    if kept_at is not None:
        mosaic_resume.save_descent(kept_at, task.fingerprint, {"descent_index": np.asarray(index), **m.to_arrays()})
    return m


def _descent_index(scans: list[Scan], what: str, row: int) -> int:
    """The descent index of K scans that are frames 0..K-1 of one descent in one split."""
    first = scans[0].descent
    ok = first is not None and all(
        s.descent is not None
        and s.descent.frame_index == k
        and s.descent.descent_index == first.descent_index
        and s.split == scans[0].split
        for k, s in enumerate(scans)
    )
    if not ok or first is None:
        raise HdLabelsError(f"{what}: scans {row} to {row + len(scans) - 1} are not one descent's frames in order")
    return int(first.descent_index)


@dataclass(frozen=True)
class MosaicSummary:
    """What ``mosaic_dataset`` did."""

    out: str
    poses: str
    n_mosaics: int
    descent_frames: int
    frames: tuple[int, ...]  # the frames used
    n_shards: int
    sigmas_m: tuple[float, ...]
    splits: dict[str, int]
    coverage: float  # mean fraction of the DEM's cells with a clean mosaic height
    median_correction_m: float | None  # registered poses: median translation of the frames' corrections
    seconds: float
    resumed_descents: int = 0  # descents an interrupted run of the same settings had mosaicked already
    already_done: bool = False  # ``out`` held this mosaic dataset already: nothing was written

    def paragraph(self) -> str:
        if self.already_done:
            return (
                f"{self.out} already holds this mosaic dataset, made with the same settings "
                f"({counted(self.n_mosaics, 'mosaic')} in {counted(self.n_shards, 'shard')}): nothing to do "
                "(--overwrite makes it again)"
            )
        kept = f" ({counted(self.resumed_descents, 'descent')} kept from the interrupted run)"
        reg = (
            f"; registration moved the frames by {self.median_correction_m * 100:.0f} cm (median)"
            if self.median_correction_m is not None
            else ""
        )
        split = ", ".join(f"{v} {k}" for k, v in self.splits.items())
        used = "" if len(self.frames) == self.descent_frames else f", frames {','.join(map(str, self.frames))}"
        return (
            f"Mosaicked {counted(self.n_mosaics, 'descent')} of {self.descent_frames} frames{used} "
            f"({self.poses} poses) into {counted(self.n_shards, 'shard')} at {self.out} in {self.seconds:.1f} s"
            f"{kept if self.resumed_descents else ''}: "
            f"clean mosaics plus {counted(len(self.sigmas_m), 'noise level')}; splits {split}; "
            f"{self.coverage * 100:.1f}% of the DEM cells have a height{reg}. Label it with `hd label {self.out}`."
        )


def is_mosaic_file(name: str) -> bool:
    """Names a mosaic dataset's files take (its output: replaced together with ``overwrite``)."""
    shard = name.startswith(MOSAIC_SHARD_PREFIX) and name.endswith(".h5")
    return shard or name in (MANIFEST_NAME, MOSAIC_TERRAIN_NAME, mosaic_resume.RESUME_DIR)


def mosaic_dataset(
    source: str | os.PathLike,
    out: str | os.PathLike,
    settings: MosaicSettings = MosaicSettings(),
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    overwrite: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> MosaicSummary:
    """Write the mosaic dataset of the descent build ``source`` at ``out`` (see the module docstring).

    A run killed part-way is resumed by the same call: the descents it mosaicked are kept
    (``hdlabels.mosaic_resume``) and the output has the bytes of an uninterrupted run. ``out``
    holding this mosaic dataset already (the same settings and source, every shard present) is
    left as it is (``already_done`` in the summary).

    Raises:
        HdLabelsError: ``source`` is not a descent build; a descent that cannot be mosaicked.
        StorageError / OutputExistsError: ``out`` is unusable, is the source, holds anything but
            an earlier mosaic dataset, or a mosaic dataset (finished or not) of other settings
            (replaced only with ``overwrite``).
    """
    t0 = time.perf_counter()
    root, manifest, frames = _descent_build(source)
    dem = settings.to_dem_spec()
    used = settings.frame_indices(frames)
    inputs: dict[str, str | os.PathLike | None] = {"the descent build": root}
    output = OutputDir(out, what="mosaic", marker=MANIFEST_NAME, owns=is_mosaic_file, inputs=inputs)
    out_dir = output.check_place()
    attrs = _file_attrs(manifest, settings, dem, used)
    record = _mosaic_record(manifest, settings, dem, frames, used, str(root))
    fingerprint = mosaic_resume.settings_fingerprint(record, attrs)
    if not overwrite and (done := _finished_identical(out_dir, record)) is not None:
        return _summary(out_dir, settings, frames, used, done, time.perf_counter() - t0, 0, already_done=True)
    resuming = mosaic_resume.resumable(out_dir, fingerprint, record, overwrite)
    # An unfinished run of these settings (no manifest yet) is resumed without --overwrite.
    replace = overwrite or (resuming and not os.path.lexists(out_dir / MANIFEST_NAME))
    output.check(replace)
    with output.open(replace) as staging:
        resume_dir = mosaic_resume.start(out_dir, fingerprint, record)
        kept = mosaic_resume.kept_descents(out_dir)
        tasks = [
            MosaicTask(
                str(root), entry, str(staging / _shard_name(i)), frames, used, settings.poses, dem, attrs,
                resume_dir=str(resume_dir), fingerprint=fingerprint,
            )
            for i, entry in enumerate(manifest["shards"])
        ]  # fmt: skip
        try:
            records = _run_mosaic_tasks(tasks, int(manifest["n_descents"]), workers, scheduler, progress)
        except BaseException:
            if mosaic_resume.kept_descents(out_dir) == 0:
                mosaic_resume.discard(out_dir)  # nothing to resume: the directory is left as it was
            raise
        dtm = _terrain_entry(root, manifest, staging)
        new = _manifest(manifest, record, records, dtm)
        write_json_atomic(staging / MANIFEST_NAME, new)
        mosaic_resume.discard(out_dir)  # the output is whole in staging; the commit only renames
        output.commit()
    return _summary(out_dir, settings, frames, used, new, time.perf_counter() - t0, kept)


def _descent_build(source: str | os.PathLike) -> tuple[Path, ManifestJson, int]:
    """Step 1: the source's absolute path, manifest and frames per descent.

    Raises:
        HdLabelsError: a mosaic dataset, or a build that is no descent build.
    """
    root = Path(source).resolve()
    manifest = read_manifest(root)
    frames = manifest.get("descent_frames")
    if manifest.get("kind") == MANIFEST_KIND_MOSAICS:
        raise HdLabelsError(f"{root}: already a mosaic dataset; hd mosaic reads a descent build (--descent-frames)")
    if not isinstance(frames, int):
        raise HdLabelsError(
            f"{root}: not a descent build (its manifest records no descent_frames); build one with "
            "`hd build-dataset --descent-frames K`"
        )
    return root, manifest, frames


def _finished_identical(out_dir: Path, record: Mapping[str, object]) -> ManifestJson | None:
    """Step 2: the manifest of a finished mosaic dataset in ``out_dir`` of exactly these settings (its
    ``mosaic`` record, the source's shards by sha256 included) with every file present, else None."""
    try:
        raw = json.loads(read_regular_text(out_dir / MANIFEST_NAME))
        manifest = validate_manifest(raw, str(out_dir / MANIFEST_NAME))
    except (ValueError, RecursionError, ShardFormatError):  # StorageError is a ValueError
        return None
    if manifest.get("kind") != MANIFEST_KIND_MOSAICS or manifest.get("mosaic") != json.loads(json.dumps(record)):
        return None
    path = manifest.get("dtm", {}).get("path")
    files = [e["path"] for e in manifest["shards"]] + ([path] if path == MOSAIC_TERRAIN_NAME else [])
    return manifest if all((out_dir / name).is_file() for name in files) else None


def _run_mosaic_tasks(
    tasks: list[MosaicTask],
    total: int,
    workers: int | None,
    scheduler: str | None,
    progress: Callable[[int, int], None] | None,
) -> dict[int, MosaicShardRecord]:
    """Step 3: every shard mosaicked (by position), ``progress`` told the descents done."""
    records: dict[int, MosaicShardRecord] = {}
    n_workers = max(1, workers if workers is not None else (os.cpu_count() or 1))
    done = 0
    if progress:
        progress(0, total)
    for position, rec in run_tasks(run_mosaic_task, tasks, n_workers, scheduler):
        records[position] = rec
        done += int(rec.entry["n_scans"])
        if progress:
            progress(done, total)
    return records


def _summary(
    out_dir: Path,
    settings: MosaicSettings,
    frames: int,
    used: tuple[int, ...],
    manifest: ManifestJson,
    seconds: float,
    resumed: int,
    already_done: bool = False,
) -> MosaicSummary:
    """Step 4: what was made, read from the output's shards (coverage and registration corrections)."""
    coverage, moved = _coverage(out_dir, manifest)
    moved = moved[moved > 0]
    return MosaicSummary(
        out=str(out_dir),
        poses=settings.poses,
        n_mosaics=int(manifest["n_scans"]),
        descent_frames=frames,
        frames=used,
        n_shards=len(manifest["shards"]),
        sigmas_m=tuple(float(s) for s in manifest["sigmas_m"]),
        splits=dict(manifest["splits"]),
        coverage=coverage,
        median_correction_m=float(np.median(moved)) if settings.poses == "registered" and moved.size else None,
        seconds=seconds,
        resumed_descents=resumed,
        already_done=already_done,
    )


def _shard_name(index: int) -> str:
    return f"{MOSAIC_SHARD_PREFIX}{index:05d}.h5"


def _file_attrs(
    manifest: ManifestJson, settings: MosaicSettings, dem: DemSpec, used: tuple[int, ...]
) -> dict[str, Any]:
    """The mosaic shards' file attributes: the source's seed and the mosaic's settings (schema 1.4)."""
    return {
        "seed": int(manifest.get("seed", 0)),
        MOSAIC_ATTR: settings.poses,
        "mosaic_frames": len(used),
        "mosaic_frame_indices": np.asarray(used, dtype=np.int64),
        "mosaic_anchor_frame": used[-1],
        **{f"mosaic_{k}": v for k, v in dem.to_attrs().items()},
        "mosaic_icp_voxels_m": np.asarray(ICP_VOXELS_M, dtype=np.float64),
        "mosaic_frame_weight": "returns per square metre (1 / sample spacing squared)",
    }


def _terrain_entry(root: Path, manifest: ManifestJson, staging: Path) -> DtmJson:
    """The source's ``dtm`` entry for the mosaic dataset: a DTM inside the source (its procedural
    terrain) is copied beside the mosaics (hard-linked where the file system allows); a user's DTM
    keeps its absolute path."""
    dtm: DtmJson = {**manifest.get("dtm", {})}
    path = dtm.get("path")
    if not isinstance(path, str) or os.path.isabs(path):
        return dtm
    src = confine(root, path)
    try:
        os.link(src, staging / MOSAIC_TERRAIN_NAME)
    except OSError:
        shutil.copyfile(src, staging / MOSAIC_TERRAIN_NAME)
    return dtm | {"path": MOSAIC_TERRAIN_NAME, "size_bytes": (staging / MOSAIC_TERRAIN_NAME).stat().st_size}


def _mosaic_record(
    source: ManifestJson,
    settings: MosaicSettings,
    dem: DemSpec,
    frames: int,
    used: tuple[int, ...],
    source_dir: str,
) -> MosaicJson:
    """The manifest's ``mosaic`` record: the source (by its shards' sha256) and the settings."""
    return {
        "source": {
            "path": source_dir,
            "n_descents": source["n_descents"],
            "descent_frames": frames,
            "config_sha256": source.get("config_sha256"),
            "shards_sha256": [s["sha256"] for s in source["shards"]],
        },
        "poses": settings.poses,
        "frames": list(used),
        "anchor_frame": used[-1],
        "dem": dem.to_entry(),
        "icp_voxels_m": list(ICP_VOXELS_M),
    }


def _manifest(
    source: ManifestJson,
    record: MosaicJson,
    records: dict[int, MosaicShardRecord],
    dtm: DtmJson,
) -> ManifestJson:
    shards = [records[i].entry for i in sorted(records)]
    splits = {name: sum(int(s["split_counts"][name]) for s in shards) for name in SPLIT_NAMES}
    return {
        "schema": MANIFEST_SCHEMA,
        "schema_version": MANIFEST_SCHEMA_VERSION_SIZES,
        "kind": MANIFEST_KIND_MOSAICS,
        "software": "hd",
        "software_version": __version__,
        "n_scans": sum(int(s["n_scans"]) for s in shards),
        "sigmas_m": list(source["sigmas_m"]),
        "seed": source.get("seed", 0),
        "config_sha256": source.get("config_sha256"),
        "config": source["config"],  # every scan build records it
        "dtm": dtm,
        "mosaic": record,
        "splits": splits,
        "shards": shards,
        "labelings": [],
    }


def _coverage(out_dir: Path, manifest: ManifestJson) -> tuple[float, np.ndarray]:
    """Mean fraction of DEM cells with a clean mosaic height, and every frame's registration
    correction (translation, metres; zero where none was applied)."""
    valid = cells = 0
    moved = [np.zeros(0)]
    for entry in manifest["shards"]:
        with open_scan_shard(out_dir, entry) as reader:
            v = reader.h5["valid"][:]
            valid += int(v.sum())
            cells += v.size
            moved.append(np.linalg.norm(reader.h5["registration_correction"][:][..., :3, 3], axis=-1).ravel())
    return valid / max(1, cells), np.concatenate(moved)


def mosaic_dem_entry(manifest: ManifestJson) -> Mapping[str, object] | None:
    """The DEM grid a mosaic dataset was made on (its manifest's ``mosaic.dem``: empty when the record
    lacks it), None for a scan dataset."""
    if manifest.get("kind") != MANIFEST_KIND_MOSAICS:
        return None
    mosaic: object = manifest.get("mosaic")
    dem = mosaic.get("dem") if isinstance(mosaic, dict) else None
    return dem if isinstance(dem, dict) else {}


def check_mosaic_grid(manifest: ManifestJson, dem: DemSpec, where: str) -> None:
    """Refuse to grid a mosaic dataset on another grid than its own (its points are its cells' centres).

    Raises:
        HdLabelsError: another DEM side or spacing, naming both.
    """
    entry = mosaic_dem_entry(manifest)
    if entry is None:
        return
    own = (entry.get("rows"), entry.get("cols"), entry.get("spacing_m"))
    if own != (dem.rows, dem.cols, dem.spacing_m):
        raise HdLabelsError(
            f"{where} is a mosaic dataset made on {own[0]} x {own[1]} cells of {own[2]} m; its points are those "
            f"cells' centres, so it is labelled on that grid only (asked: {dem.rows} x {dem.cols} cells of "
            f"{dem.spacing_m:g} m; pass --dem-size {own[0]} --dem-spacing {own[2]})"
        )
