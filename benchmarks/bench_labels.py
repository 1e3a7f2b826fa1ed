"""Label throughput: hazard maps and P(safe) per DEM, the loop reference on the same DEMs, gridding.

Run: ``.venv/bin/python benchmarks/bench_labels.py [--dems 20] [--ref-size 40]``. Prints, side by
side in one run: per-DEM time of the deterministic maps and of P(safe) (numba and numpy back ends,
100x100 DEMs at 1 m), the loop reference and the fast path on the same small DEMs with their
ratio, ``grid_points`` per 128x128 scan, and the projected time to label 1000 scans x 3 sigma.
Single-threaded: set NUMBA_NUM_THREADS / OMP_NUM_THREADS=1 for one core (the kernels are serial).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "hdlabels"))

from alhat_reference import reference_maps  # noqa: E402

from hdlabels.alhat import hazard_maps, probability_from_maps, safety_probability  # noqa: E402
from hdlabels.grid import grid_points  # noqa: E402
from hdlabels.lander import Lander  # noqa: E402


def terrain(rng: np.random.Generator, n: int) -> np.ndarray:
    """Hills plus sparse rocks (metres), a mix of safe and unsafe sites."""
    return gaussian_filter(rng.normal(0.0, 1.0, (n, n)), 3.0) * 2.0 + (rng.random((n, n)) < 0.02) * 0.15


def per_call_ms(fn: Callable[[np.ndarray], object], inputs: list[np.ndarray]) -> float:
    """Median wall time of ``fn`` over ``inputs``, milliseconds (one warm-up call first)."""
    fn(inputs[0])
    times = []
    for x in inputs:
        t0 = time.perf_counter()
        fn(x)
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def nadir_scan(dem_fn: Callable[[np.ndarray, np.ndarray], np.ndarray], n: int = 128) -> np.ndarray:
    """Organised (n, n, 3) returns of a 12 deg nadir sensor at 500 m over z = dem_fn(x, y)."""
    u = math.tan(math.radians(6.0)) * (2 * (np.arange(n) + 0.5) / n - 1)
    dx, dy = np.meshgrid(u, -u)
    d = np.stack([dx, dy, -np.ones_like(dx)], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    t = np.full(dx.shape, 500.0)
    for _ in range(20):
        p = np.array([0.0, 0.0, 500.0]) + t[..., None] * d
        t = t + (p[..., 2] - dem_fn(p[..., 0], p[..., 1])) / -d[..., 2]
    return (np.array([0.0, 0.0, 500.0]) + t[..., None] * d).astype(np.float32)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dems", type=int, default=20, help="100x100 DEMs timed per back end")
    parser.add_argument("--ref-size", type=int, default=40, help="side of the DEMs the loop reference runs on")
    parser.add_argument("--ref-dems", type=int, default=2, help="DEMs the loop reference runs on")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    lander = Lander()
    sigma = 0.03

    dems = [terrain(rng, 100) for _ in range(args.dems)]
    noisy = [d + rng.normal(0.0, sigma, d.shape) for d in dems]
    print(f"per 100x100 DEM at 1 m ({args.dems} DEMs, median):")
    rows = {}
    for backend in ("numba", "numpy"):
        det = per_call_ms(lambda d, b=backend: hazard_maps(d, 1.0, lander, backend=b), dems)
        prob = per_call_ms(lambda d, b=backend: safety_probability(d, 1.0, sigma, lander, backend=b), noisy)
        rows[backend] = (det, prob)
        print(f"  {backend:6s} deterministic maps {det:8.2f} ms   P(safe) {prob:8.2f} ms   both {det + prob:8.2f} ms")
        one = per_call_ms(
            lambda d, b=backend: probability_from_maps(hazard_maps(d, 1.0, lander, backend=b), sigma, lander), noisy
        )
        print(f"  {backend:6s} both maps of one DEM (slope, roughness, label and P(safe) from one pass): "
              f"{one:8.2f} ms (target <= 10 ms)")

    small = [terrain(rng, args.ref_size) for _ in range(args.ref_dems)]
    ref = per_call_ms(lambda d: reference_maps(d, 1.0, lander), small)
    print(f"loop reference vs fast path, {args.ref_dems} DEMs of {args.ref_size}x{args.ref_size}:")
    for backend in ("numba", "numpy"):
        fast = per_call_ms(lambda d, b=backend: hazard_maps(d, 1.0, lander, backend=b), small * 5)
        print(f"  reference {ref:9.1f} ms   {backend:6s} {fast:7.2f} ms   ratio {ref / fast:8.0f}x")

    scans = [nadir_scan(lambda x, y, k=k: 2 * np.sin(x / 7 + k) + np.cos(y / 5)) for k in range(5)]
    print("grid_points per 128x128 scan -> 100x100 DEM:")
    grid_ms = {}
    for backend in ("numba", "numpy"):
        grid_ms[backend] = per_call_ms(lambda p, b=backend: grid_points(p, backend=b), scans)
        print(f"  {backend:6s} {grid_ms[backend]:8.2f} ms")

    det, prob = rows["numba"]
    total = 1000 * (grid_ms["numba"] + det) + 3000 * (grid_ms["numba"] + prob)
    print(f"projected: 1000 scans x 3 sigma (grid + labels + P(safe), numba, one core): {total / 1e3:.1f} s")


if __name__ == "__main__":
    main()
