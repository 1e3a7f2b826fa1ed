"""A descent's altitudes and attitudes drawn per scan, and a build with the realistic sensor
(footprint, SNR noise): its settings recorded, its weak returns stored as no return, its shards
labelled; the paper's sensor keeps its settings hash and its 1.1 shards."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from test_build import rough_dtm

from hdcli.cli import main
from hdlabels.grid import grid_points
from hdlabels.labeling import label_dataset
from hdlabels.settings import LabelSettings
from lidarsim.build import BuildConfig, build_dataset
from lidarsim.errors import LidarsimError
from lidarsim.footprint import FootprintConfig
from lidarsim.inspect import describe_dataset
from lidarsim.noise import NoiseModel, noisy_points, recover_ranges, scan_directions
from lidarsim.recipe import BuildSettings, load_recipe
from lidarsim.scan import STATUS_RETURN, STATUS_WEAK
from lidarsim.sensor import SensorConfig
from lidarsim.shards import iter_scans, read_manifest
from lidarsim.span import parse_span
from lidarsim.trajectory import TrajectoryConfig

NARROW = SensorConfig(rows=32, cols=32, fov_x_deg=3.0, fov_y_deg=3.0)


@pytest.mark.parametrize(
    ("value", "expected"),
    [(500.0, (500.0, None)), ("500", (500.0, None)), ("250:1000", (250.0, 1000.0)), ([250, 1000], (250.0, 1000.0))],
)
def test_a_setting_is_one_number_or_a_range(value, expected):
    assert parse_span("altitude_m", value) == expected


@pytest.mark.parametrize("value", ["a:b", "1:2:3", True, [1], None])
def test_a_bad_range_is_refused(value):
    with pytest.raises(LidarsimError, match="altitude_m must be a number or a range"):
        parse_span("altitude_m", value)


@pytest.mark.parametrize(
    ("settings", "match"),
    [
        ({"altitude_m": "1000:250"}, "runs backwards"),
        ({"altitude_m": "250:-1"}, "--altitude range must end within"),
        ({"tilt_deg": "0:70"}, "--tilt range must end within"),
        ({"jitter_deg": "0:9"}, "--jitter range must end within"),
    ],
)
def test_ranges_are_checked_against_their_bounds(settings, match):
    with pytest.raises(LidarsimError, match=match):
        BuildSettings(**settings).to_config()


def test_per_scan_altitude_tilt_and_jitter_are_seeded_draws_within_their_ranges():
    traj = TrajectoryConfig(
        altitude_m=250.0, altitude_max_m=1000.0, tilt_deg=-5.0, tilt_max_deg=5.0, jitter_max_deg=0.1
    )
    poses = np.array([traj.scan_pose(11, k) for k in range(400)])
    assert (poses[:, 0] >= 250.0).all() and (poses[:, 0] <= 1000.0).all()
    assert poses[:, 0].min() < 300.0 and poses[:, 0].max() > 950.0  # spans the descent
    assert (np.abs(poses[:, 1]) <= 5.0).all() and ((poses[:, 2] >= 0.0) & (poses[:, 2] <= 0.1)).all()
    assert np.array_equal(poses, np.array([traj.scan_pose(11, k) for k in range(400)]))
    assert not np.array_equal(poses, np.array([traj.scan_pose(12, k) for k in range(400)]))
    assert traj.max_altitude_m == 1000.0 and traj.max_abs_tilt_deg == 5.0 and traj.max_jitter_deg == 0.1
    assert TrajectoryConfig().scan_pose(11, 3) == (500.0, 0.0, 0.0)


def test_the_paper_sensor_records_none_of_the_new_settings():
    plain = BuildSettings().to_config()
    assert plain.fingerprint() == BuildConfig().fingerprint()
    d = plain.to_dict()
    assert "footprint" not in d and "noise_model" not in d and "altitude_max_m" not in d["trajectory"]
    assert plain.realism_attrs == {}
    assert not any("max" in k for k in plain.trajectory.to_attrs())
    realistic = BuildSettings(footprint_samples=5, noise_model="snr", altitude_m="250:1000").to_config()
    assert realistic.fingerprint() != plain.fingerprint()
    assert realistic.realism_attrs["footprint_samples"] == 5 and realistic.realism_attrs["noise_model"] == "snr"


@pytest.fixture(scope="module")
def realistic(tmp_path_factory) -> Path:
    """12 scans with 3 x 3 sub-rays per pixel and the SNR noise, from 400 to 1000 m: at SNR_ref 20 and
    threshold 4, ground tilted by more than about 35 degrees stops returning near 1000 m
    (signal cos(theta) (500/r)^2 < 0.2)."""
    tmp = tmp_path_factory.mktemp("realistic")
    dtm = rough_dtm(tmp / "rough.tif")
    config = BuildConfig(
        sigmas_m=(0.0167, 0.07),
        seed=5,
        sensor=NARROW,
        trajectory=TrajectoryConfig(n_scans=12, altitude_m=400.0, altitude_max_m=1000.0),
        dtm_path=str(dtm),
        shard_size=6,
        footprint=FootprintConfig(samples=3),
        noise_model=NoiseModel(kind="snr", snr_ref=20.0, snr_min=4.0),
    )
    out = tmp / "ds"
    build_dataset(out, config, workers=1)
    return out


def test_a_realistic_build_records_its_sensor_and_stores_weak_returns_as_no_return(realistic):
    manifest = read_manifest(realistic)
    assert {s["schema_version"] for s in manifest["shards"]} == {"1.2"}
    assert manifest["config"]["footprint"]["samples"] == 3 and manifest["config"]["noise_model"]["kind"] == "snr"
    weak_scans = 0
    for entry in manifest["shards"]:
        with h5py.File(realistic / entry["path"]) as f:
            assert f.attrs["schema_version"] == "1.2"
            assert f.attrs["footprint_samples"] == 3 and f.attrs["noise_model"] == "snr"
            assert f.attrs["trajectory_altitude_max_m"] == 1000.0
            assert "4 weak" in f["status"].attrs["codes"]
            altitude = f["sensor_position"][:, 2]
            status = f["status"][:]
            clean, noisy, valid = f["points_clean"][:], f["points_noisy"][:], f["valid"][:]
        assert ((altitude >= 400.0) & (altitude <= 1000.0)).all()
        weak = status == STATUS_WEAK
        assert np.isnan(clean[weak]).all()
        assert np.isnan(noisy[np.broadcast_to(weak[:, None], noisy.shape[:-1])]).all()
        assert (valid[weak] == 0).all() and (valid[status == STATUS_RETURN] == 1).all()
        for k in range(len(altitude)):
            fraction = weak[k].mean()
            if altitude[k] < 800.0:  # only the steepest facets of the rough terrain, if any
                assert fraction < 0.05
            weak_scans += fraction > 0
            # the gridding takes the returns and leaves the weak pixels out (holes stay NaN)
            dem = grid_points(clean[k], (8, 8), 1.0)
            assert np.isfinite(dem).mean() > 0.5
    assert weak_scans >= 1


def test_a_realistic_build_is_labelled(realistic):
    label_dataset(realistic, LabelSettings(dem_size=16, dem_spacing_m=1.0), workers=1)
    manifest = json.loads((realistic / "manifest.json").read_text())
    assert manifest["labelings"]


def test_hd_inspect_names_the_realistic_sensor(realistic):
    text = describe_dataset(realistic)
    assert "altitude 400.0 to 1000.0 m per scan" in text
    assert "footprint 3 x 3 sub-rays, gaussian spot, centroid range" in text and "snr noise" in text


def test_the_realistic_sensor_recipe_is_what_its_card_says():
    recipe = load_recipe("mars-realistic-sensor")
    build = recipe.build
    assert build.footprint == FootprintConfig(samples=5)
    assert build.noise_model == NoiseModel(kind="snr", snr_ref=25.0, snr_min=5.0)
    assert (build.trajectory.altitude_m, build.trajectory.altitude_max_m) == (250.0, 1000.0)
    published = recipe.checksums()
    assert published is not None and published["config_sha256"] == build.fingerprint()
    assert published["shard_schema_version"] == "1.2"


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--footprint-samples", "0"], "--footprint-samples"),
        (["--footprint-samples", "17"], "--footprint-samples"),
        (["--pulse-width", "0"], "--pulse-width"),
        (["--return-fraction", "1"], "--return-fraction"),
        (["--noise-model", "poisson"], "--noise-model"),
        (["--snr-min", "-1"], "--snr-min"),
        (["--altitude", "1000:250"], "--altitude"),
        (["--altitude", "250:inf"], "--altitude"),
        (["--tilt", "0:61"], "--tilt"),
    ],
)
def test_the_command_line_refuses_bad_sensor_settings_before_any_work(tmp_path, args, needle):
    out = tmp_path / "never"
    result = CliRunner().invoke(main, ["build-dataset", "--out", str(out), "--scans", "4", *args])
    assert result.exit_code != 0 and needle in result.output and not out.exists()


def test_help_shows_the_new_settings_and_their_ranges():
    text = CliRunner().invoke(main, ["build-dataset", "--help"], terminal_width=200).output
    flags = ("--footprint-samples", "--range-estimator", "--pulse-width", "--noise-model", "--snr-ref", "--snr-min")
    assert all(flag in text for flag in flags)
    assert "1<=x<=16" in text and "LOW:HIGH" in text


def test_noise_drawn_again_from_a_shard_of_the_snr_model_is_the_stored_noise(realistic):
    # the one noise model on the fly: clean points, the stored noise_scale and the dataset's streams
    manifest = read_manifest(realistic)
    sigmas = manifest["sigmas_m"]
    for scan in iter_scans(realistic):
        assert scan.noise_scale is not None and scan.noise_scale.dtype == np.float32
        returned = scan.status == STATUS_RETURN
        scale = scan.noise_scale.astype(np.float64)
        # below 500 m the signal exceeds a whole pixel's at 500 m: sigma shrinks there, as (r / 500 m)
        assert np.isfinite(scale).all() and (scale[returned] > 0.0).all()
        d = scan_directions(NARROW, scan.sensor_attitude)
        ranges = recover_ranges(scan.points_clean, scan.sensor_position, d)
        for s, sigma in enumerate(sigmas):
            again = noisy_points(ranges, d, scan.sensor_position, sigma, 5, scan.scan_index, sigma_scale=scale)
            assert np.array_equal(again, scan.points_noisy[s], equal_nan=True)


def test_the_landing_recipe_is_the_realistic_sensor_at_training_scale_labelled_from_the_terrain():
    landing, sensor = load_recipe("mars-landing"), load_recipe("mars-realistic-sensor")
    build = landing.build
    assert (build.footprint, build.noise_model) == (sensor.build.footprint, sensor.build.noise_model)
    assert (build.trajectory.altitude_m, build.trajectory.altitude_max_m) == (250.0, 1000.0)
    assert build.trajectory.n_scans == 5000 and build.seed != sensor.build.seed
    assert landing.label["truth"] == "terrain"
    published = landing.checksums()
    assert published is not None and published["config_sha256"] == build.fingerprint()
    card = (Path(landing.path).parent / "card.md").read_text()
    assert "--truth clean-scan" in card and "split 4000/500/500" in card


def test_label_with_a_recipe_takes_its_truth_and_may_name_the_other(tmp_path):
    """A recipe's [label] truth is what `hd label --recipe` makes; --truth picks the other truth of the
    same lander and DEM, while the lander and DEM options stay refused."""
    dtm = rough_dtm(tmp_path / "rough.tif")
    data = tmp_path / "data"
    build_dataset(
        data,
        BuildConfig(
            sigmas_m=(0.02,),
            sensor=SensorConfig(rows=24, cols=24),
            trajectory=TrajectoryConfig(n_scans=2, altitude_m=250.0),
            dtm_path=str(dtm),
        ),
        workers=1,
    )
    recipe = tmp_path / "r"
    recipe.mkdir()
    (recipe / "recipe.toml").write_text(
        '[dataset]\nname = "r"\nversion = 1\n\n[build]\nscans = 2\nsigmas_m = [0.02]\n\n'
        '[label]\nconvention = "paper"\ndem_size = 16\ntruth = "terrain"\n'
    )
    runner = CliRunner()
    result = runner.invoke(main, ["label", str(data), "--recipe", str(recipe), "--workers", "1"])
    assert result.exit_code == 0, result.output
    result = runner.invoke(
        main, ["label", str(data), "--recipe", str(recipe), "--truth", "clean-scan", "--workers", "1"]
    )
    assert result.exit_code == 0, result.output
    truths = sorted(lab.get("truth", "clean-scan") for lab in read_manifest(data)["labelings"])
    assert truths == ["clean-scan", "terrain"]
    result = runner.invoke(main, ["label", str(data), "--recipe", str(recipe), "--dem-size", "20"])
    assert result.exit_code != 0 and "--recipe fixes the lander and DEM settings" in result.output
