"""Dead-pixel drop and repair: exact on planes, the 4-neighbour mean when isolated, lander-size masks."""

from __future__ import annotations

import numpy as np
import pytest

from hdlabels.deadpixels import drop_and_repair, random_dead_pixels
from hdlabels.errors import HdLabelsError
from hdlabels.lander import Lander


def test_random_dead_pixels_distinct_seeded_in_range() -> None:
    a = random_dead_pixels((100, 100), 10, np.random.default_rng(3))
    b = random_dead_pixels((100, 100), 10, np.random.default_rng(3))
    assert a.shape == (10, 2) and a.dtype == np.int64
    assert np.array_equal(a, b)
    assert len({tuple(p) for p in a.tolist()}) == 10
    assert a.min() >= 0 and a.max() < 100
    with pytest.raises(HdLabelsError):
        random_dead_pixels((3, 3), 10, np.random.default_rng(0))


def test_repair_is_exact_on_a_plane_even_for_adjacent_and_border_pixels() -> None:
    i, j = np.mgrid[0:30, 0:30]
    dem = 0.3 * i - 0.1 * j + 5.0
    pixels = np.array([[10, 10], [10, 11], [11, 10], [0, 15], [29, 29], [15, 0]])
    repaired, _ = drop_and_repair(dem, pixels)
    np.testing.assert_allclose(repaired, dem, atol=1e-5)


def test_isolated_pixel_takes_the_mean_of_its_four_neighbours() -> None:
    rng = np.random.default_rng(0)
    dem = rng.normal(size=(20, 20))
    repaired, _ = drop_and_repair(dem, np.array([[7, 9]]))
    expected = (dem[6, 9] + dem[8, 9] + dem[7, 8] + dem[7, 10]) / 4
    assert repaired[7, 9] == pytest.approx(expected, abs=1e-6)
    untouched = np.ones((20, 20), dtype=bool)
    untouched[7, 9] = False
    np.testing.assert_array_equal(repaired[untouched], dem[untouched].astype(np.float32))


def test_mask_is_the_lander_reach_around_each_dropped_pixel() -> None:
    dem = np.zeros((40, 40))
    _, mask = drop_and_repair(dem, np.array([[20, 20]]), Lander(convention="hd"), 1.0)
    di, dj = np.mgrid[0:40, 0:40]
    di, dj = di - 20, dj - 20
    # Same reach as a NaN cell: body (5 m) and pad taps, Chebyshev <= 5 and |di| + |dj| <= 8.
    expected = (np.maximum(abs(di), abs(dj)) <= 5) & (abs(di) + abs(dj) <= 8)
    assert np.array_equal(mask, expected)
    assert mask[20, 25] and mask[16, 16] and not mask[20, 26]


def test_paper_mask_is_the_paper_footprint_around_each_dropped_pixel() -> None:
    _, mask = drop_and_repair(np.zeros((40, 40)), np.array([[20, 20]]), Lander(), 1.0)
    di, dj = np.mgrid[0:40, 0:40]
    di, dj = di - 20, dj - 20
    # Paper convention at 1 m: pads on nodes of the 7 distinct squares, the farthest at (+-5, 0) and
    # (0, +-5), the others within Chebyshev 4 and |di| + |dj| <= 6 ((4, 2), (3, 3), ...), and the
    # nodes strictly inside those squares, which lie in the same region.
    expected = ((np.maximum(abs(di), abs(dj)) <= 4) & (abs(di) + abs(dj) <= 6)) | (
        (abs(di) + abs(dj) == 5) & (di * dj == 0)
    )
    assert np.array_equal(mask, expected)


def test_no_pixels_no_change() -> None:
    dem = np.arange(25.0).reshape(5, 5)
    repaired, mask = drop_and_repair(dem, np.empty((0, 2), dtype=int))
    np.testing.assert_array_equal(repaired, dem)
    assert not mask.any()


@pytest.mark.parametrize("pixels", [np.array([[0, 5]]), np.array([[1.5, 2.0]]), np.array([1, 2, 3])])
def test_bad_pixels_are_one_line_errors(pixels: np.ndarray) -> None:
    with pytest.raises(HdLabelsError) as info:
        drop_and_repair(np.zeros((4, 4)), pixels)
    assert "\n" not in str(info.value)
