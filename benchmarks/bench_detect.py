"""hd detect speed: seconds per 100x100 frame (M = 8) beside the ALHAT baseline, against a 10 s budget.

Prints, measured side by side in one run on one 100x100 frame at 1 m of the procedural Mars terrain
(randomly initialised weights: speed does not depend on training):

* the network path of ``hd detect`` per frame (input preparation, MC dropout with the shared prefix,
  back to the DEM grid, entropy), one frame at a time (latency, what a lander would do) and
  batched 8 frames per call (throughput, what ``hd detect`` does over a DTM), for the ``cpu``
  profile (its width and depth, its input channels, no padding of 100 x 100), the same at full
  width, and the ``paper`` profile
  (full width, 100 -> 512 bilinear);
* the ALHAT P(safe) baseline on the same frame (numba) and the site selection;
* each as a fraction of ALHAT's onboard budget of 10 s per frame (target: < 1 s per frame at the
  cpu profile's width);
* end to end: ``detect`` on a procedural DTM (default 512 m x 512 m at 0.5 m, resampled to 1 m),
  with the cpu-profile network and a fixed threshold: seconds, tiles, seconds per tile and per km^2.

On a machine whose cores other processes share, OpenMP's default busy-waiting makes small calls
stall (several times slower, erratic); ``OMP_WAIT_POLICY=PASSIVE`` or one thread avoids it, and
the cpu profile is also timed on one thread for that reason.

Usage: python benchmarks/bench_detect.py [--samples 8] [--repeats 3] [--dtm-size 512] [--skip-paper] [--threads N]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hdlabels.lander import Lander
from hdlabels.store import DemSpec, LabelingEntry
from hdnet.detect import (
    SAFETY_SAFE,
    DetectRun,
    baseline_p_safe,
    detect,
    network_input,
    network_output,
    select_sites,
)
from hdnet.detect_settings import DetectSettings
from hdnet.fit import input_spec_for
from hdnet.infer import mc_dropout_predict, predictive_entropy
from hdnet.inputs import Normalisation, network_shape
from hdnet.model import BayesianSegNet, count_parameters
from hdnet.profiles import CPU, PAPER, TrainingProfile
from hdnet.run_record import CheckpointHeader
from hdnet.train import CHECKPOINT_SCHEMA, CHECKPOINT_VERSION, save_checkpoint
from lidarsim.procedural import MarsTerrainParams, generate_mars_terrain, write_geotiff

BUDGET_S = 10.0  # hd choice: the per-frame time budget detection is measured against (docs/benchmarks.md)
# the default label convention's lander on 100 x 100 DEMs at 1 m
LABELING = LabelingEntry("default-lander-dem100x100at1m", Lander(), DemSpec.for_convention("paper"))


def median_seconds(fn: Callable[[], object], repeats: int, warmups: int = 2) -> float:
    """Median seconds of ``repeats`` calls of ``fn`` after ``warmups`` calls."""
    for _ in range(warmups):  # numba compilation, oneDNN primitives, the allocator: the first call of a
        fn()  # new model is several times slower than the steady state
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def untrained_run(profile: TrainingProfile, width: float, dem: np.ndarray) -> DetectRun:
    """An untrained model of ``profile``'s architecture and input preparation at ``width``."""
    torch.manual_seed(0)
    norm = (
        Normalisation(float(np.nanmin(dem)) - 5.0, float(np.nanmax(dem)) + 5.0) if profile.heights == "minmax" else None
    )
    spec = input_spec_for(profile, 1.0, norm)
    model = BayesianSegNet(replace(profile, width=width).model_config(spec.n_channels)).eval()
    return DetectRun(
        Path("-"),
        model,
        CheckpointHeader(0, None, None),
        0.0167,
        spec,
        LABELING.name,
        LABELING,
        Lander(),
        (100, 100),
        1.0,
        None,
    )


def untrained_checkpoint(path: Path, dem: np.ndarray, profile: TrainingProfile = CPU) -> Path:
    """A checkpoint of ``profile``'s network (default: the cpu profile's), untrained (timing needs no
    training), at ``path``: what ``hd detect`` loads, labelled as :data:`LABELING` on 100 x 100 DEMs
    at 1.67 cm."""
    run = untrained_run(profile, profile.width, dem)
    save_checkpoint(
        path,
        {
            "schema": CHECKPOINT_SCHEMA,
            "schema_version": CHECKPOINT_VERSION,
            "model_name": "bayesian_segnet",
            "model_config": run.model.config.to_dict(),
            "profile": profile.to_dict(),
            "epoch": 0,
            "model": run.model.state_dict(),
            "extra_config": {
                "train_sigma_m": 0.0167,
                "input": run.input_spec.to_dict(),
                "normalisation": None,
                "input_size": None,
                "labels": LABELING.name,
                "dem_shape": [100, 100],
                "labeling": LABELING.to_json(),
            },
        },
    )
    return path


def _frame_seconds(run: DetectRun, dem: np.ndarray, samples: int, batch: int, repeats: int, warmups: int = 2) -> float:
    def once() -> None:
        x = torch.cat([network_input(dem, run) for _ in range(batch)])
        probs = network_output(mc_dropout_predict(run.model, x, n_samples=samples).mean_probs, run)
        predictive_entropy(probs)

    return median_seconds(once, repeats, warmups) / batch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--dtm-size", type=float, default=512.0, help="side of the end-to-end DTM, metres (0: skip)")
    parser.add_argument("--skip-paper", action="store_true", help="skip the paper profile (full width at 512x512)")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's, one per core)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, OMP_WAIT_POLICY="
        f"{os.environ.get('OMP_WAIT_POLICY', '(default)')}, load average {os.getloadavg()[0]:.1f}, M = {args.samples}, "
        f"budget {BUDGET_S:g} s/frame"
    )

    terrain = generate_mars_terrain(MarsTerrainParams(size_m=100.0), seed=1)  # 200 x 200 at 0.5 m
    dem = terrain[::2, ::2].astype(np.float64)
    dem = dem - dem.mean()  # scan frame
    rows = []
    configs = [("cpu profile", CPU, CPU.width), ("cpu profile at full width", CPU, 1.0)]
    if not args.skip_paper:
        configs.append(("paper profile", PAPER, PAPER.width))
    for name, profile, width in configs:
        run = untrained_run(profile, width, dem)
        size = profile.input_size
        rows_px, cols_px = network_shape((100, 100), size, run.input_spec.size_multiple)
        grid = f"{size}x{size}" if size else f"{rows_px}x{cols_px}, depth {profile.depth}"
        if size is None:
            one = _frame_seconds(run, dem, args.samples, 1, args.repeats)
            eight = _frame_seconds(run, dem, args.samples, 8, args.repeats)
        else:  # 512 x 512 at full width: tens of seconds per frame on a CPU; one warm-up, one timed call
            one, eight = _frame_seconds(run, dem, args.samples, 1, 1, warmups=1), float("nan")
        rows.append((f"{name}: width {width:g}, {count_parameters(run.model):,} parameters, {grid}", one, eight))
    threads = torch.get_num_threads()
    if threads > 1:  # one thread: no OpenMP barriers, which stall when other processes share the cores
        torch.set_num_threads(1)
        run = untrained_run(CPU, CPU.width, dem)
        one = _frame_seconds(run, dem, args.samples, 1, args.repeats)
        eight = _frame_seconds(run, dem, args.samples, 8, args.repeats)
        rows.insert(1, ("cpu profile on 1 thread", one, eight))
        torch.set_num_threads(threads)
    base = median_seconds(lambda: baseline_p_safe(dem, 1.0, 0.0167, LABELING), args.repeats * 3)
    p = baseline_p_safe(dem, 1.0, 0.0167, LABELING)
    from rasterio.transform import from_origin

    safety = np.where(np.isfinite(p), SAFETY_SAFE, 255).astype(np.uint8)  # worst case: every valid cell safe
    sites = median_seconds(
        lambda: select_sites(
            safety, np.nan_to_num(p), np.zeros_like(p), p, from_origin(0, 100, 1, 1), (1.0, 1.0), Lander(), 10
        ),
        args.repeats * 3,
    )
    print(f"\n{'per 100x100 frame':76s} {'1 at a time':>12s} {'batch of 8':>11s} {'/ budget':>9s}")
    for label, one, eight in rows:
        batched = f"{eight:9.3f} s" if np.isfinite(eight) else f"{'-':>11s}"
        print(f"  {label:74s} {one:10.3f} s {batched} {one / BUDGET_S:8.3f}")
    label = f"ALHAT baseline P(safe) (numba, {Lander().convention} convention)"
    print(f"  {label:74s} {base:10.4f} s {'':>11s} {base / BUDGET_S:8.4f}")
    print(f"  {'site selection (every valid cell safe: the most candidates)':74s} {sites:10.4f} s")
    print()
    for label, one, _ in rows:
        if label.startswith("cpu profile"):
            name = label.split(":")[0]
            print(
                f"{name}, one frame at a time: network {one:.3f} s + baseline {base:.4f} s = {one + base:.3f} s per "
                f"frame, {(one + base) / BUDGET_S:.3f} of the 10 s budget (target < 1 s: "
                f"{'met' if one + base < 1.0 else 'NOT met'}); network / baseline = {one / base:.0f}x"
            )

    if args.dtm_size > 0:
        with tempfile.TemporaryDirectory() as tmp:
            big = generate_mars_terrain(MarsTerrainParams(size_m=args.dtm_size), seed=2)
            dtm = Path(tmp) / "mars.tif"
            write_geotiff(dtm, big, 0.5, origin_xy=(0.0, args.dtm_size))
            ckpt = untrained_checkpoint(Path(tmp) / "run.pt", dem)
            t0 = time.perf_counter()
            result = detect(
                ckpt, Path(tmp) / "out", DetectSettings(threshold="nats:0.35", mc_samples=args.samples), dtm=dtm
            )
            total = time.perf_counter() - t0
            n = result.info["tiling"]["n_tiles"]
            km2 = (args.dtm_size / 1000.0) ** 2
            t = result.timings_s
            print(
                f"\nend to end, {args.dtm_size:g} m x {args.dtm_size:g} m procedural DTM (0.5 m -> 1 m), cpu profile: "
                f"{total:.1f} s for {n} tiles = {total / n:.3f} s per tile, {total / km2:.0f} s per km^2 "
                f"(network {t['network']:.1f} s, baseline {t['baseline']:.1f} s, read {t['read']:.1f} s, "
                f"write {t['write']:.1f} s, sites {t['sites']:.1f} s, overview {t['overview']:.1f} s)"
            )


if __name__ == "__main__":
    main()
