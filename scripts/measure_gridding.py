"""Measure how much range noise each gridding leaves in the DEM, and what that does to the baseline.

Part 1 (always): scans of a flat, level terrain at the paper's noise levels; for every gridding,
the residual DEM noise ``noisy DEM - clean DEM`` over the 100x100 cells (its mean, standard
deviation and rms, in metres and as a multiple of sigma).

Part 2 (``--dataset DIR``): for every paper-convention labelling of a labelled dataset (one per
gridding, ``hd label DIR --convention paper --gridding G``), the ALHAT baseline (P(safe) >= 0.5)
scored against the labels on the training and validation splits, beside the paper's Table 1
baseline rows.

    .venv/bin/python scripts/measure_gridding.py [--scans 40] [--dataset /path/to/mars-paper]

The tables in docs/labels.md ("Gridding") were printed by this script.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hdlabels import defaults as label_defaults
from hdlabels.grid import grid_points
from hdnet.paper_results import PAPER_ROWS
from lidarsim import defaults as lidar_defaults
from lidarsim.build import BuildConfig, build_dataset
from lidarsim.procedural import write_geotiff
from lidarsim.shards import ScanShardReader, read_manifest
from lidarsim.trajectory import TrajectoryConfig


def flat_terrain(path: Path, side_m: float = 400.0, spacing_m: float = 0.5) -> Path:
    """A level plane (height 0 m) as a GeoTIFF."""
    n = int(side_m / spacing_m)
    write_geotiff(path, np.zeros((n, n), dtype=np.float32), spacing_m, origin_xy=(0.0, side_m))
    return path


def residual_noise(n_scans: int) -> None:
    sigmas = lidar_defaults.PAPER_SIGMAS_M
    with tempfile.TemporaryDirectory() as tmp:
        dtm = flat_terrain(Path(tmp) / "flat.tif")
        out = Path(tmp) / "flat"
        build_dataset(
            out,
            BuildConfig(sigmas_m=sigmas, seed=5, trajectory=TrajectoryConfig(n_scans=n_scans), dtm_path=str(dtm)),
            workers=1,
        )
        res: dict[str, list[list[np.ndarray]]] = {g: [[] for _ in sigmas] for g in label_defaults.GRIDDINGS}
        for entry in read_manifest(out)["shards"]:
            with ScanShardReader(out / entry["path"]) as reader:
                for scan in reader:
                    for g in label_defaults.GRIDDINGS:
                        clean = grid_points(scan.points_clean, method=g)
                        for s in range(len(sigmas)):
                            res[g][s].append((grid_points(scan.points_noisy[s], method=g) - clean).ravel())
    print(f"Residual DEM noise on a flat, level terrain ({n_scans} scans x 100 x 100 cells), noisy - clean DEM:")
    print("| gridding | " + " | ".join(f"σ = {s * 100:g} cm: mean / std / rms (m)" for s in sigmas) + " | rms / σ |")
    print("|---|" + "---|" * (len(sigmas) + 1))
    for g in label_defaults.GRIDDINGS:
        cells, ratios = [], []
        for s, sigma in enumerate(sigmas):
            r = np.concatenate(res[g][s])
            r = r[np.isfinite(r)]
            rms = float(np.sqrt(np.mean(r**2)))
            cells.append(f"{r.mean():+.4f} / {r.std():.4f} / {rms:.4f}")
            ratios.append(rms / sigma)
        print(f"| {g} | " + " | ".join(cells) + f" | {np.mean(ratios):.2f} |")


def baseline_scores(dataset: Path) -> None:
    manifest = json.loads((dataset / "manifest.json").read_text())
    sigmas = manifest["sigmas_m"]
    print(f"\nALHAT baseline (P >= 0.5) vs labels, train + val splits of {dataset.name}:")
    print("| labelling | σ | PA | mIoU | precision | sensitivity |")
    print("|---|---|---|---|---|---|")
    for lab in manifest.get("labelings", []):
        if lab.get("convention") != "paper":
            continue
        counts = np.zeros((len(sigmas), 4))
        for e in lab["shards"]:
            with h5py.File(dataset / e["path"], "r") as f:
                keep = f["split"][:] != 2  # train and val
                y, p = f["label"][:][keep], f["p_safe"][:][keep]
            valid, truth = y != label_defaults.LABEL_INVALID, y == label_defaults.LABEL_SAFE
            for s in range(len(sigmas)):
                b = p[:, s] >= label_defaults.SAFE_PROBABILITY_THRESHOLD
                counts[s] += [
                    (b & truth & valid).sum(),
                    (b & ~truth & valid).sum(),
                    (~b & truth & valid).sum(),
                    (~b & ~truth & valid).sum(),
                ]
        for s, sigma in enumerate(sigmas):
            tp, fp, fn, tn = counts[s]
            miou = (tp / (tp + fp + fn) + tn / (tn + fp + fn)) / 2
            print(
                f"| {lab['dem'].get('gridding', 'linear')} | {sigma * 100:g} cm | {(tp + tn) / counts[s].sum():.4f} | "
                f"{miou:.4f} | {tp / (tp + fp):.4f} | {tp / (tp + fn):.4f} |"
            )
    for row in PAPER_ROWS:
        if row.table == "noise" and row.method == "alhat_baseline":
            print(
                f"| paper | {row.test_sigma_m * 100:g} cm | {row.pixel_accuracy:.4f} | {row.miou:.4f} | "
                f"{row.precision:.4f} | {row.sensitivity:.4f} |"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=40, help="flat-terrain scans (default 40)")
    parser.add_argument("--dataset", type=Path, default=None, help="a dataset labelled once per gridding")
    args = parser.parse_args()
    residual_noise(args.scans)
    if args.dataset is not None:
        baseline_scores(args.dataset)


if __name__ == "__main__":
    main()
