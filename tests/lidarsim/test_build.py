"""The dataset factory end to end: determinism, resume after a kill, Dask, bad input, real terrain."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from hdcli.cli import main
from lidarsim.build import BuildConfig, assign_splits, build_dataset
from lidarsim.sensor import SensorConfig
from lidarsim.shards import ScanShardReader, iter_scans, read_manifest, verify_dataset
from lidarsim.trajectory import TrajectoryConfig
from tests.geotiff import write_geotiff

REPO = Path(__file__).resolve().parents[2]
REAL = REPO.parent / "shared" / "data" / "real-terrain"
SMALL_SENSOR = SensorConfig(rows=32, cols=32)


def rough_dtm(
    path: Path, n: int = 320, spacing: float = 0.5, origin=(1000.0, 2000.0), crs: str | None = None, seed: int = 3
) -> Path:
    """A small rough terrain GeoTIFF (seeded)."""
    rng = np.random.default_rng(seed)
    z = np.cumsum(np.cumsum(rng.normal(0, 0.02, (n, n)), axis=0), axis=1)
    z += rng.normal(0, 0.05, (n, n))
    return write_geotiff(path, z, spacing, origin, crs)


def small_config(dtm: Path, **kw) -> BuildConfig:
    traj = kw.pop("trajectory", TrajectoryConfig(n_scans=12, altitude_m=500.0))
    return BuildConfig(
        sigmas_m=kw.pop("sigmas_m", (0.0167, 0.07)),
        seed=kw.pop("seed", 5),
        sensor=SMALL_SENSOR,
        trajectory=traj,
        dtm_path=str(dtm),
        shard_size=kw.pop("shard_size", 4),
        **kw,
    )


def load_arrays(directory: Path) -> dict[str, np.ndarray]:
    out: dict[str, list[np.ndarray]] = {}
    for entry in read_manifest(directory)["shards"]:
        with h5py.File(directory / entry["path"]) as f:
            for key in (
                "scan_index",
                "split",
                "origin_map",
                "sensor_attitude",
                "points_clean",
                "points_noisy",
                "status",
            ):
                out.setdefault(key, []).append(f[key][:])
    return {k: np.concatenate(v) for k, v in out.items()}


@pytest.fixture(scope="module")
def dtm(tmp_path_factory) -> Path:
    return rough_dtm(tmp_path_factory.mktemp("dtm") / "rough.tif")


def test_workers_and_shard_size_do_not_change_the_data(tmp_path, dtm):
    a = build_dataset(tmp_path / "a", small_config(dtm), workers=1)
    b = build_dataset(tmp_path / "b", small_config(dtm), workers=2)
    c = build_dataset(tmp_path / "c", small_config(dtm, shard_size=5), workers=2)
    assert a.n_scans == b.n_scans == c.n_scans == 12
    arrays_a, arrays_b, arrays_c = (load_arrays(tmp_path / n) for n in "abc")
    for key in arrays_a:
        np.testing.assert_array_equal(arrays_a[key], arrays_b[key], err_msg=key)
        np.testing.assert_array_equal(arrays_a[key], arrays_c[key], err_msg=key)
    # same shard size: byte-identical files
    ma, mb = read_manifest(tmp_path / "a"), read_manifest(tmp_path / "b")
    assert [s["sha256"] for s in ma["shards"]] == [s["sha256"] for s in mb["shards"]]
    assert verify_dataset(tmp_path / "a") == []


def test_shard_round_trip_and_lazy_reader(tmp_path, dtm):
    out = tmp_path / "d"
    build_dataset(out, small_config(dtm), workers=1)
    manifest = read_manifest(out)
    assert manifest["n_scans"] == 12 and len(manifest["shards"]) == 3
    assert sum(s["n_scans"] for s in manifest["shards"]) == 12
    scans = list(iter_scans(out))
    assert [s.scan_index for s in scans] == list(range(12))
    with ScanShardReader(out / manifest["shards"][1]["path"]) as reader:
        assert len(reader) == 4 and reader.sigmas_m == (0.0167, 0.07)
        scan = reader[2]
        assert scan.scan_index == 6
        assert scan.points_clean.shape == (32, 32, 3) and scan.points_clean.dtype == np.float32
        assert scan.points_noisy.shape == (2, 32, 32, 3)
        np.testing.assert_allclose(scan.sensor_position, [0, 0, 500.0])
        # plain h5py sees the same numbers, chunked per scan and compressed
        f = reader.h5
        assert f["points_clean"].chunks == (1, 32, 32, 3) and f["points_clean"].compression == "gzip"
        assert all(f[name].fletcher32 for name in f)  # every chunk checksummed (schema 1.1)
        assert f.attrs["schema"] == "hd.lidar-scans" and f.attrs["schema_version"] == "1.1"
        np.testing.assert_array_equal(f["points_noisy"][2, 1], scan.points_noisy[1])
        assert f.attrs["dtm_sha256"] == manifest["dtm"]["sha256"]
    # points are near the terrain: about 500 m below the sensor
    z = scans[0].points_clean[..., 2]
    assert np.nanmax(np.abs(z)) < 20


def kill_after_two_shards(argv: list[str], out: Path) -> None:
    """Run ``hd ARGV --out OUT`` in its own process and SIGKILL it once two shard files are written;
    the build must not have finished (no manifest)."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "hdcli", *argv, "--out", str(out)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 60
    while time.time() < deadline and len(list((out / "shards").glob("scans-*.h5"))) < 2:
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (out / "manifest.json").exists(), "the build finished before it could be killed"


def test_resume_after_kill_gives_the_uninterrupted_dataset(tmp_path, dtm):
    reference = tmp_path / "ref"
    argv = [
        "build-dataset",
        "--dtm",
        str(dtm),
        "--scans",
        "16",
        "--shard-size",
        "2",
        "--sigma",
        "0.03",
        "--seed",
        "9",
        "--workers",
        "1",
        "--resolution",
        "48",
    ]
    assert CliRunner().invoke(main, [*argv, "--out", str(reference)]).exit_code == 0
    out = tmp_path / "killed"
    kill_after_two_shards(argv, out)
    result = CliRunner().invoke(main, [*argv, "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "already complete" in result.output
    ref_m, out_m = read_manifest(reference), read_manifest(out)
    assert [s["sha256"] for s in ref_m["shards"]] == [s["sha256"] for s in out_m["shards"]]
    assert not list((out / "shards").glob(".*partial*"))
    assert not (out / ".hd-build.json").exists()


def test_existing_output_is_never_overwritten_without_the_flag(tmp_path, dtm):
    out = tmp_path / "d"
    build_dataset(out, small_config(dtm), workers=1)
    before = (out / "manifest.json").read_text()
    argv = ["build-dataset", "--out", str(out), "--dtm", str(dtm), "--scans", "12", "--resolution", "32"]
    result = CliRunner().invoke(main, argv)
    # Other settings (the CLI's default sigma and seed): refused, the differences named.
    assert result.exit_code != 0 and "--overwrite" in result.output
    assert "sigmas_m [0.0167, 0.07] -> [0.0167]" in result.output and "seed 5 -> 0" in result.output
    assert (out / "manifest.json").read_text() == before
    # The identical command again: done already, exit 0, nothing touched.
    same = [*argv, "--sigma", "0.0167", "--sigma", "0.07", "--seed", "5", "--shard-size", "4"]
    result = CliRunner().invoke(main, same)
    assert result.exit_code == 0 and "already holds this dataset" in result.output, result.output
    assert (out / "manifest.json").read_text() == before
    # Its shards gone: not the same dataset any more, and said so.
    shard = out / read_manifest(out)["shards"][0]["path"]
    shard.rename(shard.with_suffix(".moved"))
    result = CliRunner().invoke(main, same)
    assert result.exit_code != 0 and "hd verify" in result.output
    shard.with_suffix(".moved").rename(shard)
    result = CliRunner().invoke(main, [*argv, "--overwrite", "--sigma", "0.05"])
    assert result.exit_code == 0, result.output
    assert read_manifest(out)["sigmas_m"] == [0.05]


def test_foreign_directory_is_refused(tmp_path, dtm):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.txt").write_text("precious")
    result = CliRunner().invoke(main, ["build-dataset", "--out", str(out), "--dtm", str(dtm), "--overwrite"])
    assert result.exit_code != 0 and "not an hd dataset" in result.output
    assert (out / "thesis.txt").read_text() == "precious"


def test_dask_local_cluster_gives_the_same_data(tmp_path, dtm):
    distributed = pytest.importorskip("distributed")
    build_dataset(tmp_path / "pool", small_config(dtm), workers=1)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        build_dataset(tmp_path / "dask", small_config(dtm), scheduler=cluster.scheduler_address)
    a, b = load_arrays(tmp_path / "pool"), load_arrays(tmp_path / "dask")
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_splits_are_block_shuffled_and_independent_of_shards():
    s = assign_splits(1000, seed=0)
    assert np.bincount(s).tolist() == [800, 100, 100]
    blocks = s.reshape(20, 50)
    assert (blocks == blocks[:, :1]).all()  # blocks of 50 consecutive scans share a split
    assert not np.array_equal(s, assign_splits(1000, seed=1))


# ---------------------------------------------------------------- bad input: one line, exit != 0, nothing written


def _run_bad(tmp_path: Path, *args: str) -> str:
    out = tmp_path / "never"
    result = CliRunner().invoke(main, ["build-dataset", "--out", str(out), *args])
    assert result.exit_code != 0
    assert not out.exists(), "bad input must not create the output"
    assert "Traceback" not in result.output
    message = result.output.strip().splitlines()[-1]
    assert message.startswith("Error: ")
    return message


def test_bad_inputs_are_refused_with_one_line(tmp_path, dtm):
    msg = _run_bad(tmp_path, "--dtm", str(tmp_path / "missing.tif"))
    assert "missing.tif" in msg
    junk = tmp_path / "junk.tif"
    junk.write_text("this is not a raster")
    assert "junk.tif" in _run_bad(tmp_path, "--dtm", str(junk))
    assert "sigma" in _run_bad(tmp_path, "--dtm", str(dtm), "--sigma", "0").lower()
    assert "sigma" in _run_bad(tmp_path, "--dtm", str(dtm), "--sigma", "-0.01").lower()
    assert "sigma" in _run_bad(tmp_path, "--dtm", str(dtm), "--sigma", "nan").lower()
    assert "scans" in _run_bad(tmp_path, "--dtm", str(dtm), "--scans", "0").lower()
    assert "dtm-scale" in _run_bad(tmp_path, "--dtm", str(dtm), "--dtm-scale", "0")
    msg = _run_bad(tmp_path, "--dtm", str(dtm), "--altitude", "2000")
    assert "too small" in msg and "--altitude" in msg
    assert "workers" in _run_bad(tmp_path, "--dtm", str(dtm), "--workers", "0")


def test_all_nodata_and_geographic_dtms_are_refused(tmp_path):
    nodata = write_geotiff(tmp_path / "empty.tif", np.full((50, 50), -9999.0), 1.0, (0.0, 50.0), nodata=-9999)
    assert "nodata" in _run_bad(tmp_path, "--dtm", str(nodata))
    geo = rough_dtm(tmp_path / "geo.tif", n=50, spacing=0.001, origin=(10.0, 45.0), crs="EPSG:4326")
    assert "geographic" in _run_bad(tmp_path, "--dtm", str(geo))


def test_verify_and_inspect_catch_damage_and_unknown_versions(tmp_path, dtm):
    out = tmp_path / "d"
    build_dataset(out, small_config(dtm), workers=1)
    runner = CliRunner()
    ok = runner.invoke(main, ["verify", str(out)])
    assert ok.exit_code == 0 and "OK" in ok.output
    assert "12 in 3 shards" in runner.invoke(main, ["inspect", str(out)]).output
    shard = out / read_manifest(out)["shards"][0]["path"]
    with h5py.File(shard, "r+") as f:
        f.attrs["schema_version"] = "2.0"
    bad = runner.invoke(main, ["verify", str(out)])  # the attribute grew the file: its size is named first
    assert bad.exit_code != 0 and ("checksum mismatch" in bad.output or "size mismatch" in bad.output)
    # fix the checksum in the manifest: now the schema version is what is wrong
    manifest = json.loads((out / "manifest.json").read_text())
    from lidarsim.shards import sha256_file

    manifest["shards"][0]["sha256"] = sha256_file(shard)
    manifest["shards"][0]["size_bytes"] = shard.stat().st_size
    (out / "manifest.json").write_text(json.dumps(manifest))
    bad = runner.invoke(main, ["verify", str(out)])
    assert bad.exit_code != 0 and "version 2.0 is not supported" in bad.output
    bad = runner.invoke(main, ["inspect", str(out)])
    assert bad.exit_code != 0 and "version 2.0 is not supported" in bad.output
    manifest["schema_version"] = "7.1"
    (out / "manifest.json").write_text(json.dumps(manifest))
    bad = runner.invoke(main, ["inspect", str(out)])
    assert bad.exit_code != 0 and "version 7.1" in bad.output
    assert runner.invoke(main, ["verify", str(tmp_path)]).exit_code != 0  # not a dataset


# ---------------------------------------------------------------- real terrain


@pytest.mark.skipif(not REAL.is_dir(), reason="shared real-terrain data not present")
def test_real_terrain_autzen_builds_and_ames_needs_a_lower_altitude(tmp_path):
    out = tmp_path / "autzen"
    config = BuildConfig(
        sigmas_m=(0.03,),
        sensor=SMALL_SENSOR,
        trajectory=TrajectoryConfig(n_scans=6),
        dtm_path=str(REAL / "autzen-ground-1m.tif"),
        shard_size=3,
    )
    build_dataset(out, config, workers=1)
    for scan in iter_scans(out):
        assert scan.valid.all()  # footprints were placed on valid terrain only
        z_map = scan.points_clean[..., 2] + scan.origin_map[2]
        assert np.nanmin(z_map) > 123.0 and np.nanmax(z_map) < 133.0
    msg = _run_bad(tmp_path, "--dtm", str(REAL / "ames-0.5m.tif"), "--scans", "5")
    assert "too small" in msg and "ames-0.5m.tif" in msg
    out = tmp_path / "ames"
    config = BuildConfig(
        sigmas_m=(0.03,),
        sensor=SMALL_SENSOR,
        trajectory=TrajectoryConfig(n_scans=4, altitude_m=150.0),
        dtm_path=str(REAL / "ames-0.5m.tif"),
        shard_size=4,
    )
    build_dataset(out, config, workers=1)
    for scan in iter_scans(out):
        assert scan.valid.all()
        assert scan.origin_map[1] > 4.1e6  # UTM northing kept in float64
        z_map = scan.points_clean[..., 2] + scan.origin_map[2]
        assert np.nanmin(z_map) > 2.7 and np.nanmax(z_map) < 5.5


def test_recipes_parse_and_mars_paper_is_what_reproduce_builds():
    from lidarsim import defaults
    from lidarsim.recipe import load_recipe

    paper = load_recipe(REPO / "datasets" / "mars-paper")
    reproduce = BuildConfig(
        sigmas_m=defaults.PAPER_SIGMAS_M, seed=0, trajectory=TrajectoryConfig(n_scans=defaults.N_SCANS)
    )
    assert paper.build.fingerprint() == reproduce.fingerprint()
    for name, sigma in (("mars-s167", 0.0167), ("mars-s300", 0.03), ("mars-s700", 0.07)):
        r = load_recipe(REPO / "datasets" / name)
        assert r.build.sigmas_m == (sigma,) and r.build.dtm_path is None and r.build.trajectory.n_scans == 1000
    user = load_recipe(REPO / "datasets" / "user-dtm-paper")
    assert user.build.dtm_path is not None and user.build.dtm_path.endswith("sabrina.tif")
    assert user.build.sigmas_m == paper.build.sigmas_m
    for name in ("mars-paper", "mars-s167", "mars-s300", "mars-s700", "user-dtm-paper"):
        r = load_recipe(REPO / "datasets" / name)
        assert r.version == 2 and r.label["convention"] == "paper" and r.label["gridding"] == "nearest"
    # Real Mars: the Jezero DTM ships beside its recipe, named by sha256; the rocks recipe builds on it.
    jezero, rocky = (load_recipe(REPO / "datasets" / n) for n in ("mars-jezero", "mars-jezero-rocks"))
    dtm = REPO / "datasets" / "mars-jezero" / "jezero-hirise-3.69m.tif"
    assert jezero.build.dtm_path == rocky.build.dtm_path == str(dtm.resolve())
    assert not jezero.build.rocks_on_dtm and rocky.build.rocks_on_dtm
    for r in (jezero, rocky):
        assert r.build.sigmas_m == paper.build.sigmas_m and r.build.trajectory.n_scans == 1000
        assert r.label == load_recipe(REPO / "datasets" / "mars-paper").label
    assert "DTEEC_045994_1985_046060_1985_U01" in (REPO / "datasets" / "mars-jezero" / "SOURCE.md").read_text()
    # Every published build's settings hash is the recipe's here, wherever this checkout lies.
    for published in sorted((REPO / "datasets").glob("*/checksums.json")):
        recorded = json.loads(published.read_text())["config_sha256"]
        assert load_recipe(published.parent).build.fingerprint() == recorded, published.parent.name


def test_build_from_a_recipe_and_verify_against_its_checksums(tmp_path, dtm):
    recipe = tmp_path / "r"
    recipe.mkdir()
    (recipe / "recipe.toml").write_text(
        f'[dataset]\nname = "tiny"\n[build]\nscans = 6\nsigmas_m = [0.03]\nresolution = 32\nshard_size = 3\n'
        f'dtm = "{dtm}"\n[label]\nmax_roughness_m = 0.25\n'
    )
    out = tmp_path / "d"
    runner = CliRunner()
    bad = runner.invoke(main, ["build-dataset", "--recipe", str(recipe), "--out", str(out), "--resolution", "16"])
    assert bad.exit_code != 0 and "--resolution" in bad.output and not out.exists()
    ok = runner.invoke(main, ["build-dataset", "--recipe", str(recipe), "--out", str(out), "--workers", "1"])
    assert ok.exit_code == 0, ok.output
    bad = runner.invoke(main, ["label", str(out), "--recipe", str(recipe), "--max-slope-deg", "8"])
    assert bad.exit_code != 0 and "--max-slope-deg" in bad.output
    labelled = runner.invoke(main, ["label", str(out), "--workers", "1", "--recipe", str(recipe)])
    assert labelled.exit_code == 0, labelled.output
    assert read_manifest(out)["labelings"][0]["lander"]["max_roughness_m"] == 0.25
    card = runner.invoke(main, ["card", str(out), "--recipe", str(recipe)])
    assert card.exit_code == 0, card.output
    card_text = (recipe / "card.md").read_text()
    assert "safe" in card_text
    # the recipe where it is, not a datasets/<name> of a checkout it is not in
    assert f"hd build-dataset --recipe {recipe} --out tiny" in card_text and "datasets/r" not in card_text
    assert f"hd verify tiny --recipe {recipe}" in card_text
    assert runner.invoke(main, ["verify", str(out), "--recipe", str(recipe)]).exit_code == 0
    sums = json.loads((recipe / "checksums.json").read_text())
    sums["shards"][1]["sha256"] = "0" * 64  # the published bytes differ, their content is this shard's
    (recipe / "checksums.json").write_text(json.dumps(sums))
    rebuilt = runner.invoke(main, ["verify", str(out), "--recipe", str(recipe)])
    assert rebuilt.exit_code == 0, rebuilt.output
    assert "shards/scans-00001.h5: rebuilt: equal to the published build within tolerance" in rebuilt.output
    assert "shards/scans-00000.h5: identical (sha256)" in rebuilt.output
    del sums["shards"][1]["content"]  # checksums published without content fingerprints
    (recipe / "checksums.json").write_text(json.dumps(sums))
    bad = runner.invoke(main, ["verify", str(out), "--recipe", str(recipe)])
    assert bad.exit_code != 0 and "differs from the recipe's published build" in bad.output
    bad = runner.invoke(main, ["build-dataset", "--recipe", str(tmp_path / "nope"), "--out", str(tmp_path / "x")])
    assert bad.exit_code != 0 and "no such recipe" in bad.output


def test_a_copied_recipe_reads_its_relative_dtm_beside_it_and_says_so_when_it_is_missing(tmp_path, dtm, monkeypatch):
    import shutil

    from lidarsim.recipe import load_recipe

    original = tmp_path / "a"
    original.mkdir()
    shutil.copy(dtm, original / "site.tif")
    (original / "recipe.toml").write_text('[build]\nscans = 4\nresolution = 16\ndtm = "site.tif"\n')
    copy = tmp_path / "elsewhere" / "b"
    copy.mkdir(parents=True)
    shutil.copy(original / "recipe.toml", copy / "recipe.toml")  # the recipe copied without its DTM
    monkeypatch.chdir(original)  # a DTM of that name in the current directory is not the recipe's
    assert load_recipe(copy).build.dtm_path == str((copy / "site.tif").resolve())  # read without it (verify)
    result = CliRunner().invoke(main, ["build-dataset", "--recipe", str(copy), "--out", str(tmp_path / "x")])
    assert result.exit_code == 1 and result.output.strip().splitlines() == [
        (
            f"Error: {(copy / 'recipe.toml').resolve()}: its DTM {(copy / 'site.tif').resolve()} does not exist (a "
            'relative dtm is read beside the recipe: dtm = "site.tif"); copy the DTM beside the recipe or give its '
            "absolute path"
        )
    ]
    assert not (tmp_path / "x").exists()
    shutil.copy(dtm, copy / "site.tif")
    monkeypatch.chdir(tmp_path / "elsewhere")
    assert load_recipe("b").build.dtm_path == str((copy / "site.tif").resolve())
    assert load_recipe(original / "recipe.toml").build.dtm_path == str((original / "site.tif").resolve())


def test_a_card_names_a_recipe_that_comes_with_hd_by_its_place_in_the_checkout():
    from lidarsim.card import recipe_reference
    from lidarsim.recipe import load_recipe

    for name in ("mars-paper", "mars-jezero"):
        assert recipe_reference(load_recipe(name)) == f"datasets/{name}"  # the published cards' words


@pytest.mark.parametrize("altitude_m", [1e6, 1e9])
def test_an_absurd_altitude_is_refused_at_once(altitude_m):
    """--altitude 1e9 never answered: a 2e8-cell minimum filter ran before the footprint met the terrain."""
    from lidarsim.errors import LidarsimError
    from lidarsim.trajectory import plan_scans

    def too_slow(signum, frame):
        raise TimeoutError("planning took more than 10 s")

    previous = signal.signal(signal.SIGALRM, too_slow)
    signal.alarm(10)
    try:
        with pytest.raises(LidarsimError, match="too small for the sensor footprint"):
            plan_scans(
                np.ones((256, 256), bool),
                (4.0, 0.0, 0.0, 0.0, -4.0, 1024.0),
                SensorConfig(),
                TrajectoryConfig(n_scans=3, altitude_m=altitude_m),
            )
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def test_a_recipe_is_found_by_name_from_anywhere(tmp_path, monkeypatch):
    from lidarsim.errors import RecipeError
    from lidarsim.recipe import RECIPE_PATH_ENV, load_recipe

    monkeypatch.chdir(tmp_path)
    assert load_recipe("mars-paper").path == (REPO / "datasets" / "mars-paper" / "recipe.toml").resolve()
    mine = tmp_path / "shelf" / "mine"
    mine.mkdir(parents=True)
    (mine / "recipe.toml").write_text('[dataset]\nname = "mine"\n[build]\nscans = 5\n')
    with pytest.raises(RecipeError, match="no such recipe") as info:
        load_recipe("mine")
    assert "mars-jezero" in str(info.value) and RECIPE_PATH_ENV in str(info.value)
    monkeypatch.setenv(RECIPE_PATH_ENV, str(tmp_path / "shelf"))
    assert load_recipe("mine").build.trajectory.n_scans == 5
    # A path with a directory part is taken as it is, never looked up by name.
    with pytest.raises(RecipeError, match="no such recipe"):
        load_recipe("elsewhere/mars-paper")
    result = CliRunner().invoke(main, ["build-dataset", "--recipe", "nope", "--out", str(tmp_path / "x")])
    assert result.exit_code != 0 and "no such recipe" in result.output and not (tmp_path / "x").exists()


def test_the_settings_hash_names_the_dtm_by_its_content_not_where_it_lies(tmp_path, dtm):
    """A recipe checked out in two places builds the same bytes: the settings hash and the shards'
    ``config_json`` name the DTM by its file name, not by the path it was read from (its content is
    checked apart: each shard's ``dtm_sha256``, reliability test class E)."""
    import shutil

    here, there = tmp_path / "a" / "rough.tif", tmp_path / "b" / "deeper" / "rough.tif"
    for copy in (here, there):
        copy.parent.mkdir(parents=True)
        shutil.copyfile(dtm, copy)
    cfg_here, cfg_there = small_config(here), small_config(there)
    assert cfg_here.to_dict()["dtm_path"] != cfg_there.to_dict()["dtm_path"]  # the manifest keeps where it was
    assert cfg_here.fingerprint() == cfg_there.fingerprint()
    assert cfg_here.canonical_dict()["dtm_path"] == "rough.tif"
    small = {"trajectory": TrajectoryConfig(n_scans=4, altitude_m=500.0)}
    build_dataset(tmp_path / "da", small_config(here, **small), workers=1)
    build_dataset(tmp_path / "db", small_config(there, **small), workers=1)
    shards = [e["path"] for e in read_manifest(tmp_path / "da")["shards"]]
    for name in shards:
        assert (tmp_path / "da" / name).read_bytes() == (tmp_path / "db" / name).read_bytes(), name
        with h5py.File(tmp_path / "da" / name) as f:
            assert str(tmp_path) not in f.attrs["config_json"]


def test_one_shard_is_one_shard_in_every_summary(tmp_path, dtm):
    runner = CliRunner()
    out = tmp_path / "d"
    args = ["build-dataset", "--dtm", str(dtm), "--out", str(out), "--scans", "3", "--shard-size", "3"]
    built = runner.invoke(main, [*args, "--resolution", "16", "--workers", "1"])
    assert built.exit_code == 0, built.output
    assert "Built 3 scans in 1 shard at" in built.output
    again = runner.invoke(main, [*args, "--resolution", "16", "--workers", "1"])
    assert "(3 scans in 1 shard, sigma" in again.output
    assert "scans     3 in 1 shard, " in runner.invoke(main, ["inspect", str(out)]).output
    labelled = runner.invoke(main, ["label", str(out), "--workers", "1"])
    assert labelled.exit_code == 0 and ": 3 scans in 1 label shard, labelled" in labelled.output, labelled.output
    assert " shards" not in built.output + again.output + labelled.output
