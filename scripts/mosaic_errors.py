"""Mosaic height error against the terrain: true, navigation and registered poses, across navigation errors.

For each navigation error level L (position metres : attitude degrees), builds a descent dataset on
the procedural terrain (or ``--dtm``) with a bias of 1-sigma L per axis and a random walk of L/3 per
frame (so that after 9 frames the walk alone reaches L), the same seed for every level (the same
descents, frames and range noise; only the navigation error differs), and mosaics every descent
with the three poses at each stored noise level (and the clean points). Prints one markdown table:
per level, sigma and poses, the RMS and 99th percentile of |height error| over every mosaic cell
(``hdlabels.mosaic.terrain_residual``, in the anchor's navigation frame for ``nav`` and
``registered``), the ratio to the true poses' RMS, the frames' mean RMS disagreement with the anchor,
and the mean time per mosaic.

Run: ``.venv/bin/python scripts/mosaic_errors.py --out /tmp/mosaics [--descents 20] [--levels 0.3:0.05 1:0.1 3:0.3]``,
or ``--dataset DIR [--split test]`` to measure a built descent dataset (a recipe) at its own error.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hdlabels.mosaic import POSES, Poses, descent_frames, mosaic_frames, navigation_error, terrain_residual
from hdlabels.store import DemSpec
from hdlabels.truth import check_build_terrain
from lidarsim.build import build_dataset
from lidarsim.recipe import BuildSettings
from lidarsim.shards import iter_descents, read_manifest
from lidarsim.terrain import DTM


def build(out: Path, args: argparse.Namespace, position_m: float, attitude_deg: float) -> Path:
    """The descent dataset of one navigation error level (built once; reused when present)."""
    if (out / "manifest.json").exists():
        return out
    settings = BuildSettings(
        scans=args.descents,
        descent_frames=args.frames,
        descent_altitudes_m=args.altitudes,
        nav_position_sigma_m=position_m,
        nav_position_walk_m=position_m / 3.0,
        nav_attitude_sigma_deg=attitude_deg,
        nav_attitude_walk_deg=attitude_deg / 3.0,
        sigmas_m=tuple(args.sigmas),
        seed=args.seed,
        **({"dtm_path": args.dtm} if args.dtm else {}),
    )
    build_dataset(out, settings.to_config(), workers=args.workers)
    return out


def measure(
    dataset: Path, dem: DemSpec, poses: tuple[Poses, ...], split: str | None = None
) -> dict[tuple[str, str], dict[str, float]]:
    """Per (sigma label, poses): RMS and p99 of |height error| (metres), mean frame residual and time per mosaic."""
    manifest = read_manifest(dataset)
    path, _, scale = check_build_terrain(dataset, manifest)
    sigmas = [None, *range(len(manifest["sigmas_m"]))]
    labels = ["clean", *(f"{100 * s:g} cm" for s in manifest["sigmas_m"])]
    errors: dict[tuple[str, str], list[np.ndarray]] = {}
    agreement: dict[tuple[str, str], list[float]] = {}
    seconds: dict[tuple[str, str], list[float]] = {}
    with DTM.open(path, scale) as dtm:
        for scans in iter_descents(dataset, split):
            for s, label in zip(sigmas, labels, strict=True):
                frames, target = descent_frames(scans, s)
                to_true = np.linalg.inv(navigation_error(frames[-1]))
                for p in poses:
                    t0 = time.perf_counter()
                    mosaic = mosaic_frames(frames, target, dem, p)
                    seconds.setdefault((label, p), []).append(time.perf_counter() - t0)
                    r = terrain_residual(mosaic.heights, dem, target, np.eye(4) if p == "true" else to_true, dtm)
                    errors.setdefault((label, p), []).append(r[np.isfinite(r)])
                    agreement.setdefault((label, p), []).append(float(np.nanmean(mosaic.frame_residual_m[:-1])))
    out = {}
    for key, errs in errors.items():
        e = np.abs(np.concatenate(errs))
        out[key] = {
            "rms": float(np.sqrt(np.mean(e**2))),
            "p99": float(np.percentile(e, 99)),
            "agree": float(np.mean(agreement[key])),
            "seconds": float(np.mean(seconds[key])),
        }
    return out


def measure_dataset(dataset: Path, split: str, dem: DemSpec) -> None:
    """Print the table for one built descent dataset (its own navigation error), one split."""
    manifest = read_manifest(dataset)
    config = manifest["config"]["trajectory"]["descent"]
    nav = config["nav"]
    print(
        f"{dataset.name}, {split} split: descents of {config['frames']} frames, {config['altitude_start_m']:g} to "
        f"{config['altitude_end_m']:g} m, approach {config['approach_deg']:g} deg; navigation error "
        f"{nav['position_sigma_m']:g} m + {nav['position_walk_m']:g} m/frame, {nav['attitude_sigma_deg']:g} deg + "
        f"{nav['attitude_walk_deg']:g} deg/frame; DEM {dem.rows}x{dem.cols} at {dem.spacing_m:g} m, {dem.gridding}"
    )
    print("| sigma | poses | RMS (cm) | p99 (cm) | RMS / true | frames vs anchor (cm) | s per mosaic |")
    print("|---|---|---:|---:|---:|---:|---:|")
    rows = measure(dataset, dem, POSES, split)
    true_rms = {label: row["rms"] for (label, p), row in rows.items() if p == "true"}
    for (label, p), row in sorted(rows.items(), key=lambda kv: (kv[0][0], POSES.index(kv[0][1]))):
        print(
            f"| {label} | {p} | {100 * row['rms']:.2f} | {100 * row['p99']:.2f} | {row['rms'] / true_rms[label]:.2f} | "
            f"{100 * row['agree']:.2f} | {row['seconds']:.2f} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, help="work directory (datasets are kept and reused)")
    parser.add_argument(
        "--dataset",
        type=Path,
        help="instead: measure this descent dataset (a built recipe) at its own navigation error, --split only",
    )
    parser.add_argument("--split", default="test", help="with --dataset: the split measured (default test)")
    parser.add_argument("--descents", type=int, default=20)
    parser.add_argument("--frames", type=int, default=9)
    parser.add_argument("--altitudes", default="1000:250")
    parser.add_argument("--sigmas", type=float, nargs="+", default=[0.0167, 0.07])
    parser.add_argument("--levels", nargs="+", default=["0.3:0.05", "1:0.1", "3:0.3"], help="POSITION_M:ATTITUDE_DEG")
    parser.add_argument("--dtm", default=None, help="a DTM (default: the procedural terrain)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    dem = DemSpec(gridding="linear")
    if args.dataset is not None:
        measure_dataset(args.dataset, args.split, dem)
        return
    if args.out is None:
        parser.error("give --out (a work directory) or --dataset")
    print(
        f"{args.descents} descents of {args.frames} frames, {args.altitudes} m; "
        f"DEM {dem.rows}x{dem.cols} at {dem.spacing_m:g} m, {dem.gridding} gridding"
    )
    print(
        "| nav error (bias; walk = bias/3 per frame) | sigma | poses | RMS (cm) | p99 (cm) | RMS / true "
        "| frames vs anchor (cm) | s per mosaic |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|")
    true_rms: dict[str, float] = {}
    for k, level in enumerate(args.levels):
        position_m, attitude_deg = (float(v) for v in level.split(":"))
        dataset = build(args.out / f"nav-{position_m:g}m-{attitude_deg:g}deg", args, position_m, attitude_deg)
        # the true poses do not depend on the navigation error: measured once
        poses: tuple[Poses, ...] = POSES if k == 0 else ("nav", "registered")
        rows = measure(dataset, dem, poses)
        for (label, p), row in sorted(rows.items(), key=lambda kv: (kv[0][0], POSES.index(kv[0][1]))):
            if p == "true":
                true_rms[label] = row["rms"]
            ratio = row["rms"] / true_rms[label]
            print(
                f"| {position_m:g} m, {attitude_deg:g} deg | {label} | {p} | {100 * row['rms']:.2f} | "
                f"{100 * row['p99']:.2f} | {ratio:.2f} | {100 * row['agree']:.2f} | {row['seconds']:.2f} |"
            )


if __name__ == "__main__":
    main()
