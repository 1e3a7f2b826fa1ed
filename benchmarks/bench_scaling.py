"""How cost grows: build, label and detect time and peak memory against the work, on log-log plots.

Four sweeps, each point one fresh child process whose wall time and peak resident memory (its own
and its worker processes', ``os.wait4``) are recorded with the load average before and after:

* scans: ``hd build-dataset`` (procedural terrain, default trajectory, the paper's 3 noise levels,
  gzip) and ``hd label`` (paper convention) of N scans;
* noise levels: the same at a fixed scan count with 1, 2, 4 and 8 noise levels;
* area: ``hd detect``'s procedure (``hdnet.detect``, the cpu profile's untrained network, M = 8, a
  fixed threshold) on square crops of the Jezero DTM (datasets/mars-jezero, 3.69 m posts mapped at
  1 m) of the given areas; 14.3 km^2 is the whole DTM;
* Dask workers: ``hd build-dataset --scheduler`` on a ``dask.distributed.LocalCluster`` of 1, 2 and
  4 single-threaded worker processes (peak memory: the largest worker's, asked of the workers).

Prints a table per sweep with the cost per unit of work (seconds per scan, per noise level, per
km^2) and the log-log slope between neighbouring points (1 = linear), writes the numbers to
``--json`` and, with ``--plots DIR``, one figure per sweep (``scaling_<sweep>.png``: time on
log-log axes with a line of slope 1 through the first point, peak memory beside it).

    python benchmarks/bench_scaling.py [--full] [--sweeps scans noise area workers] [--workers 2]
        [--scans 100 300 1000] [--areas 0.25 0.5 1] [--json scaling.json] [--plots docs/figures]

The default sweep takes a few minutes on 2 cores (100 -> 1000 scans, 1 -> 8 noise levels at 200
scans, 0.25 -> 1 km^2, 1 -> 4 Dask workers at 300 scans); ``--full`` runs 100 -> 10,000 scans,
0.25 -> 14.3 km^2 and 1000 scans on the Dask workers (an hour or more on 2 cores).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from machine import cpu_model

REPO = Path(__file__).resolve().parents[1]
JEZERO = REPO / "datasets" / "mars-jezero" / "jezero-hirise-3.69m.tif"
PAPER_SIGMAS = ("0.0167", "0.03", "0.07")  # the paper's S-167, S-300, S-700 (lidarsim.defaults)
EIGHT_SIGMAS = ("0.01", "0.0167", "0.02", "0.03", "0.04", "0.05", "0.06", "0.07")  # 1..8 levels: the first k


@dataclass(frozen=True)
class Sizes:
    """The points of each sweep: scan counts, the scans of the noise sweep, noise levels, areas
    (km^2) and the scans built on the Dask workers."""

    scans: tuple[int, ...]
    noise_scans: int
    levels: tuple[int, ...]
    areas: tuple[float, ...]
    worker_scans: int


DEFAULT = Sizes((100, 300, 1000), 200, (1, 2, 4, 8), (0.25, 0.5, 1.0), 300)
FULL = Sizes((100, 300, 1000, 3000, 10000), 1000, (1, 2, 4, 8), (0.25, 1.0, 4.0, 14.3), 1000)
WORKERS = [1, 2, 4]


def hd_command() -> list[str]:
    """The ``hd`` entry point of this interpreter's environment."""
    local = Path(sys.executable).with_name("hd")
    return [str(local)] if local.exists() else ["hd"]


def measured(args: list[str]) -> dict[str, float]:
    """Run one of this script's children (``args``): the wall seconds and peak resident MiB it
    reports on its last line (JSON), with the 1-minute load average before and after."""
    load = os.getloadavg()[0]
    done = subprocess.run(args, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(args)} failed ({done.returncode}): {done.stderr.strip()[-800:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    return {**result, "load_before": load, "load_after": os.getloadavg()[0]}


def hd_measured(args: list[str]) -> dict[str, float]:
    """An ``hd`` command run by a fresh child of this script (``child_run``), which reports the
    command's wall time and the peak memory of the command and its worker processes."""
    return measured([sys.executable, __file__, "--child", "run", "--", *hd_command(), *args])


def child_run(command: list[str]) -> None:
    """Run ``command`` and print its wall time and peak memory (this process is fresh: the
    children's maximum is the command's and its workers')."""
    import resource

    t0 = time.perf_counter()
    done = subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0  # the peak below: RUSAGE_CHILDREN holds the largest reaped descendant
    if done.returncode != 0:
        print(done.stderr[-800:], file=sys.stderr)
        raise SystemExit(done.returncode)
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(json.dumps({"seconds": wall, "peak_mib": peak}))


def child_detect(area_km2: float, tmp: Path) -> None:
    """Time ``hdnet.detect`` on a square crop of the Jezero DTM of ``area_km2`` (the whole if larger)."""
    import resource

    import numpy as np
    from bench_detect import untrained_checkpoint

    from hdnet.detect import detect
    from hdnet.detect_settings import DetectSettings
    from lidarsim.procedural import write_geotiff
    from lidarsim.terrain import DTM

    with DTM.open(JEZERO) as dtm:
        info = dtm.info
        side = min(info.rows, info.cols, round(math.sqrt(area_km2) * 1e6**0.5 / info.spacing_m[0]))
        row0, col0 = (info.rows - side) // 2, (info.cols - side) // 2
        heights = dtm.read(row0, col0, side, side)
        t = info.transform
        origin = (t[2] + col0 * t[0], t[5] + row0 * t[4])
    crop = tmp / "crop.tif"
    write_geotiff(crop, heights.astype(np.float32), info.spacing_m[0], origin_xy=origin, crs_wkt=info.crs_wkt)
    dem = np.zeros((100, 100))
    ckpt = untrained_checkpoint(tmp / "run.pt", dem)
    t0 = time.perf_counter()
    detect(ckpt, tmp / "out", DetectSettings(threshold="nats:0.35", mc_samples=8, upsample=True), dtm=crop)
    wall = time.perf_counter() - t0
    km2 = (side * info.spacing_m[0]) ** 2 / 1e6
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"seconds": wall, "peak_mib": peak, "km2": km2}))


def build_args(out: Path, scans: int, sigmas: tuple[str, ...], workers: int | None) -> list[str]:
    args = ["build-dataset", "--out", str(out), "--scans", str(scans)]
    args += [a for s in sigmas for a in ("--sigma", s)]
    return args + (["--workers", str(workers)] if workers else [])


def sweep_scans(tmp: Path, scans: list[int], workers: int) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    for n in scans:
        out = tmp / f"scans{n}"
        build = hd_measured(build_args(out, n, PAPER_SIGMAS, workers))
        label = hd_measured(["label", str(out), "--convention", "paper", "--workers", str(workers)])
        _remove(out)
        rows.append({"x": n, "build": build, "label": label})
        _report("scans", n, "scan", rows)
    return rows


def sweep_noise(tmp: Path, scans: int, levels: list[int], workers: int) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    for k in levels:
        out = tmp / f"noise{k}"
        build = hd_measured(build_args(out, scans, EIGHT_SIGMAS[:k], workers))
        label = hd_measured(["label", str(out), "--convention", "paper", "--workers", str(workers)])
        _remove(out)
        rows.append({"x": k, "build": build, "label": label})
        _report("noise levels", k, "level", rows)
    return rows


def sweep_area(tmp: Path, areas: list[float]) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    for a in areas:
        work = tmp / f"area{a}"
        work.mkdir()
        detect = measured([sys.executable, __file__, "--child", "detect", "--area", str(a), "--tmp", str(work)])
        _remove(work)
        km2 = float(detect.get("km2", a))
        rows.append({"x": km2, "detect": detect})
        _report("area", km2, "km^2", rows)
    return rows


def sweep_workers(tmp: Path, scans: int, counts: list[int]) -> list[dict[str, Any]]:
    from dask.distributed import Client, LocalCluster

    rows: list[dict[str, Any]] = []
    for k in counts:
        out = tmp / f"workers{k}"
        with (
            LocalCluster(n_workers=k, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
            Client(cluster) as client,
        ):
            build = hd_measured([*build_args(out, scans, PAPER_SIGMAS, None), "--scheduler", cluster.scheduler_address])
            peaks = client.run(_worker_peak_mib)
        build["peak_mib"] = max([build["peak_mib"], *peaks.values()])
        _remove(out)
        rows.append({"x": k, "build": build})
        first = rows[0]["build"]["seconds"]
        print(
            f"  {k} Dask worker(s): build {build['seconds']:7.1f} s, speed-up {first / build['seconds']:4.2f}, "
            f"efficiency {first / build['seconds'] / k:4.2f}, peak {build['peak_mib']:6.0f} MiB "
            f"(load {build['load_before']:.1f} -> {build['load_after']:.1f})",
            flush=True,
        )
    return rows


def _worker_peak_mib() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _remove(path: Path) -> None:
    import shutil

    shutil.rmtree(path, ignore_errors=True)


def _report(sweep: str, x: float, unit: str, rows: list[dict[str, Any]]) -> None:
    """One line per measured point: seconds, seconds per unit, slope from the point before, memory."""
    row = rows[-1]
    parts = []
    for step in ("build", "label", "detect"):
        if step not in row:
            continue
        m = row[step]
        slope = ""
        if len(rows) > 1:
            prev = rows[-2]
            slope = f", slope {math.log(m['seconds'] / prev[step]['seconds']) / math.log(row['x'] / prev['x']):4.2f}"
        per = m["seconds"] / row["x"]
        parts.append(f"{step} {m['seconds']:7.1f} s ({per:.4g} s/{unit}{slope}), peak {m['peak_mib']:6.0f} MiB")
    load = next(row[s] for s in ("build", "label", "detect") if s in row)
    print(
        f"  {sweep} {x:g}: " + "; ".join(parts) + f" (load {load['load_before']:.1f} -> {load['load_after']:.1f})",
        flush=True,
    )


def plot(results: dict[str, Any], folder: Path) -> None:
    """One figure per sweep: time (log-log, slope-1 reference through the first point), peak memory."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder.mkdir(parents=True, exist_ok=True)

    labels = {
        "scans": "scans (3 noise levels)",
        "noise": f"noise levels ({results.get('noise_scans', '')} scans)",
        "area": "area mapped, km$^2$",
        "workers": "Dask workers",
    }
    for sweep, rows in results["sweeps"].items():
        if not rows:
            continue
        fig, (ax_t, ax_m) = plt.subplots(1, 2, figsize=(9.5, 3.6))
        xs = [r["x"] for r in rows]
        loads = []
        for step, colour in (("build", "C0"), ("label", "C1"), ("detect", "C2")):
            if step not in rows[0]:
                continue
            ts = [r[step]["seconds"] for r in rows]
            ax_t.loglog(xs, ts, "o-", color=colour, label=f"{step}")
            ref = [ts[0] * x / xs[0] for x in xs] if sweep != "workers" else [ts[0] * xs[0] / x for x in xs]
            ax_t.loglog(xs, ref, ":", color=colour, linewidth=1, label="linear" if sweep != "workers" else "ideal")
            ax_m.semilogx(xs, [r[step]["peak_mib"] for r in rows], "o-", color=colour, label=step)
            loads += [r[step]["load_before"] for r in rows] + [r[step]["load_after"] for r in rows]
        for ax in (ax_t, ax_m):
            ax.set_xticks(xs, [f"{x:.3g}" for x in xs], minor=False)
            ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
            ax.set_xlabel(labels[sweep])
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8)
        ax_t.set_ylabel("wall time, s")
        ax_m.set_ylabel("peak resident memory, MiB")
        ax_m.set_ylim(bottom=0)
        fig.suptitle(
            f"{results['cpu']}, {results['cores']} cores; load average {min(loads):.1f}-{max(loads):.1f}; "
            f"{results['date'][:10]}",
            fontsize=9,
        )
        fig.tight_layout()
        fig.savefig(folder / f"scaling_{sweep}.png", dpi=110)
        plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--child", choices=["run", "detect"], help=argparse.SUPPRESS)
    parser.add_argument("--area", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--tmp", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--full", action="store_true", help="the full sweep (an hour or more on 2 cores)")
    parser.add_argument("--sweeps", nargs="+", default=["scans", "noise", "area", "workers"])
    parser.add_argument("--workers", type=int, default=2, help="worker processes of build and label")
    parser.add_argument("--json", type=Path, default=None, help="write the measurements here")
    parser.add_argument("--plots", type=Path, default=None, help="write scaling_<sweep>.png here")
    parser.add_argument("--scans", type=int, nargs="+", default=None, help="the scan counts of the scans sweep")
    parser.add_argument("--areas", type=float, nargs="+", default=None, help="the areas (km^2) of the area sweep")
    parser.add_argument("--replot", type=Path, default=None, help="only draw the figures of a --json file")
    parser.add_argument("command", nargs="*", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child == "run":
        child_run(args.command)
        return
    if args.child == "detect":
        child_detect(args.area, args.tmp)
        return
    if args.replot:
        plot(json.loads(args.replot.read_text()), args.plots or Path("."))
        return
    sizes = FULL if args.full else DEFAULT
    if args.scans:
        sizes = dataclasses.replace(sizes, scans=tuple(args.scans))
    if args.areas:
        sizes = dataclasses.replace(sizes, areas=tuple(args.areas))
    results: dict[str, Any] = {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "workers": args.workers,
        "noise_scans": sizes.noise_scans,
        "sweeps": {},
    }
    print(f"{results['cpu']}, {results['cores']} cores, load average {os.getloadavg()[0]:.1f}; {results['date']}")
    if args.json and args.json.exists():  # sweeps run before: kept, those run now replaced
        results["sweeps"] = json.loads(args.json.read_text()).get("sweeps", {})
    sweeps = {
        "scans": lambda tmp: sweep_scans(tmp, list(sizes.scans), args.workers),
        "noise": lambda tmp: sweep_noise(tmp, sizes.noise_scans, list(sizes.levels), args.workers),
        "area": lambda tmp: sweep_area(tmp, list(sizes.areas)),
        "workers": lambda tmp: sweep_workers(tmp, sizes.worker_scans, WORKERS),
    }
    with tempfile.TemporaryDirectory(prefix="hd-scaling-") as tmp_name:
        for name in args.sweeps:
            results["sweeps"][name] = sweeps[name](Path(tmp_name))
            if args.json:  # after every sweep: a later failure keeps what was measured
                args.json.write_text(json.dumps(results, indent=1))
    if args.plots:
        plot(results, args.plots)


if __name__ == "__main__":
    main()
