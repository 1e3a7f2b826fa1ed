"""Real relief plus procedural rocks (``lidarsim.base_relief``, ``hd make-dtm --base``)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import h5py
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.crs import CRS
from terrain_files import plane, write_tif

from hdcli.cli import main
from hdcore.storage import sha256_file
from lidarsim import terrain_defaults as td
from lidarsim.base_relief import resample_bilinear, rocks_on_base
from lidarsim.build import BuildConfig, build_dataset
from lidarsim.errors import TerrainError
from lidarsim.procedural import (
    MarsTerrainParams,
    expected_rock_count,
    rock_q_per_m,
    sample_rock_diameters,
    terrain_stream,
)
from lidarsim.sensor import SensorConfig
from lidarsim.shards import read_manifest
from lidarsim.trajectory import TrajectoryConfig

# A tilted plane on a coarse grid, as HiRISE posts: 3 m cells, 40 x 30 cells (120 m x 90 m).
BASE_SPACING, ROWS, COLS, ORIGIN = 3.0, 30, 40, (1000.0, 5000.0)
Z0, GX, GY = 10.0, 0.05, -0.02
NO_ROCKS = dataclasses.replace(MarsTerrainParams(), rock_k=0.0)


@pytest.fixture
def base(tmp_path: Path) -> Path:
    return write_tif(
        tmp_path / "base.tif",
        plane(ROWS, COLS, BASE_SPACING, Z0, GX, GY),
        BASE_SPACING,
        ORIGIN,
        crs=CRS.from_epsg(32610),
    )


def _plane_at(shape: tuple[int, int], spacing: float) -> np.ndarray:
    """The base plane at the centres of the output cells (same top-left corner)."""
    return plane(shape[0], shape[1], spacing, Z0, GX, GY)


def test_a_plane_resamples_to_the_same_plane_inside_the_outer_centres(base: Path) -> None:
    out = rocks_on_base(base, NO_ROCKS, seed=0, spacing_m=0.5)
    assert out.heights.shape == (180, 240) and out.n_rocks == 0
    expected = _plane_at(out.heights.shape, 0.5)
    # Inside the outermost base centres (1.5 m from the edge) bilinear interpolation of a plane is exact.
    inner = (slice(3, -3), slice(3, -3))
    np.testing.assert_allclose(out.heights[inner], expected[inner], atol=1e-4)
    # Beyond them the edge value is kept: rows 0-2 (0.25-1.25 m) take the first base row (1.5 m).
    x = 5.5 * 0.5
    for row in (0, 1, 2):
        assert out.heights[row, 5] == pytest.approx(Z0 + GX * x + GY * -1.5, abs=1e-5)
    assert out.origin_xy == ORIGIN and CRS.from_wkt(out.crs_wkt).to_epsg() == 32610


def test_resample_bilinear_by_hand() -> None:
    src = np.array([[0.0, 2.0], [4.0, 6.0]])  # cells 2 m wide: centres at 1 m and 3 m
    out = resample_bilinear(src, (2.0, 2.0), 1.0, (4, 4))  # centres at 0.5, 1.5, 2.5, 3.5 m
    # Column weights along x: 0.5 -> clamp 0; 1.5 -> 0.25; 2.5 -> 0.75; 3.5 -> clamp 1.
    np.testing.assert_allclose(out[0], [0.0, 0.5, 1.5, 2.0])
    np.testing.assert_allclose(out[:, 0], [0.0, 1.0, 3.0, 4.0])
    with_nan = resample_bilinear(np.array([[0.0, np.nan], [4.0, 6.0]]), (2.0, 2.0), 1.0, (4, 4))
    assert np.isnan(with_nan[0, 3]) and np.isnan(with_nan[1, 1]) and with_nan[3, 0] == 4.0


def test_rocks_leave_the_base_relief_alone_where_none_lands(base: Path) -> None:
    params = dataclasses.replace(MarsTerrainParams(), rock_k=0.2)
    bare = rocks_on_base(base, NO_ROCKS, seed=4, spacing_m=0.5).heights
    rocky = rocks_on_base(base, params, seed=4, spacing_m=0.5)
    assert rocky.n_rocks > 100
    diff = rocky.heights.astype(np.float64) - bare
    assert diff.min() >= -1e-6  # rocks rest on the relief, never dig into it
    # Cells no rock reaches (centre outside every rock's radius, rocks drawn again from the stream):
    # the base relief to 1 mm (here exactly).
    rng = terrain_stream(4, td.PURPOSE_ROCKS)
    rows, cols = rocky.heights.shape
    diam = sample_rock_diameters(0.2, td.ROCK_D_MIN_M, td.ROCK_D_MAX_M, rows * cols * 0.25, rng)
    xy = rng.random((diam.size, 2)) * np.array([cols * 0.5, rows * 0.5])
    assert diam.size == rocky.n_rocks
    yy, xx = np.mgrid[0:rows, 0:cols]
    reached = np.zeros((rows, cols), dtype=bool)
    for (x, y), d in zip(xy, diam, strict=True):
        reached |= (((xx + 0.5) * 0.5 - x) ** 2 + ((yy + 0.5) * 0.5 - y) ** 2) < (d / 2) ** 2
    assert 0.05 < reached.mean() < 0.5
    np.testing.assert_allclose(rocky.heights[~reached], bare[~reached], atol=1e-3)
    assert (diff[reached] > 1e-3).mean() > 0.9
    # The highest rock stands no more than height_ratio * D_max above the relief.
    assert diff.max() <= params.rock_height_ratio * params.rock_d_max_m + 1e-4


def test_rock_count_matches_golombek_rapp(base: Path) -> None:
    k = 0.2
    params = dataclasses.replace(MarsTerrainParams(), rock_k=k)
    out = rocks_on_base(base, params, seed=1, spacing_m=0.5)
    area = 120.0 * 90.0
    expected = expected_rock_count(k, td.ROCK_D_MIN_M, td.ROCK_D_MAX_M, area)
    assert abs(out.n_rocks - expected) < 4 * math.sqrt(expected)
    # Area covered above 1.5 rock height ~ the cumulative fractional area of the larger rocks:
    # a cell is raised by > 0.25 m only inside a rock of D > 0.5 m (H = D/2) - rough but bounded.
    q = rock_q_per_m(k)
    bare = rocks_on_base(base, NO_ROCKS, seed=1, spacing_m=0.5).heights
    raised = float(np.mean(out.heights - bare > 0.25))
    assert 0.2 * k * math.exp(-q * 0.5) < raised < k * math.exp(-q * 0.5)


def test_same_seed_same_terrain_and_tags_name_the_base(base: Path) -> None:
    a = rocks_on_base(base, seed=7, spacing_m=0.5)
    b = rocks_on_base(base, seed=7, spacing_m=0.5)
    c = rocks_on_base(base, seed=8, spacing_m=0.5)
    np.testing.assert_array_equal(a.heights, b.heights)
    assert not np.array_equal(a.heights, c.heights)
    assert a.tags["base_sha256"] == sha256_file(base) and a.tags["base"] == "base.tif"
    assert json.loads(a.tags["params"])["rock_k"] == td.ROCK_K and a.tags["seed"] == "7"


def test_small_craters_dig_below_the_relief(base: Path) -> None:
    params = dataclasses.replace(NO_ROCKS, crater_d_max_m=8.0, crater_n_gt_10m_per_km2=2000.0)
    out = rocks_on_base(base, params, seed=2, spacing_m=0.5, craters=True)
    bare = rocks_on_base(base, NO_ROCKS, seed=2, spacing_m=0.5).heights
    assert out.n_craters > 10
    depth = bare - out.heights
    # Bowls dig in (depth up to 0.2 D = 1.6 m each, more where craters overlap), rims and ejecta rise.
    assert depth.max() > 0.2 and depth.min() < -0.05
    assert json.loads(out.tags["params"])["crater_d_max_m"] == 8.0


@pytest.mark.parametrize("spacing", [0.0, 0.6, math.nan])
def test_bad_spacing_is_refused(base: Path, spacing: float) -> None:
    with pytest.raises(TerrainError, match="spacing"):
        rocks_on_base(base, spacing_m=spacing)


def test_make_dtm_base_writes_a_georeferenced_rocky_dtm(base: Path, tmp_path: Path) -> None:
    out = tmp_path / "rocky.tif"
    runner = CliRunner()
    result = runner.invoke(main, ["make-dtm", str(out), "--base", str(base), "--seed", "3", "--craters-below", "6"])
    assert result.exit_code == 0, result.output
    assert "rocks" in result.output and "craters of 2-6 m" in result.output
    with rasterio.open(out) as src:
        assert src.res == (0.5, 0.5) and src.crs.to_epsg() == 32610
        assert (src.transform.c, src.transform.f) == ORIGIN and src.shape == (180, 240)
        assert src.tags()["base_sha256"] == sha256_file(base)
    for args, needle in (
        (["make-dtm", str(base), "--base", str(base), "--overwrite"], "is the base DTM"),
        (["make-dtm", str(tmp_path / "x.tif"), "--base", str(base), "--size", "100"], "exclude each other"),
        (["make-dtm", str(tmp_path / "x.tif"), "--craters-below", "5"], "needs --base"),
        (["make-dtm", str(tmp_path / "x.tif"), "--base", str(base), "--spacing", "1"], "spacing"),
    ):
        bad = runner.invoke(main, args)
        assert bad.exit_code != 0 and needle in bad.output, (args, bad.output)
        lines = bad.output.strip().splitlines()
        # one line; a value outside its declared range is click's usage error (usage hint, then Error:)
        assert len(lines) == 1 or (bad.exit_code == 2 and lines[-1].startswith("Error: ")), bad.output
    assert sha256_file(base) == sha256_file(base)  # the base is untouched (readable, same bytes)


def test_a_build_with_rocks_on_the_dtm_scans_the_rocky_terrain(base: Path, tmp_path: Path) -> None:
    cfg = BuildConfig(
        sigmas_m=(0.03,),
        seed=5,
        sensor=SensorConfig(rows=16, cols=16),
        trajectory=TrajectoryConfig(n_scans=3, altitude_m=200.0),
        dtm_path=str(base),
        shard_size=3,
        rocks_on_dtm=True,
    )
    plain = dataclasses.replace(cfg, rocks_on_dtm=False)
    assert "rocks_on_dtm" not in plain.to_dict() and plain.to_dict()["terrain"] is None
    assert cfg.to_dict()["rocks_on_dtm"] is True and cfg.fingerprint() != plain.fingerprint()
    build_dataset(tmp_path / "d", cfg, workers=1)
    terrain = tmp_path / "d" / "terrain" / "base-rocks-seed5.tif"
    with rasterio.open(terrain) as src:
        assert src.tags()["base_sha256"] == sha256_file(base) and src.res == (0.5, 0.5)
    manifest = read_manifest(tmp_path / "d")
    with h5py.File(tmp_path / "d" / manifest["shards"][0]["path"]) as f:
        assert f.attrs["dtm_sha256"] == sha256_file(terrain)
    with pytest.raises(ValueError, match="full resolution"):
        dataclasses.replace(cfg, dtm_scale=0.5)


def test_a_recipe_names_its_dtm_by_sha256_and_may_put_rocks_on_it(base: Path, tmp_path: Path) -> None:
    from lidarsim.errors import RecipeError
    from lidarsim.recipe import load_recipe

    def recipe(extra: str) -> Path:
        (tmp_path / "recipe.toml").write_text(f'[build]\nscans = 3\ndtm = "{base}"\n{extra}')
        return tmp_path

    digest = sha256_file(base)
    loaded = load_recipe(recipe(f'dtm_sha256 = "{digest}"\nrocks_on_dtm = true\n'))
    assert loaded.build.rocks_on_dtm and loaded.build.dtm_path == str(base)
    for extra, needle in (
        (f'dtm_sha256 = "{"0" * 64}"\n', "not the recipe's terrain"),
        ('dtm_sha256 = "abc"\n', "64 hex digits"),
        ("rocks_on_dtm = 1\n", "true or false"),
    ):
        with pytest.raises(RecipeError, match=needle) as info:
            load_recipe(recipe(extra))
        assert str(info.value).count("recipe.toml") == 1


def test_the_card_of_a_build_with_rocks_on_the_dtm_lists_only_the_rock_settings(base: Path, tmp_path: Path) -> None:
    """Such a build takes its relief from the DTM: the card names the rock population it added,
    not the procedural relief and crater fields, which the build does not use."""
    from lidarsim.card import render_card
    from lidarsim.recipe import load_recipe

    (tmp_path / "recipe.toml").write_text(f'[build]\nscans = 3\ndtm = "{base}"\nrocks_on_dtm = true\n')
    recipe = load_recipe(tmp_path)
    cfg = dataclasses.replace(
        recipe.build, sensor=SensorConfig(rows=16, cols=16), trajectory=TrajectoryConfig(n_scans=3, altitude_m=200.0)
    )
    build_dataset(tmp_path / "d", cfg, workers=1)
    card = render_card(tmp_path / "d", recipe)
    line = next(x for x in card.splitlines() if "rocks added to the DTM" in x)
    assert '"rock_k": 0.08' in line and '"spacing_m": 0.5' in line
    assert "crater" not in card and "relief_" not in card and "procedural terrain:" not in card
