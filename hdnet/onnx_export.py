"""A trained run's network as one ONNX graph for flight software, with MC dropout outside the graph.

``export_onnx(RUN, OUT, settings)`` (``hd export-model RUN --format onnx --out model.onnx``) writes:

* ``model.onnx``: the network of the run's ``last.pt`` (the checkpoint ``hd eval`` and ``hd detect``
  read, whose sha256 the threshold cache and ``report.json`` name; ``best.pt`` is the best
  validation epoch, which no evaluation scored) as :class:`MaskedSegNet`: inputs ``dem`` (N, C, H,
  W), the network input ``hdnet.inputs.network_input`` makes of a DEM, and one dropout mask per
  MC-dropout layer, ``mask_0`` ... ``mask_k`` (M, N, C_k, H / d_k, W / d_k), in the order the
  network applies them; outputs ``logits`` and ``probs`` (their softmax over the classes), both
  (M, N, 2, H, W). N (inputs) and M (samples) are free axes; the grid H x W is fixed at export.
  The deterministic prefix (the layers before the first dropout) runs once per input and the rest on
  M sample-major copies, as ``hdnet.infer.mc_dropout_predict`` does; flight software draws the masks
  (each element 0 with probability p, else ``keep_scale(p)``, which is 1 / (1 - p) with p rounded to
  1/65536: ``hdnet.dropout_masks``), runs the graph once and averages ``probs``
  over the M samples: P(safe) is the mean's class 1, the uncertainty the mean's entropy.
* ``model.json`` (beside it, the ``.onnx`` suffix replaced: ``hdnet.export_model_settings.sidecar_path``):
  the input preparation (``InputSpec``,
  the channels, the DEM and grid sizes, the spacing), the masks (names, layers, shapes), the drop
  probability and the masks' values, the class order, H_t when the run's threshold cache holds it
  for this checkpoint (``RUN/thresholds.json``), the checkpoint's sha256, hd's version and the opset
  (``hdnet.model_json.ModelJson``).

One graph rather than the prefix and suffix pair of ``benchmarks/probe_onnxruntime.py``: the
prefix's outputs (features and pooling indices) never leave the graph, so flight software feeds one
DEM batch and its masks, and the graph tiles the prefix's state itself. The input preparation
(hole filling by nearest finite cell, the least-squares plane, the highpass box filter) stays
outside the graph: it is NumPy and SciPy code that ONNX would express only approximately; the side
file names every number it needs. Both files are written atomically, together or not at all.
"""

from __future__ import annotations

import contextlib
import copy
import importlib.util
import json
import logging
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn

from hdcore.storage import atomic_path, sha256_bytes, sha256_file
from hdnet import defaults
from hdnet._version import __version__
from hdnet.dropout_masks import keep_scale
from hdnet.engine import NCHWDrawDropout
from hdnet.errors import HdNetError
from hdnet.export_model_settings import ExportModelSettings
from hdnet.inputs import SIGMA_CHANNEL_SCALE_M, highpass_window_px, network_shape
from hdnet.model import BayesianSegNet, MCDropout
from hdnet.model_json import MaskJson, ModelInputJson, ModelJson, ModelThresholdJson, TensorJson
from hdnet.preflight import check_run
from hdnet.run_files import CONFIG
from hdnet.threshold_cache import CACHE_FILE, CachedThreshold
from hdnet.trained_run import TrainedRun
from hdnet.uncertainty import ENTROPY, recorded_score

MODEL_SCHEMA = "hd.onnx-model"
MODEL_SCHEMA_VERSION = 1
INPUT_NAME = "dem"
OUTPUT_NAMES = ("logits", "probs")
CLASSES = ("unsafe", "safe")  # defaults.CLASS_UNSAFE = 0, defaults.CLASS_SAFE = 1
INSTALL_HINT = "pip install 'hd[onnx]'"
# The example sizes of the free axes at export: distinct and above 1 (torch.export fixes an axis of size 1).
_EXAMPLE_BATCH, _EXAMPLE_SAMPLES = 2, 3


def mask_name(k: int) -> str:
    """The graph input of the ``k``-th mask the network applies: ``mask_k``."""
    return f"mask_{k}"


@dataclass(frozen=True)
class MaskSpec:
    """One MC-dropout layer as the graph takes its mask: its module name in ``BayesianSegNet``
    (``drop_pool3``, ``drop_dec5``, ...), the channels it drops and the factor its grid is smaller
    than the network grid by (``2**level``)."""

    layer: str
    channels: int
    divisor: int

    def shape(self, samples: int, batch: int, grid_hw: tuple[int, int]) -> tuple[int, int, int, int, int]:
        """The mask's shape for ``samples`` x ``batch`` inputs on the network grid ``grid_hw`` (pixels)."""
        return samples, batch, self.channels, grid_hw[0] // self.divisor, grid_hw[1] // self.divisor


class _MaskedDropout(nn.Module):
    """An MC-dropout layer whose mask is given: ``x * mask`` (``mask`` set by :class:`MaskedSegNet`);
    with ``record`` set, it appends its name and input shape there and passes ``x`` on."""

    def __init__(self, layer: str) -> None:
        super().__init__()
        self.layer = layer
        self.mask: torch.Tensor | None = None
        self.record: list[tuple[str, torch.Size]] | None = None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.record is not None:
            self.record.append((self.layer, x.shape))
            return x
        if self.mask is None:
            raise HdNetError(f"the dropout layer {self.layer} has no mask: call MaskedSegNet with its masks.")
        return x * self.mask


class MaskedSegNet(nn.Module):
    """A Bayesian SegNet whose MC-dropout masks are inputs: ``forward(dem, *masks) -> (logits, probs)``.

    ``dem``: (N, in_channels, H, W), the network input (``hdnet.inputs.network_input``); ``masks``:
    one per dropout layer in the order the network applies them (:attr:`masks`), mask ``k`` of shape
    ``masks[k].shape(M, N, (H, W))``, values 0 (dropped) or ``keep_scale(p)`` (kept;
    ``hdnet.dropout_masks``: 1 / (1 - p) for p on the 1/65536 grid). The prefix runs once per input,
    the rest on the M sample-major copies of its state. ``logits``: (M, N, n_classes, H, W);
    ``probs``: their softmax over the classes. The weights are a copy of
    ``model``'s, in inference mode (BatchNorm's running statistics).
    """

    def __init__(self, model: BayesianSegNet) -> None:
        super().__init__()
        self.net = copy.deepcopy(model).cpu().eval()
        self.config = self.net.config
        self._drops: dict[str, _MaskedDropout] = {}
        for name, module in list(self.net.named_modules()):
            if isinstance(module, MCDropout):
                drop = _MaskedDropout(name)
                setattr(self.net, name, drop)  # the dropout modules are the network's own attributes
                self._drops[name] = drop
        self.masks = self._applied_masks()

    def _applied_masks(self) -> tuple[MaskSpec, ...]:
        """The dropout layers in the order the network applies them, from one recording pass on a
        grid of one ``size_multiple`` (the channels and each layer's grid divisor)."""
        side = self.config.size_multiple
        recorded: list[tuple[str, torch.Size]] = []
        for drop in self._drops.values():
            drop.record = recorded
        try:
            with torch.no_grad():
                self.net(torch.zeros(1, self.config.in_channels, side, side))
        finally:
            for drop in self._drops.values():
                drop.record = None
        return tuple(MaskSpec(layer, int(shape[1]), side // int(shape[-2])) for layer, shape in recorded)

    def forward(self, dem: torch.Tensor, *masks: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(logits, probs), each (M, N, n_classes, H, W), of ``dem`` with the M samples' ``masks``."""
        if len(masks) != len(self.masks):
            raise HdNetError(f"the network takes {len(self.masks)} dropout masks, got {len(masks)}.")
        samples, batch = masks[0].shape[0], dem.shape[0]
        state = self.net.prefix(dem)
        try:
            for spec, mask in zip(self.masks, masks, strict=True):
                self._drops[spec.layer].mask = mask.reshape(samples * batch, *mask.shape[2:])
            logits = self.net.suffix(state.repeat(samples))
        finally:
            for drop in self._drops.values():
                drop.mask = None
        logits = logits.reshape(samples, batch, *logits.shape[1:])
        return logits, torch.softmax(logits, dim=2)


def draw_masks(model: MaskedSegNet, samples: int, batch: int, grid_hw: tuple[int, int]) -> list[torch.Tensor]:
    """The masks of ``samples`` MC samples of ``batch`` inputs on the network grid ``grid_hw`` (pixels),
    drawn as ``hd detect`` draws them (``hdnet.engine.NCHWDrawDropout.draw``: hd's own PCG64 draws of
    ``hdnet.dropout_masks``, seeded from PyTorch's default generator, layer by layer in the order the
    network applies them, each over the sample-major batch of M * N): after ``torch.manual_seed(s)``
    they are the masks of ``hdnet.engine.predict(..., "channels-last-per-tile")`` seeded with ``s``.
    Float32 (0 or ``keep_scale(p)``), on the CPU."""
    draw = NCHWDrawDropout(model.config.dropout_p)
    scale = keep_scale(model.config.dropout_p)
    out = []
    for spec in model.masks:
        shape = spec.shape(samples, batch, grid_hw)
        keep = draw.draw((samples * batch, *shape[2:]), torch.device("cpu"))
        out.append((keep.to(torch.float32) * scale).view(shape))
    return out


def _require_onnx() -> None:
    """Refuse in one line when the exporter's packages are missing (the ``onnx`` extra)."""
    missing = [name for name in ("onnx", "onnxscript") if importlib.util.find_spec(name) is None]
    if missing:
        raise HdNetError(f"exporting to ONNX needs {' and '.join(missing)}: {INSTALL_HINT}")


@contextlib.contextmanager
def _quiet_exporter() -> Iterator[None]:
    """The exporter's log lines and warnings (skipped torchvision operators, axis names) kept off the terminal."""
    logger = logging.getLogger("torch.onnx")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        logger.setLevel(level)


def onnx_model_bytes(model: MaskedSegNet, grid_hw: tuple[int, int]) -> tuple[bytes, int]:
    """The ONNX graph of ``model`` on the network grid ``grid_hw`` (pixels; N and M free) and its opset:
    PyTorch's dynamo exporter (``torch.onnx.export(dynamo=True)``), checked by ``onnx.checker``.

    Raises:
        HdNetError: onnx or onnxscript missing; the exporter or the checker failing.
    """
    _require_onnx()
    import onnx
    from torch.export import Dim

    dem = torch.zeros(_EXAMPLE_BATCH, model.config.in_channels, *grid_hw)
    masks = [torch.ones(spec.shape(_EXAMPLE_SAMPLES, _EXAMPLE_BATCH, grid_hw)) for spec in model.masks]
    batch, samples = Dim("batch"), Dim("samples")
    names = [INPUT_NAME, *(mask_name(k) for k in range(len(masks)))]
    try:
        with _quiet_exporter(), torch.no_grad():
            program = torch.onnx.export(
                model,
                (dem, *masks),
                input_names=names,
                output_names=list(OUTPUT_NAMES),
                dynamic_shapes=({0: batch}, tuple({0: samples, 1: batch} for _ in masks)),
                dynamo=True,
                verbose=False,
            )
        if program is None:
            raise HdNetError("the ONNX exporter returned no program.")
        proto = program.model_proto
        onnx.checker.check_model(proto)
    except HdNetError:
        raise
    except Exception as exc:  # the exporter's and the checker's errors are of many kinds
        raise HdNetError(f"the ONNX export failed ({type(exc).__name__}: {str(exc).splitlines()[0]}).") from exc
    opset = next(int(o.version) for o in proto.opset_import if o.domain in ("", "ai.onnx"))
    return proto.SerializeToString(), opset


def _dem_shape(run: TrainedRun, settings: ExportModelSettings) -> tuple[int, int]:
    """Step 2: the DEM size (rows, cols) the graph takes: the settings', else the training DEMs'."""
    trained = run.data.dem_shape
    if trained is None and run.data.input.input_size is not None:
        trained = (run.data.input.input_size, run.data.input.input_size)
    rows = settings.rows if settings.rows is not None else (trained[0] if trained else None)
    cols = settings.cols if settings.cols is not None else (trained[1] if trained else None)
    if rows is None or cols is None:
        raise HdNetError(f"{run.checkpoint} does not record its DEM size: give --rows and --cols.")
    return rows, cols


def recorded_threshold(run_dir: Path, checkpoint_sha256: str) -> ModelThresholdJson:
    """H_t of this checkpoint as ``hd detect`` cached it in ``run_dir``'s ``thresholds.json``: the newest
    entry on the predictive entropy at the run's reference noise level, the default rule
    (``defaults.THRESHOLD_SPEC``) preferred; else no value and a note saying how to calibrate one."""
    entries = CachedThreshold(run_dir).entries_of(checkpoint_sha256) if (run_dir / CONFIG).is_file() else []
    usable = [e for e in entries if recorded_score(e[0]).name == ENTROPY.name and e[0].get("calibrate") == "reference"]
    usable.sort(key=lambda e: e[0].get("spec") == defaults.THRESHOLD_SPEC)  # stable: the newest last
    if not usable:
        return {
            "value_nats": None,
            "note": "no threshold is calibrated for this checkpoint: run `hd detect RUN --data DATASET --scan 0 "
            "--out DIR` (it caches H_t in RUN/thresholds.json) and export again, or calibrate H_t on the flight "
            "software's own validation DEMs",
        }
    key, value, info = usable[-1]
    return {
        "value_nats": None if value == float("inf") else value,
        "unbounded": value == float("inf"),
        "spec": str(key["spec"]),
        "uncertainty": ENTROPY.name,
        "calibration_sigma_m": float(key["sigma_m"]),
        "calibration_labels": str(key.get("labels", info.get("calibration_labels", ""))),
        "mc_samples": int(key["mc_samples"]),
        "source": str(run_dir / CACHE_FILE),
    }


def _input_record(run: TrainedRun, dem_shape: tuple[int, int], grid: tuple[int, int]) -> ModelInputJson:
    """Step 4: the ``dem`` input and how flight software makes it from a DEM."""
    spec = run.data.input
    return {
        "name": INPUT_NAME,
        "shape": ["batch", spec.n_channels, *grid],
        "dtype": "float32",
        "channels": [f"heights:{spec.heights}", *spec.extra_channels],
        "dem_shape": list(dem_shape),
        "grid": list(grid),
        "spacing_m": float(spec.spacing_m),
        "spec": spec.to_dict(),
        "sigma_channel_scale_m": SIGMA_CHANNEL_SCALE_M,
        "highpass_window_px": highpass_window_px(spec),
    }


def model_record(
    run: TrainedRun,
    model: MaskedSegNet,
    dem_shape: tuple[int, int],
    grid: tuple[int, int],
    onnx_name: str,
    onnx_sha256: str,
    opset: int,
    threshold: ModelThresholdJson,
) -> ModelJson:
    """Step 4: ``model.json`` of the graph ``onnx_name`` (its sha256 and opset) exported from ``run``."""
    p = model.config.dropout_p
    free: list[int | str] = ["samples", "batch"]
    masks: list[MaskJson] = [
        {
            "name": mask_name(k),
            "layer": spec.layer,
            "shape": [*free, spec.channels, grid[0] // spec.divisor, grid[1] // spec.divisor],
            "channels": spec.channels,
            "grid_divisor": spec.divisor,
        }
        for k, spec in enumerate(model.masks)
    ]
    outputs: list[TensorJson] = [
        {"name": name, "shape": [*free, model.config.n_classes, *grid], "dtype": "float32"} for name in OUTPUT_NAMES
    ]
    return {
        "schema": MODEL_SCHEMA,
        "schema_version": MODEL_SCHEMA_VERSION,
        "hd_version": __version__,
        "torch_version": torch.__version__,
        "format": "onnx",
        "onnx_file": onnx_name,
        "onnx_sha256": onnx_sha256,
        "opset": opset,
        "run": {
            "checkpoint": str(run.checkpoint.resolve()),
            "checkpoint_sha256": sha256_file(run.checkpoint),
            "epoch": run.header.epoch,
            "profile": run.header.profile,
            "model_config": run.header.model_config,
            "train_sigma_m": float(run.data.train_sigma_m),
        },
        "input": _input_record(run, dem_shape, grid),
        "masks": masks,
        "dropout_p": float(p),
        "mask_values": [0.0, keep_scale(p)],
        "outputs": outputs,
        "classes": list(CLASSES),
        "threshold": threshold,
    }


@dataclass(frozen=True)
class ExportedModel:
    """What :func:`export_onnx` wrote: the graph ``out`` and its side file ``sidecar``, and the record
    ``model`` (``model.json``'s content)."""

    out: Path
    sidecar: Path
    model: ModelJson

    def summary(self) -> str:
        """One line: the files, the grid, the masks and H_t."""
        m = self.model
        grid = "x".join(str(v) for v in m["input"]["grid"])
        h_t = m["threshold"].get("value_nats")
        said = "H_t not calibrated (see model.json)" if h_t is None else f"H_t {h_t:.4f} nats"
        return (
            f"wrote {self.out} (ONNX opset {m['opset']}, {grid} grid, {len(m['masks'])} dropout masks) and "
            f"{self.sidecar}; {said}"
        )


def export_onnx(
    run_dir: str | Path, out: str | Path, settings: ExportModelSettings | None = None, overwrite: bool = False
) -> ExportedModel:
    """Export the network of the run ``run_dir`` (its ``last.pt``; a checkpoint file is taken as it is)
    to the ONNX graph ``out`` and its side file ``model.json`` (module docstring); both are written
    atomically, together, after the graph has been made and checked.

    Raises:
        HdNetError: no run, an unfinished run, a DEM size unknown or out of range, onnx missing, a
            failed export; StorageError: ``out`` (or its side file) exists without ``overwrite``, or
            cannot be written. Nothing is written when any is raised.
    """
    settings = settings if settings is not None else ExportModelSettings()
    out = Path(out)
    checkpoint = check_run(run_dir)
    side = settings.check_outputs(out, overwrite)
    _require_onnx()
    run = TrainedRun.load(checkpoint, "cpu")
    if run.unfinished is not None:
        raise HdNetError(f"{run.unfinished}: finish its training before exporting it.")
    dem_shape = _dem_shape(run, settings)
    spec = run.data.input
    grid = network_shape(dem_shape, spec.input_size, max(spec.size_multiple, run.model.size_multiple))
    model = MaskedSegNet(run.model)
    data, opset = onnx_model_bytes(model, grid)
    threshold = recorded_threshold(checkpoint.parent, sha256_file(checkpoint))
    record = model_record(run, model, dem_shape, grid, out.name, sha256_bytes(data), opset, threshold)
    with atomic_path(out) as tmp_onnx, atomic_path(side) as tmp_side:
        tmp_onnx.write_bytes(data)
        tmp_side.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    return ExportedModel(out, side, record)
