"""The ALHAT baseline on descent mosaics against single frames, scored against the terrain.

For every descent of one split of a descent dataset (a built recipe, e.g. ``datasets/mars-descent``)
and each stored noise level, the probabilistic baseline P(safe) >= 0.5 (the dataset's labelling's
lander, the paper's rule) is computed on: the lowest frame alone (250 m), a middle frame alone (about
500 m), and the mosaic of all the frames placed with the true poses, the navigation estimate, and
the registered estimate (``hdlabels.mosaic``). Each is scored pixel by pixel against the **terrain
truth** on its own grid: the terrain's mesh sampled at each cell centre (a single frame: in its scan
frame, the target's; a navigation or registered mosaic: in the lowest frame's navigation frame, where
the mosaic lies, through the inverse of that frame's navigation error), labelled with the same lander.
Prints per product and noise level: the labelled share of the 100 x 100 grid (coverage), the
baseline's safe share, its precision and sensitivity for "safe" against the terrain truth.

Run: ``.venv/bin/python scripts/mosaic_baseline.py DATASET [--split test] [--frame-mid 5]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hdlabels import defaults
from hdlabels.alhat import hazard_maps, safety_probability
from hdlabels.grid import cell_centres, grid_points
from hdlabels.lander import Lander
from hdlabels.mosaic import MosaicFrame, apply, descent_frames, mosaic_frames, navigation_error
from hdlabels.store import DemSpec
from hdlabels.truth import check_build_terrain, mesh_heights
from lidarsim.shards import iter_descents, read_manifest
from lidarsim.terrain import DTM

PRODUCTS = ("lowest frame", "middle frame", "mosaic, true poses", "mosaic, navigation", "mosaic, registered")


def truth_dem(dtm: DTM, dem: DemSpec, target: np.ndarray, to_true: np.ndarray) -> np.ndarray:
    """The terrain's height under each cell centre of a grid lying in the frame ``to_true`` takes to the
    true map (metres, relative to the target; NaN off the terrain)."""
    xc, yc = cell_centres((dem.rows, dem.cols), dem.spacing_m)
    xx, yy = np.meshgrid(xc, yc)
    placed = np.stack([xx, yy, np.zeros_like(xx)], axis=-1) + target
    true = apply(to_true, placed)
    heights = mesh_heights(dtm, true[..., 0], true[..., 1])
    ground = np.stack([true[..., 0], true[..., 1], heights], axis=-1)
    return apply(np.linalg.inv(to_true), ground)[..., 2] - target[2]


def single_frame(frame: MosaicFrame, dem: DemSpec) -> np.ndarray:
    """A frame gridded alone in its scan frame (the target's, true pose), metres."""
    return grid_points(frame.points, (dem.rows, dem.cols), dem.spacing_m, method=dem.gridding)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--split", default="test")
    parser.add_argument("--frame-mid", type=int, default=5, help="the middle frame's index (5 of 9: 531 m)")
    args = parser.parse_args()
    manifest = read_manifest(args.dataset)
    entry = manifest["labelings"][0]
    lander = Lander.from_attrs(entry["lander"])
    dem = DemSpec.from_entry(entry["dem"])
    sigmas = [float(s) for s in manifest["sigmas_m"]]
    path, _, scale = check_build_terrain(args.dataset, manifest)
    # per (product, sigma): counts of true safe, false safe, false unsafe; labelled and grid cells
    tally: dict[tuple[str, float], np.ndarray] = {}
    n_descents = 0
    with DTM.open(path, scale) as dtm:
        for scans in iter_descents(args.dataset, args.split):
            n_descents += 1
            clean, target = descent_frames(scans, None)
            to_true_nav = np.linalg.inv(navigation_error(clean[-1]))
            truths = {
                "single": hazard_maps(truth_dem(dtm, dem, target, np.eye(4)), dem.spacing_m, lander).label,
                "nav": hazard_maps(truth_dem(dtm, dem, target, to_true_nav), dem.spacing_m, lander).label,
            }
            for s, sigma in enumerate(sigmas):
                frames, _ = descent_frames(scans, s)
                heights = {
                    PRODUCTS[0]: (single_frame(frames[-1], dem), "single"),
                    PRODUCTS[1]: (single_frame(frames[args.frame_mid], dem), "single"),
                    PRODUCTS[2]: (mosaic_frames(frames, target, dem, "true").heights, "single"),
                    PRODUCTS[3]: (mosaic_frames(frames, target, dem, "nav").heights, "nav"),
                    PRODUCTS[4]: (mosaic_frames(frames, target, dem, "registered").heights, "nav"),
                }
                for product, (h, frame) in heights.items():
                    label = truths[frame]
                    p_safe = safety_probability(h, dem.spacing_m, sigma, lander)
                    valid = (label != defaults.LABEL_INVALID) & np.isfinite(p_safe)
                    safe_truth = label == defaults.LABEL_SAFE
                    safe_pred = np.nan_to_num(p_safe) >= defaults.SAFE_PROBABILITY_THRESHOLD
                    counts = np.array(
                        [
                            (valid & safe_truth & safe_pred).sum(),
                            (valid & ~safe_truth & safe_pred).sum(),
                            (valid & safe_truth & ~safe_pred).sum(),
                            valid.sum(),
                            label.size,
                        ]
                    )
                    tally[(product, sigma)] = tally.get((product, sigma), 0) + counts
    print(
        f"{args.dataset.name}, {args.split} split, {n_descents} descents; baseline P(safe) >= 0.5 vs the terrain "
        f"truth; DEM {dem.rows}x{dem.cols} at {dem.spacing_m:g} m, {dem.gridding}"
    )
    print("| product | sigma | coverage | baseline safe | precision | sensitivity |")
    print("|---|---|---:|---:|---:|---:|")
    for sigma in sigmas:
        for product in PRODUCTS:
            ts, fs, fu, n, cells = tally[(product, sigma)]
            print(
                f"| {product} | {100 * sigma:g} cm | {n / cells:.1%} | {(ts + fs) / max(n, 1):.1%} | "
                f"{ts / max(ts + fs, 1):.4f} | {ts / max(ts + fu, 1):.4f} |"
            )


if __name__ == "__main__":
    main()
