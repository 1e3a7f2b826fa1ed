"""Real relief plus a procedural rock population: a measured DTM resampled finer, with rocks.

A HiRISE DTM resolves the relief of a landing site (slopes, craters of tens of metres) but not
its boulders: at 1-4 m posts a 1 m rock is invisible. Landing-site studies take the rock
abundance from thermal inertia and rock counts instead. :func:`rocks_on_base` combines the two:

1. the base DTM is resampled to ``spacing_m`` (<= 0.5 m, the procedural terrain's limit) by
   bilinear interpolation between the centres of its cells (cells outside the outermost centres
   take the edge value; a cell next to an invalid base cell is invalid);
2. optionally, small fresh craters below the base's resolution (diameters
   ``crater_d_min_m .. crater_d_max_m``, the procedural size-frequency distribution and profile);
3. the procedural rock population (Golombek & Rapp, ``rock_k``), each rock resting on the relief
   under its centre (:func:`lidarsim.procedural.stamp_rocks`).

Random streams are the procedural terrain's (``SeedSequence([seed, purpose])``): the same seed
gives the same craters and rocks per square metre. The output keeps the base's CRS and its
top-left corner; its tags record the base's name and sha256 (``hd make-dtm --base``,
``docs/terrain.md``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from hdcore.storage import write_bytes_atomic
from lidarsim import terrain_defaults as td
from lidarsim.errors import TerrainError
from lidarsim.procedural import (
    MarsTerrainParams,
    geotiff_bytes,
    sample_craters,
    sample_rock_diameters,
    stamp_crater,
    stamp_rocks,
    terrain_stream,
)
from lidarsim.terrain import DTM, DTMInfo

__all__ = [
    "RockyTerrain",
    "check_relief",
    "resample_bilinear",
    "rocks_on_base",
    "rocky_geotiff_bytes",
    "write_rocky_dtm",
]

GENERATOR = "lidarsim.base_relief.rocks_on_base"
# Largest output accepted (cells): 2**28 float32 cells = 1 GiB (16384^2, the procedural limit).
_MAX_CELLS = 1 << 28


@dataclass(frozen=True)
class RockyTerrain:
    """A base DTM resampled with rocks (and small craters) added.

    Attributes:
        heights: float32 metres, row 0 north; NaN where the base is invalid.
        spacing_m: grid spacing, metres/pixel.
        origin_xy: map position of the top-left corner (the base's), metres.
        crs_wkt: the base's CRS ("" = local metres).
        tags: GeoTIFF tags: generator, base name and sha256, seed, parameters (JSON).
        n_rocks: rocks placed.
        n_craters: small craters placed.
    """

    heights: np.ndarray
    spacing_m: float
    origin_xy: tuple[float, float]
    crs_wkt: str
    tags: dict[str, str]
    n_rocks: int
    n_craters: int


def axis_weights(n_out: int, spacing_m: float, n_src: int, src_spacing_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Lower source index and weight of the upper one for ``n_out`` cell centres along one axis.

    Cell i of the output has its centre at (i + 0.5) * spacing_m from the common corner; source
    cell j at (j + 0.5) * src_spacing_m. Centres outside the outermost source centres clamp.
    """
    pos = ((np.arange(n_out, dtype=np.float64) + 0.5) * spacing_m) / src_spacing_m - 0.5
    pos = np.clip(pos, 0.0, n_src - 1.0)
    lo = np.minimum(np.floor(pos).astype(np.int64), max(n_src - 2, 0))
    return lo, pos - lo


def resample_bilinear(
    values: np.ndarray, src_spacing_m: tuple[float, float], spacing_m: float, shape: tuple[int, int]
) -> np.ndarray:
    """Bilinear resampling of a north-up grid onto ``shape`` cells of ``spacing_m`` (metres/pixel).

    ``values`` (rows, cols) are heights at the centres of cells ``src_spacing_m`` = (x, y) metres
    wide; both grids share their top-left corner. NaN spreads to every output cell that
    interpolates from it with a non-zero weight. Returns float64 metres. Separable: along the
    columns of the two source rows around an output row, then between them; compiled with numba
    (one thread), the arithmetic of the NumPy form it replaced, bit for bit
    (``tests/lidarsim/rocks_numpy.py``).
    """
    src = np.ascontiguousarray(values, dtype=np.float64)
    rows, cols = src.shape
    r_lo, r_w = axis_weights(shape[0], spacing_m, rows, src_spacing_m[1])
    c_lo, c_w = axis_weights(shape[1], spacing_m, cols, src_spacing_m[0])
    return resample_cells(src, (r_lo, r_w), (c_lo, c_w))


def resample_cells(
    src: np.ndarray, row_weights: tuple[np.ndarray, np.ndarray], col_weights: tuple[np.ndarray, np.ndarray]
) -> np.ndarray:
    """The output cells of :func:`resample_bilinear` whose rows and columns have the weights
    ``row_weights`` and ``col_weights`` (each ``axis_weights``' (lower source index, weight of the
    upper one), or any selection of their entries): a window of the output is the same cells, bit for
    bit, as the whole grid's. ``src``: float64 C-contiguous source heights. Returns float64 metres."""
    (r_lo, r_w), (c_lo, c_w) = row_weights, col_weights
    rows, cols = src.shape
    out = np.empty((r_lo.size, c_lo.size), dtype=np.float64)
    _resample_jit(src, r_lo, np.minimum(r_lo + 1, rows - 1), r_w, c_lo, np.minimum(c_lo + 1, cols - 1), c_w, out)
    return out


def _lerp_one(a, b, w):  # pragma: no cover - compiled by numba
    """a (1 - w) + b w, with a value of weight 0 left out (a NaN there does not spread)."""
    if w == 0.0:
        return a
    if w == 1.0:
        return b
    return a * (1.0 - w) + b * w


def _resample_loops(src, r_lo, r_hi, r_w, c_lo, c_hi, c_w, out):  # pragma: no cover - compiled by numba
    """Every output row from the two source rows around it."""
    for i in range(out.shape[0]):
        lo, hi, w = src[r_lo[i]], src[r_hi[i]], r_w[i]
        for j in range(out.shape[1]):
            a = _lerp_one(lo[c_lo[j]], lo[c_hi[j]], c_w[j])
            b = _lerp_one(hi[c_lo[j]], hi[c_hi[j]], c_w[j])
            out[i, j] = _lerp_one(a, b, w)


_lerp_one = numba.njit(cache=True)(_lerp_one)
_resample_jit = numba.njit(cache=True)(_resample_loops)


def _checked_spacing(spacing_m: float) -> float:
    if not (isinstance(spacing_m, (int, float)) and math.isfinite(spacing_m) and 0.0 < spacing_m <= td.MAX_SPACING_M):
        raise TerrainError(
            f"--spacing must be in (0, {td.MAX_SPACING_M}] metres so that boulders are represented, got {spacing_m}"
        )
    return float(spacing_m)


def check_relief(values: np.ndarray, path: str) -> None:
    """Refuse a base DTM that has no relief to put rocks on, before any work is done with it.

    ``values``: the base's heights (metres, NaN where invalid). Refused: every cell nodata; and
    valid cells that never form a 2 x 2 block. Bilinear resampling (:func:`resample_bilinear`)
    defines the relief only between four valid cell centres - an output cell next to an invalid
    one is invalid - so such a base would give a terrain of nodata, with rocks stamped on NaN.

    Raises:
        TerrainError: one line naming the base and what it lacks.
    """
    valid = np.isfinite(values)
    if not valid.any():
        raise TerrainError(f"{path}: every cell is nodata; a base DTM needs relief to put the rocks on")
    blocks = valid
    if blocks.shape[0] > 1:
        blocks = blocks[:-1] & blocks[1:]
    if blocks.shape[1] > 1:
        blocks = blocks[:, :-1] & blocks[:, 1:]
    if not blocks.any():
        raise TerrainError(
            f"{path}: {int(valid.sum())} of {valid.size} cells are valid, none in a 2 x 2 block of valid cells: "
            "resampled bilinearly, the base has no relief to put the rocks on; use a DTM with a valid area"
        )


def _output_shape(info: DTMInfo, spacing_m: float) -> tuple[int, int]:
    """Step 1 of :func:`rocks_on_base`: the (rows, cols) of the base's extent at ``spacing_m`` (m/px).

    Raises:
        TerrainError: fewer than two cells a side, or more than 2**28 cells.
    """
    width_m = info.cols * info.spacing_m[0]
    height_m = info.rows * info.spacing_m[1]
    shape = (int(math.floor(height_m / spacing_m + 1e-9)), int(math.floor(width_m / spacing_m + 1e-9)))
    if shape[0] < 2 or shape[1] < 2:
        raise TerrainError(f"{info.path}: {width_m:g} x {height_m:g} m is less than two cells of {spacing_m:g} m")
    if shape[0] * shape[1] > _MAX_CELLS:
        raise TerrainError(
            f"{info.path}: {width_m:g} x {height_m:g} m at {spacing_m:g} m/px is {shape[0]} x {shape[1]} cells "
            f"({shape[0] * shape[1] * 4 / 2**30:.1f} GiB); hd's maximum is {_MAX_CELLS * 4 / 2**30:.0f} GiB: "
            "cut the base DTM into parts or choose a coarser --spacing"
        )
    return shape


def _recorded_params(params: MarsTerrainParams, spacing_m: float, craters: bool) -> dict[str, Any]:
    """Step 2 of :func:`rocks_on_base`: the parameters the output's tags record (the rocks', the
    spacing in m/px, ``craters`` and, with craters, the crater_* fields)."""
    recorded: dict[str, Any] = {
        "rock_k": params.rock_k,
        "rock_d_min_m": params.rock_d_min_m,
        "rock_d_max_m": params.rock_d_max_m,
        "rock_height_ratio": params.rock_height_ratio,
        "spacing_m": spacing_m,
        "craters": bool(craters),
    }
    if craters:
        recorded |= {f.name: getattr(params, f.name) for f in dataclasses.fields(params) if f.name.startswith("crater")}
    return recorded


def rocks_on_base(
    base_path: str | os.PathLike[str],
    params: MarsTerrainParams | None = None,
    seed: int = 0,
    spacing_m: float = td.SPACING_M,
    craters: bool = False,
) -> RockyTerrain:
    """The base DTM at ``base_path`` resampled to ``spacing_m`` with the rocks of ``params`` added.

    ``params`` gives the rock population (rock_k, rock_d_min_m, rock_d_max_m, rock_height_ratio)
    and, with ``craters``, the small craters (crater_* fields; choose crater_d_max_m below the
    base's resolution; None = the defaults). Its size and relief fields are not used: the base gives the relief.

    Raises:
        TerrainError: an unreadable base, a base without relief (:func:`check_relief`), a spacing
            outside (0, 0.5] m, an output of more than 2**28 cells, or a negative seed.
    """
    params = MarsTerrainParams() if params is None else params
    spacing_m = _checked_spacing(spacing_m)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise TerrainError(f"--seed must be an integer >= 0, got {seed!r}")
    with DTM.open(base_path) as base:
        info = base.info
        shape = _output_shape(info, spacing_m)
        values = base.read(0, 0, info.rows, info.cols)
        check_relief(values, info.path)
        digest = base.sha256()
        t = info.transform
        origin = (float(t[2]), float(t[5]))
    heights = resample_bilinear(values, info.spacing_m, spacing_m, shape)
    del values
    n_craters = 0
    if craters and params.crater_n_gt_10m_per_km2 > 0.0:
        side = max(shape) * spacing_m
        centers, diameters = sample_craters(
            dataclasses.replace(params, size_m=side), terrain_stream(seed, td.PURPOSE_CRATERS)
        )
        for center, diameter in zip(centers, diameters, strict=True):
            stamp_crater(heights, spacing_m, (float(center[0]), float(center[1])), float(diameter), params)
        n_craters = int(diameters.size)
    rock_rng = terrain_stream(seed, td.PURPOSE_ROCKS)
    area = shape[0] * shape[1] * spacing_m * spacing_m
    rock_d = sample_rock_diameters(params.rock_k, params.rock_d_min_m, params.rock_d_max_m, area, rock_rng)
    rock_xy = rock_rng.random((rock_d.size, 2)) * np.array([shape[1] * spacing_m, shape[0] * spacing_m])
    stamp_rocks(heights, spacing_m, rock_xy, rock_d, params.rock_height_ratio)
    recorded = _recorded_params(params, spacing_m, craters)
    tags = {
        "generator": GENERATOR,
        "base": info.name,
        "base_sha256": digest,
        "seed": str(seed),
        "params": json.dumps(recorded, sort_keys=True),
    }
    return RockyTerrain(
        heights=heights.astype(np.float32),
        spacing_m=spacing_m,
        origin_xy=origin,
        crs_wkt=info.crs_wkt,
        tags=tags,
        n_rocks=int(rock_d.size),
        n_craters=n_craters,
    )


def rocky_geotiff_bytes(terrain: RockyTerrain, name: str) -> bytes:
    """``terrain`` as the bytes of hd's float32 GeoTIFF (``name`` names the file in errors)."""
    return geotiff_bytes(terrain.heights, terrain.spacing_m, terrain.origin_xy, terrain.crs_wkt, terrain.tags, name)


def write_rocky_dtm(path: str | os.PathLike[str], terrain: RockyTerrain) -> None:
    """Write ``terrain`` to ``path`` as a GeoTIFF (atomic: temporary name, fsync, rename)."""
    target = os.path.abspath(os.fspath(path))
    directory = os.path.dirname(target)
    if not os.path.isdir(directory):
        raise TerrainError(f"{target}: directory {directory} does not exist")
    write_bytes_atomic(target, rocky_geotiff_bytes(terrain, target))
