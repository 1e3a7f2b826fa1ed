"""lidarsim.map_window: the window's text, its cells on a grid (snapped outwards, clipped), its refusals."""

from __future__ import annotations

import click
import pytest
from click.testing import CliRunner

from lidarsim.errors import LidarsimError, TerrainError
from lidarsim.map_window import MAP_WINDOW, MapWindow, WindowCells, grid_bounds, parse_map_window, window_cells

# 20 rows x 30 columns of 2 m cells, top-left corner (1000, 2000): x 1000..1060, y 1960..2000.
GRID = (2.0, 0.0, 1000.0, 0.0, -2.0, 2000.0)


def test_the_text_form_and_its_refusals():
    assert parse_map_window(" 1000, 1960.5 ,1060,2000") == MapWindow(1000.0, 1960.5, 1060.0, 2000.0)
    assert MapWindow(1000.0, 1960.5, 1060.0, 2000.0).text() == "1000,1960.5,1060,2000"
    for text, needle in [
        ("1,2,3", "give four numbers separated by commas"),
        ("1,2,3,4,5", "give four numbers"),
        ("1,2,x,4", "'x' is not a number"),
        ("1,nan,3,4", "'nan' is not a finite number"),
        ("3,2,1,4", "XMIN 3 must be less than XMAX 1"),
        ("1,4,3,4", "YMIN 4 must be less than YMAX 4"),
    ]:
        with pytest.raises(LidarsimError, match=needle):
            parse_map_window(text)
    assert MapWindow.of((1, 2, 3, 4)) == MapWindow(1, 2, 3, 4) and MapWindow.of("1,2,3,4") == (1.0, 2.0, 3.0, 4.0)
    with pytest.raises(LidarsimError, match="four numbers"):
        MapWindow.of((1, 2, 3))
    with pytest.raises(LidarsimError, match="XMIN < XMAX"):
        MapWindow.of((3, 2, 1, 4))
    assert (
        MapWindow(1, 2, float("inf"), 4).problem() == "a window XMIN,YMIN,XMAX,YMAX of four finite numbers (map metres)"
    )


def test_the_click_type_refuses_a_bad_window_as_a_usage_error():
    @click.command()
    @click.option("--window", type=MAP_WINDOW)
    def show(window):
        click.echo(repr(window))

    ok = CliRunner().invoke(show, ["--window", "1,2,3,4"])
    assert ok.exit_code == 0 and ok.output.strip() == "MapWindow(xmin=1.0, ymin=2.0, xmax=3.0, ymax=4.0)"
    bad = CliRunner().invoke(show, ["--window", "3,2,1,4"])
    assert bad.exit_code == 2 and "Invalid value for '--window'" in bad.output and "XMIN 3" in bad.output


@pytest.mark.parametrize(
    ("window", "cells"),
    [
        ((1000.0, 1960.0, 1060.0, 2000.0), WindowCells(0, 0, 20, 30)),  # the whole grid, edges on cell edges
        ((1004.0, 1970.0, 1010.0, 1996.0), WindowCells(2, 2, 13, 3)),  # x 1004..1010: columns 2..4
        ((1004.1, 1970.1, 1009.9, 1995.9), WindowCells(2, 2, 13, 3)),  # edges inside cells: snapped outwards
        ((1003.9, 1969.9, 1010.1, 1996.1), WindowCells(1, 1, 15, 5)),  # ... to the next cell edge
        ((1004.0 + 1e-12, 1970.0, 1010.0 - 1e-12, 1996.0), WindowCells(2, 2, 13, 3)),  # rounding is no new cell
        ((1005.0, 1975.0, 1005.5, 1975.5), WindowCells(12, 2, 1, 1)),  # inside one cell: that cell
        ((990.0, 1990.0, 1006.0, 2010.0), WindowCells(0, 0, 5, 3, clipped=True)),  # past the north-west corner
        ((1050.0, 1900.0, 1100.0, 1965.0), WindowCells(17, 25, 3, 5, clipped=True)),  # past the south-east corner
    ],
)
def test_window_cells_by_hand(window, cells):
    got = window_cells(MapWindow(*window), GRID, 20, 30, "grid.tif")
    assert got == cells
    bounds = got.bounds(GRID)  # the snapped window holds the asked one, or all of the grid it overlaps
    assert bounds.xmin <= max(window[0], 1000.0) + 1e-9 and bounds.xmax >= min(window[2], 1060.0) - 1e-9
    assert bounds.ymin <= max(window[1], 1960.0) + 1e-9 and bounds.ymax >= min(window[3], 2000.0) - 1e-9
    a, _, c, _, e, f = got.transform(GRID)
    assert (a, e) == (2.0, -2.0) and (c, f) == (1000.0 + 2.0 * got.col0, 2000.0 - 2.0 * got.row0)


def test_a_window_outside_the_grid_is_refused_naming_its_bounds():
    assert grid_bounds(GRID, 20, 30) == MapWindow(1000.0, 1960.0, 1060.0, 2000.0)
    for window in [(0.0, 0.0, 10.0, 10.0), (1060.0, 1960.0, 1070.0, 2000.0), (1000.0, 2000.0, 1060.0, 2001.0)]:
        with pytest.raises(
            TerrainError, match=r"lies outside grid.tif, whose bounds are x 1000 to 1060, y 1960 to 2000"
        ):
            window_cells(MapWindow(*window), GRID, 20, 30, "grid.tif")


def test_a_south_up_grid_maps_y_the_other_way():
    south_up = (2.0, 0.0, 1000.0, 0.0, 2.0, 1960.0)  # row 0 is the south: y 1960..2000 again
    assert window_cells(MapWindow(1004.0, 1970.0, 1010.0, 1996.0), south_up, 20, 30, "s.tif") == WindowCells(
        5, 2, 13, 3
    )
