"""Sensor geometry and ray casting against hand-derivable terrain (planes)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import rasterio

from lidarsim.errors import LidarsimError
from lidarsim.scan import STATUS_DAMAGED, STATUS_DEAD, STATUS_MISS, TileScene, scan_geometry, simulate_scans
from lidarsim.sensor import SensorConfig, footprint_corners, footprint_half_width_m, ray_directions, sensor_attitude
from lidarsim.terrain import DTM
from lidarsim.trajectory import TrajectoryConfig, plan_scans
from tests.geotiff import write_geotiff


def write_plane(
    path: Path,
    n: int,
    spacing: float,
    origin: tuple[float, float],
    slope_x: float,
    slope_y: float,
    z0: float,
    crs: str | None,
) -> Path:
    """A GeoTIFF of z = z0 + slope_x * (x - x0) + slope_y * (y - y0) sampled at cell centres."""
    x0, y0 = origin
    x = x0 + (np.arange(n) + 0.5) * spacing
    y = y0 - (np.arange(n) + 0.5) * spacing
    z = z0 + slope_x * (x[None, :] - x0) + slope_y * (y[:, None] - y0)
    return write_geotiff(path, z, spacing, origin, crs, dtype="float64")


def test_rays_are_unit_and_pass_through_pixel_centres():
    sensor = SensorConfig()
    d = ray_directions(sensor)
    assert d.shape == (128, 128, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    # Corner pixel centre: image-plane offsets tan(6 deg) * (1 - 1/128) on both axes.
    t = math.tan(math.radians(6.0)) * (1.0 - 1.0 / 128.0)
    expected = math.atan(math.hypot(t, t))
    for i, j in ((0, 0), (0, 127), (127, 0), (127, 127)):
        angle = math.acos(d[i, j, 2])
        assert angle == pytest.approx(expected, abs=1e-12)
    # Adjacent columns are one pixel apart on the image plane.
    step = d[64, 65, 0] / d[64, 65, 2] - d[64, 64, 0] / d[64, 64, 2]
    assert step == pytest.approx(2 * math.tan(math.radians(6.0)) / 128, rel=1e-12)


def test_nadir_attitude_is_north_up():
    r = sensor_attitude()
    d = ray_directions(SensorConfig()) @ r.T
    assert d[0, 64, 1] > 0  # row 0 looks north
    assert d[64, 0, 0] < 0  # column 0 looks west
    assert np.all(d[..., 2] < 0)  # every ray goes down
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)


def test_tilt_turns_the_boresight_north():
    r = sensor_attitude(tilt_deg=10.0)
    boresight = r @ np.array([0.0, 0.0, 1.0])
    assert math.degrees(math.acos(-boresight[2])) == pytest.approx(10.0)
    assert boresight[1] > 0


def test_footprint_half_width_at_500m():
    assert footprint_half_width_m(SensorConfig(), 500.0) == pytest.approx(500 * math.tan(math.radians(6.0)))


def test_footprint_corners_by_hand():
    """A 30 x 20 degree detector 100 m above the plane: at nadir the rectangle ±100 tan 15°, ±100 tan 10°
    (row 0 looks north); tilted 10° north, the north edge at 100 tan 20°, the south one below the sensor."""
    tx, ty = 100.0 * math.tan(math.radians(15.0)), 100.0 * math.tan(math.radians(10.0))
    attitudes = np.stack([sensor_attitude(), sensor_attitude(tilt_deg=10.0), sensor_attitude(tilt_deg=85.0)])
    positions = np.array([[0.0, 0.0, 100.0], [5.0, -7.0, 100.0], [0.0, 0.0, 100.0]])
    corners = footprint_corners(30.0, 20.0, attitudes, positions)
    np.testing.assert_allclose(corners[0], [[-tx, ty], [tx, ty], [tx, -ty], [-tx, -ty]], atol=1e-9)
    north = 100.0 * math.tan(math.radians(20.0))
    np.testing.assert_allclose(corners[1][:, 1], [north - 7.0, north - 7.0, -7.0, -7.0], atol=1e-9)
    # across track: the north corners' ray (tan 15°, sin 20°/cos 10°, -cos 20°/cos 10°) meets the plane at
    # x = ±100 tan 15° cos 10°/cos 20°, the south corners' (tan 15°, 0, -1/cos 10°) at x = ±100 tan 15° cos 10°
    cos10, cos20 = math.cos(math.radians(10.0)), math.cos(math.radians(20.0))
    np.testing.assert_allclose(corners[1][:, 0] - 5.0, np.array([-1, 1, 1, -1]) * tx * cos10 / [cos20, cos20, 1, 1])
    assert np.isnan(corners[2][:2]).all() and np.isfinite(corners[2][2:]).all()  # above the horizon: no corner


def test_bad_sensor_is_refused():
    with pytest.raises(LidarsimError, match="fov_x_deg"):
        SensorConfig(fov_x_deg=0.0)
    with pytest.raises(LidarsimError, match="exceed"):
        SensorConfig(rows=4, cols=4, dead_elements=10, damaged_elements=10)


def _scan_plane(
    tmp_path: Path, origin: tuple[float, float], crs: str | None, sigmas=(0.0167,), sensor=None, n_scans: int = 3
):
    slope_x, slope_y, z0 = math.tan(math.radians(5.0)), -0.03, 1234.5
    path = write_plane(tmp_path / "plane.tif", 300, 0.5, origin, slope_x, slope_y, z0, crs)
    sensor = sensor or SensorConfig()
    traj = TrajectoryConfig(n_scans=n_scans)
    with DTM.open(path) as dtm:
        valid, transform = dtm.validity_overview(2.0)
        plan = plan_scans(valid, transform, sensor, traj)
        scene = TileScene(dtm, plan.tile_centre_xy(*plan.tile_ij[0]), plan.tile_m / 2 + plan.half_width_m)
        geoms = [scan_geometry(scene, plan.nadir_xy[i], i, traj, plan.half_width_m, seed=7) for i in range(n_scans)]
        results = simulate_scans(scene, geoms, list(range(n_scans)), sensor, sigmas, seed=7)

    def plane(p: np.ndarray) -> np.ndarray:
        return z0 + slope_x * (p[..., 0] - origin[0]) + slope_y * (p[..., 1] - origin[1])

    return results, plane


@pytest.mark.parametrize(("origin", "crs"), [((0.0, 150.0), None), ((582600.0, 4141950.0), "EPSG:32610")])
def test_clean_points_lie_on_a_tilted_plane(tmp_path, origin, crs):
    results, plane = _scan_plane(tmp_path, origin, crs)
    for res in results:
        p = res.points_clean.astype(np.float64) + res.geometry.origin_map
        assert not np.isnan(p).any()
        rms = np.sqrt(np.mean((p[..., 2] - plane(p)) ** 2))
        assert rms < 1e-3  # < 1 mm rms, also at UTM coordinates


def test_range_noise_has_the_requested_sigma_along_each_ray(tmp_path):
    sigmas = (0.0167, 0.03, 0.07)
    results, _ = _scan_plane(tmp_path, (0.0, 150.0), None, sigmas=sigmas)
    for s_i, sigma in enumerate(sigmas):
        deltas = []
        for res in results:
            d = ray_directions(SensorConfig()) @ res.geometry.attitude.T
            diff = res.points_noisy[s_i].astype(np.float64) - res.points_clean.astype(np.float64)
            along = np.sum(diff * d, axis=-1)
            across = np.linalg.norm(diff - along[..., None] * d, axis=-1)
            assert np.max(across) < 1e-3  # noise is along the ray only (float32 storage)
            deltas.append(along.ravel())
        rms = np.sqrt(np.mean(np.concatenate(deltas) ** 2))
        assert rms == pytest.approx(sigma, rel=0.03)


def test_dead_and_damaged_elements(tmp_path):
    sensor = SensorConfig(rows=32, cols=32, dead_elements=5, damaged_elements=4, damaged_error_m=3.0)
    results, _ = _scan_plane(tmp_path, (0.0, 150.0), None, sensor=sensor, n_scans=2)
    for res in results:
        dead = res.status == STATUS_DEAD
        damaged = res.status == STATUS_DAMAGED
        assert dead.sum() == 5 and damaged.sum() == 4
        assert np.isnan(res.points_clean[dead]).all() and np.isnan(res.points_noisy[:, dead]).all()
        err = np.linalg.norm(res.points_noisy[0][damaged] - res.points_clean[damaged], axis=-1)
        assert np.median(err) > 0.3  # 3 m sigma: large errors
        assert not np.isnan(res.points_clean[damaged]).any()
    # the same elements in every scan (a property of the detector)
    np.testing.assert_array_equal(results[0].status, results[1].status)


def test_rays_over_a_nodata_hole_miss(tmp_path):
    path = write_plane(tmp_path / "p.tif", 300, 0.5, (0.0, 150.0), 0.0, 0.0, 0.0, None)
    with rasterio.open(path, "r+") as ds:
        z = ds.read(1)
        z[140:160, 140:160] = np.nan
        ds.write(z, 1)
    with DTM.open(path) as dtm:
        scene = TileScene(dtm, (75.0, 75.0), 80.0)
        sensor = SensorConfig(rows=64, cols=64)
        traj = TrajectoryConfig(n_scans=1)
        g = scan_geometry(scene, np.array([75.0, 75.0]), 0, traj, 52.0, 0)
        (res,) = simulate_scans(scene, [g], [0], sensor, (0.01,), 0)
    miss = res.status == STATUS_MISS
    assert 0 < miss.sum() < 64 * 64 * 0.05
    assert np.isnan(res.points_clean[miss]).all()
    assert miss[32, 32]  # the nadir ray looks into the hole
