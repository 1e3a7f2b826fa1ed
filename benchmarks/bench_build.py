"""Dataset-factory throughput: raw Open3D ``cast_rays`` vs. the end-to-end build, side by side.

On the default procedural terrain and the default trajectory (1000 scans of 128x128 rays):

1. raw: the rays of every scan cast against the same tile meshes the build uses, BVHs built
   beforehand; only ``cast_rays`` is timed;
2. end to end: ``build_dataset`` with three noise levels (noise, transforms, compressed HDF5
   writes, BVH builds, worker start-up included), for each compression setting.

Prints rays/s for each and the ratio end-to-end / raw. With ``--footprint K [K ...]`` it builds
instead the same scans at each footprint (K x K sub-rays per pixel, centroid, constant sigma, gzip)
side by side in one run and prints each build's wall time, its ratio to the first K's and the largest
resident memory of a worker process so far. Usage:
    python benchmarks/bench_build.py [--scans 1000] [--workers 2] [--footprint 1 3 5]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import open3d as o3d

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lidarsim.build import BuildConfig, _procedural_terrain_bytes, build_dataset, procedural_terrain_name
from lidarsim.defaults import PAPER_SIGMAS_M
from lidarsim.footprint import FootprintConfig
from lidarsim.scan import TileScene
from lidarsim.sensor import ray_directions, sensor_attitude
from lidarsim.terrain import DTM
from lidarsim.trajectory import TrajectoryConfig, plan_scans


def raw_cast_rate(dtm_path: Path, config: BuildConfig) -> tuple[float, int]:
    """Rays/s of bare cast_rays over the build's tile meshes (BVH build excluded)."""
    with DTM.open(dtm_path) as dtm:
        valid, transform = dtm.validity_overview(2.0)
        plan = plan_scans(valid, transform, config.sensor, config.trajectory)
        d = ray_directions(config.sensor) @ sensor_attitude().T
        tiles: dict[tuple[int, int], list[int]] = {}
        for m, ij in enumerate(map(tuple, plan.tile_ij.tolist())):
            tiles.setdefault(ij, []).append(m)
        elapsed, n_rays = 0.0, 0
        for tile, members in tiles.items():
            scene = TileScene(dtm, plan.tile_centre_xy(*tile), plan.tile_m / 2 + plan.half_width_m)
            scene.focus(scene.full_window)  # the whole tile's mesh
            probe = o3d.core.Tensor(np.zeros((1, 6), np.float32))  # type: ignore[call-overload]  # stubs omit ndarray
            scene.scene.cast_rays(probe)  # builds the BVH
            rays = np.empty((len(members), *d.shape[:2], 6), np.float32)
            for k, m in enumerate(members):
                x, y = plan.nadir_xy[m]
                z = scene.mean_height(x, y, plan.half_width_m) + config.trajectory.altitude_m
                rays[k, ..., :3] = np.array([x, y, z]) - scene.origin
                rays[k, ..., 3:] = d
            tensor = o3d.core.Tensor(rays.reshape(-1, 6))  # type: ignore[call-overload]  # stubs omit ndarray
            t0 = time.perf_counter()
            scene.scene.cast_rays(tensor)
            elapsed += time.perf_counter() - t0
            n_rays += tensor.shape[0]
    return n_rays / elapsed, n_rays


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=1000)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--footprint", type=int, nargs="+", default=None, help="compare builds at these K")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        base = BuildConfig(sigmas_m=PAPER_SIGMAS_M, trajectory=TrajectoryConfig(n_scans=args.scans))
        t0 = time.perf_counter()
        dtm_path = tmp_path / procedural_terrain_name(base.seed)
        dtm_path.write_bytes(_procedural_terrain_bytes(base.terrain, base.seed, dtm_path))
        print(f"procedural terrain generated in {time.perf_counter() - t0:.1f} s (not counted below)")
        config = BuildConfig(sigmas_m=PAPER_SIGMAS_M, trajectory=base.trajectory, dtm_path=str(dtm_path))
        if args.footprint:
            footprint_builds(tmp_path, config, args.footprint, args.workers)
            return
        raw, n_rays = raw_cast_rate(dtm_path, config)
        print(f"raw cast_rays:            {raw / 1e6:6.2f} M rays/s ({n_rays / 1e6:.1f} M rays, all cores)")
        for compression in ("gzip", "lzf", "none"):
            cfg = BuildConfig(
                sigmas_m=PAPER_SIGMAS_M, trajectory=base.trajectory, dtm_path=str(dtm_path), compression=compression
            )
            t0 = time.perf_counter()
            summary = build_dataset(tmp_path / f"out-{compression}", cfg, workers=args.workers)
            wall = time.perf_counter() - t0
            rate = n_rays / wall
            print(
                f"end-to-end ({compression:4s}, {len(cfg.sigmas_m)} sigma): {rate / 1e6:6.2f} M rays/s, "
                f"{args.scans} scans in {wall:5.1f} s (target < 30 s), {summary.bytes_written / 1e6:.0f} MB, "
                f"ratio end-to-end/raw = {rate / raw:.2f} (target >= 0.8)"
            )


def footprint_builds(tmp_path: Path, config: BuildConfig, ks: list[int], workers: int) -> None:
    """The same build at each footprint K, one after the other: wall time, ratio to the first, worker memory."""
    first = None
    pixels = config.trajectory.n_scans * config.sensor.rows * config.sensor.cols
    for k in ks:
        cfg = BuildConfig(
            sigmas_m=config.sigmas_m,
            trajectory=config.trajectory,
            dtm_path=config.dtm_path,
            footprint=FootprintConfig(samples=k),
        )
        t0 = time.perf_counter()
        build_dataset(tmp_path / f"out-k{k}", cfg, workers=workers)
        wall = time.perf_counter() - t0
        first = first or wall
        rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024  # KiB on Linux
        print(
            f"footprint K = {k} ({k * k} rays per pixel, {len(cfg.sigmas_m)} sigma): {config.trajectory.n_scans} scans "
            f"in {wall:6.1f} s, {pixels * k * k / wall / 1e6:5.2f} M rays/s, {wall / first:4.2f} x K = {ks[0]} "
            f"(target for K = 3: <= 2.5 x K = 1); largest worker so far {rss:.0f} MiB"
        )


if __name__ == "__main__":
    main()
