"""The compiled rock stamping and bilinear resampling equal their NumPy forms bit for bit (the
published terrains' sha256 rest on them), and a scan's mesh cut to what its rays can reach, or to
the triangles they can hit first, casts the ranges of the whole tile's mesh bit for bit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rocks_numpy import resample_bilinear_numpy, stamp_rocks_numpy

from lidarsim.base_relief import resample_bilinear
from lidarsim.noise import scan_directions
from lidarsim.procedural import stamp_rocks
from lidarsim.reach import candidate_triangles
from lidarsim.scan import TileScene
from lidarsim.sensor import SensorConfig, corner_directions, sensor_attitude
from lidarsim.terrain import DTM
from tests.geotiff import write_geotiff


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_stamped_rocks_equal_the_numpy_form_bit_for_bit(dtype):
    rng = np.random.default_rng(3)
    heights = rng.normal(0.0, 0.3, (90, 70)).astype(dtype)
    heights[10:14, 20:30] = np.nan  # a hole: NaN stays NaN, rocks on it stay NaN
    centres = rng.random((400, 2)) * np.array([70 * 0.5, 90 * 0.5]) + np.array([-1.0, -1.0])  # some off the grid
    diameters = rng.uniform(0.1, 3.0, 400)
    expected = heights.copy()
    stamp_rocks_numpy(expected, 0.5, centres, diameters, 0.5)
    stamp_rocks(heights, 0.5, centres, diameters, 0.5)
    assert heights.dtype == dtype
    assert np.array_equal(heights.view(np.uint8), expected.view(np.uint8))


def test_one_rock_is_the_half_ellipsoid_by_hand():
    heights = np.zeros((9, 9))
    stamp_rocks(heights, 1.0, np.array([[4.5, 4.5]]), np.array([4.0]), 0.25)  # R = 2 m, H = 1 m on cell (4, 4)
    assert heights[4, 4] == 1.0 and heights[4, 5] == pytest.approx(np.sqrt(1.0 - 0.25))
    assert heights[4, 6] == 0.0 and heights[0, 0] == 0.0  # r = R: outside


def test_a_non_contiguous_heights_array_is_refused():
    heights = np.zeros((10, 10))[:, :5]
    with pytest.raises(ValueError, match="contiguous"):
        stamp_rocks(heights, 1.0, np.array([[2.0, 2.0]]), np.array([1.0]), 0.5)


@pytest.mark.parametrize(
    ("src_shape", "src_spacing", "spacing", "shape"),
    [
        ((40, 50), (3.69, 3.69), 0.5, (290, 365)),
        ((7, 5), (2.0, 1.0), 0.25, (28, 40)),
        ((2, 2), (1.0, 1.0), 0.5, (4, 4)),
    ],
)
def test_resampling_equals_the_numpy_form_bit_for_bit(src_shape, src_spacing, spacing, shape):
    rng = np.random.default_rng(5)
    values = rng.normal(-2500.0, 20.0, src_shape).astype(np.float32)
    values[0, 0] = np.nan
    if src_shape[0] > 3:
        values[3, 2] = np.nan
    got = resample_bilinear(values, src_spacing, spacing, shape)
    expected = resample_bilinear_numpy(values, src_spacing, spacing, shape)
    assert got.dtype == np.float64 and np.array_equal(got.view(np.uint8), expected.view(np.uint8))


def test_resampling_a_plane_gives_the_plane_by_hand():
    # z = x on centres 0.5, 1.5, 2.5 (1 m cells) sampled at 0.5 m cells: centres 0.25 .. 2.75, clamped at the edges
    values = np.tile(np.array([0.5, 1.5, 2.5]), (3, 1))
    got = resample_bilinear(values, (1.0, 1.0), 0.5, (6, 6))
    assert np.allclose(got[0], [0.5, 0.75, 1.25, 1.75, 2.25, 2.5])


def _rough_dtm(path: Path) -> Path:
    rng = np.random.default_rng(11)
    heights = rng.normal(0.0, 0.4, (400, 400)).cumsum(axis=0) * 0.05 + rng.normal(0.0, 0.05, (400, 400))
    heights[150:160, 40:60] = np.nan  # a hole under a scan: rays through it miss in both meshes
    write_geotiff(path, heights.astype(np.float32), 0.5, origin_xy=(1000.0, 2000.0))
    return path


@pytest.mark.parametrize("tilt_deg", [0.0, 20.0])
def test_a_scan_cast_against_its_reach_equals_the_whole_window_bit_for_bit(tmp_path, tilt_deg):
    sensor = SensorConfig(rows=48, cols=48)
    with DTM.open(_rough_dtm(tmp_path / "rough.tif")) as dtm:
        whole = TileScene(dtm, (1100.0, 1900.0), 95.0)
        whole.focus(whole.full_window)
        cut = TileScene(dtm, (1100.0, 1900.0), 95.0)
        for x, y in ((1080.0, 1920.0), (1115.0, 1880.0), (1020.0, 1930.0)):
            attitude = sensor_attitude(tilt_deg)
            origin = np.array([[x, y, 120.0]])
            window = cut.reach(origin, corner_directions(sensor, attitude)[None])
            cut.focus(window)
            d = scan_directions(sensor, attitude)[None]
            expected = whole.cast(origin, d)
            got = cut.cast(origin, d)
            assert cut.window == window  # the corner rays' reach holds every ray's: no other scene was built
            assert cut.n_triangles < whole.n_triangles / 2
            assert np.array_equal(got.view(np.uint32), expected.view(np.uint32))
            assert np.isnan(got).any() == np.isnan(expected).any()


def test_scans_that_overlap_share_one_mesh_and_a_dense_tile_takes_the_whole_window(tmp_path):
    with DTM.open(_rough_dtm(tmp_path / "rough.tif")) as dtm:
        scene = TileScene(dtm, (1100.0, 1900.0), 95.0)
        rows, cols = scene.heights.shape
        a, b, far = (10, 50, 10, 50), (12, 52, 14, 54), (100, 140, 100, 140)
        assert scene.plan([a, b, far]) == [((10, 52, 10, 54), [0, 1]), (far, [2])]
        # windows that together hold as many cells as the tile: one mesh of the whole tile
        quarters = [(0, rows // 2 + 1, 0, cols), (rows // 2 - 1, rows, 0, cols)]
        assert scene.plan(quarters) == [((0, rows, 0, cols), [0, 1])]


def test_a_ray_over_a_plane_marks_the_triangle_it_hits_by_hand():
    heights = np.zeros((20, 20))  # vertices at x = 0, 0.5, ..; y = 10, 9.5, .. (row 0 north)
    x, y = np.arange(20) * 0.5, 10.0 - np.arange(20) * 0.5
    d = np.array([[0.01, 0.02, -1.0]]) / np.linalg.norm([0.01, 0.02, -1.0])
    marked = candidate_triangles(heights, x, y, np.array([[2.03, -4.9, 500.0]]), d)
    assert marked is not None
    upper, lower = marked
    # it meets z = 0 at x = 7.03, y = 5.1: block (9, 14), p = 0.06, q = 0.8: the upper-left triangle
    assert np.argwhere(upper).tolist() == [[9, 14]] and not lower.any()
    # a ray that does not descend may hit anything: no culling
    assert candidate_triangles(heights, x, y, np.array([[2.0, 5.0, 1.0]]), np.array([[0.0, 0.6, 0.8]])) is None


def test_only_the_hit_triangles_cast_the_whole_meshes_ranges_bit_for_bit(tmp_path):
    sensor = SensorConfig(rows=64, cols=64)
    with DTM.open(_rough_dtm(tmp_path / "rough.tif")) as dtm:
        whole = TileScene(dtm, (1100.0, 1900.0), 95.0)
        whole.focus(whole.full_window)
        cut = TileScene(dtm, (1100.0, 1900.0), 95.0)
        for x, y, tilt in ((1080.0, 1920.0, 0.0), (1115.0, 1880.0, 15.0), (1020.0, 1930.0, 0.0)):
            attitude = sensor_attitude(tilt)
            origin = np.array([[x, y, 120.0]])
            cut.focus(cut.reach(origin, corner_directions(sensor, attitude)[None]), only_hits=True)
            d = scan_directions(sensor, attitude)[None]
            got = cut.cast(origin, d)
            assert 0 < cut.n_triangles < 2.5 * 64 * 64  # about one triangle per ray (and the hole's misses)
            assert np.array_equal(got.view(np.uint32), whole.cast(origin, d).view(np.uint32))
