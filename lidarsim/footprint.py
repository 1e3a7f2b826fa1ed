"""The flash-LiDAR pixel footprint: sub-rays over each pixel's field of view and the pixel's range.

A detector pixel integrates the light returned from its whole instantaneous field of view (12°/128 =
1.64 mrad: 0.82 m at 500 m). With ``samples = K`` the sensor casts K x K sub-rays per pixel, at the
centres of a K x K grid over the pixel's square on the image plane, each weighted by the spot
profile ``w``:

* ``gaussian``: ``w = exp(-2 (a^2 + b^2))`` where ``(a, b)`` in [-1, 1]^2 are the sub-ray's
  offsets from the pixel centre in units of half the pixel's side (the 1/e^2 radius of the spot is
  half the pixel's side, and the spot is cut off at the pixel's edges);
* ``uniform``: every sub-ray the same weight.

The weights are normalised to sum to 1. The energy a sub-ray brings back is (the LiDAR range
equation for an extended Lambertian target of uniform albedo, docs/references.md)

    e_i = w_i cos(theta_i) (R_ref / r_i)^2

with ``theta_i`` the angle between the ray and the terrain's normal, ``r_i`` its range and
``R_ref`` the reference range of the noise model; a sub-ray that misses the terrain brings back
nothing. The pixel's returned pulse is the sum of the sub-returns, each a Gaussian pulse of full
width at half maximum ``pulse_width_m`` (in range) centred on ``r_i``. Its range is formed by a
range estimator:

* ``centroid``: the energy-weighted centroid of the pulse, ``sum(e_i r_i) / sum(e_i)`` (the pulse
  shape is symmetric, so its width drops out);
* ``first``: a constant-fraction discriminator. The first range at which the waveform reaches
  ``fraction`` times its peak, plus the lead of that crossing on a single pulse,
  ``s sqrt(-2 ln fraction)`` with ``s`` the pulse's 1-sigma: an isolated return is ranged exactly,
  a pixel straddling an edge fires on the nearer surface when it holds enough of the energy.

``samples = 1`` is the paper's sensor: one ray through each pixel centre (``lidarsim.scan`` then
takes its original path, and every published dataset is unchanged).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np

from hdcore.setting import check, setting
from lidarsim import defaults, limits
from lidarsim.errors import LidarsimError
from lidarsim.sensor import SensorConfig

# Points of the coarse waveform grid of the "first" estimator (then refined by bisection).
_WAVEFORM_GRID = 48
_BISECTIONS = 30
# Pixels whose waveforms are evaluated at once (bounds the memory: chunk x grid x sub-rays doubles).
_PIXEL_CHUNK = 2048
# FWHM of a Gaussian over its 1-sigma: 2 sqrt(2 ln 2).
_FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


@dataclass(frozen=True)
class FootprintConfig:
    """How a pixel samples its field of view and forms its range. Each field's help, unit, default
    and range is its metadata (``hdcore.setting``): ``hd build-dataset``'s options, a recipe's
    ``[build]`` keys (``lidarsim.recipe.BuildSettings``) and the checks here are made from it.

    Attributes:
        samples: sub-rays per pixel side (K x K sub-rays per pixel); 1 = one ray through the centre.
        spot_profile: "gaussian" or "uniform" weights over the pixel's field of view.
        range_estimator: "centroid" or "first" (see the module docstring).
        pulse_width_m: full width at half maximum of the returned pulse, in range, metres.
        return_fraction: fraction of the waveform's peak at which the "first" estimator fires.
    """

    samples: int = setting(
        defaults.FOOTPRINT_SAMPLES,
        "Sub-rays per pixel side: K x K sub-rays over each pixel's field of view (1: one ray through the centre)",
        bound=limits.FOOTPRINT_SAMPLES,
        flag="--footprint-samples",
    )
    spot_profile: str = setting(
        defaults.SPOT_PROFILE,
        "Weights of the sub-rays over the pixel (gaussian: 1/e^2 radius at half the pixel's side)",
        choices=defaults.SPOT_PROFILES,
    )
    range_estimator: str = setting(
        defaults.RANGE_ESTIMATOR,
        "A pixel's range from its returned pulse: energy-weighted centroid, or first crossing of "
        "--return-fraction of the peak",
        choices=defaults.RANGE_ESTIMATORS,
    )
    pulse_width_m: float = setting(
        defaults.PULSE_WIDTH_M,
        "Full width at half maximum of the returned pulse, in range",
        unit="metres",
        bound=limits.PULSE_WIDTH_M,
        flag="--pulse-width",
    )
    return_fraction: float = setting(
        defaults.RETURN_FRACTION,
        "Fraction of the pulse's peak at which the first-return estimator fires",
        bound=limits.RETURN_FRACTION,
    )

    def __post_init__(self) -> None:
        if self.spot_profile not in defaults.SPOT_PROFILES:
            raise LidarsimError(f"unknown spot profile {self.spot_profile!r}; use {', '.join(defaults.SPOT_PROFILES)}")
        if self.range_estimator not in defaults.RANGE_ESTIMATORS:
            raise LidarsimError(
                f"unknown range estimator {self.range_estimator!r}; use {', '.join(defaults.RANGE_ESTIMATORS)}"
            )
        check(self, LidarsimError)

    @property
    def is_default(self) -> bool:
        """True for the paper's sensor (one ray per pixel, every other setting at its default)."""
        return self == FootprintConfig()

    @property
    def pulse_sigma_m(self) -> float:
        """1-sigma of the returned pulse, in range, metres."""
        return self.pulse_width_m / _FWHM_PER_SIGMA

    def to_attrs(self) -> dict[str, int | float | str]:
        """Flat attribute dictionary (HDF5/JSON friendly): ``footprint_*``."""
        return {f"footprint_{k}": v for k, v in asdict(self).items()}


def subpixel_offsets(samples: int) -> np.ndarray:
    """Offsets of the K sub-ray centres along one pixel side, in units of half the pixel's side: (K,) in (-1, 1)."""
    return (2.0 * np.arange(samples) + 1.0) / samples - 1.0


def spot_weights(config: FootprintConfig) -> np.ndarray:
    """Weights of the K x K sub-rays (row-major: offset ``b`` along rows, ``a`` along columns), summing to 1."""
    t = subpixel_offsets(config.samples)
    bb, aa = np.meshgrid(t, t, indexing="ij")
    w = np.exp(-2.0 * (aa**2 + bb**2)) if config.spot_profile == "gaussian" else np.ones_like(aa)
    w = w.ravel()
    return w / w.sum()


def subray_directions(sensor: SensorConfig, samples: int) -> np.ndarray:
    """Unit sub-ray directions in the sensor frame, float64 (rows, cols, K*K, 3).

    Sub-ray ``(l, k)`` of pixel ``(i, j)`` (index ``l * K + k``) passes through the image-plane
    point ``(tan(fov_x/2) (u_j + t_k / cols), tan(fov_y/2) (v_i + t_l / rows))``, with ``u_j, v_i``
    the pixel centre of :func:`lidarsim.sensor.ray_directions` and ``t`` the :func:`subpixel_offsets`.
    The array is shared between calls (read-only).
    """
    return _subray_directions(sensor.rows, sensor.cols, sensor.fov_x_deg, sensor.fov_y_deg, samples)


@lru_cache(maxsize=4)
def _subray_directions(rows: int, cols: int, fov_x_deg: float, fov_y_deg: float, samples: int) -> np.ndarray:
    tx = math.tan(math.radians(fov_x_deg) / 2.0)
    ty = math.tan(math.radians(fov_y_deg) / 2.0)
    u = (2.0 * np.arange(cols) + 1.0) / cols - 1.0
    v = (2.0 * np.arange(rows) + 1.0) / rows - 1.0
    t = subpixel_offsets(samples)
    tb, ta = np.meshgrid(t, t, indexing="ij")
    x = tx * (u[None, :, None] + ta.ravel()[None, None, :] / cols)
    y = ty * (v[:, None, None] + tb.ravel()[None, None, :] / rows)
    x, y = np.broadcast_arrays(x, y)
    d = np.stack([x, y, np.ones_like(x)], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    d.flags.writeable = False
    return d


def subreturn_energy(
    ranges_m: np.ndarray, cos_incidence: np.ndarray, weights: np.ndarray, reference_range_m: float
) -> np.ndarray:
    """Energy of each sub-return, relative to a whole pixel's return at normal incidence from
    ``reference_range_m``: ``w cos(theta) (R_ref / r)^2`` (0 where the sub-ray missed, NaN range).

    Args:
        ranges_m: (..., M) sub-ray ranges, metres, NaN where the sub-ray missed.
        cos_incidence: (..., M) cosine of the angle between each sub-ray and the terrain normal.
        weights: (M,) spot weights.
        reference_range_m: the noise model's reference range, metres.
    """
    hit = np.isfinite(ranges_m)
    r = np.where(hit, ranges_m, 1.0)
    e = weights * np.abs(cos_incidence) * (reference_range_m / r) ** 2
    return np.where(hit, e, 0.0)


def pixel_ranges(ranges_m: np.ndarray, energy: np.ndarray, config: FootprintConfig) -> np.ndarray:
    """The range (metres, float64) of each pixel from its sub-returns, by ``config.range_estimator``.

    Args:
        ranges_m: (..., M) sub-ray ranges, metres, NaN where the sub-ray missed.
        energy: (..., M) sub-return energies (:func:`subreturn_energy`), 0 where missed.
        config: the footprint model.

    Returns:
        (...) ranges; NaN where no sub-ray returned.
    """
    total = energy.sum(axis=-1)
    got = total > 0.0
    r = np.where(np.isfinite(ranges_m), ranges_m, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        centroid = np.where(got, (energy * r).sum(axis=-1) / np.where(got, total, 1.0), np.nan)
    if config.range_estimator == "centroid":
        return centroid
    return _first_crossing(r, energy, got, config)


def _waveform(r_eval: np.ndarray, r: np.ndarray, energy: np.ndarray, sigma: float) -> np.ndarray:
    """The pulse ``sum_i e_i exp(-(r - r_i)^2 / 2 s^2)`` at ranges ``r_eval`` (..., G) of pixels (..., M)."""
    z = (r_eval[..., :, None] - r[..., None, :]) / sigma
    return (energy[..., None, :] * np.exp(-0.5 * z * z)).sum(axis=-1)


def _first_crossing(r: np.ndarray, energy: np.ndarray, got: np.ndarray, config: FootprintConfig) -> np.ndarray:
    """The "first" estimator on the pixels with a return (NaN elsewhere); see the module docstring.

    The waveform is sampled on a grid of ``_WAVEFORM_GRID`` ranges from 4 sigma before the nearest
    sub-return to the farthest; its peak is refined by a parabola through the logarithm of the grid
    maximum and its neighbours (exact for one Gaussian pulse); the first grid interval that reaches
    the threshold is then bisected.
    """
    out = np.full(got.shape, np.nan)
    rr_all, ee_all = r[got], energy[got]
    ranges = np.empty(rr_all.shape[0])
    for start in range(0, rr_all.shape[0], _PIXEL_CHUNK):
        part = slice(start, start + _PIXEL_CHUNK)
        ranges[part] = _first_crossing_pixels(rr_all[part], ee_all[part], config)
    out[got] = ranges
    return out


def _first_crossing_pixels(rr: np.ndarray, ee: np.ndarray, config: FootprintConfig) -> np.ndarray:
    """:func:`_first_crossing` on (P, M) sub-returns of P pixels that all returned."""
    s = config.pulse_sigma_m
    hit = ee > 0.0
    lo = np.where(hit, rr, np.inf).min(axis=-1) - 4.0 * s
    hi = np.where(hit, rr, -np.inf).max(axis=-1) + 4.0 * s
    steps = np.linspace(0.0, 1.0, _WAVEFORM_GRID)
    grid = lo[:, None] + (hi - lo)[:, None] * steps[None, :]
    wave = _waveform(grid, rr, ee, s)
    k = np.clip(wave.argmax(axis=-1), 1, _WAVEFORM_GRID - 2)
    n = np.arange(rr.shape[0])
    y0, y1, y2 = (np.log(np.maximum(wave[n, k + d], 1e-300)) for d in (-1, 0, 1))
    denom = y0 - 2.0 * y1 + y2
    with np.errstate(invalid="ignore", divide="ignore"):
        shift = np.where(denom < 0.0, 0.5 * (y0 - y2) / denom, 0.0)
    shift = np.clip(shift, -1.0, 1.0)
    peak_at = grid[n, k] + shift * (hi - lo) / (_WAVEFORM_GRID - 1)
    peak = np.maximum(_waveform(peak_at[:, None], rr, ee, s)[:, 0], wave.max(axis=-1))
    level = config.return_fraction * peak
    above = wave >= level[:, None]
    first = above.argmax(axis=-1)  # the grid's first point at or above the level (>= 1: the grid starts 4 s early)
    a = grid[n, np.maximum(first - 1, 0)]
    b = grid[n, first]
    for _ in range(_BISECTIONS):
        mid = 0.5 * (a + b)
        up = _waveform(mid[:, None], rr, ee, s)[:, 0] >= level
        b = np.where(up, mid, b)
        a = np.where(up, a, mid)
    return b + s * math.sqrt(-2.0 * math.log(config.return_fraction))
