"""The compiled product rule's bounds and skipped sums against the previous kernel, which summed every node.

``hdlabels.alhat`` bounds each site's P(safe) from a polynomial of log Phi and each configuration's
highest node, and sums the table's log Phi only where the bounds leave the result open
(``_product_loops``). The previous kernel (``alhat_previous.py``, kept verbatim) is the oracle:
the maps must be identical, the P >= 0.5 decision identical on every pixel and P(safe) within 1e-6,
on hand-derivable DEMs (flat, tilted, one rock, a flat plane right at the decision) and on random
DEMs with NaN holes.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter
from scipy.special import log_ndtr, ndtr, ndtri

pytest.importorskip("numba")

from alhat_previous import previous_hazard_and_probability

from hdlabels import alhat
from hdlabels.alhat import HazardMaps, hazard_and_probability
from hdlabels.lander import Lander

PAPER = Lander()
N = 30  # DEM side, pixels: 20x20 labelled sites inside the 5-px band at 1 m
SIGMAS = (0.0167, 0.03, 0.07, 0.15)


def assert_same_as_previous(dem: np.ndarray, spacing: float, sigma: float, lander: Lander) -> np.ndarray:
    """Both kernels on one DEM: identical maps and decisions, P within 1e-6. Returns the new P."""
    maps, p = hazard_and_probability(dem, spacing, sigma, lander)
    old_maps, old_p = previous_hazard_and_probability(dem, spacing, sigma, lander)
    assert_maps_equal(maps, old_maps)
    assert np.array_equal(np.isnan(p), np.isnan(old_p))
    valid = ~np.isnan(p)
    assert np.abs(p[valid] - old_p[valid]).max(initial=0.0) <= 1e-6
    assert np.array_equal(p[valid] >= 0.5, old_p[valid] >= 0.5)
    return p


def assert_maps_equal(a: HazardMaps, b: HazardMaps) -> None:
    np.testing.assert_array_equal(a.label, b.label)
    np.testing.assert_array_equal(a.slope_rad, b.slope_rad)
    np.testing.assert_array_equal(a.roughness_m, b.roughness_m)


def plane(slope_deg: float, azimuth_deg: float = 30.0, n: int = N) -> np.ndarray:
    """Heights (m) of a plane rising along map azimuth (deg from east), 1 m grid."""
    i, j = np.mgrid[0:n, 0:n]
    a = math.radians(azimuth_deg)
    return math.tan(math.radians(slope_deg)) * (j * math.cos(a) - i * math.sin(a)) + 50.0


def rough_terrain(seed: int, n: int = 48, holes: int = 0) -> np.ndarray:
    """Hills, 0.1-0.4 m rocks and 3 cm noise (metres), with ``holes`` NaN cells."""
    rng = np.random.default_rng(seed)
    dem = gaussian_filter(rng.normal(0.0, 1.0, (n, n)), 4.0) * 3.0
    dem += (rng.random((n, n)) < 0.03) * rng.uniform(0.1, 0.4, (n, n))
    dem += rng.normal(0.0, 0.03, (n, n))
    dem[rng.integers(0, n, holes), rng.integers(0, n, holes)] = np.nan
    return dem


@pytest.mark.parametrize("sigma", SIGMAS)
def test_flat_plane_by_hand(sigma: float) -> None:
    p = assert_same_as_previous(np.full((N, N), 12.5), 1.0, sigma, PAPER)
    valid = ~np.isnan(p)
    # every node on the plane: the 41-node square gives the smallest product
    np.testing.assert_allclose(p[valid], ndtr(0.2 / sigma) ** 41, rtol=0, atol=1e-7)


@pytest.mark.parametrize("slope_deg", [5.0, 9.99, 10.01, 15.0])
@pytest.mark.parametrize("sigma", SIGMAS)
def test_tilted_plane_by_hand(slope_deg: float, sigma: float) -> None:
    p = assert_same_as_previous(plane(slope_deg), 1.0, sigma, PAPER)
    valid = ~np.isnan(p)
    if slope_deg > 10.0:  # the slope test: P = 0 exactly, without any sum
        assert np.all(p[valid] == 0.0)
    else:  # on a plane of slope theta the noise scale is cos(theta) sigma: u = 0.2 / (cos sigma)
        expected = ndtr(0.2 / (math.cos(math.radians(slope_deg)) * sigma)) ** 41
        np.testing.assert_allclose(p[valid], expected, rtol=0, atol=2e-6)


@pytest.mark.parametrize("height_m", [0.1, 0.3, 1.0])
@pytest.mark.parametrize("sigma", SIGMAS)
def test_a_single_rock(height_m: float, sigma: float) -> None:
    dem = np.zeros((N, N))
    dem[15, 15] = height_m
    p = assert_same_as_previous(dem, 1.0, sigma, PAPER)
    # the site on the rock: its node is inside every pad square, the rest on the plane
    flat = log_ndtr(0.2 / sigma)
    expected = math.exp(40 * flat + log_ndtr((0.2 - height_m) / sigma))
    assert p[15, 15] == pytest.approx(expected, abs=2e-7)


@pytest.mark.parametrize("delta", [-2e-3, -1e-4, 0.0, 1e-4, 2e-3])
def test_a_flat_plane_at_the_decision(delta: float) -> None:
    # Phi(0.2 / sigma)^41 = 0.5 at sigma = 0.2 / Phi^-1(0.5^(1/41)): P within a hair of 0.5 everywhere
    sigma = 0.2 / float(ndtri(0.5 ** (1 / 41))) + delta * 0.01
    p = assert_same_as_previous(np.full((N, N), 3.0), 1.0, sigma, PAPER)
    valid = ~np.isnan(p)
    np.testing.assert_allclose(p[valid], ndtr(0.2 / sigma) ** 41, rtol=0, atol=1e-7)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("sigma", SIGMAS)
def test_random_dems_with_nan_holes(seed: int, sigma: float) -> None:
    assert_same_as_previous(rough_terrain(seed, holes=6 * seed), 1.0, sigma, PAPER)


@pytest.mark.parametrize(
    "lander",
    [
        Lander(layout="triangle"),
        Lander(count_holes=True),
        Lander(convention="hd", baseline_combine="product"),
        Lander(max_slope_deg=5.0),
    ],
    ids=["triangle", "holes", "hd-product", "slope5"],
)
@pytest.mark.parametrize("sigma", [0.0167, 0.07])
def test_other_landers(lander: Lander, sigma: float) -> None:
    assert_same_as_previous(rough_terrain(7, holes=4), 1.0, sigma, lander)


@pytest.mark.parametrize("sigma", [0.0167, 0.07])
def test_half_metre_grid(sigma: float) -> None:
    dem = rough_terrain(11, n=56) * 0.5  # gentler at 0.5 m/px: fewer slope failures
    assert_same_as_previous(dem, 0.5, sigma, PAPER)


def test_bounds_rest_on_a_monotone_non_positive_table_and_a_measured_polynomial_error() -> None:
    coef = alhat._LOG_PHI.reshape(-1, 4)
    t = np.linspace(0.0, 1.0, 33)[:, None]
    table = (coef[:-1, 0] + t * (coef[:-1, 1] + t * (coef[:-1, 2] + t * coef[:-1, 3]))).T.ravel()
    assert np.all(np.diff(table) >= 0.0) and table.max() <= 0.0  # f non-decreasing and <= 0
    # the polynomial's bound holds at random points too, not only on the grid it was measured on
    x = np.random.default_rng(0).uniform(alhat._POLY_X[0], alhat._POLY_X[1], 200_000)
    q = x.astype(np.int64)
    c, r = coef[q], x - q
    exact = c[:, 0] + r * (c[:, 1] + r * (c[:, 2] + r * c[:, 3]))
    tt = x * alhat._T_SCALE + alhat._T_SHIFT
    poly = np.zeros_like(tt)
    for k in alhat._LOG_PHI_POLY_HORNER:
        poly = poly * tt + k
    assert np.abs(poly - exact).max() <= alhat._POLY_ERROR < 1e-4
    top = alhat._POLY_X[1]
    assert abs(alhat._table_log_phi(alhat._LOG_PHI, top)) <= alhat._TAIL_ERROR < 1e-7
