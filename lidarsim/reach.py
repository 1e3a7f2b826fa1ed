"""Which triangles of a terrain mesh a bundle of rays can hit: the mesh a sparse scan is cast against.

A scan's 128 x 128 rays fall on some 47,000 cells of a 0.5 m terrain (94,000 triangles), yet each
ray's first hit is one triangle: Embree's BVH build, linear in the triangles, costs the scan more
than its rays. :func:`candidate_triangles` marks, for each ray, every triangle of the mesh of
``lidarsim.scan.terrain_mesh`` that the ray passes within a margin of before it is certainly
below the terrain, by walking the cells under the ray (a 2-D DDA over the cells' xy squares):

* a triangle is marked when the ray, while over its cell (or within ``eps_m`` of it in x or y),
  crosses the triangle's plane or passes within ``delta_m`` of it in height;
* the walk starts where the ray is ``delta_m`` above the highest terrain and ends where it is
  ``delta_m`` below the lowest, or, once it has met no hole, after the first cell whose two
  triangles' planes it leaves more than ``delta_m`` below (it has crossed the surface).

Embree's first hit on the whole mesh is a triangle the ray meets within float32 rounding (metres
of 1e-5 at these ranges) before it is below the surface, hence a marked one; every marked
triangle keeps its vertices and so its float32 hit, and the first hit among the marked triangles
is the same triangle at the same range. The margins (1 cm in height, 1 mm across) are hundreds of
times the rounding.
"""

from __future__ import annotations

import math

import numba
import numpy as np

# Margins of the walk, metres: in height (ray against the triangle's vertex heights) and across
# (the ray's distance from a cell's square). Hundreds of times float32's rounding of the rays and
# vertices (~1e-5 m at 500 m ranges and 100 m from the origin).
DELTA_M = 0.01
EPS_M = 0.001


def candidate_triangles(
    heights: np.ndarray,
    x_centres: np.ndarray,
    y_centres: np.ndarray,
    origins: np.ndarray,
    directions: np.ndarray,
    delta_m: float = DELTA_M,
    eps_m: float = EPS_M,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The triangles rays can hit first, as two masks over the cells' 2 x 2 blocks.

    Args:
        heights: float64 (rows, cols) heights of the mesh's vertices (cell centres), metres, NaN where nodata.
        x_centres: (cols,) map x of the cell centres, metres, evenly spaced and increasing.
        y_centres: (rows,) map y of the cell centres, metres, evenly spaced and decreasing (row 0 north).
        origins: float64 (N, 3) ray origins, map coordinates, metres.
        directions: float64 (N, 3) unit ray directions.
        delta_m: margin in height, metres.
        eps_m: margin across, metres.

    Returns:
        ``(upper, lower)``: bool (rows - 1, cols - 1) masks of the triangles ``(a, c, b)`` and
        ``(b, c, d)`` of each block (``terrain_mesh``'s two kinds), or None when a ray does not
        descend (it may hit anything) or the grid has fewer than 2 x 2 cells.
    """
    rows, cols = heights.shape
    d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
    o = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
    if rows < 2 or cols < 2 or not (d[:, 2] < -1e-9).all():
        return None
    finite = heights[np.isfinite(heights)]
    upper = np.zeros((rows - 1, cols - 1), dtype=np.bool_)
    lower = np.zeros((rows - 1, cols - 1), dtype=np.bool_)
    if finite.size == 0:
        return upper, lower
    h = np.ascontiguousarray(heights, dtype=np.float64)
    dx = float(x_centres[1] - x_centres[0])
    dy = float(y_centres[0] - y_centres[1])
    z_low, z_high = float(finite.min()), float(finite.max())
    _walk_jit(h, float(x_centres[0]), dx, float(y_centres[0]), dy, o, d, z_low, z_high, delta_m, eps_m, upper, lower)
    return upper, lower


def _mark(h, i, j, x0, dx, y0, dy, ray, ta, tb, delta, eps, upper, lower):  # pragma: no cover - compiled by numba
    """Mark the valid triangles of block (i, j) whose planes the ray crosses, within ``delta`` in
    height, between ``ta`` and ``tb`` while it is over the triangle's half of the block (within
    ``eps`` of the diagonal); returns whether the ray ends below both triangles' planes by more
    than ``delta`` (it has crossed the surface) and whether the block has an invalid vertex.

    ``ray`` = (ox, oy, oz, ux, uy, uz). Block coordinates: p = (x - x_j) / dx, q = (y_i - y) / dy;
    the triangle (a, c, b) (p + q <= 1) lies in the plane z_a + (z_b - z_a) p + (z_c - z_a) q, the
    triangle (b, c, d) (p + q >= 1) in z_b + z_c - z_d + (z_d - z_c) p + (z_d - z_b) q; the height
    above a plane is linear along the ray: its two ends decide."""
    ox, oy, _, ux, uy, _ = ray
    za, zb, zc, zd = h[i, j], h[i, j + 1], h[i + 1, j], h[i + 1, j + 1]
    xj = x0 + j * dx
    yi = y0 - i * dy
    band = 2.0 * eps / min(dx, dy)  # eps across the diagonal, in units of p + q
    sa = (ox + ta * ux - xj) / dx + (yi - oy - ta * uy) / dy
    sb = (ox + tb * ux - xj) / dx + (yi - oy - tb * uy) / dy
    hole = not (np.isfinite(za) and np.isfinite(zb) and np.isfinite(zc) and np.isfinite(zd))
    below = not hole
    if np.isfinite(za) and np.isfinite(zb) and np.isfinite(zc):
        z0, zp, zq = za, zb - za, zc - za
        lo, hi = _near(sa, sb, ta, tb, -1, 1.0 + band)  # p + q < 1 + band
        if lo <= hi and _crosses(ray, xj, dx, yi, dy, z0, zp, zq, lo, hi, delta):
            upper[i, j] = True
        below = below and _gap(ray, xj, dx, yi, dy, z0, zp, zq, tb) < -delta
    if np.isfinite(zb) and np.isfinite(zc) and np.isfinite(zd):
        z0, zp, zq = zb + zc - zd, zd - zc, zd - zb
        lo, hi = _near(sa, sb, ta, tb, 1, band)  # p + q > 1 - band
        if lo <= hi and _crosses(ray, xj, dx, yi, dy, z0, zp, zq, lo, hi, delta):
            lower[i, j] = True
        below = below and _gap(ray, xj, dx, yi, dy, z0, zp, zq, tb) < -delta
    return below, hole


def _gap(ray, xj, dx, yi, dy, z0, zp, zq, t):  # pragma: no cover - compiled by numba
    """Height of the ray at ``t`` above the plane z0 + zp p + zq q of a block."""
    ox, oy, oz, ux, uy, uz = ray
    return oz + t * uz - (z0 + zp * (ox + t * ux - xj) / dx + zq * (yi - oy - t * uy) / dy)


def _crosses(ray, xj, dx, yi, dy, z0, zp, zq, ta, tb, delta):  # pragma: no cover - compiled by numba
    """Whether the ray crosses the plane, or passes within ``delta`` of it, between ``ta`` and ``tb``."""
    fa = _gap(ray, xj, dx, yi, dy, z0, zp, zq, ta)
    fb = _gap(ray, xj, dx, yi, dy, z0, zp, zq, tb)
    return min(fa, fb) <= delta and max(fa, fb) >= -delta


def _near(ga, gb, ta, tb, side, band):  # pragma: no cover - compiled by numba
    """The part of ``ta .. tb`` where a block coordinate going linearly from ``ga`` to ``gb`` lies
    within ``band`` of the block's side ``side`` (-1: 0, +1: 1; 0: anywhere); empty when lo > hi."""
    if side == 0:
        return ta, tb
    edge = 0.0 + band if side < 0 else 1.0 - band
    inside_a = ga < edge if side < 0 else ga > edge
    inside_b = gb < edge if side < 0 else gb > edge
    if inside_a and inside_b:
        return ta, tb
    if not inside_a and not inside_b:
        return 1.0, 0.0
    tc = ta + (edge - ga) / (gb - ga) * (tb - ta)  # where it crosses the band's edge
    return (ta, tc) if inside_a else (tc, tb)


def _walk_loops(h, x0, dx, y0, dy, origins, dirs, z_low, z_high, delta, eps, upper, lower):  # pragma: no cover - numba
    """A 2-D DDA over the blocks under every ray (block (i, j): x from x0 + j dx, y down from y0 - i dy)."""
    nb_r, nb_c = h.shape[0] - 1, h.shape[1] - 1
    for n in range(origins.shape[0]):
        ox, oy, oz = origins[n, 0], origins[n, 1], origins[n, 2]
        ux, uy, uz = dirs[n, 0], dirs[n, 1], dirs[n, 2]
        ray = (ox, oy, oz, ux, uy, uz)
        t = max(0.0, (oz - (z_high + delta)) / -uz)
        t_end = (oz - (z_low - delta)) / -uz
        j = math.floor((ox + t * ux - x0) / dx)
        i = math.floor((y0 - (oy + t * uy)) / dy)
        hole = False
        while t < t_end:
            tp = (x0 + (j + (1 if ux > 0 else 0)) * dx - ox) / ux if ux != 0.0 else math.inf
            tq = (oy - (y0 - (i + (1 if uy < 0 else 0)) * dy)) / -uy if uy != 0.0 else math.inf
            t_next = min(max(min(tp, tq), t), t_end)
            below = False
            if 0 <= i < nb_r and 0 <= j < nb_c:
                crossed, gap = _mark(h, i, j, x0, dx, y0, dy, ray, t, t_next, delta, eps, upper, lower)
                hole = hole or gap
                below = crossed and not hole
            else:
                hole = True  # beyond the grid: nothing to cross, nothing to stop at
            # within eps of a neighbouring block: its triangles too, while the ray is that near it
            pa = (ox + t * ux - x0) / dx - j
            pb = (ox + t_next * ux - x0) / dx - j
            qa = (y0 - (oy + t * uy)) / dy - i
            qb = (y0 - (oy + t_next * uy)) / dy - i
            for di in range(-1, 2):
                qi_lo, qi_hi = _near(qa, qb, t, t_next, di, eps / dy)
                if qi_lo > qi_hi:
                    continue
                for dj in range(-1, 2):
                    if di == 0 and dj == 0:
                        continue
                    pj_lo, pj_hi = _near(pa, pb, t, t_next, dj, eps / dx)
                    lo, hi = max(qi_lo, pj_lo), min(qi_hi, pj_hi)
                    if lo <= hi and 0 <= i + di < nb_r and 0 <= j + dj < nb_c:
                        _mark(h, i + di, j + dj, x0, dx, y0, dy, ray, lo, hi, delta, eps, upper, lower)
            if below:
                break
            if tp <= tq:
                j += 1 if ux > 0 else -1
            else:
                i += 1 if uy < 0 else -1
            t = t_next


_gap = numba.njit(cache=True)(_gap)
_crosses = numba.njit(cache=True)(_crosses)
_mark = numba.njit(cache=True)(_mark)
_near = numba.njit(cache=True)(_near)
_walk_jit = numba.njit(cache=True)(_walk_loops)
