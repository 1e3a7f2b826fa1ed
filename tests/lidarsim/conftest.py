"""Tiny terrain files written in code for the lidarsim tests.

Every fixture returns the path of a small raster (a few dozen cells) whose heights are known in
closed form, so tests compare against hand-derivable numbers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.crs import CRS
from rasterio.transform import from_origin

REAL_TERRAIN_DIR = Path("/work/shared/data/real-terrain")

# Tilted plane: z = TILT_Z0 + TILT_GX * x + TILT_GY * y (map metres).
TILT_Z0, TILT_GX, TILT_GY = 3.0, 0.1, -0.05
# UTM plane: z = UTM_Z0 + UTM_GX * (x - UTM_X0) + UTM_GY * (y - UTM_Y0); top-left corner (UTM_X0, UTM_Y0).
UTM_X0, UTM_Y0, UTM_Z0, UTM_GX, UTM_GY = 500000.0, 4100000.0, 100.0, 0.02, 0.03
UTM_EPSG = 32610
HIRISE_NULL = -3.4028227e38


def write_tif(
    path: Path,
    heights: np.ndarray,
    spacing_m: float,
    origin_xy: tuple[float, float],
    crs: CRS | None = None,
    nodata: float | None = None,
) -> Path:
    """Write a north-up float32 GeoTIFF with top-left corner ``origin_xy`` (independent of lidarsim)."""
    profile = {
        "driver": "GTiff",
        "height": heights.shape[0],
        "width": heights.shape[1],
        "count": 1,
        "dtype": "float32",
        "transform": from_origin(origin_xy[0], origin_xy[1], spacing_m, spacing_m),
    }
    if crs is not None:
        profile["crs"] = crs
    if nodata is not None:
        profile["nodata"] = nodata
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(heights.astype(np.float32), 1)
    return path


def plane(rows: int, cols: int, spacing_m: float, z0: float, gx: float, gy: float) -> np.ndarray:
    """Heights z0 + gx*(x - x0) + gy*(y - y0) at cell centres, (x0, y0) being the top-left corner."""
    x = (np.arange(cols) + 0.5) * spacing_m
    y = -(np.arange(rows) + 0.5) * spacing_m
    return z0 + gx * x[None, :] + gy * y[:, None]


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


def write_pds3(path: Path, heights: np.ndarray, map_scale_m: float = 1.01) -> Path:
    """Write a HiRISE-like PDS3 DTM: attached label, float32 (PC_REAL), MISSING_CONSTANT 16#FF7FFFFB#.

    Equirectangular projection on the Mars sphere (3396.19 km), MAP_SCALE ``map_scale_m`` m/px,
    LINE_PROJECTION_OFFSET 1000.5 and SAMPLE_PROJECTION_OFFSET -2000.5 pixels.
    """
    lines, samples = heights.shape
    record_bytes = samples * 4

    def label(label_records: int) -> bytes:
        text = f"""PDS_VERSION_ID = PDS3
RECORD_TYPE = FIXED_LENGTH
RECORD_BYTES = {record_bytes}
FILE_RECORDS = {label_records + lines}
LABEL_RECORDS = {label_records}
^IMAGE = {label_records + 1}
OBJECT = IMAGE
  LINES = {lines}
  LINE_SAMPLES = {samples}
  BANDS = 1
  SAMPLE_TYPE = PC_REAL
  SAMPLE_BITS = 32
  UNIT = METER
  MISSING_CONSTANT = 16#FF7FFFFB#
  SCALING_FACTOR = 1.0
  OFFSET = 0.0
END_OBJECT = IMAGE
OBJECT = IMAGE_MAP_PROJECTION
  MAP_PROJECTION_TYPE = "EQUIRECTANGULAR"
  A_AXIS_RADIUS = 3396.19 <KM>
  B_AXIS_RADIUS = 3396.19 <KM>
  C_AXIS_RADIUS = 3396.19 <KM>
  COORDINATE_SYSTEM_NAME = PLANETOCENTRIC
  POSITIVE_LONGITUDE_DIRECTION = EAST
  CENTER_LATITUDE = 0.0 <DEG>
  CENTER_LONGITUDE = 0.0 <DEG>
  LINE_FIRST_PIXEL = 1
  LINE_LAST_PIXEL = {lines}
  SAMPLE_FIRST_PIXEL = 1
  SAMPLE_LAST_PIXEL = {samples}
  MAP_SCALE = {map_scale_m} <METERS/PIXEL>
  LINE_PROJECTION_OFFSET = 1000.5 <PIXEL>
  SAMPLE_PROJECTION_OFFSET = -2000.5 <PIXEL>
END_OBJECT = IMAGE_MAP_PROJECTION
END
"""
        return text.replace("\n", "\r\n").encode("ascii")

    records = 1
    while len(label(records)) > records * record_bytes:
        records += 1
    with open(path, "wb") as fh:
        fh.write(label(records).ljust(records * record_bytes, b" "))
        fh.write(heights.astype("<f4").tobytes())
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
