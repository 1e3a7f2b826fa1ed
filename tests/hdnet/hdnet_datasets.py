"""Tiny labelled hd datasets built in code (real shards, real labels) for the hdnet data/fit/eval tests.

A 400 x 400 m GeoTIFF of smooth seeded hills (2 m standard deviation, 12 m correlation) with 60
small rocks gives about half safe pixels; 20 scans of a 48 x 48 detector at 500 m, two noise
levels (1.67 cm and 7 cm), 10 scans per shard; splits 16 / 2 / 2. Building and labelling take ~1.5 s.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import ndimage

from hdlabels.labeling import label_dataset
from lidarsim.build import BuildConfig, build_dataset
from lidarsim.sensor import SensorConfig
from lidarsim.shards import read_manifest, sha256_file, write_json_atomic
from lidarsim.trajectory import TrajectoryConfig
from tests.geotiff import write_geotiff

SIGMAS_M = (0.0167, 0.07)


def hills_dtm(path: Path, n: int = 400, relief_m: float = 2.0, seed: int = 3) -> Path:
    """Smooth seeded hills plus rocks, 1 m/px, as a float32 GeoTIFF at ``path``."""
    rng = np.random.default_rng(seed)
    z = ndimage.gaussian_filter(rng.normal(0.0, 1.0, (n, n)), 12)
    z = z / z.std() * relief_m
    rocks = np.zeros((n, n))
    idx = rng.integers(0, n, (60, 2))
    rocks[idx[:, 0], idx[:, 1]] = 1.0
    z += ndimage.gaussian_filter(rocks, 1.5) * 8.0
    return write_geotiff(path, z)


def build_labelled(root: Path, n_scans: int = 20, sigmas_m: tuple[float, ...] = SIGMAS_M, label: bool = True) -> Path:
    """Build (and label) a tiny dataset under ``root``; returns the dataset directory."""
    root.mkdir(parents=True, exist_ok=True)
    dtm = hills_dtm(root / "hills.tif")
    out = root / "dataset"
    config = BuildConfig(
        sigmas_m=sigmas_m,
        sensor=SensorConfig(rows=48, cols=48),
        trajectory=TrajectoryConfig(n_scans=n_scans, altitude_m=500.0),
        dtm_path=str(dtm),
        shard_size=10,
    )
    build_dataset(out, config, workers=1)
    if label:
        label_dataset(out, workers=1)
    return out


def reseal(dataset: Path) -> None:
    """Record the current sha256 of every file in the manifest (after a test edited shards on purpose)."""
    manifest = read_manifest(dataset)
    for entry in manifest["shards"] + [e for lab in manifest["labelings"] for e in lab["shards"]]:
        entry["sha256"] = sha256_file(dataset / entry["path"])
        entry["size_bytes"] = (dataset / entry["path"]).stat().st_size
    write_json_atomic(dataset / "manifest.json", manifest)
