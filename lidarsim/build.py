"""Dataset factory: plan the scans, run shard tasks (process pool or Dask), write the manifest.

A build directory holds ``manifest.json`` (only once the build is complete), ``shards/`` and,
for the procedural terrain, ``terrain/``. While a build runs, ``.hd-build.json`` records its
settings and ``.hd-lock`` holds the writer lock (one build or labelling per directory at a time);
re-running the same command after an interruption finishes only the missing shards and ends with
the same files as an uninterrupted run.

Every option and the output path are checked before anything is written (the procedural terrain
is generated and planned in memory); a failed build removes its partial files, and a build that
created its directory and completed no shard removes the directory too (docs/reliability.md).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import time
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from hdcore.errors import HdWarning, OutputExistsError
from hdcore.outcome import counted
from hdcore.storage import (
    LOCK_NAME,
    PARTIAL_MARK,
    OutputTransaction,
    StorageError,
    attr_int,
    check_h5_data,
    check_not_input,
    check_output_dir,
    first_missing,
    make_subdir,
    read_regular_text,
    sha256_bytes,
    write_bytes_atomic,
)
from lidarsim import defaults, limits
from lidarsim._version import __version__
from lidarsim.base_relief import rocks_on_base, rocky_geotiff_bytes
from lidarsim.errors import LidarsimError
from lidarsim.footprint import FootprintConfig
from lidarsim.manifest_json import BuildConfigJson, DtmJson, ManifestJson, RecipeDeviationJson, ScanShardJson
from lidarsim.navigation import DescentNavErrors, descent_nav_errors
from lidarsim.noise import NoiseModel
from lidarsim.parallel import probe_scheduler, run_tasks
from lidarsim.procedural import MarsTerrainParams, generate_mars_terrain, geotiff_bytes, terrain_tags
from lidarsim.scan import (
    STATUS_DAMAGED,
    STATUS_DEAD,
    STATUS_RETURN,
    STATUS_WEAK,
    ScanGeometry,
    TileScene,
    scan_geometry,
    simulate_scans,
)
from lidarsim.sensor import SensorConfig, corner_directions
from lidarsim.shards import (
    BUILD_STATE_NAME,
    MANIFEST_KIND_SCANS,
    MANIFEST_NAME,
    MANIFEST_SCHEMA,
    MANIFEST_SCHEMA_VERSION_SIZES,
    SCAN_SCHEMA,
    SCAN_SCHEMA_VERSION_PLAIN,
    SPLIT_NAMES,
    DescentFrame,
    ScanShardReader,
    ScanShardWriter,
    ShardFormatError,
    remove_partials,
    scan_schema_version,
    sha256_file,
    validate_manifest,
    write_json_atomic,
)
from lidarsim.streams import Purpose, stream
from lidarsim.terrain import DTM, dtm_sha256
from lidarsim.trajectory import ScanPlan, TrajectoryConfig, plan_scans
from lidarsim.weak_inputs import coarse_dtm_message, overlap_message, split_overlap

SHARD_DIR = "shards"
TERRAIN_DIR = "terrain"
# Scans grouped into one ray-casting call (16 x 128 x 128 rays).
CAST_BATCH_SCANS = 16
# Cell of the coarse validity grid used for trajectory planning, metres (at least one DTM cell).
OVERVIEW_CELL_M = 2.0


@dataclass(frozen=True)
class BuildConfig:
    """Everything that determines the content of a dataset (workers and scheduler do not).

    Attributes:
        sigmas_m: noise levels (1-sigma along each ray), metres.
        seed: master seed of every random stream.
        sensor: the detector.
        trajectory: scan count, altitude, tilt, jitter.
        dtm_path: DTM file; None builds on the procedural Mars terrain.
        dtm_scale: resampling factor of the DTM (1 = full resolution).
        terrain: parameters of the procedural terrain (used when ``dtm_path`` is None; with
            ``rocks_on_dtm``, its rock population).
        rocks_on_dtm: scan the DTM at ``dtm_path`` resampled to ``terrain.spacing_m`` with the
            procedural rock population of ``terrain`` and ``seed`` added (``lidarsim.base_relief``);
            the terrain made is written to ``terrain/``.
        shard_size: scans per shard file (a descent build's shards hold whole descents: see
            ``scans_per_shard``).
        compression: HDF5 compression of the point arrays: gzip, lzf or none.
        footprint: the pixel footprint (sub-rays, spot profile, range estimator); the default is
            one ray through each pixel centre.
        noise_model: how the range noise depends on the returned signal; the default is the
            paper's constant sigma.
    """

    sigmas_m: tuple[float, ...] = (defaults.DEFAULT_SIGMA_M,)
    seed: int = defaults.SEED
    sensor: SensorConfig = field(default_factory=SensorConfig)
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    dtm_path: str | None = None
    dtm_scale: float = defaults.DTM_SCALE
    terrain: MarsTerrainParams = field(default_factory=MarsTerrainParams)
    shard_size: int = defaults.SHARD_SIZE
    compression: str = defaults.COMPRESSION
    rocks_on_dtm: bool = False
    footprint: FootprintConfig = field(default_factory=FootprintConfig)
    noise_model: NoiseModel = field(default_factory=NoiseModel)

    def __post_init__(self) -> None:
        if not self.sigmas_m:
            raise LidarsimError("at least one --sigma is needed")
        for s in self.sigmas_m:
            if not (isinstance(s, (int, float)) and limits.SIGMA_M.contains(s)):
                raise LidarsimError(
                    f"--sigma must be a number of metres in {limits.SIGMA_M.interval()}, got {s} ({limits.SIGMA_HINT})"
                )
        if len(set(self.sigmas_m)) != len(self.sigmas_m):
            raise LidarsimError(f"--sigma values must be distinct, got {list(self.sigmas_m)}")
        if not limits.SEED.contains(self.seed):
            raise LidarsimError(f"--seed must be in {limits.SEED.interval()}, got {self.seed}")
        if not limits.SHARD_SIZE.contains(self.shard_size):
            raise LidarsimError(f"shard size must be in {limits.SHARD_SIZE.interval()}, got {self.shard_size}")
        if self.rocks_on_dtm and (self.dtm_path is None or self.dtm_scale != 1.0):
            raise LidarsimError("rocks on a DTM need a DTM (--dtm) at full resolution (--dtm-scale 1)")
        if not limits.DTM_SCALE.contains(self.dtm_scale):
            raise LidarsimError(f"--dtm-scale must be in {limits.DTM_SCALE.interval()}, got {self.dtm_scale}")
        if self.compression not in defaults.COMPRESSIONS:
            raise LidarsimError(f"unknown compression {self.compression!r}; use {', '.join(defaults.COMPRESSIONS)}")
        per_scan = self.sensor.rows * self.sensor.cols * (4 * 3 * (1 + len(self.sigmas_m)) + 2)
        scans = min(self.scans_per_shard, self.trajectory.n_scans)
        if scans * per_scan > limits.MAX_SHARD_BYTES:
            raise LidarsimError(
                f"a shard of {scans} scans of {self.sensor.rows}x{self.sensor.cols} px at {len(self.sigmas_m)} noise "
                f"level(s) needs {scans * per_scan / 2**30:.1f} GiB in memory (hd's maximum is "
                f"{limits.MAX_SHARD_BYTES / 2**30:.0f} GiB); lower --shard-size to at most "
                f"{max(1, limits.MAX_SHARD_BYTES // per_scan)}"
            )

    @property
    def scans_per_shard(self) -> int:
        """Scans per shard file: ``shard_size``, rounded up to whole descents in a descent build (a
        descent never straddles two shards)."""
        k = self.trajectory.frames
        return -(-self.shard_size // k) * k

    def to_dict(self) -> BuildConfigJson:
        """JSON-friendly dictionary of the whole configuration (``docs/shard-format.md``)."""
        d = asdict(self)
        d["sigmas_m"] = list(self.sigmas_m)
        if self.dtm_path is not None and not self.rocks_on_dtm:
            d["terrain"] = None
        if not self.rocks_on_dtm:
            del d["rocks_on_dtm"]  # absent, as before the option existed: published fingerprints hold
        # Likewise the sensor-realism settings: absent at the paper's sensor.
        if self.footprint.is_default:
            del d["footprint"]
        if self.noise_model.is_default:
            del d["noise_model"]
        d["trajectory"] = {k: v for k, v in d["trajectory"].items() if v is not None}
        if self.trajectory.descent is not None:  # the descent's altitudes and approach replace these
            del d["trajectory"]["altitude_m"], d["trajectory"]["tilt_deg"]
        return cast("BuildConfigJson", d)  # asdict's keys, as BuildConfigJson lists them

    @property
    def realism_attrs(self) -> dict[str, object]:
        """The scan shards' attributes of the sensor-realism settings (none at the paper's sensor)."""
        attrs: dict[str, object] = {}
        if not self.footprint.is_default:
            attrs.update(self.footprint.to_attrs())
        if not self.noise_model.is_default:
            attrs.update(self.noise_model.to_attrs())
        return attrs

    def canonical_dict(self) -> BuildConfigJson:
        """``to_dict`` with the DTM named by its file name instead of the path it was read from, so
        that the same recipe gives the same settings wherever the checkout or the DTM lies (the
        settings hash and the shards' ``config_json``). The DTM's content is checked apart from the
        settings: every shard records its ``dtm_sha256`` and is made again when the DTM changed, and
        a recipe names its DTM by sha256."""
        d = self.to_dict()
        if self.dtm_path is not None:
            d["dtm_path"] = Path(self.dtm_path).name
        return d

    def fingerprint(self) -> str:
        """SHA-256 of the canonical JSON of the configuration (the DTM by its file name)."""
        return sha256_bytes(json.dumps(self.canonical_dict(), sort_keys=True).encode())


@dataclass(frozen=True)
class ShardTask:
    """One shard's work: scans ``first_scan .. first_scan + n - 1`` of the plan (``nadir_xy`` and
    ``tile_ij`` one row per scan: in a descent build each frame's row is its descent's target)."""

    out_dir: str
    shard_index: int
    first_scan: int
    nadir_xy: np.ndarray
    tile_ij: np.ndarray
    splits: np.ndarray
    dtm_path: str
    config: BuildConfig
    plan_half_width_m: float
    tile_anchor_xy: tuple[float, float]
    tile_m: float
    file_attrs: dict[str, object]
    n_threads: int = 0

    @property
    def path(self) -> Path:
        return Path(self.out_dir) / SHARD_DIR / shard_name(self.shard_index)


@dataclass(frozen=True)
class ShardRecord:
    """What the manifest says of a finished shard."""

    path: str
    sha256: str
    n_scans: int
    first_scan: int
    split: str
    split_counts: dict[str, int]
    schema_version: str = SCAN_SCHEMA_VERSION_PLAIN
    size_bytes: int = 0

    def to_dict(self) -> ScanShardJson:
        """The manifest's entry of the shard."""
        return {
            "path": self.path,
            "sha256": self.sha256,
            "size_bytes": self.size_bytes,
            "n_scans": self.n_scans,
            "first_scan": self.first_scan,
            "split": self.split,
            "split_counts": dict(self.split_counts),
            "schema": SCAN_SCHEMA,
            "schema_version": self.schema_version,
        }


@dataclass(frozen=True)
class BuildSummary:
    """Result of a build."""

    out_dir: Path
    n_scans: int
    n_shards: int
    sigmas_m: tuple[float, ...]
    split_counts: dict[str, int]
    seconds: float
    resumed_shards: int
    bytes_written: int
    rays_per_second: float
    already_built: bool = False
    n_descents: int = 0
    descent_frames: int = 0

    def paragraph(self) -> str:
        """A one-paragraph human summary."""
        sig = ", ".join(f"{s * 100:.2f} cm" for s in self.sigmas_m)
        splits = ", ".join(f"{self.split_counts.get(k, 0)} {k}" for k in SPLIT_NAMES)
        if self.already_built:
            return (
                f"{self.out_dir} already holds this dataset, built with the same settings ({self.n_scans} scans in "
                f"{counted(self.n_shards, 'shard')}, sigma = {sig}; splits {splits}): nothing to do. Check it with "
                f"`hd verify {self.out_dir}`; pass --overwrite to build it again."
            )
        kept = "was" if self.resumed_shards == 1 else "were"
        resumed = (
            f" ({counted(self.resumed_shards, 'shard')} {kept} already complete and kept)"
            if self.resumed_shards
            else ""
        )
        descents = ""
        if self.n_descents:
            descents = f" ({counted(self.n_descents, 'descent')} of {self.descent_frames} frames)"
        return (
            f"Built {self.n_scans} scans{descents} in {counted(self.n_shards, 'shard')} at {self.out_dir} in "
            f"{self.seconds:.1f} s"
            f"{resumed}: clean points plus noisy points at sigma = {sig}; splits {splits}; "
            f"{self.bytes_written / 1e6:.0f} MB on disk; {self.rays_per_second / 1e6:.2f} M rays/s end to end. "
            f"Inspect it with `hd inspect {self.out_dir}`, check it with `hd verify {self.out_dir}`."
        )


def shard_name(index: int) -> str:
    """File name of scan shard ``index``."""
    return f"scans-{index:05d}.h5"


def split_block_size(n_scans: int) -> int:
    """Scans per split block: consecutive scans share a split (at most 50, about 20 blocks)."""
    return max(1, min(50, n_scans // 20))


def scan_splits(config: BuildConfig) -> np.ndarray:
    """Split of every scan of a build: :func:`assign_splits` over its scans or, in a descent build,
    over its descents (consecutive descents form the blocks), every frame taking its descent's."""
    trajectory = config.trajectory
    return np.repeat(assign_splits(trajectory.n_positions, config.seed), trajectory.frames)


def assign_splits(
    n_scans: int, seed: int, fractions: tuple[float, float, float] = defaults.SPLIT_FRACTIONS
) -> np.ndarray:
    """Split of every scan: 0 train, 1 val, 2 test.

    Consecutive scans along the trajectory form blocks (``split_block_size``); blocks, not scans,
    are shuffled into the splits with the given fractions (the paper's 800/100/100 for 1000
    scans). Neighbouring scans overlap on the ground, so block splits keep test terrain apart
    from training terrain better than a per-scan shuffle. Independent of shard size and workers.
    """
    block = split_block_size(n_scans)
    n_blocks = math.ceil(n_scans / block)
    n_val = int(round(fractions[1] * n_blocks))
    n_test = int(round(fractions[2] * n_blocks))
    if n_blocks >= 3:
        n_val, n_test = max(1, n_val), max(1, n_test)
    labels = np.zeros(n_blocks, dtype=np.uint8)
    labels[n_blocks - n_val - n_test : n_blocks - n_test] = 1
    labels[n_blocks - n_test :] = 2
    labels = labels[stream(seed, Purpose.SPLIT).permutation(n_blocks)]
    return np.repeat(labels, block)[:n_scans]


def run_shard(task: ShardTask) -> ShardRecord:
    """Simulate and write one shard (runs in a worker process or on a Dask worker)."""
    cfg = task.config
    n = task.nadir_xy.shape[0]
    footprint_hw = task.plan_half_width_m - cfg.trajectory.margin_m
    half_extent = task.tile_m / 2.0 + task.plan_half_width_m
    task.path.parent.mkdir(parents=True, exist_ok=True)
    writer = ScanShardWriter(
        path=task.path,
        n_scans=n,
        rows=cfg.sensor.rows,
        cols=cfg.sensor.cols,
        sigmas_m=cfg.sigmas_m,
        attrs={**task.file_attrs, "shard_index": task.shard_index, "first_scan": task.first_scan},
        compression=cfg.compression,
    )
    nav_errors: dict[int, DescentNavErrors] = {}
    realistic = not (cfg.footprint.is_default and cfg.noise_model.is_default)
    with DTM.open(task.dtm_path, scale=cfg.dtm_scale) as dtm, writer:
        k = 0
        for tile, members in _group_by_tile(task.tile_ij):
            scene = _scene_for(dtm, task, tile, half_extent)
            poses = {
                m: scan_geometry(scene, task.nadir_xy[m], task.first_scan + m, cfg.trajectory, footprint_hw, cfg.seed)
                for m in members
            }
            for window, group in _scene_groups(scene, [poses[m] for m in members], cfg.sensor, realistic):
                scene.focus(window, only_hits=len(group) <= CAST_BATCH_SCANS)  # one cast: its hit triangles
                for batch in _batches([members[i] for i in group], CAST_BATCH_SCANS):
                    k += _simulate_and_write(task, scene, batch, [poses[m] for m in batch], writer, nav_errors)
        assert k == n
        digest = writer.commit()
    return _record(task, digest)


def _scene_groups(
    scene: TileScene, geometries: list[ScanGeometry], sensor: SensorConfig, realistic: bool
) -> list[tuple[tuple[int, int, int, int], list[int]]]:
    """The tile's scans grouped by the terrain they can hit (``TileScene.plan``): each scan's reach
    from its detector's corner rays, which bound every ray it casts. A realistic sensor's sub-rays
    (``TileScene.cast_with_incidence``) take the whole window: one group."""
    if not realistic:
        windows = [
            scene.reach((g.origin_map + g.sensor_position)[None, :], corner_directions(sensor, g.attitude)[None])
            for g in geometries
        ]
        return scene.plan(windows)
    return [(scene.full_window, list(range(len(geometries))))]  # incidence is cast against the whole window


def _simulate_and_write(
    task: ShardTask,
    scene: TileScene,
    batch: list[int],
    geoms: list[ScanGeometry],
    writer: ScanShardWriter,
    nav_errors: dict[int, DescentNavErrors],
) -> int:
    """Cast one batch of the shard's scans (positions ``batch`` in the shard) and write them; returns the count."""
    cfg = task.config
    indices = [task.first_scan + m for m in batch]
    results = simulate_scans(
        scene,
        geoms,
        indices,
        cfg.sensor,
        cfg.sigmas_m,
        cfg.seed,
        n_threads=task.n_threads,
        footprint=cfg.footprint,
        noise_model=cfg.noise_model,
    )
    for m, scan_index, result in zip(batch, indices, results, strict=True):
        check_returns(result.status, scan_index, task.dtm_path)
        g = result.geometry
        writer.write_scan(
            m,
            scan_index=scan_index,
            split=int(task.splits[m]),
            origin_map=g.origin_map,
            sensor_position=g.sensor_position,
            sensor_attitude=g.attitude,
            points_clean=result.points_clean,
            points_noisy=result.points_noisy,
            status=result.status,
            valid=((result.status == STATUS_RETURN) | (result.status == STATUS_DAMAGED)).astype(np.uint8),
            noise_scale=result.noise_scale,
            descent=_descent_frame(cfg, scan_index, g, nav_errors),
        )
    return len(batch)


def _descent_frame(
    config: BuildConfig, scan_index: int, geometry: ScanGeometry, cache: dict[int, DescentNavErrors]
) -> DescentFrame | None:
    """A descent frame's record (None for a single scan): its descent and frame, the target (the
    scan frame's origin) and the navigation estimate of its pose; ``cache`` keeps each descent's
    errors for its other frames."""
    descent = config.trajectory.descent
    if descent is None:
        return None
    index, frame = divmod(scan_index, descent.frames)
    errors = cache.get(index)
    if errors is None:
        errors = cache[index] = descent_nav_errors(descent.nav, config.seed, index, descent.frames)
    position, attitude = errors.estimate(frame, geometry.sensor_position, geometry.attitude)
    return DescentFrame(
        descent_index=index,
        frame_index=frame,
        target_map=np.asarray(geometry.origin_map, dtype=np.float64),
        nav_sensor_position=position,
        nav_sensor_attitude=attitude,
    )


def check_returns(status: np.ndarray, scan_index: int, dtm_name: str) -> None:
    """Fail on a (nearly) empty scan: fewer than ``limits.MIN_RETURN_FRACTION`` of its working
    elements hit the terrain, although the planner put its footprint on valid terrain, or came back
    above the noise model's detection threshold.

    Raises:
        LidarsimError: naming the scan and the DTM.
    """
    working = int((status != STATUS_DEAD).sum())
    hits = int(((status == STATUS_RETURN) | (status == STATUS_DAMAGED)).sum())
    weak = int((status == STATUS_WEAK).sum())
    if working and hits < limits.MIN_RETURN_FRACTION * working and hits + weak >= limits.MIN_RETURN_FRACTION * working:
        raise LidarsimError(
            f"scan {scan_index}: only {100.0 * hits / working:.1f}% of the rays came back above the noise model's "
            f"detection threshold ({100.0 * weak / working:.1f}% too weak); lower --snr-min or the altitude, or "
            "raise --snr-ref"
        )
    if working and hits < limits.MIN_RETURN_FRACTION * working:
        raise LidarsimError(
            f"scan {scan_index}: only {100.0 * hits / working:.1f}% of the rays hit the terrain of "
            f"{Path(dtm_name).name} "
            "although its footprint lies on valid cells; the DTM's heights look invalid (check its nodata value "
            "and height range)"
        )


def _record(task: ShardTask, digest: str) -> ShardRecord:
    counts = {name: int((task.splits == i).sum()) for i, name in enumerate(SPLIT_NAMES)}
    present = [name for name, c in counts.items() if c]
    return ShardRecord(
        path=f"{SHARD_DIR}/{shard_name(task.shard_index)}",
        sha256=digest,
        n_scans=int(task.nadir_xy.shape[0]),
        first_scan=task.first_scan,
        split=present[0] if len(present) == 1 else "mixed",
        split_counts=counts,
        schema_version=scan_schema_version(task.file_attrs),
        size_bytes=task.path.stat().st_size,
    )


_SCENE_CACHE: dict[tuple[str, float, int, int, float], TileScene] = {}


def _scene_for(dtm: DTM, task: ShardTask, tile: tuple[int, int], half_extent: float) -> TileScene:
    """The tile's scene, reused by consecutive shards in the same worker process (one kept)."""
    key = (task.dtm_path, task.config.dtm_scale, tile[0], tile[1], half_extent)
    scene = _SCENE_CACHE.get(key)
    if scene is None:
        _SCENE_CACHE.clear()
        x0, y0 = task.tile_anchor_xy
        centre = (x0 + (tile[1] + 0.5) * task.tile_m, y0 - (tile[0] + 0.5) * task.tile_m)
        scene = TileScene(dtm, centre, half_extent)
        _SCENE_CACHE[key] = scene
    return scene


def _group_by_tile(tile_ij: np.ndarray) -> list[tuple[tuple[int, int], list[int]]]:
    groups: dict[tuple[int, int], list[int]] = {}
    for m, (i, j) in enumerate(tile_ij.tolist()):
        groups.setdefault((i, j), []).append(m)
    return list(groups.items())


def _batches(items: list[int], size: int) -> Iterable[list[int]]:
    for start in range(0, len(items), size):
        yield items[start : start + size]


def _check_existing_shard(task: ShardTask, fingerprint: str) -> ShardRecord | None:
    """A complete shard from an earlier run of the same build, or None if it must be (re)made."""
    if not task.path.is_file():
        return None
    try:
        with ScanShardReader(task.path) as reader:
            ok = (
                reader.attrs.get("config_sha256") == fingerprint
                and reader.attrs.get("dtm_sha256") == task.file_attrs.get("dtm_sha256")
                and len(reader) == task.nadir_xy.shape[0]
                and attr_int(reader.attrs.get("first_scan", -1)) == task.first_scan
            )
        if ok:
            check_h5_data(task.path)  # every chunk's fletcher32 checksum
    except (ShardFormatError, StorageError, OSError, KeyError, TypeError, ValueError):
        ok = False
    if not ok:
        return None
    return _record(task, sha256_file(task.path))


def prepare_output(out_dir: Path, config: BuildConfig, overwrite: bool) -> bool:
    """Check the output directory; returns True when an unfinished identical build is resumed.

    Raises:
        OutputExistsError: a complete dataset without ``overwrite``, an unfinished build with other
            settings, or a non-empty directory that is not an hd build.
        StorageError: ``out_dir`` is, holds or lies inside the DTM (``--overwrite`` would delete it).
    """
    if config.dtm_path is not None and Path(config.dtm_path).is_file():  # a bad --dtm gets its own error later
        check_not_input(out_dir, {"the DTM": config.dtm_path})
    if not out_dir.exists():
        return False
    if not out_dir.is_dir():
        raise OutputExistsError(f"{out_dir} exists and is not a directory")
    manifest = out_dir / MANIFEST_NAME
    state = out_dir / BUILD_STATE_NAME
    if os.path.lexists(manifest) or os.path.lexists(state):
        if overwrite:
            return False
        if manifest.exists():
            previous = _recorded_settings(manifest)
            if previous.get("config_sha256") == config.fingerprint():
                raise OutputExistsError(
                    f"{out_dir} holds a dataset of these settings whose shards or DTM changed (check it with "
                    "`hd verify`); pass --overwrite to build it again"
                )
            difference = settings_difference(previous, config)
            raise OutputExistsError(
                f"{out_dir} already holds a dataset built with other settings ({difference}); "
                "pass --overwrite to replace it, or choose another --out"
            )
        previous = _recorded_settings(state)
        if previous.get("config_sha256") != config.fingerprint():
            difference = settings_difference(previous, config)
            raise OutputExistsError(
                f"{out_dir} holds an unfinished build with other settings ({difference}); "
                "rerun that build's command to resume it, or pass --overwrite to start again"
            )
        return True
    if any(p.name != LOCK_NAME and PARTIAL_MARK not in p.name for p in out_dir.iterdir()):
        raise OutputExistsError(f"{out_dir} exists, is not empty and is not an hd dataset; choose another --out")
    return False


def _recorded_settings(path: Path) -> dict[str, object]:
    """``config_sha256`` and ``config`` recorded in a manifest or a build state file ({} if unreadable)."""
    try:
        record = json.loads(read_regular_text(path))
    except (ValueError, RecursionError):
        return {}
    return record if isinstance(record, dict) else {}


def _flatten(value: object, prefix: str = "") -> dict[str, object]:
    if isinstance(value, dict):
        out: dict[str, object] = {}
        for k, v in value.items():
            out |= _flatten(v, f"{prefix}{k}.")
        return out
    return {prefix.rstrip("."): value}


def _changes(before: Mapping[str, object], after: Mapping[str, object]) -> list[tuple[str, object, object]]:
    """(dotted key, value before, value after) of every setting that differs (``"absent"`` for a missing one)."""
    flat_before, flat_after = _flatten(before), _flatten(after)
    keys = sorted(set(flat_before) | set(flat_after))
    return [
        (k, flat_before.get(k, "absent"), flat_after.get(k, "absent"))
        for k in keys
        if flat_before.get(k, "absent") != flat_after.get(k, "absent")
    ]


def settings_difference(recorded: Mapping[str, object], config: BuildConfig, limit: int = 4) -> str:
    """The settings that differ between a recorded build (manifest or state) and ``config``, for messages:
    ``sigmas_m [0.0167] -> [0.07], trajectory.n_scans 20 -> 40``."""
    old = recorded.get("config")
    if not isinstance(old, dict):
        return "its settings are not recorded"
    changes = _changes(old, config.to_dict())
    if not changes:
        return "the same recorded settings, another settings hash (a build of another hd version)"
    shown = [f"{k} {json.dumps(before)} -> {json.dumps(after)}" for k, before, after in changes[:limit]]
    more = f" and {len(changes) - limit} more" if len(changes) > limit else ""
    return "; ".join(shown) + more


def setting_changes(recorded: Any, config: BuildConfig) -> list[tuple[str, Any, Any]]:
    """(setting, recorded value, value of ``config``) for every setting in which a recorded build
    configuration (a manifest's ``config``) differs from ``config``: dotted keys of
    ``BuildConfig.to_dict`` (``trajectory.n_scans``), the DTM named by its file name as the settings
    hash names it. Nothing when ``recorded`` is not a configuration."""
    if not isinstance(recorded, dict):
        return []
    before = dict(recorded)
    if isinstance(before.get("dtm_path"), str):
        before["dtm_path"] = Path(before["dtm_path"]).name
    return _changes(before, config.canonical_dict())


def finished_identical(out_dir: Path, config: BuildConfig) -> ManifestJson | None:
    """The manifest of a finished build in ``out_dir`` made with exactly ``config`` (settings hash, and a
    user DTM of the same bytes), else None. Beyond the manifest's own structure (``validate_manifest``),
    nothing is verified but the shards being present."""
    record = _recorded_settings(out_dir / MANIFEST_NAME)
    if not record or record.get("config_sha256") != config.fingerprint():
        return None
    try:
        manifest = validate_manifest(record, str(out_dir / MANIFEST_NAME))
    except ShardFormatError:
        return None
    if not all((out_dir / e["path"]).is_file() for e in manifest["shards"]):
        return None
    if config.dtm_path is not None and not config.rocks_on_dtm:
        recorded_sha = manifest.get("dtm", {}).get("sha256")
        if not Path(config.dtm_path).is_file() or dtm_sha256(config.dtm_path) != recorded_sha:
            return None
    return manifest


def clear_output(out_dir: Path, keep_state: bool = False) -> None:
    """Remove a previous hd build from ``out_dir`` (manifest first, so it is never seen half-removed).

    ``keep_state``: keep ``.hd-build.json`` (the new build's, written before, so that a kill while
    clearing leaves a build that the same command resumes).
    """
    (out_dir / MANIFEST_NAME).unlink(missing_ok=True)
    for name in (SHARD_DIR, TERRAIN_DIR, "labels"):
        path = out_dir / name
        if path.is_symlink() or path.is_file():
            path.unlink()
        else:
            shutil.rmtree(path, ignore_errors=True)
    if not keep_state:
        (out_dir / BUILD_STATE_NAME).unlink(missing_ok=True)


def procedural_terrain_name(seed: int) -> str:
    """File name of the procedural terrain of a build, in ``terrain/``."""
    return f"mars-procedural-seed{seed}.tif"


def default_out_dir(config: BuildConfig, recipe_name: str | None = None) -> Path:
    """The dataset directory ``hd build-dataset`` writes when no ``--out`` is given, relative to the
    current directory: the recipe's name; else the DTM's file name without its suffix
    (``sabrina.tif`` -> ``sabrina``; ``NAME-dataset`` for a DTM file without a suffix, so that the
    directory never takes the DTM's own name); else the procedural terrain's (``mars-procedural-seedS``).
    """
    if recipe_name:
        return Path(recipe_name)
    if config.dtm_path is not None:
        dtm = Path(config.dtm_path)
        return Path(dtm.stem if dtm.suffix else f"{dtm.name}-dataset")
    return Path(Path(procedural_terrain_name(config.seed)).stem)


def rocky_terrain_name(dtm_path: str, seed: int) -> str:
    """File name, in ``terrain/``, of a build's DTM with rocks (``BuildConfig.rocks_on_dtm``)."""
    return f"{Path(dtm_path).stem}-rocks-seed{seed}.tif"


def _procedural_terrain_bytes(params: MarsTerrainParams, seed: int, path: Path) -> bytes:
    """The procedural terrain of ``params`` and ``seed`` as GeoTIFF bytes (built in memory; nothing is written)."""
    heights = generate_mars_terrain(params, seed=seed)
    return geotiff_bytes(
        heights,
        params.spacing_m,
        origin_xy=(0.0, 0.0),
        crs_wkt="",
        tags=terrain_tags(params, seed),
        name=str(path),
    )


def restore_procedural_terrain(root: Path, manifest: ManifestJson) -> Path | None:
    """Write back the procedural terrain of the dataset at ``root`` when its file in ``terrain/`` is
    gone or its bytes changed: regenerated from the seed and terrain parameters the manifest records,
    and kept only if its sha256 is the one the manifest records for the build's terrain (with a
    warning that says so).

    Returns:
        The path written; None when the file is intact (or is not a regular file), or the dataset
        was not built on the procedural terrain (a user's DTM, or rocks on one, cannot be
        regenerated from the manifest).

    Raises:
        LidarsimError: the regenerated terrain is not the one the build cast its rays on (another hd
            version made the dataset), or it cannot be written.
    """
    config, dtm = manifest.get("config"), manifest.get("dtm")
    if not isinstance(config, dict) or not isinstance(dtm, dict) or config.get("dtm_path") is not None:
        return None
    seed, terrain = config.get("seed"), config.get("terrain")
    if isinstance(seed, bool) or not isinstance(seed, int) or not isinstance(terrain, dict):
        return None
    path = root / TERRAIN_DIR / procedural_terrain_name(seed)
    if dtm.get("path") != f"{TERRAIN_DIR}/{path.name}" or (os.path.lexists(path) and not path.is_file()):
        return None
    missing = not path.exists()
    if not missing and sha256_file(path) == dtm.get("sha256"):
        return None
    try:
        params = MarsTerrainParams(**terrain)
    except (TypeError, ValueError):
        return None  # parameters this version does not know: it cannot regenerate that terrain
    data = _procedural_terrain_bytes(params, seed, path)
    digest = sha256_bytes(data)
    state = "is missing" if missing else "changed since the build"
    if digest != dtm.get("sha256"):
        raise LidarsimError(
            f"{path}: the terrain {root.name} was built on {state}, and regenerating it from the build's seed "
            f"{seed} gives other bytes (sha256 {digest[:12]}..., the manifest says {str(dtm.get('sha256'))[:12]}...); "
            "restore the file"
        )
    path.parent.mkdir(exist_ok=True)
    write_bytes_atomic(path, data)
    warnings.warn(
        HdWarning(
            f"{path} {'was missing' if missing else 'had changed since the build'}: regenerated from the build's "
            f"seed {seed} and terrain parameters (the sha256 the manifest records)"
        ),
        stacklevel=2,
    )
    return path


def check_workers(workers: int | None, flag: str = "--workers") -> None:
    """Refuse a worker count outside 1..limits.MAX_WORKERS (None = all cores)."""
    if workers is not None and (isinstance(workers, bool) or not 1 <= int(workers) <= limits.MAX_WORKERS):
        raise LidarsimError(f"{flag} must be in 1..{limits.MAX_WORKERS}, got {workers}")


def check_shard_files(config: BuildConfig, max_shards: int = limits.MAX_SHARD_FILES) -> None:
    """Refuse a build that would write more than ``max_shards`` shard files (``--max-shards``; by
    default ``limits.MAX_SHARD_FILES``). The bound is an option of the command, not of the dataset:
    it is recorded nowhere, so a dataset's bytes do not depend on it."""
    if isinstance(max_shards, bool) or not limits.SHARD_FILES.contains(max_shards):
        raise LidarsimError(f"--max-shards must be an integer in {limits.SHARD_FILES.interval()}, got {max_shards!r}")
    scans, size = config.trajectory.n_scans, config.scans_per_shard
    files = math.ceil(scans / size)
    if files > max_shards:
        why = ": the default, against a --shard-size typed too small" if max_shards == limits.MAX_SHARD_FILES else ""
        raise LidarsimError(
            f"the build would write {files:,} shard files ({scans:,} scans, {size:,} per shard), more than "
            f"--max-shards allows ({max_shards:,}{why}); make shards of at least {math.ceil(scans / max_shards):,} "
            f"scans, or allow them with --max-shards {files}"
        )


def _completed_shards(out_dir: Path) -> int:
    shard_dir = out_dir / SHARD_DIR
    if not shard_dir.is_dir():
        return 0
    return sum(1 for p in shard_dir.glob("scans-*.h5") if PARTIAL_MARK not in p.name)


def _clean_after_failure(out_dir: Path, created: bool) -> None:
    """Remove partial files; a build that created ``out_dir`` and completed no shard removes its files."""
    for sub in (out_dir / SHARD_DIR, out_dir / TERRAIN_DIR, out_dir):
        remove_partials(sub)
    if created and not (out_dir / MANIFEST_NAME).exists() and _completed_shards(out_dir) == 0:
        for name in (SHARD_DIR, TERRAIN_DIR):
            shutil.rmtree(out_dir / name, ignore_errors=True)
        (out_dir / BUILD_STATE_NAME).unlink(missing_ok=True)


def build_dataset(
    out_dir: str | os.PathLike,
    config: BuildConfig,
    workers: int | None = None,
    scheduler: str | None = None,
    overwrite: bool = False,
    progress: Callable[[int, int], None] | None = None,
    max_shards: int = limits.MAX_SHARD_FILES,
    recipe_deviation: RecipeDeviationJson | None = None,
) -> BuildSummary:
    """Build (or finish building) a dataset of clean and noisy scans.

    Args:
        out_dir: the dataset directory.
        config: what to build.
        workers: local worker processes (default: all cores); ignored with ``scheduler``.
        scheduler: address of a Dask scheduler (``tcp://host:8786``), or None for a process pool.
        overwrite: replace an existing dataset at ``out_dir``.
        progress: called with (scans done, scans total) as shards finish.
        max_shards: the most shard files the build may write (:func:`check_shard_files`).
        recipe_deviation: a recipe built at another size: the manifest's record of it
            (``lidarsim.recipe_deviation``; the manifest is then schema version 1.1).

    Raises:
        LidarsimError: bad input (DTM, sizes, existing output, more shard files than ``max_shards``);
            nothing is written or overwritten then.
    """
    t_start = time.perf_counter()
    out_dir = check_output_dir(out_dir, "--out").resolve()
    check_workers(workers)
    check_shard_files(config, max_shards)
    if not overwrite and (done := finished_identical(out_dir, config)) is not None:
        splits = done.get("splits")
        return BuildSummary(
            out_dir=out_dir,
            n_scans=int(done.get("n_scans", config.trajectory.n_scans)),
            n_shards=len(done["shards"]),
            sigmas_m=config.sigmas_m,
            split_counts={str(k): int(v) for k, v in splits.items()} if isinstance(splits, dict) else {},
            seconds=time.perf_counter() - t_start,
            resumed_shards=len(done["shards"]),
            bytes_written=0,
            rays_per_second=0.0,
            already_built=True,
            n_descents=config.trajectory.n_descents,
            descent_frames=config.trajectory.frames if config.trajectory.descent is not None else 0,
        )
    if scheduler is not None:
        probe_scheduler(scheduler)
    prepare_output(out_dir, config, overwrite)
    terrain = _open_terrain(out_dir, config)
    _warn_weak_inputs(config, terrain)
    # Input is valid: from here on the output directory is written, by this process alone.
    created = first_missing(out_dir) is not None
    with OutputTransaction(
        out_dir,
        "dataset",
        check=lambda: prepare_output(out_dir, config, overwrite),  # again, now that no other writer can run
        rollback=lambda: _clean_after_failure(out_dir, created),
    ) as tx:
        resume = bool(tx.checked)
        # The build's settings first: from here on, a kill leaves a build the same command resumes.
        write_json_atomic(
            out_dir / BUILD_STATE_NAME,
            {
                "config_sha256": config.fingerprint(),
                "dtm_sha256": terrain.attrs["dtm_sha256"],
                "config": config.to_dict(),
            },
        )
        if overwrite:
            clear_output(out_dir, keep_state=True)
        if terrain.data is not None:
            make_subdir(out_dir, TERRAIN_DIR)
            if not (terrain.path.is_file() and sha256_file(terrain.path) == terrain.attrs["dtm_sha256"]):
                write_bytes_atomic(terrain.path, terrain.data)
            terrain.data = None
        make_subdir(out_dir, SHARD_DIR)
        return _build_locked(out_dir, config, resume, terrain, workers, scheduler, progress, t_start, recipe_deviation)


def _warn_weak_inputs(config: BuildConfig, terrain: _BuildTerrain) -> None:
    """One ``HdWarning`` per input that weakens the dataset (``lidarsim.weak_inputs``)."""
    spacing = terrain.attrs.get("dtm_spacing_m")
    if isinstance(spacing, (list, tuple)) and spacing:
        message = coarse_dtm_message(
            terrain.path.name, float(max(spacing)), config.sensor, config.trajectory.min_altitude_m
        )
        if message:
            warnings.warn(message, HdWarning, stacklevel=3)
    plan = terrain.plan
    splits = assign_splits(config.trajectory.n_positions, config.seed)
    footprint = 2.0 * plan.half_width_m
    message = overlap_message(split_overlap(plan.nadir_xy, splits, footprint), plan.step_m, footprint)
    if message:
        warnings.warn(message, HdWarning, stacklevel=3)


@dataclass
class _BuildTerrain:
    """The terrain of a build: its path, the procedural terrain's GeoTIFF bytes (None for a user's
    DTM), the scan plan over it, the shards' ``dtm_*`` attributes and the manifest's provenance."""

    path: Path
    data: bytes | None
    plan: ScanPlan
    attrs: dict[str, object]
    provenance: DtmJson


def _open_terrain(out_dir: Path, config: BuildConfig) -> _BuildTerrain:
    """Step 1: the terrain read (a user's DTM) or generated in memory (the procedural terrain, also
    on resume: a damaged terrain file is rewritten), checked and planned; nothing is written."""
    terrain_bytes: bytes | None = None
    if config.dtm_path is None:
        dtm_path = out_dir / TERRAIN_DIR / procedural_terrain_name(config.seed)
        terrain_bytes = _procedural_terrain_bytes(config.terrain, config.seed, dtm_path)
    elif config.rocks_on_dtm:
        dtm_path = out_dir / TERRAIN_DIR / rocky_terrain_name(config.dtm_path, config.seed)
        rocky = rocks_on_base(config.dtm_path, config.terrain, config.seed, config.terrain.spacing_m)
        terrain_bytes = rocky_geotiff_bytes(rocky, str(dtm_path))
        del rocky
    else:
        dtm_path = Path(config.dtm_path).resolve()
    opened = (
        DTM.from_bytes(terrain_bytes, dtm_path, scale=config.dtm_scale)
        if terrain_bytes is not None
        else DTM.open(dtm_path, scale=config.dtm_scale)
    )
    with opened as dtm:
        cell = max(OVERVIEW_CELL_M, *dtm.info.spacing_m)
        valid, overview_transform = dtm.validity_overview(cell)
        plan = plan_scans(valid, overview_transform, config.sensor, config.trajectory, dtm.info.name)
        dtm_attrs = {f"dtm_{k}": v for k, v in dtm.info.to_attrs().items()}
        dtm_sha256 = dtm_attrs["dtm_sha256"] = dtm.sha256()
        dtm_provenance: DtmJson = {**dtm.info.to_attrs(), "sha256": dtm_sha256}
    return _BuildTerrain(dtm_path, terrain_bytes, plan, dtm_attrs, dtm_provenance)


def _build_locked(
    out_dir: Path,
    config: BuildConfig,
    resume: bool,
    terrain: _BuildTerrain,
    workers: int | None,
    scheduler: str | None,
    progress: Callable[[int, int], None] | None,
    t_start: float,
    recipe_deviation: RecipeDeviationJson | None = None,
) -> BuildSummary:
    """The part of ``build_dataset`` that writes (called with the writer lock held)."""
    fingerprint = config.fingerprint()
    remove_partials(out_dir / SHARD_DIR)
    splits = scan_splits(config)
    n_workers = max(1, workers if workers is not None else (os.cpu_count() or 1))
    tasks = _make_tasks(
        out_dir, terrain.plan, splits, str(terrain.path), config, _file_attrs(config, terrain), n_workers
    )
    records, pending = _finished_shards(tasks, fingerprint, resume)
    t_work = time.perf_counter()
    _run_shards(pending, records, config.trajectory.n_scans, n_workers, scheduler, progress)
    t_end = time.perf_counter()
    manifest = _write_manifest(out_dir, config, terrain, splits, records, recipe_deviation)
    (out_dir / BUILD_STATE_NAME).unlink(missing_ok=True)
    new_scans = sum(t.nadir_xy.shape[0] for t in pending)
    rays = new_scans * config.sensor.rows * config.sensor.cols * config.footprint.samples**2
    size = sum((out_dir / r.path).stat().st_size for r in records.values())
    return BuildSummary(
        out_dir=out_dir,
        n_scans=config.trajectory.n_scans,
        n_shards=len(records),
        sigmas_m=config.sigmas_m,
        split_counts=manifest["splits"],
        seconds=t_end - t_start,
        resumed_shards=len(tasks) - len(pending),
        bytes_written=size,
        rays_per_second=rays / max(t_end - t_work, 1e-9),
        n_descents=config.trajectory.n_descents,
        descent_frames=config.trajectory.frames if config.trajectory.descent is not None else 0,
    )


def _file_attrs(config: BuildConfig, terrain: _BuildTerrain) -> dict[str, object]:
    """Step 2: the root attributes of every scan shard (settings, sensor, trajectory, terrain)."""
    return {
        "seed": config.seed,
        "config_json": json.dumps(config.canonical_dict(), sort_keys=True),
        "config_sha256": config.fingerprint(),
        "frame": (
            "scan frame: origin at the nadir point on the reference height (origin_map); x east, y north, z up; metres"
        ),
        **config.sensor.to_attrs(),
        **config.trajectory.to_attrs(),
        **config.realism_attrs,
        **terrain.attrs,
        "dtm_path": terrain.path.name,
    }


def _finished_shards(
    tasks: list[ShardTask], fingerprint: str, resume: bool
) -> tuple[dict[int, ShardRecord], list[ShardTask]]:
    """Step 3: the shards a resumed build already holds intact (by shard index), and the tasks left."""
    records: dict[int, ShardRecord] = {}
    pending: list[ShardTask] = []
    for task in tasks:
        existing_record = _check_existing_shard(task, fingerprint) if resume else None
        if existing_record is not None:
            records[task.shard_index] = existing_record
        else:
            pending.append(task)
    return records, pending


def _run_shards(
    pending: list[ShardTask],
    records: dict[int, ShardRecord],
    total: int,
    n_workers: int,
    scheduler: str | None,
    progress: Callable[[int, int], None] | None,
) -> None:
    """Step 4: the pending shards simulated and written by the workers; ``records`` completed as they finish."""
    done = sum(r.n_scans for r in records.values())
    if progress:
        progress(done, total)
    with contextlib.closing(run_tasks(run_shard, pending, n_workers, scheduler)) as results:
        for position, record in results:
            records[pending[position].shard_index] = record
            done += record.n_scans
            if progress:
                progress(done, total)


def _write_manifest(
    out_dir: Path,
    config: BuildConfig,
    terrain: _BuildTerrain,
    splits: np.ndarray,
    records: dict[int, ShardRecord],
    recipe_deviation: RecipeDeviationJson | None = None,
) -> ManifestJson:
    """Step 5: ``manifest.json``, written last: the dataset is complete once it exists. A recipe's
    deviation (1.1) and a descent build's ``n_descents`` and ``descent_frames`` (1.2) are recorded only
    when there are some. Every file it lists records its size in bytes (1.4)."""
    dtm_path = terrain.path
    inside = dtm_path.is_relative_to(out_dir)
    dtm: DtmJson = terrain.provenance | {"path": os.path.relpath(dtm_path, out_dir) if inside else str(dtm_path)}
    if inside:
        dtm["size_bytes"] = dtm_path.stat().st_size
    manifest: ManifestJson = {
        "schema": MANIFEST_SCHEMA,
        "schema_version": MANIFEST_SCHEMA_VERSION_SIZES,
        "kind": MANIFEST_KIND_SCANS,
        "software": "hd",
        "software_version": __version__,
        "n_scans": config.trajectory.n_scans,
        "n_descents": config.trajectory.n_descents,
        "descent_frames": config.trajectory.frames,
        "sigmas_m": list(config.sigmas_m),
        "seed": config.seed,
        "config_sha256": config.fingerprint(),
        "config": config.to_dict(),
        "dtm": dtm,
        "trajectory": {"step_m": terrain.plan.step_m, "footprint_half_width_m": terrain.plan.half_width_m},
        "splits": {name: int((splits == i).sum()) for i, name in enumerate(SPLIT_NAMES)},
        "shards": [records[i].to_dict() for i in sorted(records)],
        "labelings": [],
    }
    if config.trajectory.descent is None:  # only a descent build has descents (the other keys keep their order)
        del manifest["n_descents"], manifest["descent_frames"]
    if recipe_deviation is not None:
        manifest["recipe_deviation"] = recipe_deviation
    write_json_atomic(out_dir / MANIFEST_NAME, manifest)
    return manifest


def _make_tasks(
    out_dir: Path,
    plan: ScanPlan,
    splits: np.ndarray,
    dtm_path: str,
    config: BuildConfig,
    file_attrs: dict[str, object],
    n_workers: int,
) -> list[ShardTask]:
    # one row per scan: a descent's frames share its target and tile
    frames = config.trajectory.frames
    nadir_xy, tile_ij = np.repeat(plan.nadir_xy, frames, axis=0), np.repeat(plan.tile_ij, frames, axis=0)
    n = nadir_xy.shape[0]
    threads = max(1, (os.cpu_count() or 1) // n_workers)
    tasks = []
    size = config.scans_per_shard
    for shard_index, first in enumerate(range(0, n, size)):
        last = min(n, first + size)
        tasks.append(
            ShardTask(
                out_dir=str(out_dir),
                shard_index=shard_index,
                first_scan=first,
                nadir_xy=nadir_xy[first:last],
                tile_ij=tile_ij[first:last],
                splits=splits[first:last],
                dtm_path=dtm_path,
                config=config,
                plan_half_width_m=plan.half_width_m,
                tile_anchor_xy=plan.tile_anchor_xy,
                tile_m=plan.tile_m,
                file_attrs=file_attrs,
                n_threads=threads,
            )
        )
    return tasks
