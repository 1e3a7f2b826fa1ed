"""The one GeoTIFF writer of the tests: a height grid as a north-up, single-band GeoTIFF.

Every test folder imports it (``from tests.geotiff import write_geotiff``; the repository root is
on pytest's ``pythonpath``). It writes with rasterio directly, independently of the writers under
test (``lidarsim.procedural.write_geotiff``), so a reader test never reads a file made by the code
it checks. Files whose format itself is the subject of a test (another driver, a damaged header, a
PDS3 label) are written where that test is.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.transform import from_origin

# hd choice: the top-left corner (map metres) of most test terrains, away from (0, 0) so that a
# reader mixing up map and grid coordinates is caught.
ORIGIN_XY = (1000.0, 2000.0)


def write_geotiff(
    path: Path,
    heights: np.ndarray,
    spacing_m: float = 1.0,
    origin_xy: tuple[float, float] = ORIGIN_XY,
    crs: CRS | str | None = None,
    nodata: float | None = None,
    dtype: str = "float32",
) -> Path:
    """Write ``heights`` (metres, row 0 the north) at ``path``: cells of ``spacing_m`` metres, the
    top-left corner at ``origin_xy`` (map metres), optional ``crs`` and ``nodata``; returns ``path``."""
    heights = np.asarray(heights)
    profile: dict[str, object] = {
        "driver": "GTiff",
        "height": heights.shape[0],
        "width": heights.shape[1],
        "count": 1,
        "dtype": dtype,
        "transform": from_origin(origin_xy[0], origin_xy[1], spacing_m, spacing_m),
    }
    if crs is not None:
        profile["crs"] = crs
    if nodata is not None:
        profile["nodata"] = nodata
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(heights.astype(dtype), 1)
    return path
