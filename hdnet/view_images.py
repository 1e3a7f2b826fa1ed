"""The images of ``hd view``: maps of any size reduced to a bounded image, coloured and encoded as PNG.

A map of ``rows x cols`` cells is shown at one image pixel per block of ``factor x factor`` cells,
``factor`` the smallest integer that brings the longer side to at most ``max_px`` pixels
(:class:`Reduction`; 1 for maps that fit). The GeoTIFFs are read window by window, a strip of
blocks at a time, so that a map larger than memory is reduced in bounded memory
(:func:`reduced_map`): a continuous map (P(safe), entropy, mutual information, the baseline) as the
mean of each block's valid cells, the safety map as each block's worst class (unsafe over uncertain
over safe over invalid), so that a pixel shown safe is safe in every cell it stands for. Blocks
past the map's last row or column hold only the map's own cells (the rest is invalid).

Colours: P(safe) and the ALHAT baseline with the diverging ``RdYlGn`` map over [0, 1] (red unsafe,
green safe), the uncertainty scores with ``viridis`` over [0, ln 2] nats (the range of a two-class
entropy), the safety map with ``hdnet.palette``'s colours; invalid cells are transparent. The
hillshade is matplotlib's ``LightSource`` (sun at azimuth 315 degrees, 45 degrees high) of heights
read from the terrain over the image's extent (:func:`terrain_heights`).
"""

from __future__ import annotations

import io
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.image
import numpy as np
import rasterio
from matplotlib.colors import LightSource, to_rgb
from rasterio.enums import Resampling
from rasterio.errors import RasterioError
from rasterio.windows import Window, from_bounds

from hdcore.errors import DamagedFileError
from hdcore.storage import check_regular_file
from hdnet.palette import SAFETY_HEX
from hdnet.sites import SAFETY_INVALID, SAFETY_SAFE, SAFETY_UNCERTAIN, SAFETY_UNSAFE

# hd choice: cells read per window while reducing a map (16 MiB of float32), whatever its size.
STRIP_CELLS = 1 << 22
SAFETY_CODES = (SAFETY_UNSAFE, SAFETY_SAFE, SAFETY_UNCERTAIN, SAFETY_INVALID)
# Worst first: the class a reduced block shows is the first of these that one of its cells has.
SAFETY_PRIORITY = (SAFETY_UNSAFE, SAFETY_UNCERTAIN, SAFETY_SAFE, SAFETY_INVALID)
# Opacity (0-255) of each safety class in the safety layer's own image; the page's slider scales it.
SAFETY_ALPHA = {SAFETY_UNSAFE: 255, SAFETY_SAFE: 255, SAFETY_UNCERTAIN: 255, SAFETY_INVALID: 0}
PROBABILITY_CMAP = "RdYlGn"
UNCERTAINTY_CMAP = "viridis"
UNCERTAINTY_MAX_NATS = math.log(2.0)  # a two-class entropy's largest value; mutual information <= entropy


@dataclass(frozen=True)
class Reduction:
    """How a map of ``grid`` = (rows, cols) cells is shown: one pixel per ``factor x factor`` cells, an
    image of ``shape`` = (rows, cols) pixels."""

    grid: tuple[int, int]
    factor: int
    shape: tuple[int, int]

    @classmethod
    def of(cls, grid: tuple[int, int], max_px: int) -> Reduction:
        """The reduction of a ``grid`` (rows, cols) whose image's longer side is at most ``max_px`` pixels."""
        rows, cols = int(grid[0]), int(grid[1])
        factor = max(1, math.ceil(max(rows, cols) / max_px))
        return cls((rows, cols), factor, (math.ceil(rows / factor), math.ceil(cols / factor)))

    @property
    def reduced(self) -> bool:
        """True when a pixel stands for more than one cell."""
        return self.factor > 1


def _reduce_block(block: np.ndarray, factor: int, categorical: bool) -> np.ndarray:
    """One strip (a whole number of blocks, padded) reduced: (r*f, c*f) -> (r, c)."""
    r, c = block.shape[0] // factor, block.shape[1] // factor
    cells = block.reshape(r, factor, c, factor).swapaxes(1, 2).reshape(r, c, factor * factor)
    if categorical:
        out = np.full((r, c), SAFETY_INVALID, np.uint8)
        for code in reversed(SAFETY_PRIORITY[:-1]):  # the worst class last, so that it wins
            out[(cells == code).any(axis=2)] = code
        return out
    valid = np.isfinite(cells)
    count = valid.sum(axis=2)
    total = np.where(valid, cells, 0.0).sum(axis=2, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan).astype(np.float32)


def reduced_array(values: np.ndarray, reduction: Reduction) -> np.ndarray:
    """A continuous array of ``reduction.grid`` cells in memory reduced as :func:`reduced_map` reduces a map."""
    f = reduction.factor
    block = np.full((reduction.shape[0] * f, reduction.shape[1] * f), np.nan, np.float64)
    block[: values.shape[0], : values.shape[1]] = values
    return _reduce_block(block, f, categorical=False)


def reduced_codes(codes: np.ndarray, reduction: Reduction) -> np.ndarray:
    """Safety codes of ``reduction.grid`` cells in memory (uint8) reduced as :func:`reduced_map` reduces a
    safety map: each block's worst class."""
    f = reduction.factor
    block = np.full((reduction.shape[0] * f, reduction.shape[1] * f), SAFETY_INVALID, np.uint8)
    block[: codes.shape[0], : codes.shape[1]] = codes
    return _reduce_block(block, f, categorical=True)


def reduced_map(path: Path, reduction: Reduction, categorical: bool = False) -> np.ndarray:
    """Band 1 of the map at ``path`` reduced as ``reduction`` says (see the module's docstring):
    float32 with NaN where a block has no valid cell, or (``categorical``) the safety codes, uint8.

    Raises:
        DamagedFileError: a missing file, one GDAL cannot read (or whose blocks cannot be read), of another size
            than ``reduction.grid``, with more than one band, of another data type, or (a safety map)
            holding a value that is no safety code. FormatError: not a regular file.
    """
    f = reduction.factor
    rows, cols = reduction.grid
    fill: float | int = SAFETY_INVALID if categorical else np.nan
    dtype = np.uint8 if categorical else np.float32
    out = np.empty(reduction.shape, dtype)
    if not os.path.lexists(path):
        raise DamagedFileError(f"{path}: missing; the output is incomplete: run hd detect again")
    check_regular_file(path)  # a FIFO or a device in its place is refused, never opened
    try:
        with rasterio.open(path) as src:
            if (src.height, src.width) != (rows, cols) or src.count != 1:
                raise DamagedFileError(
                    f"{path}: {src.count} band(s) of {src.height} x {src.width} cells, not the one band of "
                    f"{rows} x {cols} cells of detect.json's grid; the output is damaged: run hd detect again"
                )
            if np.dtype(src.dtypes[0]) != np.dtype(dtype):
                raise DamagedFileError(
                    f"{path}: {src.dtypes[0]} values, not the {np.dtype(dtype).name} hd detect writes; the "
                    "output is damaged: run hd detect again"
                )
            strip = max(1, STRIP_CELLS // max(1, f * f * reduction.shape[1]))  # image rows per read
            for i0 in range(0, reduction.shape[0], strip):
                i1 = min(i0 + strip, reduction.shape[0])
                r0, r1 = i0 * f, min(i1 * f, rows)
                values = src.read(1, window=Window(0, r0, cols, r1 - r0))
                block = np.full(((i1 - i0) * f, reduction.shape[1] * f), fill, dtype)
                block[: r1 - r0, :cols] = values
                if categorical:
                    odd = ~np.isin(values, SAFETY_CODES)
                    if odd.any():
                        r, c = (int(v[0]) for v in np.nonzero(odd))
                        raise DamagedFileError(
                            f"{path}: the value {int(values[r, c])} at row {r0 + r}, column {c} is no safety code "
                            "(0 unsafe, 1 safe, 2 uncertain, 255 invalid); the output is damaged: run hd detect again"
                        )
                out[i0:i1] = _reduce_block(block, f, categorical)
    except RasterioError as exc:
        raise DamagedFileError(
            f"{path}: unreadable ({exc}); the output is damaged: run hd detect again (or restore the file)"
        ) from exc
    return out


def terrain_heights(
    path: Path,
    extent: tuple[float, float, float, float],
    shape: tuple[int, int],
) -> np.ndarray:
    """Heights (float64 metres, NaN where invalid or outside the raster) of the raster at ``path`` over
    ``extent`` = (left, right, bottom, top) map metres, on a grid of ``shape`` (rows, cols) cells:
    block means where the raster is finer, bilinear where it is coarser.

    Raises:
        DamagedFileError: a raster GDAL cannot read.
    """
    left, right, bottom, top = extent
    try:
        with rasterio.open(path) as src:
            window = from_bounds(left, bottom, right, top, src.transform)
            finer = window.width >= shape[1]
            values = src.read(
                1,
                window=window,
                out_shape=shape,
                boundless=True,
                masked=True,
                out_dtype="float64",
                resampling=Resampling.average if finer else Resampling.bilinear,
            )
    except RasterioError as exc:
        raise DamagedFileError(f"{path}: unreadable raster ({exc})") from exc
    heights = np.ma.filled(values.astype(np.float64), np.nan)
    heights[~np.isfinite(heights) | (np.abs(heights) > 1e15)] = np.nan  # HiRISE NULL and the like
    return np.asarray(heights)


def hillshade_rgba(heights_m: np.ndarray, cell_m: float) -> np.ndarray:
    """A grey hillshade (uint8 RGBA) of heights on ``cell_m``-metre cells; NaN cells transparent."""
    z = np.asarray(heights_m, np.float64)
    finite = np.isfinite(z)
    filled = np.where(finite, z, np.nanmean(z) if finite.any() else 0.0)
    shade = LightSource(azdeg=315, altdeg=45).hillshade(filled, vert_exag=1.0, dx=cell_m, dy=cell_m)
    grey = np.clip(np.round(np.nan_to_num(shade, nan=0.5) * 255.0), 0, 255).astype(np.uint8)
    rgba = np.empty((*z.shape, 4), np.uint8)
    rgba[..., :3] = grey[..., None]
    rgba[..., 3] = np.where(finite, 255, 0)
    return rgba


def colour_rgba(values: np.ndarray, cmap: str, vmin: float, vmax: float) -> np.ndarray:
    """``values`` coloured with the matplotlib colour map ``cmap`` over [vmin, vmax] (uint8 RGBA); NaN transparent."""
    v = np.asarray(values, np.float64)
    scaled = np.clip((v - vmin) / (vmax - vmin), 0.0, 1.0)
    rgba = matplotlib.colormaps[cmap](np.nan_to_num(scaled, nan=0.0), bytes=True)
    rgba[..., 3] = np.where(np.isfinite(v), 255, 0)
    return np.asarray(rgba, np.uint8)


def safety_rgba(codes: np.ndarray) -> np.ndarray:
    """The safety codes coloured as ``hdnet.palette`` says (uint8 RGBA; invalid transparent)."""
    rgba = np.zeros((*codes.shape, 4), np.uint8)
    for code, colour in zip((SAFETY_UNSAFE, SAFETY_SAFE, SAFETY_UNCERTAIN), SAFETY_HEX[:3], strict=True):
        r, g, b = (round(255 * c) for c in to_rgb(colour))
        rgba[codes == code] = (r, g, b, SAFETY_ALPHA[code])
    return rgba


def _hex(rgb: Any) -> str:
    return "#{:02x}{:02x}{:02x}".format(*(int(v) for v in rgb[:3]))


def colour_table(cmap: str) -> list[str]:
    """Every colour of the matplotlib colour map ``cmap`` in order, as ``#rrggbb``: exactly the colours
    :func:`colour_rgba` gives (entry ``i`` of ``n`` for a value in the ``i``-th ``n``-th of its range),
    so that a page can read a value back from a pixel."""
    colours = matplotlib.colormaps[cmap]
    return [_hex(rgb) for rgb in colours(np.arange(colours.N), bytes=True)]


SAFETY_WORDS = {SAFETY_UNSAFE: "unsafe", SAFETY_SAFE: "safe", SAFETY_UNCERTAIN: "uncertain"}


def safety_classes() -> dict[str, str]:
    """The colour (``#rrggbb``) of each safety class in :func:`safety_rgba`'s image -> its name."""
    rgba = safety_rgba(np.array([list(SAFETY_WORDS)], np.uint8))[0]
    return {_hex(px): SAFETY_WORDS[code] for code, px in zip(SAFETY_WORDS, rgba, strict=True)}


def colour_stops(cmap: str, n: int = 11) -> list[str]:
    """``n`` evenly spaced colours of a matplotlib colour map, as ``#rrggbb`` (a legend's gradient)."""
    colours = matplotlib.colormaps[cmap](np.linspace(0.0, 1.0, n))
    return ["#{:02x}{:02x}{:02x}".format(*(round(255 * c) for c in rgb[:3])) for rgb in colours]


def png_bytes(rgba: np.ndarray) -> bytes:
    """The PNG encoding of a uint8 RGBA image (no timestamp: the same image gives the same bytes)."""
    buf = io.BytesIO()
    no_software: dict[str, Any] = {"Software": None}  # matplotlib's documented way to leave the key out
    matplotlib.image.imsave(buf, np.ascontiguousarray(rgba, np.uint8), format="png", metadata=no_software)
    return buf.getvalue()


def png_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) pixels of PNG bytes from their header, or None when they are no PNG."""
    if len(data) < 24 or data[:8] != b"\x89PNG\r\n\x1a\n" or data[12:16] != b"IHDR":
        return None
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def check_png(data: bytes, path: Path) -> tuple[int, int]:
    """(width, height) of the PNG image ``data`` read from ``path``, decoded whole to check it.

    Raises:
        DamagedFileError: no PNG, or one that does not decode (cut short, altered).
    """
    size = png_size(data)
    if size is None:
        raise DamagedFileError(f"{path}: not a PNG image; the report is damaged: run hd eval again")
    try:
        matplotlib.image.imread(io.BytesIO(data), format="png")
    except (OSError, ValueError, SyntaxError) as exc:  # Pillow's errors of a damaged image
        raise DamagedFileError(
            f"{path}: a damaged PNG image ({exc}); the report is damaged: run hd eval again"
        ) from exc
    return size
