"""The shard format: plain HDF5 files of scans plus a ``manifest.json`` (a public interface).

Every field is documented in ``docs/shard-format.md``; a team without hd reads shards with h5py
alone. This module holds the writer, the lazy reader, the manifest and the checks of
``hd verify``. Files are written and read through ``hdcore.storage``: built in memory, written
under a temporary name and renamed when complete; every array chunk carries a fletcher32
checksum (schema 1.1); readers check the manifest's sha256, confine manifest paths to the dataset
and name the file and the scan in every error.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, cast

import h5py
import numpy as np

from hdcore.outcome import counted
from hdcore.storage import (
    CheckedH5File,
    DamagedFileError,
    FormatError,
    H5Image,
    StorageError,
    attr_int,
    check_relative,
    check_schema,
    commit_file,
    confine,
    h5_chunk_kwargs,
    is_sha256,
    lock_holder,
    open_h5,
    partial_path,
    read_json,
    remove_partials,
    require,
    sha256_file,
    verify_sha256,
    write_json_atomic,
)
from lidarsim import defaults, limits
from lidarsim._version import __version__
from lidarsim.errors import LidarsimError
from lidarsim.location import PUBLISH_MARK, dataset_label, is_url, join, open_h5_at, remote_dataset
from lidarsim.manifest_json import FileEntryJson, LabelingJson, ManifestJson, ShardRefJson
from lidarsim.noise import stored_kind

__all__ = [
    "BUILD_STATE_NAME",
    "MANIFEST_KIND_MOSAICS",
    "MANIFEST_KIND_SCANS",
    "MANIFEST_NAME",
    "MANIFEST_SCHEMA",
    "MANIFEST_SCHEMA_VERSION",
    "MANIFEST_SCHEMA_VERSION_DESCENT",
    "MANIFEST_SCHEMA_VERSION_DEVIATION",
    "MANIFEST_SCHEMA_VERSION_MOSAIC",
    "MANIFEST_SCHEMA_VERSION_SIZES",
    "SCAN_SCHEMA",
    "SCAN_SCHEMA_VERSION",
    "SCAN_SCHEMA_VERSION_DESCENT",
    "SCAN_SCHEMA_VERSION_PLAIN",
    "SCAN_SCHEMA_VERSION_REALISM",
    "SPLIT_NAMES",
    "TRUTH_DTM_SHA256_ATTR",
    "DamagedFileError",
    "MosaicRecord",
    "Scan",
    "ScanShardReader",
    "ScanShardWriter",
    "ShardFormatError",
    "StorageError",
    "check_arrays",
    "check_schema",
    "commit_file",
    "compression_kwargs",
    "entry_size",
    "iter_descents",
    "iter_scans",
    "open_scan_shard",
    "partial_path",
    "read_manifest",
    "remove_partials",
    "scan_schema_version",
    "sha256_file",
    "size_problem",
    "sizes_version",
    "validate_manifest",
    "verify_dataset",
    "write_attrs",
    "write_json_atomic",
]

SCAN_SCHEMA = "hd.lidar-scans"
# 1.1: every dataset chunked with a fletcher32 checksum per chunk (1.0 files stay readable).
# 1.2: the sensor-realism attributes (footprint_*, noise_model, noise_*, the trajectory's range ends)
# and status code 4 (weak). Only shards that use them are 1.2: the paper's sensor still writes 1.1
# files, byte for byte as before (scan_schema_version).
# 1.3: descents: the datasets descent_index, frame_index, target_map, nav_sensor_position and
# nav_sensor_attitude and the descent_* and nav_* attributes; only a descent build's shards are 1.3.
# 1.4: descent mosaics (``hd mosaic``): one "scan" per descent, its points at the DEM's cell centres,
# with the datasets frame_to_map, registration_correction, registration_fitness, registration_rmse_m
# and frame_residual_m and the mosaic_* attributes; only a mosaic dataset's shards are 1.4.
SCAN_SCHEMA_VERSION = "1.4"
SCAN_SCHEMA_VERSION_DESCENT = "1.3"
SCAN_SCHEMA_VERSION_REALISM = "1.2"
SCAN_SCHEMA_VERSION_PLAIN = "1.1"
# The file attribute whose presence makes a shard a descent's (version 1.3).
DESCENT_ATTR = "descent_frames"
# The file attribute whose presence makes a shard a mosaic dataset's (version 1.4).
MOSAIC_ATTR = "mosaic_poses"
# File attributes whose presence makes a shard version 1.2.
REALISM_ATTR_PREFIXES: tuple[str, ...] = (
    "footprint_",
    "noise_",
    "trajectory_altitude_max",
    "trajectory_tilt_max",
    "trajectory_jitter_max",
)
STATUS_CODES_PLAIN = "0 return, 1 miss, 2 dead element, 3 damaged element"
STATUS_CODES = STATUS_CODES_PLAIN + ", 4 weak (signal below the detection threshold)"
MANIFEST_SCHEMA = "hd.dataset-manifest"
MANIFEST_SCHEMA_VERSION = "1.0"
# The manifest of a recipe built at another size: 1.0 plus its ``recipe_deviation`` record.
MANIFEST_SCHEMA_VERSION_DEVIATION = "1.1"
# The manifest of a descent build: ``n_descents`` and ``descent_frames`` (and 1.1's record, if any).
MANIFEST_SCHEMA_VERSION_DESCENT = "1.2"
# The manifest of a mosaic dataset (``hd mosaic``): kind ``descent-mosaics`` and its ``mosaic`` record.
MANIFEST_SCHEMA_VERSION_MOSAIC = "1.3"
# 1.4: every file entry (scan shards, label shards, the dataset's terrain) records its ``size_bytes``;
# hd writes it into every manifest it writes (the 1.1-1.3 records are told apart by their keys).
MANIFEST_SCHEMA_VERSION_SIZES = "1.4"
MANIFEST_KIND_SCANS = "lidar-scans"
MANIFEST_KIND_MOSAICS = "descent-mosaics"
MANIFEST_NAME = "manifest.json"
# Settings of a build in progress; present only until its manifest is written.
BUILD_STATE_NAME = ".hd-build.json"
SPLIT_NAMES: tuple[str, str, str] = ("train", "val", "test")
# The file attribute in which a label shard of the terrain truth records the sha256 of the terrain it
# was labelled from (written by hdlabels, schema hd.labels 1.2): verify_dataset requires the
# manifest's dtm.sha256, the terrain the scans were cast on.
TRUTH_DTM_SHA256_ATTR = "truth_dtm_sha256"

# Not a format this version reads, or a damaged file (the storage layer's FormatError).
ShardFormatError = FormatError


def scan_schema_version(attrs: Mapping[str, object]) -> str:
    """The schema version of a scan shard with these file attributes: 1.4 for a mosaic dataset's, 1.3
    for a descent's, 1.2 when it records any of the sensor-realism settings, else 1.1 (the bytes every
    earlier hd wrote for the same settings)."""
    if MOSAIC_ATTR in attrs:
        return SCAN_SCHEMA_VERSION
    if DESCENT_ATTR in attrs:
        return SCAN_SCHEMA_VERSION_DESCENT
    realistic = any(key.startswith(REALISM_ATTR_PREFIXES) for key in attrs)
    return SCAN_SCHEMA_VERSION_REALISM if realistic else SCAN_SCHEMA_VERSION_PLAIN


def _attr_value(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, (list, tuple)):
        return np.asarray(value)
    return value


def write_attrs(obj: h5py.HLObject, attrs: Mapping[str, object]) -> None:
    """Write a flat dict as HDF5 attributes (None becomes an empty string)."""
    for key, value in attrs.items():
        obj.attrs[key] = _attr_value(value)


@dataclass
class ScanShardWriter:
    """Writes one shard of ``n_scans`` scans; use as a context manager, then ``commit()``.

    The file is built in memory (``hdcore.storage.H5Image``) and written to ``path`` atomically
    by ``commit()``; leaving the block with an exception discards it. Every dataset is chunked with
    a fletcher32 checksum per chunk.

    Args:
        path: final path of the shard.
        n_scans: number of scans it will hold.
        rows, cols: detector size.
        sigmas_m: the noise levels, metres (order of the noisy axis).
        attrs: file attributes (sensor, trajectory, DTM provenance, seed, config...).
        compression: "gzip" (deflate level 1 + shuffle, readable by any HDF5), "lzf" or "none".
    """

    path: Path
    n_scans: int
    rows: int
    cols: int
    sigmas_m: tuple[float, ...]
    attrs: dict[str, object]
    compression: str = defaults.COMPRESSION

    def __enter__(self) -> ScanShardWriter:
        kw = compression_kwargs(self.compression)
        self._image = H5Image(self.path)
        f = self._f = self._image.file
        write_attrs(
            f,
            {
                "schema": SCAN_SCHEMA,
                "schema_version": scan_schema_version(self.attrs),
                "software": "hd",
                "software_version": __version__,
                "n_scans": self.n_scans,
                "sigmas_m": np.asarray(self.sigmas_m, dtype=np.float64),
                **self.attrs,
            },
        )
        n, r, c, s = self.n_scans, self.rows, self.cols, len(self.sigmas_m)
        small = compression_kwargs("none")

        def whole(*shape: int) -> dict[str, Any]:
            return {**small, "chunks": shape}

        self._d = {
            "scan_index": f.create_dataset("scan_index", (n,), np.int64, **whole(n)),
            "split": f.create_dataset("split", (n,), np.uint8, **whole(n)),
            "origin_map": f.create_dataset("origin_map", (n, 3), np.float64, **whole(n, 3)),
            "sensor_position": f.create_dataset("sensor_position", (n, 3), np.float64, **whole(n, 3)),
            "sensor_attitude": f.create_dataset("sensor_attitude", (n, 3, 3), np.float64, **whole(n, 3, 3)),
            "points_clean": f.create_dataset("points_clean", (n, r, c, 3), np.float32, chunks=(1, r, c, 3), **kw),
            "points_noisy": f.create_dataset("points_noisy", (n, s, r, c, 3), np.float32, chunks=(1, 1, r, c, 3), **kw),
            "status": f.create_dataset("status", (n, r, c), np.uint8, chunks=(1, r, c), **kw),
            "valid": f.create_dataset("valid", (n, r, c), np.uint8, chunks=(1, r, c), **kw),
        }
        self._d["split"].attrs["names"] = np.asarray(SPLIT_NAMES, dtype=h5py.string_dtype())
        self._d["points_noisy"].attrs["sigmas_m"] = np.asarray(self.sigmas_m, dtype=np.float64)
        realistic = scan_schema_version(self.attrs) != SCAN_SCHEMA_VERSION_PLAIN
        self._d["status"].attrs["codes"] = STATUS_CODES if realistic else STATUS_CODES_PLAIN
        if "noise_scale" in stored_kind(self.attrs).stored_fields:
            self._d["noise_scale"] = f.create_dataset("noise_scale", (n, r, c), np.float32, chunks=(1, r, c), **kw)
        # a descent's arrays are gathered here and written whole by commit(): one write each, not one per scan
        self._descent: dict[str, np.ndarray] = {}
        if DESCENT_ATTR in self.attrs:
            for name, (dtype, tail) in DESCENT_DATASETS.items():
                self._d[name] = f.create_dataset(name, (n, *tail), dtype, **whole(n, *tail))
                self._descent[name] = np.zeros((n, *tail), dtype=dtype)
        if MOSAIC_ATTR in self.attrs:
            sizes = {"sigma": s, "frame": attr_int(self.attrs["mosaic_frames"])}
            for name, (dtype, axes) in MOSAIC_DATASETS.items():
                tail = tuple(sizes[a] if isinstance(a, str) else a for a in axes)
                self._d[name] = f.create_dataset(name, (n, *tail), dtype, **whole(n, *tail))
                self._descent[name] = np.zeros((n, *tail), dtype=dtype)
        return self

    def write_scan(
        self,
        k: int,
        scan_index: int,
        split: int,
        origin_map: np.ndarray,
        sensor_position: np.ndarray,
        sensor_attitude: np.ndarray,
        points_clean: np.ndarray,
        points_noisy: np.ndarray,
        status: np.ndarray,
        valid: np.ndarray,
        noise_scale: np.ndarray | None = None,
        descent: DescentFrame | None = None,
        mosaic: MosaicRecord | None = None,
    ) -> None:
        """Write scan ``k`` (0-based within the shard); ``noise_scale`` only to a shard of the snr noise
        model, ``descent`` (the frame's place in its descent and its navigation estimate) only to a
        descent's shard, and to every scan of it; ``mosaic`` (how the mosaic was placed) to every scan
        of a mosaic dataset's shard."""
        d = self._d
        for record, names, what in (
            (descent, DESCENT_DATASETS, "descent's shard needs each frame's descent record"),
            (mosaic, MOSAIC_DATASETS, "mosaic dataset's shard needs each mosaic's record"),
        ):
            if next(iter(names)) in self._descent:
                if record is None:
                    raise ValueError(f"a {what}")
                for name in names:
                    self._descent[name][k] = getattr(record, name)
        d["scan_index"][k] = scan_index
        d["split"][k] = split
        d["origin_map"][k] = origin_map
        d["sensor_position"][k] = sensor_position
        d["sensor_attitude"][k] = sensor_attitude
        d["points_clean"][k] = points_clean
        d["points_noisy"][k] = points_noisy
        d["status"][k] = status
        d["valid"][k] = valid
        if "noise_scale" in d:
            if noise_scale is None:
                raise ValueError("a shard of the snr noise model needs each scan's noise_scale")
            d["noise_scale"][k] = noise_scale

    def commit(self) -> str:
        """Write the shard to its final path (temporary name, fsync, rename); returns its sha256.

        Raises:
            StorageError: the disk is full or not writable (nothing is left at the temporary name).
        """
        for name, values in self._descent.items():
            self._d[name][...] = values
        return self._image.commit()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is not None:
            self._image.discard()


def compression_kwargs(name: str) -> dict[str, Any]:
    """h5py dataset keywords of a compression setting: gzip (deflate 1 + shuffle), lzf or none,
    always with a fletcher32 checksum per chunk."""
    return h5_chunk_kwargs(name)


@dataclass(frozen=True)
class Scan:
    """One scan read back from a shard (scan frame, metres)."""

    scan_index: int
    split: str
    origin_map: np.ndarray
    sensor_position: np.ndarray
    sensor_attitude: np.ndarray
    points_clean: np.ndarray
    points_noisy: np.ndarray  # (n_sigma, rows, cols, 3)
    status: np.ndarray
    valid: np.ndarray
    noise_scale: np.ndarray | None = None  # (rows, cols) factor on each sigma (1.2, snr noise model only)
    descent: DescentFrame | None = None  # 1.3, a descent build's frames only: the descent and navigation estimate
    mosaic: MosaicRecord | None = None  # 1.4, a mosaic dataset's only: how the descent's frames were placed


@dataclass(frozen=True)
class DescentFrame:
    """A frame's place in its descent and the navigation system's estimate of its pose (schema 1.3).

    Attributes:
        descent_index: the descent the frame belongs to (0-based, global).
        frame_index: 0 .. K - 1 within its descent (0 the highest).
        target_map: float64 (3,) the descent's target in map coordinates: x, y and the terrain's mean
            height around it (the height the frames' altitudes are measured from), metres.
        nav_sensor_position: float64 (3,) estimated sensor position in the frame's scan frame, metres.
        nav_sensor_attitude: float64 (3, 3) estimated rotation from the sensor frame to the scan frame.
    """

    descent_index: int
    frame_index: int
    target_map: np.ndarray
    nav_sensor_position: np.ndarray
    nav_sensor_attitude: np.ndarray


# The datasets of a descent's shard (1.3): dtype and shape after the scan axis.
DESCENT_DATASETS: dict[str, tuple[type, tuple[int, ...]]] = {
    "descent_index": (np.int64, ()),
    "frame_index": (np.int64, ()),
    "target_map": (np.float64, (3,)),
    "nav_sensor_position": (np.float64, (3,)),
    "nav_sensor_attitude": (np.float64, (3, 3)),
}


@dataclass(frozen=True)
class MosaicRecord:
    """How one descent's mosaic was made (schema 1.4, a mosaic dataset's shards; ``hd mosaic``).

    The mosaic's "scan" holds the DEM's cell centres (x east, y north, metres from the descent's
    target) with the mosaic's heights; its frame is the lowest frame's navigation frame (the true
    map for the ``true`` poses).

    Attributes:
        frame_to_map: float64 (4, 4) rigid transform taking a point of the mosaic, placed in the map
            (``origin_map`` plus the point), to the true map point it shows: the inverse of the lowest
            frame's navigation error (the identity for the ``true`` poses).
        registration_correction: float64 (sigma, frame, 4, 4) the rigid correction registration
            applied to each frame of each noise level's mosaic (identity where none was applied).
        registration_fitness: float64 (sigma, frame) fraction of each frame's registered points with
            a correspondence at the finest scale (1 where none was registered).
        registration_rmse_m: float64 (sigma, frame) RMS distance of those correspondences, metres
            (0 where none was registered; NaN for a frame with too few points near the target).
        frame_residual_m: float64 (sigma, frame) RMS height difference of each frame to the lowest
            frame where both cover the DEM, metres (NaN where they share no cell).
    """

    frame_to_map: np.ndarray
    registration_correction: np.ndarray
    registration_fitness: np.ndarray
    registration_rmse_m: np.ndarray
    frame_residual_m: np.ndarray


# The datasets of a mosaic dataset's shard (1.4): dtype and axes after the scan axis.
MOSAIC_DATASETS: dict[str, tuple[type, tuple[int | str, ...]]] = {
    "frame_to_map": (np.float64, (4, 4)),
    "registration_correction": (np.float64, ("sigma", "frame", 4, 4)),
    "registration_fitness": (np.float64, ("sigma", "frame")),
    "registration_rmse_m": (np.float64, ("sigma", "frame")),
    "frame_residual_m": (np.float64, ("sigma", "frame")),
}


# Every array of a scan shard by its axes: named axes must agree across the arrays (docs/shard-format.md).
SCAN_ARRAYS: dict[str, tuple[int | str, ...]] = {
    "scan_index": ("scan",),
    "split": ("scan",),
    "origin_map": ("scan", 3),
    "sensor_position": ("scan", 3),
    "sensor_attitude": ("scan", 3, 3),
    "points_clean": ("scan", "row", "col", 3),
    "points_noisy": ("scan", "sigma", "row", "col", 3),
    "status": ("scan", "row", "col"),
    "valid": ("scan", "row", "col"),
}
# Optional arrays: present only in the shards whose settings make them (1.2: the snr noise model).
OPTIONAL_SCAN_ARRAYS: dict[str, tuple[int | str, ...]] = {"noise_scale": ("scan", "row", "col")}
# The arrays of a descent's shard (1.3): all of them, or none.
DESCENT_SCAN_ARRAYS: dict[str, tuple[int | str, ...]] = {
    name: ("scan", *tail) for name, (_, tail) in DESCENT_DATASETS.items()
}
# The arrays of a mosaic dataset's shard (1.4): all of them, or none.
MOSAIC_SCAN_ARRAYS: dict[str, tuple[int | str, ...]] = {
    name: ("scan", *axes) for name, (_, axes) in MOSAIC_DATASETS.items()
}


def check_arrays(f: CheckedH5File, layout: dict[str, tuple[int | str, ...]], what: str) -> dict[str, int]:
    """Check that a shard holds every array of ``layout``, numeric, with its axes: an int is that size,
    a name the same size in every array that has it. Returns the size of each named axis.

    Raises:
        DamagedFileError: a missing array, or one of another type, rank or size (named), so that a file
            whose arrays do not fit together is refused when it is opened, not half-way through it.
    """
    sizes: dict[str, int] = {}
    for name, axes in layout.items():
        ds = f[name]  # a missing array: DamagedFileError naming it
        shape, kind = tuple(ds.shape or ()), ds.dtype.kind
        if kind not in "biuf" or len(shape) != len(axes):
            raise DamagedFileError(f"{what}: {name} is {ds.dtype} of shape {shape}, not an array hd writes")
        for size, axis in zip(shape, axes, strict=True):
            expected = axis if isinstance(axis, int) else sizes.setdefault(axis, size)
            if size != expected:
                raise DamagedFileError(
                    f"{what}: {name} has shape {shape}; its {axis if isinstance(axis, str) else 'last'} axis "
                    f"should be {expected} long, as in the file's other arrays"
                )
    return sizes


class ScanShardReader:
    """Lazy reader of one scan shard; scans are read one at a time.

    Args:
        path: the shard file.
        sha256: the checksum its manifest records; when given, the file is checked against it
            before it is opened.
        what: how errors name the file (default: its path).
        size_bytes: the size its manifest records (1.4): at a URL, a server that sends more is refused.

    Raises:
        ShardFormatError: not an hd scan shard, an unknown major schema version, a checksum
            mismatch or damaged data (``DamagedFileError``, naming the file and the scan).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        sha256: str | None = None,
        what: str | None = None,
        size_bytes: int | None = None,
    ) -> None:
        self.path: Path | str = str(path) if is_url(path) else Path(path)
        self.what = what or dataset_label(self.path)
        if sha256 is not None and not is_url(path):  # a URL is read lazily: hd verify checks its sha256
            verify_sha256(self.path, sha256, self.what)
        self._f: CheckedH5File = open_h5_at(self.path, self.what, sha256, size_bytes)
        try:
            attrs = self._f.attrs
            check_schema(
                _py(attrs.get("schema", "")),
                _py(attrs.get("schema_version", "")),
                SCAN_SCHEMA,
                SCAN_SCHEMA_VERSION,
                self.what,
            )
            self.attrs: dict[str, object] = {k: _py(v) for k, v in attrs.items()}
            self.sigmas_m: tuple[float, ...] = tuple(float(s) for s in np.atleast_1d(attrs["sigmas_m"]))
            optional = {k: v for k, v in OPTIONAL_SCAN_ARRAYS.items() if k in self._f}
            self.is_descent = any(name in self._f for name in DESCENT_SCAN_ARRAYS)
            if self.is_descent:  # a descent's shard holds all its arrays: a missing one is named
                optional |= DESCENT_SCAN_ARRAYS
            self.is_mosaic = any(name in self._f for name in MOSAIC_SCAN_ARRAYS)
            if self.is_mosaic:
                optional |= MOSAIC_SCAN_ARRAYS
            dims = check_arrays(self._f, SCAN_ARRAYS | optional, self.what)
            if dims["sigma"] != len(self.sigmas_m):
                raise DamagedFileError(
                    f"{self.what}: points_noisy holds {dims['sigma']} noise levels, sigmas_m lists {len(self.sigmas_m)}"
                )
            self._n = dims["scan"]
        except (KeyError, TypeError, ValueError, OSError) as exc:
            self._f.close()
            if isinstance(exc, LidarsimError):
                raise
            raise DamagedFileError(f"{self.what}: not a readable hd scan shard ({exc})") from exc
        except BaseException:
            self._f.close()
            raise

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, k: int) -> Scan:
        if not -self._n <= k < self._n:
            raise IndexError(f"scan {k} out of range for {self.what} ({self._n} scans)")
        f = self._f
        try:
            split = SPLIT_NAMES[int(f["split"][k])]
        except IndexError as exc:
            raise DamagedFileError(f"{self.what}: row {k} has an unknown split code") from exc
        return Scan(
            scan_index=int(f["scan_index"][k]),
            split=split,
            origin_map=f["origin_map"][k],
            sensor_position=f["sensor_position"][k],
            sensor_attitude=f["sensor_attitude"][k],
            points_clean=f["points_clean"][k],
            points_noisy=f["points_noisy"][k],
            status=f["status"][k],
            valid=f["valid"][k].astype(bool),
            noise_scale=f["noise_scale"][k] if "noise_scale" in f else None,
            descent=self._descent_frame(k) if self.is_descent else None,
            mosaic=MosaicRecord(**{name: f[name][k] for name in MOSAIC_DATASETS}) if self.is_mosaic else None,
        )

    def _descent_frame(self, k: int) -> DescentFrame:
        f = self._f
        return DescentFrame(
            descent_index=int(f["descent_index"][k]),
            frame_index=int(f["frame_index"][k]),
            target_map=f["target_map"][k],
            nav_sensor_position=f["nav_sensor_position"][k],
            nav_sensor_attitude=f["nav_sensor_attitude"][k],
        )

    def __iter__(self) -> Iterator[Scan]:
        for k in range(len(self)):
            yield self[k]

    @property
    def h5(self) -> CheckedH5File:
        """The open file (read-only): h5py's interface, with reads that name the file and scan on error."""
        return self._f

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> ScanShardReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _py(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, bytes):
        return value.decode(errors="replace")
    return value


# ------------------------------------------------------------------------------------------ manifest
def _check_entries(entries: Any, where: str) -> None:
    if not isinstance(entries, list):
        raise FormatError(f"{where} must be a list, got {type(entries).__name__}")
    seen: set[str] = set()
    for i, entry in enumerate(entries):
        at = f"{where}[{i}]"
        path = check_relative(require(entry, "path", str, at), at)
        if path in seen:
            raise FormatError(f"{at}: {path!r} is listed twice")
        seen.add(path)
        if not is_sha256(require(entry, "sha256", str, at)):
            raise FormatError(f"{at}: 'sha256' is not a 64-digit hex checksum")
        _check_size(entry, at)
        n = require(entry, "n_scans", int, at)
        if not 0 <= n <= limits.MAX_SCANS:
            raise FormatError(f"{at}: 'n_scans' must be in 0..{limits.MAX_SCANS}, got {n}")
        counts = entry.get("split_counts")
        if counts is not None:
            if not isinstance(counts, dict) or set(counts) != set(SPLIT_NAMES):
                raise FormatError(f"{at}: 'split_counts' must give {', '.join(SPLIT_NAMES)}")
            values = [counts[k] for k in SPLIT_NAMES]
            if any(isinstance(v, bool) or not isinstance(v, int) or v < 0 for v in values) or sum(values) != n:
                raise FormatError(f"{at}: 'split_counts' {counts} do not add up to its {n} scans")


def _check_size(entry: Mapping[str, Any], at: str) -> None:
    """An entry's ``size_bytes`` (1.4; absent in older manifests): a whole number of bytes, >= 0."""
    size = entry.get("size_bytes")
    if size is not None and (isinstance(size, bool) or not isinstance(size, int) or size < 0):
        raise FormatError(f"{at}: 'size_bytes' must be a whole number of bytes >= 0, got {size!r}")


def _check_terrain_entry(dtm: Any, where: str) -> None:
    """The terrain kept inside the dataset (a relative ``dtm.path``): a path inside it (no ``..``), its
    sha256 and size well-formed; an absolute path names the user's DTM outside the dataset."""
    if not isinstance(dtm, dict) or not isinstance(dtm.get("path"), str) or os.path.isabs(dtm["path"]):
        return
    check_relative(dtm["path"], f"{where}: dtm.path")
    _check_size(dtm, f"{where}: dtm")


def entry_size(entry: Mapping[str, Any]) -> int | None:
    """The size in bytes a manifest entry records (``size_bytes``, 1.4), None for an older entry."""
    size = entry.get("size_bytes")
    return size if isinstance(size, int) and not isinstance(size, bool) else None


def sizes_version(version: str) -> str:
    """The schema version of a manifest once hd has written sizes into it: ``version``, at least 1.4."""
    try:
        minor = int(version.split(".")[1])
    except (IndexError, ValueError):
        return MANIFEST_SCHEMA_VERSION_SIZES
    return version if version.startswith("1.") and minor >= 4 else MANIFEST_SCHEMA_VERSION_SIZES


def validate_manifest(data: Any, where: str) -> ManifestJson:
    """Check the structure of a manifest (keys, types, relative paths, checksums, scan counts).

    Raises:
        ShardFormatError: naming ``where`` and the faulty key.
    """
    if not isinstance(data, dict):
        raise FormatError(f"{where}: not a JSON object")
    check_schema(
        str(data.get("schema", "")),
        str(data.get("schema_version", "")),
        MANIFEST_SCHEMA,
        MANIFEST_SCHEMA_VERSION,
        where,
    )
    n_scans = require(data, "n_scans", int, where)
    shards = require(data, "shards", list, where)
    _check_entries(shards, f"{where}: shards")
    held = sum(int(e["n_scans"]) for e in shards)
    if held != n_scans:
        raise FormatError(f"{where}: lists {n_scans} scans but its shards hold {held}")
    if "n_descents" in data or "descent_frames" in data:
        n_descents = require(data, "n_descents", int, where)
        frames = require(data, "descent_frames", int, where)
        if not 2 <= frames <= limits.MAX_DESCENT_FRAMES or n_descents * frames != n_scans:
            raise FormatError(
                f"{where}: {n_descents} descents of {frames} frames are not its {n_scans} scans "
                f"(frames per descent: 2 to {limits.MAX_DESCENT_FRAMES})"
            )
    splits = data.get("splits")
    if splits is not None and shards and all("split_counts" in e for e in shards):
        summed = {k: sum(int(e["split_counts"][k]) for e in shards) for k in SPLIT_NAMES}
        if not isinstance(splits, dict) or {k: splits.get(k) for k in SPLIT_NAMES} != summed:
            raise FormatError(f"{where}: 'splits' {splits} differ from its shards' split counts {summed}")
    sigmas = require(data, "sigmas_m", list, where)
    if not sigmas or not all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) and x > 0 for x in sigmas
    ):
        raise FormatError(f"{where}: 'sigmas_m' must be a non-empty list of positive numbers")
    labelings = data.get("labelings", [])
    if not isinstance(labelings, list):
        raise FormatError(f"{where}: 'labelings' must be a list")
    for i, lab in enumerate(labelings):
        at = f"{where}: labelings[{i}]"
        name = require(lab, "name", str, at)
        if not name or "/" in name or name in (".", ".."):
            raise FormatError(f"{at}: {name!r} is not a labelling name")
        _check_entries(require(lab, "shards", list, at), f"{at}.shards")
    _check_terrain_entry(data.get("dtm"), where)
    return cast("ManifestJson", data)  # its keys and their types checked above


def _build_progress(directory: Path) -> str:
    """`` (k of n shards complete)`` of an unfinished build, best effort."""
    try:
        config = read_json(directory / BUILD_STATE_NAME)["config"]
        n_scans, size = int(config["trajectory"]["n_scans"]), int(config["shard_size"])
        frames = int((config["trajectory"].get("descent") or {}).get("frames", 1))
        size = -(-size // frames) * frames  # a descent build's shards hold whole descents
        total = -(-n_scans // size)
    except Exception:  # noqa: BLE001 - the state file is only informative here
        return ""
    done = sum(1 for p in (directory / "shards").glob("scans-*.h5")) if (directory / "shards").is_dir() else 0
    return f" ({done} of {counted(total, 'shard')} complete)"


def read_manifest(directory: str | os.PathLike) -> ManifestJson:
    """Read and check ``manifest.json`` of a dataset directory.

    Raises:
        ShardFormatError: no manifest (an unfinished build is named as such), unreadable JSON, an
            unknown schema/major version, or a malformed manifest (missing keys, paths leaving
            the dataset, bad checksums).
    """
    if is_url(directory):
        return _read_remote_manifest(str(directory))
    directory = Path(directory)
    path = directory / MANIFEST_NAME
    if os.path.lexists(path):
        confine(directory, MANIFEST_NAME, str(path))
        if not path.is_file():
            raise FormatError(f"{path}: unreadable manifest (not a regular file)")
    if not path.is_file():
        if (directory / BUILD_STATE_NAME).is_file():
            holder = lock_holder(directory)
            if holder is not None:
                raise FormatError(f"{directory}: a build is in progress (PID {holder}); wait for it to finish")
            raise FormatError(
                f"{directory}: unfinished build{_build_progress(directory)} - re-run the same "
                "`hd build-dataset` command to finish it"
            )
        if not directory.exists():
            raise FormatError(f"{directory}: no such dataset directory")
        if not directory.is_dir():
            raise FormatError(f"{directory}: not a directory")
        raise FormatError(f"{directory}: not an hd dataset (no {MANIFEST_NAME})")
    return validate_manifest(read_json(path, "manifest"), str(path))


def manifest_text(data: bytes, where: str) -> Any:
    """The JSON of a manifest's bytes (``DamagedFileError`` naming ``where`` when it is not JSON)."""
    try:
        return json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise DamagedFileError(f"{where}: unreadable manifest ({exc})") from exc
    except RecursionError as exc:
        raise DamagedFileError(f"{where}: unreadable manifest (nested too deeply)") from exc


def _read_remote_manifest(url: str) -> ManifestJson:
    """``read_manifest`` of a dataset at a URL: what is there instead of a manifest is named."""
    remote = remote_dataset(url)
    where = remote.label_of(MANIFEST_NAME)
    data = remote.read_if_there(MANIFEST_NAME)  # one request when the process has read this version already
    if data is None:
        if remote.size(PUBLISH_MARK) is not None:
            raise FormatError(
                f"{remote.label}: a dataset is being published there, or its publication was interrupted "
                "(no manifest yet); wait for `hd publish` to finish, or re-run it"
            )
        held = remote.listing()
        if not held:
            remote.probe(MANIFEST_NAME)  # an unreachable host is named as such, not as "nothing there"
            raise FormatError(f"{remote.label}: no dataset there (nothing at that URL)")
        raise FormatError(
            f"{remote.label}: not an hd dataset (no {MANIFEST_NAME}; it holds {counted(len(held), 'other file')})"
        )
    return validate_manifest(manifest_text(data, where), where)


def open_scan_shard(directory: str | os.PathLike, entry: ShardRefJson) -> ScanShardReader:
    """Open the scan shard of a manifest entry: path confined to the dataset, sha256 checked first,
    and its scan count compared with the entry's ``n_scans`` when the entry gives one. At a URL the
    shard is read lazily and its sha256 is left to ``hd verify`` (its chunks' fletcher32 checks stay)."""
    path = join(directory, entry["path"])
    what = dataset_label(path) if is_url(directory) else f"{Path(directory) / entry['path']}"
    reader = ScanShardReader(path, sha256=entry["sha256"], what=what, size_bytes=entry_size(entry))
    keys: Mapping[str, object] = entry  # a manifest's entry (FileEntryJson) also gives its scans
    claimed = keys.get("n_scans")
    if isinstance(claimed, int) and not isinstance(claimed, bool) and claimed != len(reader):
        reader.close()
        raise DamagedFileError(f"{reader.what}: holds {len(reader)} scans, its manifest entry claims {claimed}")
    return reader


def iter_scans(directory: str | os.PathLike, split: str | None = None) -> Iterator[Scan]:
    """Iterate lazily over every scan of a dataset (optionally one split), in scan order.

    Each shard is checked against the manifest's sha256 before it is read.
    """
    manifest = read_manifest(directory)
    for entry in manifest["shards"]:
        with open_scan_shard(directory, entry) as reader:
            for scan in reader:
                if split is None or scan.split == split:
                    yield scan


def iter_descents(directory: str | os.PathLike, split: str | None = None) -> Iterator[list[Scan]]:
    """Iterate lazily over the descents of a descent build (optionally one split), in order: each a
    list of its K frames, frame 0 (the highest) first. A descent never straddles two shards, and all
    its frames share a split.

    Raises:
        ShardFormatError: not a descent build (its manifest records no ``descent_frames``), or a shard
            whose frames are not whole descents in order.
    """
    manifest = read_manifest(directory)
    frames = manifest.get("descent_frames")
    if not isinstance(frames, int):
        raise FormatError(f"{directory}: not a descent build (its manifest records no descent_frames)")
    for entry in manifest["shards"]:
        with open_scan_shard(directory, entry) as reader:
            if not reader.is_descent or len(reader) % frames:
                raise DamagedFileError(f"{reader.what}: does not hold whole descents of {frames} frames")
            for first in range(0, len(reader), frames):
                descent = [reader[first + k] for k in range(frames)]
                if not _one_descent(descent):
                    raise DamagedFileError(
                        f"{reader.what}: scans {first} to {first + frames - 1} are not one descent's frames in order"
                    )
                if split is None or descent[0].split == split:
                    yield descent


def _one_descent(scans: list[Scan]) -> bool:
    """True when ``scans`` are frames 0, 1, ... of one descent, all in one split."""
    index = None
    for k, scan in enumerate(scans):
        if scan.descent is None or scan.descent.frame_index != k or scan.split != scans[0].split:
            return False
        index = scan.descent.descent_index if index is None else index
        if scan.descent.descent_index != index:
            return False
    return True


def verify_dataset(directory: str | os.PathLike, known_schemas: dict[str, str] | None = None) -> list[str]:
    """Check every file listed in the manifest: confinement, presence, sha256, schema, scan count and,
    for a label shard of the terrain truth, the terrain it was labelled from (``TRUTH_DTM_SHA256_ATTR``
    must be the manifest's ``dtm.sha256``).

    Args:
        directory: the dataset directory, or its URL (each file then read once, as a stream: its
            sha256 and its attributes come from the same bytes).
        known_schemas: schema name -> version this reader understands (default: scan shards);
            other packages add theirs (label shards).

    Returns:
        A list of one-line problems (empty when the dataset is intact).

    Raises:
        ShardFormatError: no readable, well-formed manifest.
    """
    known = {SCAN_SCHEMA: SCAN_SCHEMA_VERSION, **(known_schemas or {})}
    if is_url(directory):
        return _verify_remote(str(directory), known)
    directory = Path(directory)
    manifest = read_manifest(directory)
    problems: list[str] = []
    entries: list[FileEntryJson] = list(manifest.get("shards", []))
    for labelling in manifest.get("labelings", []):
        entries.extend(labelling.get("shards", []))
        problems += _entry_schema_problems(labelling, known)
    for entry in entries:
        rel = entry["path"]
        try:
            path = confine(directory, rel)
        except FormatError as exc:
            problems.append(str(exc))
            continue
        if not path.is_file():
            problems.append(f"{rel}: missing" if not os.path.lexists(path) else f"{rel}: not a regular file")
            continue
        if (problem := size_problem(rel, path.stat().st_size, entry)) is not None:
            problems.append(problem)
            continue
        try:
            digest = sha256_file(path)
        except StorageError as exc:
            problems.append(str(exc))
            continue
        if digest != entry["sha256"]:
            problems.append(
                f"{rel}: checksum mismatch (sha256 {digest[:12]}..., manifest says {entry['sha256'][:12]}...)"
            )
            continue
        problems += _file_problems(lambda p=path, r=rel: open_h5(p, r), rel, entry, known, manifest)
    problems += _terrain_problems(directory, manifest)
    return problems


def size_problem(rel: str, size: int, entry: Mapping[str, Any]) -> str | None:
    """A file of ``size`` bytes against the size its manifest entry records (None: they agree, or the
    entry records none)."""
    recorded = entry_size(entry)
    if recorded is None or size == recorded:
        return None
    return f"{rel}: {size} bytes, the manifest records {recorded} (size mismatch: the file is damaged or was replaced)"


def _file_problems(
    opener: Any, rel: str, entry: FileEntryJson, known: dict[str, str], manifest: ManifestJson
) -> list[str]:
    """The schema, scan count and terrain of one file whose sha256 matched (``opener()`` opens it)."""
    problems: list[str] = []
    try:
        with opener() as f:
            name = _py(f.attrs.get("schema", ""))
            version = _py(f.attrs.get("schema_version", ""))
            if name not in known:
                return [f"{rel}: unknown schema {name!r}"]
            check_schema(name, version, name, known[name], rel)
            if int(_py(f.attrs.get("n_scans", -1))) != int(entry["n_scans"]):
                problems.append(f"{rel}: holds {_py(f.attrs.get('n_scans'))} scans, manifest says {entry['n_scans']}")
            problems += _terrain_digest_problems(rel, _py(f.attrs.get(TRUTH_DTM_SHA256_ATTR)), manifest)
    except (FormatError, StorageError) as exc:
        problems.append(str(exc))
    except (OSError, TypeError, ValueError):
        problems.append(f"{rel}: not a readable HDF5 file")
    return problems


def _stream_sha256(remote: Any, rel: str, limit: int | None) -> tuple[str, bytes]:
    """The sha256 and the bytes of a remote file, read once as a stream (refused, and read no further,
    past ``limit`` bytes: the size the manifest records)."""
    h = hashlib.sha256()
    buf = io.BytesIO()
    for block in remote.stream(rel, limit):
        h.update(block)
        buf.write(block)
    return h.hexdigest(), buf.getvalue()


def _verify_remote(url: str, known: dict[str, str]) -> list[str]:
    """``verify_dataset`` of a dataset at a URL: each file streamed once (sha256), then its attributes
    read from the same bytes in memory (one file at a time)."""
    remote = remote_dataset(url)
    manifest = read_manifest(url)
    problems: list[str] = []
    entries: list[FileEntryJson] = list(manifest.get("shards", []))
    for labelling in manifest.get("labelings", []):
        entries.extend(labelling.get("shards", []))
        problems += _entry_schema_problems(labelling, known)
    for entry in entries:
        rel = entry["path"]
        try:
            size = remote.size(rel)
            if size is None:
                problems.append(f"{rel}: missing")
                continue
            if (problem := size_problem(rel, size, entry)) is not None:
                problems.append(problem)
                continue
            digest, data = _stream_sha256(remote, rel, entry_size(entry))
        except (FormatError, StorageError) as exc:
            problems.append(str(exc))
            continue
        if digest != entry["sha256"]:
            problems.append(
                f"{rel}: checksum mismatch (sha256 {digest[:12]}..., manifest says {entry['sha256'][:12]}...)"
            )
            continue

        def opener(data: bytes = data, rel: str = rel) -> CheckedH5File:
            return CheckedH5File(h5py.File(io.BytesIO(data), "r"), rel)

        problems += _file_problems(opener, rel, entry, known, manifest)
    dtm = manifest.get("dtm")
    if isinstance(dtm, dict) and isinstance(dtm.get("path"), str) and not os.path.isabs(dtm["path"]):
        rel, recorded = dtm["path"], dtm.get("sha256")
        try:
            size = remote.size(rel)
            if size is None:
                problems.append(f"{rel}: missing (the dataset's terrain)")
            elif (problem := size_problem(rel, size, dtm)) is not None:
                problems.append(problem)
            else:
                digest, _ = _stream_sha256(remote, rel, entry_size(dtm))
                if is_sha256(recorded) and digest != recorded:
                    problems.append(
                        f"{rel}: checksum mismatch (sha256 {digest[:12]}..., manifest says {str(recorded)[:12]}...)"
                    )
        except (FormatError, StorageError) as exc:
            problems.append(str(exc))
    return problems


def _entry_schema_problems(labelling: LabelingJson, known: dict[str, str]) -> list[str]:
    """The schema a labelling entry (and each of its shard entries) claims in the manifest, checked as
    its readers check it (a labelling whose entry says 2.0 is refused by train and eval, so by verify too)."""
    problems = []
    where = f"labelling {labelling.get('name')}"
    claimed = [(where, labelling.get("schema"), labelling.get("schema_version"))]
    claimed += [
        (f"{where}: {e.get('path')}", e.get("schema", labelling.get("schema")), e.get("schema_version"))
        for e in labelling.get("shards", [])
    ]
    for at, name, version in claimed:
        if name is None or version is None:
            continue  # entries written before they recorded a schema: the files' own attributes decide
        if not isinstance(name, str) or name not in known:
            problems.append(f"{at}: unknown schema {name!r}")
            continue
        try:
            check_schema(str(name), str(version), str(name), known[str(name)], at)
        except FormatError as exc:
            problems.append(str(exc))
    return problems


def _terrain_digest_problems(rel: str, recorded: Any, manifest: ManifestJson) -> list[str]:
    """A file that records the terrain it was made from (``TRUTH_DTM_SHA256_ATTR``; None: it records
    none) against the terrain the manifest records: labels from another terrain are damage."""
    if recorded is None:
        return []
    dtm = manifest.get("dtm")
    build = dtm.get("sha256") if isinstance(dtm, dict) else None
    if recorded == build:
        return []
    return [
        (
            f"{rel}: labelled from another terrain ({TRUTH_DTM_SHA256_ATTR} {str(recorded)[:12]}..., the manifest's "
            f"terrain is {str(build)[:12]}...): the file is damaged; re-run the hd label --truth terrain command "
            "that made it to label it again"
        )
    ]


def _terrain_problems(directory: Path, manifest: ManifestJson) -> list[str]:
    """The terrain file kept inside the dataset (the procedural terrain) against its recorded sha256."""
    dtm = manifest.get("dtm")
    if not isinstance(dtm, dict) or not isinstance(dtm.get("path"), str) or os.path.isabs(dtm["path"]):
        return []
    rel, recorded = dtm["path"], dtm.get("sha256")
    try:
        path = confine(directory, rel)
    except FormatError as exc:
        return [str(exc)]
    if not path.is_file():
        return [f"{rel}: missing (the dataset's terrain)"]
    if (problem := size_problem(rel, path.stat().st_size, dtm)) is not None:
        return [problem]
    try:
        digest = sha256_file(path)
    except StorageError as exc:
        return [str(exc)]
    if is_sha256(recorded) and digest != recorded:
        return [f"{rel}: checksum mismatch (sha256 {digest[:12]}..., manifest says {str(recorded)[:12]}...)"]
    return []


def check_dataset_files(directory: str | os.PathLike, manifest: ManifestJson) -> list[str]:
    """Cheap checks of the files a manifest lists (confinement, presence), without reading them."""
    problems: list[str] = []
    entries: list[FileEntryJson] = list(manifest.get("shards", []))
    for labelling in manifest.get("labelings", []):
        entries.extend(labelling.get("shards", []))
    for entry in entries:
        try:
            path = confine(directory, entry["path"])
        except FormatError as exc:
            problems.append(str(exc))
            continue
        if not path.is_file():
            problems.append(f"{entry['path']}: missing")
    return problems
