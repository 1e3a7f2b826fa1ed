"""The shard format: plain HDF5 files of scans plus a ``manifest.json`` (a public interface).

Every field is documented in ``docs/shard-format.md``; a team without hd reads shards with h5py
alone. This module holds the writer, the lazy reader, the manifest and the checks of
``hd verify``. Files are written under a temporary name and renamed when complete.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from lidarsim._version import __version__
from lidarsim.errors import LidarsimError

SCAN_SCHEMA = "hd.lidar-scans"
SCAN_SCHEMA_VERSION = "1.0"
MANIFEST_SCHEMA = "hd.dataset-manifest"
MANIFEST_SCHEMA_VERSION = "1.0"
MANIFEST_NAME = "manifest.json"
SPLIT_NAMES: tuple[str, str, str] = ("train", "val", "test")


class ShardFormatError(LidarsimError):
    """A shard or manifest that is not of a format this version reads."""


def sha256_file(path: str | os.PathLike, chunk_bytes: int = 1 << 22) -> str:
    """Hex SHA-256 of a file's bytes, streamed."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk_bytes):
            h.update(block)
    return h.hexdigest()


def check_schema(name: str, version: str, expected_name: str, expected_version: str, where: str) -> None:
    """Refuse a schema of another name or of an unknown major version (minor versions are compatible)."""
    if name != expected_name:
        raise ShardFormatError(f"{where}: schema is {name!r}, expected {expected_name!r}")
    major = str(version).split(".")[0]
    if major != expected_version.split(".")[0]:
        raise ShardFormatError(
            f"{where}: schema {name} version {version} is not supported by this hd "
            f"(reads major version {expected_version.split('.')[0]}); upgrade hd"
        )


def _attr_value(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, (list, tuple)):
        return np.asarray(value)
    return value


def write_attrs(obj: h5py.HLObject, attrs: dict[str, Any]) -> None:
    """Write a flat dict as HDF5 attributes (None becomes an empty string)."""
    for key, value in attrs.items():
        obj.attrs[key] = _attr_value(value)


def partial_path(final: Path) -> Path:
    """Temporary name used while ``final`` is being written (hidden, unique to this process)."""
    return final.with_name(f".{final.name}.partial-{os.getpid()}")


def remove_partials(directory: Path) -> int:
    """Delete leftovers of interrupted writes (``.*.partial-*``) in ``directory``; returns the count."""
    n = 0
    if directory.is_dir():
        for p in directory.glob(".*.partial-*"):
            p.unlink(missing_ok=True)
            n += 1
    return n


def commit_file(tmp: Path, final: Path) -> None:
    """Flush ``tmp`` to disk and rename it to ``final`` (atomic on POSIX)."""
    fd = os.open(tmp, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, final)


@dataclass
class ScanShardWriter:
    """Writes one shard of ``n_scans`` scans; use as a context manager, then ``commit()``.

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
    attrs: dict[str, Any]
    compression: str = "gzip"

    def __enter__(self) -> ScanShardWriter:
        self._tmp = partial_path(self.path)
        self._f = h5py.File(self._tmp, "w")
        f = self._f
        write_attrs(f, {
            "schema": SCAN_SCHEMA,
            "schema_version": SCAN_SCHEMA_VERSION,
            "software": "hd",
            "software_version": __version__,
            "n_scans": self.n_scans,
            "sigmas_m": np.asarray(self.sigmas_m, dtype=np.float64),
            **self.attrs,
        })
        n, r, c, s = self.n_scans, self.rows, self.cols, len(self.sigmas_m)
        kw = compression_kwargs(self.compression)
        small = dict(track_times=False)
        self._d = {
            "scan_index": f.create_dataset("scan_index", (n,), np.int64, **small),
            "split": f.create_dataset("split", (n,), np.uint8, **small),
            "origin_map": f.create_dataset("origin_map", (n, 3), np.float64, **small),
            "sensor_position": f.create_dataset("sensor_position", (n, 3), np.float64, **small),
            "sensor_attitude": f.create_dataset("sensor_attitude", (n, 3, 3), np.float64, **small),
            "points_clean": f.create_dataset("points_clean", (n, r, c, 3), np.float32, chunks=(1, r, c, 3), **kw),
            "points_noisy": f.create_dataset("points_noisy", (n, s, r, c, 3), np.float32, chunks=(1, 1, r, c, 3), **kw),
            "status": f.create_dataset("status", (n, r, c), np.uint8, chunks=(1, r, c), **kw),
            "valid": f.create_dataset("valid", (n, r, c), np.uint8, chunks=(1, r, c), **kw),
        }
        self._d["split"].attrs["names"] = np.asarray(SPLIT_NAMES, dtype=h5py.string_dtype())
        self._d["points_noisy"].attrs["sigmas_m"] = np.asarray(self.sigmas_m, dtype=np.float64)
        self._d["status"].attrs["codes"] = "0 return, 1 miss, 2 dead element, 3 damaged element"
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
    ) -> None:
        """Write scan ``k`` (0-based within the shard)."""
        d = self._d
        d["scan_index"][k] = scan_index
        d["split"][k] = split
        d["origin_map"][k] = origin_map
        d["sensor_position"][k] = sensor_position
        d["sensor_attitude"][k] = sensor_attitude
        d["points_clean"][k] = points_clean
        d["points_noisy"][k] = points_noisy
        d["status"][k] = status
        d["valid"][k] = valid

    def commit(self) -> str:
        """Close, fsync and rename to the final path; returns the shard's sha256."""
        self._f.close()
        commit_file(self._tmp, self.path)
        return sha256_file(self.path)

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            try:
                self._f.close()
            finally:
                Path(self._tmp).unlink(missing_ok=True)


def compression_kwargs(name: str) -> dict[str, Any]:
    """h5py dataset keywords of a compression setting: gzip (deflate 1 + shuffle), lzf or none."""
    base: dict[str, Any] = {"track_times": False}
    if name == "gzip":
        return {**base, "compression": "gzip", "compression_opts": 1, "shuffle": True}
    if name == "lzf":
        return {**base, "compression": "lzf", "shuffle": True}
    if name == "none":
        return base
    raise LidarsimError(f"unknown compression {name!r}; use gzip, lzf or none")


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


class ScanShardReader:
    """Lazy reader of one scan shard; scans are read one at a time.

    Raises:
        ShardFormatError: not an hd scan shard, or an unknown major schema version.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        try:
            self._f = h5py.File(self.path, "r")
        except (OSError, FileNotFoundError) as exc:
            raise ShardFormatError(f"{self.path}: cannot open as HDF5 ({exc.__class__.__name__})") from None
        attrs = self._f.attrs
        check_schema(str(attrs.get("schema", "")), str(attrs.get("schema_version", "")),
                     SCAN_SCHEMA, SCAN_SCHEMA_VERSION, str(self.path))
        self.attrs: dict[str, Any] = {k: _py(v) for k, v in attrs.items()}
        self.sigmas_m: tuple[float, ...] = tuple(float(s) for s in attrs["sigmas_m"])

    def __len__(self) -> int:
        return int(self._f["scan_index"].shape[0])

    def __getitem__(self, k: int) -> Scan:
        f = self._f
        return Scan(
            scan_index=int(f["scan_index"][k]),
            split=SPLIT_NAMES[int(f["split"][k])],
            origin_map=f["origin_map"][k],
            sensor_position=f["sensor_position"][k],
            sensor_attitude=f["sensor_attitude"][k],
            points_clean=f["points_clean"][k],
            points_noisy=f["points_noisy"][k],
            status=f["status"][k],
            valid=f["valid"][k].astype(bool),
        )

    def __iter__(self) -> Iterator[Scan]:
        for k in range(len(self)):
            yield self[k]

    @property
    def h5(self) -> h5py.File:
        """The underlying open h5py file (read-only)."""
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
        return value.decode()
    return value


def write_json_atomic(path: Path, data: dict[str, Any]) -> None:
    """Write JSON to a temporary name and rename it into place."""
    tmp = partial_path(path)
    tmp.write_text(json.dumps(data, indent=2, sort_keys=False) + "\n")
    commit_file(tmp, path)


def read_manifest(directory: str | os.PathLike) -> dict[str, Any]:
    """Read and check ``manifest.json`` of a dataset directory.

    Raises:
        ShardFormatError: no manifest, unreadable JSON, or an unknown schema/major version.
    """
    path = Path(directory) / MANIFEST_NAME
    if not path.is_file():
        raise ShardFormatError(f"{directory}: not an hd dataset (no {MANIFEST_NAME})")
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ShardFormatError(f"{path}: unreadable manifest ({exc})") from None
    check_schema(str(data.get("schema", "")), str(data.get("schema_version", "")),
                 MANIFEST_SCHEMA, MANIFEST_SCHEMA_VERSION, str(path))
    return data


def iter_scans(directory: str | os.PathLike, split: str | None = None) -> Iterator[Scan]:
    """Iterate lazily over every scan of a dataset (optionally one split), in scan order."""
    manifest = read_manifest(directory)
    for entry in manifest["shards"]:
        with ScanShardReader(Path(directory) / entry["path"]) as reader:
            for scan in reader:
                if split is None or scan.split == split:
                    yield scan


def verify_dataset(
    directory: str | os.PathLike, known_schemas: dict[str, str] | None = None
) -> list[str]:
    """Check every file listed in the manifest: presence, sha256, schema and scan count.

    Args:
        directory: the dataset directory.
        known_schemas: schema name -> version this reader understands (default: scan shards);
            other packages add theirs (label shards).

    Returns:
        A list of one-line problems (empty when the dataset is intact).
    """
    known = {SCAN_SCHEMA: SCAN_SCHEMA_VERSION, **(known_schemas or {})}
    directory = Path(directory)
    manifest = read_manifest(directory)
    problems: list[str] = []
    entries = list(manifest.get("shards", []))
    for labelling in manifest.get("labelings", []):
        entries.extend(labelling.get("shards", []))
    for entry in entries:
        path = directory / entry["path"]
        if not path.is_file():
            problems.append(f"{entry['path']}: missing")
            continue
        digest = sha256_file(path)
        if digest != entry["sha256"]:
            problems.append(
                f"{entry['path']}: checksum mismatch (sha256 {digest[:12]}..., manifest says {entry['sha256'][:12]}...)"
            )
            continue
        try:
            with h5py.File(path, "r") as f:
                name = str(f.attrs.get("schema", ""))
                version = str(f.attrs.get("schema_version", ""))
                if name not in known:
                    problems.append(f"{entry['path']}: unknown schema {name!r}")
                    continue
                check_schema(name, version, name, known[name], entry["path"])
                if int(f.attrs.get("n_scans", -1)) != int(entry["n_scans"]):
                    problems.append(
                        f"{entry['path']}: holds {f.attrs.get('n_scans')} scans, manifest says {entry['n_scans']}"
                    )
        except ShardFormatError as exc:
            problems.append(str(exc))
        except OSError:
            problems.append(f"{entry['path']}: not a readable HDF5 file")
    return problems
