"""hdnet.run_record: one typed run record, written once, read through one migration of older versions."""

from __future__ import annotations

import json
from typing import cast

import pytest

from hdlabels.lander import Lander
from hdlabels.store import DemSpec, LabelingEntry
from hdnet.checkpoint_json import CheckpointJson
from hdnet.errors import HdNetError
from hdnet.inputs import InputSpec, Normalisation
from hdnet.noise_levels import TrainingNoise
from hdnet.run_record import (
    RUN_DATA_KEYS,
    RUN_SCHEMA_VERSION,
    AlsoDataset,
    CheckpointHeader,
    RunRecord,
    TrainingData,
    checkpoint_data,
    migrate,
    read_run_record,
    write_run_record,
)

SPEC = InputSpec(heights="median", extra_channels=("slope", "highpass"), spacing_m=1.0, size_multiple=4)
ENTRY = LabelingEntry("paper-square", Lander(), DemSpec.for_convention("paper"), schema_version="1.1")
LABELING = ENTRY.to_json()  # as a run records it: the manifest's entry without the shard list


def _record_v1() -> dict:
    """A config.json as hd wrote it with schema version 1 (the layout of the runs kept from then):
    the input spec and, beside it, its normalisation, size and rule repeated."""
    return {
        "schema": "hdnet.run",
        "schema_version": 1,
        "model_name": "bayesian_segnet",
        "model_config": {"in_channels": 3, "n_classes": 2, "width": 0.5, "dropout_p": 0.2, "depth": 2},
        "profile": {"name": "cpu", "epochs": 40},
        "epochs": 20,
        "seed": 0,
        "world_size": 1,
        "hd_version": "0.1.0",
        "torch_version": "2.13.0+cpu",
        "extra_config": {
            "dataset": "/data/train",
            "manifest_sha256": "a" * 64,
            "labels": "paper-square",
            "labeling": LABELING,
            "train_sigma_m": 0.0167,
            "train_noise": {"kind": "single", "levels_m": [0.0167], "range_m": None},
            "normalisation": None,
            "input_size": None,
            "input_rule": "pad:4",
            "dem_shape": [100, 100],
            "input": SPEC.to_dict(),
            "also": [{"dataset": "/data/rocks", "manifest_sha256": "b" * 64}],
        },
        "class_weights": None,
    }


def test_a_version_1_record_reads_as_the_same_run_without_its_repeated_keys():
    raw = _record_v1()
    record = RunRecord.from_dict(raw)
    assert record.file_version == 1 and record.profile_name == "cpu" and record.epochs == 20
    data = record.data
    assert data.input == SPEC and data.train_sigma_m == 0.0167 and data.train_noise == TrainingNoise.single(0.0167)
    assert data.dataset == "/data/train" and data.labels == "paper-square" and data.labeling == ENTRY
    assert data.dem_shape == (100, 100) and data.also == (AlsoDataset("/data/rocks", "b" * 64),)
    out = record.to_dict()
    assert out["schema_version"] == RUN_SCHEMA_VERSION == 2
    assert set(out["extra_config"]) == {*RUN_DATA_KEYS, "also"}  # normalisation, input_size, input_rule gone
    assert TrainingData.from_dict(out["extra_config"]) == data
    assert raw == _record_v1()  # the record read is not modified


def test_a_first_version_run_reads_as_minmax_heights_padded_to_its_depth():
    """hd 0.1.0: no input spec, no training noise, no labelling entry, no depth in the model config."""
    raw = _record_v1()
    raw["model_config"].pop("depth")
    extra = raw["extra_config"]
    for key in ("input", "train_noise", "labeling", "also"):
        extra.pop(key)
    extra.update(normalisation={"min_m": -2.0, "max_m": 3.0}, input_size=512, input_rule="resize:512")
    data = RunRecord.from_dict(raw).data
    # Five encoder stages (the paper's SegNet): padding would be to 2**5; the size wins here (resize).
    assert data.input == InputSpec(
        heights="minmax", normalisation=Normalisation(-2.0, 3.0), input_size=512, size_multiple=32
    )
    assert data.train_noise == TrainingNoise.single(0.0167) and data.labeling is None and data.also == ()


def test_a_checkpoint_is_read_through_the_same_migration():
    raw = _record_v1()
    ckpt = cast(CheckpointJson, {"model_config": raw["model_config"], "extra_config": raw["extra_config"], "epoch": 3})
    assert checkpoint_data(ckpt, "run/last.pt") == RunRecord.from_dict(raw).data
    with pytest.raises(HdNetError, match=r"^run/last\.pt was not trained by hdnet\.fit"):
        checkpoint_data(cast(CheckpointJson, {"extra_config": {"norm_max_m": 2.0}}), "run/last.pt")


def test_written_and_read_back_unchanged(tmp_path):
    record = RunRecord.from_dict(_record_v1())
    write_run_record(tmp_path, record)
    text = (tmp_path / "config.json").read_text()
    assert text == json.dumps(record.to_dict(), indent=2) + "\n"
    again = read_run_record(tmp_path)
    assert again.to_dict() == record.to_dict() and again.file_version == RUN_SCHEMA_VERSION
    assert migrate(record.to_dict()) == record.to_dict()  # the current version migrates to itself


def test_a_run_of_the_training_loop_alone_keeps_its_own_extra_config():
    raw = {**_record_v1(), "schema_version": 2, "extra_config": {"norm_min_m": -1.5, "norm_max_m": 2.0}}
    record = RunRecord.from_dict(raw)
    assert record.extra_config == {"norm_min_m": -1.5, "norm_max_m": 2.0}
    with pytest.raises(HdNetError, match=r"was not trained by hdnet\.fit"):
        _ = record.data


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"schema": "hd.labels"}, r"schema 'hd.labels' is not an hd run"),
        ({"schema_version": 3}, r"run schema version 3 is not readable by this hd \(reads 1 to 2\)"),
        ({"schema_version": True}, r"run schema version True is not readable"),
    ],
)
def test_other_records_are_refused(change, message):
    with pytest.raises(HdNetError, match=message):
        RunRecord.from_dict({**_record_v1(), **change})


def test_unreadable_config_files_are_one_error_naming_the_file(tmp_path):
    with pytest.raises(HdNetError, match=r"config\.json: unreadable run config"):
        read_run_record(tmp_path)
    (tmp_path / "config.json").write_text("[1, 2]")
    with pytest.raises(HdNetError, match=r"config\.json: not a JSON object"):
        read_run_record(tmp_path)


def test_a_checkpoints_header_is_read_in_one_place():
    """Epoch, profile name and model config, as hd eval's report and hd detect's detect.json record
    them (in that order); a checkpoint without them reads as epoch 0 and None."""
    ckpt = cast(
        CheckpointJson,
        {"epoch": 7, "profile": {"name": "robust", "width": 0.75}, "model_config": {"depth": 2}, "model": {}},
    )
    header = CheckpointHeader.of(ckpt)
    assert header == CheckpointHeader(7, "robust", {"depth": 2})
    assert list(header.to_dict().items()) == [("epoch", 7), ("profile", "robust"), ("model_config", {"depth": 2})]
    assert CheckpointHeader.of(cast(CheckpointJson, {})) == CheckpointHeader(0, None, None)
    assert CheckpointHeader.of(cast(CheckpointJson, {"profile": None})).profile is None
