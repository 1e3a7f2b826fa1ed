"""Terrain files for the lidarsim tests, written in code: constants and writers.

Kept apart from ``conftest.py`` so test modules can import the constants by a unique module name.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rasterio.crs import CRS

from tests.geotiff import write_geotiff

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
    """Write a north-up float32 GeoTIFF with top-left corner ``origin_xy`` (``tests.geotiff``)."""
    return write_geotiff(path, heights, spacing_m, origin_xy, crs, nodata)


def plane(rows: int, cols: int, spacing_m: float, z0: float, gx: float, gy: float) -> np.ndarray:
    """Heights z0 + gx*(x - x0) + gy*(y - y0) at cell centres, (x0, y0) being the top-left corner."""
    x = (np.arange(cols) + 0.5) * spacing_m
    y = -(np.arange(rows) + 0.5) * spacing_m
    return z0 + gx * x[None, :] + gy * y[:, None]


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
