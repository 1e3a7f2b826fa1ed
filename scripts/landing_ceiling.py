"""How safe a landing can be when the site is chosen from the scan: the sensing ceiling of the landing table.

For docs/results.md, "Landing safety". In every scene of a dataset's split, an **oracle** that knows a
labelling's map perfectly (no noise, no network: the stored labels themselves, safe where 1) picks
its best site with ``hd detect``'s rule (``hdnet.sites.select_sites``, the same dispersion the
touchdowns are drawn with), and the touchdowns are scored against the **terrain** truth exactly as
``hd eval``'s landing table scores them (``hdnet.landing``). No method that reads the scan can
beat the oracle of the clean scan's labels on average; an oracle of a stricter labelling of the clean
scan (a lower roughness or slope limit than the lander's: a margin) shows what a margin buys, and at
what abstain rate. The terrain's own labels as the oracle give the ceiling that the dispersion alone
leaves.

Also printed: the pixel precision of each oracle against the terrain (of the pixels the oracle calls
safe, the fraction the terrain calls safe), and with ``--altitude-bins`` the same table per bin of
the scans' altitude above their nadir point (metres): the sensor's samples thin out with range.

Usage::

    python scripts/landing_ceiling.py DATASET --terrain LABELLING --oracle NAME=LABELLING ... [--split test]
        [--altitude-bins 250,500,750,1000]
"""

from __future__ import annotations

import argparse
import itertools
import math
from pathlib import Path

import numpy as np
from rasterio.transform import Affine

from hdcore.storage import confine, open_h5
from hdlabels.lander import Lander
from hdlabels.store import find_labeling
from hdnet.data import split_labels
from hdnet.defaults import NAV_SIGMAS_M, TOUCHDOWNS
from hdnet.landing import LandingTally, score_touchdowns, touchdown_offsets
from hdnet.sites import SAFETY_INVALID, SAFETY_SAFE, SAFETY_UNSAFE, select_sites
from lidarsim.shards import read_manifest

SAFE, INVALID = 1, 255


def oracle_map(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The safety map (``hdnet.sites`` codes) and P(safe) of an oracle that trusts ``labels``."""
    safety = np.where(labels == SAFE, SAFETY_SAFE, SAFETY_UNSAFE).astype(np.uint8)
    safety[labels == INVALID] = SAFETY_INVALID
    return safety, (labels == SAFE).astype(np.float32)


def scan_altitudes(dataset: Path) -> dict[int, float]:
    """Each scan's sensor height above its nadir point (metres), by scan index."""
    out: dict[int, float] = {}
    for entry in read_manifest(dataset)["shards"]:
        with open_h5(confine(dataset, entry["path"])) as f:
            z = np.asarray(f["sensor_position"][:, 2] - f["origin_map"][:, 2])
            out.update(zip((int(i) for i in f["scan_index"][:]), (float(v) for v in z), strict=True))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--terrain", required=True, help="the terrain-truth labelling that scores the touchdowns")
    parser.add_argument("--oracle", action="append", default=[], help="NAME=LABELLING, repeatable")
    parser.add_argument("--split", default="test")
    parser.add_argument("--nav-sigma", type=float, action="append", help="metres (default 0, 1, 3)")
    parser.add_argument("--altitude-bins", help="comma-separated altitude edges, metres: one table per bin")
    args = parser.parse_args()
    navs = tuple(args.nav_sigma or NAV_SIGMAS_M)
    terrain = split_labels(args.dataset, args.split, args.terrain)
    entry = find_labeling(args.dataset, args.terrain)
    lander, spacing = entry.lander, entry.spacing_m
    oracles = [("terrain truth", args.terrain), *(tuple(o.split("=", 1)) for o in args.oracle)]
    print(
        f"{len(terrain)} {args.split} scenes of {args.dataset}; touchdowns scored against {args.terrain}; "
        f"{TOUCHDOWNS} touchdowns per scene\n"
    )
    bins: list[tuple[float, float]] = [(-math.inf, math.inf)]
    altitude: dict[int, float] = {}
    if args.altitude_bins:
        edges = [float(e) for e in args.altitude_bins.split(",")]
        bins += list(itertools.pairwise(edges))
        altitude = scan_altitudes(args.dataset)
    maps = {labelling: split_labels(args.dataset, args.split, labelling) for _, labelling in oracles}
    for lo, hi in bins:
        last = hi == bins[-1][1]  # the last bin holds its upper edge
        scans = sorted(s for s in terrain if not altitude or lo <= altitude[s] < hi or (last and altitude[s] == hi))
        if math.isfinite(lo):
            print(f"\n**Scans from {lo:g} to {hi:g} m** ({len(scans)} scenes)\n")
        print("| oracle | pixel precision vs terrain | safe % | " + " | ".join(f"nav. {n:g} m" for n in navs) + " |")
        print("|---|---|---|" + "---|" * len(navs))
        for name, labelling in oracles:
            print(_row(name, maps[labelling], terrain, scans, navs, lander, spacing))


def _row(
    name: str,
    maps: dict[int, np.ndarray],
    terrain: dict[int, np.ndarray],
    scans: list[int],
    navs: tuple[float, ...],
    lander: Lander,
    spacing: float,
) -> str:
    """One oracle's table row over ``scans``."""
    tallies = {nav: LandingTally() for nav in navs}
    tp = called = valid = 0
    for scan in scans:
        truth, lab = terrain[scan], maps[scan]
        h = lab.shape[0]
        transform = Affine(spacing, 0.0, 0.0, 0.0, -spacing, h * spacing)
        safety, p = oracle_map(lab)
        ok = (lab != INVALID) & (truth != INVALID)
        called += int(np.sum(ok & (lab == SAFE)))
        tp += int(np.sum(ok & (lab == SAFE) & (truth == SAFE)))
        valid += int(np.sum(ok))
        unit = touchdown_offsets(TOUCHDOWNS, 1.0, 0, scan)
        for nav in navs:
            sites = select_sites(safety, p, p, p, transform, (spacing, spacing), lander, 1, nav)
            if not sites:
                tallies[nav].abstain()
                continue
            score = score_touchdowns(truth, sites[0].row, sites[0].col, unit * nav, (spacing, spacing))
            tallies[nav].land(score, sites[0].clearance_m, math.nan)
    cells = []
    for nav in navs:
        row = tallies[nav].row("oracle", 0.0, nav, "terrain")
        p_safe = "\u2013" if not math.isfinite(row.p_safe) else f"{row.p_safe:.4f} [{row.p_safe_low:.4f}]"
        cells.append(f"{p_safe} · abstain {100 * row.abstain_rate:.1f} %")
    precision = tp / called if called else math.nan
    return f"| {name} | {precision:.4f} | {100 * called / max(valid, 1):.1f} | " + " | ".join(cells) + " |"


if __name__ == "__main__":
    main()
