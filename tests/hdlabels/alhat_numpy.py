"""The numpy oracle of ``hdlabels.alhat``: the same rules as array operations, for the tests.

The library computes the hazard maps and P(safe) with its compiled kernels only. This module
writes the same rules a second way, vectorised over all sites with numpy (loops over yaws, pads
and nodes; scipy's ``log_ndtr`` for log Phi), and plugs it into the library's own preparation and
assembly (``alhat._evaluate``), so that a test can compare the kernels with an independent
implementation: ``hazard_maps(..., backend="numpy")`` is the oracle, ``backend="numba"`` the
library.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from scipy.special import log_ndtr

from hdlabels import alhat
from hdlabels.alhat import HazardMaps
from hdlabels.geometry import Geometry
from hdlabels.lander import Lander

Backend = Literal["numba", "numpy"]


def hazard_maps(
    dem: np.ndarray, spacing_m: float, lander: Lander = Lander(), *, backend: Backend = "numba"
) -> HazardMaps:
    """``alhat.hazard_maps`` (``"numba"``) or the oracle's (``"numpy"``)."""
    if backend == "numba":
        return alhat.hazard_maps(dem, spacing_m, lander)
    return alhat._evaluate(dem, spacing_m, lander, None, False, numpy_worst_case)[0]


def hazard_and_probability(
    dem: np.ndarray, spacing_m: float, sigma_m: float, lander: Lander = Lander(), *, backend: Backend = "numba"
) -> tuple[HazardMaps, np.ndarray]:
    """``alhat.hazard_and_probability`` (``"numba"``) or the oracle's (``"numpy"``)."""
    if backend == "numba":
        return alhat.hazard_and_probability(dem, spacing_m, sigma_m, lander)
    alhat._check_sigma(sigma_m)
    maps, p = alhat._evaluate(dem, spacing_m, lander, float(sigma_m), False, numpy_worst_case)
    assert p is not None
    return maps, p


def safety_probability(
    dem: np.ndarray, spacing_m: float, sigma_m: float, lander: Lander = Lander(), *, backend: Backend = "numba"
) -> np.ndarray:
    """``alhat.safety_probability`` (``"numba"``) or the oracle's (``"numpy"``)."""
    return hazard_and_probability(dem, spacing_m, sigma_m, lander, backend=backend)[1]


def numpy_worst_case(
    z: np.ndarray,
    valid: np.ndarray,
    geo: Geometry,
    lander: Lander,
    spacing_m: float,
    mode: int,
    sigma_m: float,
    parallel: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Worst-case slope (rad), roughness (m) and P score over the interior sites, as ``alhat._worst_case``.

    float64 throughout, every node of every site summed (no bounds); ``parallel`` is ignored.
    """
    b = geo.band_px
    hv, wv = z.shape[0] - 2 * b, z.shape[1] - 2 * b
    scale_by_c = lander.rules.noise_scale_by_cos
    inv_sigma = 1.0 / sigma_m if sigma_m > 0 else 0.0
    score = np.zeros((hv, wv))
    heights = np.empty((geo.tap_w.shape[0], hv, wv))
    pad_heights(z, b, geo, heights)
    gx, gy, c = resting_planes(heights, geo, lander.n_pads)
    n_cfg = gx.shape[0] // geo.n_yaws
    tan2 = (gx * gx + gy * gy) / (spacing_m * spacing_m)
    sec = np.sqrt(1.0 + tan2)
    slope = np.arctan(np.sqrt(tan2.max(axis=0)))
    rough = np.zeros((hv, wv))
    best = np.full((hv, wv), np.inf)
    rc = lander.max_roughness_m
    for q in range(gx.shape[0]):
        di, dj = geo.nodes(q // n_cfg)
        dev = np.stack([z[b + a : b + a + hv, b + e : b + e + wv] for a, e in zip(di, dj, strict=True)])
        dev = dev - c[q] - gx[q] * dj[:, None, None] + gy[q] * di[:, None, None]
        height = np.maximum(dev.max(axis=0), 0.0)
        if lander.count_holes:
            height = np.maximum(height, -dev.min(axis=0))
        np.maximum(rough, height / sec[q], out=rough)
        if mode == alhat._P_NONE:
            continue
        # Standardised margin of a node at perpendicular height r: u = (rc - r) / s, with the noise
        # scale s = c sigma (c = 1 / sec) or sigma, as the convention says.
        scale = sec[q] * inv_sigma if scale_by_c else inv_sigma
        if mode == alhat._P_PRODUCT:
            q_score = log_ndtr((rc - dev / sec[q]) * scale).sum(axis=0)
        else:  # the worst node: the largest signed height above the plane
            q_score = (rc - dev.max(axis=0) / sec[q]) * scale
        np.minimum(best, q_score, out=best)
    if mode != alhat._P_NONE:
        score = best
    return slope, rough, score


def pad_heights(z: np.ndarray, b: int, geo: Geometry, out: np.ndarray) -> None:
    """Pad contact heights: for each pad position, max over samples of bilinear terrain (metres)."""
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


def resting_planes(heights: np.ndarray, geo: Geometry, n_pads: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resting planes per site, stacked over (yaw, plane of that yaw), from the pad heights.

    ``heights`` is (n_yaws * n_pads, Hv, Wv), metres. Returns gx, gy (metres per pixel along x east
    and y north) and c (metres, the plane's height at the site), each (n_yaws * n_cfg, Hv, Wv).
    """
    n_yaws = heights.shape[0] // n_pads
    h = heights.reshape(n_yaws, n_pads, *heights.shape[1:])
    gx, gy, c = [], [], []
    for m in range(n_yaws):
        coeffs = [
            np.tensordot(geo.plane_weights[m, t], h[m, list(triple)], axes=1) for t, triple in enumerate(geo.triples)
        ]
        if n_pads == 4:  # rock on the higher diagonal, both ways
            on_02 = h[m, 0] + h[m, 2] >= h[m, 1] + h[m, 3]
            coeffs = [np.where(on_02, coeffs[0], coeffs[2]), np.where(on_02, coeffs[1], coeffs[3])]
        for co in coeffs:
            gx.append(co[0])
            gy.append(co[1])
            c.append(co[2])
    return np.stack(gx), np.stack(gy), np.stack(c)
