"""The paper convention's compiled kernel as it was before P(safe) skipped decided sites: a test oracle.

``hdlabels.alhat`` now bounds each site's product-rule P(safe) from its worst node and sums the
per-node log Phi only for the sites and lander configurations that can change the result. This
module keeps the previous kernel, which sums every node of every configuration of every site,
verbatim (the loops compiled by numba) with the same entry point as ``hazard_and_probability``, so
tests can check that the new path gives the same labels, the same P >= 0.5 decision on every
pixel and P(safe) within 1e-6.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from hdlabels import defaults
from hdlabels.alhat import (
    _FASTMATH,
    _LOG_PHI,
    _P_MIN,
    _P_NONE,
    _P_PRODUCT,
    _U_HI,
    _U_LO,
    _U_STEP,
    HazardMaps,
    _pad_heights_jit,
    _prepare,
    _score_to_probability,
)
from hdlabels.lander import Lander


def previous_hazard_and_probability(
    dem: np.ndarray, spacing_m: float, sigma_m: float, lander: Lander = Lander()
) -> tuple[HazardMaps, np.ndarray]:
    """``hdlabels.alhat.hazard_and_probability`` computed by the previous kernel.

    Only the kernel's P(safe) modes (``product``, or ``min`` with the paper convention) are
    reproduced; the hd convention's ``min`` baseline never used the kernel's P score.
    """
    z, valid, geo = _prepare(dem, spacing_m, lander)
    assert not lander.rules.baseline_from_maps(str(lander.baseline_combine))
    mode = _P_NONE
    if sigma_m:
        mode = _P_PRODUCT if lander.baseline_combine == "product" else _P_MIN
    b = geo.band_px
    hv, wv = z.shape[0] - 2 * b, z.shape[1] - 2 * b
    z32 = z.astype(np.float32)
    heights = np.empty((geo.tap_w.shape[0], hv, wv), dtype=np.float32)
    _pad_heights_jit(z32, b, geo.tap_di, geo.tap_dj, geo.tap_w.astype(np.float32), heights)
    slope, rough, score = np.empty((hv, wv)), np.empty((hv, wv)), np.zeros((hv, wv))
    _previous_jit(
        z32,
        b,
        heights,
        lander.n_pads,
        geo.plane_weights,
        geo.triples,
        geo.node_ptr,
        geo.node_di,
        geo.node_dj,
        lander.count_holes,
        spacing_m,
        mode,
        lander.max_roughness_m,
        1.0 / sigma_m if sigma_m > 0 else 0.0,
        lander.rules.noise_scale_by_cos,
        _LOG_PHI,
        slope,
        rough,
        score,
    )
    inner = (slice(b, z.shape[0] - b), slice(b, z.shape[1] - b))

    def full(a: np.ndarray) -> np.ndarray:
        out = np.full(z.shape, np.nan)
        out[inner] = a
        out[~valid] = np.nan
        return out

    slope_full, rough_full = full(slope), full(rough)
    safe = (slope_full < math.radians(lander.max_slope_deg)) & (rough_full < lander.max_roughness_m)
    label = np.where(safe, defaults.LABEL_SAFE, defaults.LABEL_UNSAFE).astype(np.uint8)
    label[~valid] = defaults.LABEL_INVALID
    maps = HazardMaps(slope_full.astype(np.float32), rough_full.astype(np.float32), label)
    if mode == _P_NONE:
        p = (rough_full < lander.max_roughness_m).astype(np.float64)
    else:
        p = _score_to_probability(full(score), mode)
    limit = math.radians(lander.max_slope_deg)
    slope_ok = slope_full <= limit if lander.rules.baseline_slope_inclusive else slope_full < limit
    p = np.where(slope_ok, p, 0.0)
    p[~valid] = np.nan
    return maps, p.astype(np.float32)


def _previous_worst_case_loops(
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
    mode,
    rc,
    inv_sigma,
    scale_by_c,
    log_phi,
    slope,
    rough,
    score,
):  # pragma: no cover - compiled by numba
    """Resting planes, slope, roughness and the P score, worst case over configurations (numba).

    Same numbers as ``_worst_case``'s numpy path; rows are processed one at a time so every
    working array stays in the L1 cache. ``score``: product mode, the smallest sum over a
    configuration's nodes of log Phi(u); min mode, the smallest u of any node.
    """
    n_yaws = plane_weights.shape[0]
    hv, wv = slope.shape
    n_cfg = 2 if n_pads == 4 else 1
    gx = np.empty((n_cfg, wv), dtype=z.dtype)
    gy = np.empty((n_cfg, wv), dtype=z.dtype)
    c = np.empty((n_cfg, wv), dtype=z.dtype)
    dmax = np.empty(wv, dtype=z.dtype)
    dmin = np.empty(wv, dtype=z.dtype)
    acc = np.empty(wv)
    ua = np.empty(wv)
    ub = np.empty(wv)
    slope[:, :] = 0.0
    rough[:, :] = 0.0
    score[:, :] = np.inf
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
                if mode == 1:
                    # u = ua - ub * h for a node at vertical height h above the plane (metres):
                    # u = (rc - h cos) / s with s = cos sigma (paper) or sigma (hd).
                    # In table units: x = (u - LO) / STEP = ua - ub * h, clamped to the table.
                    for j in range(wv):
                        tan2 = (gxk[j] * gxk[j] + gyk[j] * gyk[j]) * inv_s2
                        sec = np.sqrt(1.0 + tan2)
                        if scale_by_c:
                            ua[j] = (rc * sec * inv_sigma - _U_LO) * (1.0 / _U_STEP)
                            ub[j] = inv_sigma * (1.0 / _U_STEP)
                        else:
                            ua[j] = (rc * inv_sigma - _U_LO) * (1.0 / _U_STEP)
                            ub[j] = inv_sigma / sec * (1.0 / _U_STEP)
                        acc[j] = 0.0
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
                    if mode == 1:  # acc += log Phi(u), the piecewise cubic of _LOG_PHI
                        for j in range(wv):
                            dev = zr[j] - ck[j] - gxk[j] * dj + gyk[j] * di
                            x = min(max(ua[j] - ub[j] * dev, 0.0), (_U_HI - _U_LO) / _U_STEP)
                            q = int(x)
                            t = x - q
                            q *= 4
                            acc[j] += log_phi[q] + t * (log_phi[q + 1] + t * (log_phi[q + 2] + t * log_phi[q + 3]))
                for j in range(wv):
                    tan2 = (gxk[j] * gxk[j] + gyk[j] * gyk[j]) * inv_s2
                    height = max(dmax[j], 0.0)
                    if count_holes:
                        height = max(height, -dmin[j])
                    r = height / np.sqrt(1.0 + tan2)
                    slope[i, j] = max(slope[i, j], tan2)  # tan^2 for now; arctan at the end
                    rough[i, j] = max(rough[i, j], r)
                    if mode == 1:
                        score[i, j] = min(score[i, j], acc[j])
                    elif mode == 2:  # the worst node: the largest signed height above the plane
                        sec = np.sqrt(1.0 + tan2)
                        scale = sec * inv_sigma if scale_by_c else inv_sigma
                        score[i, j] = min(score[i, j], (rc - dmax[j] / sec) * scale)
    for i in range(hv):
        for j in range(wv):
            slope[i, j] = np.arctan(np.sqrt(slope[i, j]))


_previous_jit = numba.njit(cache=True, fastmath=_FASTMATH)(_previous_worst_case_loops)
