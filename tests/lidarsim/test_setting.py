"""hdcore.setting: one description per setting gives the checks, the recipe reading and the options."""

from __future__ import annotations

from dataclasses import dataclass

import click
import pytest
from click.testing import CliRunner

from hdcore.bounds import Bound
from hdcore.setting import (
    SettingsCommand,
    check,
    click_options,
    described_as,
    described_fields,
    from_mapping,
    setting,
)
from lidarsim.errors import LidarsimError
from lidarsim.map_window import MAP_WINDOW, MapWindow


@dataclass(frozen=True)
class Toy:
    """A settings class of each kind."""

    count: int = setting(3, "Things counted", bound=Bound(1, 10, integer=True))
    width_m: float = setting(2.5, "Width", unit="metres", bound=Bound(0.0, low_open=True))
    levels_m: tuple[float, ...] = setting((0.5,), "Levels; repeat it", unit="metres", bound=Bound(0.0))
    shape: str = setting("square", "Shape", choices=("square", "triangle"))
    holes: bool = setting(False, "Count the holes")
    yaws: int | None = setting(None, "Yaws (default: the shape's)", bound=Bound(1, 360, integer=True))

    def __post_init__(self) -> None:
        check(self, LidarsimError)


@pytest.mark.parametrize(
    ("field", "value", "needle"),
    [
        ("count", True, "--count must be an integer"),  # a bool is not a count
        ("count", 2.0, "--count must be an integer"),
        ("count", 11, r"in \[1, 10\]"),
        ("width_m", float("nan"), "finite number"),
        ("width_m", 0.0, r"in \(0, inf\)"),
        ("levels_m", (0.5, -1.0), "--levels-m must be a finite number in"),
        ("shape", "circle", "one of square, triangle"),
        ("holes", 1, "true or false"),
        ("yaws", 0, "--yaws"),
    ],
)
def test_a_wrong_value_is_refused_naming_its_option(field, value, needle):
    with pytest.raises(LidarsimError, match=needle):
        Toy(**{field: value})


@dataclass(frozen=True)
class Framed:
    """A setting whose kind is a value type of its own (it says what is wrong with it)."""

    window: MapWindow | None = setting(None, "Window", unit="metres", kind=MapWindow, click_type=MAP_WINDOW)

    def __post_init__(self) -> None:
        check(self, LidarsimError)


@pytest.mark.parametrize(
    ("value", "needle"),
    [
        ((1.0, 2.0, 3.0, 4.0), r"--window must be a MapWindow, got \(1.0"),  # a plain tuple is not one
        (MapWindow(3.0, 2.0, 1.0, 4.0), "--window must be a window XMIN,YMIN,XMAX,YMAX with XMIN < XMAX"),
        (MapWindow(1.0, 2.0, 3.0, float("nan")), "of four finite numbers"),
    ],
)
def test_a_value_type_of_its_own_is_checked_by_its_problem(value, needle):
    assert Framed().window is None and Framed(MapWindow(1.0, 2.0, 3.0, 4.0)).window == (1.0, 2.0, 3.0, 4.0)
    with pytest.raises(LidarsimError, match=needle):
        Framed(window=value)


def test_right_values_pass_and_none_is_the_default_of_an_optional_setting():
    toy = Toy(count=10, width_m=1, levels_m=(0.0, 2.0), shape="triangle", holes=True)
    assert toy.count == 10 and toy.yaws is None


def test_a_recipe_section_is_read_one_way():
    toy = from_mapping(Toy, {"width_m": 3, "levels_m": [1, 2]}, "r.toml", "toy", LidarsimError, shape="triangle")
    assert toy.width_m == 3.0 and isinstance(toy.width_m, float)  # a TOML integer where a number is meant
    assert toy.levels_m == (1.0, 2.0) and toy.shape == "triangle"
    with pytest.raises(LidarsimError, match=r"r.toml: unknown \[toy\] key\(s\) \['depth'\]"):
        from_mapping(Toy, {"depth": 1}, "r.toml", "toy", LidarsimError)
    with pytest.raises(LidarsimError, match=r"r.toml: \[toy\] holes = 'yes' is not true or false"):
        from_mapping(Toy, {"holes": "yes"}, "r.toml", "toy", LidarsimError)


def _command(lazy: bool) -> click.Command:
    def run(**settings: object) -> None:
        click.echo(repr(Toy(**settings)))  # type: ignore[arg-type]  # the options are Toy's fields

    if lazy:
        return SettingsCommand("toy", callback=run, settings=(f"{__name__}:Toy",))
    return click.command("toy")(click_options(Toy)(run))


@pytest.mark.parametrize("lazy", [False, True], ids=["decorator", "lazy"])
def test_the_options_carry_help_unit_default_and_range(lazy):
    command = _command(lazy)
    names = [p.name for p in command.params]
    assert names[:6] == ["count", "width_m", "levels_m", "shape", "holes", "yaws"]
    text = CliRunner().invoke(command, ["--help"]).output
    assert "Width, metres." in text and "x>0.0" in text and "1<=x<=10" in text and "[default: 3;" in text
    refused = CliRunner().invoke(command, ["--count", "11"])
    assert refused.exit_code == 2 and "1<=x<=10" in refused.output
    ran = CliRunner().invoke(command, ["--levels-m", "1", "--levels-m", "2", "--holes"])
    assert ran.exit_code == 0, ran.output
    assert "levels_m=(1.0, 2.0)" in ran.output and "holes=True" in ran.output


def test_a_field_described_as_another_shares_its_description():
    @dataclass(frozen=True)
    class Flat:
        size: int = described_as(Toy, "count", flag="--size")

    ((field, described),) = described_fields(Flat)
    assert field.default == 3 and described.bound == Bound(1, 10, integer=True)
    assert described.help == "Things counted" and described.option_name("size") == "--size"
