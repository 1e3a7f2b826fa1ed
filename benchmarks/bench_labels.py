"""Label throughput: hazard maps and P(safe) per DEM in both conventions, beside the paper's own replica.

Run: ``.venv/bin/python benchmarks/bench_labels.py [--dems 20] [--reference-python PY --reference-src DIR]``.
Prints, side by side in one run: per-DEM time of the deterministic maps, of P(safe), and of both
from one pass (numba and numpy back ends, 100x100 DEMs at 1 m), for the paper convention
(product baseline) and the hd convention ("min" baseline); with ``--reference-python`` and
``--reference-src`` (pydem at commit e7734ae in a throw-away environment, see
``benchmarks/reference_pydem.py``; also read from HD_PYDEM_PYTHON / HD_PYDEM_SRC) the replica's
own numba code (``dhd`` + ``alhat``) on the same DEMs and the speed-up; the loop reference of the
hd convention on small DEMs; the gridding of a 128x128 scan by every method; and the projected
time to label 1000 scans x 3 sigma. hd's kernels are serial (one core); the replica's are
numba-parallel and use every core of the machine.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "hdlabels"))

from alhat_reference import reference_maps

from hdlabels.alhat import hazard_and_probability, hazard_maps, safety_probability
from hdlabels.defaults import GRIDDING, GRIDDINGS
from hdlabels.grid import grid_points
from hdlabels.lander import Lander


def terrain(rng: np.random.Generator, n: int) -> np.ndarray:
    """Hills plus sparse rocks (metres), a mix of safe and unsafe sites."""
    return gaussian_filter(rng.normal(0.0, 1.0, (n, n)), 3.0) * 2.0 + (rng.random((n, n)) < 0.02) * 0.15


def per_call_ms(fn: Callable[..., object], inputs: list[np.ndarray]) -> float:
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


def reference_ms(python: str, src: str, dems: list[np.ndarray], sigma: float, repeat: int) -> tuple[float, float]:
    """Per-DEM milliseconds of the replica's dhd and alhat (median of ``repeat`` calls), in its own environment."""
    runner = Path(__file__).resolve().parent / "reference_pydem.py"
    with tempfile.TemporaryDirectory() as tmp:
        inputs, outputs = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(inputs, dems=np.stack(dems[:1]).astype(np.float32), sigmas=np.array([sigma]))
        subprocess.run(
            [python, str(runner), str(inputs), str(outputs), "--src", src, "--repeat", str(repeat)],
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        out = np.load(outputs)
        return 1e3 * float(out["dhd_s"]), 1e3 * float(out["alhat_s"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dems", type=int, default=20, help="100x100 DEMs timed per back end")
    parser.add_argument("--ref-size", type=int, default=40, help="side of the DEMs the loop reference runs on")
    parser.add_argument("--ref-dems", type=int, default=2, help="DEMs the loop reference runs on")
    parser.add_argument(
        "--reference-python", default=os.environ.get("HD_PYDEM_PYTHON"), help="python of pydem's throw-away environment"
    )
    parser.add_argument("--reference-src", default=os.environ.get("HD_PYDEM_SRC"), help="pydem checkout (e7734ae)")
    args = parser.parse_args()
    rng = np.random.default_rng(0)

    dems = [terrain(rng, 100).astype(np.float32) for _ in range(args.dems)]
    both_ms: dict[str, float] = {}
    for name, lander in (("paper", Lander()), ("hd", Lander(convention="hd"))):
        print(
            f"{name} convention ({lander.baseline_combine} baseline), per 100x100 DEM at 1 m "
            f"({args.dems} DEMs, median):"
        )
        for sigma in (0.0167, 0.07):
            noisy = [(d + rng.normal(0.0, sigma, d.shape)).astype(np.float32) for d in dems]
            for backend in ("numba", "numpy"):
                det = per_call_ms(lambda d, b=backend, la=lander: hazard_maps(d, 1.0, la, backend=b), dems)
                prob = per_call_ms(
                    lambda d, b=backend, la=lander, s=sigma: safety_probability(d, 1.0, s, la, backend=b), noisy
                )
                both = per_call_ms(
                    lambda d, b=backend, la=lander, s=sigma: hazard_and_probability(d, 1.0, s, la, backend=b), noisy
                )
                print(
                    f"  sigma {sigma * 100:4.2f} cm {backend:6s} deterministic maps {det:7.2f} ms   "
                    f"P(safe) {prob:7.2f} ms"
                    f"   both maps from one pass {both:7.2f} ms (target <= 10 ms)"
                )
                if backend == "numba":
                    both_ms[f"{name} {sigma}"] = both
                    both_ms[f"{name} {sigma} det"] = det
                    both_ms[f"{name} {sigma} prob"] = prob

    if args.reference_python and args.reference_src:
        print("the paper's replica (pydem e7734ae, numba, parallel) on the same DEMs, per DEM:")
        for sigma in (0.0167, 0.07):
            dhd, alhat = reference_ms(args.reference_python, args.reference_src, dems, sigma, repeat=5)
            ours = both_ms[f"paper {sigma}"]
            print(
                f"  sigma {sigma * 100:4.2f} cm: dhd {dhd:7.1f} ms + alhat {alhat:7.1f} ms = {dhd + alhat:7.1f} ms; "
                f"hd paper convention, both maps from one pass {ours:6.2f} ms: {(dhd + alhat) / ours:5.0f}x faster "
                "(target >= 5x)"
            )
    else:
        print("the paper's replica: skipped (give --reference-python and --reference-src)")

    lander = Lander(convention="hd")
    small = [terrain(rng, args.ref_size) for _ in range(args.ref_dems)]
    ref = per_call_ms(lambda d: reference_maps(d, 1.0, lander), small)
    print(f"hd convention, loop reference vs fast path, {args.ref_dems} DEMs of {args.ref_size}x{args.ref_size}:")
    for backend in ("numba", "numpy"):
        fast = per_call_ms(lambda d, b=backend: hazard_maps(d, 1.0, lander, backend=b), small * 5)
        print(f"  reference {ref:9.1f} ms   {backend:6s} {fast:7.2f} ms   ratio {ref / fast:8.0f}x")

    def hills(k: int) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        return lambda x, y: 2 * np.sin(x / 7 + k) + np.cos(y / 5)

    scans = [nadir_scan(hills(k)) for k in range(5)]
    print("grid_points per 128x128 scan -> 100x100 DEM:")
    grid_ms = {}
    for method in GRIDDINGS:
        backends = ("numba", "numpy") if method == "linear" else ("auto",)
        for backend in backends:
            grid_ms[f"{method} {backend}"] = per_call_ms(
                lambda p, b=backend, m=method: grid_points(p, method=m, backend=b), scans
            )
            print(f"  {method:8s} {backend:6s} {grid_ms[f'{method} {backend}']:8.2f} ms")

    for name, grid in (("paper", f"{GRIDDING['paper']} auto"), ("hd", "linear numba")):
        det, prob = both_ms[f"{name} 0.07 det"], both_ms[f"{name} 0.07 prob"]
        total = 1000 * (grid_ms[grid] + det) + 3000 * (grid_ms[grid] + prob)
        print(
            f"projected, {name} convention: 1000 scans x 3 sigma (grid + labels + P(safe), numba, one core): "
            f"{total / 1e3:.1f} s"
        )


if __name__ == "__main__":
    main()
