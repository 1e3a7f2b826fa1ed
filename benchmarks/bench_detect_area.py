"""hd detect at area scale: today's network layout (NCHW) against channels-last on one Jezero crop.

Prints, measured side by side in one run on one square crop of the Jezero DTM (datasets/mars-jezero,
3.69 m posts interpolated to the run's 1 m, as ``hd detect --upsample`` does; default 1 km^2) with
the robust profile's network (width 3/4, untrained weights: speed does not depend on training), a
fixed threshold and M = 8:

* for each layout (``DetectSettings.layout``: nchw, today's path; channels-last; channels-last with
  each tile's samples through the network alone): seconds end to end, s/km^2, and where they went
  (``detect.json``'s timings: network, baseline, read, write, sites, overview);
* max |delta P(safe)|, max |delta entropy| and max |delta mutual information| between the two
  layouts' maps (the same MC-dropout draws: round-off only), and whether the valid cells agree;
* the 14.3 km^2 Jezero floor's time extrapolated linearly in area (docs/benchmarks.md, "How cost
  grows": detect is linear in area) from each layout's s/km^2, against the 60 s target;
* the CPU model, torch's threads and the load average before and after (other jobs share the cores:
  read the ratio, measured in the same run).

Usage: python benchmarks/bench_detect_area.py [--area 1.0] [--samples 8] [--order nchw,channels-last,...]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rasterio
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_detect import untrained_checkpoint
from machine import cpu_model

from hdnet.detect import detect
from hdnet.detect_settings import DetectSettings
from hdnet.profiles import ROBUST
from lidarsim.procedural import write_geotiff
from lidarsim.terrain import DTM

JEZERO = Path(__file__).resolve().parents[1] / "datasets" / "mars-jezero" / "jezero-hirise-3.69m.tif"
FLOOR_KM2 = 14.3  # the Jezero floor mapped whole (issue 30's target: <= 60 s)
TARGET_S = 60.0
MAPS = ("p_safe.tif", "entropy.tif", "mutual_information.tif", "baseline_p_safe.tif")


def jezero_crop(path: Path, area_km2: float) -> tuple[Path, float]:
    """A centred square crop of the Jezero DTM of about ``area_km2`` written to ``path``; its km^2."""
    with DTM.open(JEZERO) as dtm:
        info = dtm.info
        side = min(info.rows, info.cols, round(math.sqrt(area_km2) * 1000.0 / info.spacing_m[0]))
        row0, col0 = (info.rows - side) // 2, (info.cols - side) // 2
        heights = dtm.read(row0, col0, side, side)
        t = info.transform
        origin = (t[2] + col0 * t[0], t[5] + row0 * t[4])
    write_geotiff(path, heights.astype(np.float32), info.spacing_m[0], origin_xy=origin, crs_wkt=info.crs_wkt)
    return path, (side * info.spacing_m[0]) ** 2 / 1e6


def _read(folder: Path, name: str) -> np.ndarray:
    with rasterio.open(folder / name) as src:
        return src.read(1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--area", type=float, default=1.0, help="crop of the Jezero DTM, km^2")
    parser.add_argument("--samples", type=int, default=8)
    parser.add_argument(
        "--order",
        default="nchw,channels-last,channels-last-per-tile",
        help="the layouts, in the order they run; the first is the reference the others are compared with",
    )
    args = parser.parse_args()
    layouts = args.order.split(",")
    load_before = os.getloadavg()
    print(
        f"{cpu_model()}, {os.cpu_count()} cores, torch {torch.__version__} on {torch.get_num_threads()} threads, "
        f"load average before {load_before[0]:.1f} / {load_before[1]:.1f} (1 / 5 min), M = {args.samples}, "
        "robust profile network (width 3/4, untrained)"
    )
    results: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        crop, km2 = jezero_crop(tmp / "crop.tif", args.area)
        ckpt = untrained_checkpoint(tmp / "run.pt", np.zeros((100, 100)), ROBUST)
        n_tiles = 0
        for layout in layouts:
            t0 = time.perf_counter()
            settings = DetectSettings(threshold="nats:0.35", mc_samples=args.samples, upsample=True, layout=layout)
            result = detect(ckpt, tmp / layout, settings, dtm=crop)
            results[layout] = {"seconds": time.perf_counter() - t0, **result.timings_s}
            n_tiles = result.info["tiling"]["n_tiles"]
        print(f"\nJezero crop {km2:.2f} km^2 at 1 m ({n_tiles} tiles of 100 x 100)")
        print(f"{'layout':22s} {'s':>7s} {'s/km^2':>7s} {'network':>8s} {'baseline':>9s} {'read':>5s} {'write':>6s}")
        for layout, r in results.items():
            print(
                f"{layout:22s} {r['seconds']:7.1f} {r['seconds'] / km2:7.1f} {r['network']:8.1f} {r['baseline']:9.1f} "
                f"{r['read']:5.1f} {r['write']:6.1f}   (sites {r['sites']:.1f}, overview {r['overview']:.1f})"
            )
        ref = layouts[0]
        for new in layouts[1:]:
            print(f"\n{new} against {ref}, the same draws:")
            for name in MAPS:
                a, b = _read(tmp / ref, name), _read(tmp / new, name)
                same_valid = np.array_equal(np.isnan(a), np.isnan(b))
                print(f"  {name:24s} max |delta| {np.nanmax(np.abs(a - b)):.2e}, same valid cells: {same_valid}")
            print(
                f"  speed-up {results[ref]['seconds'] / results[new]['seconds']:.2f}x end to end, "
                f"{results[ref]['network'] / results[new]['network']:.2f}x in the network"
            )
    print(f"\nthe {FLOOR_KM2} km^2 Jezero floor, extrapolated linearly in area (target {TARGET_S:.0f} s):")
    for layout, r in results.items():
        floor = r["seconds"] / km2 * FLOOR_KM2
        print(f"  {layout:22s} {floor:7.0f} s = {floor / TARGET_S:.1f}x the target")
    load_after = os.getloadavg()
    print(f"\nload average after {load_after[0]:.1f} / {load_after[1]:.1f} (1 / 5 min)")


if __name__ == "__main__":
    main()
