"""lidarsim.upsampled: a DTM interpolated window by window equals the whole interpolated grid, cell for cell."""

from __future__ import annotations

import numpy as np
import pytest

from lidarsim.base_relief import resample_bilinear
from lidarsim.map_window import WindowCells
from lidarsim.procedural import write_geotiff
from lidarsim.upsampled import UpsampledDTM


@pytest.fixture
def coarse(tmp_path):
    """A 3.5 m grid of 30 x 40 cells: a tilted plane with bumps, two nodata cells."""
    rng = np.random.default_rng(7)
    r, c = np.mgrid[:30, :40]
    z = 0.2 * r - 0.1 * c + rng.normal(0.0, 0.3, (30, 40))
    z[5, 7] = np.nan
    z[22, 31] = np.nan
    path = tmp_path / "coarse.tif"
    write_geotiff(path, z, 3.5, origin_xy=(1000.0, 5000.0))
    return path, z.astype(np.float32).astype(np.float64)  # as the file holds them


def whole(z: np.ndarray, source: WindowCells, spacing_m: float) -> np.ndarray:
    """The whole grid as the in-memory interpolation made it (float64, stored as float32)."""
    part = z[source.row0 : source.row0 + source.rows, source.col0 : source.col0 + source.cols]
    shape = (int(source.rows * 3.5 / spacing_m + 1e-9), int(source.cols * 3.5 / spacing_m + 1e-9))
    return resample_bilinear(part, (3.5, 3.5), spacing_m, shape).astype(np.float32).astype(np.float64)


@pytest.mark.parametrize("source", [WindowCells(0, 0, 30, 40), WindowCells(3, 5, 20, 25)])
def test_windows_are_the_whole_grids_cells_bit_for_bit(coarse, source):
    path, z = coarse
    dtm = UpsampledDTM(path, source, 1.0)
    ref = whole(z, source, 1.0)
    assert (dtm.info.rows, dtm.info.cols) == ref.shape and dtm.info.spacing_m == (1.0, 1.0)
    assert dtm.info.transform == (1.0, 0.0, 1000.0 + 3.5 * source.col0, 0.0, -1.0, 5000.0 - 3.5 * source.row0)
    np.testing.assert_array_equal(dtm.read(0, 0, *ref.shape), ref)  # NaN where NaN, equal elsewhere
    np.testing.assert_array_equal(dtm.read(17, 29, 13, 11), ref[17:30, 29:40])
    edge = dtm.read(-3, ref.shape[1] - 4, 6, 9)  # past the grid: NaN there
    assert np.isnan(edge[:3]).all() and np.isnan(edge[:, 4:]).all()
    np.testing.assert_array_equal(edge[3:, :4], ref[:3, -4:])
    np.testing.assert_array_equal(dtm.valid_cells(), np.isfinite(ref))


def test_a_nodata_cell_spreads_to_the_cells_interpolating_from_it(coarse):
    path, _ = coarse
    dtm = UpsampledDTM(path, WindowCells(0, 0, 30, 40), 1.0)
    valid = dtm.valid_cells()
    # source cell (5, 7) has its centre at (19.25, 26.25) m: the 1 m cells between the centres around it are NaN
    assert not valid[19, 26] and not valid[17, 23] and valid[10, 10]
    assert 0 < (~valid).sum() < 0.05 * valid.size


def test_the_preview_picks_the_nearest_cells(coarse):
    path, z = coarse
    dtm = UpsampledDTM(path, WindowCells(0, 0, 30, 40), 1.0)
    ref = whole(z, WindowCells(0, 0, 30, 40), 1.0)
    small = dtm.preview(35)
    assert small.shape == (26, 35)
    np.testing.assert_array_equal(small[0, 0], ref[2, 2])  # (0 + 0.5) * 105 / 26 -> row 2; * 140 / 35 -> col 2
    assert dtm.preview(1000).shape == ref.shape
