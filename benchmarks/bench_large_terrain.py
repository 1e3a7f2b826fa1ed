"""Large-terrain builds: ``mars-jezero-rocks`` against ``mars-jezero``, side by side in one run.

Both recipes scan the same 1000 positions of the Jezero floor at the paper's three noise levels;
the rocks recipe scans the DTM resampled to 0.5 m with a rock population (56 M cells, against
4 M), so each ray-casting mesh holds some 14 times the triangles. Each round builds both datasets
end to end with ``build_dataset`` (terrain, planning, workers, compressed writes), in alternating
order so that a change of the machine's load touches both alike, and prints both wall times and
their ratio (the issue's target: rocks <= 2 x plain), with the CPU and the load average. The rocks
terrain's preparation (resampling, rock stamping, its GeoTIFF) is timed apart as well.

    python benchmarks/bench_large_terrain.py [--rounds 1] [--workers 2] [--scans 1000]

``--scans`` below the recipes' 1000 builds fewer scans over the same floor (a sparser plan: more
tiles per scan, so the ratio is higher than at 1000).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from machine import cpu_model

from hdcore.errors import HdWarning
from lidarsim.base_relief import rocks_on_base, rocky_geotiff_bytes
from lidarsim.build import BuildConfig, build_dataset
from lidarsim.recipe import load_recipe


def recipe_config(name: str, scans: int) -> BuildConfig:
    """The recipe's build settings, at ``scans`` scans."""
    config = load_recipe(name).build
    if scans != config.trajectory.n_scans:
        config = dataclasses.replace(config, trajectory=dataclasses.replace(config.trajectory, n_scans=scans))
    return config


def timed_build(out: Path, config: BuildConfig, workers: int) -> float:
    """Wall seconds of one build from scratch (its output removed afterwards)."""
    t0 = time.perf_counter()
    build_dataset(out, config, workers=workers)
    wall = time.perf_counter() - t0
    shutil.rmtree(out)
    return wall


def terrain_seconds(config: BuildConfig) -> float:
    """Wall seconds of the rocks terrain in memory: resampling, rocks and the GeoTIFF's bytes."""
    assert config.dtm_path is not None
    t0 = time.perf_counter()
    rocky = rocks_on_base(config.dtm_path, config.terrain, config.seed, config.terrain.spacing_m)
    rocky_geotiff_bytes(rocky, "rocks.tif")
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--scans", type=int, default=1000)
    args = parser.parse_args()
    warnings.simplefilter("ignore", HdWarning)  # mars-jezero's: its DTM is coarser than the scans (as published)
    plain, rocks = recipe_config("mars-jezero", args.scans), recipe_config("mars-jezero-rocks", args.scans)
    print(f"CPU: {cpu_model()}, {os.cpu_count()} cores; {args.workers} workers; {args.scans} scans x 3 sigma")
    terrain_seconds(rocks)  # numba's kernels compiled (or read from their cache) before any timing
    ratios = []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            load = os.getloadavg()[0]
            order = [("plain", plain), ("rocks", rocks)]
            if r % 2:
                order.reverse()
            walls = {name: timed_build(Path(tmp) / name, cfg, args.workers) for name, cfg in order}
            prep = terrain_seconds(rocks)
            ratios.append(walls["rocks"] / walls["plain"])
            print(
                f"round {r + 1}: mars-jezero {walls['plain']:6.1f} s, mars-jezero-rocks {walls['rocks']:6.1f} s "
                f"(of which its terrain in memory {prep:4.1f} s), ratio {ratios[-1]:4.2f} (target <= 2); "
                f"load average {load:.1f} -> {os.getloadavg()[0]:.1f}"
            )
    print(f"median ratio rocks / plain: {statistics.median(ratios):.2f} over {len(ratios)} round(s)")


if __name__ == "__main__":
    main()
