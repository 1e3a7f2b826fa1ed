"""Descent mosaics (``hdlabels.mosaic``): frames placed by their poses, registered and gridded into one DEM."""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hdcore.errors import HdWarning
from hdlabels.errors import HdLabelsError
from hdlabels.mosaic import (
    POSES,
    MosaicFrame,
    apply,
    descent_frames,
    mosaic_dem,
    mosaic_frames,
    navigation_error,
    placed_points,
    register_frames,
    rigid,
    sample_spacing_m,
    terrain_residual,
)
from hdlabels.store import DemSpec
from lidarsim.build import build_dataset
from lidarsim.noise import points_at_ranges, scan_directions
from lidarsim.recipe import BuildSettings
from lidarsim.scan import TileScene
from lidarsim.sensor import SensorConfig, sensor_attitude
from lidarsim.shards import iter_descents, iter_scans
from lidarsim.terrain import DTM
from tests.geotiff import write_geotiff

SIDE_M = 600.0  # the terrain square, metres (1 m cells)
TARGET_XY = (300.0, 300.0)  # the descents' target, map metres
ALTITUDES_M = (400.0, 300.0, 200.0)  # three frames, the last the anchor
DEM = DemSpec(rows=60, cols=60, spacing_m=1.0, gridding="linear")


def write_terrain(path: Path, heights: np.ndarray) -> DTM:
    """A 1 m/px DTM of ``heights`` with its north-west corner at (0, SIDE_M)."""
    write_geotiff(path, heights, 1.0, (0.0, SIDE_M))
    return DTM.open(path)


def centres() -> tuple[np.ndarray, np.ndarray]:
    """Map x (per column) and y (per row) of the terrain's cell centres, metres."""
    c = np.arange(int(SIDE_M)) + 0.5
    return c, SIDE_M - c


def tilted_plane() -> np.ndarray:
    """z = 12 + 0.05 x + 0.02 y (metres): linear interpolation reproduces it exactly."""
    x, y = centres()
    return 12.0 + 0.05 * x[None, :] + 0.02 * y[:, None]


def hills() -> np.ndarray:
    """Seeded smooth relief with rocks: 40 Gaussian hills (1-6 m high, 6-30 m wide) and 200 boulders."""
    rng = np.random.default_rng(5)
    x, y = centres()
    xx, yy = np.meshgrid(x, y)
    z = np.zeros_like(xx)
    for _ in range(40):
        cx, cy, h, w = rng.uniform(150, 450), rng.uniform(150, 450), rng.uniform(1, 6), rng.uniform(6, 30)
        z += h * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * w * w))
    for _ in range(200):
        cx, cy, h = rng.uniform(200, 400), rng.uniform(200, 400), rng.uniform(0.3, 1.5)
        z += h * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * 1.2**2))
    return z


def descent(
    dtm: DTM,
    position_errors: list[np.ndarray] | None = None,
    rotation_errors_deg: list[np.ndarray] | None = None,
    jitter_deg: float = 0.0,
) -> tuple[list[MosaicFrame], np.ndarray]:
    """Noise-free frames of a vertical descent over TARGET_XY (ALTITUDES_M), each with the given
    navigation errors (map metres; rotation vectors in degrees); returns the frames and the target."""
    sensor = SensorConfig()
    scene = TileScene(dtm, TARGET_XY, 150.0)
    target = np.array([*TARGET_XY, scene.mean_height(*TARGET_XY, 30.0)])
    rng = np.random.default_rng(1)
    frames = []
    for k, altitude in enumerate(ALTITUDES_M):
        attitude = sensor_attitude(0.0, tuple(np.radians(jitter_deg) * rng.standard_normal(3)))
        position = np.array([0.0, 0.0, altitude])
        directions = scan_directions(sensor, attitude)
        ranges = scene.cast((target + position)[None], directions[None])[0].astype(np.float64)
        e_p = np.zeros(3) if position_errors is None else position_errors[k]
        e_r = np.zeros(3) if rotation_errors_deg is None else np.radians(rotation_errors_deg[k])
        frames.append(
            MosaicFrame(
                points=points_at_ranges(position, ranges, directions),
                origin_map=target.copy(),
                sensor_position=position,
                attitude=attitude,
                nav_sensor_position=position + e_p,
                nav_attitude=Rotation.from_rotvec(e_r).as_matrix() @ attitude,
            )
        )
    return frames, target


def test_a_tilted_plane_with_true_poses_mosaics_to_the_plane(tmp_path: Path) -> None:
    dtm = write_terrain(tmp_path / "plane.tif", tilted_plane())
    frames, target = descent(dtm, jitter_deg=0.2)
    mosaic = mosaic_frames(frames, target, DEM, "true")
    heights = mosaic.heights
    assert mosaic.registration is None and mosaic.poses == "true"
    np.testing.assert_allclose(mosaic.frame_residual_m, 0.0, atol=2e-3)
    assert np.isfinite(heights).all()
    residual = terrain_residual(heights, DEM, target, np.eye(4), dtm)
    assert np.abs(residual).max() < 2e-3  # float32 points 300 m from the sensor
    # and the plane itself: z relative to the target's reference height
    x = (np.arange(DEM.cols) - (DEM.cols - 1) / 2) + target[0]
    y = ((DEM.rows - 1) / 2 - np.arange(DEM.rows)) + target[1]
    expected = 12.0 + 0.05 * x[None, :] + 0.02 * y[:, None] - target[2]
    np.testing.assert_allclose(heights, expected, atol=2e-3)


def test_navigation_poses_without_error_place_frames_as_the_true_poses(tmp_path: Path) -> None:
    dtm = write_terrain(tmp_path / "hills.tif", hills())
    frames, target = descent(dtm, jitter_deg=0.1)
    for f in frames:
        np.testing.assert_array_equal(navigation_error(f), np.eye(4))
    nav, true = mosaic_frames(frames, target, DEM, "nav"), mosaic_frames(frames, target, DEM, "true")
    np.testing.assert_array_equal(nav.heights, true.heights)


def test_the_error_transform_is_the_documented_placement(tmp_path: Path) -> None:
    dtm = write_terrain(tmp_path / "hills.tif", hills())
    offsets = [np.array([0.5, -0.3, 0.2])] * 3
    frames, target = descent(dtm, position_errors=offsets, rotation_errors_deg=[np.array([0.2, -0.1, 0.3])] * 3)
    f = frames[1]
    true_map = f.points.astype(np.float64) + f.origin_map
    np.testing.assert_allclose(
        apply(navigation_error(f), true_map) - target, placed_points(f, target, "nav"), atol=1e-7, equal_nan=True
    )


def test_a_position_error_shifts_every_point_by_it(tmp_path: Path) -> None:
    dtm = write_terrain(tmp_path / "hills.tif", hills())
    offset = np.array([0.5, -0.3, 0.2])
    frames, target = descent(dtm, position_errors=[offset] * 3)
    true = placed_points(frames[0], target, "true")
    nav = placed_points(frames[0], target, "nav")
    ok = np.isfinite(true).all(axis=-1)
    np.testing.assert_allclose((nav - true)[ok], np.broadcast_to(offset, (int(ok.sum()), 3)), atol=1e-9)


def test_an_attitude_error_turns_the_points_about_the_sensor(tmp_path: Path) -> None:
    dtm = write_terrain(tmp_path / "plane.tif", tilted_plane())
    frames, _ = descent(dtm, rotation_errors_deg=[np.array([0.0, 0.0, 1.0])] * 3)
    error = navigation_error(frames[0])
    sensor_map = frames[0].origin_map + frames[0].sensor_position
    np.testing.assert_allclose(apply(error, sensor_map), sensor_map, atol=1e-9)  # the sensor stays put
    # a 1 degree yaw moves a point 100 m east of the sensor's nadir 100 * sin(1 deg) northwards
    point = sensor_map + np.array([100.0, 0.0, -400.0])
    moved = apply(error, point)
    assert moved[1] - point[1] == pytest.approx(100.0 * math.sin(math.radians(1.0)), abs=1e-9)


def test_registration_recovers_a_known_pose_error_of_one_frame(tmp_path: Path) -> None:
    dtm = write_terrain(tmp_path / "hills.tif", hills())
    zero = np.zeros(3)
    offset, turn_deg = np.array([0.8, -0.6, 0.4]), np.array([0.1, -0.05, 0.08])
    frames, target = descent(dtm, position_errors=[offset, zero, zero], rotation_errors_deg=[turn_deg, zero, zero])
    placed = [placed_points(f, target, "nav") for f in frames]
    registration = register_frames(placed, 0.5 * DEM.cols * DEM.spacing_m)
    np.testing.assert_array_equal(registration.corrections[-1], np.eye(4))
    # the correction (mosaic frame) composed with the error (map frame) must be the identity
    to_mosaic = rigid(np.eye(3), -target)
    residual = np.linalg.inv(to_mosaic) @ registration.corrections[0] @ to_mosaic @ navigation_error(frames[0])
    angle = np.degrees(np.arccos(np.clip((np.trace(residual[:3, :3]) - 1) / 2, -1, 1)))
    assert angle < 0.02
    # displacement left at the target area's corners and centre (ground level)
    probe = target + np.array([[0, 0, 0], [30, 30, 0], [-30, 30, 0], [30, -30, 0], [-30, -30, 0]], dtype=float)
    assert np.linalg.norm(apply(residual, probe) - probe, axis=1).max() < 0.05
    # and the frame left alone by the error needed (almost) no correction
    assert registration.translation_m()[1] < 0.05 and registration.rotation_deg()[1] < 0.02
    assert registration.fitness[0] > 0.2 and registration.rmse_m[0] < 0.3  # nearest points 0.25 m apart


def test_registered_mosaic_is_close_to_the_true_one_and_the_navigation_one_is_not(tmp_path: Path) -> None:
    dtm = write_terrain(tmp_path / "hills.tif", hills())
    errors = [np.array([1.0, -0.5, 0.6]), np.array([0.2, 0.7, -0.4]), np.array([-0.3, 0.1, 0.2])]
    turns = [np.array([0.1, 0.05, -0.1]), np.array([-0.08, 0.1, 0.05]), np.array([0.02, -0.03, 0.04])]
    frames, target = descent(dtm, position_errors=errors, rotation_errors_deg=turns)
    to_true = np.linalg.inv(navigation_error(frames[-1]))  # the mosaic lives in the anchor's navigation frame

    mosaics = {p: mosaic_frames(frames, target, DEM, p) for p in POSES}
    rms = {}
    for poses, mosaic in mosaics.items():
        r = terrain_residual(mosaic.heights, DEM, target, np.eye(4) if poses == "true" else to_true, dtm)
        rms[poses] = float(np.sqrt(np.nanmean(r**2)))
    assert rms["registered"] < 1.2 * rms["true"] + 0.01
    assert rms["nav"] > 5 * rms["registered"]
    # the frames' disagreement shows in the navigation mosaic and is gone after registration
    assert mosaics["nav"].frame_residual_m[0] > 0.3
    assert mosaics["registered"].frame_residual_m[:2].max() < 0.05


def test_frames_are_weighted_by_their_density_of_returns() -> None:
    def grid_frame(spacing: float, z: float) -> np.ndarray:
        n = int(round(40 / spacing))
        c = (np.arange(n) - (n - 1) / 2) * spacing
        xx, yy = np.meshgrid(c, -c)
        return np.stack([xx, yy, np.full_like(xx, z)], axis=-1)

    coarse, fine = grid_frame(1.0, 0.0), grid_frame(0.5, 1.0)
    assert sample_spacing_m(coarse) == pytest.approx(1.0) and sample_spacing_m(fine) == pytest.approx(0.5)
    dem = DemSpec(rows=20, cols=20, spacing_m=1.0, gridding="linear")
    out = mosaic_dem([coarse, fine], dem)
    np.testing.assert_allclose(out, (1.0 * 0.0 + 4.0 * 1.0) / 5.0, atol=1e-6)


def test_a_frame_without_neighbouring_returns_is_refused() -> None:
    lonely = np.full((4, 4, 3), np.nan)
    lonely[0, 0] = (0.0, 0.0, 0.0)
    with pytest.raises(HdLabelsError, match="no two neighbouring returns"):
        mosaic_dem([lonely], DEM)


def test_registration_needs_an_anchor_near_the_target() -> None:
    far = np.zeros((8, 8, 3))
    far[..., 0] = 500.0  # every return 500 m east of the target
    with pytest.raises(HdLabelsError, match="anchor frame has fewer than 3 returns"):
        register_frames([far, far], half_width_m=30.0)


def test_frames_read_from_a_descent_build_mosaic_to_the_terrain(tmp_path: Path) -> None:
    write_geotiff(tmp_path / "plane.tif", tilted_plane(), 1.0, (0.0, SIDE_M))
    settings = BuildSettings(
        scans=1,
        descent_frames=3,
        descent_altitudes_m="300:150",
        resolution=64,
        sigmas_m=(0.02,),
        seed=2,
        dtm_path=str(tmp_path / "plane.tif"),
        nav_position_sigma_m=1.0,
        nav_attitude_sigma_deg=0.1,
    )
    with pytest.warns(HdWarning, match="coarser than the LiDAR"):  # a plane has no rocks to miss
        build_dataset(tmp_path / "ds", settings.to_config(), workers=1)
    (scans,) = list(iter_descents(tmp_path / "ds"))
    frames, target = descent_frames(scans, None)
    assert len(frames) == 3 and [f.sensor_position[2] for f in frames] == pytest.approx([300.0, 225.0, 150.0])
    dem = DemSpec(rows=40, cols=40, spacing_m=1.0, gridding="linear")
    with DTM.open(tmp_path / "plane.tif") as dtm:
        true = mosaic_frames(frames, target, dem, "true")
        assert np.nanmax(np.abs(terrain_residual(true.heights, dem, target, np.eye(4), dtm))) < 2e-3
        # the navigation error moved the frames: their placement is not the true one
        nav = placed_points(frames[0], target, "nav") - placed_points(frames[0], target, "true")
        assert np.nanmax(np.linalg.norm(nav, axis=-1)) > 0.1
    noisy, _ = descent_frames(scans, 0)
    assert not np.array_equal(noisy[0].points, frames[0].points, equal_nan=True)


def test_a_scan_without_its_descent_record_is_refused(tmp_path: Path) -> None:
    write_geotiff(tmp_path / "plane.tif", tilted_plane(), 1.0, (0.0, SIDE_M))
    settings = BuildSettings(scans=2, resolution=16, sigmas_m=(0.02,), seed=2, dtm_path=str(tmp_path / "plane.tif"))
    build_dataset(tmp_path / "ds", settings.to_config(), workers=1)
    scans = list(iter_scans(tmp_path / "ds"))
    with pytest.raises(HdLabelsError, match="not a descent's frame"):
        descent_frames(scans, None)


def test_the_user_guide_example_runs_as_printed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    text = (Path(__file__).resolve().parents[2] / "docs" / "user-guide.md").read_text()
    start = text.index("One DEM of a descent's target area")
    code = re.search(r"```python\n(.*?)```", text[start:], re.S).group(1)  # type: ignore[union-attr]  # asserted by running it
    write_geotiff(tmp_path / "hills.tif", hills(), 1.0, (0.0, SIDE_M))
    settings = BuildSettings(
        scans=10,
        descent_frames=3,
        descent_altitudes_m="300:150",
        resolution=32,
        sigmas_m=(0.01, 0.02, 0.03),
        seed=1,
        dtm_path=str(tmp_path / "hills.tif"),
        nav_position_sigma_m=1.0,
        nav_attitude_sigma_deg=0.1,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", HdWarning)  # held-out descents share ground on a 600 m terrain
        build_dataset(tmp_path / "descents", settings.to_config(), workers=1)
    assert any(True for _ in iter_descents(tmp_path / "descents", split="test"))
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "user-guide.md mosaic example", "exec"), {})


def test_coarse_frames_only_fill_the_cells_no_resolving_frame_covers() -> None:
    def grid_frame(spacing: float, half_width: float, z: float) -> np.ndarray:
        n = int(round(2 * half_width / spacing))
        c = (np.arange(n) - (n - 1) / 2) * spacing
        xx, yy = np.meshgrid(c, -c)
        return np.stack([xx, yy, np.full_like(xx, z)], axis=-1)

    coarse = grid_frame(2.0, 30.0, 0.0)  # returns 2 m apart: they do not resolve 1 m cells
    fine = grid_frame(0.5, 10.0, 1.0)  # resolves the centre only
    dem = DemSpec(rows=40, cols=40, spacing_m=1.0, gridding="linear")
    out = mosaic_dem([coarse, fine], dem)
    centre, edge = out[15:25, 15:25], out[:5, :5]
    np.testing.assert_array_equal(centre, 1.0)  # the fine frame alone, the coarse one not averaged in
    np.testing.assert_array_equal(edge, 0.0)  # the coarse frame fills where the fine one has nothing
    both_coarse = mosaic_dem([coarse, grid_frame(4.0, 30.0, 1.0)], dem)  # none resolves: all averaged
    np.testing.assert_allclose(both_coarse[10:30, 10:30], (0.25 * 0.0 + 0.0625 * 1.0) / 0.3125, atol=1e-6)
