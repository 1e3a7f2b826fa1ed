"""Dead detector elements on a DEM: drop pixels, refill them, mask their lander-size neighbourhood.

The paper's damaged-DEM test ("Damaged elements", Table 2): ten random pixels are dropped from
the 100x100 DEM, reconstructed by bilinear interpolation, and every pixel whose lander
footprint reaches a dropped pixel is ignored in the metrics.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from hdlabels import defaults
from hdlabels.errors import HdLabelsError
from hdlabels.lander import Lander, geometry


def random_dead_pixels(shape: tuple[int, int], k: int, rng: np.random.Generator) -> np.ndarray:
    """``k`` distinct pixels drawn uniformly from a DEM of ``shape``, as a (k, 2) int64 (row, col) array."""
    if len(shape) != 2 or min(shape) < 1:
        raise HdLabelsError(f"DEM shape must be two positive integers, got {shape!r}.")
    n = int(shape[0]) * int(shape[1])
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k <= n:
        raise HdLabelsError(f"The number of dead pixels must be an integer in [0, {n}], got {k!r}.")
    flat = rng.choice(n, size=int(k), replace=False)
    return np.stack(np.unravel_index(flat, shape), axis=1).astype(np.int64)


def drop_and_repair(
    dem: np.ndarray,
    pixels: np.ndarray,
    lander: Lander = Lander(),
    spacing_m: float = defaults.DEM_SPACING_M,
) -> tuple[np.ndarray, np.ndarray]:
    """Drop the given pixels of a DEM, refill them by bilinear interpolation, mask their neighbourhoods.

    Refill: each dropped pixel takes the mean of the linear interpolations along its row and along
    its column between the nearest valid (not dropped, finite) pixels on either side; for an
    isolated pixel that is the mean of its four neighbours, the bilinear kernel of dead-pixel
    correction. Exact on planes. Where no axis has valid pixels on both sides (a DEM edge or
    corner), the line through the two nearest valid pixels on one side is extended instead; a
    pixel with no two valid pixels on any axis stays NaN.

    Args:
        dem: (H, W) heights, metres.
        pixels: (K, 2) integer (row, col) pixels to drop.
        lander: defines the neighbourhood to ignore (its footprint, see ``hdlabels.lander``).
        spacing_m: DEM spacing, metres per pixel.

    Returns:
        (repaired DEM as float32, bool mask of the pixels whose lander footprint contains a dropped pixel).
    """
    z = np.asarray(dem)
    if z.ndim != 2 or not np.issubdtype(z.dtype, np.number):
        raise HdLabelsError(f"A DEM must be a 2-D numeric array, got shape {z.shape} of {z.dtype}.")
    px = np.asarray(pixels)
    if px.size == 0:
        px = px.reshape(0, 2)
    if px.ndim != 2 or px.shape[1] != 2 or not np.issubdtype(px.dtype, np.integer):
        raise HdLabelsError(f"Dead pixels must be a (K, 2) integer array of (row, col), got shape {px.shape}.")
    h, w = z.shape
    if px.size and (px.min() < 0 or (px[:, 0] >= h).any() or (px[:, 1] >= w).any()):
        raise HdLabelsError(f"A dead pixel lies outside the {h}x{w} DEM.")
    if not (math.isfinite(spacing_m) and spacing_m > 0):
        raise HdLabelsError(f"DEM spacing must be a finite positive number of metres per pixel, got {spacing_m!r}.")

    out = z.astype(np.float64, copy=True)
    dropped = np.zeros((h, w), dtype=bool)
    dropped[px[:, 0], px[:, 1]] = True
    good = ~dropped & np.isfinite(out)
    for i, j in px:
        out[i, j] = _refill(out, good, int(i), int(j))

    footprint = geometry(lander, float(spacing_m)).footprint
    mask = ndimage.binary_dilation(dropped, structure=footprint) if dropped.any() else dropped
    return out.astype(np.float32), mask


def _refill(z: np.ndarray, good: np.ndarray, i: int, j: int) -> float:
    """Refill pixel (i, j) from the nearest good pixels along its row and its column (see drop_and_repair)."""
    between: list[float] = []
    beyond: list[float] = []
    for line, good_line, pos in ((z[i, :], good[i, :], j), (z[:, j], good[:, j], i)):
        before = np.flatnonzero(good_line[:pos])
        after = np.flatnonzero(good_line[pos + 1 :]) + pos + 1
        if before.size and after.size:
            a, b = before[-1], after[0]
        elif before.size >= 2:
            a, b = before[-2], before[-1]
        elif after.size >= 2:
            a, b = after[0], after[1]
        else:
            continue
        t = (pos - a) / (b - a)
        value = (1.0 - t) * line[a] + t * line[b]
        (between if a < pos < b else beyond).append(value)
    if between or beyond:
        return float(np.mean(between or beyond))
    return float("nan")
