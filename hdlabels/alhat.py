"""ALHAT-style hazard maps of a DEM: slope, roughness, safe/unsafe labels and P(safe).

A replica of the deterministic slope / roughness evaluation and of the probabilistic roughness
evaluation of Ivanov, Huertas & Carson (2013), as used by the paper for its labels (clean DEM)
and its baseline (noisy DEM). For every aiming point (DEM pixel) and every sampled yaw:

1. each pad rests on the highest bilinear terrain under its disk (rim samples + nodes inside);
2. the lander rests on a plane through three pads such that no remaining pad's contact point is
   above it (the tipping rule; a square lander rocks on its higher diagonal, both ways are kept);
3. slope = angle of that plane's normal to vertical; roughness = largest perpendicular height of
   the terrain nodes under the body (centres within the lander radius) above that plane.

Site slope and roughness are the worst case over yaws and resting planes. ``docs/labels.md``
holds the equations, units and choices. Everything is in pixels internally (see ``lander.py``);
heights are metres.

Two interchangeable back ends compute the same numbers: vectorised numpy (loops over yaws, pads
and body offsets, each an array operation over all sites) and, when numba is installed, the
same loops compiled (``backend="numba"``, the default via ``"auto"``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import ndimage
from scipy.special import ndtr

from hdlabels import defaults
from hdlabels.errors import HdLabelsError
from hdlabels.lander import Geometry, Lander, geometry

try:  # numba is optional: the numpy back end computes the same numbers, slower.
    import numba
except ImportError:  # pragma: no cover - exercised only where numba is absent
    numba = None

Backend = Literal["auto", "numba", "numpy"]



@dataclass(frozen=True)
class HazardMaps:
    """Per-pixel hazard maps of one DEM (same shape as the DEM).

    Attributes:
        slope_rad: float32, worst-case resting slope over yaws, radians; NaN where invalid.
        roughness_m: float32, worst-case roughness (perpendicular height above the lander plane),
            metres, >= 0; NaN where invalid.
        label: uint8, ``LABEL_SAFE`` (1) iff slope < max slope and roughness < max roughness,
            ``LABEL_UNSAFE`` (0) otherwise, ``LABEL_INVALID`` (255) in the border band and at sites
            whose footprint touches a NaN DEM cell.
    """

    slope_rad: np.ndarray
    roughness_m: np.ndarray
    label: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        """Bool mask of labelled (not invalid) pixels."""
        return self.label != defaults.LABEL_INVALID


def hazard_maps(
    dem: np.ndarray, spacing_m: float, lander: Lander = Lander(), *, backend: Backend = "auto"
) -> HazardMaps:
    """Deterministic slope, roughness and label of every aiming point of a DEM.

    Args:
        dem: (H, W) terrain heights, metres, north-up; NaN marks cells without data.
        spacing_m: grid spacing, metres per pixel.
        lander: lander geometry and thresholds.
        backend: ``"numba"``, ``"numpy"`` or ``"auto"`` (numba when installed).

    Returns:
        HazardMaps with slope (radians), roughness (metres) and the uint8 label.
    """
    z, valid, geo = _prepare(dem, spacing_m, lander)
    slope, rough = _worst_case(z, geo, lander, spacing_m, _choose(backend))
    shape = z.shape
    b = geo.band_px
    slope_full = np.full(shape, np.nan, dtype=np.float64)
    rough_full = np.full(shape, np.nan, dtype=np.float64)
    slope_full[b : shape[0] - b, b : shape[1] - b] = slope
    rough_full[b : shape[0] - b, b : shape[1] - b] = rough
    slope_full[~valid] = np.nan
    rough_full[~valid] = np.nan
    safe = (slope_full < math.radians(lander.max_slope_deg)) & (rough_full < lander.max_roughness_m)
    label = np.where(safe, defaults.LABEL_SAFE, defaults.LABEL_UNSAFE).astype(np.uint8)
    label[~valid] = defaults.LABEL_INVALID
    return HazardMaps(slope_full.astype(np.float32), rough_full.astype(np.float32), label)


def probability_from_maps(maps: HazardMaps, sigma_m: float, lander: Lander = Lander()) -> np.ndarray:
    """P(safe) from the worst-case maps of a noisy DEM whose heights have 1-sigma noise ``sigma_m``.

    ``P = [slope < max slope] * Phi((max roughness - roughness) / sigma_m)``: the deterministic slope
    test times the Gaussian probability that the true roughness is below its limit. Taking the
    worst case (minimum P) over yaws and resting planes equals this expression evaluated at the
    worst-case slope and roughness, because it decreases in both. ``sigma_m = 0`` gives the
    deterministic test. Returns float32 in [0, 1], NaN where invalid.
    """
    if not (isinstance(sigma_m, (int, float)) and math.isfinite(sigma_m) and sigma_m >= 0):
        raise HdLabelsError(f"DEM noise sigma must be a finite number of metres >= 0, got {sigma_m!r}.")
    slope = maps.slope_rad.astype(np.float64)
    rough = maps.roughness_m.astype(np.float64)
    slope_ok = slope < math.radians(lander.max_slope_deg)
    margin = lander.max_roughness_m - rough
    if sigma_m > 0:
        p_rough = ndtr(margin / sigma_m)
    else:
        p_rough = (margin > 0).astype(np.float64)
    p = np.where(slope_ok, p_rough, 0.0)
    p[~maps.valid] = np.nan
    return p.astype(np.float32)


def safety_probability(
    dem: np.ndarray, spacing_m: float, sigma_m: float, lander: Lander = Lander(), *, backend: Backend = "auto"
) -> np.ndarray:
    """Probabilistic baseline P(safe) of a noisy DEM (float32 in [0, 1], NaN where invalid).

    Deterministic slope test times P(roughness < limit) under Gaussian DEM noise ``sigma_m``
    (metres), worst case over yaws; see ``probability_from_maps``. The baseline map is P >= 0.5.
    """
    return probability_from_maps(hazard_maps(dem, spacing_m, lander, backend=backend), sigma_m, lander)


def valid_sites(dem: np.ndarray, spacing_m: float, lander: Lander = Lander()) -> np.ndarray:
    """Bool mask of the sites that get a label: outside the border band, footprint free of NaN."""
    return _prepare(dem, spacing_m, lander)[1]


# --------------------------------------------------------------------------------------------------
# Internals.


def _choose(backend: Backend) -> str:
    if backend == "auto":
        return "numba" if numba is not None else "numpy"
    if backend == "numba" and numba is None:
        raise HdLabelsError("The numba back end was requested but numba is not installed.")
    if backend not in ("numba", "numpy"):
        raise HdLabelsError(f"Unknown back end {backend!r}: use 'auto', 'numba' or 'numpy'.")
    return backend


def _prepare(dem: np.ndarray, spacing_m: float, lander: Lander) -> tuple[np.ndarray, np.ndarray, Geometry]:
    """Checked float64 DEM with NaN set to 0 and shifted to mean 0, the valid-site mask, geometry."""
    if not isinstance(lander, Lander):
        raise HdLabelsError(f"Expected a Lander, got {type(lander).__name__}.")
    arr = np.asarray(dem)
    if arr.ndim != 2 or not np.issubdtype(arr.dtype, np.number):
        raise HdLabelsError(f"A DEM must be a 2-D numeric array, got shape {arr.shape} of {arr.dtype}.")
    geo = geometry(lander, float(spacing_m))
    b = geo.band_px
    if 2 * b >= min(arr.shape):
        raise HdLabelsError(
            f"The lander ({lander.diameter_m} m, footprint {2 * b + 1} px) is larger than the "
            f"{arr.shape[0]}x{arr.shape[1]} DEM at {spacing_m} m/px."
        )
    z = arr.astype(np.float64, copy=True)
    nan = ~np.isfinite(z)
    if nan.all():
        raise HdLabelsError("The DEM has no finite height (all NaN).")
    z -= z[~nan].mean()
    z[nan] = 0.0
    valid = np.zeros(z.shape, dtype=bool)
    valid[b : z.shape[0] - b, b : z.shape[1] - b] = True
    if nan.any():
        valid &= ~ndimage.binary_dilation(nan, structure=geo.footprint)
    return z, valid, geo


def _resting_planes(heights: np.ndarray, geo: Geometry, n_pads: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resting planes per site, stacked over (yaw, plane of that yaw), from the pad heights.

    ``heights`` is (n_yaws * n_pads, Hv, Wv), metres. Returns gx, gy (metres per pixel along x east
    and y north) and c (metres, the plane's height at the site), each (n_yaws * n_cfg, Hv, Wv).
    """
    n_yaws = heights.shape[0] // n_pads
    h = heights.reshape(n_yaws, n_pads, *heights.shape[1:])
    gx, gy, c = [], [], []
    for m in range(n_yaws):
        coeffs = [np.tensordot(geo.plane_weights[m, t], h[m, list(triple)], axes=1)
                  for t, triple in enumerate(geo.triples)]
        if n_pads == 4:  # rock on the higher diagonal, both ways
            on_02 = h[m, 0] + h[m, 2] >= h[m, 1] + h[m, 3]
            coeffs = [np.where(on_02, coeffs[0], coeffs[2]), np.where(on_02, coeffs[1], coeffs[3])]
        for co in coeffs:
            gx.append(co[0])
            gy.append(co[1])
            c.append(co[2])
    return np.stack(gx), np.stack(gy), np.stack(c)


def _worst_case(z: np.ndarray, geo: Geometry, lander: Lander, spacing_m: float, backend: str) -> tuple[np.ndarray, np.ndarray]:
    """Worst-case slope (rad) and roughness (m) over the interior sites (band removed)."""
    b = geo.band_px
    hv, wv = z.shape[0] - 2 * b, z.shape[1] - 2 * b
    if backend == "numba":
        z = z.astype(np.float32)  # half the memory traffic, twice the SIMD width; ~1e-6 m rounding
        heights = np.empty((geo.tap_w.shape[0], hv, wv), dtype=np.float32)
        _pad_heights_jit(z, b, geo.tap_di, geo.tap_dj, geo.tap_w.astype(np.float32), heights)
        slope = np.empty((hv, wv))
        rough = np.empty((hv, wv))
        _worst_case_jit(z, b, heights, lander.n_pads, geo.plane_weights, geo.triples, geo.body_di, geo.body_dj,
                        lander.count_holes, spacing_m, slope, rough)
        return slope, rough
    heights = np.empty((geo.tap_w.shape[0], hv, wv))
    _pad_heights_numpy(z, b, geo, heights)
    gx, gy, c = _resting_planes(heights, geo, lander.n_pads)
    dmax, dmin = _deviations_numpy(z, b, geo, gx, gy, c, lander.count_holes)
    tan2 = (gx * gx + gy * gy) / (spacing_m * spacing_m)
    height = np.maximum(dmax, 0.0)
    if lander.count_holes:
        height = np.maximum(height, -dmin)
    slope = np.arctan(np.sqrt(tan2.max(axis=0)))
    rough = (height / np.sqrt(1.0 + tan2)).max(axis=0)
    return slope, rough


def _pad_heights_numpy(z: np.ndarray, b: int, geo: Geometry, out: np.ndarray) -> None:
    """Pad contact heights, numpy: for each pad position, max over samples of bilinear terrain."""
    n_pos, n_samp, n_tap = geo.tap_w.shape
    hv, wv = out.shape[1:]
    for p in range(n_pos):
        best = np.full((hv, wv), -np.inf)
        for q in range(n_samp):
            value = np.zeros((hv, wv))
            for t in range(n_tap):
                w = geo.tap_w[p, q, t]
                if w > 0.0:
                    i0, j0 = b + geo.tap_di[p, q, t], b + geo.tap_dj[p, q, t]
                    value += w * z[i0 : i0 + hv, j0 : j0 + wv]
            np.maximum(best, value, out=best)
        out[p] = best


def _deviations_numpy(
    z: np.ndarray, b: int, geo: Geometry, gx: np.ndarray, gy: np.ndarray, c: np.ndarray, count_holes: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Max and min vertical height (m) of the body nodes above each resting plane, numpy."""
    hv, wv = gx.shape[1:]
    dmax = np.full(gx.shape, -np.inf)
    dmin = np.full(gx.shape, np.inf)
    for di, dj in zip(geo.body_di, geo.body_dj):
        znode = z[b + di : b + di + hv, b + dj : b + dj + wv]
        dev = znode - c - gx * dj + gy * di  # node at map vector (x, y) = (dj, -di)
        np.maximum(dmax, dev, out=dmax)
        if count_holes:
            np.minimum(dmin, dev, out=dmin)
    return dmax, dmin


def _pad_heights_loops(z, b, tap_di, tap_dj, tap_w, out):  # pragma: no cover - compiled by numba
    """Same as ``_pad_heights_numpy``, as explicit loops (compiled by numba)."""
    n_pos, n_samp, _ = tap_w.shape
    hv, wv = out.shape[1], out.shape[2]
    for p in range(n_pos):
        best = out[p]
        best[:, :] = -np.inf
        for q in range(n_samp):
            a0, c0, w0 = tap_di[p, q, 0] + b, tap_dj[p, q, 0] + b, tap_w[p, q, 0]
            a1, c1, w1 = tap_di[p, q, 1] + b, tap_dj[p, q, 1] + b, tap_w[p, q, 1]
            a2, c2, w2 = tap_di[p, q, 2] + b, tap_dj[p, q, 2] + b, tap_w[p, q, 2]
            a3, c3, w3 = tap_di[p, q, 3] + b, tap_dj[p, q, 3] + b, tap_w[p, q, 3]
            for i in range(hv):
                r0, r1, r2, r3 = z[i + a0, c0:], z[i + a1, c1:], z[i + a2, c2:], z[i + a3, c3:]
                row = best[i]
                for j in range(wv):
                    v = w0 * r0[j] + w1 * r1[j] + w2 * r2[j] + w3 * r3[j]
                    row[j] = max(row[j], v)


def _worst_case_loops(z, b, heights, n_pads, plane_weights, triples, body_di, body_dj, count_holes,
                      spacing, slope, rough):  # pragma: no cover - compiled by numba
    """Resting planes, slope and roughness, worst case over yaws, as explicit loops (numba).

    Same numbers as ``_resting_planes`` + ``_deviations_numpy`` + the reduction in ``_worst_case``;
    rows are processed one at a time so every working array stays in the L1 cache.
    """
    n_yaws = plane_weights.shape[0]
    hv, wv = slope.shape
    n_cfg = 2 if n_pads == 4 else 1
    gx = np.empty((n_cfg, wv), dtype=z.dtype)
    gy = np.empty((n_cfg, wv), dtype=z.dtype)
    c = np.empty((n_cfg, wv), dtype=z.dtype)
    dmax = np.empty(wv, dtype=z.dtype)
    dmin = np.empty(wv, dtype=z.dtype)
    slope[:, :] = 0.0
    rough[:, :] = 0.0
    inv_s2 = 1.0 / (spacing * spacing)
    for i in range(hv):
        for m in range(n_yaws):
            h0 = heights[m * n_pads]
            h1 = heights[m * n_pads + 1]
            h2 = heights[m * n_pads + 2]
            for j in range(wv):
                if n_pads == 4:
                    h3 = heights[m * n_pads + 3]
                    t0 = 0 if h0[i, j] + h2[i, j] >= h1[i, j] + h3[i, j] else 2
                else:
                    t0 = 0
                for k in range(n_cfg):
                    t = t0 + k
                    za = heights[m * n_pads + triples[t, 0], i, j]
                    zb = heights[m * n_pads + triples[t, 1], i, j]
                    zc = heights[m * n_pads + triples[t, 2], i, j]
                    w = plane_weights[m, t]
                    gx[k, j] = w[0, 0] * za + w[0, 1] * zb + w[0, 2] * zc
                    gy[k, j] = w[1, 0] * za + w[1, 1] * zb + w[1, 2] * zc
                    c[k, j] = w[2, 0] * za + w[2, 1] * zb + w[2, 2] * zc
            for k in range(n_cfg):
                gxk, gyk, ck = gx[k], gy[k], c[k]
                dmax[:] = -np.inf
                dmin[:] = np.inf
                for n in range(body_di.shape[0]):
                    di = body_di[n]
                    dj = body_dj[n]
                    zr = z[i + b + di, b + dj : b + dj + wv]
                    if count_holes:
                        for j in range(wv):
                            dev = zr[j] - ck[j] - gxk[j] * dj + gyk[j] * di
                            if dev > dmax[j]:
                                dmax[j] = dev
                            if dev < dmin[j]:
                                dmin[j] = dev
                    else:
                        for j in range(wv):
                            dev = zr[j] - ck[j] - gxk[j] * dj + gyk[j] * di
                            if dev > dmax[j]:
                                dmax[j] = dev
                for j in range(wv):
                    tan2 = (gxk[j] * gxk[j] + gyk[j] * gyk[j]) * inv_s2
                    height = max(dmax[j], 0.0)
                    if count_holes:
                        height = max(height, -dmin[j])
                    slope[i, j] = max(slope[i, j], tan2)  # tan^2 for now; arctan at the end
                    rough[i, j] = max(rough[i, j], height / np.sqrt(1.0 + tan2))
    for i in range(hv):
        for j in range(wv):
            slope[i, j] = np.arctan(np.sqrt(slope[i, j]))


# Fast-math without the no-NaN / no-inf assumptions (the loops start from -inf).
_FASTMATH = {"contract", "reassoc", "arcp", "nsz", "afn"}

if numba is not None:
    _pad_heights_jit = numba.njit(cache=True, fastmath=_FASTMATH)(_pad_heights_loops)
    _worst_case_jit = numba.njit(cache=True, fastmath=_FASTMATH)(_worst_case_loops)
