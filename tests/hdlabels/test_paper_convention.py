"""The paper convention (the ALHAT replica the paper used) against hand-derivable cases and a literal loop replica."""

from __future__ import annotations

import math

import numpy as np
import pytest
from alhat_numpy import Backend, hazard_and_probability, hazard_maps, safety_probability
from paper_reference import reference
from scipy.special import ndtr

from hdlabels.alhat import valid_sites
from hdlabels.defaults import LABEL_INVALID, LABEL_SAFE, LABEL_UNSAFE
from hdlabels.errors import HdLabelsError
from hdlabels.lander import Lander, geometry
from hdlabels.paper_geometry import distinct_polygons, orientations_rad, pad_offsets, strictly_inside

BACKENDS = ["numpy", "numba"]
PAPER = Lander()  # the default lander is the paper convention with the product baseline
N = 30  # DEM side, pixels (1 m): 20x20 labelled sites inside the 5-px band


def plane(slope_deg: float, azimuth_deg: float = 30.0, n: int = N) -> np.ndarray:
    """Heights (m) of a plane rising along map azimuth (deg from east), 1 m grid."""
    i, j = np.mgrid[0:n, 0:n]
    a = math.radians(azimuth_deg)
    return math.tan(math.radians(slope_deg)) * (j * math.cos(a) - i * math.sin(a)) + 50.0


def test_default_lander_is_the_paper_convention() -> None:
    assert PAPER.convention == "paper" and PAPER.baseline_combine == "product"
    assert Lander(convention="hd").baseline_combine == "min"
    attrs = PAPER.to_attrs()
    assert attrs["convention"] == "paper" and attrs["orientation_step_deg"] == 10.0 and "n_yaws" not in attrs
    assert Lander.from_attrs(attrs) == PAPER
    # records from before conventions existed are the hd convention with the worst-node baseline
    old = {
        "diameter_m": 10.0,
        "pad_diameter_m": 1.0,
        "max_slope_deg": 10.0,
        "max_roughness_m": 0.2,
        "layout": "square",
        "n_yaws": 8,
        "count_holes": False,
        "n_pads": 4,
        "yaw_step_deg": 11.25,
    }
    assert Lander.from_attrs(old) == Lander(convention="hd")


def test_the_36_orientations_give_7_squares_of_pixel_pads() -> None:
    assert len(orientations_rad()) == 36
    # hand: c = trunc(5 cos t), s = trunc(5 sin t) for t = 0..80 deg:
    # (5,0) (4,0) (4,1) (4,2) (3,3) (3,3) (2,4) (1,4) (0,4)
    assert pad_offsets("square", 5, math.radians(20)) == ((1, -4), (4, 1), (-1, 4), (-4, -1))
    squares = distinct_polygons("square", 5)
    assert len(squares) == 7  # (3,3) twice; (0,4) is (4,0) turned by 90 degrees
    assert {frozenset(p) for p in squares} >= {
        frozenset({(0, -5), (5, 0), (0, 5), (-5, 0)}),
        frozenset({(3, -3), (3, 3), (-3, 3), (-3, -3)}),
    }
    geo = geometry(PAPER, 1.0)
    counts = [geo.nodes(m)[0].size for m in range(geo.n_yaws)]
    # strictly inside |di| + |dj| < 5: 41 nodes; inside the axis-aligned 6 m square: 5 x 5 = 25.
    assert counts[0] == 41 and counts[1] == 25 and 25 in counts
    assert geo.band_px == 5


def test_strictly_inside_excludes_edges_and_vertices() -> None:
    square = ((0, -5), (5, 0), (0, 5), (-5, 0))
    inside = set(strictly_inside(square, 4))
    assert (0, 0) in inside and (2, 2) in inside and (4, 0) in inside
    assert (3, 2) not in inside and (0, 5) not in inside  # on an edge, on a vertex
    assert len(inside) == 41


def test_lander_too_small_for_the_grid_is_refused() -> None:
    with pytest.raises(HdLabelsError, match="too few"):
        geometry(Lander(diameter_m=2.0, pad_diameter_m=1.0), 1.0)
    with pytest.raises(HdLabelsError, match="hd convention only"):
        Lander(n_yaws=4)


@pytest.mark.parametrize("backend", BACKENDS)
def test_flat_plane_all_safe_and_probability_by_hand(backend: Backend) -> None:
    dem = np.full((N, N), 12.5)
    maps, p = hazard_and_probability(dem, 1.0, 0.07, PAPER, backend=backend)
    valid = maps.valid
    assert valid.sum() == 20 * 20 and np.all(maps.label[valid] == LABEL_SAFE)
    assert np.all(maps.slope_rad[valid] == 0) and np.all(maps.roughness_m[valid] == 0)
    # Every node on the plane: u = 0.2 / 0.07 for each node; the 41-node square is the smallest product.
    np.testing.assert_allclose(p[valid], ndtr(0.2 / 0.07) ** 41, rtol=1e-6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_product_and_min_disagree_on_a_flat_noisy_plane(backend: Backend) -> None:
    dem = np.zeros((N, N))
    sigma = 0.1  # u = 2 at every node: Phi(2) = 0.97725 per node
    product = safety_probability(dem, 1.0, sigma, PAPER, backend=backend)
    worst = safety_probability(dem, 1.0, sigma, Lander(baseline_combine="min"), backend=backend)
    valid = ~np.isnan(product)
    np.testing.assert_allclose(product[valid], 0.9772498680518208**41, rtol=1e-6)  # 0.389: unsafe
    np.testing.assert_allclose(worst[valid], 0.9772498680518208, rtol=1e-6)  # safe
    assert np.all(product[valid] < 0.5) and np.all(worst[valid] >= 0.5)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(("slope_deg", "expected"), [(5.0, LABEL_SAFE), (15.0, LABEL_UNSAFE)])
@pytest.mark.parametrize("azimuth_deg", [0.0, 30.0, 77.0])
def test_tilted_plane_slope_exact(backend: Backend, slope_deg: float, expected: int, azimuth_deg: float) -> None:
    maps = hazard_maps(plane(slope_deg, azimuth_deg), 1.0, PAPER, backend=backend)
    valid = maps.valid
    # Pads sit on nodes of the plane: every resting plane is the terrain plane itself.
    np.testing.assert_allclose(np.degrees(maps.slope_rad[valid]), slope_deg, atol=1e-3)
    assert np.all(maps.roughness_m[valid] < 1e-4)
    assert np.all(maps.label[valid] == expected)
    p = safety_probability(plane(slope_deg, azimuth_deg), 1.0, 0.03, PAPER, backend=backend)
    assert np.all((p[valid] > 0.99) == (expected == LABEL_SAFE)) and np.all(
        (p[valid] == 0) == (expected == LABEL_UNSAFE)
    )


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_rock_counts_only_strictly_inside_the_pad_polygon(backend: Backend) -> None:
    dem = np.zeros((N, N))
    dem[15, 15] = 0.3  # a 0.3 m rock on one node
    paper = hazard_maps(dem, 1.0, PAPER, backend=backend)
    hd = hazard_maps(dem, 1.0, Lander(convention="hd"), backend=backend)
    # rock 2 m south and 2 m east of the site: inside the 41-node square -> roughness 0.3 m, unsafe
    assert paper.label[13, 13] == LABEL_UNSAFE and paper.roughness_m[13, 13] == pytest.approx(0.3, abs=1e-6)
    # rock at offset (3, 4): 5 m away, inside hd's body disk but outside every pad square -> safe
    assert paper.label[12, 11] == LABEL_SAFE and hd.label[12, 11] == LABEL_UNSAFE
    # rock under a pad ((5, 0) is a pad of the largest square): the lander tilts by atan(0.3 / 7.07 m)
    # at most and the nodes fall below the tilted plane -> safe
    assert paper.label[10, 15] == LABEL_SAFE
    assert 0 < paper.slope_rad[10, 15] <= math.atan(0.3 / math.hypot(5, 5)) + 1e-6
    # the unsafe sites are exactly those whose polygons hold the rock: a diamond |di| + |dj| <= 4 and more
    unsafe = np.argwhere(paper.label == LABEL_UNSAFE) - 15
    assert np.all(np.abs(unsafe).max(axis=1) <= 4)
    assert np.all(np.abs(unsafe).sum(axis=1) <= 6)


@pytest.mark.parametrize("backend", BACKENDS)
def test_border_band_and_nan_cells_are_invalid(backend: Backend) -> None:
    dem = plane(2.0)
    dem[15, 15] = np.nan
    maps = hazard_maps(dem, 1.0, PAPER, backend=backend)
    band = np.ones((N, N), dtype=bool)
    band[5:-5, 5:-5] = False  # the lander radius in whole pixels
    assert np.all(maps.label[band] == LABEL_INVALID)
    footprint = geometry(PAPER, 1.0).footprint  # every node a site's result depends on
    reach = np.zeros((N, N), dtype=bool)
    reach[10:21, 10:21] = footprint[::-1, ::-1]
    assert np.array_equal(maps.label == LABEL_INVALID, band | reach)
    assert np.array_equal(valid_sites(dem, 1.0, PAPER), ~(band | reach))


CASES = [
    {"layout": "square", "combine": "product", "holes": False, "sigma": 0.05},
    {"layout": "square", "combine": "min", "holes": True, "sigma": 0.03},
    {"layout": "triangle", "combine": "product", "holes": False, "sigma": 0.07},
]


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c['layout']}-{c['combine']}")
@pytest.mark.parametrize("backend", BACKENDS)
def test_matches_the_literal_36_orientation_replica(case: dict, backend: Backend) -> None:
    rng = np.random.default_rng(21)
    n = 22
    dem = rng.normal(0.0, 0.06, (n, n)) + 0.02 * np.arange(n)[None, :]
    dem[rng.integers(0, n, 6), rng.integers(0, n, 6)] += 0.35  # rocks
    lander = Lander(layout=case["layout"], baseline_combine=case["combine"], count_holes=case["holes"])
    maps, p = hazard_and_probability(dem, 1.0, case["sigma"], lander, backend=backend)
    label, p_ref, slope = reference(dem, 1.0, case["layout"], case["sigma"], case["combine"], case["holes"])
    assert np.array_equal(maps.label, label)
    valid = maps.valid
    np.testing.assert_allclose(maps.slope_rad[valid], slope[valid], atol=1e-5)
    np.testing.assert_allclose(p[valid], p_ref[valid], atol=2e-6)
    assert np.isnan(p[~valid]).all()
    # the product and the worst node really differ somewhere on this noisy DEM
    if case["combine"] == "product":
        other = safety_probability(dem, 1.0, case["sigma"], Lander(layout=case["layout"], baseline_combine="min"))
        assert np.any((p[valid] >= 0.5) != (other[valid] >= 0.5))


@pytest.mark.parametrize("backend", BACKENDS)
def test_half_metre_grid_uses_pixel_disk_pads(backend: Backend) -> None:
    rng = np.random.default_rng(3)
    n = 26  # 0.5 m: lander radius 10 px, pad radius 1 px (5-node pad disks), pad circle 9 px
    dem = rng.normal(0.0, 0.04, (n, n))
    dem[13, 13] += 0.3
    maps, p = hazard_and_probability(dem, 0.5, 0.03, PAPER, backend=backend)
    label, p_ref, _ = reference(dem, 0.5, sigma=0.03)
    assert geometry(PAPER, 0.5).band_px == 10
    assert np.array_equal(maps.label, label)
    np.testing.assert_allclose(p[maps.valid], p_ref[maps.valid], atol=2e-6)


@pytest.mark.parametrize("rotation", range(1, 4))
@pytest.mark.parametrize("flip", [False, True])
def test_square_labels_commute_with_the_d4_symmetries(rotation: int, flip: bool) -> None:
    rng = np.random.default_rng(8)
    dem = rng.normal(0.0, 0.08, (N, N)) + 0.03 * np.arange(N)[:, None]

    def transform(a: np.ndarray) -> np.ndarray:
        a = np.rot90(a, rotation)
        return a[:, ::-1] if flip else a

    maps, p = hazard_and_probability(dem, 1.0, 0.05, PAPER)
    t_maps, t_p = hazard_and_probability(transform(dem), 1.0, 0.05, PAPER)
    assert np.array_equal(t_maps.label, transform(maps.label))
    np.testing.assert_allclose(t_p, transform(p), atol=1e-5)
