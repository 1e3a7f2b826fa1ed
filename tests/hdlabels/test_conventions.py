"""The label conventions as objects: one protocol, the rules of each, and no convention compared by name."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from hdlabels import defaults
from hdlabels.conventions import CONVENTIONS, HdConvention, PaperConvention, convention
from hdlabels.errors import HdLabelsError
from hdlabels.hd_geometry import hd_geometry
from hdlabels.lander import Lander, geometry
from hdlabels.paper_geometry import paper_geometry
from hdlabels.store import DemSpec, labeling_name

ROOT = Path(__file__).resolve().parents[2]


def test_each_name_gives_its_object_and_an_unknown_name_is_refused() -> None:
    assert sorted(CONVENTIONS) == sorted(defaults.CONVENTIONS)
    assert isinstance(convention("paper"), PaperConvention) and isinstance(convention("hd"), HdConvention)
    assert Lander().rules is convention("paper") and Lander(convention="hd").rules is convention("hd")
    for bad in ("Paper", "", None, 1):
        with pytest.raises(HdLabelsError, match="convention must be 'paper' or 'hd'") as info:
            convention(bad)
        assert "\n" not in str(info.value)


def test_the_rules_of_each_convention() -> None:
    paper, hd = convention("paper"), convention("hd")
    assert (paper.baseline_combine, paper.gridding) == ("product", "nearest")
    assert (hd.baseline_combine, hd.gridding) == ("min", "linear")
    assert paper.noise_scale_by_cos and not hd.noise_scale_by_cos
    assert paper.baseline_slope_inclusive and not hd.baseline_slope_inclusive
    assert not paper.has_yaws and hd.has_yaws
    assert hd.baseline_from_maps("min") and not hd.baseline_from_maps("product")
    assert not paper.baseline_from_maps("min") and not paper.baseline_from_maps("product")
    assert Lander().baseline_combine == "product" and Lander(convention="hd").baseline_combine == "min"
    assert DemSpec.for_convention("paper").gridding == "nearest" and DemSpec.for_convention("hd").gridding == "linear"


def test_the_paper_convention_refuses_a_yaw_count() -> None:
    with pytest.raises(HdLabelsError, match="n_yaws applies to the hd convention only"):
        Lander(n_yaws=6)
    assert Lander(convention="hd", n_yaws=6).n_yaws == 6


def test_geometry_comes_from_the_convention() -> None:
    paper, hd = Lander(), Lander(convention="hd")
    assert geometry(paper, 1.0) is paper_geometry(paper, 1.0)
    hd_tables = hd_geometry(hd, 1.0)
    assert np.array_equal(geometry(hd, 1.0).node_di, hd_tables.node_di)
    assert geometry(paper, 1.0).n_yaws == 7 and geometry(hd, 1.0).n_yaws == 8  # 7 distinct squares; 8 yaws


@pytest.mark.parametrize("lander", [Lander(), Lander(convention="hd", layout="triangle", n_yaws=6, count_holes=True)])
def test_lander_attrs_round_trip_through_the_convention(lander: Lander) -> None:
    attrs = lander.to_attrs()
    assert ("n_yaws" in attrs) == lander.rules.has_yaws
    assert ("orientation_step_deg" in attrs) == (not lander.rules.has_yaws)
    assert Lander.from_attrs(attrs) == lander


def test_labelling_names_are_unchanged() -> None:
    dem = DemSpec.for_convention("paper")
    assert labeling_name(Lander(), dem) == "paper-square-d10m-pad1m-slope10deg-rough0.2m-product-nearest-dem100x100at1m"
    hd_dem = DemSpec.for_convention("hd")
    assert (
        labeling_name(Lander(convention="hd"), hd_dem) == "square-d10m-pad1m-slope10deg-rough0.2m-yaws8-dem100x100at1m"
    )
    other = Lander(convention="hd", baseline_combine="product", count_holes=True)
    assert labeling_name(other, DemSpec(100, 100, 1.0, "nearest")) == (
        "square-d10m-pad1m-slope10deg-rough0.2m-yaws8-holes-product-nearest-dem100x100at1m"
    )


def test_no_module_compares_a_convention_name() -> None:
    """Every rule that differs between the conventions is asked of the convention object."""
    pattern = re.compile(r"""convention\s*[!=]=|[!=]=\s*["'](paper|hd)["']|["'](paper|hd)["']\s*[!=]=""")
    found = [
        f"{path.relative_to(ROOT)}:{n}"
        for package in ("lidarsim", "hdlabels", "hdnet")
        for path in sorted((ROOT / package).glob("*.py"))
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if pattern.search(line)
    ]
    assert found == []
    assert pattern.search('if lander.convention == "paper":') and pattern.search("x != 'hd'")
