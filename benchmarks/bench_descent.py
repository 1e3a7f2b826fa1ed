"""Descent builds against single-frame builds: build time per frame, side by side in one run.

On the default procedural terrain, with the paper's three noise levels and 128x128 rays per scan:

1. single frames: today's build of N scans at 500 m;
2. descents: N / K descents of K frames from 1000 m to 250 m (vertical, or along ``--approach``
   degrees), with a navigation error of 1 m and 0.1 degrees (bias) and 0.1 m and 0.01 degrees
   (walk per frame): the same number of scans.

The two builds alternate ``--repeat`` times (the best of each is kept, so that a burst of load on a
shared machine hits both alike) and the script prints each build's seconds per frame and the ratio
descent / single (target: <= 1, a descent costs no more per frame). Usage:
    python benchmarks/bench_descent.py [--descents 111] [--frames 9] [--workers 2] [--repeat 2] [--approach 0]
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


def configs(dtm_path: Path, descents: int, frames: int, approach_deg: float) -> dict[str, BuildConfig]:
    """The single-frame and the descent build of the same number of scans on the same terrain."""
    n = descents * frames
    descent = DescentConfig(frames=frames, approach_deg=approach_deg, nav=NAV)
    return {
        "single": BuildConfig(sigmas_m=PAPER_SIGMAS_M, trajectory=TrajectoryConfig(n_scans=n), dtm_path=str(dtm_path)),
        "descent": BuildConfig(
            sigmas_m=PAPER_SIGMAS_M,
            trajectory=TrajectoryConfig(n_scans=n, descent=descent),
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
    args = parser.parse_args()
    n = args.descents * args.frames
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        base = BuildConfig()
        t0 = time.perf_counter()
        dtm_path = tmp_path / procedural_terrain_name(base.seed)
        dtm_path.write_bytes(_procedural_terrain_bytes(base.terrain, base.seed, dtm_path))
        print(f"procedural terrain generated in {time.perf_counter() - t0:.1f} s (not counted below)")
        builds = configs(dtm_path, args.descents, args.frames, args.approach)
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
            "descent": f"{args.descents} descents x {args.frames} frames, 1000 -> 250 m, approach {args.approach:g}°",
        }
        for name in builds:
            print(
                f"{what[name]:55s}: {best[name]:6.1f} s, {1000 * best[name] / n:6.1f} ms per frame "
                f"(best of {args.repeat}, {args.workers} workers, {len(PAPER_SIGMAS_M)} sigma)"
            )
        print(f"ratio descent / single per frame = {best['descent'] / best['single']:.2f} (target <= 1)")


if __name__ == "__main__":
    main()
