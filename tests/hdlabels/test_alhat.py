"""ALHAT hazard maps against cases derivable by hand (planes, a boulder, pits, NaN, borders)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from alhat_numpy import Backend, hazard_maps, safety_probability

from hdlabels import alhat
from hdlabels.alhat import HazardMaps, probability_from_maps, valid_sites
from hdlabels.defaults import LABEL_INVALID, LABEL_SAFE, LABEL_UNSAFE
from hdlabels.errors import HdLabelsError
from hdlabels.lander import Lander

BACKENDS = ["numpy", "numba"]
HD = Lander(convention="hd")  # these hand-derived cases are of the hd convention (test_paper_convention.py: paper)
N = 40  # DEM side, pixels (1 m): 30x30 labelled sites inside the 5-px band


def plane(slope_deg: float, azimuth_deg: float = 30.0, n: int = N, spacing: float = 1.0) -> np.ndarray:
    """Heights (m) of a plane through the centre, rising along map azimuth (deg from east)."""
    i, j = np.mgrid[0:n, 0:n]
    x, y = j * spacing, -i * spacing
    a = math.radians(azimuth_deg)
    return math.tan(math.radians(slope_deg)) * (x * math.cos(a) + y * math.sin(a)) + 100.0


def offsets_from(centre: tuple[int, int], n: int = N) -> tuple[np.ndarray, np.ndarray]:
    i, j = np.mgrid[0:n, 0:n]
    return i - centre[0], j - centre[1]


@pytest.mark.parametrize("backend", BACKENDS)
def test_flat_plane_every_valid_site_safe(backend: Backend) -> None:
    maps = hazard_maps(np.full((N, N), -1234.5), 1.0, backend=backend)
    assert maps.slope_rad.dtype == np.float32 and maps.roughness_m.dtype == np.float32
    assert maps.label.dtype == np.uint8
    valid = maps.label != LABEL_INVALID
    assert valid.sum() == 30 * 30
    assert np.all(maps.label[valid] == LABEL_SAFE)
    assert np.all(maps.slope_rad[valid] == 0) and np.all(maps.roughness_m[valid] == 0)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(("slope_deg", "expected"), [(5.0, LABEL_SAFE), (15.0, LABEL_UNSAFE)])
@pytest.mark.parametrize("azimuth_deg", [0.0, 30.0, 77.0])
def test_tilted_plane_slope_recovered(backend: Backend, slope_deg: float, expected: int, azimuth_deg: float) -> None:
    maps = hazard_maps(plane(slope_deg, azimuth_deg), 1.0, HD, backend=backend)
    valid = maps.label != LABEL_INVALID
    # Every pad is lifted by the same r |grad z| cos(angle to the nearest rim sample), so the
    # resting plane is parallel to the terrain: slope exact, terrain entirely below it.
    np.testing.assert_allclose(np.degrees(maps.slope_rad[valid]), slope_deg, atol=0.01)
    assert np.all(maps.roughness_m[valid] == 0)
    assert np.all(maps.label[valid] == expected)


def test_border_band_is_invalid() -> None:
    maps = hazard_maps(plane(2.0), 1.0, HD)
    band = np.ones((N, N), dtype=bool)
    band[5:-5, 5:-5] = False  # one lander radius (5 m = 5 px)
    assert np.all(maps.label[band] == LABEL_INVALID)
    assert np.all(maps.label[~band] != LABEL_INVALID)
    assert np.all(np.isnan(maps.slope_rad[band])) and np.all(np.isnan(maps.roughness_m[band]))


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("base_tilt_deg", [0.0, 3.0])
def test_single_boulder_unsafe_exactly_within_body_reach(backend: Backend, base_tilt_deg: float) -> None:
    dem = plane(base_tilt_deg)
    dem[20, 20] += 0.5  # a 0.5 m boulder on one node
    maps = hazard_maps(dem, 1.0, HD, backend=backend)
    di, dj = offsets_from((20, 20))
    valid = maps.label != LABEL_INVALID
    # By hand: a site is unsafe iff the boulder is under its body, i.e. within 5 m of the site
    # (di^2 + dj^2 <= 25, 81 sites). Some yaw always keeps the boulder clear of the pads, so the
    # plane is the terrain's and the boulder stands (0.5 - tiny pad lift) * cos(tilt) > 0.20 m above it.
    # Beyond 5 m only a pad can touch it: the lander tips (slope atan(0.5 sqrt2 / 9) < 4.5 deg at worst)
    # and the terrain stays below 0.14 m above the tipped plane, so it is safe.
    within = (di**2 + dj**2 <= 25) & valid
    assert within.sum() == 81
    assert np.all(maps.label[within] == LABEL_UNSAFE)
    assert np.all(maps.label[valid & ~within] == LABEL_SAFE)
    assert np.all(maps.roughness_m[within] > 0.45 * math.cos(math.radians(base_tilt_deg)))
    assert (
        np.nanmax(np.degrees(maps.slope_rad)) < base_tilt_deg + math.degrees(math.atan(0.5 * math.sqrt(2) / 9)) + 0.01
    )


@pytest.mark.parametrize("backend", BACKENDS)
def test_pit_under_one_pad_tips_the_lander(backend: Backend) -> None:
    # One yaw (0): pad 0 at 4.5 m east of the site, pads 1, 3 north/south, pad 2 west.
    lander = Lander(convention="hd", n_yaws=1)
    dem = np.zeros((N, N))
    site = (20, 20)
    dem[18:23, 22:28] = -0.5  # pit 0.5 m deep, rows -2..2, cols +2..+7: holds pad 0 entirely
    maps = hazard_maps(dem, 1.0, lander, backend=backend)
    # By hand: pad 0 rests at -0.5; the lander rocks on diagonal (1, 3) and may tip into the pit:
    # plane z = -x / 9 (x east, metres), slope atan(0.5 / 4.5). Body node (x=4, y=3) is outside the
    # pit at 0 m, 4/9 m above the plane; no node is higher. Perpendicular: (4/9) cos(slope).
    slope = math.atan(0.5 / 4.5)
    assert math.degrees(maps.slope_rad[site]) == pytest.approx(math.degrees(slope), abs=1e-4)
    assert maps.roughness_m[site] == pytest.approx(4 / 9 * math.cos(slope), abs=1e-6)
    assert maps.label[site] == LABEL_UNSAFE  # deeper than the roughness limit: unsafe


@pytest.mark.parametrize("backend", BACKENDS)
def test_pit_between_the_pads_counts_only_with_count_holes(backend: Backend) -> None:
    dem = np.zeros((N, N))
    di, dj = offsets_from((20, 20))
    dem[di**2 + dj**2 <= 4] = -0.5  # pit of radius 2 m, 0.5 m deep, centred on the site
    # The pads (4.5 +- 0.5 m out, taps within one pixel) never reach it: the lander straddles it.
    default = hazard_maps(dem, 1.0, HD, backend=backend)
    assert default.slope_rad[20, 20] < 1e-9 and default.roughness_m[20, 20] < 1e-9
    assert default.label[20, 20] == LABEL_SAFE
    holes = hazard_maps(dem, 1.0, Lander(convention="hd", count_holes=True), backend=backend)
    assert holes.roughness_m[20, 20] == pytest.approx(0.5)
    assert holes.label[20, 20] == LABEL_UNSAFE


@pytest.mark.parametrize("backend", BACKENDS)
def test_single_node_hole_unsafe_within_reach_only_when_holes_count(backend: Backend) -> None:
    dem = plane(0.0)
    dem[20, 20] -= 0.5
    di, dj = offsets_from((20, 20))
    holes = hazard_maps(dem, 1.0, Lander(convention="hd", count_holes=True), backend=backend)
    valid = holes.label != LABEL_INVALID
    within = (di**2 + dj**2 <= 25) & valid
    assert np.all(holes.label[within] == LABEL_UNSAFE)
    assert np.all(holes.label[valid & ~within] == LABEL_SAFE)
    # A 1 m pad never sits only over one node at 4.5 m (4.5^2 is not a sum of two integer squares),
    # so every pad bridges the hole; below the plane it is no hazard by default.
    default = hazard_maps(dem, 1.0, HD, backend=backend)
    assert np.all(default.label[valid] == LABEL_SAFE)


@pytest.mark.parametrize("backend", BACKENDS)
def test_nan_cell_invalidates_its_footprint_reach(backend: Backend) -> None:
    dem = plane(2.0)
    dem[20, 20] = np.nan
    maps = hazard_maps(dem, 1.0, HD, backend=backend)
    di, dj = offsets_from((20, 20))
    # By hand: body nodes reach 5 m; pad samples reach 5 m and their bilinear taps the nodes of
    # their cell: Chebyshev <= 5 and |di| + |dj| <= 8.
    reach = (np.maximum(abs(di), abs(dj)) <= 5) & (abs(di) + abs(dj) <= 8)
    interior = np.zeros((N, N), dtype=bool)
    interior[5:-5, 5:-5] = True
    assert np.array_equal(maps.label == LABEL_INVALID, ~interior | reach)
    assert np.all(np.isnan(maps.slope_rad[reach])) and np.all(np.isnan(maps.roughness_m[reach]))
    assert np.all(maps.label[interior & ~reach] == LABEL_SAFE)
    assert np.array_equal(valid_sites(dem, 1.0, HD), interior & ~reach)


def test_spacing_scales_the_footprint() -> None:
    # At 0.5 m/px the 10 m lander spans 21 px: the band is 10 px and the plane is still exact.
    maps = hazard_maps(plane(5.0, n=30, spacing=0.5), 0.5, HD)
    assert (maps.label != LABEL_INVALID).sum() == 10 * 10
    valid = maps.label != LABEL_INVALID
    np.testing.assert_allclose(np.degrees(maps.slope_rad[valid]), 5.0, atol=0.01)


def test_triangle_lander_on_tilted_plane() -> None:
    maps = hazard_maps(plane(5.0, 50.0), 1.0, Lander(convention="hd", layout="triangle"))
    valid = maps.label != LABEL_INVALID
    np.testing.assert_allclose(np.degrees(maps.slope_rad[valid]), 5.0, atol=0.01)
    assert np.all(maps.label[valid] == LABEL_SAFE)


@pytest.mark.parametrize("backend", BACKENDS)
def test_safety_probability_limits(backend: Backend) -> None:
    p_flat = safety_probability(plane(0.0), 1.0, 1e-3, HD, backend=backend)
    valid = ~np.isnan(p_flat)
    assert valid.sum() == 30 * 30 and p_flat.dtype == np.float32
    assert np.all(p_flat[valid] == pytest.approx(1.0))
    p_steep = safety_probability(plane(15.0), 1.0, 1e-3, HD, backend=backend)
    assert np.all(p_steep[valid] == 0.0)


def test_safety_probability_is_gaussian_cdf_of_roughness_margin() -> None:
    dem = plane(0.0)
    dem[20, 20] += 0.25  # 5 cm above the limit at sites whose body covers it (free yaw, flat plane)
    maps = hazard_maps(dem, 1.0, HD)
    p = probability_from_maps(maps, 0.05, Lander(convention="hd"))
    assert maps.roughness_m[20, 20] == pytest.approx(0.25)
    assert p[20, 20] == pytest.approx(0.15865525, abs=1e-6)  # Phi(-1)
    assert p[30, 30] == pytest.approx(0.99996833, abs=1e-7)  # boulder > 5 m away: roughness 0, Phi(4)
    # The baseline decision P >= 0.5 is roughness <= limit (and slope below its limit).
    baseline = p >= 0.5
    assert np.array_equal(baseline[maps.valid], (maps.roughness_m <= 0.2)[maps.valid])
    # sigma = 0 is the deterministic test.
    p0 = probability_from_maps(maps, 0.0, Lander(convention="hd"))
    assert np.array_equal(p0[maps.valid] == 1.0, maps.label[maps.valid] == LABEL_SAFE)


def test_probability_decreases_with_noise() -> None:
    rng = np.random.default_rng(4)
    dem = plane(2.0) + rng.normal(0.0, 0.03, (N, N))
    maps = hazard_maps(dem, 1.0, HD)
    p_small, p_large = probability_from_maps(maps, 0.01, HD), probability_from_maps(maps, 0.07, HD)
    ok = maps.valid & (maps.roughness_m < 0.2)
    assert np.all(p_large[ok] <= p_small[ok])


@pytest.mark.parametrize(
    ("dem", "spacing", "message"),
    [
        (np.zeros((8, 8)), 1.0, "larger than"),
        (np.full((20, 20), np.nan), 1.0, "all NaN"),
        (np.zeros((4, 4, 4)), 1.0, "2-D"),
        (np.zeros((20, 20)), -1.0, "spacing"),
    ],
)
def test_bad_dem_is_one_line_error(dem: np.ndarray, spacing: float, message: str) -> None:
    with pytest.raises(HdLabelsError, match=message) as info:
        hazard_maps(dem, spacing, HD)
    assert "\n" not in str(info.value)


def test_bad_sigma() -> None:
    with pytest.raises(HdLabelsError, match="sigma"):
        safety_probability(plane(0.0), 1.0, -0.1, HD)


@pytest.mark.parametrize(
    "lander", [HD, Lander(), Lander(baseline_combine="min"), Lander(convention="hd", count_holes=True)]
)
def test_parallel_rows_give_the_same_numbers(lander: Lander) -> None:
    """Rows of sites on numba's threads: every map and P(safe) bit for bit those of one thread."""
    rng = np.random.default_rng(7)
    dem = plane(4.0) + rng.normal(0.0, 0.02, (N, N))
    dem[17, 22] += 0.4
    serial = alhat.hazard_and_probability(dem, 1.0, 0.05, lander)
    parallel = alhat.hazard_and_probability(dem, 1.0, 0.05, lander, parallel=True)
    for a, b in ((serial[0].slope_rad, parallel[0].slope_rad), (serial[0].roughness_m, parallel[0].roughness_m)):
        assert np.array_equal(a, b, equal_nan=True)
    assert np.array_equal(serial[0].label, parallel[0].label)
    assert np.array_equal(serial[1], parallel[1], equal_nan=True)
    assert np.array_equal(alhat.hazard_maps(dem, 1.0, lander, parallel=True).label, serial[0].label)
    assert 0 < np.count_nonzero(serial[1] >= 0.5) < np.count_nonzero(serial[0].valid)  # both decisions occur


def test_parallel_kernels_are_cached_apart_from_the_serial_ones() -> None:
    """numba's disk cache files a kernel by qualified name and signature, not by its options: the
    parallel dispatchers compile copies under their own names, else they load the serial code."""
    for serial, parallel in ((alhat._maps_jit, alhat._maps_par_jit), (alhat._product_jit, alhat._product_par_jit)):
        assert parallel.targetoptions.get("parallel") and not serial.targetoptions.get("parallel")
        assert parallel.py_func.__qualname__ != serial.py_func.__qualname__
        assert parallel.py_func.__code__ is serial.py_func.__code__  # the same loops, compiled twice


def test_the_slope_test_is_strict_for_labels_and_as_the_convention_says_for_the_baseline() -> None:
    limit = math.radians(10.0)
    slopes = np.array([limit - 1e-9, limit, limit + 1e-9, np.nan])
    assert alhat.slope_passes(slopes, HD, baseline=False).tolist() == [True, False, False, False]
    assert alhat.slope_passes(slopes, HD, baseline=True).tolist() == [True, False, False, False]
    assert alhat.slope_passes(slopes, Lander(), baseline=False).tolist() == [True, False, False, False]
    assert alhat.slope_passes(slopes, Lander(), baseline=True).tolist() == [True, True, False, False]


def test_hazard_maps_is_a_frozen_record() -> None:
    maps = hazard_maps(plane(0.0), 1.0, HD)
    assert isinstance(maps, HazardMaps)
    with pytest.raises(AttributeError):
        maps.label = None  # type: ignore[misc, assignment]  # the point: a frozen record refuses it


def test_every_label_kernel_divides_without_zero_checks():
    """numba's default error model checks each divisor for zero, which keeps LLVM from vectorising
    the loops that divide (docs/labels.md, Speed); every kernel of hdlabels.alhat uses IEEE division."""
    import numba

    from hdlabels import alhat

    kernels = [v for v in vars(alhat).values() if isinstance(v, numba.core.registry.CPUDispatcher)]
    assert len(kernels) >= 8
    assert all(k.targetoptions.get("error_model") == "numpy" for k in kernels)
