"""Descents: K frames from a start to an end altitude toward one target, each with its true pose and
the navigation system's estimate of it (lidarsim.descent, lidarsim.navigation), stored in schema 1.3
shards; the paper's build is untouched."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial.transform import Rotation
from test_build import REPO, kill_after_two_shards, rough_dtm

from hdcli.cli import main
from hdlabels.labeling import label_dataset
from hdlabels.settings import LabelSettings
from lidarsim.build import BuildConfig, assign_splits, build_dataset, scan_splits
from lidarsim.descent import DescentConfig, frame_pose
from lidarsim.errors import LidarsimError
from lidarsim.inspect import dataset_record, describe_dataset
from lidarsim.navigation import NavigationError, descent_nav_errors, estimated_map_points, rotation_from_vector
from lidarsim.recipe import BuildSettings, load_recipe
from lidarsim.recipe_deviation import deviate
from lidarsim.sensor import NADIR_ATTITUDE, SensorConfig, rotation_x, rotation_y, rotation_z
from lidarsim.shards import (
    DamagedFileError,
    ScanShardReader,
    ShardFormatError,
    iter_descents,
    iter_scans,
    read_manifest,
    scan_schema_version,
    verify_dataset,
)
from lidarsim.trajectory import TrajectoryConfig

SENSOR = SensorConfig(rows=32, cols=32)
NAV = NavigationError(position_sigma_m=1.0, position_walk_m=0.3, attitude_sigma_deg=0.1, attitude_walk_deg=0.02)
# 3 descents of 3 frames from 200 m to 100 m along a 20-degree approach, 6 frames (2 descents) per shard.
SETTINGS = {
    "scans": 3,
    "descent_frames": 3,
    "descent_altitudes_m": "200:100",
    "approach_deg": 20.0,
    "nav_position_sigma_m": NAV.position_sigma_m,
    "nav_position_walk_m": NAV.position_walk_m,
    "nav_attitude_sigma_deg": NAV.attitude_sigma_deg,
    "nav_attitude_walk_deg": NAV.attitude_walk_deg,
    "resolution": 32,
    "sigmas_m": (0.03,),
    "seed": 4,
    "shard_size": 4,
}
DATASETS = ("descent_index", "frame_index", "target_map", "nav_sensor_position", "nav_sensor_attitude")


def descent_config(dtm: Path, **changes) -> BuildConfig:
    return BuildSettings(**{**SETTINGS, "dtm_path": str(dtm), **changes}).to_config()


@pytest.fixture(scope="module")
def dtm(tmp_path_factory) -> Path:
    return rough_dtm(tmp_path_factory.mktemp("dtm") / "rough.tif")


@pytest.fixture(scope="module")
def built(dtm, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("descent") / "ds"
    build_dataset(out, descent_config(dtm), workers=1)  # warns: 3 descents on a 160 m terrain overlap
    return out


def arrays(directory: Path) -> dict[str, np.ndarray]:
    out: dict[str, list[np.ndarray]] = {}
    for entry in read_manifest(directory)["shards"]:
        with h5py.File(directory / entry["path"]) as f:
            for name in ("scan_index", "split", "origin_map", "sensor_position", "sensor_attitude", *DATASETS):
                out.setdefault(name, []).append(f[name][:])
    return {k: np.concatenate(v) for k, v in out.items()}


# ------------------------------------------------------------------------------------------ geometry
def test_frame_altitudes_follow_the_schedule(built):
    descent = DescentConfig(frames=5, altitude_start_m=1000.0, altitude_end_m=250.0)
    assert [descent.altitude_m(k) for k in range(5)] == [1000.0, 812.5, 625.0, 437.5, 250.0]
    a = arrays(built)
    # frame k of 3 at 200 + (100 - 200) k / 2 above the target's reference height (the scan frame's z = 0)
    np.testing.assert_array_equal(a["sensor_position"][:, 2], np.tile([200.0, 150.0, 100.0], 3))
    np.testing.assert_array_equal(a["frame_index"], np.tile([0, 1, 2], 3))
    np.testing.assert_array_equal(a["descent_index"], np.repeat([0, 1, 2], 3))
    np.testing.assert_array_equal(a["scan_index"], np.arange(9))


@pytest.mark.parametrize("approach_deg", [0.0, 25.0, 55.0])
def test_the_target_is_at_the_image_centre_of_every_frame(approach_deg):
    descent = DescentConfig(frames=4, altitude_start_m=800.0, altitude_end_m=200.0, approach_deg=approach_deg)
    for azimuth in (0.0, 37.0, 90.0, 200.0, 333.0):
        for k in range(4):
            position, attitude = frame_pose(descent, k, azimuth)
            h = descent.altitude_m(k)
            # on the straight line through the target (the origin): h tan A from it, toward the azimuth
            offset = h * math.tan(math.radians(approach_deg))
            az = math.radians(azimuth)
            np.testing.assert_allclose(position, [offset * math.sin(az), offset * math.cos(az), h], atol=1e-9)
            target = attitude.T @ (np.zeros(3) - position)  # the target in the sensor frame
            assert target[2] > 0 and np.hypot(target[0], target[1]) < 1e-12 * target[2]  # on the boresight
            np.testing.assert_allclose(attitude @ attitude.T, np.eye(3), atol=1e-15)
            assert np.linalg.det(attitude) == pytest.approx(1.0)
    # a vertical descent is the nadir attitude (north-up images); from the south, the --tilt of the same angle
    np.testing.assert_array_equal(frame_pose(DescentConfig(frames=2), 1, 0.0)[1], NADIR_ATTITUDE)
    tilted = DescentConfig(frames=2, approach_deg=25.0)
    expected = NADIR_ATTITUDE @ rotation_x(math.radians(25.0))
    np.testing.assert_allclose(frame_pose(tilted, 0, 180.0)[1], expected, atol=1e-15)


def test_the_target_is_at_the_image_centre_of_every_stored_frame(built):
    a = arrays(built)
    for k in range(9):
        target = a["sensor_attitude"][k].T @ (np.zeros(3) - a["sensor_position"][k])
        assert np.hypot(target[0], target[1]) < 1e-12 * target[2]
        # 20 degrees from the vertical: the sensor is h tan(20 deg) from the target
        assert np.hypot(*a["sensor_position"][k, :2]) == pytest.approx(
            a["sensor_position"][k, 2] * math.tan(math.radians(20.0))
        )
    np.testing.assert_array_equal(a["target_map"], a["origin_map"])  # the scan frame's origin is the target
    # the rays of the 2 x 2 centre pixels surround the line of sight to the target: each clean point lies
    # off that line by its range times the angle of its pixel centre from the boresight, whatever the relief
    off_axis = math.atan(math.sqrt(2.0) * math.tan(math.radians(6.0)) / 32)
    for scan in iter_scans(built):
        s = scan.sensor_position
        axis = -s / np.linalg.norm(s)
        for p in scan.points_clean[15:17, 15:17].reshape(-1, 3).astype(np.float64):
            rel = p - s
            distance = np.linalg.norm(rel - (rel @ axis) * axis)
            assert distance == pytest.approx(np.linalg.norm(rel) * math.sin(off_axis), rel=1e-4)


@pytest.mark.parametrize("approach_deg", [0.0, 10.0, 30.0, 50.0])
def test_every_frame_of_a_descent_lies_within_the_planned_reach(approach_deg):
    """Corner rays of the detector, with a 3-sigma jitter, on flat ground: inside the square the planner keeps valid."""
    descent = DescentConfig(frames=3, altitude_start_m=1000.0, altitude_end_m=250.0, approach_deg=approach_deg)
    jitter_deg = 0.05
    reach = descent.reach_m(SensorConfig(), jitter_deg)
    t = math.tan(math.radians(6.0))
    corners = np.array([[sx * t, sy * t, 1.0] for sx in (-1, 1) for sy in (-1, 1)])
    corners /= np.linalg.norm(corners, axis=1, keepdims=True)
    three = math.radians(3.0 * jitter_deg)
    farthest = 0.0
    for azimuth in np.linspace(0.0, 360.0, 73):
        for k in range(3):
            for jitter in ((three, three, three), (-three, three, -three), (three, -three, 0.0), (0.0, 0.0, 0.0)):
                position, attitude = frame_pose(descent, k, azimuth, jitter)
                d = corners @ attitude.T
                ground = position[None, :2] + d[:, :2] * (position[2] / -d[:, 2:3])
                farthest = max(farthest, float(np.abs(ground).max()))
    assert farthest <= reach
    assert reach < 1.08 * farthest  # and is not loose: within 8 % of the farthest corner seen


# ------------------------------------------------------------------------------------------ navigation
def test_with_perfect_navigation_the_estimate_is_the_true_pose_exactly(dtm, tmp_path):
    errors = descent_nav_errors(NavigationError(), seed=3, descent_index=7, frames=5)
    assert not errors.position_m.any() and not errors.rotation_rad.any()
    out = tmp_path / "perfect"
    perfect = {k: 0.0 for k in SETTINGS if k.startswith("nav_")}
    build_dataset(out, descent_config(dtm, **perfect), workers=1)
    a = arrays(out)
    np.testing.assert_array_equal(a["nav_sensor_position"], a["sensor_position"])
    np.testing.assert_array_equal(a["nav_sensor_attitude"], a["sensor_attitude"])


def test_navigation_error_statistics_match_the_parameters():
    """2000 descents of 9 frames: the sample standard deviation of n normal draws is off by about
    1/sqrt(2n) of itself, its variance by sqrt(2/n); each tolerance is about 4 of those."""
    n, frames = 2000, 9
    errors = [descent_nav_errors(NAV, 11, d, frames) for d in range(n)]
    position = np.stack([e.position_m for e in errors])  # (n, K, 3), metres
    rotation = np.degrees(np.stack([e.rotation_rad for e in errors]))  # degrees
    for e, sigma, walk in (
        (position, NAV.position_sigma_m, NAV.position_walk_m),
        (rotation, NAV.attitude_sigma_deg, NAV.attitude_walk_deg),
    ):
        bias, increments = e[:, 0], np.diff(e, axis=1)  # frame 0 is the bias alone
        assert np.abs(bias.mean(axis=0)).max() < 4 * sigma / math.sqrt(n)
        np.testing.assert_allclose(bias.std(axis=0), sigma, rtol=0.09)  # per axis: n = 2000
        assert bias.std() == pytest.approx(sigma, rel=0.05)  # the three axes: n = 6000
        assert np.abs(increments.mean(axis=(0, 1))).max() < 4 * walk / math.sqrt(n * (frames - 1))
        np.testing.assert_allclose(increments.std(axis=(0, 1)), walk, rtol=0.035)  # n = 16000 per axis
        variance = (e**2).mean(axis=(0, 2))  # frame k, three axes: n = 6000
        np.testing.assert_allclose(variance, sigma**2 + np.arange(frames) * walk**2, rtol=0.08)
        # the bias and the walk are independent: their correlation is within 4 / sqrt(n) of 0
        r = np.corrcoef(bias[:, 0], increments[:, 0, 0])[0, 1]
        assert abs(r) < 4 / math.sqrt(n)
    # the same seed and descent give the same errors; another descent or seed others
    again = descent_nav_errors(NAV, 11, 5, frames)
    np.testing.assert_array_equal(again.position_m, errors[5].position_m)
    assert not np.array_equal(descent_nav_errors(NAV, 12, 5, frames).position_m, errors[5].position_m)
    # the errors of a descent's first frames do not depend on its number of frames
    np.testing.assert_array_equal(descent_nav_errors(NAV, 11, 5, 4).rotation_rad, errors[5].rotation_rad[:4])


def test_the_rotation_and_the_map_placement_formula_by_hand():
    quarter = rotation_from_vector(np.array([0.0, 0.0, math.pi / 2]))
    np.testing.assert_allclose(quarter, rotation_z(math.pi / 2), atol=1e-15)
    np.testing.assert_array_equal(rotation_from_vector(np.zeros(3)), np.eye(3))
    rng = np.random.default_rng(2)
    for theta in rng.normal(0.0, 0.5, (20, 3)):
        np.testing.assert_allclose(rotation_from_vector(theta), Rotation.from_rotvec(theta).as_matrix(), atol=1e-14)
    # sensor 100 m above the origin looking down; the estimate 1 m east of it and turned 90 degrees about z
    s, origin = np.array([0.0, 0.0, 100.0]), np.array([1000.0, 2000.0, 5.0])
    p = np.array([[10.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    placed = estimated_map_points(p, origin, s, NADIR_ATTITUDE, s + np.array([1.0, 0.0, 0.0]), quarter @ NADIR_ATTITUDE)
    # p - s = (10, 0, -100) turned to (0, 10, -100), then + origin + s + (1, 0, 0)
    np.testing.assert_allclose(placed, [[1001.0, 2010.0, 5.0], [1001.0, 2000.0, 5.0]], atol=1e-12)
    # perfect navigation places the points where they are (origin_map + p)
    attitude = rotation_x(0.3) @ rotation_y(-0.2) @ NADIR_ATTITUDE
    np.testing.assert_allclose(estimated_map_points(p, origin, s, attitude, s, attitude), p + origin, atol=1e-12)


def test_stored_estimates_are_the_error_model_applied_to_the_true_poses(built):
    a = arrays(built)
    for d in range(3):
        errors = descent_nav_errors(NAV, 4, d, 3)  # SETTINGS' seed
        for k in range(3):
            i = 3 * d + k
            np.testing.assert_array_equal(a["nav_sensor_position"][i], a["sensor_position"][i] + errors.position_m[k])
            expected = rotation_from_vector(errors.rotation_rad[k]) @ a["sensor_attitude"][i]
            np.testing.assert_array_equal(a["nav_sensor_attitude"][i], expected)
            assert np.linalg.norm(errors.position_m[k]) > 0.0
        # frame 0 carries the bias only; later frames the bias plus the walk
        assert not np.array_equal(errors.position_m[0], errors.position_m[1])


# ------------------------------------------------------------------------------------------ the build
def test_a_descent_build_stores_whole_descents_in_schema_1_3(built):
    manifest = read_manifest(built)
    assert manifest["schema_version"] == "1.4" and manifest["n_scans"] == 9
    assert (manifest["n_descents"], manifest["descent_frames"]) == (3, 3)
    # --shard-size 4 is rounded up to 6 frames: two whole descents, then one
    assert [s["n_scans"] for s in manifest["shards"]] == [6, 3]
    assert {s["schema_version"] for s in manifest["shards"]} == {"1.3"}
    assert verify_dataset(built) == []
    with h5py.File(built / manifest["shards"][0]["path"]) as f:
        assert f.attrs["schema_version"] == "1.3"
        expected = {
            "descent_frames": 3,
            "descent_altitude_start_m": 200.0,
            "descent_altitude_end_m": 100.0,
            "descent_approach_deg": 20.0,
            "nav_position_sigma_m": 1.0,
            "nav_position_walk_m": 0.3,
            "nav_attitude_sigma_deg": 0.1,
            "nav_attitude_walk_deg": 0.02,
        }
        assert {k: f.attrs[k] for k in expected} == expected
        assert "trajectory_altitude_m" not in f.attrs and "trajectory_tilt_deg" not in f.attrs  # the descent's own
        shapes = {name: (f[name].dtype, f[name].shape) for name in DATASETS}
        assert shapes == {
            "descent_index": (np.int64, (6,)),
            "frame_index": (np.int64, (6,)),
            "target_map": (np.float64, (6, 3)),
            "nav_sensor_position": (np.float64, (6, 3)),
            "nav_sensor_attitude": (np.float64, (6, 3, 3)),
        }
        assert all(f[name].fletcher32 for name in DATASETS)
    a = arrays(built)
    for d in range(3):  # a descent's frames share their target and their split
        rows = slice(3 * d, 3 * d + 3)
        assert len(set(a["split"][rows])) == 1 and len({tuple(t) for t in a["target_map"][rows]}) == 1
    descents = list(iter_descents(built))
    assert [[s.scan_index for s in d] for d in descents] == [[0, 1, 2], [3, 4, 5], [6, 7, 8]]
    assert [s.descent.frame_index for s in descents[2] if s.descent is not None] == [0, 1, 2]
    # a reader of a single-frame build sees no descent
    assert all(s.descent is None for s in iter_scans(REPO / "tests" / "data" / "golden"))


def test_a_shard_missing_one_descent_array_or_a_dataset_of_single_scans_is_refused(built, tmp_path):
    manifest = read_manifest(built)
    copy = tmp_path / "damaged.h5"
    shutil.copy(built / manifest["shards"][1]["path"], copy)
    with h5py.File(copy, "r+") as f:
        del f["nav_sensor_attitude"]
    with pytest.raises(DamagedFileError, match="nav_sensor_attitude"):
        ScanShardReader(copy)
    with pytest.raises(ShardFormatError, match="not a descent build"):
        next(iter_descents(REPO / "tests" / "data" / "golden"))


def test_each_frame_of_a_descent_is_labelled_on_a_dem_centred_on_the_target(built, tmp_path):
    data = tmp_path / "labelled"
    shutil.copytree(built, data)
    label_dataset(data, LabelSettings(dem_size=40, dem_spacing_m=1.0), workers=1)
    lab = read_manifest(data)["labelings"][0]
    with h5py.File(data / lab["shards"][0]["path"]) as f:
        dem = f["dem_clean"][:]
    # the frames look at the target, the DEM's centre: frame 0 (200 m, 42 m across) fills the 40 m DEM
    # nearly, frame 2 (100 m) covers its centre; both see the centre cells
    assert dem.shape == (6, 40, 40) and np.isfinite(dem[:, 18:22, 18:22]).all()
    assert np.isfinite(dem[0]).mean() > np.isfinite(dem[2]).mean() > 0.2


def test_hd_inspect_names_the_descents_and_the_navigation_error(built):
    text = describe_dataset(built)
    assert "scans     9 (3 descents of 3 frames)" in text
    assert "descents  3 of 3 frames, 200.0 m down to 100.0 m above the target, approach 20.0 deg" in text
    assert "nav error position 1.0 m bias + 0.3 m walk per frame, attitude 0.1 deg bias + 0.02 deg walk" in text
    record = dataset_record(built)
    assert (record["n_descents"], record["descent_frames"]) == (3, 3)
    assert json.loads(json.dumps(record))["descent"]["nav"]["attitude_walk_deg"] == 0.02  # as hd --json prints it
    result = CliRunner().invoke(main, ["inspect", str(built)])
    assert result.exit_code == 0 and "nav error" in result.output and "intact" in result.output


def test_workers_do_not_change_a_descent_build(built, dtm, tmp_path):
    build_dataset(tmp_path / "two", descent_config(dtm), workers=2)
    one, two = read_manifest(built), read_manifest(tmp_path / "two")
    assert [s["sha256"] for s in one["shards"]] == [s["sha256"] for s in two["shards"]]
    build_dataset(tmp_path / "seed", descent_config(dtm, seed=5), workers=1)
    assert arrays(tmp_path / "seed")["nav_sensor_position"].tolist() != arrays(built)["nav_sensor_position"].tolist()


def test_a_killed_descent_build_resumes_to_the_same_bytes(dtm, tmp_path):
    argv = [
        "build-dataset",
        "--dtm",
        str(dtm),
        "--scans",
        "8",
        "--descent-frames",
        "3",
        "--descent-altitudes",
        "150:100",
        "--nav-position-walk",
        "0.5",
        "--shard-size",
        "3",
        "--sigma",
        "0.03",
        "--workers",
        "1",
        "--resolution",
        "48",
    ]
    reference = tmp_path / "ref"
    assert CliRunner().invoke(main, [*argv, "--out", str(reference)]).exit_code == 0
    out = tmp_path / "killed"
    kill_after_two_shards(argv, out)
    result = CliRunner().invoke(main, [*argv, "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "already complete" in result.output and "8 descents of 3 frames" in result.output
    ref, resumed = read_manifest(reference), read_manifest(out)
    assert len(ref["shards"]) == 8
    assert [s["sha256"] for s in ref["shards"]] == [s["sha256"] for s in resumed["shards"]]


def test_splits_are_assigned_by_descent():
    config = BuildSettings(scans=100, descent_frames=9).to_config()
    splits = scan_splits(config)
    np.testing.assert_array_equal(splits, np.repeat(assign_splits(100, config.seed), 9))
    assert splits.shape == (900,) and (splits.reshape(100, 9) == splits[::9, None]).all()
    assert config.scans_per_shard == 54  # --shard-size 50 rounded up to whole descents of 9
    # single scans: today's splits, scan by scan
    np.testing.assert_array_equal(scan_splits(BuildConfig()), assign_splits(1000, 0))


def test_a_recipe_takes_the_descent_keys_and_its_size_counts_descents(tmp_path):
    recipe = tmp_path / "descent" / "recipe.toml"
    recipe.parent.mkdir()
    recipe.write_text(
        "[build]\nscans = 40\ndescent_frames = 9\ndescent_altitudes_m = [800, 200]\napproach_deg = 15\n"
        "nav_position_sigma_m = 1\nnav_attitude_walk_deg = 0.05\n"
    )
    loaded = load_recipe(recipe)
    descent = loaded.build.trajectory.descent
    assert descent is not None and loaded.build.trajectory.n_scans == 360
    assert (descent.frames, descent.altitude_start_m, descent.altitude_end_m, descent.approach_deg) == (9, 800, 200, 15)
    assert descent.nav == NavigationError(position_sigma_m=1.0, attitude_walk_deg=0.05)
    config, deviation = deviate(loaded, {"scans": 10})
    assert config.trajectory.n_scans == 90 and deviation is not None
    assert deviation.words() == "--scans 10 (recipe: 40)"


# ------------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize(
    ("settings", "match"),
    [
        ({"descent_frames": 3, "descent_altitudes_m": "250:1000"}, "does not descend"),
        ({"descent_frames": 3, "descent_altitudes_m": "250:250"}, "does not descend"),
        ({"descent_frames": 3, "descent_altitudes_m": "1000:-5"}, "two numbers of metres in"),
        ({"descent_frames": 3, "descent_altitudes_m": "1000"}, "two numbers START:END"),
        ({"descent_frames": 1}, r"--descent-frames must be an integer in \[2, 64\]"),
        ({"descent_frames": 65}, r"--descent-frames must be an integer in \[0, 64\]"),
        ({"descent_frames": 64, "scans": 20000}, "20000 descents of 64 frames are 1,280,000 scans"),
        ({"descent_frames": 3, "nav_position_sigma_m": -1.0}, r"--nav-position-sigma must be a finite number in"),
        ({"descent_frames": 3, "nav_attitude_walk_deg": 5.0}, r"--nav-attitude-walk must be a finite number in"),
        ({"descent_frames": 3, "approach_deg": 60.0}, r"--approach-deg must be a finite number in \[0, 60\)"),
        ({"approach_deg": 10.0}, "describe descents: give --descent-frames"),
        ({"nav_position_walk_m": 1.0}, "describe descents: give --descent-frames"),
        ({"descent_frames": 3, "altitude_m": 300.0}, "--altitude and --tilt do not apply to a descent"),
        ({"descent_frames": 3, "tilt_deg": "0:5"}, "--altitude and --tilt do not apply to a descent"),
    ],
)
def test_bad_descent_settings_are_refused_with_one_line(settings, match):
    with pytest.raises(LidarsimError, match=match) as info:
        BuildSettings(**settings).to_config()
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--descent-frames", "3", "--descent-altitudes", "200:300"], "200:300 does not descend"),
        (["--descent-frames", "1"], "--descent-frames must be an integer in [2, 64]"),
        (["--descent-frames", "3", "--nav-attitude-sigma", "-0.1"], "'--nav-attitude-sigma'"),
        (["--descent-frames", "99"], "'--descent-frames': 99 is not in the range 0<=x<=64"),
    ],
)
def test_the_command_line_refuses_bad_descents_before_any_work(tmp_path, args, needle):
    result = CliRunner().invoke(main, ["build-dataset", "--out", str(tmp_path / "x"), *args])
    assert result.exit_code != 0 and needle in result.output
    assert len(result.output.strip().splitlines()) == 1 and not (tmp_path / "x").exists()


def test_an_oblique_descent_that_grazes_the_terrain_is_refused():
    descent = DescentConfig(frames=2, approach_deg=59.0)
    with pytest.raises(LidarsimError, match="reaches 84 deg off nadir; the footprint would be unbounded"):
        descent.reach_m(SensorConfig(fov_x_deg=50.0, fov_y_deg=50.0), 0.0)


def test_the_paper_build_records_nothing_of_descents():
    plain = BuildSettings().to_config()
    assert plain.fingerprint() == BuildConfig().fingerprint()
    assert plain.trajectory.descent is None and "descent" not in plain.to_dict()["trajectory"]
    described = BuildSettings(scans=2, descent_frames=3).to_config().to_dict()["trajectory"]
    assert "altitude_m" not in described and "tilt_deg" not in described and described["descent"]["frames"] == 3
    attrs = plain.trajectory.to_attrs()
    assert "trajectory_altitude_m" in attrs and not any(k.startswith(("descent", "nav_")) for k in attrs)
    assert scan_schema_version(attrs) == "1.1" and plain.scans_per_shard == plain.shard_size
    assert TrajectoryConfig().n_positions == 1000 and TrajectoryConfig().frames == 1
