"""The NumPy forms of rock stamping and bilinear resampling that ``lidarsim.procedural.stamp_rocks``
and ``lidarsim.base_relief.resample_bilinear`` had before they were compiled with numba: the
oracles their compiled kernels must equal bit for bit (the published terrains' sha256 rest on them)."""

from __future__ import annotations

import numpy as np


def stamp_rocks_numpy(
    heights: np.ndarray, spacing_m: float, centers_m: np.ndarray, diameters_m: np.ndarray, height_ratio: float
) -> None:
    """Half-ellipsoid rocks merged with ``max()`` (in place), vectorised per rock half-width."""
    centers = np.asarray(centers_m, dtype=np.float64).reshape(-1, 2)
    diam = np.asarray(diameters_m, dtype=np.float64).ravel()
    if diam.size == 0:
        return
    rows, cols = heights.shape
    crow = np.clip(np.floor(centers[:, 1] / spacing_m).astype(np.int64), 0, rows - 1)
    ccol = np.clip(np.floor(centers[:, 0] / spacing_m).astype(np.int64), 0, cols - 1)
    base = heights[crow, ccol].astype(np.float64)
    radius = 0.5 * diam
    half_width = np.ceil(radius / spacing_m).astype(np.int64) + 1
    flat = heights.reshape(-1)
    for hw in np.unique(half_width):
        sel = np.nonzero(half_width == hw)[0]
        offs = np.arange(-hw, hw + 1)
        dr, dc = np.meshgrid(offs, offs, indexing="ij")
        rr = crow[sel, None] + dr.ravel()[None, :]
        cc = ccol[sel, None] + dc.ravel()[None, :]
        dy = (rr + 0.5) * spacing_m - centers[sel, 1:2]
        dx = (cc + 0.5) * spacing_m - centers[sel, 0:1]
        rho2 = (dx**2 + dy**2) / radius[sel, None] ** 2
        keep = (rho2 < 1.0) & (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
        z = base[sel, None] + height_ratio * diam[sel, None] * np.sqrt(np.clip(1.0 - rho2, 0.0, None))
        with np.errstate(invalid="ignore"):  # NaN heights stay NaN
            np.maximum.at(flat, (rr[keep] * cols + cc[keep]), z[keep].astype(heights.dtype))


def _axis_weights(n_out: int, spacing_m: float, n_src: int, src_spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
    pos = ((np.arange(n_out, dtype=np.float64) + 0.5) * spacing_m) / src_spacing_m - 0.5
    pos = np.clip(pos, 0.0, n_src - 1.0)
    lo = np.minimum(np.floor(pos).astype(np.int64), max(n_src - 2, 0))
    return lo, pos - lo


def _lerp(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        mixed = a * (1.0 - w) + b * w
    return np.where(w == 0.0, a, np.where(w == 1.0, b, mixed))


def resample_bilinear_numpy(
    values: np.ndarray, src_spacing_m: tuple[float, float], spacing_m: float, shape: tuple[int, int]
) -> np.ndarray:
    """Separable bilinear resampling: along columns for every source row, then along rows."""
    src = np.asarray(values, dtype=np.float64)
    rows, cols = src.shape
    r_lo, r_w = _axis_weights(shape[0], spacing_m, rows, src_spacing_m[1])
    c_lo, c_w = _axis_weights(shape[1], spacing_m, cols, src_spacing_m[0])
    c_hi = np.minimum(c_lo + 1, cols - 1)
    r_hi = np.minimum(r_lo + 1, rows - 1)
    across = _lerp(src[:, c_lo], src[:, c_hi], c_w[None, :])
    return _lerp(across[r_lo], across[r_hi], r_w[:, None])
