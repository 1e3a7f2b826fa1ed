"""The paper convention's sampling tables: the ALHAT replica's pads, orientations and roughness nodes.

The paper labelled its DEMs with the ALHAT replica of its first author's public library (pydem,
commit e7734ae, April 2023; ``docs/references.md``). Its rules, in hd's words (``docs/labels.md``,
"The paper convention"), on a grid of ``s`` metres per pixel:

* radii in whole pixels, rounded down: pad ``n_p = floor(d / 2 / s)``, lander ``n_l = floor(D / 2 / s)``;
  pad centres on the circle of radius ``R = n_l - n_p`` pixels;
* orientations ``theta = 0, 10, ..., 350`` degrees (a full turn); each pad centre is snapped to a
  node by truncating its (row, column) offset towards zero. Square, with ``c = trunc(R cos theta)``
  and ``s = trunc(R sin theta)``: pads at (row, col) ``(s, -c), (c, s), (-s, c), (-c, -s)``. Triangle:
  ``(trunc(R sin theta), trunc(R cos(theta + pi)))``, ``(trunc(R sin(theta + 2pi/3)), trunc(R cos(theta - pi/3)))``,
  ``(trunc(R sin(theta - 2pi/3)), trunc(R cos(theta + pi/3)))``;
* pad height: the highest DEM node within the pad disk ``i^2 + j^2 <= n_p^2`` (the node itself at 1 m);
* resting plane through pads 0, 1, 2; a square lander's orientation counts only if pad 3 is not
  above that plane (the tipping rule);
* roughness nodes: offsets with ``|di|, |dj| <= n_l - (2 n_p + 1)`` strictly inside the pad polygon;
* sites closer than ``n_l`` pixels to the border are invalid.

Truncation makes several orientations land on the same pads (at 1 m/px the 36 orientations of
the square lander give 7 distinct squares). The four orientations 90 degrees apart share one
square and are its four resting planes, of which exactly those through the diagonal with the
higher pad-height sum pass the tipping rule - the tipping rule ``hdlabels.alhat`` already applies.
So the tables hold each distinct polygon once (a "yaw" of ``Geometry``), which gives the same
slopes, roughness and probabilities as evaluating all 36 orientations, in a fifth of the work.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from hdlabels import defaults
from hdlabels.errors import HdLabelsError
from hdlabels.geometry import RESTING_TRIPLES, Geometry, LanderShape, plane_weights_of

Offset = tuple[int, int]  # (row, column) offset from the site, pixels


def pixel_radii(lander: LanderShape, spacing_m: float) -> tuple[int, int]:
    """(pad radius, lander radius) in whole pixels, rounded down, as the replica sizes them."""
    return int(lander.pad_radius_m / spacing_m), int(lander.radius_m / spacing_m)


def orientations_rad() -> np.ndarray:
    """The evaluated lander orientations, radians: every 10 degrees over a full turn (36)."""
    step = math.radians(defaults.PAPER_ORIENTATION_STEP_DEG)
    return np.arange(0.0, 2.0 * math.pi, step)


def pad_offsets(layout: str, radius_px: int, theta: float) -> tuple[Offset, ...]:
    """The pads of one orientation as (row, column) node offsets, in the replica's pad order."""
    r = radius_px
    if layout == "square":
        c, s = int(r * math.cos(theta)), int(r * math.sin(theta))
        return ((s, -c), (c, s), (-s, c), (-c, -s))
    return (
        (int(r * math.sin(theta)), int(r * math.cos(theta + math.pi))),
        (int(r * math.sin(theta + 2.0 * math.pi / 3.0)), int(r * math.cos(theta - math.pi / 3.0))),
        (int(r * math.sin(theta - 2.0 * math.pi / 3.0)), int(r * math.cos(theta + math.pi / 3.0))),
    )


def strictly_inside(pads: tuple[Offset, ...], reach: int) -> list[Offset]:
    """Node offsets within ``reach`` (per axis) strictly inside the pad polygon, in the replica's sense.

    A node is inside when it lies strictly to the left of every edge pad[k-1] -> pad[k] in
    (row, column) coordinates: nodes on an edge or a vertex are outside. Integer arithmetic, exact.
    """
    n = len(pads)
    inside = []
    for di in range(-reach, reach + 1):
        for dj in range(-reach, reach + 1):
            ok = True
            for k in range(n):
                (a0, a1), (b0, b1) = pads[k - 1], pads[k]
                if (b0 - a0) * (dj - a1) - (b1 - a1) * (di - a0) <= 0:
                    ok = False
                    break
            if ok:
                inside.append((di, dj))
    return inside


def distinct_polygons(layout: str, radius_px: int) -> list[tuple[Offset, ...]]:
    """The distinct pad polygons of all orientations, each in the pad order of its first orientation.

    Raises:
        HdLabelsError: a polygon whose pads coincide or are collinear (the lander is too small for
            the grid), or a square that does not appear in all four of its 90-degree rotations.
    """
    polygons: list[tuple[Offset, ...]] = []
    seen: dict[frozenset[Offset], int] = {}
    rotations: dict[frozenset[Offset], set[tuple[Offset, ...]]] = {}
    for theta in orientations_rad():
        pads = pad_offsets(layout, radius_px, float(theta))
        (a0, a1), (b0, b1), (c0, c1) = pads[:3]
        if len(set(pads)) < len(pads) or (b0 - a0) * (c1 - a1) - (b1 - a1) * (c0 - a0) == 0:
            raise HdLabelsError(
                f"the paper convention's pads coincide at a pad-circle radius of {radius_px} px: the lander "
                "spans too few DEM pixels; use a finer DEM spacing or the hd convention"
            )
        key = frozenset(pads)
        if key not in seen:
            seen[key] = len(polygons)
            polygons.append(pads)
        rotations.setdefault(key, set()).add(pads)
    if layout == "square":
        for key, orders in rotations.items():
            first = polygons[seen[key]]
            if len(orders) != 4 or any(first[k:] + first[:k] not in orders for k in range(4)):
                raise HdLabelsError(f"internal: the square {sorted(key)} lacks some of its 90-degree rotations")
    return polygons


@lru_cache(maxsize=32)
def paper_geometry(lander: LanderShape, spacing_m: float) -> Geometry:
    """The paper convention's sampling tables for ``lander`` at ``spacing_m`` metres per pixel (cached)."""
    n_pad, n_body = pixel_radii(lander, spacing_m)
    radius = n_body - n_pad
    reach = n_body - (2 * n_pad + 1)
    if radius < 1 or reach < 0:
        raise HdLabelsError(
            f"the lander ({lander.diameter_m:g} m, pads {lander.pad_diameter_m:g} m) spans too few pixels of "
            f"{spacing_m:g} m for the paper convention (lander radius {n_body} px, pad radius {n_pad} px)"
        )
    polygons = distinct_polygons(lander.layout, radius)
    disk = [
        (i, j) for i in range(-n_pad, n_pad + 1) for j in range(-n_pad, n_pad + 1) if i * i + j * j <= n_pad * n_pad
    ]

    n_pads = lander.n_pads
    n_yaws = len(polygons)
    pad_xy = np.empty((n_yaws, n_pads, 2))
    shape = (n_yaws * n_pads, len(disk), 4)
    tap_di = np.zeros(shape, dtype=np.int64)
    tap_dj = np.zeros(shape, dtype=np.int64)
    tap_w = np.zeros(shape, dtype=np.float64)
    node_ptr = [0]
    node_di: list[int] = []
    node_dj: list[int] = []
    used: set[Offset] = set()
    for m, pads in enumerate(polygons):
        for k, (pi, pj) in enumerate(pads):
            pad_xy[m, k] = (pj, -pi)  # map vector: x east = column, y north = -row
            for q, (a, b) in enumerate(disk):
                tap_di[m * n_pads + k, q, :] = pi + a  # one tap of weight 1; the padding taps repeat it
                tap_dj[m * n_pads + k, q, :] = pj + b
                tap_w[m * n_pads + k, q, 0] = 1.0
                used.add((pi + a, pj + b))
        nodes = strictly_inside(pads, reach)
        node_di += [a for a, _ in nodes]
        node_dj += [b for _, b in nodes]
        node_ptr.append(len(node_di))
        used.update(nodes)

    band = n_body
    footprint = np.zeros((2 * band + 1, 2 * band + 1), dtype=bool)
    for a, b in used:
        footprint[a + band, b + band] = True
    triples = np.array(RESTING_TRIPLES[n_pads], dtype=np.int64)
    return Geometry(
        pad_xy_px=pad_xy,
        tap_di=tap_di,
        tap_dj=tap_dj,
        tap_w=tap_w,
        node_ptr=np.array(node_ptr, dtype=np.int64),
        node_di=np.array(node_di, dtype=np.int64),
        node_dj=np.array(node_dj, dtype=np.int64),
        footprint=footprint,
        band_px=band,
        triples=triples,
        plane_weights=plane_weights_of(pad_xy, triples),
    )
