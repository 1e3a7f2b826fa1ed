"""A DTM interpolated bilinearly to a finer spacing, computed window by window (``hd detect --upsample``).

``hd detect`` maps a DTM coarser than the run's DEM spacing (HiRISE's 1-4 m posts for a 1 m/px
network) by interpolating it between its cell centres (``lidarsim.base_relief.resample_bilinear``).
Holding the whole interpolated grid costs 8 bytes per output cell (~37 MiB per km² at 1 m even as
float32 in memory, 0.5 GiB for the 14.3 km² Jezero floor), growing with the area. An
:class:`UpsampledDTM` keeps only the coarse cells (13.6 × fewer at 3.69 m posts) and the two axes'
interpolation weights, and computes each window it is asked for with the same arithmetic: every
output cell depends only on its own weights and the four source cells around it, so a window is
bit for bit the same cells of the whole grid. Values are rounded through float32, as the
in-memory GeoTIFF this replaces stored them, so the maps are unchanged.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from lidarsim.base_relief import axis_weights, resample_cells
from lidarsim.map_window import WindowCells
from lidarsim.terrain import DTM, DTMInfo

# Output rows per block when the valid cells of the whole grid are computed (memory: a block of
# float64 heights at a time).
_VALID_BLOCK_ROWS = 256


class UpsampledDTM:
    """The cells ``source`` of the DTM at ``path`` interpolated bilinearly to ``spacing_m``
    metres/pixel over the same extent, read window by window like a :class:`lidarsim.terrain.DTM`
    (``info``, ``read``, ``preview``, ``sha256``); never held whole.

    Raises:
        TerrainError: the DTM cannot be read (``DTM.open``).
    """

    def __init__(self, path: str | os.PathLike[str], source: WindowCells, spacing_m: float) -> None:
        with DTM.open(path) as src:
            coarse = src.info
            values = src.read(source.row0, source.col0, source.rows, source.cols)
            self._sha256 = src.sha256()
        sx, sy = coarse.spacing_m
        rows = max(1, int(source.rows * sy / spacing_m + 1e-9))
        cols = max(1, int(source.cols * sx / spacing_m + 1e-9))
        self._src = np.ascontiguousarray(values, dtype=np.float64)
        self._rows = axis_weights(rows, spacing_m, source.rows, sy)  # (lower source row, weight of the upper)
        self._cols = axis_weights(cols, spacing_m, source.cols, sx)
        t = source.transform(coarse.transform)
        self.info = DTMInfo(
            path=coarse.path,
            name=coarse.name,
            crs_wkt=coarse.crs_wkt,
            transform=(float(spacing_m), 0.0, float(t[2]), 0.0, -float(spacing_m), float(t[5])),
            rows=rows,
            cols=cols,
            spacing_m=(float(spacing_m), float(spacing_m)),
            scale=1.0,
            nodata=None,
            driver=coarse.driver,
        )

    def _cells(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """The interpolated heights of the grid rows ``rows`` x columns ``cols`` (index arrays), float64
        metres rounded through float32, NaN where a NaN source cell has weight."""
        (r_lo, r_w), (c_lo, c_w) = self._rows, self._cols
        out = resample_cells(self._src, (r_lo[rows], r_w[rows]), (c_lo[cols], c_w[cols]))
        return out.astype(np.float32).astype(np.float64)

    def read(self, row0: int, col0: int, rows: int, cols: int) -> np.ndarray:
        """Heights (float64 metres) of a window of the interpolated grid; NaN outside it and where invalid."""
        out = np.full((rows, cols), np.nan, dtype=np.float64)
        r_lo, r_hi = max(row0, 0), min(row0 + rows, self.info.rows)
        c_lo, c_hi = max(col0, 0), min(col0 + cols, self.info.cols)
        if r_lo < r_hi and c_lo < c_hi:
            out[r_lo - row0 : r_hi - row0, c_lo - col0 : c_hi - col0] = self._cells(
                np.arange(r_lo, r_hi), np.arange(c_lo, c_hi)
            )
        return out

    def valid_cells(self) -> np.ndarray:
        """(rows, cols) bool: the interpolated cells that hold a height, computed block by block."""
        valid = np.empty((self.info.rows, self.info.cols), dtype=bool)
        cols = np.arange(self.info.cols)
        for r0 in range(0, self.info.rows, _VALID_BLOCK_ROWS):
            r1 = min(r0 + _VALID_BLOCK_ROWS, self.info.rows)
            valid[r0:r1] = np.isfinite(self._cells(np.arange(r0, r1), cols))
        return valid

    def preview(
        self, max_px: int, row0: int = 0, col0: int = 0, rows: int | None = None, cols: int | None = None
    ) -> np.ndarray:
        """Heights of a window of the grid (default: all of it) decimated to at most ``max_px`` cells per
        side, each preview cell the grid cell nearest its centre (for figures; float64 metres, NaN invalid)."""
        rows = self.info.rows - row0 if rows is None else rows
        cols = self.info.cols - col0 if cols is None else cols
        k = min(1.0, max_px / max(rows, cols))
        n_r, n_c = max(1, round(rows * k)), max(1, round(cols * k))
        pick_r = row0 + np.minimum(((np.arange(n_r) + 0.5) * rows / n_r).astype(np.int64), rows - 1)
        pick_c = col0 + np.minimum(((np.arange(n_c) + 0.5) * cols / n_c).astype(np.int64), cols - 1)
        return self._cells(pick_r, pick_c)

    def sha256(self) -> str:
        """The SHA-256 of the coarse DTM file the grid is interpolated from."""
        return self._sha256

    @property
    def path(self) -> Path:
        """The coarse DTM file."""
        return Path(self.info.path)

    def close(self) -> None:
        """Nothing to release: the coarse cells are in memory."""
