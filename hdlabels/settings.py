"""The settings of a labelling, as ``hd label`` takes them and a recipe's ``[label]`` section records them.

One flat record (:class:`LabelSettings`, defaults from ``hdlabels.defaults``) that makes the
:class:`~hdlabels.lander.Lander` and the :class:`~hdlabels.store.DemSpec` of a labelling, so that
the command line and recipes map onto the lander in one place.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hdcore.setting import check, described_as, from_mapping, setting
from hdlabels import defaults, limits
from hdlabels.conventions import convention
from hdlabels.errors import HdLabelsError
from hdlabels.lander import Lander
from hdlabels.store import DemSpec

# Recipes written before label conventions existed carry no ``convention``: they are the hd convention.
RECIPE_CONVENTION_BEFORE_CONVENTIONS = "hd"


@dataclass(frozen=True)
class LabelSettings:
    """Lander and DEM settings of a labelling (field names are the recipe's ``[label]`` keys). Each
    field's help, unit, default and range is its metadata (``hdcore.setting``): the options of
    ``hd label``, the reading of a recipe's ``[label]`` and the checks here are made from it.
    """

    lander: str = described_as(Lander, "layout", cli=True)
    lander_diameter_m: float = described_as(Lander, "diameter_m", cli=True, flag="--lander-diameter")
    pad_diameter_m: float = described_as(Lander, "pad_diameter_m", cli=True, flag="--pad-diameter")
    max_slope_deg: float = described_as(Lander, "max_slope_deg", cli=True)
    max_roughness_m: float = described_as(Lander, "max_roughness_m", cli=True, flag="--max-roughness")
    yaws: int | None = setting(
        None,
        f"hd convention: yaws per symmetry period of the pad layout (default {defaults.N_YAWS})",
        bound=limits.YAWS,
    )
    count_holes: bool = described_as(Lander, "count_holes", cli=True)
    dem_size: int = setting(defaults.DEM_ROWS, "DEM side", unit="pixels", bound=limits.DEM_SIZE_PX)
    dem_spacing_m: float = setting(
        defaults.DEM_SPACING_M, "DEM spacing", unit="metres/pixel", bound=limits.DEM_SPACING_M, flag="--dem-spacing"
    )
    convention: str = described_as(Lander, "convention", cli=True, choices=defaults.CONVENTIONS)
    baseline_combine: str | None = described_as(Lander, "baseline_combine", cli=True)
    gridding: str | None = setting(
        None,
        "Points to DEM: linear interpolation, or the mean, max or most central of each cell's returns "
        "(default: the convention's)",
        choices=defaults.GRIDDINGS,
    )
    truth: str = setting(
        defaults.TRUTH,
        "What the deterministic labels come from: the clean scan's DEM (the paper's) or the terrain itself, "
        "the DTM the dataset was built on sampled on each scan's DEM grid",
        choices=defaults.TRUTHS,
    )

    def __post_init__(self) -> None:
        check(self, HdLabelsError)

    @classmethod
    def from_recipe(cls, section: Mapping[str, Any], where: str = "recipe") -> LabelSettings:
        """The settings of a recipe's ``[label]`` section (missing keys take the defaults; a recipe
        without ``convention`` is the hd convention, as recipes were before conventions existed).

        Raises:
            HdLabelsError: an unknown key or a wrong value, naming ``where`` and the key.
        """
        return from_mapping(
            cls, section, where, "label", HdLabelsError, convention=RECIPE_CONVENTION_BEFORE_CONVENTIONS
        )

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
