"""Tiny terrain files written in code for the lidarsim tests.

Every fixture returns the path of a small raster (a few dozen cells) whose heights are known in
closed form, so tests compare against hand-derivable numbers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rasterio.crs import CRS
from terrain_files import (
    HIRISE_NULL,
    REAL_TERRAIN_DIR,
    TILT_GX,
    TILT_GY,
    TILT_Z0,
    UTM_EPSG,
    UTM_GX,
    UTM_GY,
    UTM_X0,
    UTM_Y0,
    UTM_Z0,
    plane,
    write_pds3,
    write_tif,
)

__all__ = ["UTM_EPSG", "plane", "write_pds3", "write_tif"]


@pytest.fixture
def flat_tif(tmp_path: Path) -> Path:
    """20 x 30 cells of 1 m at height 5 m, top-left (1000, 2000), no CRS."""
    return write_tif(tmp_path / "flat.tif", np.full((20, 30), 5.0), 1.0, (1000.0, 2000.0))


@pytest.fixture
def tilted_tif(tmp_path: Path) -> Path:
    """40 x 40 cells of 0.5 m, plane TILT_Z0 + TILT_GX x + TILT_GY y in map metres, top-left (0, 20)."""
    x = (np.arange(40) + 0.5) * 0.5
    y = 20.0 - (np.arange(40) + 0.5) * 0.5
    z = TILT_Z0 + TILT_GX * x[None, :] + TILT_GY * y[:, None]
    return write_tif(tmp_path / "tilted.tif", z, 0.5, (0.0, 20.0))


@pytest.fixture
def utm_tif(tmp_path: Path) -> Path:
    """30 x 50 cells of 1 m in EPSG:32610 with top-left (500000 E, 4100000 N); a tilted plane."""
    z = plane(30, 50, 1.0, UTM_Z0, UTM_GX, UTM_GY)
    return write_tif(tmp_path / "utm.tif", z, 1.0, (UTM_X0, UTM_Y0), crs=CRS.from_epsg(UTM_EPSG))


@pytest.fixture
def nodata_tif(tmp_path: Path) -> Path:
    """10 x 12 cells of 1 m, value 10*row + col, nodata -9999 at (2, 3) and NaN at (5, 7)."""
    z = (10.0 * np.arange(10)[:, None] + np.arange(12)[None, :]).astype(np.float64)
    z[2, 3] = -9999.0
    z[5, 7] = np.nan
    return write_tif(tmp_path / "nodata.tif", z, 1.0, (0.0, 10.0), nodata=-9999.0)


@pytest.fixture
def hirise_null_tif(tmp_path: Path) -> Path:
    """8 x 8 cells of 1 m at height 1 m, HiRISE NULL at (1, 1) and -FLT_MAX at (6, 2); no declared nodata."""
    z = np.ones((8, 8), dtype=np.float32)
    z[1, 1] = np.float32(HIRISE_NULL)
    z[6, 2] = np.finfo(np.float32).min
    return write_tif(tmp_path / "hirise-null.tif", z, 1.0, (0.0, 8.0))


@pytest.fixture
def all_nodata_tif(tmp_path: Path) -> Path:
    """6 x 6 cells, every one NaN."""
    return write_tif(tmp_path / "empty.tif", np.full((6, 6), np.nan), 1.0, (0.0, 6.0))


@pytest.fixture
def geographic_tif(tmp_path: Path) -> Path:
    """10 x 10 cells in EPSG:4326 (degrees)."""
    return write_tif(tmp_path / "wgs84.tif", np.zeros((10, 10)), 0.001, (-122.0, 37.0), crs=CRS.from_epsg(4326))


@pytest.fixture
def not_a_raster(tmp_path: Path) -> Path:
    """A text file with a .tif name."""
    path = tmp_path / "notes.tif"
    path.write_text("these are not heights\n")
    return path


@pytest.fixture
def pds3_img(tmp_path: Path) -> Path:
    """6 x 8 HiRISE-like PDS3 DTM, value row*8 + col - 2000 m, NULL 16#FF7FFFFB# at (1, 2), -FLT_MAX at (3, 4)."""
    z = (np.arange(48, dtype=np.float32).reshape(6, 8) - 2000.0).astype(np.float32)
    z[1, 2] = np.float32(HIRISE_NULL)
    z[3, 4] = np.finfo(np.float32).min
    return write_pds3(tmp_path / "DTEEC_TEST.IMG", z)


@pytest.fixture
def real_terrain_dir() -> Path:
    """The shared directory of real DTMs; the test is skipped when it is absent."""
    if not REAL_TERRAIN_DIR.is_dir():
        pytest.skip(f"{REAL_TERRAIN_DIR} is not available")
    return REAL_TERRAIN_DIR
