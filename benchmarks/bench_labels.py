"""Label throughput: hazard maps and P(safe) per DEM in both conventions, beside the paper's own replica.

Run: ``.venv/bin/python benchmarks/bench_labels.py [--dems 20] [--dataset DIR]
[--reference-python PY [--reference-python PY2]] [--reference-src DIR]``.
Prints, side by side in one run: the machine (CPU model, load average, numba and numpy versions);
per-DEM time of the deterministic maps, of P(safe), and of both from one pass (the compiled kernels
on one thread, the same with ``parallel=True`` on every core, wall-clock and CPU time, and the tests'
numpy oracle; 100x100 DEMs at 1 m), for the paper convention (product baseline) and the hd
convention ("min" baseline); the paper convention's product rule beside the previous compiled
kernel, which summed every node of every site (``tests/hdlabels/alhat_previous.py``), on the same
noisy DEMs, with ``--dataset`` also on the stored noisy DEMs of a labelled dataset; with
``--reference-python`` (repeatable: one per environment, e.g. pydem's era with numba 0.57 /
numpy 1.23 and today's) and ``--reference-src`` (pydem at commit e7734ae, see
``benchmarks/reference_pydem.py``; also read from HD_PYDEM_PYTHON, several joined by ``os.pathsep``,
and HD_PYDEM_SRC) the replica's own numba code (``dhd`` + ``alhat``) on the same noisy DEM in each
environment and the speed-up; the loop reference of the hd convention on small DEMs; the gridding
of a 128x128 scan by every method; and the projected time to label 1000 scans x 3 sigma. hd's
kernels run on one thread unless ``parallel`` (``hd label`` keeps them on one thread per worker);
the replica's are numba-parallel and use every core of the machine unless limited to one thread.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
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

import numba
from alhat_numpy import Backend
from alhat_numpy import hazard_and_probability as oracle_hazard_and_probability
from alhat_numpy import hazard_maps as oracle_hazard_maps
from alhat_numpy import safety_probability as oracle_safety_probability
from alhat_previous import previous_hazard_and_probability
from alhat_reference import reference_maps
from grid_numpy import grid_points as oracle_grid_points

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


def per_call_ms_cpu(fn: Callable[..., object], inputs: list[np.ndarray]) -> tuple[float, float]:
    """Median wall time and median process CPU time (every thread) of ``fn`` over ``inputs``, milliseconds."""
    fn(inputs[0])
    wall, cpu = [], []
    for x in inputs:
        t0, c0 = time.perf_counter(), time.process_time()
        fn(x)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return 1e3 * float(np.median(wall)), 1e3 * float(np.median(cpu))


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


def reference_ms(
    python: str, src: str, dem: np.ndarray, sigma: float, repeat: int, threads: int | None = None
) -> tuple[float, float]:
    """Milliseconds of the replica's dhd and alhat on ``dem`` (median of ``repeat`` calls), in its own
    environment, on every core or on ``threads`` numba threads."""
    runner = Path(__file__).resolve().parent / "reference_pydem.py"
    env = dict(os.environ)
    if threads is not None:
        env["NUMBA_NUM_THREADS"] = str(threads)
    with tempfile.TemporaryDirectory() as tmp:
        inputs, outputs = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(inputs, dems=dem[None].astype(np.float32), sigmas=np.array([sigma]))
        subprocess.run(
            [python, str(runner), str(inputs), str(outputs), "--src", src, "--repeat", str(repeat)],
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=env,
        )
        out = np.load(outputs)
        return 1e3 * float(out["dhd_s"]), 1e3 * float(out["alhat_s"])


def environment(python: str) -> str:
    """numba and numpy versions of another interpreter's environment."""
    code = "import numba, numpy; print(f'numba {numba.__version__}, numpy {numpy.__version__}')"
    return subprocess.run([python, "-c", code], capture_output=True, text=True, check=True).stdout.strip()


def machine() -> str:
    """CPU model (lscpu), core count, load average and this environment's numba and numpy."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        model = next(line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("Model name"))
    except (OSError, subprocess.CalledProcessError, StopIteration):
        model = platform.processor() or "unknown CPU"
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    return f"{model}, {os.cpu_count()} CPUs, load average {load}; numba {numba.__version__}, numpy {np.__version__}"


def stored_noisy_dems(dataset: Path, n: int) -> tuple[list[np.ndarray], tuple[float, ...]]:
    """The first ``n`` scans' noisy DEMs of a labelled dataset, per noise level, and the levels (m)."""
    from hdlabels.store import LabelShardReader, find_labeling

    entry = find_labeling(dataset, None)
    with LabelShardReader(entry.shard_paths(dataset)[0]) as reader:
        return [reader.h5["dem_noisy"][:n, s] for s in range(len(reader.sigmas_m))], tuple(reader.sigmas_m)


def previous_vs_now(label: str, dems: list[np.ndarray], sigma: float, rounds: int = 3) -> float:
    """Prints both maps from one pass of the paper convention, previous kernel against now; returns now's ms.

    The two are called alternately on every DEM, ``rounds`` times over, so a change in the machine's
    load affects both alike; each figure is the median of its calls.
    """
    lander = Lander()
    calls = {
        "previous": lambda d: previous_hazard_and_probability(d, 1.0, sigma, lander),
        "now": lambda d: hazard_and_probability(d, 1.0, sigma, lander),
        "now, parallel": lambda d: hazard_and_probability(d, 1.0, sigma, lander, parallel=True),
    }
    times: dict[str, list[float]] = {name: [] for name in calls}
    cpu: dict[str, list[float]] = {name: [] for name in calls}
    for fn in calls.values():
        fn(dems[0])
    for _ in range(rounds):
        for d in dems:
            for name, fn in calls.items():
                t0, c0 = time.perf_counter(), time.process_time()
                fn(d)
                times[name].append(time.perf_counter() - t0)
                cpu[name].append(time.process_time() - c0)
    before, now, par = (1e3 * float(np.median(times[name])) for name in calls)
    before_cpu, now_cpu, par_cpu = (1e3 * float(np.median(cpu[name])) for name in calls)
    print(
        f"  {label} sigma {sigma * 100:4.2f} cm: previous kernel {before:6.2f} ms ({before_cpu:5.2f} CPU), "
        f"now {now:6.2f} ms ({now_cpu:5.2f} CPU): {before / now:4.2f}x; now with parallel rows {par:6.2f} ms wall, "
        f"{par_cpu:6.2f} ms CPU (target <= 5 ms)"
    )
    return now


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dems", type=int, default=20, help="100x100 DEMs timed per back end")
    parser.add_argument("--ref-size", type=int, default=40, help="side of the DEMs the loop reference runs on")
    parser.add_argument("--ref-dems", type=int, default=2, help="DEMs the loop reference runs on")
    parser.add_argument(
        "--reference-python",
        action="append",
        default=None,
        help="python of a throw-away environment holding pydem's requirements (repeat for several environments)",
    )
    parser.add_argument("--dataset", type=Path, default=None, help="also time a labelled dataset's stored noisy DEMs")
    parser.add_argument("--reference-src", default=os.environ.get("HD_PYDEM_SRC"), help="pydem checkout (e7734ae)")
    args = parser.parse_args()
    if args.reference_python is None and os.environ.get("HD_PYDEM_PYTHON"):
        args.reference_python = os.environ["HD_PYDEM_PYTHON"].split(os.pathsep)
    rng = np.random.default_rng(0)
    print(machine())

    dems = [terrain(rng, 100).astype(np.float32) for _ in range(args.dems)]
    both_ms: dict[str, float] = {}
    for name, lander in (("paper", Lander()), ("hd", Lander(convention="hd"))):
        print(
            f"{name} convention ({lander.baseline_combine} baseline), per 100x100 DEM at 1 m "
            f"({args.dems} DEMs, median):"
        )
        for sigma in (0.0167, 0.07):
            noisy = [(d + rng.normal(0.0, sigma, d.shape)).astype(np.float32) for d in dems]
            kernels = {
                "numba": (hazard_maps, safety_probability, hazard_and_probability),
                "numpy": (oracle_hazard_maps, oracle_safety_probability, oracle_hazard_and_probability),
            }
            for backend, (maps_fn, prob_fn, both_fn) in kernels.items():
                kw = {"backend": "numpy"} if backend == "numpy" else {}
                det = per_call_ms(lambda d, f=maps_fn, la=lander, k=kw: f(d, 1.0, la, **k), dems)
                prob = per_call_ms(lambda d, f=prob_fn, la=lander, s=sigma, k=kw: f(d, 1.0, s, la, **k), noisy)
                both, both_cpu = per_call_ms_cpu(
                    lambda d, f=both_fn, la=lander, s=sigma, k=kw: f(d, 1.0, s, la, **k), noisy
                )
                name_b = backend if backend == "numba" else "numpy oracle (tests)"
                target = " (target <= 5 ms)" if (name, backend) == ("paper", "numba") else ""
                print(
                    f"  sigma {sigma * 100:4.2f} cm {name_b:6s} deterministic maps {det:7.2f} ms   "
                    f"P(safe) {prob:7.2f} ms"
                    f"   both maps from one pass {both:7.2f} ms wall, {both_cpu:7.2f} ms CPU{target}"
                )
                if backend == "numba":
                    both_ms[f"{name} {sigma}"] = both
                    both_ms[f"{name} {sigma} det"] = det
                    both_ms[f"{name} {sigma} prob"] = prob
            wall, cpu = per_call_ms_cpu(
                lambda d, la=lander, s=sigma: hazard_and_probability(d, 1.0, s, la, parallel=True), noisy
            )
            print(
                f"  sigma {sigma * 100:4.2f} cm numba, parallel rows on {numba.get_num_threads()} threads: "
                f"both maps from one pass {wall:7.2f} ms wall, {cpu:7.2f} ms CPU"
            )

    print("paper convention, P(safe) and maps from one pass, the previous kernel (every node summed) against now:")
    noisy_by_sigma: dict[float, list[np.ndarray]] = {}
    for sigma in (0.0167, 0.07):
        noisy_by_sigma[sigma] = [(d + rng.normal(0.0, sigma, d.shape)).astype(np.float32) for d in dems]
        previous_vs_now("synthetic", noisy_by_sigma[sigma], sigma)
    if args.dataset is not None:
        stored, sigmas = stored_noisy_dems(args.dataset, args.dems)
        for level, sigma in zip(stored, sigmas, strict=True):
            previous_vs_now(args.dataset.name, list(level), sigma)

    if args.reference_python and args.reference_src:
        print(
            "the paper's replica (pydem e7734ae, numba, parallel) on the same noisy DEM, per DEM, on every core "
            "and on one thread (hd: parallel rows on every core, or one thread); a loaded machine slows the "
            "parallel replica the most; target >= 15x under today's numba:"
        )
        for python in args.reference_python:
            print(f"  {python} ({environment(python)}):")
            for sigma in (0.0167, 0.07):
                first = noisy_by_sigma[sigma][0]
                for threads in (None, 1):
                    dhd, alhat = reference_ms(python, args.reference_src, first, sigma, 5, threads)
                    par = threads is None
                    ours = per_call_ms(
                        lambda d, s=sigma, p=par: hazard_and_probability(d, 1.0, s, Lander(), parallel=p), [first] * 15
                    )
                    cores = "1 thread " if threads else "all cores"
                    print(
                        f"    sigma {sigma * 100:4.2f} cm, {cores}: dhd {dhd:6.1f} ms "
                        f"+ alhat {alhat:6.1f} ms = {dhd + alhat:6.1f} ms; hd paper convention ({cores}), both maps "
                        f"from one pass {ours:5.2f} ms: {(dhd + alhat) / ours:5.1f}x faster"
                    )
    else:
        print("the paper's replica: skipped (give --reference-python and --reference-src)")

    lander = Lander(convention="hd")
    small = [terrain(rng, args.ref_size) for _ in range(args.ref_dems)]
    ref = per_call_ms(lambda d: reference_maps(d, 1.0, lander), small)
    print(f"hd convention, loop reference vs fast path, {args.ref_dems} DEMs of {args.ref_size}x{args.ref_size}:")
    backends: tuple[Backend, ...] = ("numba", "numpy")
    for backend in backends:
        fast = per_call_ms(lambda d, b=backend: oracle_hazard_maps(d, 1.0, lander, backend=b), small * 5)
        print(f"  reference {ref:9.1f} ms   {backend:6s} {fast:7.2f} ms   ratio {ref / fast:8.0f}x")

    def hills(k: int) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        return lambda x, y: 2 * np.sin(x / 7 + k) + np.cos(y / 5)

    scans = [nadir_scan(hills(k)) for k in range(5)]
    print("grid_points per 128x128 scan -> 100x100 DEM:")
    grid_ms = {}
    for method in GRIDDINGS:
        backends = ("numba", "numpy") if method == "linear" else ("numba",)
        for backend in backends:
            grid_ms[f"{method} {backend}"] = per_call_ms(
                (lambda p: oracle_grid_points(p, backend="numpy"))
                if backend == "numpy"
                else (lambda p, m=method: grid_points(p, method=m)),
                scans,
            )
            print(f"  {method:8s} {backend:6s} {grid_ms[f'{method} {backend}']:8.2f} ms")

    for name, grid in (("paper", f"{GRIDDING['paper']} numba"), ("hd", "linear numba")):
        det, prob = both_ms[f"{name} 0.07 det"], both_ms[f"{name} 0.07 prob"]
        total = 1000 * (grid_ms[grid] + det) + 3000 * (grid_ms[grid] + prob)
        print(
            f"projected, {name} convention: 1000 scans x 3 sigma (grid + labels + P(safe), numba, one core): "
            f"{total / 1e3:.1f} s"
        )


if __name__ == "__main__":
    main()
