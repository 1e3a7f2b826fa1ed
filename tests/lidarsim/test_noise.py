"""lidarsim.noise: the one range-noise model, and the exact recovery of ranges from clean points."""

from __future__ import annotations

import numpy as np
import pytest

from lidarsim.errors import LidarsimError
from lidarsim.noise import noisy_points, noisy_ranges, points_at_ranges, recover_ranges, scan_directions
from lidarsim.sensor import SensorConfig, sensor_attitude
from lidarsim.streams import Purpose, sigma_key, stream

SENSOR = SensorConfig(rows=32, cols=32)


def _scan(seed: int = 1, tilt: float = 3.0):
    rng = np.random.default_rng(seed)
    d = scan_directions(SENSOR, sensor_attitude(tilt, tuple(np.radians(0.2) * rng.standard_normal(3))))
    ranges = (500.0 + rng.normal(0.0, 3.0, (32, 32))).astype(np.float32).astype(np.float64)
    ranges[3, 4] = np.nan  # a miss
    sp = np.array([0.0, 0.0, 500.0])
    return ranges, d, sp


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_recover_ranges_returns_the_exact_float32_ranges(seed):
    ranges, d, sp = _scan(seed)
    clean = points_at_ranges(sp, ranges, d)
    got = recover_ranges(clean, sp, d)
    assert np.array_equal(got, ranges, equal_nan=True)
    assert np.isnan(got[3, 4]) and np.isnan(clean[3, 4]).all()


def test_recover_ranges_refuses_points_that_are_no_return_of_the_ray():
    ranges, d, sp = _scan()
    clean = points_at_ranges(sp, ranges, d)
    clean[5, 6, 0] += 0.5  # moved sideways off its ray
    with pytest.raises(LidarsimError, match=r"\(5, 6\)"):
        recover_ranges(clean, sp, d)


def test_noise_is_the_streams_gaussian_along_each_ray():
    ranges, d, sp = _scan()
    sigma = 0.07
    r = noisy_ranges(ranges, sigma, seed=5, scan_index=9)
    n = stream(5, Purpose.RANGE_NOISE, 9, sigma_key(sigma)).standard_normal(ranges.shape)
    assert np.array_equal(r, ranges + sigma * n, equal_nan=True)
    pts = noisy_points(ranges, d, sp, sigma, seed=5, scan_index=9)
    finite = np.isfinite(ranges)
    along = np.einsum("...k,...k->...", pts.astype(np.float64) - sp, d)[finite]
    assert np.allclose(along, r[finite], atol=1e-4)  # on the ray, at the noisy range (float32 points)


def test_realisations_are_independent_and_none_is_the_stored_draw():
    ranges, _, _ = _scan()
    own = noisy_ranges(ranges, 0.03, 0, 1)
    again = noisy_ranges(ranges, 0.03, 0, 1)
    other = noisy_ranges(ranges, 0.03, 0, 1, realisation=0)
    third = noisy_ranges(ranges, 0.03, 0, 1, realisation=1)
    assert np.array_equal(own, again, equal_nan=True)
    finite = np.isfinite(ranges)
    for a, b in ((own, other), (other, third)):
        corr = np.corrcoef((a - ranges)[finite], (b - ranges)[finite])[0, 1]
        assert abs(corr) < 0.1  # independent draws


def test_damaged_elements_get_their_extra_error_from_their_own_stream():
    ranges, _, _ = _scan()
    damaged = np.zeros(ranges.shape, bool)
    damaged[0, :5] = True
    a = noisy_ranges(ranges, 0.0, 0, 2, damaged, damaged_error_m=5.0)
    extra = stream(0, Purpose.DAMAGED_ERROR, 2, sigma_key(0.0)).standard_normal(5)
    assert np.allclose(a[0, :5] - ranges[0, :5], 5.0 * extra)
    assert np.array_equal(a[~damaged], ranges[~damaged], equal_nan=True)  # sigma 0: nothing else moves


def test_each_registered_noise_model_knows_its_fields_help_and_inspect_line() -> None:
    from lidarsim.noise import NOISE_KINDS, NoiseModel, help_text, stored_kind

    assert list(NOISE_KINDS) == ["constant", "snr"]
    assert all(f"{name}: " in help_text() for name in NOISE_KINDS)
    signal = np.array([1.0, 0.25, 0.01, 0.0])
    constant, snr = NoiseModel("constant"), NoiseModel("snr", snr_ref=100.0, snr_min=5.0)
    assert constant.is_default and not snr.is_default
    assert constant.sigma_scale(signal) is None
    np.testing.assert_array_equal(snr.sigma_scale(signal), [1.0, 2.0, 10.0, 1.0])  # 1 / sqrt(P), 1 without signal
    np.testing.assert_array_equal(constant.detected(signal), [True] * 4)
    np.testing.assert_array_equal(snr.detected(signal), [True, True, False, False])  # SNR 100, 25, 1, 0 vs 5
    assert stored_kind(snr.to_attrs()).stored_fields == ("noise_scale",)
    assert stored_kind({}).stored_fields == () and stored_kind({}).inspect_line({}) == ""
    assert stored_kind(snr.to_attrs()).inspect_line(snr.to_attrs()) == (
        "snr noise (sigma at 500.0 m, SNR 100.0; no return below SNR 5.0)"
    )
    with pytest.raises(LidarsimError, match="unknown noise model 'gauss'; use constant, snr"):
        NoiseModel("gauss")
