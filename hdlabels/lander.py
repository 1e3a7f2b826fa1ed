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
from hdlabels.conventions import Convention, convention
from hdlabels.errors import HdLabelsError
from hdlabels.geometry import RESTING_TRIPLES, Geometry, plane_weights_of
from hdlabels.hd_geometry import bilinear_taps, pad_sample_points

__all__ = [
    "RESTING_TRIPLES",
    "Geometry",
    "Lander",
    "bilinear_taps",
    "geometry",
    "pad_sample_points",
    "plane_weights_of",
]


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
        rules = convention(self.convention)
        rules.check(self)
        if self.baseline_combine is None:
            object.__setattr__(self, "baseline_combine", rules.baseline_combine)
        if self.baseline_combine not in defaults.BASELINE_COMBINES:
            raise HdLabelsError(f"Baseline combination must be 'product' or 'min', got {self.baseline_combine!r}.")

    @property
    def rules(self) -> Convention:
        """The label convention's rules (``hdlabels.conventions``), the object ``convention`` names."""
        return convention(self.convention)

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
        self.rules.lander_attrs(self, attrs)
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
        convention(values["convention"]).lander_values(values)
        return cls(**values)  # type: ignore[arg-type]  # recorded values, checked by __post_init__


def _plain(value: object) -> object:
    """numpy scalars (as h5py returns attributes) as plain Python values."""
    return value.item() if isinstance(value, np.generic) else value


@lru_cache(maxsize=32)
def geometry(lander: Lander, spacing_m: float) -> Geometry:
    """Sampling tables for ``lander`` on a grid of ``spacing_m`` metres per pixel (cached)."""
    if not (math.isfinite(spacing_m) and spacing_m > 0):
        raise HdLabelsError(f"DEM spacing must be a finite positive number of metres per pixel, got {spacing_m!r}.")
    return lander.rules.geometry(lander, spacing_m)
