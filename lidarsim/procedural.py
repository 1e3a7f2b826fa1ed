"""The embedded default terrain: a seeded procedural Mars surface at sub-metre spacing.

Three components, each with its own random stream (``SeedSequence([seed, purpose])``):

1. fractal relief — spectral synthesis of a self-affine surface (power-law spectrum, Hurst H),
   scaled to a target RMS slope at a reference baseline;
2. craters — diameters from a cumulative power-law size-frequency distribution, positions
   uniform, each added as a fresh simple-crater profile (parabolic bowl, raised rim, ejecta);
3. rocks — diameters from the Golombek & Rapp (1997) model, positions uniform, each a
   half-ellipsoid resting on the terrain, stamped with ``max()``.

Grids are north-up: row 0 is the north edge, column 0 the west edge. Inside this module positions
are offsets in metres from the grid's top-left corner: ``east_m`` along columns, ``south_m`` along
rows (cell (r, c) has its centre at ``((c + 0.5) * spacing, (r + 0.5) * spacing)``).
Constants and their sources: :mod:`lidarsim.terrain_defaults`; guide: ``docs/terrain.md``.
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
from rasterio.crs import CRS
from rasterio.transform import Affine, from_origin

from hdcore.storage import write_bytes_atomic
from lidarsim import terrain_defaults as td
from lidarsim.errors import TerrainError

__all__ = [
    "MarsTerrainParams",
    "crater_profile",
    "expected_rock_count",
    "fractal_relief",
    "generate_mars_terrain",
    "geotiff_profile",
    "params_tags",
    "rock_q_per_m",
    "sample_craters",
    "sample_rock_diameters",
    "stamp_crater",
    "stamp_rocks",
    "terrain_stream",
    "terrain_tags",
    "write_geotiff",
    "write_procedural_dtm",
]

# Largest grid accepted (cells per side): 2**14 cells = 1 GiB of float32 heights.
_MAX_CELLS_PER_SIDE = 1 << 14
# Points of the numerical inverse CDF used to sample rock diameters.
_ROCK_CDF_POINTS = 4096


@dataclass(frozen=True)
class MarsTerrainParams:
    """Parameters of the procedural Mars terrain (defaults and sources in ``terrain_defaults``).

    Attributes:
        size_m: side of the square tile (metres).
        spacing_m: grid spacing (metres/pixel), 0 < spacing_m <= 0.5.
        relief_hurst: Hurst exponent H of the fractal relief, 0 < H < 1 (dimensionless).
        relief_rms_slope_deg: RMS slope of the relief at ``relief_baseline_m`` (degrees); 0 = flat.
        relief_baseline_m: baseline of that RMS slope (metres).
        crater_sfd_exponent: b in the cumulative SFD N(>D) = N10 (D / 10 m)^-b (dimensionless).
        crater_n_gt_10m_per_km2: N10, craters with D > 10 m per km^2; 0 = no craters.
        crater_d_min_m: smallest crater diameter sampled (metres).
        crater_d_max_m: largest crater diameter sampled (metres).
        crater_depth_ratio: rim-crest-to-floor depth over diameter (dimensionless).
        crater_rim_ratio: rim height above the surroundings over diameter (dimensionless).
        crater_ejecta_falloff_exponent: ejecta thickness ~ (r/R)^-n outside the rim (dimensionless).
        crater_ejecta_extent_radii: ejecta tapered to zero at this distance, in crater radii.
        rock_k: Golombek-Rapp total rock abundance k (fraction of area), 0 or 0.05-0.4; 0 = no rocks.
        rock_d_min_m: smallest rock diameter sampled (metres).
        rock_d_max_m: largest rock diameter sampled (metres).
        rock_height_ratio: rock height over diameter (dimensionless).
    """

    size_m: float = td.SIZE_M
    spacing_m: float = td.SPACING_M
    relief_hurst: float = td.RELIEF_HURST
    relief_rms_slope_deg: float = td.RELIEF_RMS_SLOPE_DEG
    relief_baseline_m: float = td.RELIEF_BASELINE_M
    crater_sfd_exponent: float = td.CRATER_SFD_EXPONENT
    crater_n_gt_10m_per_km2: float = td.CRATER_N_GT_10M_PER_KM2
    crater_d_min_m: float = td.CRATER_D_MIN_M
    crater_d_max_m: float = td.CRATER_D_MAX_M
    crater_depth_ratio: float = td.CRATER_DEPTH_RATIO
    crater_rim_ratio: float = td.CRATER_RIM_RATIO
    crater_ejecta_falloff_exponent: float = td.CRATER_EJECTA_FALLOFF_EXPONENT
    crater_ejecta_extent_radii: float = td.CRATER_EJECTA_EXTENT_RADII
    rock_k: float = td.ROCK_K
    rock_d_min_m: float = td.ROCK_D_MIN_M
    rock_d_max_m: float = td.ROCK_D_MAX_M
    rock_height_ratio: float = td.ROCK_HEIGHT_RATIO

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise TerrainError(f"terrain parameter {f.name}={value!r} must be a finite number")
        if not 0.0 < self.spacing_m <= td.MAX_SPACING_M:
            raise TerrainError(
                f"terrain parameter spacing_m={self.spacing_m} must be in (0, {td.MAX_SPACING_M}] metres "
                "so that boulders are represented"
            )
        if self.size_m < 2 * self.spacing_m:
            raise TerrainError(f"terrain parameter size_m={self.size_m} must be at least two grid cells")
        if self.size_m / self.spacing_m > _MAX_CELLS_PER_SIDE:
            raise TerrainError(
                f"terrain of {self.size_m} m at {self.spacing_m} m/px exceeds {_MAX_CELLS_PER_SIDE} cells per side"
            )
        if not 0.0 < self.relief_hurst < 1.0:
            raise TerrainError(f"terrain parameter relief_hurst={self.relief_hurst} must be in (0, 1)")
        if not 0.0 <= self.relief_rms_slope_deg < 90.0 or self.relief_baseline_m <= 0.0:
            raise TerrainError("terrain parameters need 0 <= relief_rms_slope_deg < 90 and relief_baseline_m > 0")
        if self.crater_n_gt_10m_per_km2 < 0.0 or self.crater_sfd_exponent <= 0.0:
            raise TerrainError("terrain parameters need crater_n_gt_10m_per_km2 >= 0 and crater_sfd_exponent > 0")
        if not 0.0 < self.crater_d_min_m <= self.crater_d_max_m:
            raise TerrainError("terrain parameters need 0 < crater_d_min_m <= crater_d_max_m")
        if self.crater_depth_ratio < self.crater_rim_ratio or self.crater_rim_ratio < 0.0:
            raise TerrainError("terrain parameters need 0 <= crater_rim_ratio <= crater_depth_ratio")
        if self.crater_ejecta_extent_radii <= 1.0 or self.crater_ejecta_falloff_exponent <= 0.0:
            raise TerrainError("terrain parameters need crater_ejecta_extent_radii > 1 and a positive falloff")
        if self.rock_k != 0.0 and not td.ROCK_K_MIN <= self.rock_k <= td.ROCK_K_MAX:
            raise TerrainError(
                f"terrain parameter rock_k={self.rock_k} must be 0 (no rocks) or within the Golombek-Rapp "
                f"range [{td.ROCK_K_MIN}, {td.ROCK_K_MAX}]"
            )
        if not 0.0 < self.rock_d_min_m <= self.rock_d_max_m or self.rock_height_ratio <= 0.0:
            raise TerrainError("terrain parameters need 0 < rock_d_min_m <= rock_d_max_m and rock_height_ratio > 0")

    @property
    def cells(self) -> int:
        """Cells per side: round(size_m / spacing_m)."""
        return int(round(self.size_m / self.spacing_m))


def terrain_stream(seed: int, purpose: int) -> np.random.Generator:
    """The random stream ``purpose`` (``terrain_defaults.PURPOSE_*``) of terrain seed ``seed``."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(purpose)]))


# ---------------------------------------------------------------------------------- relief
def fractal_relief(
    n: int, spacing_m: float, hurst: float, rms_slope_deg: float, baseline_m: float, rng: np.random.Generator
) -> np.ndarray:
    """Self-affine (fBm-like) heights, shape (n, n), metres, periodic, zero mean.

    Spectral synthesis: white Gaussian noise filtered by |k|^-(H+1) (power spectrum
    ~ |k|^-(2H+2)), then scaled so the RMS slope over ``baseline_m`` (rounded to whole cells; both
    axes pooled) equals ``rms_slope_deg``.
    """
    if rms_slope_deg == 0.0:
        return np.zeros((n, n), dtype=np.float64)
    noise = rng.standard_normal((n, n))
    spectrum = np.fft.rfft2(noise)
    ky = np.fft.fftfreq(n)[:, None]
    kx = np.fft.rfftfreq(n)[None, :]
    k = np.hypot(kx, ky)
    k[0, 0] = 1.0
    spectrum *= k ** (-(hurst + 1.0))
    spectrum[0, 0] = 0.0
    heights = np.fft.irfft2(spectrum, s=(n, n))
    lag = max(1, int(round(baseline_m / spacing_m)))
    dz = np.concatenate(
        [(np.roll(heights, -lag, axis=0) - heights).ravel(), (np.roll(heights, -lag, axis=1) - heights).ravel()]
    )
    rms_gradient = float(np.sqrt(np.mean(dz**2))) / (lag * spacing_m)
    heights *= math.tan(math.radians(rms_slope_deg)) / rms_gradient
    return heights


# ---------------------------------------------------------------------------------- craters
def crater_profile(r_m: np.ndarray, diameter_m: float, params: MarsTerrainParams = MarsTerrainParams()) -> np.ndarray:
    """Height change (metres) of a fresh simple crater at distances ``r_m`` (metres) from its centre.

    Inside the rim (r <= R = D/2): parabolic bowl from the floor, ``rim - depth`` below the
    surroundings, to the rim crest, ``rim`` above them (depth = depth_ratio D, rim = rim_ratio D).
    Outside: ejecta ``rim ((r/R)^-n - E^-n) / (1 - E^-n)``, continuous at the rim and zero from
    E = ejecta_extent_radii crater radii on.
    """
    radius = 0.5 * diameter_m
    depth = params.crater_depth_ratio * diameter_m
    rim = params.crater_rim_ratio * diameter_m
    rho = np.asarray(r_m, dtype=np.float64) / radius
    n = params.crater_ejecta_falloff_exponent
    tail = params.crater_ejecta_extent_radii ** (-n)
    inside = rim - depth + depth * rho**2
    with np.errstate(divide="ignore"):
        outside = rim * (np.maximum(rho, 1.0) ** (-n) - tail) / (1.0 - tail)
    return np.where(rho <= 1.0, inside, np.maximum(outside, 0.0))


def stamp_crater(
    heights: np.ndarray,
    spacing_m: float,
    center_m: tuple[float, float],
    diameter_m: float,
    params: MarsTerrainParams = MarsTerrainParams(),
) -> None:
    """Add one crater profile to ``heights`` (in place); ``center_m`` = (east_m, south_m) offsets."""
    east, south = center_m
    reach = 0.5 * diameter_m * params.crater_ejecta_extent_radii
    rows, cols = heights.shape
    r0 = max(0, int(math.floor((south - reach) / spacing_m - 0.5)))
    r1 = min(rows, int(math.ceil((south + reach) / spacing_m - 0.5)) + 1)
    c0 = max(0, int(math.floor((east - reach) / spacing_m - 0.5)))
    c1 = min(cols, int(math.ceil((east + reach) / spacing_m - 0.5)) + 1)
    if r0 >= r1 or c0 >= c1:
        return
    yy = (np.arange(r0, r1) + 0.5) * spacing_m - south
    xx = (np.arange(c0, c1) + 0.5) * spacing_m - east
    r = np.hypot(yy[:, None], xx[None, :])
    heights[r0:r1, c0:c1] += crater_profile(r, diameter_m, params).astype(heights.dtype)


def sample_craters(params: MarsTerrainParams, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Crater centres (k, 2) as (east_m, south_m) and diameters (k,) in metres.

    Count ~ Poisson(area * [N(>D_min) - N(>D_max)]) over the tile grown by the largest ejecta reach
    (so craters centred just outside still shape the edges); D by inverse-CDF sampling of the
    truncated power law; sorted largest first.
    """
    p = params
    if p.crater_n_gt_10m_per_km2 == 0.0:
        return np.zeros((0, 2)), np.zeros(0)
    margin = 0.5 * p.crater_d_max_m * p.crater_ejecta_extent_radii
    side = p.size_m + 2 * margin
    b = p.crater_sfd_exponent
    frac_lo = (p.crater_d_min_m / 10.0) ** (-b)
    frac_hi = (p.crater_d_max_m / 10.0) ** (-b)
    mean = p.crater_n_gt_10m_per_km2 * (frac_lo - frac_hi) * side**2 / 1e6
    count = int(rng.poisson(mean))
    u = rng.random(count)
    # Inverse CDF of N(>D) ~ D^-b truncated to [d_min, d_max].
    diameters = 10.0 * (frac_lo - u * (frac_lo - frac_hi)) ** (-1.0 / b)
    centers = rng.random((count, 2)) * side - margin
    order = np.argsort(-diameters, kind="stable")
    return centers[order], diameters[order]


# ---------------------------------------------------------------------------------- rocks
def rock_q_per_m(k: float) -> float:
    """Golombek-Rapp exponent q(k) = 1.79 + 0.152 / k (1/metre)."""
    return td.ROCK_Q_A_PER_M + td.ROCK_Q_B_PER_M / k


def _rock_number_density(d_m: np.ndarray, k: float) -> np.ndarray:
    """Rocks per m^2 per metre of diameter: n(D) = -dF/dD * 4 / (pi D^2), F = k exp(-q D)."""
    q = rock_q_per_m(k)
    return 4.0 * k * q * np.exp(-q * d_m) / (math.pi * d_m**2)


def _rock_cdf(k: float, d_min_m: float, d_max_m: float) -> tuple[np.ndarray, np.ndarray]:
    d = np.geomspace(d_min_m, d_max_m, _ROCK_CDF_POINTS) if d_max_m > d_min_m else np.array([d_min_m, d_min_m])
    dens = _rock_number_density(d, k)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (dens[1:] + dens[:-1]) * np.diff(d))])
    return d, cum


def expected_rock_count(k: float, d_min_m: float, d_max_m: float, area_m2: float) -> float:
    """Expected number of rocks with d_min_m <= D <= d_max_m on ``area_m2`` (Golombek-Rapp k)."""
    if k == 0.0:
        return 0.0
    _, cum = _rock_cdf(k, d_min_m, d_max_m)
    return float(cum[-1] * area_m2)


def sample_rock_diameters(
    k: float, d_min_m: float, d_max_m: float, area_m2: float, rng: np.random.Generator
) -> np.ndarray:
    """Rock diameters (metres) on ``area_m2``: Poisson count, inverse-CDF diameters (Golombek-Rapp)."""
    if k == 0.0:
        return np.zeros(0)
    d, cum = _rock_cdf(k, d_min_m, d_max_m)
    count = int(rng.poisson(cum[-1] * area_m2))
    return np.interp(rng.random(count) * cum[-1], cum, d)


def stamp_rocks(
    heights: np.ndarray,
    spacing_m: float,
    centers_m: np.ndarray,
    diameters_m: np.ndarray,
    height_ratio: float = td.ROCK_HEIGHT_RATIO,
) -> None:
    """Put half-ellipsoid rocks on ``heights`` (in place), each resting on the terrain under its centre.

    Rock i: z = base_i + H_i sqrt(1 - (r / R_i)^2) for r < R_i, R_i = D_i / 2, H_i = height_ratio D_i,
    base_i = terrain height of the cell holding its centre (before any rock); merged with
    ``max()`` so overlapping rocks and rocks on slopes never dig into the ground. Heights are
    sampled at cell centres (a rock narrower than a cell can fall between them). Compiled with
    numba, rock after rock; the arithmetic is that of the NumPy form it replaced, bit for bit
    (``tests/lidarsim/rocks_numpy.py``).
    """
    centers = np.ascontiguousarray(np.asarray(centers_m, dtype=np.float64).reshape(-1, 2))
    diam = np.ascontiguousarray(np.asarray(diameters_m, dtype=np.float64).ravel())
    if diam.size == 0:
        return
    rows, cols = heights.shape
    crow = np.clip(np.floor(centers[:, 1] / spacing_m).astype(np.int64), 0, rows - 1)
    ccol = np.clip(np.floor(centers[:, 0] / spacing_m).astype(np.int64), 0, cols - 1)
    base = heights[crow, ccol].astype(np.float64)  # every rock's base before any rock is stamped
    half_width = np.ceil(0.5 * diam / spacing_m).astype(np.int64) + 1
    flat = heights.reshape(-1)  # a view: the rocks are stamped into ``heights``
    if not np.shares_memory(flat, heights):
        raise ValueError("stamp_rocks needs a contiguous heights array (it stamps in place)")
    _stamp_rocks_jit(
        flat, rows, cols, float(spacing_m), centers, diam, crow, ccol, base, half_width, float(height_ratio)
    )


def _stamp_rocks_loops(
    flat, rows, cols, spacing_m, centers, diam, crow, ccol, base, half_width, height_ratio
):  # pragma: no cover - compiled by numba
    """Every rock's cells merged into ``flat`` (the heights, row-major) with NumPy's ``maximum``."""
    cell = np.empty(1, dtype=flat.dtype)  # a rock's height rounded to the heights' dtype, as NumPy's astype
    for i in range(diam.size):
        radius = 0.5 * diam[i]
        r2 = radius**2
        top = height_ratio * diam[i]
        hw = half_width[i]
        for dr in range(-hw, hw + 1):
            rr = crow[i] + dr
            dy = (rr + 0.5) * spacing_m - centers[i, 1]
            for dc in range(-hw, hw + 1):
                cc = ccol[i] + dc
                dx = (cc + 0.5) * spacing_m - centers[i, 0]
                rho2 = (dx**2 + dy**2) / r2
                if not (rho2 < 1.0 and rr >= 0 and rr < rows and cc >= 0 and cc < cols):
                    continue
                cell[0] = base[i] + top * np.sqrt(max(1.0 - rho2, 0.0))
                k = rr * cols + cc
                old = flat[k]
                z = cell[0]
                if np.isnan(old):
                    continue
                if np.isnan(z) or z > old:
                    flat[k] = z


_stamp_rocks_jit = numba.njit(cache=True)(_stamp_rocks_loops)


# ---------------------------------------------------------------------------------- terrain
def generate_mars_terrain(params: MarsTerrainParams = MarsTerrainParams(), seed: int = 0) -> np.ndarray:
    """Procedural Mars heights (float32 metres), shape (n, n) with n = round(size_m / spacing_m).

    Row 0 is north. Deterministic in (params, seed); relief, craters and rocks each draw from
    ``np.random.default_rng(SeedSequence([seed, purpose]))``.
    """
    p = params
    n = p.cells
    heights = fractal_relief(
        n,
        p.spacing_m,
        p.relief_hurst,
        p.relief_rms_slope_deg,
        p.relief_baseline_m,
        terrain_stream(seed, td.PURPOSE_RELIEF),
    )
    centers, diameters = sample_craters(p, terrain_stream(seed, td.PURPOSE_CRATERS))
    for center, diameter in zip(centers, diameters, strict=True):
        stamp_crater(heights, p.spacing_m, (float(center[0]), float(center[1])), float(diameter), p)
    rock_rng = terrain_stream(seed, td.PURPOSE_ROCKS)
    side = n * p.spacing_m
    rock_d = sample_rock_diameters(p.rock_k, p.rock_d_min_m, p.rock_d_max_m, side * side, rock_rng)
    rock_xy = rock_rng.random((rock_d.size, 2)) * side
    stamp_rocks(heights, p.spacing_m, rock_xy, rock_d, p.rock_height_ratio)
    return heights.astype(np.float32)


def params_tags(params: MarsTerrainParams, seed: int) -> dict[str, str]:
    """GeoTIFF tags recording the generator, its parameters (JSON) and the seed."""
    return {
        "HD_GENERATOR": "lidarsim.procedural.generate_mars_terrain",
        "HD_PARAMS": json.dumps(dataclasses.asdict(params), sort_keys=True),
        "HD_SEED": str(int(seed)),
    }


def terrain_tags(params: MarsTerrainParams, seed: int) -> dict[str, str]:
    """GeoTIFF tags of the procedural terrain files hd writes (``hd make-dtm`` and a build's
    ``terrain/``): the generator, the seed and the parameters (JSON). A build's terrain bytes, and so
    its shards' ``dtm_sha256``, depend on them: they do not change."""
    return {"generator": "lidarsim.procedural", "seed": str(seed), "params": json.dumps(dataclasses.asdict(params))}


def write_procedural_dtm(path: str | os.PathLike[str], params: MarsTerrainParams, seed: int) -> np.ndarray:
    """Generate the procedural terrain and write it to ``path`` as a GeoTIFF (local metres, origin
    (0, 0), no CRS); returns the heights (metres)."""
    heights = generate_mars_terrain(params, seed=seed)
    write_geotiff(path, heights, params.spacing_m, origin_xy=(0.0, 0.0), crs_wkt="", tags=terrain_tags(params, seed))
    return heights


def geotiff_profile(
    shape: tuple[int, int],
    transform: Affine,
    crs_wkt: str = "",
    dtype: str = "float32",
    nodata: float = float("nan"),
) -> dict[str, Any]:
    """rasterio creation options of hd's single-band GeoTIFFs (``rasterio.open(path, "w", **profile)``).

    ``shape`` is (rows, cols); ``transform`` the affine of the top-left corner (map metres);
    ``crs_wkt`` "" writes no CRS (local metres). Deflate with the floating-point predictor for float
    data and horizontal differencing for integers; 256 x 256 tiles when both sides reach 256 cells.
    """
    rows, cols = int(shape[0]), int(shape[1])
    floating = np.issubdtype(np.dtype(dtype), np.floating)
    profile: dict[str, Any] = {
        "driver": "GTiff",
        "height": rows,
        "width": cols,
        "count": 1,
        "dtype": dtype,
        "nodata": nodata,
        "transform": transform,
        "compress": "deflate",
        "predictor": 3 if floating else 2,
    }
    if rows >= 256 and cols >= 256:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    if crs_wkt:
        profile["crs"] = CRS.from_wkt(crs_wkt)
    return profile


def geotiff_bytes(
    heights: np.ndarray,
    spacing_m: float,
    origin_xy: tuple[float, float] = (0.0, 0.0),
    crs_wkt: str = "",
    tags: dict[str, str] | None = None,
    name: str = "terrain.tif",
) -> bytes:
    """``heights`` (metres) as the bytes of a float32, north-up, deflate-compressed GeoTIFF with nodata NaN.

    Built in memory (GDAL's /vsimem); ``origin_xy`` is the map position (metres) of the top-left
    corner; ``crs_wkt`` "" writes no CRS (local metres); ``name`` names the file in errors.
    """
    from rasterio.io import MemoryFile

    arr = np.asarray(heights)
    if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise TerrainError(f"{name}: heights must be a non-empty 2-D array, got shape {arr.shape}")
    if not (math.isfinite(spacing_m) and spacing_m > 0.0):
        raise TerrainError(f"{name}: spacing_m={spacing_m} must be a positive number of metres")
    transform = from_origin(float(origin_xy[0]), float(origin_xy[1]), spacing_m, spacing_m)
    profile = geotiff_profile(arr.shape, transform, crs_wkt)
    with MemoryFile() as memfile:
        with memfile.open(**profile) as dst:
            dst.write(arr.astype(np.float32, copy=False), 1)
            if tags:
                dst.update_tags(**{str(k): str(v) for k, v in tags.items()})
        return bytes(memfile.read())


def write_geotiff(
    path: str | os.PathLike[str],
    heights: np.ndarray,
    spacing_m: float,
    origin_xy: tuple[float, float] = (0.0, 0.0),
    crs_wkt: str = "",
    tags: dict[str, str] | None = None,
) -> None:
    """Write ``heights`` (metres) as a float32, north-up GeoTIFF with nodata NaN (see ``geotiff_bytes``).

    The file is built in memory and written through ``hdcore.storage`` (temporary name, fsync,
    rename), so a half-written file is never visible at ``path`` and a full disk gives one error
    line naming it.
    """
    target = os.path.abspath(os.fspath(path))
    directory = os.path.dirname(target)
    if not os.path.isdir(directory):
        raise TerrainError(f"{target}: directory {directory} does not exist")
    data = geotiff_bytes(heights, spacing_m, origin_xy, crs_wkt, tags, name=target)
    write_bytes_atomic(target, data)
