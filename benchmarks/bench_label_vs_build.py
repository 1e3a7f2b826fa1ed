"""Labelling against building: ``hd label`` and ``hd build-dataset`` of the same scans, side by side.

Each round builds a fresh dataset with ``hd build-dataset`` (the paper's three noise levels, the
procedural terrain, the default trajectory) and labels it with ``hd label`` (the paper convention:
nearest gridding, ALHAT labels of the clean DEM, the product-rule P(safe) of every noisy DEM), both
with the same number of worker processes, and prints both wall-clock times (process start-up,
imports and writes included, as a user sees them) and their ratio. Rounds alternate the two
commands so that a change in the machine's load affects both alike; the median ratio is the result.

    python benchmarks/bench_label_vs_build.py [--scans 1000] [--workers 2] [--rounds 3]

The issue's target: label stage <= build stage (ratio <= 1) on 1000 scans x 3 sigma, 2 workers.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SIGMAS_M = ("0.0167", "0.03", "0.07")  # the paper's S-167, S-300 and S-700 (lidarsim.defaults)


def hd_command() -> list[str]:
    """The ``hd`` entry point of this interpreter's environment (or the one on PATH)."""
    local = Path(sys.executable).with_name("hd")
    if local.exists():
        return [str(local)]
    found = shutil.which("hd")
    if found is None:
        raise SystemExit("hd is not installed in this environment (pip install -e .)")
    return [found]


def timed(args: list[str]) -> float:
    """Wall-clock seconds of one command; its output is discarded, a failure stops the benchmark."""
    t0 = time.perf_counter()
    done = subprocess.run(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(args)} failed ({done.returncode}): {done.stderr.strip()[-500:]}")
    return time.perf_counter() - t0


def cpu_model() -> str:
    """The CPU's model name (lscpu), or the platform's processor string."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return platform.processor() or "unknown CPU"
    return next((line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("Model name")), "?")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=1000, help="scans per dataset")
    parser.add_argument("--workers", type=int, default=2, help="worker processes of both commands")
    parser.add_argument("--rounds", type=int, default=3, help="build + label rounds")
    args = parser.parse_args()
    hd = hd_command()
    print(
        f"{cpu_model()}, {os.cpu_count()} CPUs, load average at start "
        f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}; {args.scans} scans x {len(SIGMAS_M)} sigma, "
        f"{args.workers} workers"
    )
    ratios = []
    workers = ["--workers", str(args.workers)]
    with tempfile.TemporaryDirectory(prefix="hd-bench-") as tmp:
        for r in range(args.rounds):
            out = Path(tmp) / f"round{r}"
            sigmas = [a for s in SIGMAS_M for a in ("--sigma", s)]
            build = timed([*hd, "build-dataset", "--out", str(out), "--scans", str(args.scans), *sigmas, *workers])
            label = timed([*hd, "label", str(out), "--convention", "paper", *workers])
            shutil.rmtree(out)
            ratios.append(label / build)
            print(
                f"  round {r + 1}: build-dataset {build:6.1f} s, label {label:6.1f} s, label / build "
                f"{label / build:.2f} (load average now {os.getloadavg()[0]:.1f})"
            )
    print(f"label / build, median of {args.rounds} rounds: {statistics.median(ratios):.2f} (target <= 1)")


if __name__ == "__main__":
    main()
