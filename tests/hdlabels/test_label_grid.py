"""Gridding organised LiDAR returns into a DEM: planes exactly, terrain as Delaunay does, no extrapolation."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from grid_numpy import bin_nearest
from grid_numpy import grid_points as oracle_grid_points
from scipy.interpolate import LinearNDInterpolator

from hdlabels.errors import HdLabelsError
from hdlabels.grid import bin_points, cell_centres, grid_points

Surface = Callable[[np.ndarray, np.ndarray], np.ndarray]


def nadir_scan(surface: Surface, n: int = 128, fov_deg: float = 12.0, altitude_m: float = 500.0) -> np.ndarray:
    """Organised returns (n, n, 3) of a nadir-looking n x n sensor at ``altitude_m`` over z = surface(x, y).

    Rays through pixel centres (row 0 looks north); the range is found by fixed-point iteration,
    exact for planes. The scan frame's origin is the nadir point, so surface(0, 0) must be 0.
    """
    u = math.tan(math.radians(fov_deg / 2)) * (2 * (np.arange(n) + 0.5) / n - 1)
    dx, dy = np.meshgrid(u, -u)
    d = np.stack([dx, dy, -np.ones_like(dx)], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    origin = np.array([0.0, 0.0, altitude_m])
    t = np.full(dx.shape, altitude_m)
    for _ in range(100):
        p = origin + t[..., None] * d
        t = t + (p[..., 2] - surface(p[..., 0], p[..., 1])) / -d[..., 2]
    return origin + t[..., None] * d


def tilted(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return math.tan(math.radians(8.0)) * (0.6 * x + 0.8 * y)


def hills(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 2.0 * np.sin(x / 7.0) + np.cos(y / 5.0) - 1.0 + 0.3 * np.sin(x * y / 50.0)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_plane_scan_reproduces_the_plane(backend: str) -> None:
    pts = nadir_scan(tilted).astype(np.float32)
    dem = oracle_grid_points(pts, (100, 100), 1.0, backend=backend)
    x, y = cell_centres((100, 100), 1.0)
    xx, yy = np.meshgrid(x, y)
    assert dem.dtype == np.float32 and dem.shape == (100, 100)
    assert not np.isnan(dem).any()  # the ~105 m footprint covers the 100 m DEM
    assert np.max(np.abs(dem - tilted(xx, yy))) < 0.01


def test_cell_centres_north_up_centred() -> None:
    x, y = cell_centres((4, 6), 2.0)
    assert x.tolist() == [-5.0, -3.0, -1.0, 1.0, 3.0, 5.0]
    assert y.tolist() == [3.0, 1.0, -1.0, -3.0]


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_matches_scipy_delaunay_linear_interpolation(backend: str) -> None:
    pts = nadir_scan(hills)
    dem = oracle_grid_points(pts, (100, 100), 1.0, backend=backend)
    x, y = cell_centres((100, 100), 1.0)
    xx, yy = np.meshgrid(x, y)
    ref = LinearNDInterpolator(pts[..., :2].reshape(-1, 2), pts[..., 2].reshape(-1))(xx, yy)
    assert not np.isnan(ref).any() and not np.isnan(dem).any()
    np.testing.assert_allclose(dem, ref, rtol=0, atol=1e-5)


def test_missing_returns_stay_nan_and_are_not_extrapolated() -> None:
    pts = nadir_scan(tilted)
    pts[60:70, 60:70] = np.nan  # a 10x10 block of missing returns (about 8 m across)
    dem = grid_points(pts, (100, 100), 1.0)
    x, y = cell_centres((100, 100), 1.0)
    xx, yy = np.meshgrid(x, y)
    hole = np.isnan(dem)
    assert 20 < hole.sum() < 100  # the gap between the surrounding returns, nothing else
    # Every NaN cell lies inside the gap's bounding box in map coordinates.
    gx, gy = pts[59:71, 59:71, 0], pts[59:71, 59:71, 1]
    assert np.all((xx[hole] > np.nanmin(gx)) & (xx[hole] < np.nanmax(gx)))
    assert np.all((yy[hole] > np.nanmin(gy)) & (yy[hole] < np.nanmax(gy)))
    assert np.max(np.abs(dem[~hole] - tilted(xx, yy)[~hole])) < 1e-6


def test_dem_larger_than_footprint_has_nan_rim() -> None:
    dem = grid_points(nadir_scan(tilted), (120, 120), 1.0)
    assert np.isnan(dem[0]).all() and np.isnan(dem[:, -1]).all()
    assert not np.isnan(dem[10:-10, 10:-10]).any()


def test_backends_agree_on_rough_scan_with_missing_returns() -> None:
    rng = np.random.default_rng(2)
    pts = nadir_scan(hills)
    pts[..., 2] += rng.normal(0.0, 0.05, pts.shape[:2])
    pts[rng.random(pts.shape[:2]) < 0.01] = np.nan
    a = oracle_grid_points(pts, backend="numpy")
    b = grid_points(pts)
    assert np.array_equal(np.isnan(a), np.isnan(b))
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-5)


@pytest.mark.parametrize(
    ("points", "shape", "spacing"),
    [
        (np.zeros((10, 10)), (5, 5), 1.0),
        (np.zeros((1, 10, 3)), (5, 5), 1.0),
        (np.zeros((4, 4, 3)), (0, 5), 1.0),
        (np.zeros((4, 4, 3)), (5, 5), 0.0),
    ],
)
def test_bad_input_is_one_line_error(points: np.ndarray, shape: tuple[int, int], spacing: float) -> None:
    with pytest.raises(HdLabelsError) as info:
        grid_points(points, shape, spacing)
    assert "\n" not in str(info.value)


def test_nearest_binning_takes_the_most_central_return_and_the_first_of_a_tie() -> None:
    # Cell (0, 0) of a 2x2 grid at 1 m spans x in [-1, 0), y in (0, 1]; its centre is (-0.5, 0.5).
    pts = np.array(
        [
            [-0.9, 0.9, 1.0],  # corner of cell (0, 0)
            [-0.5, 0.6, 2.0],  # 0.1 m from its centre: taken
            [-0.4, 0.5, 3.0],  # also 0.1 m away, later: a tie keeps the first
            [0.0, 0.5, 4.0],  # x = 0 belongs to the cell east of the boundary, (0, 1)
            [np.nan, 0.5, 9.0],  # no return
            [5.0, 0.5, 9.0],  # outside the grid
        ]
    )
    dem = bin_points(pts, (2, 2), 1.0, "nearest")
    assert dem[0, 0] == 2.0 and dem[0, 1] == 4.0
    assert np.isnan(dem[1]).all()


def test_nearest_binning_equals_its_numpy_oracle_on_a_noisy_scan() -> None:
    rng = np.random.default_rng(5)
    pts = nadir_scan(hills)
    pts[..., :2] += rng.normal(0.0, 0.2, (*pts.shape[:2], 2))
    pts[rng.random(pts.shape[:2]) < 0.02] = np.nan
    flat = pts.reshape(-1, 3).astype(np.float32).astype(np.float64)
    flat[:50, :2] = np.round(flat[:50, :2])  # returns exactly on cell boundaries
    for shape, spacing in (((100, 100), 1.0), ((150, 150), 0.7)):
        expected = bin_nearest(flat, shape, spacing)
        assert np.array_equal(bin_points(flat, shape, spacing, "nearest"), expected, equal_nan=True)
        assert np.isfinite(expected).sum() > 0.5 * shape[0] * shape[1]  # most cells have a return
