"""D4 augmentation: the group, label invariance of the square lander's rule, refusal elsewhere, dataset use."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
import pytest
import torch
from hdnet_datasets import build_labelled
from scipy import ndimage

from hdlabels.alhat import hazard_maps
from hdlabels.lander import Lander
from hdnet.augment import D4_ORDER, check_augment, d4, d4_inverse, label_is_d4_invariant, transform_sample
from hdnet.data import HazardDataset
from hdnet.errors import HdNetError
from hdnet.inputs import InputSpec, network_input


def _terrain(n: int = 36, seed: int = 5) -> np.ndarray:
    """Hills with a 12 % tilt, a few rocks: both safe and unsafe sites for a 6 m lander (1 m/px)."""
    rng = np.random.default_rng(seed)
    z = ndimage.gaussian_filter(rng.normal(0.0, 1.0, (n, n)), 4) * 6.0
    z += 0.12 * np.arange(n)[None, :]
    rocks = np.zeros((n, n))
    idx = rng.integers(0, n, (6, 2))
    rocks[idx[:, 0], idx[:, 1]] = 0.6
    return z + rocks


def test_the_eight_elements_are_distinct_and_invertible() -> None:
    a = np.arange(12.0).reshape(3, 4)
    images = [d4(a, k) for k in range(D4_ORDER)]
    assert len({im.shape for im in images}) == 2  # quarter turns swap the axes
    assert len({im.tobytes() + bytes(im.shape) for im in images}) == 8
    for k in range(D4_ORDER):
        np.testing.assert_array_equal(d4(d4(a, k), d4_inverse(k)), a)
    np.testing.assert_array_equal(d4(a, 1), [[3, 7, 11], [2, 6, 10], [1, 5, 9], [0, 4, 8]])  # 90 deg counter-clockwise
    np.testing.assert_array_equal(d4(a, 4), a[:, ::-1])
    stack = np.stack([a, a + 100])
    np.testing.assert_array_equal(d4(stack, 5)[1], d4(a + 100, 5))  # acts on the last two axes
    with pytest.raises(HdNetError):
        d4(a, 8)


@pytest.mark.parametrize(("convention", "n_yaws"), [("paper", 8), ("hd", 8), ("hd", 3)])
def test_square_lander_labels_are_invariant_under_d4(convention: Literal["paper", "hd"], n_yaws: int) -> None:
    lander = Lander(diameter_m=6.0, pad_diameter_m=1.0, layout="square", n_yaws=n_yaws, convention=convention)
    dem = _terrain()
    label = hazard_maps(dem, 1.0, lander).label
    assert {0, 1} <= set(np.unique(label).tolist())  # both classes present: the check can fail
    for k in range(D4_ORDER):
        moved = hazard_maps(np.ascontiguousarray(d4(dem, k)), 1.0, lander).label
        np.testing.assert_array_equal(moved, d4(label, k), err_msg=f"element {k}")
    assert label_is_d4_invariant(lander)


@pytest.mark.parametrize("convention", ["paper", "hd"])
def test_a_triangle_lander_is_not_invariant_and_is_refused(convention: Literal["paper", "hd"]) -> None:
    lander = Lander(
        diameter_m=6.0,
        pad_diameter_m=1.0,
        layout="triangle",
        convention=convention,
        n_yaws=1 if convention == "hd" else 8,
    )
    dem = _terrain()
    label = hazard_maps(dem, 1.0, lander).label
    changed = [
        k
        for k in range(D4_ORDER)
        if (hazard_maps(np.ascontiguousarray(d4(dem, k)), 1.0, lander).label != d4(label, k)).any()
    ]
    if convention == "hd":
        assert changed  # three pads at 0/120/240 deg turned by 90 deg are other pads
    assert not label_is_d4_invariant(lander)
    with pytest.raises(HdNetError, match="triangle"):
        check_augment("d4", lander)
    assert check_augment("none", lander) == "none"
    with pytest.raises(HdNetError, match="augmentation must be one of"):
        check_augment("mixup", Lander())


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return build_labelled(tmp_path_factory.mktemp("hdnet-augment"))


def test_dataset_augments_dem_label_and_masks_together(dataset) -> None:
    spec = InputSpec(heights="median", extra_channels=("slope",), size_multiple=8)
    plain = HazardDataset(dataset, "train", 0.0167, input_spec=spec)
    aug = HazardDataset(dataset, "train", 0.0167, input_spec=spec, augment="d4")
    torch.manual_seed(7)
    drawn = [int(torch.randint(D4_ORDER, ())) for _ in range(6)]
    torch.manual_seed(7)
    for i, k in enumerate(drawn):
        sample = aug[i]
        raw = plain.dem_sample(i)
        expected = network_input(np.ascontiguousarray(d4(raw.dem_filled_m, k)), spec)
        torch.testing.assert_close(sample["image"], expected)
        np.testing.assert_array_equal(sample["mask"][:100, :100].numpy(), d4(raw.label, k))
        assert (sample["mask"][100:] == 255).all()
    assert len(set(drawn)) > 1


def test_transform_sample_moves_dead_pixels_with_the_grid(dataset) -> None:
    ds = HazardDataset(dataset, "test", 0.0167, dead_pixels=5, seed=2)
    s = ds.dem_sample(0)
    for k in range(D4_ORDER):
        t = transform_sample(s, k)
        marks = np.zeros(s.label.shape, bool)
        marks[tuple(s.dead_pixels.T)] = True
        moved = np.zeros(s.label.shape, bool)
        moved[tuple(t.dead_pixels.T)] = True
        np.testing.assert_array_equal(moved, d4(marks, k))
        np.testing.assert_array_equal(t.ignore, d4(s.ignore, k))
        np.testing.assert_array_equal(t.dem_noisy_m, d4(s.dem_noisy_m, k))
