"""The keys of ``model.json``, the side file ``hd export-model`` writes next to an exported network,
as typed records (``hdnet.onnx_export``; docs/user-guide.md, "Exporting the network for flight
software", says what flight software does with each).

Schema ``hd.onnx-model``, version 1.
"""

from __future__ import annotations

from typing import TypedDict

from hdnet.run_json import InputSpecJson

__all__ = ["ExportedRunJson", "MaskJson", "ModelInputJson", "ModelJson", "ModelThresholdJson", "TensorJson"]


class TensorJson(TypedDict):
    """A graph input or output: its name, shape (``"samples"`` and ``"batch"`` are free axes) and dtype."""

    name: str
    shape: list[int | str]
    dtype: str


class MaskJson(TypedDict):
    """One dropout mask input: the layer it drops (``BayesianSegNet``'s module name), its channels and
    the factor its grid is smaller than the network grid by (its rows are ``grid_rows / grid_divisor``)."""

    name: str
    layer: str
    shape: list[int | str]
    channels: int
    grid_divisor: int


class ModelInputJson(TypedDict):
    """The ``dem`` input and how it is made from a DEM (``hdnet.inputs.network_input`` with ``spec``)."""

    name: str
    shape: list[int | str]
    dtype: str
    channels: list[str]
    dem_shape: list[int]  # (rows, cols) cells of the DEM the graph was exported for
    grid: list[int]  # (rows, cols) of the network grid: dem_shape padded, or input_size squared
    spacing_m: float
    spec: InputSpecJson
    sigma_channel_scale_m: float  # the sigma channel holds sigma_m / this
    highpass_window_px: int  # the highpass box side, cells


class ModelThresholdJson(TypedDict, total=False):
    """H_t (nats) on the predictive entropy of the mean of ``mc_samples`` softmax samples, as calibrated
    for this checkpoint (``RUN/thresholds.json``), or None with a note saying how to calibrate it."""

    value_nats: float | None
    unbounded: bool
    spec: str
    uncertainty: str
    calibration_sigma_m: float
    calibration_labels: str
    mc_samples: int
    source: str
    note: str


class ExportedRunJson(TypedDict):
    """The checkpoint exported (the run's ``last.pt``, as ``hd eval`` and ``hd detect`` read it)."""

    checkpoint: str
    checkpoint_sha256: str
    epoch: int
    profile: str | None
    model_config: dict[str, float | int] | None
    train_sigma_m: float


class ModelJson(TypedDict):
    """``model.json``: everything flight software needs beside the graph."""

    schema: str
    schema_version: int
    hd_version: str
    torch_version: str
    format: str
    onnx_file: str
    onnx_sha256: str
    opset: int
    run: ExportedRunJson
    input: ModelInputJson
    masks: list[MaskJson]
    dropout_p: float
    mask_values: list[float]  # each mask element is 0 (dropped) or keep_scale(p) (kept, scaled)
    outputs: list[TensorJson]
    classes: list[str]  # index k of the class axis of logits and probs
    threshold: ModelThresholdJson
