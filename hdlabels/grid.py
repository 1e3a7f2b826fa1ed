"""Organised flash-LiDAR points to a north-up DEM, by one of three griddings.

* ``"linear"``: linear interpolation over the detector's own grid. Each 2x2 block of neighbouring
  returns is a quad, split into two triangles along the diagonal that the Delaunay (empty
  circumcircle) test prefers, so on a regular, convex scan the result equals the Delaunay
  triangulation that ``scipy.interpolate.LinearNDInterpolator`` builds. A DEM cell takes the value
  of the plane through the triangle that contains its centre. Cells inside no triangle (outside
  the scan, or under a missing return) stay NaN: nothing is extrapolated.
* ``"mean"`` / ``"max"`` / ``"nearest"``: binning. Every return falls in the cell whose square
  contains it; a cell takes the mean, the highest, or the most central (closest to the cell centre)
  height of its returns. A cell without a return of its own (the
  returns are sparser than the cells) takes the linear interpolation at its centre, so binning
  never leaves a hole where interpolation would not.

Interpolation averages neighbouring returns and keeps less of the range noise than binning
(docs/labels.md, "Gridding", has the residual DEM noise of each, measured on flat terrain).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from hdlabels import defaults
from hdlabels.errors import HdLabelsError

# A cell centre counts as inside a triangle if its barycentric coordinates are >= -_BARY_EPS.
_BARY_EPS = 1e-9


def cell_centres(shape: tuple[int, int], spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Map coordinates (x east, y north), metres, of the DEM cell centres: 1-D ``x`` per column, ``y`` per row.

    Cell ``(i, j)`` is centred at ``x = (j - (W - 1) / 2) * spacing``, ``y = ((H - 1) / 2 - i) * spacing``.
    """
    rows, cols = shape
    x = (np.arange(cols) - (cols - 1) / 2.0) * spacing_m
    y = ((rows - 1) / 2.0 - np.arange(rows)) * spacing_m
    return x, y


def grid_points(
    points: np.ndarray,
    shape: tuple[int, int] = (defaults.DEM_ROWS, defaults.DEM_COLS),
    spacing_m: float = defaults.DEM_SPACING_M,
    *,
    method: str = "linear",
) -> np.ndarray:
    """Grid organised LiDAR returns into a DEM (float32, metres, NaN where unsupported).

    Args:
        points: (H, W, 3) returns in the scan frame (origin at the sensor nadir point, x east,
            y north, z up, metres), in detector order; NaN where there is no return.
        shape: (rows, cols) of the DEM.
        spacing_m: DEM spacing, metres per pixel; the DEM is north-up and centred at (0, 0).
        method: ``"linear"`` (interpolation of the triangle containing each cell centre),
            ``"mean"`` or ``"max"`` (of the returns falling in each cell); see the module docstring.

    Returns:
        (rows, cols) float32 heights.
    """
    pts = np.asarray(points)
    if pts.ndim != 3 or pts.shape[2] != 3 or pts.shape[0] < 2 or pts.shape[1] < 2:
        raise HdLabelsError(f"Points must be an organised (H, W, 3) array with H, W >= 2, got shape {pts.shape}.")
    if len(shape) != 2 or min(shape) < 1:
        raise HdLabelsError(f"DEM shape must be two positive integers, got {shape!r}.")
    if not (math.isfinite(spacing_m) and spacing_m > 0):
        raise HdLabelsError(f"DEM spacing must be a finite positive number of metres per pixel, got {spacing_m!r}.")
    if method not in defaults.GRIDDINGS:
        raise HdLabelsError(f"Unknown gridding {method!r}: use one of {', '.join(defaults.GRIDDINGS)}.")
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    rows, cols = int(shape[0]), int(shape[1])
    binned = None
    if method != "linear":
        binned = bin_points(pts.reshape(-1, 3), (rows, cols), float(spacing_m), method)
        if not np.isnan(binned).any():
            return binned
    dem = np.full((rows, cols), np.nan)
    _grid_jit(pts, float(spacing_m), dem)
    dem = dem.astype(np.float32)
    if binned is not None:  # cells without a return of their own take the interpolated height
        dem = np.where(np.isnan(binned), dem, binned)
    return dem


def bin_points(points: np.ndarray, shape: tuple[int, int], spacing_m: float, statistic: str) -> np.ndarray:
    """Mean, highest or most central height (metres) of the points falling in each DEM cell; NaN if none.

    ``statistic``: ``"mean"``, ``"max"`` or ``"nearest"`` (the point closest to the cell centre in x, y).

    ``points`` is (N, 3) in the scan frame, NaN rows ignored. Cell (i, j) holds the points with
    ``(j - (W - 1) / 2 - 1/2) s <= x < (j - (W - 1) / 2 + 1/2) s`` and
    ``((H - 1) / 2 - i - 1/2) s < y <= ((H - 1) / 2 - i + 1/2) s`` (its square around its centre).
    Returns float32 (H, W).
    """
    rows, cols = shape
    if statistic == "nearest":
        dem = np.full(rows * cols, np.nan)
        _nearest_jit(np.ascontiguousarray(points, dtype=np.float64), rows, cols, float(spacing_m), dem)
        return dem.reshape(rows, cols).astype(np.float32)
    pts = points[np.isfinite(points).all(axis=1)]
    j = np.floor(pts[:, 0] / spacing_m + cols / 2.0)
    i = np.floor(rows / 2.0 - pts[:, 1] / spacing_m)
    inside = (i >= 0) & (i < rows) & (j >= 0) & (j < cols)
    cell = (i[inside] * cols + j[inside]).astype(np.int64)
    z = pts[inside, 2]
    count = np.bincount(cell, minlength=rows * cols)
    if statistic == "mean":
        with np.errstate(invalid="ignore", divide="ignore"):
            dem = np.bincount(cell, weights=z, minlength=rows * cols) / count
    else:
        dem = np.full(rows * cols, -np.inf)
        np.maximum.at(dem, cell, z)
    dem[count == 0] = np.nan
    return dem.reshape(rows, cols).astype(np.float32)


def _nearest_loops(points, rows, cols, spacing, dem):  # pragma: no cover - compiled by numba
    """The nearest binning: each cell of ``dem`` (flat, NaN-filled) takes the height of the return
    closest (horizontally) to its centre, the first in detector order among equally close ones.

    The same cell rule and arithmetic as the mean and max binnings of ``bin_points`` (IEEE, no
    fast-math: a return on a cell boundary falls where numpy's would put it).
    """
    best = np.full(rows * cols, np.inf)
    for k in range(points.shape[0]):
        x, y, z = points[k, 0], points[k, 1], points[k, 2]
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            continue
        fj = x / spacing + cols / 2.0
        fi = rows / 2.0 - y / spacing
        j = np.floor(fj)
        i = np.floor(fi)
        if not (i >= 0 and i < rows and j >= 0 and j < cols):
            continue
        fx = fj - (j + 0.5)
        fy = fi - (i + 0.5)
        dist = fx * fx + fy * fy
        cell = int(i) * cols + int(j)
        if dist < best[cell]:
            best[cell] = dist
            dem[cell] = z


def _fill_triangle(a, b, c, spacing, dem):  # pragma: no cover - compiled by numba
    """Write the plane of triangle (a, b, c) (xyz, metres) into the cell centres it contains."""
    rows, cols = dem.shape
    ci, cj = (rows - 1) / 2.0, (cols - 1) / 2.0
    x0, y0, z0 = a[0], a[1], a[2]
    e1x, e1y, e1z = b[0] - x0, b[1] - y0, b[2] - z0
    e2x, e2y, e2z = c[0] - x0, c[1] - y0, c[2] - z0
    det = e1x * e2y - e2x * e1y
    if det == 0.0:
        return
    xmin, xmax = min(x0, x0 + e1x, x0 + e2x), max(x0, x0 + e1x, x0 + e2x)
    ymin, ymax = min(y0, y0 + e1y, y0 + e2y), max(y0, y0 + e1y, y0 + e2y)
    # Fractional cell indices clipped to the grid (one beyond it at most) before ceil and floor make
    # them integers: a vertex 1e30 m away overflowed int64, undefined in compiled code (an endless loop).
    j_lo = math.ceil(min(max(xmin / spacing + cj - 1e-9, 0.0), float(cols)))
    j_hi = math.floor(min(max(xmax / spacing + cj + 1e-9, -1.0), cols - 1.0))
    i_lo = math.ceil(min(max(ci - ymax / spacing - 1e-9, 0.0), float(rows)))
    i_hi = math.floor(min(max(ci - ymin / spacing + 1e-9, -1.0), rows - 1.0))
    for i in range(i_lo, i_hi + 1):
        py = (ci - i) * spacing - y0
        for j in range(j_lo, j_hi + 1):
            px = (j - cj) * spacing - x0
            l1 = (px * e2y - e2x * py) / det
            l2 = (e1x * py - px * e1y) / det
            if l1 >= -_BARY_EPS and l2 >= -_BARY_EPS and l1 + l2 <= 1 + _BARY_EPS:
                dem[i, j] = z0 + l1 * e1z + l2 * e2z


def _in_circle_one(a, b, c, d):  # pragma: no cover - compiled by numba
    """The in-circle determinant (xy): > 0 if d is inside the circle through a, b, c (any orientation)."""
    ax, ay = a[0] - d[0], a[1] - d[1]
    bx, by = b[0] - d[0], b[1] - d[1]
    cx, cy = c[0] - d[0], c[1] - d[1]
    det = (
        (ax * ax + ay * ay) * (bx * cy - cx * by)
        - (bx * bx + by * by) * (ax * cy - cx * ay)
        + (cx * cx + cy * cy) * (ax * by - bx * ay)
    )
    orient = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    return det * np.sign(orient)


def _grid_loops(pts, spacing, dem):  # pragma: no cover - compiled by numba
    """The detector-grid triangulation (Delaunay split of complete quads, the one complete triangle of
    a three-corner quad), each triangle's plane written into the cell centres it contains, quad by quad."""
    h, w = pts.shape[0], pts.shape[1]
    ok = np.empty((h, w), dtype=np.bool_)
    for i in range(h):
        for j in range(w):
            ok[i, j] = np.isfinite(pts[i, j, 0]) and np.isfinite(pts[i, j, 1]) and np.isfinite(pts[i, j, 2])
    for i in range(h - 1):
        for j in range(w - 1):
            p00, p01, p10, p11 = pts[i, j], pts[i, j + 1], pts[i + 1, j], pts[i + 1, j + 1]
            k00, k01, k10, k11 = ok[i, j], ok[i, j + 1], ok[i + 1, j], ok[i + 1, j + 1]
            if k00 and k01 and k10 and k11:
                if not (_in_circle_one(p00, p01, p11, p10) > 0):
                    _fill_triangle(p00, p01, p11, spacing, dem)
                    _fill_triangle(p00, p11, p10, spacing, dem)
                else:
                    _fill_triangle(p00, p01, p10, spacing, dem)
                    _fill_triangle(p01, p11, p10, spacing, dem)
            elif k00 and k01 and k10:
                _fill_triangle(p00, p01, p10, spacing, dem)
            elif k01 and k11 and k10:
                _fill_triangle(p01, p11, p10, spacing, dem)
            elif k00 and k11 and k10:
                _fill_triangle(p00, p11, p10, spacing, dem)
            elif k00 and k01 and k11:
                _fill_triangle(p00, p01, p11, spacing, dem)


_fill_triangle = numba.njit(cache=True)(_fill_triangle)
_in_circle_one = numba.njit(cache=True)(_in_circle_one)
_grid_jit = numba.njit(cache=True)(_grid_loops)
_nearest_jit = numba.njit(cache=True)(_nearest_loops)
