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

from hdcore.setting import check, setting
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
    """A legged lander, seen from above: a body disk and footpads on a circle inside it. Each field's
    meaning, unit and range is its metadata (``hdcore.setting``), from which the checks here are
    made; how the fields go together (the pads inside the body, the convention's own rules) is
    checked after them.
    """

    diameter_m: float = setting(
        defaults.LANDER_DIAMETER_M,
        "Lander (body) diameter; the body disk is what must clear the terrain",
        unit="metres",
        bound=limits.LANDER_DIAMETER_M,
        cli=False,
    )
    pad_diameter_m: float = setting(
        defaults.PAD_DIAMETER_M,
        "Footpad diameter; pad centres lie on a circle of radius (lander diameter - pad diameter) / 2, so the "
        "pads sit inside the body disk",
        unit="metres",
        bound=limits.PAD_DIAMETER_M,
        cli=False,
    )
    max_slope_deg: float = setting(
        defaults.MAX_SLOPE_DEG,
        "Critical slope; a resting tilt at or above it is unsafe",
        unit="degrees",
        bound=limits.MAX_SLOPE_DEG,
        cli=False,
    )
    max_roughness_m: float = setting(
        defaults.MAX_ROUGHNESS_M,
        "Critical roughness; terrain at or above this distance from the lander plane (perpendicular) under the "
        "body is unsafe",
        unit="metres",
        bound=limits.MAX_ROUGHNESS_M,
        cli=False,
    )
    layout: Literal["square", "triangle"] = setting(
        defaults.LAYOUT,
        "square (4 pads, 90 deg apart) or triangle (3 pads, 120 deg apart)",
        choices=defaults.LAYOUTS,
        cli=False,
    )
    n_yaws: int = setting(
        defaults.N_YAWS,
        "Yaws evaluated per symmetry period of the layout (90 deg square, 120 deg triangle), evenly spaced from 0",
        bound=limits.YAWS,
        cli=False,
    )
    count_holes: bool = setting(
        defaults.COUNT_HOLES,
        "Terrain below the lander plane counts as roughness too (absolute distance); by default only terrain "
        "above the plane counts",
        cli=False,
    )
    convention: Literal["paper", "hd"] = setting(
        defaults.CONVENTION,
        "paper (the ALHAT replica the paper used: pads on pixel nodes, 10-degree orientations over a full turn, "
        "roughness over the nodes strictly inside the pad polygon) or hd (sub-pixel pads, n_yaws yaws, roughness "
        "over the body disk); docs/labels.md",
        kind=str,  # its choices are checked by hdlabels.conventions, with the conventions' own message
        cli=False,
    )
    baseline_combine: Literal["product", "min"] | None = setting(
        None,
        "How the P(safe) baseline combines the per-node probabilities of one lander configuration: product "
        "(Ivanov et al. 2013, Eq. 13) or min (the worst node); default: the convention's (paper: product, hd: min)",
        choices=defaults.BASELINE_COMBINES,
        cli=False,
    )

    def __post_init__(self) -> None:
        check(self, HdLabelsError, name=lambda field, _: f"Lander {field}")
        if self.pad_diameter_m >= self.diameter_m:
            raise HdLabelsError(
                f"Lander pad diameter ({self.pad_diameter_m} m) must be smaller than the lander "
                f"diameter ({self.diameter_m} m)."
            )
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
