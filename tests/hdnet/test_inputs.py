"""hdnet.inputs: the one DEM -> network input preparation (channels by hand, grids, spec round trip, old runs)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from hdnet.augment import d4
from hdnet.errors import HdNetError
from hdnet.inputs import (
    InputSpec,
    Normalisation,
    highpass,
    highpass_window_px,
    input_channels,
    network_input,
    plane_residual,
    slope_tangent,
)


def _plane(shape: tuple[int, int], a: float, b: float, c: float, spacing: float = 1.0) -> np.ndarray:
    rows, cols = np.indices(shape, dtype=np.float64)
    return a + b * cols * spacing + c * rows * spacing


def test_minmax_channel_is_the_paper_normalisation() -> None:
    dem = np.array([[1.0, 2.0], [3.0, 5.0]])
    spec = InputSpec(heights="minmax", normalisation=Normalisation(1.0, 5.0))
    np.testing.assert_allclose(input_channels(dem, spec)[0], [[0.0, 0.25], [0.5, 1.0]])


def test_median_channel_is_metres_above_the_median_over_the_scale() -> None:
    dem = np.array([[10.0, 10.2, 11.0], [9.0, 10.0, 10.0], [10.1, 12.0, 10.0]])  # median 10.0
    out = input_channels(dem, InputSpec(heights="median", height_scale_m=0.5))
    assert out.shape == (1, 3, 3) and out.dtype == np.float32
    np.testing.assert_allclose(out[0], (dem - 10.0) / 0.5, atol=1e-6)


def test_plane_channel_removes_an_exact_plane_and_keeps_a_bump() -> None:
    z = _plane((9, 9), 3.0, 0.2, -0.1, spacing=2.0)
    np.testing.assert_allclose(plane_residual(z, 2.0), 0.0, atol=1e-10)
    bump = np.zeros((9, 9))
    bump[4, 4] = 0.81  # symmetric about the centre: the fitted plane is flat at 0.81 / 81 = 0.01
    np.testing.assert_allclose(plane_residual(z + bump, 2.0), bump - 0.01, atol=1e-10)
    spec = InputSpec(heights="plane", height_scale_m=0.1, spacing_m=2.0)
    np.testing.assert_allclose(input_channels(z + bump, spec)[0], (bump - 0.01) / 0.1, atol=1e-5)


def test_slope_channel_is_the_tangent_of_a_planes_tilt() -> None:
    spacing = 0.5
    z = _plane((6, 7), 1.0, 0.3, 0.4, spacing)  # dz/dx = 0.3, dz/dy = 0.4 per metre
    np.testing.assert_allclose(slope_tangent(z, spacing), 0.5, atol=1e-12)
    tilt = math.tan(math.radians(10.0))
    z10 = _plane((5, 5), 0.0, tilt, 0.0)
    spec = InputSpec(heights="median", extra_channels=("slope",))
    out = input_channels(z10, spec)
    assert out.shape == (2, 5, 5)
    np.testing.assert_allclose(out[1], tilt, atol=1e-6)


def test_highpass_channel_removes_planes_and_keeps_a_rock() -> None:
    spec = InputSpec(heights="median", extra_channels=("highpass",), highpass_window_m=2.0, spacing_m=0.5)
    assert highpass_window_px(spec) == 5  # 2 m at 0.5 m/px, odd
    assert highpass_window_px(InputSpec(heights="median", highpass_window_m=10.0)) == 11  # 10 px -> 11
    z = _plane((15, 15), 2.0, 0.1, 0.05)
    np.testing.assert_allclose(
        highpass(z, 5)[2:-2, 2:-2], 0.0, atol=1e-12
    )  # a linear function's box mean is its centre
    rock = np.zeros((15, 15))
    rock[7, 7] = 0.5
    np.testing.assert_allclose(highpass(z + rock, 5)[7, 7], 0.5 * (1 - 1 / 25), atol=1e-12)
    out = input_channels(z + rock, spec)
    np.testing.assert_allclose(out[1, 7, 7], 0.48, atol=1e-6)


def test_network_input_fills_holes_and_pads_to_the_depths_multiple() -> None:
    rng = np.random.default_rng(0)
    dem = rng.normal(0.0, 1.0, (100, 100)).astype(np.float32)
    dem[10:12, 20] = np.nan
    for multiple, size in ((32, 128), (8, 104), (16, 112)):
        x = network_input(
            dem, InputSpec(heights="median", extra_channels=("slope", "highpass"), size_multiple=multiple)
        )
        assert x.shape == (3, size, size) and x.dtype == torch.float32 and torch.isfinite(x).all()
        torch.testing.assert_close(x[:, 100:, :100], x[:, 99:100, :100].expand(-1, size - 100, -1))  # edge replication
    resized = network_input(dem, InputSpec(heights="minmax", normalisation=Normalisation(-4.0, 4.0), input_size=64))
    assert resized.shape == (1, 64, 64)
    with pytest.raises(HdNetError, match="2-D"):
        network_input(np.zeros(5), InputSpec(heights="median"))


def test_every_channel_commutes_with_rotations_and_flips() -> None:
    rng = np.random.default_rng(1)
    dem = np.cumsum(rng.normal(0.0, 0.2, (24, 24)), axis=0) + rng.normal(0.0, 0.05, (24, 24))
    spec = InputSpec(heights="plane", extra_channels=("slope", "highpass"), size_multiple=8, highpass_window_m=5.0)
    base = network_input(dem, spec).numpy()
    for k in range(8):
        np.testing.assert_allclose(
            network_input(np.ascontiguousarray(d4(dem, k)), spec).numpy(), d4(base, k), atol=1e-5
        )


def test_spec_round_trips_through_json_and_checks_its_fields() -> None:
    spec = InputSpec(
        heights="median", height_scale_m=0.5, extra_channels=("highpass", "slope"), spacing_m=1.0, size_multiple=8
    )
    back = InputSpec.from_dict(json.loads(json.dumps(spec.to_dict())))
    assert back == spec and back.n_channels == 3 and back.rule == "pad:8"
    paper = InputSpec(heights="minmax", normalisation=Normalisation(-3.5, 40.25), input_size=512)
    assert InputSpec.from_dict(json.loads(json.dumps(paper.to_dict()))) == paper and paper.rule == "resize:512"
    with pytest.raises(HdNetError, match="normalisation"):
        InputSpec(heights="minmax")
    with pytest.raises(HdNetError, match="extra channels"):
        InputSpec(heights="median", extra_channels=("curvature",))
    with pytest.raises(HdNetError, match="heights"):
        InputSpec(heights="zscore")  # type: ignore[arg-type]  # the point: refused
    with pytest.raises(HdNetError, match="height_scale_m"):
        InputSpec(heights="median", height_scale_m=0.0)
    with pytest.raises(HdNetError, match="schema version 2"):
        InputSpec.from_dict({**spec.to_dict(), "schema_version": 2})
    with pytest.raises(HdNetError, match="unknown field"):
        InputSpec.from_dict({**spec.to_dict(), "colour": "red"})


def test_runs_saved_before_input_specs_read_as_the_papers_min_max() -> None:
    old_extra = {
        "train_sigma_m": 0.0167,
        "normalisation": {"min_m": -2.0, "max_m": 30.0},
        "input_size": None,
        "input_rule": "pad:32",
        "dem_shape": [100, 100],
    }
    old_model = {"in_channels": 1, "n_classes": 2, "width": 0.25, "dropout_p": 0.5}  # no depth: five blocks
    spec = InputSpec.from_run_config(old_extra, old_model)
    assert spec == InputSpec(
        heights="minmax", normalisation=Normalisation(-2.0, 30.0), input_size=None, size_multiple=32
    )
    dem = np.full((100, 100), 14.0, np.float32)
    x = network_input(dem, spec)
    assert x.shape == (1, 128, 128)
    np.testing.assert_allclose(x.numpy(), 0.5)
    assert InputSpec.from_run_config({**old_extra, "input_size": 512}).input_size == 512
    new = InputSpec(heights="median", size_multiple=8)
    assert InputSpec.from_run_config({**old_extra, "input": new.to_dict()}) == new
    with pytest.raises(HdNetError, match=r"not trained by hdnet\.fit"):
        InputSpec.from_run_config({"train_sigma_m": 0.0167})
