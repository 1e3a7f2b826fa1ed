"""A rectangle of map coordinates on a DTM (``hd detect --window XMIN,YMIN,XMAX,YMAX``) and the cells it covers.

The window is given in the DTM's CRS, in metres (the map coordinates a GIS shows; local metres for
a DTM without CRS). Its cells are the grid cells it overlaps: each edge is snapped outwards to the
next cell edge (an edge inside a cell takes that cell; an edge on a cell edge stays there), so the
cells cover the whole window; then they are clipped to the grid (:func:`window_cells`). A window
that overlaps no cell of the grid is refused with one line naming the grid's bounds.

The text form is four finite numbers separated by commas, ``xmin < xmax`` and ``ymin < ymax``
(:func:`parse_map_window`; on the command line through the click type :data:`MAP_WINDOW`, so a
malformed window is a usage error before anything is read).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import click

from lidarsim.errors import LidarsimError, TerrainError

# Slack (cells) when a window edge is snapped to a cell edge: an edge within 1e-9 cell of a cell
# edge is on it (map coordinates written with a few decimals round-trip through the geotransform).
_EDGE_EPS = 1e-9
FORM = "XMIN,YMIN,XMAX,YMAX"


class MapWindow(NamedTuple):
    """A north-up rectangle of map coordinates, metres in the DTM's CRS: x from ``xmin`` to ``xmax``
    (east), y from ``ymin`` to ``ymax`` (north)."""

    xmin: float
    ymin: float
    xmax: float
    ymax: float

    def text(self) -> str:
        """The window as the command line writes it (``1000,2000,1150,2150``)."""
        return ",".join(f"{v:.10g}" for v in self)

    def problem(self) -> str | None:
        """What is wrong with the window (not four finite numbers, or not ordered), None when nothing is."""
        if not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in self):
            return f"a window {FORM} of four finite numbers (map metres)"
        if not (self.xmin < self.xmax and self.ymin < self.ymax):
            return f"a window {FORM} with XMIN < XMAX and YMIN < YMAX (map metres)"
        return None

    @classmethod
    def of(cls, value: MapWindow | tuple[float, ...] | list[float] | str) -> MapWindow:
        """A window from its text (``"xmin,ymin,xmax,ymax"``) or four numbers, checked.

        Raises:
            LidarsimError: not four finite numbers, or not ordered.
        """
        if isinstance(value, str):
            return parse_map_window(value)
        if isinstance(value, MapWindow):
            window = value
        else:
            values = list(value)
            if len(values) != 4:
                raise LidarsimError(f"a window is {FORM} (four numbers, map metres), got {value!r}")
            window = cls(*values)
        problem = window.problem()
        if problem is not None:
            raise LidarsimError(f"the window must be {problem}, got {window.text()}")
        return window


def parse_map_window(text: str) -> MapWindow:
    """The window of ``"xmin,ymin,xmax,ymax"`` (map metres; blanks around the numbers allowed).

    Raises:
        LidarsimError: not four comma-separated finite numbers, or XMIN >= XMAX or YMIN >= YMAX.
    """
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) != 4:
        raise LidarsimError(f"window {text!r} is not {FORM}: give four numbers separated by commas (map metres)")
    values = []
    for part in parts:
        try:
            number = float(part)
        except ValueError as exc:
            raise LidarsimError(f"window {text!r}: {part!r} is not a number ({FORM}, map metres)") from exc
        if not math.isfinite(number):
            raise LidarsimError(f"window {text!r}: {part!r} is not a finite number ({FORM}, map metres)")
        values.append(number)
    window = MapWindow(*values)
    if not window.xmin < window.xmax:
        raise LidarsimError(f"window {text!r}: XMIN {parts[0]} must be less than XMAX {parts[2]} ({FORM})")
    if not window.ymin < window.ymax:
        raise LidarsimError(f"window {text!r}: YMIN {parts[1]} must be less than YMAX {parts[3]} ({FORM})")
    return window


class MapWindowType(click.ParamType):
    """The click type of a window option: its text parsed and checked (:func:`parse_map_window`)."""

    name = "window"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> MapWindow:
        if isinstance(value, MapWindow):
            return value
        try:
            return parse_map_window(value)
        except LidarsimError as exc:
            self.fail(str(exc), param, ctx)


MAP_WINDOW = MapWindowType()


def grid_bounds(transform: tuple[float, ...], rows: int, cols: int) -> MapWindow:
    """The map rectangle (metres) covered by a north-up grid of ``rows x cols`` cells with the GDAL
    geotransform ``transform`` = (a, b, c, d, e, f)."""
    a, _, c, _, e, f = (float(v) for v in transform[:6])
    xs, ys = (c, c + a * cols), (f, f + e * rows)
    return MapWindow(min(xs), min(ys), max(xs), max(ys))


def bounds_text(bounds: MapWindow) -> str:
    """``x 1000 to 1400, y 1600 to 2000 (map metres)``."""
    return f"x {bounds.xmin:.10g} to {bounds.xmax:.10g}, y {bounds.ymin:.10g} to {bounds.ymax:.10g} (map metres)"


@dataclass(frozen=True)
class WindowCells:
    """The cells of a window on a grid: rows ``row0 .. row0 + rows - 1``, columns ``col0 .. col0 + cols - 1``;
    ``clipped`` when the window reached past the grid and was cut to it."""

    row0: int
    col0: int
    rows: int
    cols: int
    clipped: bool = False

    def bounds(self, transform: tuple[float, ...]) -> MapWindow:
        """The map rectangle (metres) these cells cover on the grid of ``transform``."""
        a, _, c, _, e, f = (float(v) for v in transform[:6])
        shifted = (a, 0.0, c + a * self.col0, 0.0, e, f + e * self.row0)
        return grid_bounds(shifted, self.rows, self.cols)

    def transform(self, transform: tuple[float, ...]) -> tuple[float, float, float, float, float, float]:
        """The GDAL geotransform of the window's own grid (its top-left cell is (0, 0))."""
        a, _, c, _, e, f = (float(v) for v in transform[:6])
        return (a, 0.0, c + a * self.col0, 0.0, e, f + e * self.row0)


def window_cells(window: MapWindow, transform: tuple[float, ...], rows: int, cols: int, name: str) -> WindowCells:
    """The cells of the grid (``rows x cols`` cells, north-up GDAL geotransform ``transform``) that
    ``window`` overlaps, its edges snapped outwards to cell edges and clipped to the grid.

    Raises:
        TerrainError: the window overlaps no cell of the grid (the message names ``name`` and its bounds).
    """
    a, _, c, _, e, f = (float(v) for v in transform[:6])
    u = sorted(((window.xmin - c) / a, (window.xmax - c) / a))
    v = sorted(((window.ymin - f) / e, (window.ymax - f) / e))
    c0, c1 = math.floor(u[0] + _EDGE_EPS), math.ceil(u[1] - _EDGE_EPS)
    r0, r1 = math.floor(v[0] + _EDGE_EPS), math.ceil(v[1] - _EDGE_EPS)
    c1, r1 = max(c1, c0 + 1), max(r1, r0 + 1)  # a window narrower than a cell, on a cell edge
    cc0, cc1, rr0, rr1 = max(c0, 0), min(c1, cols), max(r0, 0), min(r1, rows)
    if cc0 >= cc1 or rr0 >= rr1:
        raise TerrainError(
            f"the window {window.text()} lies outside {name}, whose bounds are "
            f"{bounds_text(grid_bounds(transform, rows, cols))}; give a window inside them"
        )
    clipped = (cc0, cc1, rr0, rr1) != (c0, c1, r0, r1)
    return WindowCells(rr0, cc0, rr1 - rr0, cc1 - cc0, clipped)
