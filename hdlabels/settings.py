"""The settings of a labelling, as ``hd label`` takes them and a recipe's ``[label]`` section records them.

One flat record (:class:`LabelSettings`, defaults from ``hdlabels.defaults``) that makes the
:class:`~hdlabels.lander.Lander` and the :class:`~hdlabels.store.DemSpec` of a labelling, so that
the command line and recipes map onto the lander in one place.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from hdlabels import defaults
from hdlabels.conventions import convention
from hdlabels.errors import HdLabelsError
from hdlabels.lander import Lander
from hdlabels.store import DemSpec

# Recipes written before label conventions existed carry no ``convention``: they are the hd convention.
RECIPE_CONVENTION_BEFORE_CONVENTIONS = "hd"


@dataclass(frozen=True)
class LabelSettings:
    """Lander and DEM settings of a labelling (field names are the recipe's ``[label]`` keys).

    Attributes:
        lander: pad layout, ``"square"`` (4 pads) or ``"triangle"`` (3 pads).
        lander_diameter_m: lander (body) diameter, metres.
        pad_diameter_m: footpad diameter, metres.
        max_slope_deg: critical slope, degrees.
        max_roughness_m: critical roughness, metres.
        yaws: hd convention only: yaws per symmetry period of the layout (None: the default).
        count_holes: count terrain below the lander plane as roughness too.
        dem_size: DEM side, pixels.
        dem_spacing_m: DEM spacing, metres/pixel.
        convention: ``"paper"`` or ``"hd"`` (docs/labels.md).
        baseline_combine: ``"product"`` or ``"min"``; None takes the convention's.
        gridding: ``"linear"``, ``"mean"``, ``"max"`` or ``"nearest"``; None takes the convention's.
        truth: what the deterministic labels come from: ``"clean-scan"`` (the clean scan's DEM, the
            paper's) or ``"terrain"`` (the DTM the dataset was built on, on each scan's DEM grid).
    """

    lander: str = defaults.LAYOUT
    lander_diameter_m: float = defaults.LANDER_DIAMETER_M
    pad_diameter_m: float = defaults.PAD_DIAMETER_M
    max_slope_deg: float = defaults.MAX_SLOPE_DEG
    max_roughness_m: float = defaults.MAX_ROUGHNESS_M
    yaws: int | None = None
    count_holes: bool = defaults.COUNT_HOLES
    dem_size: int = defaults.DEM_ROWS
    dem_spacing_m: float = defaults.DEM_SPACING_M
    convention: str = defaults.CONVENTION
    baseline_combine: str | None = None
    gridding: str | None = None
    truth: str = defaults.TRUTH

    @classmethod
    def from_recipe(cls, section: Mapping[str, Any], where: str = "recipe") -> LabelSettings:
        """The settings of a recipe's ``[label]`` section (missing keys take the defaults; a recipe
        without ``convention`` is the hd convention, as recipes were before conventions existed).

        Raises:
            HdLabelsError: an unknown key or a value of the wrong type, naming ``where`` and the key.
        """
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(section) - set(known))
        if unknown:
            raise HdLabelsError(f"{where}: unknown [label] key(s) {unknown}")
        casts = {
            "lander": str,
            "lander_diameter_m": float,
            "pad_diameter_m": float,
            "max_slope_deg": float,
            "max_roughness_m": float,
            "yaws": int,
            "count_holes": bool,
            "dem_size": int,
            "dem_spacing_m": float,
            "convention": str,
            "baseline_combine": str,
            "gridding": str,
            "truth": str,
        }
        values: dict[str, Any] = {"convention": RECIPE_CONVENTION_BEFORE_CONVENTIONS}
        for key, value in section.items():
            try:
                values[key] = casts[key](value)
            except (TypeError, ValueError) as exc:
                raise HdLabelsError(f"{where}: [label] {key} = {value!r} is not a valid value") from exc
        if values.get("truth", defaults.TRUTH) not in defaults.TRUTHS:
            truths = ", ".join(defaults.TRUTHS)
            raise HdLabelsError(f"{where}: [label] truth = {values['truth']!r} is not one of {truths}")
        return cls(**values)

    def to_lander(self) -> Lander:
        """The lander these settings describe.

        Raises:
            HdLabelsError: an invalid lander, or ``yaws`` with the paper convention.
        """
        if self.yaws is not None and not convention(self.convention).has_yaws:
            raise HdLabelsError(
                "--yaws applies to --convention hd only (the paper convention turns the lander in "
                f"{defaults.PAPER_ORIENTATION_STEP_DEG:g}-degree steps)"
            )
        return Lander(
            diameter_m=self.lander_diameter_m,
            pad_diameter_m=self.pad_diameter_m,
            max_slope_deg=self.max_slope_deg,
            max_roughness_m=self.max_roughness_m,
            layout=self.lander,  # type: ignore[arg-type]  # a str, checked by Lander against LAYOUTS
            n_yaws=self.yaws if self.yaws is not None else defaults.N_YAWS,
            count_holes=self.count_holes,
            convention=self.convention,  # type: ignore[arg-type]  # checked by Lander against CONVENTIONS
            baseline_combine=self.baseline_combine,  # type: ignore[arg-type]  # checked by Lander against its combines
        )

    def to_dem_spec(self) -> DemSpec:
        """The square DEM grid of these settings, with the convention's gridding unless one is given.

        Raises:
            LabelStoreError: an invalid size, spacing or gridding.
        """
        return DemSpec.for_convention(self.convention, self.dem_size, self.dem_size, self.dem_spacing_m, self.gridding)
