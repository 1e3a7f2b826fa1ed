"""The sampling tables of a lander on a DEM grid, as every label convention lays them out.

A convention (``hdlabels.conventions``) turns a lander and a grid spacing into one ``Geometry``:
where the pads stand for each placement, which nodes each pad rests on, which nodes count for the
roughness, and the resting planes through the pads. ``hdlabels.alhat`` evaluates any ``Geometry``
with one kernel. Offsets are in pixels (row ``di`` southward, column ``dj`` eastward; the map
vector of an offset is ``x = dj``, ``y = -di``).
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

# Candidate resting planes, as the three pads each passes through. Square: the first two pads are
# the diagonal the lander rocks on; it rests on diagonal (0, 2) iff z0 + z2 >= z1 + z3, else on
# (1, 3), and may tip either way about it (the tipping rule, docs/labels.md).
RESTING_TRIPLES: dict[int, tuple[tuple[int, int, int], ...]] = {
    4: ((0, 2, 1), (0, 2, 3), (1, 3, 0), (1, 3, 2)),
    3: ((0, 1, 2),),
}


class LanderShape(Hashable, Protocol):
    """What a convention reads of a lander to lay out its tables (``hdlabels.lander.Lander`` has it all)."""

    @property
    def diameter_m(self) -> float: ...
    @property
    def pad_diameter_m(self) -> float: ...
    @property
    def layout(self) -> Literal["square", "triangle"]: ...
    @property
    def n_yaws(self) -> int: ...
    @property
    def n_pads(self) -> int: ...
    @property
    def radius_m(self) -> float: ...
    @property
    def pad_radius_m(self) -> float: ...
    @property
    def pad_centre_radius_m(self) -> float: ...
    def yaws_rad(self) -> np.ndarray: ...


@dataclass(frozen=True)
class Geometry:
    """Sampling tables of one lander on one grid spacing (all offsets in pixels, relative to the site).

    A *yaw* here is one placement of the pads around the site (the hd convention's yaws; the paper
    convention's distinct pad polygons). Both conventions fill the same tables, so one kernel
    (``hdlabels.alhat``) evaluates either.

    Attributes:
        pad_xy_px: (n_yaws, n_pads, 2) pad centres as map vectors (x east, y north), pixels.
        tap_di, tap_dj: (n_yaws * n_pads, n_samples, 4) integer node offsets of the bilinear taps of
            every pad sample point (row, column); padding taps have weight 0.
        tap_w: (n_yaws * n_pads, n_samples, 4) bilinear weights; samples are padded by repeating
            the first sample, so the max over samples is unchanged.
        node_ptr: (n_yaws + 1,) the roughness nodes of yaw m are ``node_di/dj[node_ptr[m]:node_ptr[m + 1]]``.
        node_di, node_dj: integer offsets of the roughness nodes (hd: the body disk, the same for
            every yaw; paper: the nodes strictly inside that yaw's pad polygon).
        footprint: (2b+1, 2b+1) bool, every node any result of the site depends on (roughness
            nodes and pad taps), centred on the site.
        band_px: b, sites closer than this to the border are invalid (at least the footprint's half-width).
        triples: (n_triples, 3) the pads of each candidate resting plane (see ``RESTING_TRIPLES``).
        plane_weights: (n_yaws, n_triples, 3, 3) maps the three pad heights of a triple to the
            plane ``z = gx x + gy y + c`` (gx, gy in metres per pixel, c in metres at the site).
    """

    pad_xy_px: np.ndarray
    tap_di: np.ndarray
    tap_dj: np.ndarray
    tap_w: np.ndarray
    node_ptr: np.ndarray
    node_di: np.ndarray
    node_dj: np.ndarray
    footprint: np.ndarray
    band_px: int
    triples: np.ndarray
    plane_weights: np.ndarray

    @property
    def n_yaws(self) -> int:
        """Number of pad placements evaluated per site."""
        return int(self.pad_xy_px.shape[0])

    def nodes(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """(di, dj) offsets of the roughness nodes of yaw ``m``."""
        lo, hi = int(self.node_ptr[m]), int(self.node_ptr[m + 1])
        return self.node_di[lo:hi], self.node_dj[lo:hi]


def plane_weights_of(pad_xy: np.ndarray, triples: np.ndarray) -> np.ndarray:
    """(n_yaws, n_triples, 3, 3): the inverse of [[x_k, y_k, 1]] for the pads of every triple.

    Applied to the three pad heights (metres) it gives ``(gx, gy, c)`` of the plane
    ``z = gx x + gy y + c`` (x, y in pixels).
    """
    weights = np.empty((pad_xy.shape[0], len(triples), 3, 3))
    for m in range(pad_xy.shape[0]):
        for t, triple in enumerate(triples):
            weights[m, t] = np.linalg.inv(np.array([[*pad_xy[m, k], 1.0] for k in triple]))
    return weights
