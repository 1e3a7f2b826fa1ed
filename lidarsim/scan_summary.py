"""What a dataset's scans are, from the small arrays of its shards: where each scan looked, from how
high, in which split, and a sample of its heights (``hd inspect --plot``).

:func:`scan_summary` reads per scan shard only ``scan_index``, ``split``, ``origin_map``,
``sensor_position`` and ``sensor_attitude`` (a few hundred bytes a scan, each array one checked
chunk) and the sensor's field of view from the file's attributes; no point is read, so a 1000-scan
dataset is summarised in a fraction of a second. :func:`height_sample` reads the clean points of a
few scans per split, spread evenly over each split. Files are opened through the storage layer
(confined to the dataset, every chunk's fletcher32 checksum checked as it is read) but not hashed
whole: ``hd inspect`` checks every file's sha256 first.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hdcore.errors import DamagedFileError
from hdcore.storage import attr_float, confine
from lidarsim.manifest_json import ShardRefJson
from lidarsim.sensor import footprint_corners
from lidarsim.shards import SPLIT_NAMES, ScanShardReader, read_manifest

# hd choice: scans per split whose clean points make the height sample (about 16 000 points each
# for the paper's 128 x 128 detector): enough for a histogram, a few MB read whatever the dataset's size.
HEIGHT_SAMPLE_SCANS = 24


@dataclass(frozen=True)
class ScanSummary:
    """The scans of a dataset, in scan order.

    ``scan_index`` int64 (N,); ``split`` uint8 (N,) (0 train, 1 val, 2 test: ``SPLIT_NAMES``);
    ``origin_map`` float64 (N, 3), map metres of each scan frame's origin; ``altitude_m`` float64
    (N,), the sensor's height above that origin; ``footprints_map`` float64 (N, 4, 2), map metres of
    the detector's four corners on the scan's reference plane (``lidarsim.sensor.footprint_corners``);
    ``shard`` int64 (N,) and ``row`` int64 (N,), where each scan is stored (the manifest's shard
    list and the row in that shard).
    """

    scan_index: np.ndarray
    split: np.ndarray
    origin_map: np.ndarray
    altitude_m: np.ndarray
    footprints_map: np.ndarray
    shard: np.ndarray
    row: np.ndarray

    def split_counts(self) -> dict[str, int]:
        """Scans per split, ``{"train": n, "val": n, "test": n}``."""
        return {name: int((self.split == code).sum()) for code, name in enumerate(SPLIT_NAMES)}


# The arrays of a summary of no scans: shape and dtype of each field, in order.
_EMPTY = (
    ((0,), np.int64),
    ((0,), np.uint8),
    ((0, 3), np.float64),
    ((0,), np.float64),
    ((0, 4, 2), np.float64),
    ((0,), np.int64),
    ((0,), np.int64),
)


def _shard(directory: Path, entry: ShardRefJson) -> ScanShardReader:
    """The scan shard of a manifest entry, confined to the dataset, opened without hashing it whole."""
    what = f"{directory / entry['path']}"
    return ScanShardReader(confine(directory, entry["path"], what), what=what)


def scan_summary(directory: str | os.PathLike) -> ScanSummary:
    """The poses, splits and footprints of every scan of the dataset at ``directory``.

    Raises:
        ShardFormatError: not an hd dataset, a malformed manifest, or a shard that is missing,
            damaged (a chunk failing its checksum) or not as hd writes it (named).
    """
    root = Path(directory)
    manifest = read_manifest(root)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("scan_index", "split", "origin", "position", "attitude")}
    fov: list[tuple[float, float]] = []
    where: list[tuple[np.ndarray, np.ndarray]] = []
    for k, entry in enumerate(manifest["shards"]):
        with _shard(root, entry) as reader:
            f = reader.h5
            n = len(reader)
            parts["scan_index"].append(np.asarray(f["scan_index"][:], np.int64))
            parts["split"].append(np.asarray(f["split"][:], np.uint8))
            parts["origin"].append(np.asarray(f["origin_map"][:], np.float64))
            parts["position"].append(np.asarray(f["sensor_position"][:], np.float64))
            parts["attitude"].append(np.asarray(f["sensor_attitude"][:], np.float64))
            try:
                x, y = attr_float(reader.attrs["sensor_fov_x_deg"]), attr_float(reader.attrs["sensor_fov_y_deg"])
            except (KeyError, TypeError, ValueError) as exc:
                raise DamagedFileError(f"{reader.what}: no readable sensor field of view ({exc})") from exc
            fov += [(x, y)] * n
            where.append((np.full(n, k, np.int64), np.arange(n, dtype=np.int64)))
    if not fov:  # a dataset without scans
        return ScanSummary(*(np.zeros(shape, dtype) for shape, dtype in _EMPTY))
    if int(np.concatenate(parts["split"]).max()) >= len(SPLIT_NAMES):
        raise DamagedFileError(f"{root}: a scan shard holds a split code other than {', '.join(SPLIT_NAMES)}")
    origin = np.concatenate(parts["origin"])
    position = np.concatenate(parts["position"])
    attitude = np.concatenate(parts["attitude"])
    fovs = np.asarray(fov)
    corners = np.empty((len(fovs), 4, 2))
    for x, y in {tuple(v) for v in fovs.tolist()}:  # one field of view per build, in practice
        same = (fovs[:, 0] == x) & (fovs[:, 1] == y)
        corners[same] = footprint_corners(x, y, attitude[same], position[same])
    return ScanSummary(
        scan_index=np.concatenate(parts["scan_index"]),
        split=np.concatenate(parts["split"]),
        origin_map=origin,
        altitude_m=position[:, 2],
        footprints_map=corners + origin[:, None, :2],
        shard=np.concatenate([w[0] for w in where]),
        row=np.concatenate([w[1] for w in where]),
    )


def sample_rows(summary: ScanSummary, split: int, n: int = HEIGHT_SAMPLE_SCANS) -> np.ndarray:
    """Positions (in ``summary``) of at most ``n`` scans of the split code ``split``, spread evenly
    over that split's scans in scan order (its first and last among them)."""
    members = np.flatnonzero(summary.split == split)
    if members.size <= n:
        return members
    return members[np.unique(np.round(np.linspace(0, members.size - 1, n)).astype(np.int64))]


def height_sample(
    directory: str | os.PathLike, summary: ScanSummary, n: int = HEIGHT_SAMPLE_SCANS
) -> tuple[dict[str, np.ndarray], dict[str, int]]:
    """Heights of the clean points (scan frame z, metres above each scan's reference height) of at
    most ``n`` scans per split (:func:`sample_rows`), NaN-free float32 per split, and the number of
    scans each sample holds.

    Raises:
        ShardFormatError: a shard that is missing or damaged (named with the scan).
    """
    root = Path(directory)
    manifest = read_manifest(root)
    chosen = {name: sample_rows(summary, code, n) for code, name in enumerate(SPLIT_NAMES)}
    values: dict[str, list[np.ndarray]] = {name: [] for name in SPLIT_NAMES}
    by_shard: dict[int, list[tuple[str, int]]] = {}
    for name, rows in chosen.items():
        for i in rows.tolist():
            by_shard.setdefault(int(summary.shard[i]), []).append((name, int(summary.row[i])))
    for k in sorted(by_shard):
        with _shard(root, manifest["shards"][k]) as reader:
            points = reader.h5["points_clean"]
            for name, row in by_shard[k]:
                z = np.asarray(points[row][..., 2], np.float32).ravel()
                values[name].append(z[np.isfinite(z)])
    sample = {name: np.concatenate(v) if v else np.zeros(0, np.float32) for name, v in values.items()}
    return sample, {name: int(rows.size) for name, rows in chosen.items()}
