"""The two label conventions as objects with one protocol: what differs between "paper" and "hd".

A lander names its convention (``Lander.convention``, a string recorded in shards, manifests and
recipes); ``Lander.rules`` is the object of that name, and every rule that differs between the
conventions is asked of it, never decided by comparing the name (``docs/labels.md``, "Two
conventions"):

* the sampling tables: pads, orientations and roughness support (``geometry``);
* the baseline: its default combination of the per-node probabilities, whether a node's noise
  scale is ``c sigma`` (``c`` the z-component of the lander plane's unit normal) or ``sigma``, whether
  the hd convention's original worst-node form from the hazard maps applies, and whether the
  baseline's slope test keeps a slope equal to the limit;
* the default gridding of points into DEMs;
* what a lander record carries and the name of a labelling.

A new convention is one more class implementing ``Convention`` and one more entry in ``CONVENTIONS``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from hdlabels import defaults
from hdlabels.errors import HdLabelsError
from hdlabels.geometry import Geometry, LanderShape
from hdlabels.hd_geometry import hd_geometry
from hdlabels.paper_geometry import paper_geometry


class Convention(Protocol):
    """The rules of one label convention.

    Attributes:
        name: the recorded name (``"paper"``, ``"hd"``).
        baseline_combine: the baseline's default combination of a configuration's per-node
            probabilities, ``"product"`` or ``"min"``.
        gridding: the default gridding of points into DEMs (``hdlabels.grid``).
        has_yaws: whether the lander's ``n_yaws`` is a setting of this convention.
        noise_scale_by_cos: the noise scale of a node's height is ``c sigma`` (True) or ``sigma``.
        baseline_slope_inclusive: the baseline's slope test keeps a slope equal to the limit
            (the labels' test is strict in both conventions).
    """

    @property
    def name(self) -> str: ...
    @property
    def baseline_combine(self) -> str: ...
    @property
    def gridding(self) -> str: ...
    @property
    def has_yaws(self) -> bool: ...
    @property
    def noise_scale_by_cos(self) -> bool: ...
    @property
    def baseline_slope_inclusive(self) -> bool: ...

    def check(self, lander: LanderShape) -> None:
        """Raise ``HdLabelsError`` for a lander setting this convention does not take."""
        ...

    def geometry(self, lander: LanderShape, spacing_m: float) -> Geometry:
        """The sampling tables of ``lander`` at ``spacing_m`` metres per pixel."""
        ...

    def baseline_from_maps(self, combine: str) -> bool:
        """Whether the baseline of this combination is ``Phi((r_crit - roughness) / sigma)`` of the maps."""
        ...

    def lander_attrs(self, lander: LanderShape, attrs: dict[str, float | int | str | bool]) -> None:
        """Add this convention's derived values to a lander's attributes (and drop those it lacks)."""
        ...

    def lander_values(self, values: dict[str, object]) -> None:
        """Drop, from a lander record read back, the values this convention does not take."""
        ...

    def labeling_name(self, body: str, n_yaws: int, holes: str, combine: str, gridding: str, grid: str) -> str:
        """A labelling's directory name from its parts (lander ``body``, ``holes`` suffix, DEM ``grid``)."""
        ...


@dataclass(frozen=True)
class PaperConvention:
    """The ALHAT replica the paper used (``hdlabels.paper_geometry``): pads on pixel nodes,
    10-degree orientations over a full turn, roughness over the nodes strictly inside the pad
    polygon, the product baseline with noise scale ``c sigma`` and an inclusive slope test."""

    name: str = "paper"
    baseline_combine: str = defaults.BASELINE_COMBINE["paper"]
    gridding: str = defaults.GRIDDING["paper"]
    has_yaws: bool = False
    noise_scale_by_cos: bool = True
    baseline_slope_inclusive: bool = True  # the replica calls slope > limit unsafe

    def check(self, lander: LanderShape) -> None:
        if lander.n_yaws != defaults.N_YAWS:
            raise HdLabelsError(
                "n_yaws applies to the hd convention only; the paper convention evaluates orientations "
                f"every {defaults.PAPER_ORIENTATION_STEP_DEG:g} degrees over a full turn."
            )

    def geometry(self, lander: LanderShape, spacing_m: float) -> Geometry:
        return paper_geometry(lander, spacing_m)

    def baseline_from_maps(self, combine: str) -> bool:
        return False

    def lander_attrs(self, lander: LanderShape, attrs: dict[str, float | int | str | bool]) -> None:
        del attrs["n_yaws"]
        attrs["orientation_step_deg"] = defaults.PAPER_ORIENTATION_STEP_DEG

    def lander_values(self, values: dict[str, object]) -> None:
        values.pop("n_yaws", None)

    def labeling_name(self, body: str, n_yaws: int, holes: str, combine: str, gridding: str, grid: str) -> str:
        return f"paper-{body}{holes}-{combine}-{gridding}-{grid}"


@dataclass(frozen=True)
class HdConvention:
    """hd's own geometric convention (``hdlabels.hd_geometry``): sub-pixel pads, ``n_yaws`` yaws,
    roughness over the body disk, the worst-node baseline with noise scale ``sigma`` and a strict
    slope test."""

    name: str = "hd"
    baseline_combine: str = defaults.BASELINE_COMBINE["hd"]
    gridding: str = defaults.GRIDDING["hd"]
    has_yaws: bool = True
    noise_scale_by_cos: bool = False
    baseline_slope_inclusive: bool = False

    def check(self, lander: LanderShape) -> None:
        return None

    def geometry(self, lander: LanderShape, spacing_m: float) -> Geometry:
        return hd_geometry(lander, spacing_m)

    def baseline_from_maps(self, combine: str) -> bool:
        # The hd convention's "min" baseline keeps its original form: taking the worst case over
        # configurations of Phi((r_crit - r) / sigma) equals it at the worst-case roughness.
        return combine == "min"

    def lander_attrs(self, lander: LanderShape, attrs: dict[str, float | int | str | bool]) -> None:
        attrs["pad_centre_radius_m"] = lander.pad_centre_radius_m
        attrs["yaw_step_deg"] = 360.0 / lander.n_pads / lander.n_yaws
        attrs["pad_rim_samples"] = defaults.PAD_RIM_SAMPLES

    def lander_values(self, values: dict[str, object]) -> None:
        return None

    def labeling_name(self, body: str, n_yaws: int, holes: str, combine: str, gridding: str, grid: str) -> str:
        # Labellings with the convention's own baseline and gridding keep the names they had
        # before conventions existed, so existing datasets keep their labellings.
        extra = "" if combine == self.baseline_combine else f"-{combine}"
        extra += "" if gridding == self.gridding else f"-{gridding}"
        return f"{body}-yaws{n_yaws}{holes}{extra}-{grid}"


CONVENTIONS: dict[str, Convention] = {c.name: c for c in (PaperConvention(), HdConvention())}


def convention(name: object) -> Convention:
    """The convention recorded as ``name``.

    Raises:
        HdLabelsError: an unknown name.
    """
    found = CONVENTIONS.get(name) if isinstance(name, str) else None
    if found is None:
        raise HdLabelsError(f"Label convention must be {' or '.join(map(repr, CONVENTIONS))}, got {name!r}.")
    return found
