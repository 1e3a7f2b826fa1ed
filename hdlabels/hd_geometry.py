"""The hd convention's sampling tables: sub-pixel pads on their circle, ``n_yaws`` yaws, the body disk.

Pads are sampled on their rim and at the grid nodes inside them, the terrain interpolated
bilinearly between nodes; the roughness counts every node of the body disk (``docs/labels.md``,
"The hd convention").
"""

from __future__ import annotations

import math

import numpy as np

from hdlabels import defaults
from hdlabels.geometry import RESTING_TRIPLES, Geometry, LanderShape, plane_weights_of

# Offsets closer than this (in pixels) to an exact boundary count as on it (floating-point slack).
_EPS_PX = 1e-9


def pad_sample_points(centre_xy_px: tuple[float, float], pad_radius_px: float) -> list[tuple[float, float]]:
    """Points where the terrain under one pad is sampled, as map vectors (x, y) in pixels.

    ``PAD_RIM_SAMPLES`` points on the rim at fixed map angles ``2 pi q / N`` (the same for every pad,
    so that on a plane every pad is lifted by the same amount), plus every grid node inside the
    regular N-gon inscribed in the rim (distance <= r cos(pi / N) from the centre).
    """
    cx, cy = centre_xy_px
    n = defaults.PAD_RIM_SAMPLES
    points = [
        (cx + pad_radius_px * math.cos(2 * math.pi * q / n), cy + pad_radius_px * math.sin(2 * math.pi * q / n))
        for q in range(n)
    ]
    inner = pad_radius_px * math.cos(math.pi / n) + _EPS_PX
    points += [
        (float(x), float(y))
        for x in range(math.floor(cx - inner), math.ceil(cx + inner) + 1)
        for y in range(math.floor(cy - inner), math.ceil(cy + inner) + 1)
        if (x - cx) ** 2 + (y - cy) ** 2 <= inner**2
    ]
    return points


def bilinear_taps(x: float, y: float) -> list[tuple[int, int, float]]:
    """The grid nodes and weights of bilinear interpolation at map vector (x, y), pixels.

    Returns ``(di, dj, weight)`` for each node with a non-zero weight (1 to 4 nodes).
    """
    di_f, dj_f = -y, x
    i0, j0 = math.floor(di_f + _EPS_PX), math.floor(dj_f + _EPS_PX)
    ti, tj = di_f - i0, dj_f - j0
    ti = 0.0 if abs(ti) < _EPS_PX else ti
    tj = 0.0 if abs(tj) < _EPS_PX else tj
    taps = []
    for a, wa in ((0, 1.0 - ti), (1, ti)):
        for b, wb in ((0, 1.0 - tj), (1, tj)):
            if wa * wb > 0.0:
                taps.append((i0 + a, j0 + b, wa * wb))
    return taps


def hd_geometry(lander: LanderShape, spacing_m: float) -> Geometry:
    """The hd convention's tables: sub-pixel pads on their circle, ``n_yaws`` yaws, the body disk."""
    rho = lander.pad_centre_radius_m / spacing_m
    r_pad = lander.pad_radius_m / spacing_m
    r_body = lander.radius_m / spacing_m
    yaws = lander.yaws_rad()
    n_pads = lander.n_pads

    pad_xy = np.empty((len(yaws), n_pads, 2))
    taps_all: list[list[list[tuple[int, int, float]]]] = []
    for m, yaw in enumerate(yaws):
        for k in range(n_pads):
            phi = yaw + 2.0 * math.pi * k / n_pads
            cx, cy = rho * math.cos(phi), rho * math.sin(phi)
            pad_xy[m, k] = (cx, cy)
            taps_all.append([bilinear_taps(x, y) for x, y in pad_sample_points((cx, cy), r_pad)])

    n_samples = max(len(s) for s in taps_all)
    shape = (len(taps_all), n_samples, 4)
    tap_di = np.zeros(shape, dtype=np.int64)
    tap_dj = np.zeros(shape, dtype=np.int64)
    tap_w = np.zeros(shape, dtype=np.float64)
    for p, samples in enumerate(taps_all):
        padded = samples + [samples[0]] * (n_samples - len(samples))
        for q, taps in enumerate(padded):
            for t, (di, dj, w) in enumerate(taps):
                tap_di[p, q, t], tap_dj[p, q, t], tap_w[p, q, t] = di, dj, w
            for t in range(len(taps), 4):  # weight-0 padding taps point at a real tap's node
                tap_di[p, q, t], tap_dj[p, q, t] = taps[0][0], taps[0][1]

    reach = math.floor(r_body + _EPS_PX)
    di, dj = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    inside = di**2 + dj**2 <= r_body**2 + _EPS_PX
    body_di, body_dj = di[inside], dj[inside]

    nodes = set(zip(body_di.tolist(), body_dj.tolist(), strict=True))
    nodes.update(
        (int(a), int(b)) for a, b, w in zip(tap_di.ravel(), tap_dj.ravel(), tap_w.ravel(), strict=True) if w > 0
    )
    band = max(max(abs(a), abs(b)) for a, b in nodes)
    footprint = np.zeros((2 * band + 1, 2 * band + 1), dtype=bool)
    for a, b in nodes:
        footprint[a + band, b + band] = True

    triples = np.array(RESTING_TRIPLES[n_pads], dtype=np.int64)
    plane_weights = plane_weights_of(pad_xy, triples)

    n_body = body_di.size
    return Geometry(
        pad_xy_px=pad_xy,
        tap_di=tap_di,
        tap_dj=tap_dj,
        tap_w=tap_w,
        node_ptr=np.arange(len(yaws) + 1, dtype=np.int64) * n_body,
        node_di=np.tile(body_di.astype(np.int64), len(yaws)),
        node_dj=np.tile(body_dj.astype(np.int64), len(yaws)),
        footprint=footprint,
        band_px=band,
        triples=triples,
        plane_weights=plane_weights,
    )
