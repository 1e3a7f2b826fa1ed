"""hdnet.tiling: overlapping tiles cover the grid, every cell owned once, centre crops stitch exactly."""

from __future__ import annotations

import numpy as np
import pytest

from hdnet.errors import HdNetError
from hdnet.tiling import TilePlan, axis_tiles


@pytest.mark.parametrize(
    ("n", "tile", "overlap"),
    [
        (100, 100, 20),
        (101, 100, 20),
        (180, 100, 20),
        (181, 100, 20),
        (359, 100, 20),
        (1000, 100, 20),
        (37, 16, 6),
        (64, 16, 0),
    ],
)
def test_tiles_cover_the_axis_and_own_each_cell_once(n, tile, overlap):
    ax = axis_tiles(n, tile, overlap)
    assert ax.starts[0] == 0 and ax.starts[-1] + tile == n  # first at 0, last ends at the grid's end
    steps = np.diff(ax.starts)
    assert (steps >= 1).all() and (tile - steps >= overlap).all()  # overlaps never below the minimum
    if len(steps):
        assert steps.max() - steps.min() <= 1  # spread evenly
        assert len(ax.starts) == int(np.ceil((n - tile) / (tile - overlap))) + 1  # no spare tile
    owned = np.zeros(n, int)
    for s, (lo, hi) in zip(ax.starts, ax.owned, strict=True):
        assert s <= lo < hi <= s + tile
        owned[lo:hi] += 1
        if lo > 0:
            assert lo - s >= overlap // 2  # at least half the overlap from the tile's inner edges
        if hi < n:
            assert s + tile - hi >= overlap // 2
    assert (owned == 1).all()


def test_a_grid_smaller_than_a_tile_gets_one_tile_reaching_past_it():
    ax = axis_tiles(60, 100, 20)
    assert ax.starts == (0,) and ax.owned == ((0, 60),)


def test_three_tiles_by_hand():
    # 180 cells, tiles of 100 overlapping >= 20: 2 tiles (starts 0, 80), cut in the middle of 80..100.
    ax = axis_tiles(180, 100, 20)
    assert ax.starts == (0, 80) and ax.owned == ((0, 90), (90, 180))
    # 181 cells: 3 tiles, starts 0, 40 (40.5 rounds to 40), 81; cuts (0+40+100)//2 = 70 and (40+81+100)//2 = 110.
    ax = axis_tiles(181, 100, 20)
    assert ax.starts == (0, 40, 81) and ax.owned == ((0, 70), (70, 110), (110, 181))


def test_centre_crops_stitch_a_position_function_exactly():
    """A 'network' that writes each cell's global index; stitching the owned crops restores the grid."""
    shape = (173, 259)
    plan = TilePlan.make(shape, (64, 48), 14)
    truth = np.arange(shape[0] * shape[1]).reshape(shape)
    out = np.full(shape, -1)
    seen_rows = []
    for (r_lo, r_hi), tiles in plan.strips():
        seen_rows.append((r_lo, r_hi))
        for t in tiles:
            window = np.full((t.rows, t.cols), -2)
            r1, c1 = min(t.row0 + t.rows, shape[0]), min(t.col0 + t.cols, shape[1])
            window[: r1 - t.row0, : c1 - t.col0] = truth[t.row0 : r1, t.col0 : c1]
            assert t.own_rows == (r_lo, r_hi)
            out[r_lo:r_hi, t.own_cols[0] : t.own_cols[1]] = window[t.crop]
    np.testing.assert_array_equal(out, truth)
    assert seen_rows[0][0] == 0 and seen_rows[-1][1] == shape[0]
    assert plan.n_tiles == len(plan.rows.starts) * len(plan.cols.starts)
    assert plan.to_dict()["tiles"] == [len(plan.rows.starts), len(plan.cols.starts)]


@pytest.mark.parametrize(
    ("args", "needle"),
    [((0, 100, 20), "grid size"), ((50, 0, 0), "tile size"), ((500, 100, 100), "overlap"), ((500, 100, -1), "overlap")],
)
def test_bad_tilings_are_refused(args, needle):
    with pytest.raises(HdNetError, match=needle):
        axis_tiles(*args)
