"""Landing sites of a safety map: ranked, non-overlapping, each with its whole lander footprint safe and certain.

Used by ``hd detect`` (sites of a whole map) and by ``hd eval``'s landing table (each method's best
site per test scene, ``hdnet.landing_table``), so that both choose sites with the same code.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from rasterio.transform import Affine
from scipy import ndimage

from hdlabels.lander import Lander
from hdnet.landing import dispersion_weighted
from hdnet.results import Site

# The codes of a safety map (``safety.tif`` of ``hd detect``).
SAFETY_UNSAFE, SAFETY_SAFE, SAFETY_UNCERTAIN, SAFETY_INVALID = 0, 1, 2, 255
# hd choice: sites are ranked by their footprint-mean P(safe) rounded to 0.001, then by clearance.
# Differences below 0.001 are far inside the MC estimate's spread (M = 8), so clearance decides.
SITE_RANK_DECIMALS = 3
# How select_sites ranks, as detect.json and sites.csv's readers are told (by dispersion: none or some).
SITE_RANK_RULES = {
    "aim": "disk-mean P(safe) of the aim point's lander footprint (rounded to 0.001), then clearance",
    "touchdown": (
        "expected P(safe) at the touchdown under the navigation dispersion, unsafe, uncertain and invalid "
        "ground counting 0 (rounded to 0.001), then clearance"
    ),
}
# What a site keeps safe and certain, with a margin (``select_sites``'s ``margin_m``) or without.
SITE_FOOTPRINTS = {"body": "lander body disk", "margin": "lander body disk widened by margin_m all round"}


def body_disk(lander: Lander, spacing_m: float, margin_m: float = 0.0) -> np.ndarray:
    """(2k+1, 2k+1) bool: the cells whose centres lie under the lander body (a disk of the lander's
    diameter) when it is centred on the middle cell, widened by ``margin_m`` metres all round;
    ``spacing_m`` in metres per cell."""
    r = (lander.radius_m + margin_m) / spacing_m
    k = int(math.floor(r + 1e-9))
    di, dj = np.mgrid[-k : k + 1, -k : k + 1]
    return di * di + dj * dj <= r * r + 1e-9


def select_sites(
    safety: np.ndarray,
    p_safe: np.ndarray,
    entropy: Any,
    baseline: Any,
    transform: Affine,
    spacing_xy_m: tuple[float, float],
    lander: Lander,
    n_sites: int,
    nav_sigma_m: float = 0.0,
    margin_m: float = 0.0,
) -> list[Site]:
    """Ranked, non-overlapping landing sites of a safety map.

    A site is a cell whose whole lander body disk is safe and certain (``safety == 1``); its
    ``p_safe`` is the mean P(safe) over the disk, ``entropy_max`` the largest entropy there,
    ``clearance_m`` the distance between cell centres to the nearest unsafe, uncertain or invalid
    cell (cells outside the grid count as invalid), ``baseline_p_safe`` the baseline at the site and
    ``touchdown_p_safe`` the map's expected P(safe) at the touchdown: with the navigation dispersion
    ``nav_sigma_m`` (metres, 1-sigma per horizontal axis, ``hdnet.landing``), the mean over where the
    vehicle lands of P(safe) on safe and certain cells and 0 elsewhere (unsafe, uncertain, invalid,
    outside the map); for sigma = 0, P(safe) at the site's own cell.

    Ranking (``SITE_RANK_RULES``): with ``nav_sigma_m`` = 0, best first by (the disk-mean P(safe)
    rounded to ``SITE_RANK_DECIMALS``, clearance, north, west); with ``nav_sigma_m`` > 0, by
    (``touchdown_p_safe`` rounded the same way, clearance, north, west): the probability that the
    touchdown, not only the aim point, is safe and certain (Ivanov et al. 2013 weigh the safety map
    with the navigation dispersion in the same way). Greedy: each site removes every candidate closer
    than one lander diameter; at most ``n_sites``.

    ``safety`` (uint8) and ``p_safe`` (float) are whole arrays; ``entropy`` and ``baseline`` are read
    only around the chosen sites, through 2-D slicing (arrays, or windowed raster readers).
    ``margin_m`` (metres): a safety margin; a site's body disk widened by it all round must be safe
    and certain too (the disk-mean P(safe), the entropy and the ranking stay those of the body disk).
    The hazards a map misses lie mostly right beside ground it calls safe (docs/results.md, "Landing
    safety"), so a margin trades sites for safety.

    Memory: about 32 bytes per cell at the peak (the distance transform), besides the two inputs.
    """
    sx, sy = spacing_xy_m
    disk = body_disk(lander, float(np.sqrt(sx * sy)))
    kept = body_disk(lander, float(np.sqrt(sx * sy)), margin_m) if margin_m > 0.0 else disk
    clear = safety == SAFETY_SAFE
    candidate = ndimage.binary_erosion(clear, structure=kept, border_value=0)
    if not candidate.any():
        return []
    # One ranking key per cell: round(P, 3) * scale + clearance, scale > any clearance; P the disk-mean
    # P(safe) or, with a dispersion, the expected P(safe) at the touchdown.
    clear_p = np.where(clear, p_safe, 0.0).astype(np.float64)
    touchdown = dispersion_weighted(clear_p, nav_sigma_m, (sx, sy))
    key = touchdown.copy() if nav_sigma_m > 0.0 else ndimage.correlate(clear_p, disk / disk.sum(), mode="constant")
    del clear_p
    np.multiply(key, 10.0**SITE_RANK_DECIMALS, out=key)
    np.rint(key, out=key)
    h, w = clear.shape
    key *= 2.0 ** math.ceil(math.log2(math.hypot(h * sy, w * sx) + 1.0))
    edt = ndimage.distance_transform_edt(np.pad(clear, 1), sampling=(sy, sx))[1:-1, 1:-1]  # outside = invalid
    key += edt
    clearance = edt.astype(np.float32)
    del edt
    key[~candidate] = -np.inf
    d = lander.diameter_m
    ri, rj = int(math.ceil(d / sy)), int(math.ceil(d / sx))
    di, dj = np.mgrid[-ri : ri + 1, -rj : rj + 1]
    too_close = (di * sy) ** 2 + (dj * sx) ** 2 < d * d * (1.0 - 1e-12)
    sites: list[Site] = []
    while len(sites) < n_sites:
        k = int(np.argmax(key))  # the first maximum in row-major order: ties go north, then west
        r, c = divmod(k, w)
        if key[r, c] == -np.inf:
            break
        sites.append(_site(len(sites) + 1, r, c, disk, transform, p_safe, entropy, baseline, clearance, touchdown))
        r0, r1, c0, c1 = max(r - ri, 0), min(r + ri + 1, h), max(c - rj, 0), min(c + rj + 1, w)
        key[r0:r1, c0:c1][too_close[r0 - r + ri : r1 - r + ri, c0 - c + rj : c1 - c + rj]] = -np.inf
    return sites


def _site(
    rank: int,
    r: int,
    c: int,
    disk: np.ndarray,
    transform: Affine,
    p_safe: np.ndarray,
    entropy: Any,
    baseline: Any,
    clearance: np.ndarray,
    touchdown: np.ndarray,
) -> Site:
    """Step 2 of ``select_sites``: the site of rank ``rank`` at cell (``r``, ``c``): its map position (the
    cell centre through ``transform``), the disk-mean P(safe), the disk's largest entropy, its clearance
    (metres), the baseline and the touchdown P(safe) at the cell."""
    rd = disk.shape[0] // 2
    window = (slice(r - rd, r + rd + 1), slice(c - rd, c + rd + 1))
    x, y = transform @ (c + 0.5, r + 0.5)
    return Site(
        rank,
        float(x),
        float(y),
        float(np.mean(np.asarray(p_safe[window], np.float64)[disk])),
        float(np.max(np.asarray(entropy[window])[disk])),
        float(clearance[r, c]),
        float(np.asarray(baseline[r : r + 1, c : c + 1])[0, 0]),
        r,
        c,
        float(touchdown[r, c]),
    )
