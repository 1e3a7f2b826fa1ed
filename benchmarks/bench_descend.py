"""hd descend speed: median seconds per frame of a 9-frame descent flown online, step by step.

Builds a few descents of 9 frames (1000 m to 250 m, the default 128 x 128 sensor, sigma 7 cm, a
navigation error of 1 m and 0.1 degrees with a walk of a third of that per frame) on the procedural
terrain, then flies each as ``hd descend`` does (``hdnet.descent_flight.fly``): after every frame the
frames so far re-registered to the newest (registered poses) and mosaicked on a 100 x 100 grid at
1 m, the mosaic mapped by an untrained network of the ``cpu`` profile (MC dropout, M = 8; speed does
not depend on training) with a fixed threshold, and the sites ranked and the aim updated.

Prints the CPU model, the threads and the load, then the median seconds per frame of each step
(registration, mosaic, map, sites), per frame in all, the slowest frame (the last: it registers
every frame) and the whole descent; targets: at most 2 s per frame and 20 s per 9-frame descent
on 2 cores. Usage:
    python benchmarks/bench_descend.py [--descents 3] [--samples 8] [--threads 2]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_detect import untrained_run
from bench_mosaic import descent_settings
from machine import cpu_model

from hdlabels.mosaic import descent_frames
from hdlabels.store import DemSpec
from hdnet.descent_flight import FrameStep, fly
from hdnet.detect_settings import DetectSettings
from hdnet.profiles import CPU
from lidarsim.build import build_dataset
from lidarsim.shards import iter_descents

FRAME_TARGET_S = 2.0  # hd choice (issue 44): seconds per frame on 2 cores
DESCENT_TARGET_S = 20.0  # and per 9-frame descent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--descents", type=int, default=3)
    parser.add_argument("--samples", type=int, default=8, help="MC-dropout samples M")
    parser.add_argument("--threads", type=int, default=2, help="torch, Open3D and numba threads")
    args = parser.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", str(args.threads))
    torch.set_num_threads(args.threads)
    dem = DemSpec(gridding="linear")  # 100 x 100 at 1 m, as the cpu profile's DEMs
    print(f"CPU: {cpu_model()}; {os.cpu_count()} logical cores, {args.threads} threads; load {os.getloadavg()[0]:.2f}")
    settings = DetectSettings(mc_samples=args.samples, threshold="nats:0.3", sigma_m=0.07)
    flights: list[list[FrameStep]] = []
    walls: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "descents"
        build = descent_settings(args.descents + 1)  # the first descent warms up (numba, Open3D, oneDNN): not counted
        t0 = time.perf_counter()
        build_dataset(out, build.to_config(), workers=1)
        print(f"built {args.descents + 1} descents of 9 frames in {time.perf_counter() - t0:.1f} s (not counted)")
        run = None
        for k, scans in enumerate(iter_descents(out)):
            frames, target = descent_frames(scans, 0)
            if run is None:
                run = untrained_run(CPU, CPU.width, np.zeros((dem.rows, dem.cols)))
            t0 = time.perf_counter()
            steps = fly(run, frames, target, dem, "registered", settings, (0.3, {}))
            if k:
                flights.append(steps)
                walls.append(time.perf_counter() - t0)
    _report(flights, walls)


def _report(flights: list[list[FrameStep]], walls: list[float]) -> None:
    """Print the medians over every frame flown, the slowest frame and the descents' seconds."""
    steps = [s for flight in flights for s in flight]
    columns = {
        "registration": [s.timing.registration_s for s in steps],
        "mosaic": [s.timing.mosaic_s for s in steps],
        "map": [s.timing.map_s for s in steps],
        "sites": [s.timing.sites_s for s in steps],
        "frame (all four)": [s.timing.total_s for s in steps],
    }
    print(f"{'step':18s} {'median s':>9s} {'max s':>7s}  (over {len(steps)} frames of {len(flights)} descents)")
    for name, values in columns.items():
        print(f"{name:18s} {float(np.median(values)):9.3f} {max(values):7.3f}")
    last = [flight[-1].timing.total_s for flight in flights]
    print(f"last frame (registers all 9): {float(np.median(last)):.3f} s (median)")
    frame = float(np.median(columns["frame (all four)"]))
    descent = float(np.median(walls))
    print(
        f"per frame {frame:.2f} s ({'meets' if frame <= FRAME_TARGET_S else 'misses'} "
        f"the {FRAME_TARGET_S:g} s target); "
        f"per 9-frame descent {descent:.1f} s ({'meets' if descent <= DESCENT_TARGET_S else 'misses'} "
        f"the {DESCENT_TARGET_S:g} s target)"
    )
    diverts = sum(s.divert is not None for s in steps)
    print(f"diverts: {diverts} (an untrained network: not a measure of anything)")
    print(f"load average after the run: {os.getloadavg()[0]:.2f} (other processes share the cores)")


if __name__ == "__main__":
    main()
