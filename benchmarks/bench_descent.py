"""Descent builds against single-frame builds: build time per frame, side by side in one run.

On the default procedural terrain, with the paper's three noise levels and 128x128 rays per scan:

1. single frames: today's build of N scans at 500 m (the paper's);
2. descents: N / K descents of K frames from 1000 m to 250 m (``--altitudes START:END``; vertical,
   or along ``--approach`` degrees), with a navigation error of 1 m and 0.1 degrees (bias) and 0.1 m and 0.01 degrees
   (walk per frame): the same number of scans;
3. single frames at the descents' start altitude (1000 m): the same N scans, each tile's terrain as
   wide as the descents' (the footprint of frame 0 sets it), so that the cost of the descent
   machinery itself shows apart from that of a wider footprint.

The builds alternate ``--repeat`` times (the best of each is kept, so that a burst of load on a
shared machine hits all alike) and the script prints each build's seconds per frame and the ratios
descent / single (the target: <= 1, a descent costs no more per frame than today's scans) and
descent / single at 1000 m. Usage:
    python benchmarks/bench_descent.py [--descents 111] [--frames 9] [--workers 2] [--repeat 2] [--approach 0]
        [--altitudes 1000:250]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lidarsim.build import BuildConfig, _procedural_terrain_bytes, build_dataset, procedural_terrain_name
from lidarsim.defaults import PAPER_SIGMAS_M
from lidarsim.descent import DescentConfig
from lidarsim.navigation import NavigationError
from lidarsim.trajectory import TrajectoryConfig

# The navigation error of the descents (1-sigma per axis): the middle level.
NAV = NavigationError(position_sigma_m=1.0, position_walk_m=0.1, attitude_sigma_deg=0.1, attitude_walk_deg=0.01)


def configs(
    dtm_path: Path, descents: int, frames: int, approach_deg: float, altitudes_m: tuple[float, float] = (1000.0, 250.0)
) -> dict[str, BuildConfig]:
    """The single-frame builds (500 m, the descents' start altitude) and the descent build of the same
    number of scans on the same terrain."""
    n = descents * frames
    start, end = altitudes_m
    descent = DescentConfig(
        frames=frames, altitude_start_m=start, altitude_end_m=end, approach_deg=approach_deg, nav=NAV
    )
    return {
        "single": BuildConfig(sigmas_m=PAPER_SIGMAS_M, trajectory=TrajectoryConfig(n_scans=n), dtm_path=str(dtm_path)),
        "descent": BuildConfig(
            sigmas_m=PAPER_SIGMAS_M,
            trajectory=TrajectoryConfig(n_scans=n, descent=descent),
            dtm_path=str(dtm_path),
        ),
        "single-high": BuildConfig(
            sigmas_m=PAPER_SIGMAS_M,
            trajectory=TrajectoryConfig(n_scans=n, altitude_m=descent.altitude_start_m),
            dtm_path=str(dtm_path),
        ),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--descents", type=int, default=111)
    parser.add_argument("--frames", type=int, default=9)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--approach", type=float, default=0.0, help="approach angle from the vertical, degrees")
    parser.add_argument("--altitudes", default="1000:250", help="the descents' START:END altitudes, metres")
    args = parser.parse_args()
    start, end = (float(x) for x in args.altitudes.split(":"))
    n = args.descents * args.frames
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        base = BuildConfig()
        t0 = time.perf_counter()
        dtm_path = tmp_path / procedural_terrain_name(base.seed)
        dtm_path.write_bytes(_procedural_terrain_bytes(base.terrain, base.seed, dtm_path))
        print(f"procedural terrain generated in {time.perf_counter() - t0:.1f} s (not counted below)")
        builds = configs(dtm_path, args.descents, args.frames, args.approach, (start, end))
        if start == builds["single"].trajectory.altitude_m:  # the same build as the first
            del builds["single-high"]
        best = {name: float("inf") for name in builds}
        for run in range(args.repeat):
            for name, config in builds.items():
                out = tmp_path / f"{name}-{run}"
                t0 = time.perf_counter()
                build_dataset(out, config, workers=args.workers)
                best[name] = min(best[name], time.perf_counter() - t0)
                shutil.rmtree(out)
        what = {
            "single": f"{n} single frames at 500 m",
            "descent": f"{args.descents} x {args.frames} frames, {start:g} -> {end:g} m, approach {args.approach:g}°",
            "single-high": f"{n} single frames at {start:g} m",
        }
        for name in builds:
            print(
                f"{what[name]:55s}: {best[name]:6.1f} s, {1000 * best[name] / n:6.1f} ms per frame "
                f"(best of {args.repeat}, {args.workers} workers, {len(PAPER_SIGMAS_M)} sigma)"
            )
        print(f"ratio descent / single per frame = {best['descent'] / best['single']:.2f} (target <= 1)")
        if "single-high" in best:
            print(f"ratio descent / single at {start:g} m per frame = {best['descent'] / best['single-high']:.2f}")


if __name__ == "__main__":
    main()
