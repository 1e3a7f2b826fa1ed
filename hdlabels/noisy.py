"""Noisy DEMs at any noise level, made from a dataset's clean points.

A dataset stores clean points and the noisy points of a few noise levels. Training across noise
levels and the noise sweep of an evaluation need noisy DEMs at other levels: this module makes
them with the factory's own noise model (``lidarsim.noise``: Gaussian range noise along each ray,
seeded streams) and the labelling's own gridding (``hdlabels.grid.grid_points`` with the
labelling's ``DemSpec``), the code path of ``hd build-dataset`` + ``hd label``. At a stored noise
level, with the dataset's seed and ``realisation=None``, the DEM equals the stored ``dem_noisy``
bit for bit.

Usage::

    maker = NoisyDems.of_dataset(dataset_dir, dem_spec)
    scans = maker.read_scans(dataset_dir, label_shard_entry, rows)   # ranges recovered once
    dem = maker.dem(scans[0], sigma_m=0.05)                           # float32 (rows, cols), metres
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hdcore.storage import attr_int
from hdlabels.errors import HdLabelsError
from hdlabels.grid import grid_points
from hdlabels.store import DemSpec, LabelShardEntry
from lidarsim.errors import LidarsimError
from lidarsim.location import dataset_label
from lidarsim.manifest_json import ShardRefJson
from lidarsim.noise import noisy_points, recover_ranges, scan_directions
from lidarsim.scan import STATUS_DAMAGED
from lidarsim.sensor import SensorConfig
from lidarsim.shards import MANIFEST_KIND_MOSAICS, open_scan_shard, read_manifest


@dataclass(frozen=True)
class CleanScan:
    """One scan reduced to what its noisy points at any sigma are made from.

    ``ranges_m``: float32 (rows, cols) ranges the ray caster returned, metres, NaN where none;
    ``directions``: float64 (rows, cols, 3) unit rays in the scan frame (shared by the scans of
    one attitude); ``sensor_position``: (3,) metres, scan frame; ``damaged``: (rows, cols) bool
    damaged detector elements, or None; ``noise_scale``: (rows, cols) factor on every sigma of a
    scan of the snr noise model (shard format 1.2), None for the constant sigma.
    """

    scan_index: int
    ranges_m: np.ndarray
    directions: np.ndarray
    sensor_position: np.ndarray
    damaged: np.ndarray | None
    noise_scale: np.ndarray | None = None


class NoisyDems:
    """Noisy DEMs of one dataset's scans at any noise level (see the module docstring).

    Args:
        sensor: the detector the dataset was built with (its scan shards' ``sensor_*`` attributes).
        seed: the dataset's master seed.
        dem: the labelling's DEM grid and gridding.
    """

    def __init__(self, sensor: SensorConfig, seed: int, dem: DemSpec) -> None:
        self.sensor = sensor
        self.seed = int(seed)
        self.dem_spec = dem
        self._directions: dict[bytes, np.ndarray] = {}

    @classmethod
    def of_dataset(cls, dataset_dir: str | os.PathLike, dem: DemSpec) -> NoisyDems:
        """The maker for ``dataset_dir`` (sensor and seed read from its first scan shard)."""
        manifest = read_manifest(dataset_dir)
        if manifest.get("kind") == MANIFEST_KIND_MOSAICS:
            raise HdLabelsError(
                f"{dataset_label(dataset_dir)}: a mosaic dataset's noise levels cannot be made on the fly (its noisy "
                "mosaics come from registering noisy frames): train on its stored noise levels"
            )
        shards = manifest.get("shards") or []
        if not shards:
            raise HdLabelsError(f"{dataset_label(dataset_dir)}: the manifest lists no scan shards.")
        try:
            with open_scan_shard(dataset_dir, shards[0]) as reader:
                return cls(SensorConfig.from_attrs(reader.attrs), attr_int(reader.attrs["seed"]), dem)
        except (KeyError, TypeError, ValueError) as exc:
            raise HdLabelsError(
                f"{dataset_label(dataset_dir)}: its scan shards lack the sensor or the seed ({exc})."
            ) from exc

    def directions(self, attitude: np.ndarray) -> np.ndarray:
        """Ray directions of an attitude (cached: a fixed-attitude trajectory shares one array)."""
        att = np.ascontiguousarray(attitude, dtype=np.float64)
        key = att.tobytes()
        d = self._directions.get(key)
        if d is None:
            d = self._directions[key] = scan_directions(self.sensor, att)
            d.setflags(write=False)
        return d

    def clean_scan(
        self,
        points_clean: np.ndarray,
        status: np.ndarray,
        sensor_position: np.ndarray,
        attitude: np.ndarray,
        scan_index: int,
        noise_scale: np.ndarray | None = None,
    ) -> CleanScan:
        """A scan's :class:`CleanScan` from its stored clean points, status and pose (and, for the
        snr noise model, its stored per-element ``noise_scale``).

        Raises:
            LidarsimError: clean points that are not this sensor's returns (see ``recover_ranges``),
                naming the scan.
        """
        d = self.directions(attitude)
        try:
            ranges = recover_ranges(points_clean, sensor_position, d).astype(np.float32)
        except LidarsimError as exc:
            raise type(exc)(f"scan {scan_index}: {exc}") from exc
        damaged = np.asarray(status) == STATUS_DAMAGED
        return CleanScan(
            int(scan_index),
            ranges,
            d,
            np.asarray(sensor_position, dtype=np.float64).copy(),
            damaged if damaged.any() else None,
            None if noise_scale is None else np.asarray(noise_scale, dtype=np.float64),
        )

    def read_scans(
        self, dataset_dir: str | os.PathLike, shard: LabelShardEntry, rows: Sequence[int]
    ) -> list[CleanScan]:
        """The clean scans at ``rows`` of the scan shard behind one label shard entry of a labelling
        (its ``source_path`` and ``source_sha256``; the shard is checked against the checksum)."""
        source: ShardRefJson = {"path": shard.source_path, "sha256": shard.source_sha256}
        with open_scan_shard(Path(dataset_dir), source) as reader:
            f = reader.h5
            return [
                self.clean_scan(
                    f["points_clean"][r],
                    f["status"][r],
                    f["sensor_position"][r],
                    f["sensor_attitude"][r],
                    int(f["scan_index"][r]),
                    f["noise_scale"][r] if "noise_scale" in f else None,
                )
                for r in rows
            ]

    def points(self, scan: CleanScan, sigma_m: float, realisation: int | None = None) -> np.ndarray:
        """Noisy points (float32 (rows, cols, 3), scan frame, metres) of ``scan`` at ``sigma_m`` metres."""
        r = scan.ranges_m.astype(np.float64)
        return noisy_points(
            r,
            scan.directions,
            scan.sensor_position,
            float(sigma_m),
            self.seed,
            scan.scan_index,
            scan.damaged,
            self.sensor.damaged_error_m,
            realisation,
            scan.noise_scale,
        )

    def dem(self, scan: CleanScan, sigma_m: float, realisation: int | None = None) -> np.ndarray:
        """The noisy DEM (float32 (rows, cols), metres, NaN where unsupported) of ``scan`` at ``sigma_m``.

        ``realisation``: None for the dataset's own noise draw at this level (equal to the stored
        DEM at a stored level), k >= 0 for the k-th independent other draw.
        """
        spec = self.dem_spec
        return grid_points(
            self.points(scan, sigma_m, realisation), (spec.rows, spec.cols), spec.spacing_m, method=spec.gridding
        )
