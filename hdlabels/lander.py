"""The lander: its parameters and the fixed sampling geometry they imply on a DEM grid.

Conventions (pixel units, used throughout hdlabels): a DEM is north-up, row ``i`` grows southward
and column ``j`` eastward. An offset ``(di, dj)`` in pixels is the map vector ``x = dj * spacing``
(east), ``y = -di * spacing`` (north). A yaw is the angle of pad 0 from east, counter-clockwise.
See ``docs/labels.md`` for the equations.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from functools import lru_cache
from typing import Literal

import numpy as np

from hdlabels import defaults, limits
from hdlabels.errors import HdLabelsError

# Candidate resting planes, as the three pads each passes through. Square: the first two pads are
# the diagonal the lander rocks on; it rests on diagonal (0, 2) iff z0 + z2 >= z1 + z3, else on
# (1, 3), and may tip either way about it (the tipping rule, docs/labels.md).
RESTING_TRIPLES: dict[int, tuple[tuple[int, int, int], ...]] = {
    4: ((0, 2, 1), (0, 2, 3), (1, 3, 0), (1, 3, 2)),
    3: ((0, 1, 2),),
}

# Offsets closer than this (in pixels) to an exact boundary count as on it (floating-point slack).
_EPS_PX = 1e-9


@dataclass(frozen=True)
class Lander:
    """A legged lander, seen from above: a body disk and footpads on a circle inside it.

    Attributes:
        diameter_m: lander (body) diameter, metres; the body disk is what must clear the terrain.
        pad_diameter_m: footpad diameter, metres; pad centres lie on a circle of radius
            ``(diameter_m - pad_diameter_m) / 2`` so the pads sit inside the body disk.
        max_slope_deg: critical slope, degrees; a resting tilt at or above it is unsafe.
        max_roughness_m: critical roughness, metres; terrain at or above this distance from the
            lander plane (perpendicular) under the body is unsafe.
        layout: ``"square"`` (4 pads, 90 deg apart) or ``"triangle"`` (3 pads, 120 deg apart).
        n_yaws: yaws evaluated per symmetry period of the layout (90 deg square, 120 deg triangle),
            evenly spaced from 0.
        count_holes: if True, terrain below the lander plane counts as roughness too
            (absolute distance); by default only terrain above the plane counts.
        convention: ``"paper"`` (the ALHAT replica the paper used: pads on pixel nodes, 10-degree
            orientations over a full turn, roughness over the nodes strictly inside the pad polygon)
            or ``"hd"`` (sub-pixel pads, ``n_yaws`` yaws, roughness over the body disk); see
            ``docs/labels.md``.
        baseline_combine: how the P(safe) baseline combines the per-node probabilities of one
            lander configuration: ``"product"`` (Ivanov et al. 2013, Eq. 13) or ``"min"`` (the worst
            node); None takes the convention's default (paper: product, hd: min).
    """

    diameter_m: float = defaults.LANDER_DIAMETER_M
    pad_diameter_m: float = defaults.PAD_DIAMETER_M
    max_slope_deg: float = defaults.MAX_SLOPE_DEG
    max_roughness_m: float = defaults.MAX_ROUGHNESS_M
    layout: Literal["square", "triangle"] = defaults.LAYOUT
    n_yaws: int = defaults.N_YAWS
    count_holes: bool = defaults.COUNT_HOLES
    convention: Literal["paper", "hd"] = defaults.CONVENTION
    baseline_combine: Literal["product", "min"] | None = None

    def __post_init__(self) -> None:
        for name in ("diameter_m", "pad_diameter_m", "max_slope_deg", "max_roughness_m"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise HdLabelsError(f"Lander {name} must be a finite number, got {value!r}.")
            if value <= 0:
                raise HdLabelsError(f"Lander {name} must be > 0, got {value!r}.")
        if self.pad_diameter_m >= self.diameter_m:
            raise HdLabelsError(
                f"Lander pad diameter ({self.pad_diameter_m} m) must be smaller than the lander "
                f"diameter ({self.diameter_m} m)."
            )
        if not limits.MAX_SLOPE_DEG.contains(self.max_slope_deg):
            raise HdLabelsError(
                f"Lander max_slope_deg must be in {limits.MAX_SLOPE_DEG.interval()} degrees, "
                f"got {self.max_slope_deg!r}."
            )
        if self.layout not in defaults.LAYOUTS:
            raise HdLabelsError(f"Lander layout must be 'square' or 'triangle', got {self.layout!r}.")
        if isinstance(self.n_yaws, bool) or not isinstance(self.n_yaws, int) or not limits.YAWS.contains(self.n_yaws):
            raise HdLabelsError(f"Lander n_yaws must be an integer in {limits.YAWS.interval()}, got {self.n_yaws!r}.")
        if not isinstance(self.count_holes, bool):
            raise HdLabelsError(f"Lander count_holes must be True or False, got {self.count_holes!r}.")
        if self.convention not in defaults.CONVENTIONS:
            raise HdLabelsError(f"Label convention must be 'paper' or 'hd', got {self.convention!r}.")
        if self.convention == "paper" and self.n_yaws != defaults.N_YAWS:
            raise HdLabelsError(
                "n_yaws applies to the hd convention only; the paper convention evaluates orientations "
                f"every {defaults.PAPER_ORIENTATION_STEP_DEG:g} degrees over a full turn."
            )
        if self.baseline_combine is None:
            object.__setattr__(self, "baseline_combine", defaults.BASELINE_COMBINE[self.convention])
        if self.baseline_combine not in defaults.BASELINE_COMBINES:
            raise HdLabelsError(f"Baseline combination must be 'product' or 'min', got {self.baseline_combine!r}.")

    @property
    def n_pads(self) -> int:
        """Number of footpads (4 square, 3 triangle)."""
        return 4 if self.layout == "square" else 3

    @property
    def radius_m(self) -> float:
        """Body radius, metres."""
        return self.diameter_m / 2.0

    @property
    def pad_radius_m(self) -> float:
        """Footpad radius, metres."""
        return self.pad_diameter_m / 2.0

    @property
    def pad_centre_radius_m(self) -> float:
        """Distance of each pad centre from the lander centre, metres."""
        return (self.diameter_m - self.pad_diameter_m) / 2.0

    def yaws_rad(self) -> np.ndarray:
        """The evaluated yaws, radians: ``n_yaws`` evenly spaced over one symmetry period."""
        period = 2.0 * math.pi / self.n_pads
        return np.arange(self.n_yaws, dtype=np.float64) * (period / self.n_yaws)

    def to_attrs(self) -> dict[str, float | int | str | bool]:
        """The lander as plain attributes (HDF5/JSON-friendly), with derived values for readers.

        The paper convention has no yaw count, rim samples or sub-pixel pad radius; it records its
        orientation step and the pad and body radii in whole pixels of the 1 m grid instead.
        """
        attrs: dict[str, float | int | str | bool] = dict(asdict(self))
        attrs["n_pads"] = self.n_pads
        if self.convention == "hd":
            attrs["pad_centre_radius_m"] = self.pad_centre_radius_m
            attrs["yaw_step_deg"] = 360.0 / self.n_pads / self.n_yaws
            attrs["pad_rim_samples"] = defaults.PAD_RIM_SAMPLES
        else:
            del attrs["n_yaws"]
            attrs["orientation_step_deg"] = defaults.PAPER_ORIENTATION_STEP_DEG
        return attrs

    @classmethod
    def from_attrs(cls, attrs: Mapping[str, object]) -> Lander:
        """The lander recorded by ``to_attrs`` (derived values are ignored).

        Records written before the paper convention existed carry no ``convention``: they are
        the hd convention with the worst-node ("min") baseline.
        """
        keys = (
            "diameter_m",
            "pad_diameter_m",
            "max_slope_deg",
            "max_roughness_m",
            "layout",
            "n_yaws",
            "count_holes",
            "baseline_combine",
        )
        values: dict[str, object] = {k: _plain(attrs[k]) for k in keys if k in attrs}
        values["convention"] = str(attrs.get("convention", "hd"))
        if values["convention"] == "paper":
            values.pop("n_yaws", None)
        return cls(**values)  # type: ignore[arg-type]  # recorded values, checked by __post_init__


def _plain(value: object) -> object:
    """numpy scalars (as h5py returns attributes) as plain Python values."""
    return value.item() if isinstance(value, np.generic) else value


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


@lru_cache(maxsize=32)
def geometry(lander: Lander, spacing_m: float) -> Geometry:
    """Sampling tables for ``lander`` on a grid of ``spacing_m`` metres per pixel (cached)."""
    if not (math.isfinite(spacing_m) and spacing_m > 0):
        raise HdLabelsError(f"DEM spacing must be a finite positive number of metres per pixel, got {spacing_m!r}.")
    if lander.convention == "paper":
        from hdlabels.paper_geometry import paper_geometry

        return paper_geometry(lander, spacing_m)
    return _hd_geometry(lander, spacing_m)


def _hd_geometry(lander: Lander, spacing_m: float) -> Geometry:
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
