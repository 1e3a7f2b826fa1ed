"""Lander validation and the sampling geometry derived from it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hdlabels import defaults
from hdlabels.errors import HdLabelsError
from hdlabels.lander import Lander, bilinear_taps, geometry


def test_defaults_are_the_paper_lander() -> None:
    lander = Lander(convention="hd")
    assert (lander.diameter_m, lander.pad_diameter_m) == (10.0, 1.0)
    assert lander.pad_centre_radius_m == pytest.approx(4.5)
    assert (lander.max_slope_deg, lander.max_roughness_m) == (10.0, 0.20)
    assert lander.n_pads == 4
    assert np.degrees(lander.yaws_rad()).tolist() == pytest.approx([11.25 * m for m in range(8)])
    assert (defaults.LABEL_UNSAFE, defaults.LABEL_SAFE, defaults.LABEL_INVALID) == (0, 1, 255)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"diameter_m": 0.0},
        {"pad_diameter_m": -1.0},
        {"max_slope_deg": 0.0},
        {"max_slope_deg": 90.0},
        {"max_roughness_m": 0.0},
        {"pad_diameter_m": 10.0},
        {"layout": "hexagon"},
        {"n_yaws": 0},
        {"diameter_m": math.nan},
    ],
)
def test_bad_lander_is_one_line_error(kwargs: dict) -> None:
    with pytest.raises(HdLabelsError) as info:
        Lander(convention="hd", **kwargs)
    assert "\n" not in str(info.value)


def test_to_attrs_is_plain_and_complete() -> None:
    attrs = Lander(convention="hd", layout="triangle", n_yaws=6).to_attrs()
    assert attrs["layout"] == "triangle" and attrs["n_pads"] == 3
    assert attrs["yaw_step_deg"] == pytest.approx(20.0)
    assert attrs["pad_centre_radius_m"] == pytest.approx(4.5)
    assert all(isinstance(v, (int, float, str, bool)) for v in attrs.values())


def test_bilinear_taps_weights_sum_to_one_and_skip_zero_weights() -> None:
    assert bilinear_taps(2.0, -3.0) == [(3, 2, 1.0)]  # a node: x east = column, y north = -row
    taps = bilinear_taps(0.25, -0.5)
    assert sum(w for *_, w in taps) == pytest.approx(1.0)
    assert sorted((a, b) for a, b, _ in taps) == [(0, 0), (0, 1), (1, 0), (1, 1)]


def test_geometry_of_default_lander_on_1m_grid() -> None:
    geo = geometry(Lander(convention="hd"), 1.0)
    # Body: nodes with di^2 + dj^2 <= 25 -> 81 of them (hand count: 1+2*(5+5+5+5+4+3)... = 81).
    assert all(geo.nodes(m)[0].size == 81 for m in range(geo.n_yaws))
    assert geo.band_px == 5
    # Footprint: body plus the bilinear taps of pad samples at radius <= 5: Chebyshev <= 5 and
    # |di| + |dj| <= 8 (a node like (5, 4) would need a sample at distance > 5).
    di, dj = np.mgrid[-5:6, -5:6]
    expected = (np.abs(di) + np.abs(dj)) <= 8
    assert np.array_equal(geo.footprint, expected)
    # Every pad sample lies within the body radius of the site.
    assert np.all(np.hypot(geo.pad_xy_px[..., 0], geo.pad_xy_px[..., 1]) == pytest.approx(4.5))


def test_geometry_rejects_bad_spacing() -> None:
    with pytest.raises(HdLabelsError):
        geometry(Lander(convention="hd"), 0.0)
