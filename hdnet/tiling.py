"""Overlapping tiles of the network's training size over a grid of any size, stitched by centre crops.

Along each axis of ``n`` cells, tiles of ``tile`` cells overlap by at least ``overlap`` cells: with
``k = ceil((n - tile) / (tile - overlap)) + 1`` tiles, tile ``i`` starts at
``round(i * (n - tile) / (k - 1))``, so the first tile starts at 0, the last ends at ``n`` and the
overlaps are spread evenly (never below ``overlap``). A grid smaller than one tile gets one tile
starting at 0 that reaches past the end (the reader fills those cells with NaN).

Stitching: every grid cell is *owned* by exactly one tile. Between two neighbouring tiles the cut is
the middle of their overlap, so a cell is at least ``overlap // 2`` cells from the edges of the tile
that owns it, except at the grid's own edges. The 2-D plan is the product of the two axes; it is
walked one row of tiles (a *strip*) at a time, so a caller holds one strip of outputs, never the grid.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass

from hdnet.detect_json import TilingJson
from hdnet.errors import HdNetError


@dataclass(frozen=True)
class AxisTiles:
    """Tiles along one axis: ``starts[i]`` is the first cell of tile i, ``owned[i]`` = [lo, hi) the cells it owns."""

    n: int
    tile: int
    starts: tuple[int, ...]
    owned: tuple[tuple[int, int], ...]


def axis_tiles(n: int, tile: int, overlap: int) -> AxisTiles:
    """Tiles of ``tile`` cells over ``n`` cells overlapping by at least ``overlap`` cells (see the module docstring)."""
    for name, value in (("grid size", n), ("tile size", tile)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise HdNetError(f"the {name} must be a positive number of cells, got {value!r}.")
    if isinstance(overlap, bool) or not isinstance(overlap, int) or not 0 <= overlap < tile:
        raise HdNetError(f"the tile overlap must be in [0, {tile - 1}] cells for {tile}-cell tiles, got {overlap!r}.")
    if n <= tile:
        return AxisTiles(n, tile, (0,), ((0, n),))
    k = math.ceil((n - tile) / (tile - overlap)) + 1
    starts = tuple(int(round(i * (n - tile) / (k - 1))) for i in range(k))
    cuts = [(a + b + tile) // 2 for a, b in itertools.pairwise(starts)]
    bounds = [0, *cuts, n]
    return AxisTiles(n, tile, starts, tuple((bounds[i], bounds[i + 1]) for i in range(k)))


@dataclass(frozen=True)
class Tile:
    """One tile: its window in the grid (top-left ``row0, col0``, ``rows x cols`` cells) and the cells it owns.

    ``own_rows`` / ``own_cols`` are [lo, hi) grid indices; ``crop`` selects them inside the tile's array.
    """

    row0: int
    col0: int
    rows: int
    cols: int
    own_rows: tuple[int, int]
    own_cols: tuple[int, int]

    @property
    def crop(self) -> tuple[slice, slice]:
        """Slices of the owned cells in the tile's own (rows x cols) array."""
        (r0, r1), (c0, c1) = self.own_rows, self.own_cols
        return slice(r0 - self.row0, r1 - self.row0), slice(c0 - self.col0, c1 - self.col0)


@dataclass(frozen=True)
class TilePlan:
    """Tiles of ``tile_shape`` over a grid of ``shape`` (rows, cols) overlapping by at least ``overlap`` cells."""

    shape: tuple[int, int]
    tile_shape: tuple[int, int]
    overlap: int
    rows: AxisTiles
    cols: AxisTiles

    @classmethod
    def make(cls, shape: tuple[int, int], tile_shape: tuple[int, int], overlap: int) -> TilePlan:
        rows = axis_tiles(int(shape[0]), int(tile_shape[0]), overlap)
        cols = axis_tiles(int(shape[1]), int(tile_shape[1]), overlap)
        return cls((rows.n, cols.n), (rows.tile, cols.tile), overlap, rows, cols)

    @property
    def n_tiles(self) -> int:
        return len(self.rows.starts) * len(self.cols.starts)

    def strips(self) -> Iterator[tuple[tuple[int, int], list[Tile]]]:
        """Per row of tiles: the grid rows it owns ([lo, hi)) and its tiles, west to east."""
        for r0, own_r in zip(self.rows.starts, self.rows.owned, strict=True):
            tiles = [
                Tile(r0, c0, self.rows.tile, self.cols.tile, own_r, own_c)
                for c0, own_c in zip(self.cols.starts, self.cols.owned, strict=True)
            ]
            yield own_r, tiles

    def to_dict(self) -> TilingJson:
        """Plain summary for reports: tile size, overlap, tile counts."""
        return {
            "tile_px": list(self.tile_shape),
            "min_overlap_px": self.overlap,
            "tiles": [len(self.rows.starts), len(self.cols.starts)],
            "n_tiles": self.n_tiles,
        }
