"""The numpy oracle of ``hdlabels.grid``'s linear gridding, for the tests.

The library triangulates and rasterises with its compiled kernel only. This module writes the
same rules a second way, vectorised with numpy (all quads at once, then the triangles grouped by
bounding-box size), so that a test can compare the kernel with an independent implementation:
``grid_points(..., backend="numpy")`` is the oracle, ``backend="numba"`` the library.
"""

from __future__ import annotations

import numpy as np

from hdlabels import grid
from hdlabels.grid import _BARY_EPS


def grid_points(
    points: np.ndarray, shape: tuple[int, int] = (100, 100), spacing_m: float = 1.0, *, backend: str = "numba"
) -> np.ndarray:
    """Linear gridding of organised points (float32 DEM, metres, NaN where unsupported): the library's
    (``"numba"``) or the oracle's (``"numpy"``)."""
    if backend == "numba":
        return grid.grid_points(points, shape, spacing_m)
    pts = np.ascontiguousarray(points, dtype=np.float64)
    dem = np.full(shape, np.nan)
    rasterise(triangles(pts), float(spacing_m), dem)
    return dem.astype(np.float32)


def triangles(pts: np.ndarray) -> np.ndarray:
    """(T, 3, 3) triangles (vertex, xyz) of the detector-grid triangulation, valid vertices only."""
    p00, p01 = pts[:-1, :-1].reshape(-1, 3), pts[:-1, 1:].reshape(-1, 3)
    p10, p11 = pts[1:, :-1].reshape(-1, 3), pts[1:, 1:].reshape(-1, 3)
    ok = [np.isfinite(p).all(axis=1) for p in (p00, p01, p10, p11)]
    # Delaunay choice for complete quads: split along p00-p11 unless p10 lies inside the
    # circumcircle of (p00, p01, p11) (then the other diagonal is the Delaunay one).
    split_main = ~(in_circumcircle(p00, p01, p11, p10) > 0)
    full = ok[0] & ok[1] & ok[2] & ok[3]
    candidates = [
        (p00, p01, p11, full & split_main),
        (p00, p11, p10, full & split_main),
        (p00, p01, p10, (full & ~split_main) | (~ok[3] & ok[0] & ok[1] & ok[2])),
        (p01, p11, p10, (full & ~split_main) | (~ok[0] & ok[1] & ok[2] & ok[3])),
        # three-corner quads missing p01 or p10 keep their one complete triangle
        (p00, p11, p10, ~ok[1] & ok[0] & ok[2] & ok[3]),
        (p00, p01, p11, ~ok[2] & ok[0] & ok[1] & ok[3]),
    ]
    tris = [np.stack([a[m], b[m], c[m]], axis=1) for a, b, c, m in candidates]
    return np.concatenate(tris, axis=0) if tris else np.empty((0, 3, 3))


def in_circumcircle(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Sign of the in-circle determinant (xy): > 0 if d is inside the circle through a, b, c (any orientation)."""
    ax, ay = a[:, 0] - d[:, 0], a[:, 1] - d[:, 1]
    bx, by = b[:, 0] - d[:, 0], b[:, 1] - d[:, 1]
    cx, cy = c[:, 0] - d[:, 0], c[:, 1] - d[:, 1]
    det = (
        (ax * ax + ay * ay) * (bx * cy - cx * by)
        - (bx * bx + by * by) * (ax * cy - cx * ay)
        + (cx * cx + cy * cy) * (ax * by - bx * ay)
    )
    orient = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    return det * np.sign(orient)


def rasterise(tri: np.ndarray, spacing: float, dem: np.ndarray) -> None:
    """Fill ``dem`` with the triangle planes at the cell centres they contain (vectorised over triangles)."""
    rows, cols = dem.shape
    x, y = tri[:, :, 0], tri[:, :, 1]
    # Cell index ranges covered by each triangle's bounding box (fractional index of x, y).
    # Clipped to one cell beyond the grid while still floats (no integer overflow for far vertices).
    j_lo = np.clip(np.ceil(x.min(axis=1) / spacing + (cols - 1) / 2.0 - 1e-9), -1, cols).astype(np.int64)
    j_hi = np.clip(np.floor(x.max(axis=1) / spacing + (cols - 1) / 2.0 + 1e-9), -1, cols).astype(np.int64)
    i_lo = np.clip(np.ceil((rows - 1) / 2.0 - y.max(axis=1) / spacing - 1e-9), -1, rows).astype(np.int64)
    i_hi = np.clip(np.floor((rows - 1) / 2.0 - y.min(axis=1) / spacing + 1e-9), -1, rows).astype(np.int64)
    j_lo, i_lo = np.maximum(j_lo, 0), np.maximum(i_lo, 0)
    j_hi, i_hi = np.minimum(j_hi, cols - 1), np.minimum(i_hi, rows - 1)
    keep = (j_hi >= j_lo) & (i_hi >= i_lo)
    ni, nj = (i_hi - i_lo + 1)[keep], (j_hi - j_lo + 1)[keep]
    tri, i_lo, j_lo = tri[keep], i_lo[keep], j_lo[keep]
    # Triangles grouped by bounding-box size, each group one array operation.
    for size_i, size_j in set(zip(ni.tolist(), nj.tolist(), strict=True)):
        g = (ni == size_i) & (nj == size_j)
        ii = i_lo[g][:, None, None] + np.arange(size_i)[None, :, None]
        jj = j_lo[g][:, None, None] + np.arange(size_j)[None, None, :]
        px = (jj - (cols - 1) / 2.0) * spacing
        py = ((rows - 1) / 2.0 - ii) * spacing
        t = tri[g][:, None, None]
        l1, l2, inside = barycentric(t, px, py)
        z = t[..., 0, 2] + l1 * (t[..., 1, 2] - t[..., 0, 2]) + l2 * (t[..., 2, 2] - t[..., 0, 2])
        ii_b, jj_b = np.broadcast_arrays(ii, jj)
        dem[ii_b[inside], jj_b[inside]] = z[inside]


def barycentric(t: np.ndarray, px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Barycentric coordinates (l1, l2) of (px, py) in triangles ``t`` (..., 3, 3) and an inside mask."""
    x0, y0 = t[..., 0, 0], t[..., 0, 1]
    e1x, e1y = t[..., 1, 0] - x0, t[..., 1, 1] - y0
    e2x, e2y = t[..., 2, 0] - x0, t[..., 2, 1] - y0
    det = e1x * e2y - e2x * e1y
    with np.errstate(divide="ignore", invalid="ignore"):
        l1 = ((px - x0) * e2y - e2x * (py - y0)) / det
        l2 = (e1x * (py - y0) - (px - x0) * e1y) / det
    inside = (det != 0) & (l1 >= -_BARY_EPS) & (l2 >= -_BARY_EPS) & (l1 + l2 <= 1 + _BARY_EPS)
    return l1, l2, inside


def bin_nearest(points: np.ndarray, shape: tuple[int, int], spacing_m: float) -> np.ndarray:
    """The nearest binning of ``grid.bin_points`` as array operations: each cell (float32, metres,
    NaN without a return) takes the height of its most central return, the first in detector order
    among equally central ones. ``points`` is (N, 3), NaN rows ignored."""
    rows, cols = shape
    pts = points[np.isfinite(points).all(axis=1)]
    j = np.floor(pts[:, 0] / spacing_m + cols / 2.0)
    i = np.floor(rows / 2.0 - pts[:, 1] / spacing_m)
    inside = (i >= 0) & (i < rows) & (j >= 0) & (j < cols)
    cell = (i[inside] * cols + j[inside]).astype(np.int64)
    z = pts[inside, 2]
    fx = pts[inside, 0] / spacing_m + cols / 2.0 - (j[inside] + 0.5)
    fy = rows / 2.0 - pts[inside, 1] / spacing_m - (i[inside] + 0.5)
    dist = fx * fx + fy * fy
    best = np.full(rows * cols, np.inf)
    np.minimum.at(best, cell, dist)
    first = np.full(rows * cols, cell.size)
    candidates = np.flatnonzero(dist == best[cell])
    np.minimum.at(first, cell[candidates], candidates)
    dem = np.full(rows * cols, np.nan)
    has = first < cell.size
    dem[has] = z[first[has]]
    return dem.reshape(rows, cols).astype(np.float32)
