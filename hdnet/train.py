"""Training loop for Bayesian SegNet: checkpoints every epoch, exact resume, metrics.csv, DDP.

Run directory layout (all written by rank 0, each file atomically: temporary name, then rename):

* ``config.json``: the run record (``hdnet.run_record.RunRecord``: profile, model config, seed,
  epochs, world size, versions, ``extra_config``, e.g. the training data of ``hdnet.fit``);
* ``last.pt``: checkpoint after the latest epoch; ``best.pt``: the epoch with the lowest validation loss;
* ``metrics.csv``: ``epoch, train_loss, val_loss, val_pixel_accuracy, val_miou, lr, train_images_per_s``
  (rewritten from the checkpoint's history each epoch, so it never holds an epoch the checkpoint
  does not). ``train_loss`` is the optimised objective (class-weighted with ``class_weighting =
  balanced``); ``val_loss`` is always the plain cross-entropy; ``lr`` is the rate of the epoch's
  first step; ``train_images_per_s`` counts training samples over the wall-clock time of the
  epoch's training steps (data loading included, validation excluded).

Checkpoints hold only tensors and plain Python types (schema ``hdnet.checkpoint`` version 2) and
are read with ``torch.load(weights_only=True)``: no code is ever unpickled. Version 2 adds
``content_sha256``, the SHA-256 of every tensor's bytes and every other value (``checkpoint_digest``),
checked on load: a damaged checkpoint is refused instead of silently used. Version 1 checkpoints
(no digest) are still read.

Kills: ``last.pt`` is the commit point of an epoch (written before ``best.pt`` and ``metrics.csv``);
resuming rewrites ``metrics.csv`` from the checkpoint's history and ``best.pt`` when the latest epoch
is the best one, so the three agree after a kill at any moment (docs/reliability.md).

Exact resume: shuffling is a pure function of (seed, epoch) (``DistributedSampler.set_epoch``, also
for one process), and the RNG states of torch (CPU and CUDA), NumPy and Python of every rank are
saved after each epoch and restored on resume; a run killed after epoch k and resumed ends with the
same weights as an uninterrupted one.

Distributed: under ``torchrun`` (``WORLD_SIZE`` > 1) the process group is initialised here (NCCL on
GPUs, gloo on CPU) unless it already is; each rank trains on its ``DistributedSampler`` shard with
``batch_size // world_size`` samples, so the global batch is the profile's. Losses are summed over
valid pixels across ranks. Validation runs with dropout off (deterministic network); with several
ranks ``DistributedSampler`` repeats up to world_size - 1 validation samples to even the shards.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import random
import sys
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final, cast

import numpy as np
import torch
import torch.distributed as dist
import torch.nn.functional as F
from torch import nn
from torch.utils.data import DataLoader, Dataset, DistributedSampler

from hdcore.errors import HdWarning
from hdcore.storage import write_bytes_atomic
from hdnet import defaults
from hdnet._version import __version__
from hdnet.checkpoint_json import CheckpointJson, EpochProgress, EpochRow, EpochTiming, JsonObject, RngState
from hdnet.errors import HdNetError
from hdnet.model import MODEL_NAME, BayesianSegNet, ModelConfig
from hdnet.profiles import TrainingProfile, profile_from_dict
from hdnet.run_files import BEST, LAST, METRICS  # and CONFIG, the run record (hdnet.run_record)
from hdnet.run_record import RunRecord, extra_difference, schedule_refusal, write_run_record

CHECKPOINT_SCHEMA = "hdnet.checkpoint"
CHECKPOINT_VERSION = 2
READABLE_CHECKPOINT_VERSIONS = (1, 2)  # 1: without content_sha256
DIGEST_KEY: Final = "content_sha256"


# --- process group ------------------------------------------------------------------------------
def _init_distributed() -> tuple[int, int, torch.device]:
    """(rank, world size, device); initialises the process group under torchrun when needed."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not dist.is_initialized():
        dist.init_process_group(backend="nccl" if torch.cuda.is_available() else "gloo")
    if dist.is_initialized():
        rank, world = dist.get_rank(), dist.get_world_size()
    else:
        rank, world = 0, 1
    if torch.cuda.is_available():
        local = int(os.environ.get("LOCAL_RANK", rank % max(1, torch.cuda.device_count())))
        torch.cuda.set_device(local)
        device = torch.device("cuda", local)
    else:
        device = torch.device("cpu")
    return rank, world, device


# --- RNG state as plain types ------------------------------------------------------------------
def _rng_state() -> RngState:
    np_state: Any = np.random.get_state()  # noqa: NPY002 - the global state, which a resumed run must restore
    py_version, py_state, py_gauss = random.getstate()
    return {
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state() if torch.cuda.is_available() else None,
        "numpy": {
            "name": np_state[0],
            "key": torch.from_numpy(np_state[1].astype(np.int64)),
            "pos": int(np_state[2]),
            "has_gauss": int(np_state[3]),
            "cached_gaussian": float(np_state[4]),
        },
        "python": {"version": py_version, "state": torch.tensor(py_state, dtype=torch.int64), "gauss_next": py_gauss},
    }


def _set_rng_state(state: RngState) -> None:
    torch.set_rng_state(state["torch"])
    cuda = state.get("cuda")
    if cuda is not None and torch.cuda.is_available():
        torch.cuda.set_rng_state(cuda)
    n = state["numpy"]
    legacy = (n["name"], n["key"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["cached_gaussian"])
    np.random.set_state(legacy)  # noqa: NPY002 - the global state, which a resumed run must restore
    p = state["python"]
    random.setstate((p["version"], tuple(int(v) for v in p["state"].tolist()), p["gauss_next"]))


def _seed_everything(seed: int) -> None:
    torch.manual_seed(seed)
    np.random.seed(seed % 2**32)  # noqa: NPY002 - the global state, for code that draws from it
    random.seed(seed)


# --- checkpoint I/O ----------------------------------------------------------------------------
def _hash_into(h: Any, obj: Any) -> None:
    if isinstance(obj, torch.Tensor):
        t = obj.detach().cpu().contiguous()
        h.update(f"T{t.dtype}{tuple(t.shape)};".encode())
        if t.numel():
            h.update(t.reshape(-1).view(torch.uint8).numpy())
    elif isinstance(obj, dict):
        h.update(f"D{len(obj)};".encode())
        for key in sorted(obj, key=repr):
            h.update(f"{key!r}=".encode())
            _hash_into(h, obj[key])
    elif isinstance(obj, (list, tuple)):
        h.update(f"L{len(obj)};".encode())
        for value in obj:
            _hash_into(h, value)
    else:
        h.update(f"S{obj!r};".encode())


def checkpoint_digest(checkpoint: Mapping[str, object]) -> str:
    """SHA-256 of a checkpoint's content: every tensor's dtype, shape and bytes and every other
    value, in a fixed order (``content_sha256`` itself left out)."""
    h = hashlib.sha256()
    _hash_into(h, {k: v for k, v in checkpoint.items() if k != DIGEST_KEY})
    return h.hexdigest()


def save_checkpoint(path: Path, checkpoint: CheckpointJson) -> None:
    """Write a checkpoint atomically (temporary file, fsync, rename) with its ``content_sha256``."""
    buf = io.BytesIO()
    torch.save({**checkpoint, DIGEST_KEY: checkpoint_digest(checkpoint)}, buf)
    write_bytes_atomic(Path(path), buf.getvalue())


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> CheckpointJson:
    """Read and validate a checkpoint (weights only); refuses other schemas, versions and models,
    and a content that does not match its ``content_sha256`` (a damaged file)."""
    path = Path(path)
    if not path.is_file():
        if path.exists():
            raise HdNetError(f"checkpoint {path} is not a regular file.")
        raise HdNetError(f"checkpoint {path} does not exist.")
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # unpickling errors of every kind: the file is not ours
        raise HdNetError(f"{path} is not a readable hdnet checkpoint ({type(exc).__name__}).") from exc
    if not isinstance(ckpt, dict) or ckpt.get("schema") != CHECKPOINT_SCHEMA:
        raise HdNetError(f"{path} is not an hdnet checkpoint (schema {CHECKPOINT_SCHEMA!r} missing).")
    if ckpt.get("schema_version") not in READABLE_CHECKPOINT_VERSIONS:
        raise HdNetError(
            f"{path} has checkpoint schema version {ckpt.get('schema_version')}, this hdnet reads "
            f"{', '.join(map(str, READABLE_CHECKPOINT_VERSIONS))}."
        )
    if int(ckpt["schema_version"]) < 2:
        warnings.warn(
            HdWarning(
                f"{path} is a schema-1 checkpoint without {DIGEST_KEY}: damage to its weights cannot be "
                "detected (checkpoints written by this hd carry the checksum)."
            ),
            stacklevel=2,
        )
    else:
        recorded = ckpt.get(DIGEST_KEY)
        if not isinstance(recorded, str):
            raise HdNetError(f"{path} lacks its {DIGEST_KEY}; the checkpoint is damaged.")
        try:
            actual = checkpoint_digest(ckpt)
        except Exception:  # noqa: BLE001 - a structure the digest cannot walk is damage too
            actual = ""
        if actual != recorded:
            raise HdNetError(
                f"{path}: checksum mismatch (content sha256 {actual[:12]}..., recorded "
                f"{recorded[:12]}...); the checkpoint is damaged."
            )
    if ckpt.get("model_name") != MODEL_NAME:
        raise HdNetError(f"{path} holds a {ckpt.get('model_name')!r} model, not {MODEL_NAME!r}.")
    return cast("CheckpointJson", ckpt)  # schema, version, digest and model checked; the rest by its readers


def load_trained_model(
    path: str | Path, map_location: str | torch.device = "cpu"
) -> tuple[BayesianSegNet, CheckpointJson]:
    """The model of a checkpoint (in eval mode) and the checkpoint dictionary (``extra_config`` etc.)."""
    ckpt = load_checkpoint(path, map_location)
    config = checked_model_config(ckpt, path)
    model = BayesianSegNet(config)
    model.load_state_dict(ckpt["model"])
    return model.to(map_location).eval(), ckpt


def checked_model_config(ckpt: CheckpointJson, path: str | Path) -> ModelConfig:
    """The checkpoint's ``ModelConfig``, checked against its own tensors before any model is built.

    The architecture is laid out on PyTorch's ``meta`` device (shapes only, no memory), so an absurd
    configuration costs nothing; every parameter and buffer of it must be in the checkpoint with the
    same shape, and the checkpoint must hold nothing else.

    Raises:
        HdNetError: an unreadable model config, a missing, unexpected or mis-shaped tensor (named).
    """
    raw: object = ckpt.get("model_config")
    if not isinstance(raw, dict):
        raise HdNetError(f"{path}: its model_config is not a dictionary.")
    try:
        config = ModelConfig(**raw)
    except TypeError as exc:
        raise HdNetError(f"{path}: its model_config does not describe a SegNet ({exc}).") from exc
    state = ckpt.get("model")
    if not isinstance(state, dict) or not all(isinstance(v, torch.Tensor) for v in state.values()):
        raise HdNetError(f"{path}: its model weights are not a dictionary of tensors.")
    with torch.device("meta"):
        expected = {k: tuple(v.shape) for k, v in BayesianSegNet(config).state_dict().items()}
    missing = [k for k in expected if k not in state]
    if missing:
        raise HdNetError(f"{path}: the weights lack {missing[0]!r} ({len(missing)} tensor(s) missing).")
    unexpected = [k for k in state if k not in expected]
    if unexpected:
        raise HdNetError(f"{path}: the weights hold {unexpected[0]!r}, which the model config does not have.")
    for key, shape in expected.items():
        if tuple(state[key].shape) != shape:
            raise HdNetError(
                f"{path}: {key!r} has shape {tuple(state[key].shape)}, the model config {config.to_dict()} "
                f"needs {shape}."
            )
    return config


# --- helpers ----------------------------------------------------------------------------------
METRIC_FIELDS = ("epoch", "train_loss", "val_loss", "val_pixel_accuracy", "val_miou", "lr", "train_images_per_s")


def _write_metrics_csv(path: Path, history: list[EpochRow], timing: list[EpochTiming]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(METRIC_FIELDS), lineterminator="\n", restval="")
    writer.writeheader()
    rates = {int(t["epoch"]): t for t in timing}
    for row in history:
        epoch = int(row["epoch"])
        full: dict[str, object] = {**row, **rates.get(epoch, {})}
        writer.writerow({k: (epoch if k == "epoch" else f"{v:.6g}") for k, v in full.items() if k in METRIC_FIELDS})
    write_bytes_atomic(path, buf.getvalue().encode())


def _best_epoch(history: list[EpochRow]) -> int:
    """Epoch (1-based) with the lowest validation loss, the first one on ties (as the loop keeps it); 0 if none."""
    best, best_loss = 0, math.inf
    for row in history:
        if row["val_loss"] < best_loss:
            best, best_loss = int(row["epoch"]), row["val_loss"]
    return best


def _reconcile_run(run_dir: Path, ckpt: CheckpointJson) -> None:
    """Make ``metrics.csv`` and ``best.pt`` agree with ``last.pt`` (after a kill between their writes)."""
    history = list(ckpt["history"])
    _write_metrics_csv(run_dir / METRICS, history, list(ckpt.get("timing", [])))
    best = _best_epoch(history)
    if best and best == int(ckpt["epoch"]):
        current = None
        if (run_dir / BEST).is_file():
            try:
                current = int(load_checkpoint(run_dir / BEST)["epoch"])
            except HdNetError:
                current = None
        if current != best:
            kept = ckpt.copy()
            kept.pop(DIGEST_KEY, None)  # save_checkpoint writes the digest of the rest
            save_checkpoint(run_dir / BEST, kept)


def median_images_per_s(timing: Sequence[EpochTiming]) -> float | None:
    """Median training throughput (images/s) over the epochs of a checkpoint's ``timing`` list."""
    rates = sorted(float(h["train_images_per_s"]) for h in timing if "train_images_per_s" in h)
    if not rates:
        return None
    mid = len(rates) // 2
    return rates[mid] if len(rates) % 2 else 0.5 * (rates[mid - 1] + rates[mid])


def _make_optimizer(model: nn.Module, profile: TrainingProfile) -> torch.optim.Optimizer:
    if profile.optimizer == "sgd":
        return torch.optim.SGD(model.parameters(), lr=profile.lr, momentum=profile.momentum)
    if profile.optimizer == "adam":
        return torch.optim.Adam(model.parameters(), lr=profile.lr)
    raise HdNetError(f"unknown optimizer {profile.optimizer!r} in profile {profile.name!r}; use 'sgd' or 'adam'.")


def _sum_loss(
    logits: torch.Tensor, mask: torch.Tensor, weight: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """(cross-entropy summed over valid pixels, its normaliser): the valid pixel count, or with class
    weights the sum of the weights of the valid pixels' classes."""
    loss = F.cross_entropy(logits, mask, weight=weight, ignore_index=defaults.IGNORE_INDEX, reduction="sum")
    valid = mask != defaults.IGNORE_INDEX
    if weight is None:
        return loss, valid.sum()
    return loss, weight[mask[valid]].sum()


def _val_counts(logits: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """[summed cross-entropy, valid pixels, then the 2x2 confusion matrix (truth-major) of argmax]."""
    loss, n_valid = _sum_loss(logits, mask)
    valid = mask != defaults.IGNORE_INDEX
    pred = logits.argmax(1)[valid]
    truth = mask[valid]
    confusion = torch.bincount(truth * defaults.N_CLASSES + pred, minlength=defaults.N_CLASSES**2)[
        : defaults.N_CLASSES**2
    ]
    return torch.cat([torch.stack([loss.double(), n_valid.double()]), confusion.double()])


def _accuracy_and_miou(confusion: torch.Tensor) -> tuple[float, float]:
    """Pixel accuracy and mean IoU (over classes with a non-empty union) of a 2x2 confusion matrix."""
    cm = confusion.view(defaults.N_CLASSES, defaults.N_CLASSES)
    total = float(cm.sum())
    tp = cm.diag()
    union = cm.sum(0) + cm.sum(1) - tp
    ious = [float(t / u) for t, u in zip(tp, union, strict=True) if u > 0]
    return (float(tp.sum()) / total if total else math.nan), (sum(ious) / len(ious) if ious else math.nan)


def class_weights_from_counts(counts: list[int] | tuple[int, ...]) -> list[float]:
    """Balanced class weights N / (K N_c) from per-class pixel counts (a class with no pixel gets 0)."""
    total = float(sum(counts))
    k = len(counts)
    return [total / (k * c) if c > 0 else 0.0 for c in counts]


def dataset_class_counts(ds: Dataset) -> list[int]:
    """Pixels of each class (0 unsafe, 1 safe) over the masks of a dataset (255 not counted)."""
    counts = torch.zeros(defaults.N_CLASSES, dtype=torch.int64)
    for i in range(len(ds)):  # type: ignore[arg-type]  # map-style datasets have a length
        mask = ds[i]["mask"]
        counts += torch.bincount(mask[mask != defaults.IGNORE_INDEX].flatten(), minlength=defaults.N_CLASSES)[
            : defaults.N_CLASSES
        ]
    return [int(c) for c in counts]


def _all_reduce(values: torch.Tensor) -> torch.Tensor:
    if dist.is_initialized():
        dist.all_reduce(values)
    return values


def _check_sample(ds: Dataset, name: str) -> int:
    try:
        sample = ds[0]
    except Exception as exc:  # a user's dataset may fail in any way; named in the message
        raise HdNetError(f"the {name} dataset cannot give its first sample ({exc}).") from exc
    if not isinstance(sample, dict) or "image" not in sample or "mask" not in sample:
        raise HdNetError(f"the {name} dataset must yield dicts with 'image' and 'mask'.")
    image, mask = sample["image"], sample["mask"]
    if image.dim() != 3 or mask.dim() != 2 or image.shape[-2:] != mask.shape:
        raise HdNetError(
            f"the {name} dataset must yield image (C, H, W) and mask (H, W), "
            f"got {tuple(image.shape)} and {tuple(mask.shape)}."
        )
    return int(image.shape[0])


def _json_plain(obj: Mapping[str, object], what: str) -> JsonObject:
    try:
        return json.loads(json.dumps(obj))
    except (TypeError, ValueError) as exc:
        raise HdNetError(f"{what} must hold only JSON types (numbers, strings, lists, dicts).") from exc


# --- the loop ---------------------------------------------------------------------------------
def train(
    run_dir: str | Path,
    train_ds: Dataset,
    val_ds: Dataset,
    profile: TrainingProfile,
    epochs: int | None = None,
    seed: int = 0,
    resume: bool = False,
    progress: EpochProgress = True,
    extra_config: Mapping[str, object] | None = None,
    num_workers: int = 0,
    class_weights: list[float] | None = None,
    stop_after: int | None = None,
) -> Path:
    """Train to ``epochs`` (default: the profile's) epochs in total; returns the path of ``last.pt``.

    ``train_ds``/``val_ds`` yield ``{"image": float32 (C, H, W), "mask": int64 (H, W)}`` (0 unsafe, 1 safe,
    255 ignored). ``resume=True`` continues from ``run_dir/last.pt`` (from scratch if there is none)
    when it was trained with the same model, profile and ``extra_config`` (the same data: the run
    record is never rewritten to name other data); without it an existing checkpoint in ``run_dir``
    is an error. ``extra_config`` (JSON types) is
    stored in config.json and in every checkpoint. ``class_weights`` (one per class) are used with
    ``profile.class_weighting == "balanced"``; without them they are counted from ``train_ds``.
    ``stop_after`` ends this call after that many completed epochs while the learning-rate schedule
    still spans ``epochs`` (a run split over several calls; ``resume=True`` continues it exactly).
    ``progress``: a progress bar (True), none (False), or a callable given each finished epoch's
    metrics row and the total number of epochs (e.g. one log line per epoch). With either, a resumed
    run first writes one line to standard error: where it resumes (:func:`resume_line`).
    """
    total_epochs = profile.epochs if epochs is None else int(epochs)
    extra, in_channels = _check_inputs(train_ds, val_ds, total_epochs, num_workers, extra_config)
    run_dir = Path(run_dir)
    rank, world, device = _init_distributed()
    model_config = profile.model_config(in_channels)
    class_weights = _class_weights(profile, class_weights, train_ds, model_config.n_classes)
    last = run_dir / LAST
    ckpt = _checkpoint_to_resume(run_dir, resume, model_config, profile, rank, extra, (seed, total_epochs))
    state = _start(profile, model_config, ckpt, class_weights, seed, rank, device, last)
    net: nn.Module = state.model
    if world > 1:
        net = nn.parallel.DistributedDataParallel(
            state.model, device_ids=[device.index] if device.type == "cuda" else None
        )
    train_loader, val_loader = _loaders(train_ds, val_ds, profile, world, rank, seed, num_workers, device)
    if rank == 0:
        run_dir.mkdir(parents=True, exist_ok=True)
        weights = None if state.weight is None or class_weights is None else [float(w) for w in class_weights]
        write_run_record(run_dir, _run_record(model_config, profile, total_epochs, seed, world, extra, weights))

    bar = None
    report = progress if callable(progress) and rank == 0 else None
    end_epoch = total_epochs if stop_after is None else max(state.start_epoch, min(total_epochs, int(stop_after)))
    if progress is not False and rank == 0 and 0 < state.start_epoch < end_epoch:
        print(resume_line(state.start_epoch, total_epochs, last), file=sys.stderr, flush=True)
    if progress is True and rank == 0:
        from tqdm.auto import tqdm

        bar = tqdm(total=total_epochs, initial=state.start_epoch, desc=f"train {profile.name}", unit="epoch")
    for epoch in range(state.start_epoch, end_epoch):
        train_loss, seconds, rate = _train_epoch(net, train_loader, state, profile, epoch, total_epochs, device)
        val_loss, accuracy, miou = _validate(net, val_loader, state.memory_format, device)
        row: EpochRow = {
            "epoch": epoch + 1,
            "train_loss": train_loss,
            "val_loss": val_loss,
            "val_pixel_accuracy": accuracy,
            "val_miou": miou,
            "lr": profile.learning_rate(epoch, total_epochs),
        }
        state.timing.append({"epoch": epoch + 1, "train_seconds": seconds, "train_images_per_s": rate})
        state.history.append(row)
        _save_epoch(run_dir, state, model_config, profile, epoch, seed, extra, world, rank)
        _show_epoch(bar, report, row, state.timing[-1]["train_images_per_s"], total_epochs)
        if world > 1:
            dist.barrier()
    if bar is not None:
        bar.close()
    return last


def _run_record(
    model_config: ModelConfig,
    profile: TrainingProfile,
    total_epochs: int,
    seed: int,
    world: int,
    extra: JsonObject,
    class_weights: list[float] | None,
) -> RunRecord:
    """Step 1 of ``train``: the run record (``config.json``) of this training."""
    return RunRecord(
        model_name=MODEL_NAME,
        model_config=model_config.to_dict(),
        profile=profile.to_dict(),
        epochs=total_epochs,
        seed=seed,
        world_size=world,
        hd_version=__version__,
        torch_version=torch.__version__,
        extra_config=extra,
        class_weights=class_weights,
    )


def _show_epoch(
    bar: Any,
    report: Callable[[EpochRow, int], None] | None,
    row: EpochRow,
    images_per_s: float,
    total_epochs: int,
) -> None:
    """Step 2 of ``train``, after each epoch: the progress bar moved on with the epoch's losses, or
    ``report`` given the epoch's metrics row (with its training speed, images/s)."""
    if bar is not None:
        bar.update(1)
        bar.set_postfix(
            train_loss=f"{row['train_loss']:.4f}",
            val_loss=f"{row['val_loss']:.4f}",
            val_acc=f"{row['val_pixel_accuracy']:.3f}",
            val_miou=f"{row['val_miou']:.3f}",
            img_s=f"{images_per_s:.1f}",
        )
    if report is not None:
        report({**row, "train_images_per_s": images_per_s}, total_epochs)


def resume_line(epochs_done: int, total_epochs: int, checkpoint: Path) -> str:
    """What a resumed training says before its first epoch (``hd train --resume``, a re-run ``hd demo``)."""
    return f"train: resuming at epoch {epochs_done + 1} of {total_epochs} ({epochs_done} done, from {checkpoint})"


def _check_inputs(
    train_ds: Dataset, val_ds: Dataset, total_epochs: int, num_workers: int, extra_config: Mapping[str, object] | None
) -> tuple[JsonObject, int]:
    """Step 1: the arguments and the datasets' first samples; returns the plain ``extra_config`` and
    the number of input channels."""
    if total_epochs < 1:
        raise HdNetError(f"epochs must be >= 1, got {total_epochs}.")
    if isinstance(num_workers, bool) or not isinstance(num_workers, int) or num_workers < 0:
        raise HdNetError(f"the number of DataLoader workers must be an integer >= 0, got {num_workers!r}.")
    if len(train_ds) == 0 or len(val_ds) == 0:  # type: ignore[arg-type]  # map-style datasets have a length
        raise HdNetError("the training and validation datasets must not be empty.")
    extra = _json_plain(dict(extra_config or {}), "extra_config")
    in_channels = _check_sample(train_ds, "training")
    _check_sample(val_ds, "validation")
    return extra, in_channels


def _class_weights(
    profile: TrainingProfile, class_weights: list[float] | None, train_ds: Dataset, n_classes: int
) -> list[float] | None:
    """Step 2: the loss's class weights with ``balanced`` weighting (given, or counted from ``train_ds``)."""
    if profile.class_weighting != "balanced":
        return class_weights
    if class_weights is None:
        class_weights = class_weights_from_counts(dataset_class_counts(train_ds))
    if len(class_weights) != n_classes or not all(w >= 0 for w in class_weights):
        raise HdNetError(f"class weights must be {n_classes} numbers >= 0, got {class_weights!r}.")
    return class_weights


def _checkpoint_to_resume(
    run_dir: Path,
    resume: bool,
    model_config: ModelConfig,
    profile: TrainingProfile,
    rank: int,
    extra: JsonObject,
    schedule: tuple[int, int],
) -> CheckpointJson | None:
    """Step 3: the run's ``last.pt`` when resuming (None when there is none); refused without ``resume``,
    when it was trained with another model or profile, when its ``extra_config`` (the data it was
    trained on) is not ``extra`` (the run record written next would say it was trained on them), or
    with another seed or total of epochs than ``schedule`` (``hdnet.run_record.schedule_refusal``)."""
    last = run_dir / LAST
    if not last.exists():
        return None
    if not resume:
        raise HdNetError(f"{run_dir} already holds a checkpoint; resume it or choose another run directory.")
    ckpt = load_checkpoint(last)
    saved = ckpt.get("profile")
    try:
        same_profile = isinstance(saved, dict) and profile_from_dict(saved) == profile
    except HdNetError:
        same_profile = False
    if checked_model_config(ckpt, last) != model_config or not same_profile:
        name = saved.get("name") if isinstance(saved, dict) else None
        raise HdNetError(f"checkpoint {last} was trained with another model or profile ({name!r}).")
    difference = extra_difference(ckpt.get("extra_config") or {}, extra)
    if difference is not None:
        raise HdNetError(difference.resume_refusal(run_dir))
    _check_training_state(ckpt, last)
    refusal = schedule_refusal(run_dir, ckpt.get("seed"), int(ckpt["epoch"]), profile.extendable, schedule)
    if refusal is not None:
        raise HdNetError(refusal)
    if rank == 0:
        _reconcile_run(run_dir, ckpt)
    return ckpt


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _check_training_state(ckpt: CheckpointJson, path: Path) -> None:
    """The training state of a checkpoint to resume, as this hd writes it: the epoch, the history and
    timing rows (numbers), the optimizer state and the RNG states (the weights are checked apart).

    Raises:
        HdNetError: naming the checkpoint and the first faulty value.
    """
    epoch = ckpt.get("epoch")
    problem = None
    if isinstance(epoch, bool) or not isinstance(epoch, int) or epoch < 0:
        problem = f"its epoch {epoch!r} is not a count of epochs"
    for key in ("history", "timing"):
        rows = ckpt.get(key, [])
        if problem is None and not (
            isinstance(rows, list)
            and all(isinstance(r, dict) and all(_is_number(v) for v in r.values()) for r in rows)
            and all(isinstance(r.get("epoch"), int) and not isinstance(r.get("epoch"), bool) for r in rows)
            and (key != "history" or all(_is_number(r.get("val_loss")) for r in rows))
        ):
            problem = f"its {key} is not a list of rows of numbers by epoch"
    if problem is None and not isinstance(ckpt.get("optimizer"), dict):
        problem = "its optimizer state is not a dictionary"
    rng = ckpt.get("rng")
    if problem is None and not (isinstance(rng, list) and rng and all(isinstance(r, dict) for r in rng)):
        problem = "its RNG states are not a list of dictionaries"
    if problem is not None:
        raise HdNetError(f"{path}: cannot resume from it: {problem}; the checkpoint is damaged.")


@dataclass
class _TrainState:
    """What the epochs change: the model, its optimizer, the history and the best validation loss so far."""

    model: BayesianSegNet
    optimizer: torch.optim.Optimizer
    weight: torch.Tensor | None
    memory_format: torch.memory_format
    start_epoch: int = 0
    history: list[EpochRow] = field(default_factory=list)
    timing: list[EpochTiming] = field(default_factory=list)  # wall-clock figures, apart from the history
    best_loss: float = math.inf


def _start(
    profile: TrainingProfile,
    model_config: ModelConfig,
    ckpt: CheckpointJson | None,
    class_weights: list[float] | None,
    seed: int,
    rank: int,
    device: torch.device,
    source: Path | None = None,
) -> _TrainState:
    """Step 4: seeded initialisation, or the state of ``ckpt`` (model, optimizer, history, RNG states),
    read from the checkpoint file ``source``."""
    _seed_everything(seed + rank)
    model = BayesianSegNet(model_config).to(device)
    memory_format = torch.channels_last if profile.channels_last else torch.contiguous_format
    model = model.to(memory_format=memory_format)  # type: ignore[call-overload]  # the stubs omit memory_format
    for module in model.dropout_modules():
        module.fast_masks = profile.fast_dropout
    weight = None
    if class_weights is not None and profile.class_weighting == "balanced":
        weight = torch.tensor(class_weights, dtype=torch.float32, device=device)
    state = _TrainState(model, _make_optimizer(model, profile), weight, memory_format)
    if ckpt is not None:
        model.load_state_dict(ckpt["model"])  # keys and shapes checked by _checkpoint_to_resume
        state.start_epoch, state.history = int(ckpt["epoch"]), list(ckpt["history"])
        state.timing = list(ckpt.get("timing", []))
        state.best_loss = min((h["val_loss"] for h in state.history), default=math.inf)
        states = ckpt["rng"]
        try:  # the structures inside the optimizer and RNG states are PyTorch's, NumPy's and Python's own
            state.optimizer.load_state_dict(ckpt["optimizer"])
            _check_optimizer_state(state.optimizer)
            _set_rng_state(states[rank] if rank < len(states) else states[0])
        except (KeyError, IndexError, TypeError, ValueError, RuntimeError, AttributeError) as exc:
            raise HdNetError(
                f"{source}: cannot resume from it: its optimizer or RNG state cannot be restored "
                f"({type(exc).__name__}: {_first_line(exc)}); the checkpoint is damaged."
            ) from exc
    return state


def _check_optimizer_state(optimizer: torch.optim.Optimizer) -> None:
    """Every restored per-parameter state holds the same entries as the others, each a tensor of its
    parameter's shape but for the step count (``load_state_dict`` takes any value; a wrong or missing
    one failed later inside ``step``)."""
    keys = {frozenset(values) for values in optimizer.state.values()}
    if len(keys) > 1:
        raise ValueError(f"the optimizer's per-parameter states differ in their entries ({sorted(map(sorted, keys))})")
    for param, values in optimizer.state.items():
        for key, value in values.items():
            if not isinstance(value, torch.Tensor) or (key != "step" and value.shape != param.shape):
                raise ValueError(f"the optimizer's {key!r} of a {tuple(param.shape)} parameter is not such a tensor")


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:200] if text else ""


def _loaders(
    train_ds: Dataset,
    val_ds: Dataset,
    profile: TrainingProfile,
    world: int,
    rank: int,
    seed: int,
    num_workers: int,
    device: torch.device,
) -> tuple[DataLoader, DataLoader]:
    """Step 5: the training loader (shuffled per epoch from ``seed``) and the validation loader, one share per rank."""
    per_rank_batch = max(1, profile.batch_size // world)
    train_sampler: DistributedSampler[Any] = DistributedSampler(
        train_ds, num_replicas=world, rank=rank, shuffle=True, seed=seed
    )
    val_sampler: DistributedSampler[Any] = DistributedSampler(val_ds, num_replicas=world, rank=rank, shuffle=False)
    pin = device.type == "cuda"
    train_loader = DataLoader(
        train_ds, batch_size=per_rank_batch, sampler=train_sampler, num_workers=num_workers, pin_memory=pin
    )
    val_loader = DataLoader(
        val_ds, batch_size=per_rank_batch, sampler=val_sampler, num_workers=num_workers, pin_memory=pin
    )
    return train_loader, val_loader


def _train_epoch(
    net: nn.Module,
    loader: DataLoader,
    state: _TrainState,
    profile: TrainingProfile,
    epoch: int,
    total_epochs: int,
    device: torch.device,
) -> tuple[float, float, float]:
    """Step 6: one epoch of optimisation, the learning rate set per batch; returns the mean training
    loss, the seconds taken and the images per second (summed over ranks)."""
    sampler = loader.sampler
    if isinstance(sampler, DistributedSampler):
        sampler.set_epoch(epoch)
    set_epoch = getattr(loader.dataset, "set_epoch", None)
    if callable(set_epoch):  # datasets that draw per epoch (noise levels, realisations) key their draws on it
        set_epoch(epoch)
    net.train()
    optimizer, memory_format = state.optimizer, state.memory_format
    n_batches = max(1, len(loader))
    sums = torch.zeros(2, dtype=torch.float64, device=device)  # objective sum, its normaliser
    t0, seen = time.perf_counter(), 0
    for b, batch in enumerate(loader):
        for group in optimizer.param_groups:
            group["lr"] = profile.learning_rate(epoch + b / n_batches, total_epochs)
        x = batch["image"].to(device, non_blocking=True).contiguous(memory_format=memory_format)
        y = batch["mask"].to(device, non_blocking=True).long()
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=profile.precision == "bfloat16"):
            logits = net(x)
        loss_sum, norm = _sum_loss(logits.float(), y, state.weight)
        optimizer.zero_grad(set_to_none=True)
        (loss_sum / norm.clamp(min=1e-12)).backward()
        optimizer.step()
        sums[0] += loss_sum.detach().double()
        sums[1] += norm.double()
        seen += int(x.shape[0])
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    seconds = time.perf_counter() - t0
    train_sums = _all_reduce(sums)
    rate = _all_reduce(torch.tensor([seen / max(seconds, 1e-9)], dtype=torch.float64, device=device))
    return float(train_sums[0] / train_sums[1].clamp(min=1e-12)), seconds, float(rate[0])


def _validate(
    net: nn.Module, loader: DataLoader, memory_format: torch.memory_format, device: torch.device
) -> tuple[float, float, float]:
    """Step 7: the validation loss, pixel accuracy and mIoU (one confusion matrix over the split)."""
    net.eval()
    vsums = torch.zeros(2 + defaults.N_CLASSES**2, dtype=torch.float64, device=device)
    with torch.no_grad():
        for batch in loader:
            x = batch["image"].to(device).contiguous(memory_format=memory_format)
            vsums += _val_counts(net(x), batch["mask"].to(device).long())
    vsums = _all_reduce(vsums)
    accuracy, miou = _accuracy_and_miou(vsums[2:].cpu())
    return float(vsums[0] / vsums[1].clamp(min=1)), accuracy, miou


def _save_epoch(
    run_dir: Path,
    state: _TrainState,
    model_config: ModelConfig,
    profile: TrainingProfile,
    epoch: int,
    seed: int,
    extra: JsonObject,
    world: int,
    rank: int,
) -> None:
    """Step 8: ``last.pt`` (and ``best.pt`` when the validation loss improved) with every rank's RNG
    state, and ``metrics.csv``; written by rank 0."""
    states = [_rng_state()]
    if world > 1:
        gathered: list[Any] = [None] * world
        dist.all_gather_object(gathered, states[0])
        states = gathered
    if rank != 0:
        return
    ckpt_out: CheckpointJson = {
        "schema": CHECKPOINT_SCHEMA,
        "schema_version": CHECKPOINT_VERSION,
        "model_name": MODEL_NAME,
        "model_config": model_config.to_dict(),
        "profile": profile.to_dict(),
        "epoch": epoch + 1,
        "seed": seed,
        "model": {k: v.detach().cpu() for k, v in state.model.state_dict().items()},
        "optimizer": state.optimizer.state_dict(),
        "rng": states,
        "history": state.history,
        "timing": state.timing,
        "extra_config": extra,
        "hd_version": __version__,
    }
    save_checkpoint(run_dir / LAST, ckpt_out)
    val_loss = state.history[-1]["val_loss"]
    if val_loss < state.best_loss:
        state.best_loss = val_loss
        save_checkpoint(run_dir / BEST, ckpt_out)
    _write_metrics_csv(run_dir / METRICS, state.history, state.timing)
