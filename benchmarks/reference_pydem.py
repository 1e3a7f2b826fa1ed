"""Run the paper's ALHAT replica (pydem, commit e7734ae) on DEMs, in pydem's own environment.

Not part of hd and not a dependency: ``benchmarks/bench_labels.py`` and
``scripts/compare_reference.py`` call this file with the Python of a throw-away virtual environment
that holds pydem's requirements (numpy < 1.24, numba, scipy) and point it at a checkout of pydem:

    python3 -m venv /tmp/pydem-venv
    /tmp/pydem-venv/bin/pip install "numpy==1.23.5" "numba==0.57.1" "scipy<1.12"
    git clone https://github.com/kentotomita/pydem /tmp/pydem && git -C /tmp/pydem checkout e7734ae

    /tmp/pydem-venv/bin/python benchmarks/reference_pydem.py IN.npz OUT.npz --src /tmp/pydem

``IN.npz`` holds ``dems`` (N, H, W) and ``sigmas`` (S,) in metres, and optionally ``noisy``
(N, S, H, W): the deterministic labels come from ``dems``, the probabilistic baseline of noise
level s from ``noisy[:, s]`` (or from ``dems`` when absent). ``OUT.npz`` gets ``label`` (N, H, W; 1
safe), ``valid`` (N, H, W), ``p`` (N, S, H, W; NaN where invalid) and the per-DEM seconds of each call
(``dhd_s``, ``alhat_s``: the median over ``--repeat`` timed passes after one warm-up call).
Only pydem's ``HazardDetection`` package is imported (its package ``__init__`` pulls optional
3-D libraries), with the paper's parameters: 1 m/px, square lander, defaults of ``dhd``/``alhat``.
"""

from __future__ import annotations

import argparse
import sys
import time
import types
from typing import Any

import numpy as np


def load_hazard_detection(src: str) -> types.ModuleType:
    """pydem.HazardDetection from a checkout, without pydem's package __init__."""
    np.int = int  # type: ignore[attr-defined]  # noqa: NPY001 - pydem (2023) uses the alias numpy removed in 1.24
    package = types.ModuleType("pydem")
    package.__path__ = [f"{src}/pydem"]
    sys.modules["pydem"] = package
    import pydem.HazardDetection as hazard_detection  # type: ignore[import-not-found]  # a checkout, not installed

    return hazard_detection


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("inputs")
    parser.add_argument("outputs")
    parser.add_argument("--src", required=True, help="pydem checkout at commit e7734ae")
    parser.add_argument("--repeat", type=int, default=0, help="timed passes over the first DEM (0: no timing)")
    args = parser.parse_args()
    hd = load_hazard_detection(args.src)
    data = np.load(args.inputs)
    dems, sigmas = data["dems"], [float(s) for s in data["sigmas"]]
    noisy = data["noisy"] if "noisy" in data else np.repeat(dems[:, None], len(sigmas), axis=1)
    n, h, w = dems.shape
    label = np.zeros((n, h, w), dtype=np.uint8)
    valid = np.zeros((n, h, w), dtype=bool)
    p = np.full((n, len(sigmas), h, w), np.nan)
    for k in range(n):
        _, _, _, _, safe, indef = hd.dhd(dems[k], 1.0)
        label[k], valid[k] = safe, indef == 0
        for s, sigma in enumerate(sigmas):
            p[k, s] = hd.alhat(noisy[k, s], 1.0, sigma=sigma)[4]
    timings = {}
    if args.repeat > 0:
        for name, call in (
            ("dhd_s", lambda: hd.dhd(dems[0], 1.0)),
            ("alhat_s", lambda: hd.alhat(noisy[0, -1], 1.0, sigma=sigmas[-1])),
        ):
            call()
            times = []
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                call()
                times.append(time.perf_counter() - t0)
            timings[name] = float(np.median(times))
    arrays: dict[str, Any] = {"label": label, "valid": valid, "p": p, **timings}
    np.savez(args.outputs, **arrays)


if __name__ == "__main__":
    main()
