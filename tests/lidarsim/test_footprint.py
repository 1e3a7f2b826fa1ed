"""The pixel footprint (sub-rays, range estimators) and the signal-dependent noise against
hand-derivable targets: a tilted plane, a step, a hemispherical rock, a sweep of incidence angles."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lidarsim.errors import LidarsimError
from lidarsim.footprint import FootprintConfig, spot_weights, subpixel_offsets, subray_directions
from lidarsim.noise import NoiseModel
from lidarsim.scan import STATUS_RETURN, STATUS_WEAK, ScanGeometry, TileScene, simulate_scans
from lidarsim.sensor import SensorConfig, ray_directions, sensor_attitude
from lidarsim.terrain import DTM
from tests.geotiff import write_geotiff

ALTITUDE = 500.0
IFOV_DEG = 12.0 / 128.0  # the paper's pixel: 1.64 mrad


def _scene(tmp_path: Path, heights: np.ndarray, spacing: float, name: str = "t.tif") -> tuple[TileScene, float]:
    """The scene of a float64 GeoTIFF of ``heights`` with its top-left corner at (0, side); returns it
    and the map coordinate of the centre (x = y)."""
    n = heights.shape[0]
    side = n * spacing
    path = write_geotiff(tmp_path / name, heights, spacing, (0.0, side), dtype="float64")
    with DTM.open(path) as dtm:
        return TileScene(dtm, (side / 2, side / 2), side / 2 - spacing), side / 2


def _centres(n: int, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Map x (per column) and y (per row) of the cell centres of a grid whose top-left is (0, n * spacing)."""
    c = (np.arange(n) + 0.5) * spacing
    return c, n * spacing - c


def _sensor(pixels: int) -> SensorConfig:
    fov = pixels * IFOV_DEG
    return SensorConfig(rows=pixels, cols=pixels, fov_x_deg=fov, fov_y_deg=fov)


def _shoot(scene, centre, sensor, footprint, noise=None, sigmas=(0.0167,), z_ref=0.0, seed=3):
    geometry = ScanGeometry(
        origin_map=np.array([centre, centre, z_ref]),
        sensor_position=np.array([0.0, 0.0, ALTITUDE]),
        attitude=sensor_attitude(0.0),
    )
    return simulate_scans(scene, [geometry], [0], sensor, sigmas, seed, footprint=footprint, noise_model=noise)[0]


def test_sub_rays_cover_the_pixel_and_k1_is_the_pixel_centre():
    sensor = _sensor(4)
    assert np.array_equal(subray_directions(sensor, 1)[:, :, 0], ray_directions(sensor))
    d = subray_directions(sensor, 5)
    assert np.allclose(np.linalg.norm(d, axis=-1), 1.0)
    # the sub-rays' image-plane points are the centres of a 5 x 5 grid over the pixel's square
    image = d[..., :2] / d[..., 2:]
    centre = ray_directions(sensor)
    centre_image = centre[..., :2] / centre[..., 2:]
    pitch = 2 * math.tan(math.radians(sensor.fov_x_deg) / 2) / sensor.cols
    offsets = (image - centre_image[:, :, None, :]) / (pitch / 2)
    assert np.allclose(np.sort(np.unique(offsets[..., 0].round(9))), subpixel_offsets(5))
    assert np.abs(offsets).max() == pytest.approx(0.8)
    w = spot_weights(FootprintConfig(samples=5))
    assert w.sum() == pytest.approx(1.0) and w.argmax() == 12  # peaks on the centre sub-ray
    assert w[0] / w[12] == pytest.approx(math.exp(-2 * (0.8**2 + 0.8**2)))
    assert np.allclose(spot_weights(FootprintConfig(samples=3, spot_profile="uniform")), 1 / 9)


@pytest.mark.parametrize(("estimator", "slope_deg"), [("centroid", 5.0), ("first", 5.0), ("centroid", 20.0)])
def test_every_estimator_returns_a_tilted_plane(tmp_path, estimator, slope_deg):
    n, spacing = 120, 0.25
    x, y = _centres(n, spacing)
    g = math.tan(math.radians(slope_deg))
    scene, centre = _scene(tmp_path, np.broadcast_to(g * x[None, :] + 0.01 * y[:, None], (n, n)).copy(), spacing)
    sensor = _sensor(16)
    res = _shoot(scene, centre, sensor, FootprintConfig(samples=5, range_estimator=estimator))
    p = res.points_clean.astype(np.float64) + np.array([centre, centre, 0.0])
    assert (res.status == STATUS_RETURN).all()
    error = p[..., 2] - (g * p[..., 0] + 0.01 * p[..., 1])
    assert abs(error.mean()) < 1e-3 and np.abs(error).max() < 3e-3


def _step_expected(step_x: float, low: float, high: float, samples: int) -> float:
    """Height of the nadir pixel over a step (x >= step_x at ``high``) from its sub-rays, by hand:
    flat surfaces, so each sub-ray's energy is w cos(theta) (R_ref / r)^2 with cos(theta) its
    direction's vertical component, and the centroid range is mixed along the vertical centre ray."""
    t = subpixel_offsets(samples)
    tan_half = math.tan(math.radians(3 * IFOV_DEG) / 2)
    ta, tb = np.meshgrid(t, t)
    ix = tan_half * ta / 3  # image-plane offsets of the centre pixel of a 3 x 3 detector
    iy = tan_half * tb / 3
    norm = np.sqrt(1 + ix**2 + iy**2)
    ground_x = ix * ALTITUDE  # where the sub-ray meets the low level (x east = sensor x)
    level = np.where(ground_x >= step_x, high, low)
    r = (ALTITUDE - level) * norm
    w = np.exp(-2 * (ta**2 + tb**2))
    e = w * (1 / norm) * (ALTITUDE / r) ** 2
    return ALTITUDE - float((e * r).sum() / e.sum())


def test_a_step_gives_the_energy_weighted_mix_of_its_two_sides(tmp_path):
    n, spacing = 200, 0.02  # 4 m of terrain; the step's one-cell ramp lies between two sub-ray columns
    x, _ = _centres(n, spacing)
    centre = n * spacing / 2
    step_x = 0.08  # from the pixel centre: the sub-ray columns meet the ground at 0 and +0.16 m
    high = 1.0
    heights = np.where(x[None, :] - centre >= step_x, high, 0.0) * np.ones((n, 1))
    scene, centre = _scene(tmp_path, heights, spacing)
    res = _shoot(scene, centre, _sensor(3), FootprintConfig(samples=5))
    z = float(res.points_clean[1, 1, 2])
    expected = _step_expected(step_x, 0.0, high, 5)
    assert 0.2 < expected < 0.5  # a mixed pixel, neither side
    assert abs(z - expected) < 0.01 * high
    # one ray through the centre sees the low side only
    assert abs(float(_shoot(scene, centre, _sensor(3), None).points_clean[1, 1, 2])) < 1e-3


def _rock_height_seen(radius: float, samples: int) -> float:
    """Height of the nadir pixel over a hemisphere of ``radius`` centred under it, from the spot model
    integrated with ``samples`` x ``samples`` points over the pixel (midpoint rule): analytic
    ray-sphere intersections, energy w cos(theta) (R_ref / r)^2, centroid range on the vertical."""
    t = subpixel_offsets(samples)
    tan_half = math.tan(math.radians(3 * IFOV_DEG) / 2)
    ta, tb = np.meshgrid(t, t)
    d = np.stack([tan_half * ta / 3, tan_half * tb / 3, -np.ones_like(ta)], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    o = np.array([0.0, 0.0, ALTITUDE])
    b = d @ o  # |o + s d|^2 = R^2: s^2 + 2 b s + |o|^2 - R^2 = 0
    disc = b**2 - (o @ o - radius**2)
    s_sphere = -b - np.sqrt(np.maximum(disc, 0.0))
    s_ground = ALTITUDE / -d[..., 2]
    on_rock = disc > 0
    r = np.where(on_rock, s_sphere, s_ground)
    p = o + r[..., None] * d
    normal = np.where(on_rock[..., None], p / radius, np.array([0.0, 0.0, 1.0]))
    cos = np.abs((normal * d).sum(axis=-1))
    e = np.exp(-2 * (ta**2 + tb**2)) * cos * (ALTITUDE / r) ** 2
    return ALTITUDE - float((e * r).sum() / e.sum())


def test_a_rock_smaller_than_the_footprint_is_attenuated_as_the_spot_model_predicts(tmp_path):
    radius = 0.2  # a hemispherical rock 0.4 m across, under a 0.82 m pixel at 500 m
    n, spacing = 300, 0.01
    x, y = _centres(n, spacing)
    centre = n * spacing / 2
    rho2 = (x[None, :] - centre) ** 2 + (y[:, None] - centre) ** 2
    heights = np.sqrt(np.maximum(radius**2 - rho2, 0.0))
    scene, centre = _scene(tmp_path, heights, spacing)
    seen = {
        k: float(_shoot(scene, centre, _sensor(3), FootprintConfig(samples=k)).points_clean[1, 1, 2])
        for k in (1, 5, 16)
    }
    assert seen[1] == pytest.approx(radius, abs=2e-3)  # one ray: the rock's top
    integral = _rock_height_seen(radius, 600)  # the spot model's continuous integral
    assert 0.1 * radius < integral < 0.5 * radius  # a strong attenuation
    # the simulated pixel (a faceted 1 cm mesh) against the spot model sampled the same way, and the
    # sampling against the integral
    assert seen[5] == pytest.approx(_rock_height_seen(radius, 5), rel=0.03)
    assert seen[16] == pytest.approx(integral, rel=0.05)


def _plane_residuals(tmp_path: Path, incidence_deg: float, noise: NoiseModel, sigma: float):
    """Noisy minus clean ranges of a 64 x 64 px scan of a plane tilted by ``incidence_deg``, with
    the noise model's predicted sigma of each pixel: sigma (r / R_ref) / sqrt(cos theta)."""
    n, spacing = 140, 0.5
    x, _ = _centres(n, spacing)
    g = math.tan(math.radians(incidence_deg))
    scene, centre = _scene(tmp_path, np.broadcast_to(g * x[None, :], (n, n)).copy(), spacing, f"p{incidence_deg}.tif")
    sensor = SensorConfig(rows=64, cols=64, fov_x_deg=6.0, fov_y_deg=6.0)
    res = _shoot(scene, centre, sensor, FootprintConfig(), noise, sigmas=(sigma,), z_ref=g * centre)
    d = ray_directions(sensor) @ sensor_attitude(0.0).T
    sp = np.array([0.0, 0.0, ALTITUDE])
    clean = np.einsum("ijk,ijk->ij", res.points_clean.astype(np.float64) - sp, d)
    noisy = np.einsum("ijk,ijk->ij", res.points_noisy[0].astype(np.float64) - sp, d)
    normal = np.array([-g, 0.0, 1.0]) / math.hypot(g, 1.0)
    cos = np.abs(d @ normal)
    predicted = sigma * (clean / noise.reference_range_m) / np.sqrt(cos)
    return res, noisy - clean, predicted


@pytest.mark.parametrize("incidence_deg", [0.0, 30.0, 50.0, 65.0])
def test_snr_noise_matches_its_formula_per_incidence(tmp_path, incidence_deg):
    sigma = 0.05
    res, residual, predicted = _plane_residuals(tmp_path, incidence_deg, NoiseModel(kind="snr", snr_min=0.0), sigma)
    assert (res.status == STATUS_RETURN).all()
    ratio = residual / predicted
    assert abs(ratio.std() - 1.0) < 0.05 and abs(ratio.mean()) < 0.05
    # and it differs from the constant sigma where the prediction does
    if incidence_deg >= 50.0:
        assert residual.std() > 1.2 * sigma


def test_constant_noise_model_is_the_paper_sigma(tmp_path):
    sigma = 0.05
    _, residual, _ = _plane_residuals(tmp_path, 50.0, NoiseModel(), sigma)
    assert residual.std() == pytest.approx(sigma, rel=0.05)


def test_weak_returns_come_back_as_no_return(tmp_path):
    # snr_ref 10, snr_min 8: a return needs cos(theta) (500 m / r)^2 >= 0.8; across the 6 degree
    # field of view the incidence varies by 3 degrees and the range by up to 6 %
    noise = NoiseModel(kind="snr", snr_ref=10.0, snr_min=8.0)
    kept, _, _ = _plane_residuals(tmp_path, 25.0, noise, 0.02)
    assert (kept.status == STATUS_RETURN).all()
    lost, _, _ = _plane_residuals(tmp_path, 55.0, noise, 0.02)
    assert (lost.status == STATUS_WEAK).all()
    assert np.isnan(lost.points_clean).all() and np.isnan(lost.points_noisy).all()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"samples": 0}, "footprint-samples"),
        ({"samples": 17}, "footprint-samples"),
        ({"spot_profile": "tophat"}, "spot profile"),
        ({"range_estimator": "last"}, "range estimator"),
        ({"pulse_width_m": 0.0}, "pulse-width"),
        ({"return_fraction": 1.0}, "return-fraction"),
    ],
)
def test_bad_footprint_settings_are_refused(kwargs, match):
    with pytest.raises(LidarsimError, match=match):
        FootprintConfig(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"kind": "poisson"}, "noise model"), ({"snr_ref": 0.0}, "snr-ref"), ({"snr_min": -1.0}, "snr-min")],
)
def test_bad_noise_settings_are_refused(kwargs, match):
    with pytest.raises(LidarsimError, match=match):
        NoiseModel(**kwargs)
