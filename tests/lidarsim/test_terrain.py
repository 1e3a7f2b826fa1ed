"""lidarsim.terrain: DTM reading, masks, windows, scale, coordinates, validity overview, errors."""

from __future__ import annotations

import hashlib
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from terrain_files import (
    HIRISE_NULL,
    TILT_GX,
    TILT_GY,
    TILT_Z0,
    UTM_GX,
    UTM_GY,
    UTM_X0,
    UTM_Y0,
    UTM_Z0,
    write_tif,
)

from lidarsim.errors import LidarsimError, TerrainError
from lidarsim.terrain import DTM, DTMInfo, invalid_mask


# ---------------------------------------------------------------------------- opening and info
def test_flat_info_and_values(flat_tif: Path) -> None:
    with DTM.open(flat_tif) as dtm:
        info = dtm.info
        assert isinstance(info, DTMInfo)
        assert (info.rows, info.cols) == (20, 30)
        assert info.spacing_m == (1.0, 1.0)
        assert info.transform == (1.0, 0.0, 1000.0, 0.0, -1.0, 2000.0)
        assert info.crs_wkt == ""
        assert info.nodata is None
        assert info.scale == 1.0
        assert info.driver == "GTiff"
        assert info.path == str(flat_tif.resolve()) and info.name == "flat.tif"
        heights = dtm.read(0, 0, 20, 30)
    assert heights.dtype == np.float64 and heights.shape == (20, 30)
    np.testing.assert_array_equal(heights, 5.0)


def test_to_attrs_is_flat_and_json_serialisable(utm_tif: Path, nodata_tif: Path) -> None:
    with DTM.open(utm_tif) as dtm:
        attrs = dtm.info.to_attrs()
    assert "nodata" not in attrs
    assert attrs["transform"] == [1.0, 0.0, UTM_X0, 0.0, -1.0, UTM_Y0]
    assert "32610" in attrs["crs_wkt"]
    assert all(isinstance(v, (str, int, float, list)) for v in attrs.values())
    json.dumps(attrs)
    with DTM.open(nodata_tif) as dtm:
        assert dtm.info.to_attrs()["nodata"] == -9999.0


def test_sha256_matches_file_bytes(flat_tif: Path) -> None:
    import hashlib

    with DTM.open(flat_tif) as dtm:
        assert dtm.sha256() == hashlib.sha256(flat_tif.read_bytes()).hexdigest()
        assert dtm.sha256() == dtm.sha256()


def test_tilted_plane_values_match_coordinates(tilted_tif: Path) -> None:
    with DTM.open(tilted_tif) as dtm:
        rows = np.arange(40)[:, None] * np.ones((1, 40))
        cols = np.ones((40, 1)) * np.arange(40)[None, :]
        x, y = dtm.cell_center_xy(rows, cols)
        heights = dtm.read(0, 0, 40, 40)
    np.testing.assert_allclose(heights, TILT_Z0 + TILT_GX * x + TILT_GY * y, atol=1e-5)


def test_utm_coordinates_and_inverse(utm_tif: Path) -> None:
    with DTM.open(utm_tif) as dtm:
        x, y = dtm.cell_center_xy(0, 0)
        assert (float(x), float(y)) == (UTM_X0 + 0.5, UTM_Y0 - 0.5)
        x, y = dtm.cell_center_xy(np.array([29.0]), np.array([49.0]))
        assert (x[0], y[0]) == (UTM_X0 + 49.5, UTM_Y0 - 29.5)
        r, c = dtm.rowcol_of_xy(UTM_X0 + 10.25, UTM_Y0 - 3.75)
        assert (float(r), float(c)) == pytest.approx((3.25, 9.75), abs=1e-9)
        rr, cc = dtm.rowcol_of_xy(*dtm.cell_center_xy(np.array([1.5, 7.0]), np.array([2.0, 33.25])))
        np.testing.assert_allclose(rr, [1.5, 7.0], atol=1e-9)
        np.testing.assert_allclose(cc, [2.0, 33.25], atol=1e-9)
        # Large coordinates stay exact in float64: value at a cell = plane at its centre.
        z = dtm.read(12, 40, 1, 1)[0, 0]
        xc, yc = dtm.cell_center_xy(12, 40)
        assert z == pytest.approx(UTM_Z0 + UTM_GX * (xc - UTM_X0) + UTM_GY * (yc - UTM_Y0), abs=1e-4)


# ---------------------------------------------------------------------------- masks
def test_nodata_and_nan_are_masked(nodata_tif: Path) -> None:
    with DTM.open(nodata_tif) as dtm:
        assert dtm.info.nodata == -9999.0
        heights = dtm.read(0, 0, 10, 12)
    expected = 10.0 * np.arange(10)[:, None] + np.arange(12)[None, :]
    bad = np.isnan(heights)
    assert set(zip(*np.nonzero(bad), strict=True)) == {(2, 3), (5, 7)}
    np.testing.assert_array_equal(heights[~bad], expected[~bad])


def test_hirise_null_masked_with_less_equal(hirise_null_tif: Path) -> None:
    with DTM.open(hirise_null_tif) as dtm:
        heights = dtm.read(0, 0, 8, 8)
    assert set(zip(*np.nonzero(np.isnan(heights)), strict=True)) == {(1, 1), (6, 2)}
    assert np.nansum(heights) == 62.0


def test_invalid_mask_rules() -> None:
    values = np.array([1.0, np.nan, -9999.0, HIRISE_NULL, -3.5e38, -3.4e38], dtype=np.float64)
    # -3.4e38 is above the HiRISE NULL threshold but, like any height beyond +-1e5 m, no terrain
    np.testing.assert_array_equal(invalid_mask(values, -9999.0), [False, True, True, True, True, True])
    np.testing.assert_array_equal(invalid_mask(values, None), [False, True, False, True, True, True])
    extremes = np.array([np.inf, -np.inf, 1e30, 1.0e5, -1.0e5, 1.0001e5, 21229.0, -8200.0], dtype=np.float32)
    np.testing.assert_array_equal(invalid_mask(extremes, None), [True, True, True, False, False, True, False, False])
    ints = np.array([0, -32768, 5], dtype=np.int16)
    np.testing.assert_array_equal(invalid_mask(ints, -32768), [False, True, False])


# ---------------------------------------------------------------------------- windows
def test_window_past_the_edge_is_nan_outside(nodata_tif: Path) -> None:
    with DTM.open(nodata_tif) as dtm:
        full = dtm.read(0, 0, 10, 12)
        win = dtm.read(-2, 9, 5, 6)  # rows -2..2, cols 9..14
        outside = dtm.read(50, 50, 3, 4)
        empty = dtm.read(0, 0, 0, 5)
    assert win.shape == (5, 6)
    assert np.isnan(win[:2]).all() and np.isnan(win[:, 3:]).all()
    np.testing.assert_array_equal(win[2:, :3], full[0:3, 9:12])
    assert outside.shape == (3, 4) and np.isnan(outside).all()
    assert empty.shape == (0, 5)


# ---------------------------------------------------------------------------- scale
def test_scale_half_on_tilted_plane(tilted_tif: Path) -> None:
    with DTM.open(tilted_tif, scale=0.5) as dtm:
        info = dtm.info
        assert (info.rows, info.cols) == (20, 20)
        assert info.spacing_m == (1.0, 1.0)
        assert info.transform == (1.0, 0.0, 0.0, 0.0, -1.0, 20.0)
        heights = dtm.read(0, 0, 20, 20)
        r, c = np.meshgrid(np.arange(20), np.arange(20), indexing="ij")
        x, y = dtm.cell_center_xy(r, c)
    # Bilinear resampling of a plane is the plane at the coarse cell centres (interior cells).
    np.testing.assert_allclose(heights[1:-1, 1:-1], (TILT_Z0 + TILT_GX * x + TILT_GY * y)[1:-1, 1:-1], atol=1e-4)


def test_scaled_cell_valid_only_if_every_source_cell_is(nodata_tif: Path) -> None:
    with DTM.open(nodata_tif, scale=0.5) as dtm:
        heights = dtm.read(0, 0, dtm.info.rows, dtm.info.cols)
    assert heights.shape == (5, 6)
    # Source (2, 3) lies under coarse (1, 1); source (5, 7) under coarse (2, 3). Their neighbours
    # stay valid even though the bilinear kernel reaches the invalid cells.
    assert set(zip(*np.nonzero(np.isnan(heights)), strict=True)) == {(1, 1), (2, 3)}
    expected = 10.0 * np.arange(10)[:, None] + np.arange(12)[None, :]
    coarse_mean = expected.reshape(5, 2, 6, 2).mean(axis=(1, 3))
    # On a plane, GDAL's symmetric bilinear kernel gives the coarse-cell mean away from the raster
    # edge and from invalid cells (next to those, GDAL renormalises over the valid ones).
    for r, c in [(1, 3), (1, 4), (2, 1), (3, 1)]:
        assert heights[r, c] == pytest.approx(coarse_mean[r, c], abs=1e-4)
    # NaN (undeclared) spreads through the kernel; those neighbours fall back to the coarse mean.
    for r, c in [(2, 4), (3, 3), (3, 4)]:
        assert heights[r, c] == pytest.approx(coarse_mean[r, c], abs=1e-4)
    assert np.isfinite(heights[1, 2]) and np.isfinite(heights[2, 2])


def test_scaled_windows_agree_with_the_full_scaled_grid(tilted_tif: Path) -> None:
    with DTM.open(tilted_tif, scale=0.3) as dtm:
        full = dtm.read(0, 0, dtm.info.rows, dtm.info.cols)
        win = dtm.read(3, 2, 5, 6)
    np.testing.assert_allclose(win, full[3:8, 2:8], atol=1e-6)


@pytest.mark.parametrize("scale", [0.0, -0.5, 1.5, math.nan, math.inf, "half"])
def test_bad_scale_is_refused(flat_tif: Path, scale: object) -> None:
    with pytest.raises(TerrainError, match="scale"):
        DTM.open(flat_tif, scale=scale)  # type: ignore[arg-type]  # the point: refused


# ---------------------------------------------------------------------------- validity overview
def test_validity_overview_marks_blocks_with_any_invalid_cell(nodata_tif: Path) -> None:
    with DTM.open(nodata_tif) as dtm:
        valid, transform = dtm.validity_overview(4.0)
    # 10 x 12 m at 4 m: 3 x 3 coarse cells; the last coarse row covers rows 8..11 (past the edge).
    assert valid.shape == (3, 3)
    assert transform == (4.0, 0.0, 0.0, 0.0, -4.0, 10.0)
    # Source (2, 3) is in coarse (0, 0), source (5, 7) in coarse (1, 1).
    expected = np.array([[False, True, True], [True, False, True], [False, False, False]])
    np.testing.assert_array_equal(valid, expected)


def test_validity_overview_fractional_cells(flat_tif: Path) -> None:
    with DTM.open(flat_tif) as dtm:
        valid, transform = dtm.validity_overview(2.5)
    assert valid.shape == (8, 12)
    assert transform[0] == 2.5 and transform[4] == -2.5
    assert valid.all()


def test_validity_overview_streams_in_blocks(nodata_tif: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import lidarsim.terrain as terrain

    with DTM.open(nodata_tif) as dtm:
        whole, _ = dtm.validity_overview(2.0)
    monkeypatch.setattr(terrain, "_OVERVIEW_BLOCK_CELLS", 12)  # one source row per block
    with DTM.open(nodata_tif) as dtm:
        streamed, _ = dtm.validity_overview(2.0)
    np.testing.assert_array_equal(whole, streamed)
    assert not streamed[1, 1] and not streamed[2, 3] and streamed.sum() == streamed.size - 2


def test_validity_overview_of_a_window_reads_its_cells_alone(nodata_tif: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Rows 1..6, columns 2..9 of the 10 x 12 grid (invalid cells at (2, 3) and (5, 7)), in 2 m cells."""
    reads = []
    with DTM.open(nodata_tif) as dtm:
        original = dtm._read_source

        def spy(window, *args):
            reads.append(window)
            return original(window, *args)

        monkeypatch.setattr(dtm, "_read_source", spy)
        valid, transform = dtm.validity_overview(2.0, window=(1, 2, 6, 8))
    assert transform == (2.0, 0.0, 2.0, 0.0, -2.0, 9.0)  # the window's top-left corner
    assert all(
        w.col_off >= 2 and w.col_off + w.width <= 10 and w.row_off >= 1 and w.row_off + w.height <= 7 for w in reads
    )
    # (2, 3) is window cell (1, 1): coarse (0, 0); (5, 7) is window cell (4, 5): coarse (2, 2).
    expected = np.ones((3, 4), bool)
    expected[0, 0] = expected[2, 2] = False
    np.testing.assert_array_equal(valid, expected)
    with DTM.open(nodata_tif) as dtm, pytest.raises(TerrainError, match="every cell of the window is nodata"):
        dtm.validity_overview(1.0, window=(2, 3, 1, 1))


def test_preview_decimates_a_window_in_one_read(nodata_tif: Path) -> None:
    """Value 10*row + col, nodata at (2, 3) and (5, 7): a preview cell is the source cell under its centre."""
    with DTM.open(nodata_tif) as dtm:
        whole = dtm.preview(100)
        assert whole.shape == (10, 12) and whole[4, 5] == 45.0 and np.isnan(whole).sum() == 2
        assert np.isnan(whole[2, 3]) and np.isnan(whole[5, 7])
        third = dtm.preview(4, row0=1, rows=9)  # rows 1..9 and the 12 columns, 3 x 3 cells to one
        expected = 10.0 * (3 * np.arange(3) + 2)[:, None] + (3 * np.arange(4) + 1)[None, :]
        expected[1, 2] = np.nan  # source (5, 7)
        np.testing.assert_array_equal(third, expected)
        with pytest.raises(TerrainError, match="lies outside its 10x12 cells"):
            dtm.preview(4, row0=5, rows=6)


def test_all_nodata_is_refused(all_nodata_tif: Path) -> None:
    with DTM.open(all_nodata_tif) as dtm, pytest.raises(TerrainError, match="every cell is nodata") as err:
        dtm.validity_overview(1.0)
    assert "empty.tif" in str(err.value)


@pytest.mark.parametrize("cell", [0.0, -1.0, math.nan])
def test_bad_overview_cell_is_refused(flat_tif: Path, cell: float) -> None:
    with DTM.open(flat_tif) as dtm, pytest.raises(TerrainError, match="cell size"):
        dtm.validity_overview(cell)


# ---------------------------------------------------------------------------- errors
def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(TerrainError, match="no such file") as err:
        DTM.open(tmp_path / "nope.tif")
    assert "nope.tif" in str(err.value) and "\n" not in str(err.value)
    assert issubclass(TerrainError, LidarsimError) and issubclass(TerrainError, ValueError)


def test_not_a_raster(not_a_raster: Path) -> None:
    with pytest.raises(TerrainError, match="is not a raster GDAL can read") as err:
        DTM.open(not_a_raster)
    assert "notes.tif" in str(err.value)


def test_directory_is_refused(tmp_path: Path) -> None:
    with pytest.raises(TerrainError, match="directory"):
        DTM.open(tmp_path)


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="needs POSIX permissions as non-root")
def test_unreadable_file(flat_tif: Path) -> None:
    flat_tif.chmod(0)
    try:
        with pytest.raises(TerrainError, match="not readable"):
            DTM.open(flat_tif)
    finally:
        flat_tif.chmod(0o644)


def test_geographic_crs_is_refused(geographic_tif: Path) -> None:
    with pytest.raises(TerrainError) as err:
        DTM.open(geographic_tif)
    message = str(err.value)
    assert "wgs84.tif" in message
    assert "has a geographic CRS (EPSG:4326, degrees); reproject it to a projected CRS in metres" in message
    assert "gdalwarp" in message


def test_rotated_grid_is_refused(tmp_path: Path) -> None:
    import rasterio
    from rasterio.transform import Affine

    path = tmp_path / "rotated.tif"
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        height=4,
        width=4,
        count=1,
        dtype="float32",
        transform=Affine(0.9, 0.1, 0.0, 0.1, -0.9, 4.0),
    ) as dst:
        dst.write(np.zeros((1, 4, 4), dtype=np.float32))
    with pytest.raises(TerrainError, match="rotated"):
        DTM.open(path)


def test_feet_crs_is_refused(tmp_path: Path) -> None:
    from rasterio.crs import CRS

    path = write_tif(tmp_path / "feet.tif", np.zeros((4, 4)), 3.0, (0.0, 12.0), crs=CRS.from_epsg(2992))
    with pytest.raises(TerrainError, match="not metres"):
        DTM.open(path)


# ---------------------------------------------------------------------------- HiRISE PDS3
def test_pds3_with_attached_label(pds3_img: Path) -> None:
    with DTM.open(pds3_img) as dtm:
        info = dtm.info
        assert info.driver == "PDS"
        assert (info.rows, info.cols) == (6, 8)
        assert info.spacing_m == pytest.approx((1.01, 1.01))
        # GDAL: x0 = -SAMPLE_PROJECTION_OFFSET' * MAP_SCALE, y0 = LINE_PROJECTION_OFFSET' * MAP_SCALE,
        # with the offsets shifted by half a pixel to the corner: (2000.0, 1001.0) pixels.
        assert info.transform == pytest.approx((1.01, 0.0, 2020.0, 0.0, -1.01, 1011.01))
        assert "Equirectangular" in info.crs_wkt
        heights = dtm.read(0, 0, 6, 8)
    expected = np.arange(48, dtype=np.float64).reshape(6, 8) - 2000.0
    bad = np.isnan(heights)
    assert set(zip(*np.nonzero(bad), strict=True)) == {(1, 2), (3, 4)}
    np.testing.assert_array_equal(heights[~bad], expected[~bad])


# ---------------------------------------------------------------------------- real terrain
def test_real_ames(real_terrain_dir: Path) -> None:
    with DTM.open(real_terrain_dir / "ames-0.5m.tif") as dtm:
        info = dtm.info
        assert (info.rows, info.cols) == (237, 161)
        assert info.spacing_m == (0.5, 0.5)
        assert info.nodata is None
        assert "32610" in info.crs_wkt or "UTM zone 10N" in info.crs_wkt
        x0, y0 = info.transform[2], info.transform[5]
        assert abs(x0 - 582678) < 1.0 and abs(y0 - 4141911) < 1.0
        x, y = dtm.cell_center_xy(100, 50)
        assert (float(x), float(y)) == (x0 + 25.25, y0 - 50.25)
        heights = dtm.read(0, 0, info.rows, info.cols)
        assert np.isnan(heights).mean() == pytest.approx(0.103, abs=0.002)
        assert np.nanmin(heights) == pytest.approx(2.74, abs=0.01)
        assert np.nanmax(heights) == pytest.approx(5.45, abs=0.01)
        # A window across the south-east corner.
        corner = dtm.read(info.rows - 5, info.cols - 5, 10, 10)
        np.testing.assert_array_equal(corner[:5, :5], heights[-5:, -5:])
        assert np.isnan(corner[5:]).all() and np.isnan(corner[:, 5:]).all()
        valid, transform = dtm.validity_overview(10.0)
        assert valid.shape == (12, 9) and transform[0] == 10.0  # 118.5 m x 80.5 m
        assert 0 < valid.sum() < valid.size
        # Every coarse cell marked valid really is free of NaN.
        for i, j in zip(*np.nonzero(valid), strict=True):
            assert not np.isnan(heights[20 * i : 20 * i + 20, 20 * j : 20 * j + 20]).any()
    with DTM.open(real_terrain_dir / "ames-0.5m.tif", scale=0.5) as half:
        assert (half.info.rows, half.info.cols) == (118, 80)
        coarse = half.read(0, 0, 118, 80)
        assert np.nanmin(coarse) >= 2.74 - 0.01 and np.nanmax(coarse) <= 5.45 + 0.01
        # More NaN than at full resolution (a coarse cell needs all of its source cells).
        assert np.isnan(coarse).mean() > 0.103


def test_real_autzen(real_terrain_dir: Path) -> None:
    with DTM.open(real_terrain_dir / "autzen-ground-1m.tif") as dtm:
        info = dtm.info
        assert (info.rows, info.cols) == (171, 359)
        assert info.crs_wkt == ""
        assert info.nodata == -9999.0
        assert info.spacing_m == (1.0, 1.0)
        heights = dtm.read(0, 0, info.rows, info.cols)
        assert not (heights == -9999.0).any()
        assert np.isnan(heights).mean() == pytest.approx(0.155, abs=0.002)
        assert np.nanmin(heights) == pytest.approx(123.8, abs=0.05)
        assert np.nanmax(heights) == pytest.approx(132.3, abs=0.05)
        x0, y0 = info.transform[2], info.transform[5]
        x, y = dtm.cell_center_xy(170, 358)
        assert (float(x), float(y)) == (x0 + 358.5, y0 - 170.5)
        west = dtm.read(60, -3, 4, 6)
        assert np.isnan(west[:, :3]).all()
        np.testing.assert_array_equal(west[:, 3:], heights[60:64, 0:3])
        valid, _ = dtm.validity_overview(105.0)
        assert valid.shape == (2, 4)
        assert not valid[:, -1].any()  # 359 m is not a multiple of 105 m: partial cells are False
    with DTM.open(real_terrain_dir / "autzen-ground-1m.tif", scale=0.5) as half:
        assert half.info.spacing_m[0] == pytest.approx(2.0, rel=0.01)
        coarse = half.read(0, 0, half.info.rows, half.info.cols)
        assert np.nanmin(coarse) >= 123.8 - 0.05 and np.nanmax(coarse) <= 132.3 + 0.05
        assert np.isnan(coarse).mean() >= 0.155


@pytest.mark.parametrize(("dtype", "refused"), [("uint8", True), ("int8", True), ("float32", False)])
def test_an_image_without_georeferencing_is_not_taken_for_heights(tmp_path: Path, dtype: str, refused: bool) -> None:
    """An 8-bit PNG without georeferencing was built and mapped as heights in metres without a word."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    path = tmp_path / "picture.png" if dtype != "float32" else tmp_path / "local.tif"
    z = (np.arange(64 * 64).reshape(64, 64) % 100).astype(dtype)
    driver = "PNG" if dtype == "uint8" else "GTiff"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)  # the point of the file
        with rasterio.open(path, "w", driver=driver, width=64, height=64, count=1, dtype=dtype) as dst:
            dst.write(z, 1)
    if refused:
        with pytest.raises(TerrainError, match="no georeferencing and 8-bit values"):
            DTM.open(path)
    else:
        with DTM.open(path) as dtm:  # a float DTM in local metres: 1 m cells, as GDAL says
            assert dtm.info.rows == 64 and dtm.info.spacing_m == (1.0, 1.0)


def test_the_dtm_digest_covers_the_side_files_gdal_reads(tmp_path: Path) -> None:
    """A DTM's digest was its own file's sha256: an .aux.xml beside it (which GDAL reads: PAM
    metadata, nodata, scale and offset) could change without hd noticing. Without side files the
    digest is still the file's sha256 (the recorded digests of existing datasets and recipes)."""
    from hdcore.storage import sha256_file
    from lidarsim.terrain import dtm_sha256, gdal_side_files
    from tests.geotiff import write_geotiff

    path = tmp_path / "d.tif"
    write_geotiff(path, np.arange(64, dtype=np.float32).reshape(8, 8), 1.0, (0.0, 8.0))
    plain = sha256_file(path)
    assert gdal_side_files(path) == () and dtm_sha256(path) == plain
    with DTM.open(path) as dtm:
        assert dtm.sha256() == plain
    aux = tmp_path / "d.tif.aux.xml"
    aux.write_text("<PAMDataset><Metadata><MDI key='a'>1</MDI></Metadata></PAMDataset>")
    assert gdal_side_files(path) == (aux,)
    with_aux = dtm_sha256(path)
    own_and_side = f"{plain}  d.tif\n{sha256_file(aux)}  d.tif.aux.xml\n"
    assert with_aux == hashlib.sha256(own_and_side.encode()).hexdigest()
    with DTM.open(path) as dtm:
        assert dtm.sha256() == with_aux
    aux.write_text("<PAMDataset><Metadata><MDI key='a'>2</MDI></Metadata></PAMDataset>")
    assert dtm_sha256(path) not in (plain, with_aux)
    aux.unlink()
    assert dtm_sha256(path) == plain


def test_a_world_file_is_in_the_digest_of_a_tiff_without_georeferencing(tmp_path: Path) -> None:
    """A TIFF without GeoTIFF tags takes its grid from a .tfw beside it (GDAL reads it): a changed
    world file moves the terrain, so it changes the digest; beside a GeoTIFF GDAL ignores it."""
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    from hdcore.storage import sha256_file
    from lidarsim.terrain import dtm_sha256, gdal_side_files

    path = tmp_path / "plain.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path, "w", driver="GTiff", height=8, width=8, count=1, dtype="float32") as out:
            out.write(np.zeros((1, 8, 8), dtype=np.float32))
    assert dtm_sha256(path) == sha256_file(path)
    world = tmp_path / "plain.tfw"
    world.write_text("2\n0\n0\n-2\n1\n15\n")
    assert gdal_side_files(path) == (world,)
    first = dtm_sha256(path)
    world.write_text("2\n0\n0\n-2\n101\n15\n")  # the same grid 100 m east
    assert first != dtm_sha256(path) != sha256_file(path)
