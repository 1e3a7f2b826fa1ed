"""Windowed access to digital terrain models (DTMs) through rasterio/GDAL.

Reads any raster GDAL can open — GeoTIFF, HiRISE PDS3 ``.IMG`` with an attached label (GDAL's
``PDS`` driver), ... — without ever loading the whole file: every read is a rasterio windowed read.

Conventions (see ``docs/terrain.md``):

* Heights are returned as float64 metres; invalid cells are NaN. A cell is invalid where the file
  holds NaN, +-inf, the declared nodata value, a HiRISE NULL (value <= -3.4028227e38, compared with
  ``<=`` because HiRISE products carry several values near the float32 minimum), or a height
  farther than ``MAX_ABS_HEIGHT_M`` from zero (no planetary terrain reaches it: such values are
  undeclared fill values such as 1e30).
* ``scale`` resamples the grid (bilinear, GDAL); a resampled cell is valid only if every
  full-resolution cell it overlaps is valid.
* Map coordinates are in the raster's CRS (metres). A raster without CRS is treated as local
  metres; a geographic CRS (degrees) is refused.
* Coordinates can be large (UTM northings ~4e6 m): they stay float64 here; code that hands geometry
  to float32 libraries (Open3D) recentres it first.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import rasterio
from rasterio.enums import Resampling
from rasterio.errors import NotGeoreferencedWarning, RasterioError, RasterioIOError
from rasterio.windows import Window

from hdcore.storage import StorageError, sha256_bytes, sha256_file
from lidarsim.defaults import HIRISE_NULL
from lidarsim.errors import TerrainError
from lidarsim.manifest_json import DtmJson

__all__ = ["DTM", "DTMInfo", "TerrainError", "dtm_sha256", "gdal_side_files", "invalid_mask"]


def _side_files(files: list[str], apath: str) -> tuple[Path, ...]:
    """The files of a GDAL dataset's file list other than ``apath`` itself, absolute and sorted."""
    return tuple(sorted({Path(os.path.abspath(f)) for f in files} - {Path(apath)}))


def gdal_side_files(path: str | os.PathLike[str]) -> tuple[Path, ...]:
    """The files GDAL reads with the raster at ``path`` besides it (rasterio's ``dataset.files``:
    a ``.aux.xml``, a world file or ``.prj`` where the raster has no georeferencing of its own, an
    ``.ovr``, a PDS3 detached label or its data file), absolute and sorted; none when GDAL cannot
    open it (the raster's own error comes when it is opened)."""
    apath = os.path.abspath(os.fspath(path))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(apath) as src:
                return _side_files(list(src.files), apath)
    except (RasterioIOError, RasterioError):
        return ()


def dtm_sha256(path: str | os.PathLike[str], side_files: tuple[Path, ...] | None = None) -> str:
    """The digest hd records for a DTM file (hex): the sha256 of its bytes when GDAL reads no other
    file for it (so the digests of such DTMs, the recipes' included, are those of their bytes, as
    before side files counted); else the sha256 of the lines ``SHA256  NAME\n`` of the file and of
    each side file (:func:`gdal_side_files`, or ``side_files``), names relative to the DTM's folder,
    the DTM first: a changed ``.aux.xml`` or world file changes the digest.

    Raises:
        StorageError: a file that cannot be read.
    """
    apath = os.path.abspath(os.fspath(path))
    own = sha256_file(apath)
    sides = gdal_side_files(apath) if side_files is None else side_files
    if not sides:
        return own
    folder = os.path.dirname(apath)
    lines = [f"{own}  {os.path.basename(apath)}"]
    lines += [f"{sha256_file(side)}  {os.path.relpath(side, folder)}" for side in sides]
    return sha256_bytes("".join(f"{line}\n" for line in lines).encode())


# Rotation/shear terms smaller than this fraction of the pixel size are treated as zero.
_ROTATION_TOLERANCE = 1e-9
# hd choice: heights farther than this from zero (metres) are nodata. The highest and lowest points
# of Mars (Olympus Mons ~+22 km, Hellas ~-8 km) and of the Earth stay far inside it, while fill
# values left undeclared by a producer (1e30, 3.4e38, inf) fall outside.
MAX_ABS_HEIGHT_M = 1.0e5
# Upper bound on source cells read per block by validity_overview (~4 M cells, ~50 MiB of working memory).
_OVERVIEW_BLOCK_CELLS = 1 << 22
# HiRISE NULL as stored in a float32 file (16#FF7FFFFB# = -3.4028226550889045e38): the float64
# literal -3.4028227e38 is *below* its float32 rounding, so the threshold is taken in float32.
_NULL_THRESHOLD = float(np.float32(HIRISE_NULL))
# Slack when converting fractional cell boundaries to integer indices (cells).
_EDGE_EPS = 1e-9


def invalid_mask(values: np.ndarray, nodata: float | None) -> np.ndarray:
    """Boolean mask of invalid cells: NaN, +-inf, the declared ``nodata`` value, HiRISE NULL (``<=``)
    and heights beyond +-``MAX_ABS_HEIGHT_M`` metres.

    ``values`` are heights in any numeric dtype; ``nodata`` is compared in that dtype so that a
    float32 file's nodata matches exactly.
    """
    bad = np.zeros(values.shape, dtype=bool)
    if np.issubdtype(values.dtype, np.floating):
        bad |= ~np.isfinite(values)
        bad |= values <= _NULL_THRESHOLD
        with np.errstate(invalid="ignore"):
            bad |= np.abs(values) > MAX_ABS_HEIGHT_M
    elif np.issubdtype(values.dtype, np.integer):
        bad |= np.abs(values.astype(np.float64)) > MAX_ABS_HEIGHT_M
    if nodata is not None and not math.isnan(nodata):
        bad |= values == np.asarray(nodata).astype(values.dtype)
    return bad


@dataclass(frozen=True)
class DTMInfo:
    """What a DTM is, at the chosen scale.

    Attributes:
        path: absolute path of the file.
        name: file name (no directory).
        crs_wkt: CRS as WKT; "" when the raster has no CRS (treated as local metres).
        transform: GDAL geotransform (a, b, c, d, e, f) at the chosen scale:
            x = c + a*col + b*row, y = f + d*col + e*row, for the pixel *corner* (col, row).
        rows: grid rows at the chosen scale.
        cols: grid columns at the chosen scale.
        spacing_m: (dx, dy) > 0, metres per pixel at the chosen scale.
        scale: resampling factor applied (1.0 = full resolution; 0.25 = the paper's setting).
        nodata: the declared nodata value, or None.
        driver: GDAL driver short name (e.g. "GTiff", "PDS").
    """

    path: str
    name: str
    crs_wkt: str
    transform: tuple[float, float, float, float, float, float]
    rows: int
    cols: int
    spacing_m: tuple[float, float]
    scale: float
    nodata: float | None
    driver: str

    def to_attrs(self) -> DtmJson:
        """Flat dict of str/float/int/list values for HDF5 attributes or JSON (a manifest's ``dtm``
        without its sha256).

        ``nodata`` is present only when the raster declares one (no NaN stand-in for "none").
        """
        attrs: DtmJson = {
            "path": self.path,
            "name": self.name,
            "crs_wkt": self.crs_wkt,
            "transform": [float(v) for v in self.transform],
            "rows": int(self.rows),
            "cols": int(self.cols),
            "spacing_m": [float(v) for v in self.spacing_m],
            "scale": float(self.scale),
            "driver": self.driver,
        }
        if self.nodata is not None:
            attrs["nodata"] = float(self.nodata)
        return attrs


def _check_scale(path: str, scale: float) -> float:
    try:
        value = float(scale)
    except (TypeError, ValueError) as exc:
        raise TerrainError(f"{path}: scale {scale!r} is not a number; use 0 < scale <= 1") from exc
    if not (math.isfinite(value) and 0.0 < value <= 1.0):
        raise TerrainError(f"{path}: scale {scale!r} is out of range; use 0 < scale <= 1 (1 = full resolution)")
    return value


class DTM:
    """An open DTM: windowed reads of heights and coordinate conversions. A context manager.

    Use :meth:`DTM.open`; never loads the whole raster.
    """

    def __init__(self, src: Any, info: DTMInfo, src_transform: tuple[float, ...]) -> None:
        """Wrap an open rasterio dataset (use :meth:`DTM.open` instead of calling this)."""
        self._src = src
        self.info = info
        self._src_transform = src_transform
        self._sha256: str | None = None
        self._memfile: Any = None
        # Full-resolution source cells per scaled cell, along rows and columns.
        self._fy = src.height / info.rows
        self._fx = src.width / info.cols

    # ------------------------------------------------------------------ opening
    @classmethod
    def open(cls, path: str | os.PathLike[str], scale: float = 1.0) -> DTM:
        """Open the raster at ``path``; ``scale`` in (0, 1] resamples the grid (1.0 = full resolution).

        Raises:
            TerrainError: missing/unreadable file, not a raster, geographic CRS, rotated grid,
                non-metre units, or a bad scale.
        """
        apath = os.path.abspath(os.fspath(path))
        if not os.path.exists(apath):
            raise TerrainError(f"{apath}: no such file")
        if os.path.isdir(apath):
            raise TerrainError(f"{apath}: is a directory, not a raster file")
        if not os.path.isfile(apath):
            raise TerrainError(f"{apath}: is not a regular file (a device, a pipe...), not a raster file")
        if not os.access(apath, os.R_OK):
            raise TerrainError(f"{apath}: is not readable (permission denied)")
        value_scale = _check_scale(apath, scale)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                src = rasterio.open(apath)
        except (RasterioIOError, RasterioError) as exc:
            raise TerrainError(f"{apath}: is not a raster GDAL can read") from exc
        try:
            info, src_transform = cls._describe(src, apath, value_scale)
        except BaseException:
            src.close()
            raise
        return cls(src, info, src_transform)

    @classmethod
    def from_bytes(
        cls, data: bytes, path: str | os.PathLike[str], scale: float = 1.0, sha256: str | None = None
    ) -> DTM:
        """A DTM over the bytes of a raster file held in memory.

        ``path`` is where the file will be written: it names the DTM in messages and provenance.
        ``sha256``: the digest :meth:`sha256` reports (default: of ``data``), e.g. the file a grid
        held in memory was made from.

        Raises:
            TerrainError: like :meth:`open`.
        """
        from rasterio.io import MemoryFile

        apath = os.path.abspath(os.fspath(path))
        value_scale = _check_scale(apath, scale)
        memfile = MemoryFile(bytes(data))
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                src = memfile.open()
        except (RasterioIOError, RasterioError) as exc:
            memfile.close()
            raise TerrainError(f"{apath}: is not a raster GDAL can read") from exc
        try:
            info, src_transform = cls._describe(src, apath, value_scale)
        except BaseException:
            src.close()
            memfile.close()
            raise
        dtm = cls(src, info, src_transform)
        dtm._memfile = memfile
        dtm._sha256 = sha256 if sha256 is not None else sha256_bytes(data)
        return dtm

    @staticmethod
    def _describe(src: Any, apath: str, scale: float) -> tuple[DTMInfo, tuple[float, ...]]:
        if src.count < 1 or src.width < 1 or src.height < 1:
            raise TerrainError(f"{apath}: is not a raster GDAL can read (no raster band)")
        crs = src.crs
        crs_wkt = ""
        if crs is not None:
            if crs.is_geographic:
                epsg = crs.to_epsg()
                label = f"EPSG:{epsg}" if epsg else "geographic"
                raise TerrainError(
                    f"{apath}: has a geographic CRS ({label}, degrees); reproject it to a projected CRS "
                    "in metres, e.g. with gdalwarp"
                )
            try:
                unit_name, unit_factor = crs.linear_units_factor
            except Exception:  # noqa: BLE001 - CRS without a linear unit: keep it, treat as metres
                unit_name, unit_factor = "metre", 1.0
            if abs(float(unit_factor) - 1.0) > 1e-12:
                raise TerrainError(
                    f"{apath}: has a projected CRS in {unit_name} (not metres); reproject it to metres, "
                    "e.g. with gdalwarp -t_srs"
                )
            crs_wkt = crs.to_wkt()
        t = src.transform
        if crs is None and t.is_identity and np.dtype(src.dtypes[0]).itemsize == 1:
            raise TerrainError(
                f"{apath}: has no georeferencing and 8-bit values (0-255): an image, not a DTM of heights in "
                "metres; give a GeoTIFF (or HiRISE .IMG) of heights in metres with its cell size"
            )
        a, b, c, d, e, f = (float(v) for v in (t.a, t.b, t.c, t.d, t.e, t.f))
        pixel = max(abs(a), abs(e))
        if not all(math.isfinite(v) for v in (a, b, c, d, e, f)) or a == 0.0 or e == 0.0:
            raise TerrainError(f"{apath}: has a degenerate geotransform {(a, b, c, d, e, f)}")
        if abs(b) > _ROTATION_TOLERANCE * pixel or abs(d) > _ROTATION_TOLERANCE * pixel:
            raise TerrainError(f"{apath}: has a rotated or sheared grid; warp it north-up first, e.g. with gdalwarp")
        rows = max(1, int(round(src.height * scale)))
        cols = max(1, int(round(src.width * scale)))
        fx = src.width / cols
        fy = src.height / rows
        transform = (a * fx, 0.0, c, 0.0, e * fy, f)
        nodata = src.nodatavals[0]
        info = DTMInfo(
            path=apath,
            name=os.path.basename(apath),
            crs_wkt=crs_wkt,
            transform=transform,
            rows=rows,
            cols=cols,
            spacing_m=(abs(a) * fx, abs(e) * fy),
            scale=scale,
            nodata=None if nodata is None else float(nodata),
            driver=str(src.driver),
        )
        return info, (a, 0.0, c, 0.0, e, f)

    # ------------------------------------------------------------------ context manager
    def __enter__(self) -> DTM:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Close the underlying file (idempotent)."""
        self._src.close()
        if self._memfile is not None:
            self._memfile.close()

    def __repr__(self) -> str:
        i = self.info
        return f"DTM({i.name!r}, {i.rows}x{i.cols}, spacing_m={i.spacing_m}, scale={i.scale})"

    # ------------------------------------------------------------------ provenance
    def sha256(self) -> str:
        """The DTM's digest (:func:`dtm_sha256`: its bytes' SHA-256, with the side files GDAL read
        for it when there are any; streamed; cached)."""
        if self._sha256 is None:
            try:
                self._sha256 = dtm_sha256(self.info.path, _side_files(list(self._src.files), self.info.path))
            except StorageError as exc:
                raise type(exc)(f"{self.info.path}: cannot be read for hashing ({exc})") from exc
        return self._sha256

    # ------------------------------------------------------------------ reading
    def _read_source(self, window: Window, out_shape: tuple[int, int] | None = None) -> np.ndarray:
        """Raw band-1 values of a source window (native dtype), optionally resampled (bilinear)."""
        try:
            if out_shape is None:
                return self._src.read(1, window=window)
            return self._src.read(1, window=window, out_shape=out_shape, resampling=Resampling.bilinear)
        except RasterioError as exc:
            raise TerrainError(f"{self.info.path}: read failed ({exc})") from exc

    def read(self, row0: int, col0: int, rows: int, cols: int) -> np.ndarray:
        """Heights (float64 metres) of a window of the grid at the chosen scale.

        ``row0, col0`` is the window's top-left cell, ``rows x cols`` its size (cells); the window
        may extend past the raster edge (or lie wholly outside it): those cells are NaN, as are
        invalid cells (NaN, declared nodata, HiRISE NULL). With scale != 1 the values come from a
        bilinear resampled read, and a cell is valid only if every source cell it overlaps is.
        """
        row0, col0, rows, cols = int(row0), int(col0), int(rows), int(cols)
        if rows < 0 or cols < 0:
            raise TerrainError(f"{self.info.path}: window size {rows}x{cols} is negative")
        out = np.full((rows, cols), np.nan, dtype=np.float64)
        r_lo, r_hi = max(row0, 0), min(row0 + rows, self.info.rows)
        c_lo, c_hi = max(col0, 0), min(col0 + cols, self.info.cols)
        if r_lo >= r_hi or c_lo >= c_hi:
            return out
        nr, nc = r_hi - r_lo, c_hi - c_lo
        if self.info.scale == 1.0:
            raw = self._read_source(Window(c_lo, r_lo, nc, nr))
            bad = invalid_mask(raw, self.info.nodata)
            values = raw.astype(np.float64)
        else:
            values, bad = self._read_scaled(r_lo, c_lo, nr, nc)
        values[bad] = np.nan
        out[r_lo - row0 : r_hi - row0, c_lo - col0 : c_hi - col0] = values
        return out

    def _source_span(self, start: int, count: int, factor: float, limit: int) -> tuple[np.ndarray, np.ndarray]:
        """Per scaled cell [start, start+count): first and one-past-last overlapped source index."""
        idx = np.arange(start, start + count, dtype=np.float64)
        lo = np.floor(idx * factor + _EDGE_EPS).astype(np.int64)
        hi = np.ceil((idx + 1.0) * factor - _EDGE_EPS).astype(np.int64)
        return np.clip(lo, 0, limit), np.clip(hi, 0, limit)

    def _read_scaled(self, r_lo: int, c_lo: int, nr: int, nc: int) -> tuple[np.ndarray, np.ndarray]:
        fy, fx = self._fy, self._fx
        window = Window(c_lo * fx, r_lo * fy, nc * fx, nr * fy)
        raw = self._read_source(window, out_shape=(nr, nc))
        bad_resampled = invalid_mask(raw, self.info.nodata)
        values = raw.astype(np.float64)
        # Validity from the full-resolution cells under each scaled cell (summed-area table).
        r_first, r_last = self._source_span(r_lo, nr, fy, self._src.height)
        c_first, c_last = self._source_span(c_lo, nc, fx, self._src.width)
        sr0, sr1 = int(r_first[0]), int(r_last[-1])
        sc0, sc1 = int(c_first[0]), int(c_last[-1])
        src_raw = self._read_source(Window(sc0, sr0, sc1 - sc0, sr1 - sr0))
        src_bad = invalid_mask(src_raw, self.info.nodata)
        boxes = (r_first - sr0, r_last - sr0, c_first - sc0, c_last - sc0)
        bad = _box_counts(src_bad, *boxes) > 0
        # GDAL's bilinear kernel reaches past a coarse cell, so a NaN next to a valid coarse cell can
        # spoil it; such cells (all their own source cells valid) get the mean of those source cells.
        spoiled = bad_resampled & ~bad
        if spoiled.any():
            filled = np.where(src_bad, 0.0, src_raw.astype(np.float64))
            sums = _box_sums(filled, *boxes)
            counts = (boxes[1] - boxes[0])[:, None] * (boxes[3] - boxes[2])[None, :]
            values[spoiled] = sums[spoiled] / counts[spoiled]
        return values, bad

    def preview(
        self, max_px: int, row0: int = 0, col0: int = 0, rows: int | None = None, cols: int | None = None
    ) -> np.ndarray:
        """Heights of a window of the grid (default: all of it) decimated to at most ``max_px`` cells
        per side, for figures: float64 metres, NaN where invalid, each preview cell the source cell
        nearest its centre (nothing is averaged). One GDAL read with an output shape, so a DTM larger
        than memory is never held at full resolution. The window (cells of the grid at the chosen
        scale) must lie within the grid.

        Raises:
            TerrainError: a window outside the grid, or a failed read.
        """
        rows = self.info.rows - row0 if rows is None else rows
        cols = self.info.cols - col0 if cols is None else cols
        inside = row0 >= 0 and col0 >= 0 and rows > 0 and cols > 0
        if not (inside and row0 + rows <= self.info.rows and col0 + cols <= self.info.cols):
            raise TerrainError(
                f"{self.info.path}: preview window {rows}x{cols} at ({row0}, {col0}) lies outside its "
                f"{self.info.rows}x{self.info.cols} cells"
            )
        k = min(1.0, max_px / max(rows, cols))
        shape = (max(1, round(rows * k)), max(1, round(cols * k)))
        window = Window(col0 * self._fx, row0 * self._fy, cols * self._fx, rows * self._fy)
        try:
            raw = self._src.read(1, window=window, out_shape=shape, resampling=Resampling.nearest)
        except RasterioError as exc:
            raise TerrainError(f"{self.info.path}: read failed ({exc})") from exc
        values = raw.astype(np.float64)
        values[invalid_mask(raw, self.info.nodata)] = np.nan
        return values

    # ------------------------------------------------------------------ coordinates
    def cell_center_xy(self, row: np.ndarray | float, col: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Map coordinates (metres, float64) of the centres of cells (row, col) at the chosen scale."""
        a, _, c, _, e, f = self.info.transform
        r = np.asarray(row, dtype=np.float64)
        k = np.asarray(col, dtype=np.float64)
        return c + a * (k + 0.5), f + e * (r + 0.5)

    def rowcol_of_xy(self, x: np.ndarray | float, y: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (row, col) such that :meth:`cell_center_xy` maps them back to (x, y) metres."""
        a, _, c, _, e, f = self.info.transform
        xx = np.asarray(x, dtype=np.float64)
        yy = np.asarray(y, dtype=np.float64)
        return (yy - f) / e - 0.5, (xx - c) / a - 0.5

    # ------------------------------------------------------------------ validity
    def validity_overview(
        self, cell_m: float, window: tuple[int, int, int, int] | None = None
    ) -> tuple[np.ndarray, tuple[float, ...]]:
        """Coarse validity grid of ``cell_m``-metre cells and its GDAL geotransform.

        A coarse cell is True where every full-resolution DTM cell it overlaps is valid. The grid
        starts at the raster's top-left corner and covers the whole raster; coarse cells that
        extend past the raster edge are False (part of them is not terrain). Computed by streaming
        row blocks, so a DTM larger than memory works. ``window`` = (row0, col0, rows, cols) of cells
        of the grid at the chosen scale, within it: the full-resolution cells under it alone are
        read, as if they were the raster (the coarse grid starts at their top-left corner; "every
        cell is nodata" then means the window's).

        Raises:
            TerrainError: ``cell_m`` not a positive finite number, or every DTM cell (of the window) is invalid.
        """
        path = self.info.path
        try:
            cell = float(cell_m)
        except (TypeError, ValueError) as exc:
            raise TerrainError(f"{path}: overview cell size {cell_m!r} is not a number") from exc
        if not (math.isfinite(cell) and cell > 0.0):
            raise TerrainError(f"{path}: overview cell size {cell_m!r} must be a positive number of metres")
        a, _, c, _, e, f = self._src_transform
        if window is None:
            row_off, col_off, height, width = 0, 0, self._src.height, self._src.width
        else:  # the full-resolution cells under the window's cells
            r_lo, r_hi = self._source_span(window[0], window[2], self._fy, self._src.height)
            c_lo, c_hi = self._source_span(window[1], window[3], self._fx, self._src.width)
            row_off, col_off = int(r_lo[0]), int(c_lo[0])
            height, width = int(r_hi[-1]) - row_off, int(c_hi[-1]) - col_off
        c, f = c + a * col_off, f + e * row_off
        fy = cell / abs(e)  # source rows per coarse cell
        fx = cell / abs(a)
        n_rows = max(1, math.ceil(height / fy - _EDGE_EPS))
        n_cols = max(1, math.ceil(width / fx - _EDGE_EPS))
        c_first, c_last = self._source_span(0, n_cols, fx, width)
        col_complete = np.ceil((np.arange(n_cols) + 1.0) * fx - _EDGE_EPS) <= width
        r_first, r_last = self._source_span(0, n_rows, fy, height)
        row_complete = np.ceil((np.arange(n_rows) + 1.0) * fy - _EDGE_EPS) <= height
        valid = np.zeros((n_rows, n_cols), dtype=bool)
        any_valid = False
        rows_per_block = max(1, _OVERVIEW_BLOCK_CELLS // max(width, 1))
        i = 0
        while i < n_rows:
            # Group coarse rows whose source rows fit in one block.
            j = i + 1
            while j < n_rows and r_last[j] - r_first[i] <= rows_per_block:
                j += 1
            s0, s1 = int(r_first[i]), int(r_last[j - 1])
            raw = self._read_source(Window(col_off, row_off + s0, width, s1 - s0))
            bad = invalid_mask(raw, self.info.nodata)
            any_valid = any_valid or not bool(bad.all())
            counts = _box_counts(bad, r_first[i:j] - s0, r_last[i:j] - s0, c_first, c_last)
            valid[i:j] = counts == 0
            i = j
        if not any_valid:
            raise TerrainError(f"{path}: every cell {'of the window ' if window is not None else ''}is nodata")
        valid &= row_complete[:, None] & col_complete[None, :]
        transform = (math.copysign(cell, a), 0.0, c, 0.0, math.copysign(cell, e), f)
        return valid, transform


def _box_counts(
    mask: np.ndarray,
    r_first: np.ndarray,
    r_last: np.ndarray,
    c_first: np.ndarray,
    c_last: np.ndarray,
) -> np.ndarray:
    """Number of True cells of ``mask`` in each box [r_first[i], r_last[i]) x [c_first[j], c_last[j])."""
    return _box_sums(mask.astype(np.int64), r_first, r_last, c_first, c_last)


def _box_sums(
    values: np.ndarray,
    r_first: np.ndarray,
    r_last: np.ndarray,
    c_first: np.ndarray,
    c_last: np.ndarray,
) -> np.ndarray:
    """Sum of ``values`` over each box [r_first[i], r_last[i]) x [c_first[j], c_last[j]) (summed-area table)."""
    sat = np.zeros((values.shape[0] + 1, values.shape[1] + 1), dtype=values.dtype)
    np.cumsum(np.cumsum(values, axis=0), axis=1, out=sat[1:, 1:])
    r0, r1 = r_first[:, None], r_last[:, None]
    c0, c1 = c_first[None, :], c_last[None, :]
    return sat[r1, c1] - sat[r0, c1] - sat[r1, c0] + sat[r0, c0]
