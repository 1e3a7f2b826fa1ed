"""lidarsim.procedural: determinism, shapes, hand-checkable statistics, GeoTIFF round trip."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.crs import CRS

from lidarsim import procedural
from lidarsim import terrain_defaults as td
from lidarsim.errors import TerrainError
from lidarsim.procedural import (
    MarsTerrainParams,
    crater_profile,
    expected_rock_count,
    fractal_relief,
    generate_mars_terrain,
    params_tags,
    rock_q_per_m,
    sample_rock_diameters,
    stamp_crater,
    stamp_rocks,
    write_geotiff,
)
from lidarsim.terrain import DTM

SMALL = MarsTerrainParams(size_m=64.0, spacing_m=0.5, crater_n_gt_10m_per_km2=2000.0, crater_d_max_m=20.0, rock_k=0.1)
FLAT = replace(SMALL, relief_rms_slope_deg=0.0, crater_n_gt_10m_per_km2=0.0, rock_k=0.0)


# ---------------------------------------------------------------------------- shape and determinism
def test_default_terrain_shape_dtype_and_range() -> None:
    heights = generate_mars_terrain()
    assert heights.shape == (2048, 2048) and heights.dtype == np.float32
    assert np.isfinite(heights).all()
    # Relief at 3 deg RMS slope plus craters up to 200 m (floor 0.16 D = 32 m below): tens of metres.
    assert 1.0 < float(heights.max() - heights.min()) < 100.0


def test_shape_follows_size_and_spacing() -> None:
    p = replace(FLAT, size_m=10.2, spacing_m=0.5)
    assert generate_mars_terrain(p).shape == (20, 20)
    assert generate_mars_terrain(replace(FLAT, size_m=16.0, spacing_m=0.25)).shape == (64, 64)


def test_deterministic_in_params_and_seed() -> None:
    a = generate_mars_terrain(SMALL, seed=7)
    b = generate_mars_terrain(SMALL, seed=7)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, generate_mars_terrain(SMALL, seed=8))


def test_components_draw_from_independent_streams() -> None:
    # Rocks only add (max): the terrain without rocks is unchanged under them and elsewhere.
    no_rocks = generate_mars_terrain(replace(SMALL, rock_k=0.0), seed=3)
    rocks = generate_mars_terrain(SMALL, seed=3)
    assert (rocks >= no_rocks).all()
    assert 0.0 < np.mean(rocks > no_rocks) < 0.5
    # Relief alone is the same field whatever the crater/rock settings, scaled by tan(slope).
    relief_2 = generate_mars_terrain(replace(FLAT, relief_rms_slope_deg=2.0), seed=3)
    relief_4 = generate_mars_terrain(replace(FLAT, relief_rms_slope_deg=4.0), seed=3)
    ratio = math.tan(math.radians(4.0)) / math.tan(math.radians(2.0))
    np.testing.assert_allclose(relief_4, relief_2 * ratio, rtol=1e-5, atol=1e-5)
    # Craters alone do not depend on the rock or relief parameters.
    craters = generate_mars_terrain(replace(SMALL, relief_rms_slope_deg=0.0, rock_k=0.0), seed=3)
    craters_other_rocks = generate_mars_terrain(replace(SMALL, relief_rms_slope_deg=0.0, rock_k=0.4), seed=3)
    assert (craters_other_rocks >= craters).all()
    assert np.mean(craters_other_rocks == craters) > 0.5


def test_relief_rms_slope_matches_target() -> None:
    rng = np.random.default_rng(0)
    heights = fractal_relief(256, 0.5, 0.8, 5.0, 1.0, rng)
    dz = np.concatenate([(np.roll(heights, -2, 0) - heights).ravel(), (np.roll(heights, -2, 1) - heights).ravel()])
    assert math.degrees(math.atan(np.sqrt(np.mean(dz**2)) / 1.0)) == pytest.approx(5.0, rel=1e-9)
    assert abs(heights.mean()) < 1e-9


def test_relief_is_self_affine_with_the_hurst_exponent() -> None:
    heights = fractal_relief(1024, 0.5, 0.8, 3.0, 1.0, np.random.default_rng(1))
    # Structure function rms(lag) ~ lag^H at lags far below the (periodic) tile size.
    rms = [np.sqrt(np.mean((np.roll(heights, -lag, 1) - heights) ** 2)) for lag in (2, 8)]
    hurst = math.log(rms[1] / rms[0]) / math.log(8 / 2)
    assert hurst == pytest.approx(0.8, abs=0.05)


# ---------------------------------------------------------------------------- craters
def test_single_crater_depth_and_rim() -> None:
    d = 20.0
    heights = np.zeros((200, 200), dtype=np.float64)
    stamp_crater(heights, 0.5, (50.0, 50.0), d)  # centre on a cell corner -> symmetric
    floor = heights.min()
    rim = heights.max()
    assert rim - floor == pytest.approx(0.2 * d, rel=0.01)  # depth rim crest to floor ~ 0.2 D
    assert rim == pytest.approx(0.04 * d, rel=0.01)  # rim ~ 0.04 D above the surroundings
    assert floor == pytest.approx(-(0.2 - 0.04) * d, rel=0.01)
    # Ejecta: tapered to zero at 3 radii.
    r = np.hypot(*np.meshgrid((np.arange(200) + 0.5) * 0.5 - 50.0, (np.arange(200) + 0.5) * 0.5 - 50.0))
    assert np.all(heights[r >= 3 * d / 2] == 0.0)
    assert np.all(heights[(r > d / 2) & (r < 1.4 * d / 2)] > 0.0)


def test_crater_profile_closed_form() -> None:
    p = MarsTerrainParams()
    r = np.array([0.0, 5.0, 10.0, 20.0, 30.0, 40.0])
    z = crater_profile(r, 20.0, p)
    tail = 3.0**-3
    expected = [-3.2, -3.2 + 4.0 * 0.25, 0.8, 0.8 * (2.0**-3 - tail) / (1 - tail), 0.0, 0.0]
    np.testing.assert_allclose(z, expected, atol=1e-12)


def test_crater_count_follows_the_sfd() -> None:
    p = replace(SMALL, size_m=1000.0, crater_n_gt_10m_per_km2=300.0, crater_d_min_m=5.0, crater_d_max_m=50.0)
    _centers, diameters = procedural.sample_craters(p, np.random.default_rng(0))
    side = 1000.0 + 2 * 0.5 * 50.0 * 3.0
    expected = 300.0 * ((5 / 10) ** -2 - (50 / 10) ** -2) * side**2 / 1e6
    assert abs(len(diameters) - expected) < 4 * math.sqrt(expected)
    assert diameters.min() >= 5.0 and diameters.max() <= 50.0
    # Half of the craters above D are above D*sqrt(2) for a -2 power law (far from the cut-offs).
    n10, n14 = np.sum(diameters > 10.0), np.sum(diameters > 10.0 * math.sqrt(2))
    frac = (1 / 2 - 1 / 25) / (1 - 1 / 25 * 4)  # (N(>14.1)-N(>50)) / (N(>10)-N(>50)) in units of N10
    assert n14 / n10 == pytest.approx(frac, abs=4 * math.sqrt(frac * (1 - frac) / n10))


# ---------------------------------------------------------------------------- rocks
def test_golombek_rapp_q() -> None:
    assert rock_q_per_m(0.1) == pytest.approx(1.79 + 1.52)
    assert rock_q_per_m(0.4) == pytest.approx(1.79 + 0.38)


def test_rock_area_integrates_to_the_cumulative_fractional_area() -> None:
    k, d0, d1 = 0.2, 0.5, 2.0
    q = rock_q_per_m(k)
    d = np.geomspace(d0, d1, 20001)
    dens = procedural._rock_number_density(d, k)
    area = np.trapezoid(math.pi * d**2 / 4 * dens, d)
    assert area == pytest.approx(k * (math.exp(-q * d0) - math.exp(-q * d1)), rel=1e-6)


def test_rock_count_and_area_match_golombek_rapp() -> None:
    k, d0, d1, area = 0.2, 0.4, 3.0, 4000.0
    rng = np.random.default_rng(11)
    diam = sample_rock_diameters(k, d0, d1, area, rng)
    expected = expected_rock_count(k, d0, d1, area)
    assert abs(diam.size - expected) < 4 * math.sqrt(expected)
    assert diam.min() >= d0 and diam.max() <= d1
    # Fraction of the area covered by rocks >= 1 m vs F_k(1) - F_k(3).
    q = rock_q_per_m(k)
    covered = np.sum(math.pi * diam[diam >= 1.0] ** 2 / 4) / area
    assert covered == pytest.approx(k * (math.exp(-q) - math.exp(-3 * q)), rel=0.25)


def test_no_rocks_when_k_is_zero() -> None:
    assert sample_rock_diameters(0.0, 0.4, 3.0, 1e6, np.random.default_rng(0)).size == 0
    assert expected_rock_count(0.0, 0.4, 3.0, 1e6) == 0.0


def test_single_rock_is_a_half_ellipsoid_on_the_ground() -> None:
    heights = np.full((20, 20), 1.0)
    stamp_rocks(heights, 0.5, np.array([[5.25, 5.25]]), np.array([2.0]))  # centre of cell (10, 10)
    assert heights[10, 10] == pytest.approx(2.0)  # 1 m ground + 0.5 * 2 m
    assert heights[10, 11] == pytest.approx(1.0 + 1.0 * math.sqrt(1 - 0.25))  # r = 0.5 m of R = 1 m
    assert heights[10, 12] == pytest.approx(1.0)  # r = R: back on the ground
    assert np.sum(heights > 1.0) == 9  # cells with r < R = 1 m: the centre cell and its 8 neighbours
    # A second, lower rock overlapping the first never lowers it (max()).
    before = heights.copy()
    stamp_rocks(heights, 0.5, np.array([[5.75, 5.25]]), np.array([0.6]))
    assert (heights >= before).all()


def test_rock_on_a_slope_rests_on_its_centre_cell() -> None:
    ramp = np.tile(np.arange(20, dtype=np.float64) * 0.5, (20, 1))  # z = x: 45 deg up to the east
    heights = ramp.copy()
    stamp_rocks(heights, 0.5, np.array([[5.25, 5.25]]), np.array([1.6]))  # R = 0.8 m, H = 0.8 m
    base = ramp[10, 10]
    assert heights[10, 10] == pytest.approx(base + 0.8)
    assert heights[10, 11] == pytest.approx(base + 0.8 * math.sqrt(1 - (0.5 / 0.8) ** 2))  # above the ramp
    # Uphill diagonal: the rock surface (base + 0.375) is below the ramp (base + 0.5): ground kept.
    assert heights[11, 11] == ramp[11, 11]
    assert (heights >= ramp).all()


# ---------------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    "change",
    [
        {"spacing_m": 0.6},
        {"spacing_m": 0.0},
        {"rock_k": 0.5},
        {"rock_k": 0.01},
        {"relief_hurst": 1.2},
        {"size_m": math.nan},
        {"crater_d_min_m": 30.0, "crater_d_max_m": 20.0},
    ],
)
def test_bad_params_are_refused(change: dict[str, float]) -> None:
    with pytest.raises(TerrainError):
        replace(MarsTerrainParams(), **change)


# ---------------------------------------------------------------------------- GeoTIFF writer
def test_write_geotiff_round_trip(tmp_path: Path) -> None:
    heights = generate_mars_terrain(SMALL, seed=5)
    heights[0, 0] = np.nan
    path = tmp_path / "mars.tif"
    crs = CRS.from_epsg(32610).to_wkt()
    write_geotiff(path, heights, 0.5, origin_xy=(500000.0, 4100000.0), crs_wkt=crs, tags=params_tags(SMALL, 5))
    with DTM.open(path) as dtm:
        assert dtm.info.transform == (0.5, 0.0, 500000.0, 0.0, -0.5, 4100000.0)
        assert (dtm.info.rows, dtm.info.cols) == heights.shape
        assert "32610" in dtm.info.crs_wkt
        back = dtm.read(0, 0, *heights.shape)
    np.testing.assert_array_equal(back, heights.astype(np.float64))
    with rasterio.open(path) as src:
        tags = src.tags()
        assert src.dtypes[0] == "float32" and math.isnan(src.nodata)
    assert tags["HD_SEED"] == "5"
    assert json.loads(tags["HD_PARAMS"])["rock_k"] == SMALL.rock_k
    assert [p.name for p in tmp_path.iterdir()] == ["mars.tif"]


def test_write_geotiff_without_crs(tmp_path: Path) -> None:
    write_geotiff(tmp_path / "local.tif", np.zeros((4, 5), dtype=np.float32), 0.25)
    with DTM.open(tmp_path / "local.tif") as dtm:
        assert dtm.info.crs_wkt == "" and dtm.info.spacing_m == (0.25, 0.25)
        assert dtm.info.transform == (0.25, 0.0, 0.0, 0.0, -0.25, 0.0)


def test_write_geotiff_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import errno

    from hdcore import storage

    path = tmp_path / "keep.tif"
    path.write_bytes(b"previous content")
    real_write = storage.atomic._write_all

    def disk_full(fd: int, data: bytes) -> None:  # writes part of the file, then the disk is full
        real_write(fd, memoryview(data)[: len(data) // 2])
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(storage.atomic, "_write_all", disk_full)
    with pytest.raises(storage.StorageError, match=r"keep\.tif: no space left on device"):
        write_geotiff(path, np.zeros((8, 8), dtype=np.float32), 0.5)
    assert path.read_bytes() == b"previous content"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.tif"]


def test_write_geotiff_refuses_bad_input(tmp_path: Path) -> None:
    with pytest.raises(TerrainError, match="2-D"):
        write_geotiff(tmp_path / "a.tif", np.zeros((2, 2, 2)), 0.5)
    with pytest.raises(TerrainError, match="spacing_m"):
        write_geotiff(tmp_path / "a.tif", np.zeros((2, 2)), -1.0)
    with pytest.raises(TerrainError, match="does not exist"):
        write_geotiff(tmp_path / "missing" / "a.tif", np.zeros((2, 2)), 0.5)
    assert list(tmp_path.iterdir()) == []


def test_defaults_module_matches_params() -> None:
    p = MarsTerrainParams()
    assert (p.size_m, p.spacing_m, p.rock_k) == (td.SIZE_M, td.SPACING_M, td.ROCK_K)
    assert p.crater_depth_ratio == 0.2 and p.crater_rim_ratio == 0.04 and p.rock_height_ratio == 0.5
