"""ALHAT hazard maps of a DEM: slope, roughness, safe/unsafe labels and the P(safe) baseline.

A replica of the deterministic slope / roughness evaluation and of the probabilistic roughness
evaluation of Ivanov, Huertas & Carson (2013), as used by the paper for its labels (clean DEM)
and its baseline (noisy DEM), in either of two conventions (``Lander.rules``,
``hdlabels.conventions``: the sampling tables, the noise scale and the slope test of each). For
every aiming point (DEM pixel) and every placement of the pads around it:

1. each pad rests on the highest terrain under it (hd: bilinear terrain over the pad disk; paper:
   the highest node of the pad's pixel disk);
2. the lander rests on a plane through three pads such that no remaining pad is above it (the
   tipping rule; a square lander rocks on its higher diagonal, both ways are kept);
3. slope = angle of that plane's normal to vertical; roughness = largest perpendicular height of
   the roughness nodes (hd: the body disk; paper: the nodes strictly inside the pad polygon)
   above that plane;
4. the baseline's probability that the configuration is safe combines the per-node probabilities
   ``Phi((r_crit - r_n) / s)``, with ``r_n`` the node's signed perpendicular height (terrain below
   the plane raises the probability; ``count_holes`` concerns the labels only) and ``s`` the noise
   scale (paper: ``c sigma``, ``c`` the z-component of the plane's unit normal; hd: ``sigma``), by
   their product (Ivanov et al. 2013, Eq. 13) or by the worst node ("min"). The hd convention's
   "min" baseline keeps its original form, ``Phi((r_crit - roughness) / sigma)`` from the maps.

Site slope and roughness are the worst case over configurations; P(safe) is the deterministic
slope test times the smallest configuration probability. ``docs/labels.md`` holds the equations,
units and choices. Everything is in pixels internally (see ``lander.py``); heights are metres.

The kernels are compiled by numba (cached on disk, ``cache=True``), one row of sites at a time;
``parallel=True`` spreads the rows over numba's threads (``NUMBA_NUM_THREADS``) with the same
numbers. The compiled product rule sums the nodes only of the sites and configurations whose
result the cheaper bounds leave open (``_product_loops``): the maps and the P >= 0.5 decision are
those of the full sums, P(safe) is within 1e-7 of them. The same rules written as array
operations (numpy) are the tests' oracle (``tests/hdlabels/alhat_numpy.py``), not a back end.
"""

from __future__ import annotations

import math
import types
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, TypeVar

import numba
import numpy as np
from numba.core.dispatcher import Dispatcher
from scipy import ndimage
from scipy.special import log_ndtr, ndtr

from hdlabels import defaults
from hdlabels.errors import HdLabelsError
from hdlabels.lander import Geometry, Lander, geometry

# P(safe) modes of the kernels.
_P_NONE, _P_PRODUCT, _P_MIN = 0, 1, 2

# A worst-case kernel: (z, valid, geometry, lander, spacing, P mode, sigma, parallel) -> slope, roughness, P score.
WorstCase = Callable[
    [np.ndarray, np.ndarray, Geometry, Lander, float, int, float, bool], tuple[np.ndarray, np.ndarray, np.ndarray]
]


@dataclass(frozen=True)
class HazardMaps:
    """Per-pixel hazard maps of one DEM (same shape as the DEM).

    Attributes:
        slope_rad: float32, worst-case resting slope over the lander configurations, radians; NaN where invalid.
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


def hazard_maps(dem: np.ndarray, spacing_m: float, lander: Lander = Lander(), *, parallel: bool = False) -> HazardMaps:
    """Deterministic slope, roughness and label of every aiming point of a DEM.

    Args:
        dem: (H, W) terrain heights, metres, north-up; NaN marks cells without data.
        spacing_m: grid spacing, metres per pixel.
        lander: lander geometry, thresholds and convention.
        parallel: rows of sites on numba's threads (the same numbers; for one DEM at a time, not
            inside worker processes that already share the cores).

    Returns:
        HazardMaps with slope (radians), roughness (metres) and the uint8 label.
    """
    return _evaluate(dem, spacing_m, lander, None, parallel)[0]


def safety_probability(
    dem: np.ndarray, spacing_m: float, sigma_m: float, lander: Lander = Lander(), *, parallel: bool = False
) -> np.ndarray:
    """Probabilistic baseline P(safe) of a noisy DEM whose heights have 1-sigma noise ``sigma_m`` (metres).

    ``P = [slope ok] * min over configurations of combine_n Phi((r_crit - r_n) / s)`` with the
    lander's convention and ``baseline_combine`` (module docstring). ``sigma_m = 0`` gives the
    deterministic roughness test. Returns float32 in [0, 1], NaN where invalid; the baseline map is P >= 0.5.
    """
    return hazard_and_probability(dem, spacing_m, sigma_m, lander, parallel=parallel)[1]


def hazard_and_probability(
    dem: np.ndarray, spacing_m: float, sigma_m: float, lander: Lander = Lander(), *, parallel: bool = False
) -> tuple[HazardMaps, np.ndarray]:
    """``hazard_maps`` and ``safety_probability`` of one DEM from a single pass over its sites."""
    _check_sigma(sigma_m)
    maps, p = _evaluate(dem, spacing_m, lander, float(sigma_m), parallel)
    assert p is not None
    return maps, p


def probability_from_maps(maps: HazardMaps, sigma_m: float, lander: Lander = Lander()) -> np.ndarray:
    """P(safe) of the worst-node ("min") baseline from the worst-case maps of a noisy DEM.

    ``P = [slope < max slope] * Phi((max roughness - roughness) / sigma_m)``: the deterministic slope
    test times the Gaussian probability that the true roughness is below its limit. For the hd
    convention, whose noise scale is ``sigma_m`` for every configuration, taking the worst case
    over configurations equals this expression at the worst-case slope and roughness, because it
    decreases in both. The product combination and the paper convention's per-configuration noise
    scale need the DEM itself: use ``safety_probability``.
    """
    _check_sigma(sigma_m)
    if not lander.rules.baseline_from_maps(str(lander.baseline_combine)):
        raise HdLabelsError(
            "P(safe) follows from the hazard maps only for the hd convention with the 'min' combination; "
            "use safety_probability(dem, ...)"
        )
    slope = maps.slope_rad.astype(np.float64)
    rough = maps.roughness_m.astype(np.float64)
    slope_ok = slope_passes(slope, lander, baseline=True)
    margin = lander.max_roughness_m - rough
    p_rough = ndtr(margin / sigma_m) if sigma_m > 0 else (margin > 0).astype(np.float64)
    p = np.where(slope_ok, p_rough, 0.0)
    p[~maps.valid] = np.nan
    return p.astype(np.float32)


def slope_passes(slope_rad: np.ndarray, lander: Lander, *, baseline: bool) -> np.ndarray:
    """The slope test, the one place it is written: bool array, True where ``slope_rad`` passes.

    The labels call a slope safe below the limit (``slope < max_slope_deg``) in both conventions;
    the baseline keeps a slope equal to the limit where the convention says so (the paper's replica
    calls ``slope > limit`` unsafe). NaN fails.
    """
    limit = math.radians(lander.max_slope_deg)
    if baseline and lander.rules.baseline_slope_inclusive:
        return np.asarray(slope_rad <= limit)
    return np.asarray(slope_rad < limit)


def valid_sites(dem: np.ndarray, spacing_m: float, lander: Lander = Lander()) -> np.ndarray:
    """Bool mask of the sites that get a label: outside the border band, footprint free of NaN."""
    return _prepare(dem, spacing_m, lander)[1]


# --------------------------------------------------------------------------------------------------
# Internals.


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


def _check_sigma(sigma_m: float) -> None:
    if isinstance(sigma_m, bool) or not (isinstance(sigma_m, (int, float)) and math.isfinite(sigma_m) and sigma_m >= 0):
        raise HdLabelsError(f"DEM noise sigma must be a finite number of metres >= 0, got {sigma_m!r}.")


def _evaluate(
    dem: np.ndarray,
    spacing_m: float,
    lander: Lander,
    sigma_m: float | None,
    parallel: bool,
    worst_case: WorstCase | None = None,
) -> tuple[HazardMaps, np.ndarray | None]:
    """The hazard maps and, when ``sigma_m`` is given, P(safe) (float32, NaN where invalid).

    ``worst_case``: the kernel (``_worst_case``; the tests pass their numpy oracle).
    """
    z, valid, geo = _prepare(dem, spacing_m, lander)
    from_maps = lander.rules.baseline_from_maps(str(lander.baseline_combine))
    mode = _P_NONE
    if sigma_m and not from_maps:
        mode = _P_PRODUCT if lander.baseline_combine == "product" else _P_MIN
    kernel = worst_case or _worst_case
    slope, rough, score = kernel(z, valid, geo, lander, spacing_m, mode, sigma_m or 0.0, parallel)
    b = geo.band_px
    inner = (slice(b, z.shape[0] - b), slice(b, z.shape[1] - b))

    def full(a: np.ndarray) -> np.ndarray:
        out = np.full(z.shape, np.nan)
        out[inner] = a
        out[~valid] = np.nan
        return out

    slope_full, rough_full = full(slope), full(rough)
    safe = slope_passes(slope_full, lander, baseline=False) & (rough_full < lander.max_roughness_m)
    label = np.where(safe, defaults.LABEL_SAFE, defaults.LABEL_UNSAFE).astype(np.uint8)
    label[~valid] = defaults.LABEL_INVALID
    maps = HazardMaps(slope_full.astype(np.float32), rough_full.astype(np.float32), label)
    if sigma_m is None:
        return maps, None
    if from_maps:
        return maps, probability_from_maps(maps, sigma_m, lander)
    if mode == _P_NONE:  # sigma 0: every node's probability is 0 or 1, whichever the combination
        p = (rough_full < lander.max_roughness_m).astype(np.float64)
    else:
        p = _score_to_probability(full(score), mode)
    p = np.where(slope_passes(slope_full, lander, baseline=True), p, 0.0)
    p[~valid] = np.nan
    return maps, p.astype(np.float32)


def _score_to_probability(score: np.ndarray, mode: int) -> np.ndarray:
    """P of the kernels' per-site score: product mode, the smallest sum of log Phi over a
    configuration's nodes (P = exp); min mode, the smallest standardised margin u (P = Phi(u))."""
    with np.errstate(invalid="ignore"):
        return np.exp(score) if mode == _P_PRODUCT else ndtr(score)


def _worst_case(
    z: np.ndarray,
    valid: np.ndarray,
    geo: Geometry,
    lander: Lander,
    spacing_m: float,
    mode: int,
    sigma_m: float,
    parallel: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Worst-case slope (rad), roughness (m) and P score over the interior sites (band removed).

    The score is only meaningful where ``valid`` (the full DEM's mask) holds and the slope passes
    the baseline's slope test: the compiled product rule does not sum the nodes of other sites.
    """
    b = geo.band_px
    hv, wv = z.shape[0] - 2 * b, z.shape[1] - 2 * b
    scale_by_c = lander.rules.noise_scale_by_cos
    inv_sigma = 1.0 / sigma_m if sigma_m > 0 else 0.0  # unused when sigma is 0 (no P mode)
    score = np.zeros((hv, wv))
    z = z.astype(np.float32)  # half the memory traffic, twice the SIMD width; ~1e-6 m rounding
    heights = np.empty((geo.tap_w.shape[0], hv, wv), dtype=np.float32)
    _pad_heights_jit(z, b, geo.tap_di, geo.tap_dj, geo.tap_w.astype(np.float32), heights)
    slope = np.empty((hv, wv))
    rough = np.empty((hv, wv))
    args = (z, b, heights, lander.n_pads, geo.plane_weights, geo.triples, geo.node_ptr, geo.node_di, geo.node_dj)
    if mode == _P_PRODUCT:
        inner_valid = np.ascontiguousarray(valid[b : b + hv, b : b + wv])
        tan2_cut = math.tan(math.radians(lander.max_slope_deg)) ** 2 * (1.0 + _TAN2_MARGIN)
        (_product_par_jit if parallel else _product_jit)(
            *args,
            lander.count_holes,
            spacing_m,
            lander.max_roughness_m,
            inv_sigma,
            scale_by_c,
            _LOG_PHI,
            inner_valid,
            tan2_cut,
            slope,
            rough,
            score,
        )
    else:
        (_maps_par_jit if parallel else _maps_jit)(
            *args,
            lander.count_holes,
            spacing_m,
            mode == _P_MIN,
            lander.max_roughness_m,
            inv_sigma,
            scale_by_c,
            slope,
            rough,
            score,
        )
    return slope, rough, score


# log Phi as a piecewise cubic on a grid of step 1/32 (cubic Hermite through the exact values and
# slopes, stored as polynomial coefficients so one lookup is one cache line; absolute error below
# 1e-9 per node; scipy's log_ndtr in the numpy back end). Below -40, log Phi < -800 and any product
# is 0.0 in float64 whatever the exact value; above 8.5, log Phi > -1e-17, i.e. 0.
_U_LO, _U_HI, _U_STEP = -40.0, 8.5, 1.0 / 32.0


def _log_phi_coefficients() -> np.ndarray:
    """(n + 1) * 4 coefficients: log Phi(LO + (k + t) STEP) = c0 + t (c1 + t (c2 + t c3)), t in [0, 1]."""
    u = np.arange(_U_LO, _U_HI + _U_STEP / 2, _U_STEP)
    f = log_ndtr(u)
    d = np.exp(-0.5 * u**2 - 0.5 * math.log(2.0 * math.pi) - f) * _U_STEP  # d log Phi / dt
    f0, f1, d0, d1 = f[:-1], f[1:], d[:-1], d[1:]
    coef = np.stack([f0, d0, 3.0 * (f1 - f0) - 2.0 * d0 - d1, 2.0 * (f0 - f1) + d0 + d1], axis=1)
    coef = np.vstack([coef, [f[-1], 0.0, 0.0, 0.0]])  # u = HI exactly lands on the last knot
    return np.ascontiguousarray(coef.ravel())


_LOG_PHI = _log_phi_coefficients()

# The product rule's P(safe) is bounded per site before any full sum over its nodes with the table
# (``_product_bounds``). A site whose bounds fix P to within _P_TOLERANCE, on one side of the
# P >= 0.5 decision with _DECISION_MARGIN to spare (far above float32's 6e-8 there), takes the
# middle of its interval (off by at most half the tolerance); elsewhere only the configurations
# that can hold the minimum are summed with the table, exactly as before.
_P_TOLERANCE = 1e-7
_DECISION_THRESHOLD = defaults.SAFE_PROBABILITY_THRESHOLD
_DECISION_MARGIN = 1e-6
# The compiled kernel's slope test before the sums: tan^2 of the slope above tan^2(limit) by this
# relative margin fails the test (P = 0) however the float64 arctan rounds.
_TAN2_MARGIN = 1e-6

# The bounds come from a polynomial of log Phi, which vectorises where the table's look-ups (most
# of the previous kernel's time) do not: degree 14 in t = (u - 1.5) / 4 over u in [-2.5, 5.5],
# interpolated at Chebyshev points (numpy, deterministic) and stored as monomial coefficients in
# t. Above u = 5.5 a node's log Phi (>= -1.9e-8) counts as 0; a configuration with a node below
# -2.5 gets no bound from it. _POLY_ERROR (3e-5) and _TAIL_ERROR bound the distance to the table
# per node, measured on a fine grid below with 25 % to spare.
_POLY_U = (-2.5, 5.5)
_POLY_DEGREE = 14
_POLY_X = tuple((u - _U_LO) / _U_STEP for u in _POLY_U)  # the same interval in table units


def _log_phi_polynomial() -> tuple[float, ...]:
    """Monomial coefficients in t (constant first) of the Chebyshev interpolant of log Phi on ``_POLY_U``."""
    lo, hi = _POLY_U
    cheb = np.polynomial.chebyshev.chebinterpolate(
        lambda t: log_ndtr(0.5 * (hi - lo) * t + 0.5 * (hi + lo)), _POLY_DEGREE
    )
    return tuple(float(c) for c in np.polynomial.chebyshev.cheb2poly(cheb))


_LOG_PHI_POLY = _log_phi_polynomial()
_LOG_PHI_POLY_HORNER = _LOG_PHI_POLY[::-1]  # highest degree first
# t = x * _T_SCALE + _T_SHIFT for a table position x.
_T_SCALE = 2.0 * _U_STEP / (_POLY_U[1] - _POLY_U[0])
_T_SHIFT = (2.0 * _U_LO - _POLY_U[0] - _POLY_U[1]) / (_POLY_U[1] - _POLY_U[0])


def _approximation_errors() -> tuple[float, float]:
    """(largest |polynomial - table| on the polynomial's interval, largest |table| above it), each x1.25."""
    x = np.linspace(_POLY_X[0], _POLY_X[1], 1 << 18)
    q = np.minimum(x.astype(np.int64), _LOG_PHI.size // 4 - 1)
    t = x - q
    c = _LOG_PHI.reshape(-1, 4)[q]
    table = c[:, 0] + t * (c[:, 1] + t * (c[:, 2] + t * c[:, 3]))
    tt = x * _T_SCALE + _T_SHIFT
    poly = np.zeros_like(tt)
    for coef in reversed(_LOG_PHI_POLY):
        poly = poly * tt + coef
    return 1.25 * float(np.abs(poly - table).max()), 1.25 * float(abs(table[-1]))


_POLY_ERROR, _TAIL_ERROR = _approximation_errors()


def _pad_heights_loops(z, b, tap_di, tap_dj, tap_w, out):  # pragma: no cover - compiled by numba
    """Pad contact heights (metres): for each pad position, the max over its samples of the bilinear terrain."""
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


def _table_log_phi(log_phi, x):  # pragma: no cover - compiled by numba
    """log Phi at table position ``x = (u - LO) / STEP`` (clamped to the table), the cubic of ``_LOG_PHI``."""
    x = min(max(x, 0.0), (_U_HI - _U_LO) / _U_STEP)
    q = int(x)
    t = x - q
    q *= 4
    return log_phi[q] + t * (log_phi[q + 1] + t * (log_phi[q + 2] + t * log_phi[q + 3]))


def _poly_log_phi(x):  # pragma: no cover - compiled by numba
    """log Phi at table position ``x`` from ``_LOG_PHI_POLY`` (clamped to its interval), Horner's rule."""
    t = min(max(x, _POLY_X[0]), _POLY_X[1]) * _T_SCALE + _T_SHIFT
    v = 0.0
    for c in numba.literal_unroll(_LOG_PHI_POLY_HORNER):
        v = v * t + c
    return v


def _maps_loops(
    z,
    b,
    heights,
    n_pads,
    plane_weights,
    triples,
    node_ptr,
    node_di,
    node_dj,
    count_holes,
    spacing,
    min_mode,
    rc,
    inv_sigma,
    scale_by_c,
    slope,
    rough,
    score,
):  # pragma: no cover - compiled by numba
    """Resting planes, slope, roughness and, with ``min_mode``, the P score of the worst node (numba).

    Rows of sites are independent (in parallel with ``parallel=True``), each with working arrays
    small enough for the L1 cache. ``score``: the smallest u of any node over the configurations.
    The product rule has its own kernel, ``_product_loops``.
    """
    n_yaws = plane_weights.shape[0]
    hv, wv = slope.shape
    n_cfg = 2 if n_pads == 4 else 1
    inv_s2 = 1.0 / (spacing * spacing)
    for i in numba.prange(hv):
        gx = np.empty((n_cfg, wv), dtype=z.dtype)
        gy = np.empty((n_cfg, wv), dtype=z.dtype)
        c = np.empty((n_cfg, wv), dtype=z.dtype)
        dmax = np.empty(wv, dtype=z.dtype)
        dmin = np.empty(wv, dtype=z.dtype)
        slope[i, :] = 0.0
        rough[i, :] = 0.0
        score[i, :] = np.inf
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
                for n in range(node_ptr[m], node_ptr[m + 1]):
                    di = node_di[n]
                    dj = node_dj[n]
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
                    r = height / np.sqrt(1.0 + tan2)
                    slope[i, j] = max(slope[i, j], tan2)  # tan^2 for now; arctan at the end
                    rough[i, j] = max(rough[i, j], r)
                    if min_mode:  # the worst node: the largest signed height above the plane
                        sec = np.sqrt(1.0 + tan2)
                        scale = sec * inv_sigma if scale_by_c else inv_sigma
                        score[i, j] = min(score[i, j], (rc - dmax[j] / sec) * scale)
        for j in range(wv):
            slope[i, j] = np.arctan(np.sqrt(slope[i, j]))


def _product_loops(
    z,
    b,
    heights,
    n_pads,
    plane_weights,
    triples,
    node_ptr,
    node_di,
    node_dj,
    count_holes,
    spacing,
    rc,
    inv_sigma,
    scale_by_c,
    log_phi,
    valid,
    tan2_cut,
    slope,
    rough,
    score,
):  # pragma: no cover - compiled by numba
    """Resting planes, slope, roughness and the product rule's P score, worst case over configurations (numba).

    The same slope and roughness as ``_maps_loops`` (and the tests' numpy oracle); ``score`` is
    the smallest sum over a configuration's nodes of log Phi(u) (log P), or anything where
    ``valid`` is False or the slope fails (there -inf). Rows of sites are independent, each with its
    own working arrays (in parallel with ``parallel=True``, the same numbers), each in three steps:

    1. every configuration's plane and highest node (which give slope and roughness) and, in the
       same pass, its sum of the polynomial ``_poly_log_phi`` with the sum's error bound;
    2. per site, bounds on log P from these (``_product_bounds``): a site outside ``valid`` or whose
       slope fails (tan^2 above ``tan2_cut``) gets -inf (P = 0 by the slope test); a site whose P
       the bounds fix to ``_P_TOLERANCE``, away from the 0.5 decision, gets the middle of its
       interval; otherwise the configurations that can hold the minimum are marked;
    3. the sum of the table's log Phi over the nodes of the marked configurations only (the
       others' sums are provably larger), in the previous kernel's order and arithmetic.
    """
    n_yaws = plane_weights.shape[0]
    hv, wv = slope.shape
    n_cfg = 2 if n_pads == 4 else 1
    n_q = n_yaws * n_cfg
    inv_s2 = 1.0 / (spacing * spacing)
    for i in numba.prange(hv):
        gx = np.empty((n_q, wv), dtype=z.dtype)
        gy = np.empty((n_q, wv), dtype=z.dtype)
        c = np.empty((n_q, wv), dtype=z.dtype)
        dmax = np.empty((n_q, wv), dtype=z.dtype)
        dmin = np.empty(wv, dtype=z.dtype)
        ua = np.empty((n_q, wv))
        ub = np.empty((n_q, wv))
        approx = np.zeros((n_q, wv))  # sum of the polynomial over the nodes (product mode)
        error = np.zeros((n_q, wv))  # its bound: |approx - the table's sum| <= error
        xr = np.empty(wv)  # one node's table positions along the row
        need = np.zeros((n_q, wv), dtype=np.bool_)
        acc = np.empty(wv)
        sel = np.empty(wv, dtype=np.int64)
        slope[i, :] = 0.0
        rough[i, :] = 0.0
        score[i, :] = np.inf
        # 1a. the resting planes of every configuration q = (yaw m, plane k), along the row
        for m in range(n_yaws):
            h0 = heights[m * n_pads]
            h1 = heights[m * n_pads + 1]
            for j in range(wv):
                if n_pads == 4:
                    h2 = heights[m * n_pads + 2]
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
                    q = m * n_cfg + k
                    gx[q, j] = w[0, 0] * za + w[0, 1] * zb + w[0, 2] * zc
                    gy[q, j] = w[1, 0] * za + w[1, 1] * zb + w[1, 2] * zc
                    c[q, j] = w[2, 0] * za + w[2, 1] * zb + w[2, 2] * zc
        # 1b. the highest (and lowest) node above each plane (slope, roughness) and the polynomial's
        # sum over the nodes
        for q in range(n_q):
            m = q // n_cfg
            gxq, gyq, cq, dmq = gx[q], gy[q], c[q], dmax[q]
            uaq, ubq, apq, erq = ua[q], ub[q], approx[q], error[q]
            dmq[:] = -np.inf
            dmin[:] = np.inf
            for j in range(wv):
                # u = (rc - h cos) / s for a node at vertical height h above the plane (metres),
                # s = cos sigma (paper) or sigma (hd); in table units x = (u - LO) / STEP = ua - ub h.
                sec = np.sqrt(1.0 + (gxq[j] * gxq[j] + gyq[j] * gyq[j]) * inv_s2)
                if scale_by_c:
                    uaq[j] = (rc * sec * inv_sigma - _U_LO) * (1.0 / _U_STEP)
                    ubq[j] = inv_sigma * (1.0 / _U_STEP)
                else:
                    uaq[j] = (rc * inv_sigma - _U_LO) * (1.0 / _U_STEP)
                    ubq[j] = inv_sigma / sec * (1.0 / _U_STEP)
                apq[j] = 0.0
                erq[j] = 0.0
            for n in range(node_ptr[m], node_ptr[m + 1]):
                di = node_di[n]
                dj = node_dj[n]
                zr = z[i + b + di, b + dj : b + dj + wv]
                if count_holes:
                    for j in range(wv):
                        dev = zr[j] - cq[j] - gxq[j] * dj + gyq[j] * di
                        if dev > dmq[j]:
                            dmq[j] = dev
                        if dev < dmin[j]:
                            dmin[j] = dev
                else:
                    for j in range(wv):
                        dev = zr[j] - cq[j] - gxq[j] * dj + gyq[j] * di
                        if dev > dmq[j]:
                            dmq[j] = dev
                # two loops, each with few enough arrays that LLVM vectorises it
                for j in range(wv):
                    xr[j] = uaq[j] - ubq[j] * (zr[j] - cq[j] - gxq[j] * dj + gyq[j] * di)
                for j in range(wv):  # above the interval a node counts 0 (off by at most _TAIL_ERROR)
                    v = _poly_log_phi_jit(xr[j])
                    inside = xr[j] <= _POLY_X[1]
                    apq[j] += v if inside else 0.0
                    erq[j] += _POLY_ERROR if inside else _TAIL_ERROR
            for j in range(wv):
                tan2 = (gxq[j] * gxq[j] + gyq[j] * gyq[j]) * inv_s2
                height = max(dmq[j], 0.0)
                if count_holes:
                    height = max(height, -dmin[j])
                r = height / np.sqrt(1.0 + tan2)
                slope[i, j] = max(slope[i, j], tan2)  # tan^2 for now; arctan at the end
                rough[i, j] = max(rough[i, j], r)
        # 2. the sites decided by their slope, validity or bounds; the configurations left to sum
        for j in range(wv):
            if not valid[i, j] or slope[i, j] > tan2_cut:
                score[i, j] = -np.inf
                for q in range(n_q):
                    need[q, j] = False
                continue
            lo, hi = _product_bounds_jit(log_phi, ua, ub, dmax, approx, error, node_ptr, n_cfg, need, j)
            p_lo, p_hi = np.exp(lo), np.exp(hi)
            if p_hi - p_lo <= _P_TOLERANCE and (
                p_lo >= _DECISION_THRESHOLD + _DECISION_MARGIN or p_hi <= _DECISION_THRESHOLD - _DECISION_MARGIN
            ):
                p_mid = 0.5 * (p_lo + p_hi)
                score[i, j] = np.log(p_mid) if p_mid > 0.0 else -np.inf
                for q in range(n_q):
                    need[q, j] = False
        # 3. the table's sums over the nodes of the marked configurations
        for q in range(n_q):
            m = q // n_cfg
            cnt = 0
            for j in range(wv):
                if need[q, j]:
                    sel[cnt] = j
                    cnt += 1
            if cnt == 0:
                continue
            gxq, gyq, cq, uaq, ubq = gx[q], gy[q], c[q], ua[q], ub[q]
            j0, j1 = sel[0], sel[cnt - 1] + 1
            if 2 * cnt >= j1 - j0:  # dense: the whole span, vectorised
                acc[j0:j1] = 0.0
                for n in range(node_ptr[m], node_ptr[m + 1]):
                    di = node_di[n]
                    dj = node_dj[n]
                    zr = z[i + b + di, b + dj : b + dj + wv]
                    for j in range(j0, j1):
                        dev = zr[j] - cq[j] - gxq[j] * dj + gyq[j] * di
                        acc[j] += _table_log_phi_jit(log_phi, uaq[j] - ubq[j] * dev)
                for s in range(cnt):
                    j = sel[s]
                    score[i, j] = min(score[i, j], acc[j])
            else:  # sparse: site by site
                for s in range(cnt):
                    j = sel[s]
                    total = 0.0
                    for n in range(node_ptr[m], node_ptr[m + 1]):
                        di = node_di[n]
                        dj = node_dj[n]
                        dev = z[i + b + di, b + dj + j] - cq[j] - gxq[j] * dj + gyq[j] * di
                        total += _table_log_phi_jit(log_phi, uaq[j] - ubq[j] * dev)
                    score[i, j] = min(score[i, j], total)
        for j in range(wv):
            slope[i, j] = np.arctan(np.sqrt(slope[i, j]))


def _product_bounds(log_phi, ua, ub, dmax, approx, error, node_ptr, n_cfg, need, j):  # pragma: no cover - numba
    """Bounds on one site's product-rule score, column ``j`` of the per-configuration arrays (numba).

    With f = log Phi (the table: non-decreasing, <= 0) and x_q the table position of q's highest
    node (``ua - ub * dmax``; every other node lies above it), q's sum S_q over its N_q nodes lies
    in [N_q f(x_q), f(x_q)], and in [approx - error, approx + error] when x_q is inside the
    polynomial's interval or above. ``x_q`` is widened by one table step plus 0.1 mm of height, far
    beyond the rounding between passes. The site's score, min_q S_q, lies in (lo, hi) =
    (min_q lo_q, min_q hi_q). Sets ``need[q, j]`` for the configurations whose lower bound does not
    exceed ``hi``: only these can hold the minimum (the one with the smallest upper bound among
    them). Returns (lo, hi).
    """
    hi = np.inf
    for q in range(ua.shape[0]):
        x = ua[q, j] - ub[q, j] * dmax[q, j]
        slack = 1.0 + ub[q, j] * 1e-4
        hi_q = _table_log_phi_jit(log_phi, x + slack)
        if x - slack >= _POLY_X[0]:
            hi_q = min(hi_q, approx[q, j] + error[q, j])
        hi = min(hi, hi_q)
    lo = np.inf
    for q in range(ua.shape[0]):
        m = q // n_cfg
        x = ua[q, j] - ub[q, j] * dmax[q, j]
        slack = 1.0 + ub[q, j] * 1e-4
        lo_q = (node_ptr[m + 1] - node_ptr[m]) * _table_log_phi_jit(log_phi, x - slack)
        if x - slack >= _POLY_X[0]:
            lo_q = max(lo_q, approx[q, j] - error[q, j])
        lo = min(lo, lo_q)
        need[q, j] = lo_q <= hi
    return lo, hi


# Fast-math without the no-NaN / no-inf assumptions (the loops start from -inf). IEEE division
# (error_model "numpy"): numba's default checks every divisor for zero to raise
# ZeroDivisionError, and those branches keep LLVM from vectorising the loops that divide (7 %
# of the product rule's time); no divisor here can be zero (sigma > 0 before 1 / sigma, sec >= 1,
# n_cfg >= 1).
_FASTMATH = {"contract", "reassoc", "arcp", "nsz", "afn"}
_Kernel = TypeVar("_Kernel", bound=Callable[..., object])


def _compile(
    func: _Kernel, *, inline: Literal["never", "always"] = "never", parallel: bool = False
) -> Dispatcher[_Kernel]:
    """``func`` compiled by numba with the kernels' options (above), cached on disk."""
    return numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline=inline, parallel=parallel)(func)


_pad_heights_jit = _compile(_pad_heights_loops)
_table_log_phi_jit = _compile(_table_log_phi)
_poly_log_phi_jit = _compile(_poly_log_phi, inline="always")
_product_bounds_jit = _compile(_product_bounds, inline="always")


def _named_copy(func: Callable[..., object], suffix: str) -> Callable[..., object]:
    """The same Python function under another qualified name. numba's on-disk cache (``cache=True``)
    files a compiled function under its qualified name and signature, not its options: a serial and
    a ``parallel=True`` dispatcher of one function would share entries, and whichever compiled first
    would serve both (the parallel kernels then ran on one thread)."""
    copy = types.FunctionType(func.__code__, func.__globals__, func.__name__ + suffix, func.__defaults__)
    copy.__qualname__ = func.__qualname__ + suffix
    copy.__doc__ = func.__doc__
    return copy


_maps_jit = _compile(_maps_loops)
_maps_par_jit = _compile(_named_copy(_maps_loops, "_parallel"), parallel=True)
_product_jit = _compile(_product_loops)
_product_par_jit = _compile(_named_copy(_product_loops, "_parallel"), parallel=True)
