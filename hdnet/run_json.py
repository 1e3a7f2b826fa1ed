"""The keys of a run's records as typed records: ``config.json``, its ``extra_config`` (what the
network was trained on) and the parts of them that reports and ``detect.json`` repeat.

They are JSON (``config.json``) or plain types in a checkpoint, so they are ``TypedDict``: at run
time the dictionaries the files hold, for mypy records whose keys and value types are checked. The
dataclasses that read them (``hdnet.run_record.RunRecord``, ``TrainingData``, ``hdnet.inputs.InputSpec``,
``hdnet.noise_levels.TrainingNoise``) write them with ``to_dict`` and check them in ``from_dict``.
"""

from __future__ import annotations

from typing import NotRequired, TypedDict

from lidarsim.manifest_json import LabelingJson

__all__ = [
    "AlsoDatasetJson",
    "CheckpointHeaderJson",
    "InputSpecJson",
    "NormalisationJson",
    "RunRecordJson",
    "TrainingDataJson",
    "TrainingNoiseJson",
]


class NormalisationJson(TypedDict):
    """Min-max height normalisation, metres."""

    min_m: float
    max_m: float


class InputSpecJson(TypedDict):
    """How DEMs become network inputs (``hdnet.inputs.InputSpec``)."""

    schema_version: int
    heights: str
    normalisation: NormalisationJson | None
    height_scale_m: float
    extra_channels: list[str]
    highpass_window_m: float
    spacing_m: float
    input_size: int | None
    size_multiple: int


class TrainingNoiseJson(TypedDict):
    """The training noise levels (``hdnet.noise_levels.TrainingNoise``), metres."""

    kind: str  # single, levels or range
    levels_m: list[float]
    range_m: list[float] | None


class AlsoDatasetJson(TypedDict):
    """A further training dataset (``hd train --also``)."""

    dataset: str
    manifest_sha256: str


class TrainingDataJson(TypedDict):
    """The ``extra_config`` of a run of ``hdnet.fit`` (``hdnet.run_record.TrainingData``)."""

    dataset: str | None
    manifest_sha256: str | None
    labels: str | None
    labeling: LabelingJson | None
    train_sigma_m: float
    train_noise: TrainingNoiseJson
    dem_shape: list[int] | None
    input: InputSpecJson
    also: NotRequired[list[AlsoDatasetJson]]


class CheckpointHeaderJson(TypedDict):
    """What reports and ``detect.json`` record of a checkpoint (``hdnet.run_record.CheckpointHeader``)."""

    epoch: int
    profile: str | None
    model_config: dict[str, float | int] | None


class RunRecordJson(TypedDict):
    """A run's ``config.json`` (``hdnet.run_record.RunRecord``)."""

    schema: str
    schema_version: int
    model_name: str
    model_config: dict[str, float | int]
    profile: dict[str, object]  # hdnet.profiles.TrainingProfile.to_dict
    epochs: int
    seed: int
    world_size: int
    hd_version: str
    torch_version: str
    extra_config: dict[str, object]  # a TrainingDataJson for a run of hdnet.fit
    class_weights: list[float] | None
