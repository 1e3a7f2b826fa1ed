"""hdnet.data: normalisation from the training split, grids and their inverse, dead pixels, workers, errors."""

from __future__ import annotations

import pickle
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch
from hdnet_datasets import build_labelled, reseal
from torch.utils.data import DataLoader

from hdlabels.errors import LabelStoreError
from hdlabels.store import find_labeling
from hdnet.data import (
    HazardDataset,
    Normalisation,
    compute_normalisation,
    fill_holes,
    sigma_index,
    to_dem_grid,
    to_network_grid,
)
from hdnet.errors import HdNetError


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return build_labelled(tmp_path_factory.mktemp("hdnet-data"))


def shard_arrays(directory: Path, split_code: int, sigma: int) -> dict[str, np.ndarray]:
    """Label-shard arrays of one split, read with plain h5py."""
    out: dict[str, list[np.ndarray]] = {}
    for path in find_labeling(directory).shard_paths(directory):
        with h5py.File(path) as f:
            rows = f["split"][:] == split_code
            out.setdefault("label", []).append(f["label"][:][rows])
            out.setdefault("noisy", []).append(f["dem_noisy"][:, sigma][rows])
            out.setdefault("scan", []).append(f["scan_index"][:][rows])
    return {k: np.concatenate(v) for k, v in out.items()}


def test_normalisation_is_min_max_of_the_training_split_only(dataset, tmp_path):
    train = shard_arrays(dataset, 0, 1)
    norm = compute_normalisation(dataset, 0.07)
    assert norm == Normalisation(float(np.nanmin(train["noisy"])), float(np.nanmax(train["noisy"])))
    # Raising a validation height changes nothing; raising a training height moves the max.
    copy = tmp_path / "copy"
    shutil.copytree(dataset, copy)
    paths = find_labeling(copy).shard_paths(copy)
    for code, expect_change in ((1, False), (0, True)):
        for path in paths:
            with h5py.File(path, "r+") as f:
                rows = np.flatnonzero(f["split"][:] == code)
                if rows.size:
                    f["dem_noisy"][rows[0], 1, 50, 50] = 1000.0
                    break
        reseal(copy)
        changed = compute_normalisation(copy, 0.07)
        assert (changed.max_m == 1000.0) == expect_change
        assert changed.min_m == norm.min_m


def test_padded_sample_matches_the_label_shard(dataset):
    ds = HazardDataset(dataset, "val", 0.0167)
    raw = shard_arrays(dataset, 1, 0)
    assert len(ds) == len(raw["label"]) == 2 and ds.scan_indices == raw["scan"].tolist()
    s = ds[0]
    assert set(s) == {"image", "mask", "index", "sigma_m"} and s["sigma_m"] == 0.0167
    assert s["image"].shape == (1, 128, 128) and s["image"].dtype == torch.float32
    assert s["mask"].shape == (128, 128) and s["mask"].dtype == torch.int64
    assert s["index"] == raw["scan"][0]
    assert (s["mask"][100:] == 255).all() and (s["mask"][:, 100:] == 255).all()
    np.testing.assert_array_equal(s["mask"][:100, :100].numpy(), raw["label"][0])  # no holes in this terrain
    assert ds.normalisation is not None
    expected = ds.normalisation.apply(raw["noisy"][0])
    np.testing.assert_allclose(s["image"][0, :100, :100].numpy(), expected, rtol=0, atol=1e-6)
    # edge replication in the padding
    np.testing.assert_array_equal(s["image"][0, 110, :100].numpy(), s["image"][0, 99, :100].numpy())


def test_resized_sample_round_trips_to_the_dem_grid(dataset):
    ds = HazardDataset(dataset, "train", 0.0167, input_size=512)  # the paper's size
    s = ds[3]
    assert s["image"].shape == (1, 512, 512) and s["mask"].shape == (512, 512)
    native = ds.dem_sample(3).label
    one_hot = torch.stack([(s["mask"] == 0), (s["mask"] == 1)]).float()[None]
    back = ds.to_dem_grid(one_hot)
    assert back.shape == (1, 2, 100, 100)
    valid = native != 255
    np.testing.assert_array_equal(back[0].argmax(0).numpy()[valid], native[valid])
    # probabilities stay probabilities; a constant map comes back exactly
    probs = torch.softmax(torch.randn(2, 2, 512, 512, generator=torch.Generator().manual_seed(0)), dim=1)
    np.testing.assert_allclose(ds.to_dem_grid(probs).sum(1).numpy(), 1.0, atol=1e-6)
    np.testing.assert_allclose(to_dem_grid(torch.full((1, 2, 512, 512), 0.5), (100, 100), 512).numpy(), 0.5)
    # padding is undone by cropping
    pad_img, (pad_mask,) = to_network_grid(
        torch.arange(1e4).view(1, 100, 100), [torch.zeros(100, 100, dtype=torch.int64)], None, [255]
    )
    assert pad_img.shape == (1, 128, 128) and int(pad_mask.sum()) == 255 * (128 * 128 - 100 * 100)
    np.testing.assert_array_equal(
        to_dem_grid(pad_img[None], (100, 100), None)[0, 0].numpy(), np.arange(1e4).reshape(100, 100)
    )


def test_fill_holes_takes_the_nearest_finite_value():
    z = np.array([[1.0, np.nan, np.nan, 4.0, 5.0], [1.0, 7.0, 7.0, 7.0, 7.0], [7.0, 7.0, 7.0, 7.0, 7.0]])
    z[1, 1:4] = np.nan  # (0, 1) is 1 pixel from 1.0 only; (0, 2) is 1 pixel from 4.0 only
    np.testing.assert_array_equal(fill_holes(z)[0], [1.0, 1.0, 4.0, 4.0, 5.0])
    assert (fill_holes(np.full((2, 2), np.nan)) == 0).all()


def test_holes_become_ignored_pixels(dataset, tmp_path):
    copy = tmp_path / "holes"
    shutil.copytree(dataset, copy)
    path = find_labeling(copy).shard_paths(copy)[0]
    with h5py.File(path, "r+") as f:
        f["dem_noisy"][0, 0, 40:43, 60] = np.nan
    reseal(copy)
    ds = HazardDataset(copy, "train", 0.0167)
    s = ds.dem_sample(0)
    assert (s.label[40:43, 60] == 255).all() and np.isfinite(s.dem_filled_m).all()
    assert (ds[0]["mask"][40:43, 60] == 255).all()


def test_dead_pixels_repair_the_dem_and_give_an_ignore_mask(dataset):
    plain = HazardDataset(dataset, "test", 0.0167)
    dead = HazardDataset(dataset, "test", 0.0167, dead_pixels=10, seed=4)
    dead_hi = HazardDataset(dataset, "test", 0.07, dead_pixels=10, seed=4, input_size=160)
    a, b = plain.dem_sample(0), dead.dem_sample(0)
    assert b.dead_pixels.shape == (10, 2)
    changed = np.argwhere(a.dem_noisy_m != b.dem_noisy_m)
    assert {tuple(p) for p in changed} <= {tuple(p) for p in b.dead_pixels}
    assert b.ignore[tuple(b.dead_pixels.T)].all() and b.ignore.sum() > 10 * 50  # lander-size neighbourhoods
    # the same pixels at every noise level (a property of the detector), resized like the label
    np.testing.assert_array_equal(dead_hi.dem_sample(0).dead_pixels, b.dead_pixels)
    s = dead_hi[0]
    assert s["ignore"].shape == (160, 160) and s["ignore"].dtype == torch.bool and s["ignore"].any()
    assert "ignore" not in plain[0]
    assert not np.array_equal(
        HazardDataset(dataset, "test", 0.0167, dead_pixels=10, seed=5).dem_sample(0).dead_pixels, b.dead_pixels
    )


def test_pickles_without_open_files_and_works_with_worker_processes(dataset):
    ds = HazardDataset(dataset, "train", 0.07)
    first = ds[0]  # opens a handle in this process
    clone = pickle.loads(pickle.dumps(ds))
    assert clone._files == {}
    torch.testing.assert_close(clone[0]["image"], first["image"])
    seen = []
    for batch in DataLoader(ds, batch_size=4, num_workers=2):
        assert batch["image"].shape[1:] == (1, 128, 128)
        seen += batch["index"].tolist()
    assert seen == ds.scan_indices
    torch.testing.assert_close(batch["image"][-1], ds[len(ds) - 1]["image"])


def test_sigma_matching_and_errors(dataset, tmp_path):
    assert sigma_index((0.05 / 3, 0.03, 0.07), 0.0167) == 0  # 0.0167 is S-167 as printed
    assert sigma_index((0.0167, 0.07), 0.0167 + 1e-10) == 0
    assert HazardDataset(dataset, "train", 0.03).made_on_the_fly  # a level not stored: made from the clean points
    with pytest.raises(HdNetError, match=r"sigma must be in \[0, 0\.7\] metres, got 0\.8"):
        HazardDataset(dataset, "train", 0.8)
    with pytest.raises(HdNetError, match="split"):
        HazardDataset(dataset, "validation", 0.0167)
    with pytest.raises(HdNetError, match="dead pixels"):
        HazardDataset(dataset, "test", 0.0167, dead_pixels=10_000)
    unlabelled = build_labelled(tmp_path / "u", n_scans=4, label=False)
    with pytest.raises(LabelStoreError, match="no labels"):
        HazardDataset(unlabelled, "train", 0.0167)
