"""hdnet.fit: a tiny training run on real label shards records its data; bad datasets fail clearly."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hdnet_datasets import build_labelled

from hdlabels.errors import LabelStoreError
from hdlabels.store import LabelingEntry, find_labeling
from hdnet.data import compute_normalisation
from hdnet.errors import HdNetError
from hdnet.fit import FitConfig, fit
from hdnet.inputs import InputSpec
from hdnet.run_record import RUN_DATA_KEYS, RUN_SCHEMA_VERSION, checkpoint_data, read_run_record
from hdnet.train import load_checkpoint
from lidarsim.shards import sha256_file


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return build_labelled(tmp_path_factory.mktemp("hdnet-fit"))


def test_tiny_fit_records_the_data_it_was_trained_on(dataset, tmp_path):
    last = fit(dataset, tmp_path / "run", FitConfig(profile="tiny", epochs=1, progress=False))
    assert last == tmp_path / "run" / "last.pt" and last.is_file()
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    extra = config["extra_config"]
    assert config["schema_version"] == RUN_SCHEMA_VERSION and set(extra) == set(RUN_DATA_KEYS)
    assert extra["dataset"] == str(dataset.resolve())
    assert extra["manifest_sha256"] == sha256_file(dataset / "manifest.json")
    assert extra["train_sigma_m"] == 0.0167
    spec = InputSpec.from_dict(extra["input"])
    assert spec.normalisation == compute_normalisation(dataset, 0.0167)
    assert spec.input_size is None and spec.rule == "pad:32" and extra["dem_shape"] == [100, 100]
    assert extra["labels"].startswith("paper-square-d10m")
    entry = json.loads((dataset / "manifest.json").read_text())["labelings"][0]
    assert extra["labeling"] == {k: v for k, v in entry.items() if k != "shards"}  # lander and DEM grid, no shard list
    recorded = LabelingEntry.from_json(extra["labeling"], "the run's labelling")
    assert recorded == find_labeling(dataset).without_shards() and recorded.lander.convention == "paper"
    ckpt = load_checkpoint(last)
    assert ckpt["extra_config"] == extra and ckpt["epoch"] == 1 and ckpt["profile"]["name"] == "tiny"
    record = read_run_record(tmp_path / "run")
    assert record.to_dict() == config and record.data.dataset == str(dataset.resolve())


def test_fit_refuses_bad_datasets(dataset, tmp_path):
    with pytest.raises(HdNetError, match=r"in \[0, 0\.7\] \(noise levels are in metres: 7 cm is 0\.07\)"):
        fit(dataset, tmp_path / "a", FitConfig(profile="tiny", epochs=1, train_sigma_m=0.9, progress=False))
    with pytest.raises(HdNetError, match="unknown training profile"):
        fit(dataset, tmp_path / "b", FitConfig(profile="huge", epochs=1, progress=False))
    unlabelled = build_labelled(tmp_path / "u", n_scans=4, label=False)
    with pytest.raises(LabelStoreError, match="no labels"):
        fit(unlabelled, tmp_path / "c", FitConfig(profile="tiny", epochs=1, progress=False))
    two_scans = build_labelled(tmp_path / "t", n_scans=2)  # too few split blocks: every scan is training
    with pytest.raises(HdNetError, match="the val split is empty"):
        fit(two_scans, tmp_path / "d", FitConfig(profile="tiny", epochs=1, progress=False))
    assert not (tmp_path / "d" / "last.pt").exists()


def test_fit_with_the_cpu_levers_records_its_input_spec_and_resumes_exactly(dataset, tmp_path):
    from dataclasses import replace

    import torch

    from hdnet.profiles import TINY

    profile = replace(
        TINY,
        heights="median",
        height_scale_m=0.5,
        extra_channels=("slope", "highpass"),
        depth=3,
        augment="d4",
        lr_schedule="onecycle",
        class_weighting="balanced",
    )
    straight = fit(dataset, tmp_path / "a", FitConfig(profile=profile, epochs=2, progress=False))
    fit(dataset, tmp_path / "b", FitConfig(profile=profile, epochs=2, progress=False, stop_after=1))
    resumed = fit(dataset, tmp_path / "b", FitConfig(profile=profile, epochs=2, progress=False, resume=True))
    a, b = load_checkpoint(straight), load_checkpoint(resumed)
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])  # D4 draws replay exactly
    spec = checkpoint_data(a, straight).input
    assert spec == InputSpec(
        heights="median", height_scale_m=0.5, extra_channels=("slope", "highpass"), spacing_m=1.0, size_multiple=8
    )
    assert spec.normalisation is None and spec.rule == "pad:8"
    assert a["model_config"]["in_channels"] == 3 and a["model_config"]["depth"] == 3


def test_d4_is_refused_for_a_triangle_lander(tmp_path):
    from dataclasses import replace

    from hdnet_datasets import build_labelled as build

    from hdlabels.labeling import label_dataset
    from hdlabels.settings import LabelSettings
    from hdnet.profiles import TINY

    data = build(tmp_path / "tri", n_scans=20, label=False)
    label_dataset(data, LabelSettings(lander="triangle"), workers=1)
    with pytest.raises(HdNetError, match="triangle"):
        fit(data, tmp_path / "run", FitConfig(profile=replace(TINY, augment="d4"), epochs=1, progress=False))
    assert not (tmp_path / "run").exists()


def test_the_default_training_sigma_is_the_datasets_only_one_else_the_papers() -> None:
    from hdnet.fit import training_sigma

    assert training_sigma(None, (0.07,)) == 0.07  # hd build-dataset --sigma 0.07, then hd train
    assert training_sigma(None, (0.0167, 0.03, 0.07)) == 0.0167  # the paper trains at S-167
    assert training_sigma(0.03, (0.0167, 0.03, 0.07)) == 0.03
