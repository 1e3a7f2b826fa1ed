"""The fast hazard maps agree with the slow loop reference on random rough terrain, pixel for pixel."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from alhat_numpy import Backend, hazard_maps
from alhat_reference import reference_maps
from scipy.ndimage import gaussian_filter

from hdlabels.defaults import LABEL_INVALID
from hdlabels.lander import Lander


def rough_terrain(seed: int, n: int = 30) -> np.ndarray:
    """Smooth hills (a few degrees) plus sparse 0.15 m rocks: a mix of safe and unsafe sites."""
    rng = np.random.default_rng(seed)
    hills = gaussian_filter(rng.normal(0.0, 1.0, (n, n)), 3.0) * 2.0
    rocks = (rng.random((n, n)) < 0.02) * 0.15
    return hills + rocks + rng.normal(0.0, 0.01, (n, n))


@cache
def reference_for(lander: Lander) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Loop-reference maps of ``rough_terrain(3)``, computed once per lander for both back ends."""
    return reference_maps(rough_terrain(3), 1.0, lander)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize(
    "lander",
    [
        Lander(convention="hd"),
        Lander(convention="hd", count_holes=True),
        Lander(convention="hd", layout="triangle", n_yaws=5),
        Lander(convention="hd", max_roughness_m=0.1, n_yaws=3),
    ],
    ids=["default", "holes", "triangle", "strict"],
)
def test_fast_equals_loop_reference(backend: Backend, lander: Lander) -> None:
    slope, rough, label = reference_for(lander)
    maps = hazard_maps(rough_terrain(3), 1.0, lander, backend=backend)
    assert np.array_equal(maps.label, label)
    valid = label != LABEL_INVALID
    counts = np.bincount(label[valid], minlength=2)
    assert counts[0] >= 10 and counts[1] >= 10  # both classes present: the comparison can fail
    np.testing.assert_allclose(maps.slope_rad[valid], slope[valid], rtol=0, atol=1e-6)
    np.testing.assert_allclose(maps.roughness_m[valid], rough[valid], rtol=0, atol=1e-6)


def test_fast_equals_reference_with_nan_and_other_spacing() -> None:
    dem = rough_terrain(5, n=36)
    dem[17, 12] = np.nan
    lander = Lander(convention="hd", diameter_m=8.0, pad_diameter_m=0.8)
    _slope, rough, label = reference_maps(np.nan_to_num(dem), 0.8, lander)
    maps = hazard_maps(dem, 0.8, lander)
    ok = maps.label != LABEL_INVALID
    assert ok.sum() > 100 and not ok[17, 12]
    assert np.array_equal(maps.label[ok], label[ok])
    np.testing.assert_allclose(maps.roughness_m[ok], rough[ok], rtol=0, atol=1e-6)
