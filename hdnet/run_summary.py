"""What a run directory holds (``hd inspect RUN``): profile, training data and noise, epochs, metrics.

Every file is checked first (``hdnet.run_check.check_run``: config.json's schema, each checkpoint's
content digest, metrics.csv against last.pt's history, the files against one another): a damaged or
forged run is one error, never a summary.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TypedDict

from hdnet.errors import HdNetError
from hdnet.fit import is_run_dir
from hdnet.report_json import recorded_noise
from hdnet.run_check import check_run
from hdnet.run_json import InputSpecJson, TrainingNoiseJson
from hdnet.run_record import CONFIG
from hdnet.train import LAST

__all__ = ["RunSummaryJson", "describe_run", "is_run_dir", "run_record"]


class RunSummaryJson(TypedDict):
    """``hd inspect RUN --json``: what :func:`run_record` says of a run."""

    run: str
    kind: str
    schema_version: int
    profile: str | None
    model: dict[str, float | int]
    epochs_planned: int
    epochs_done: int
    finished: bool
    checkpoints: list[str]
    dataset: str | None
    also: list[str]
    labels: str | None
    convention: str | None
    train_sigma_m: float | None
    train_noise: TrainingNoiseJson | None
    input: InputSpecJson | None
    last_epoch: dict[str, float] | None  # metrics.csv's last row
    best_epoch: dict[str, float] | None  # its row of the lowest validation loss
    writer_pid: int | None
    hd_version: str
    torch_version: str


def run_record(directory: str | os.PathLike) -> RunSummaryJson:
    """A JSON-ready description of the run at ``directory``, every file checked first.

    Raises:
        HdNetError: not a run, or a damaged, forged or inconsistent run file (``check_run``).
        StorageError: a run file that is not a regular file.
    """
    d = Path(directory)
    if not is_run_dir(d):
        raise HdNetError(f"{d} is not an hd run (no {CONFIG} or {LAST}).")
    run = check_run(d)
    record, data, rows = run.record, run.data, run.rows
    best = min(rows, key=lambda r: r.get("val_loss", float("inf"))) if rows else None
    return {
        "run": str(d.resolve()),
        "kind": "hd.run",
        "schema_version": record.file_version,
        "profile": record.profile_name,
        "model": record.model_config,
        "epochs_planned": record.epochs,
        "epochs_done": run.epochs_done,
        "finished": run.epochs_done >= record.epochs,
        "checkpoints": list(run.checkpoints),
        "dataset": None if data is None else data.dataset,
        "also": [] if data is None else [a.dataset for a in data.also],
        "labels": None if data is None else data.labels,
        "convention": None if data is None or data.labeling is None else data.labeling.convention,
        "train_sigma_m": None if data is None else data.train_sigma_m,
        "train_noise": None if data is None else data.train_noise.to_dict(),
        "input": None if data is None else data.input.to_dict(),
        "last_epoch": rows[-1] if rows else None,
        "best_epoch": best,
        "writer_pid": run.writer_pid,
        "hd_version": record.hd_version,
        "torch_version": record.torch_version,
    }


def _noise_text(record: RunSummaryJson) -> str:
    range_m, levels = recorded_noise(record["train_noise"])
    reference = record["train_sigma_m"]
    if range_m:
        lo, hi = range_m
        return f"{lo:g} to {hi:g} m, drawn per sample (reference {reference:g} m)"
    if not levels and reference is not None:  # a record without levels: its reference level
        levels = [reference]
    return ", ".join(f"{s:g} m" for s in levels)


def describe_run(directory: str | os.PathLike) -> str:
    """A multi-line summary of the run at ``directory`` (``hd inspect RUN``), every file checked first."""
    r = run_record(directory)
    lines = [
        f"run       {r['run']}",
        f"profile   {r['profile']} (model {json.dumps(r['model'])})",
        f"epochs    {r['epochs_done']} of {r['epochs_planned']} done"
        + ("" if r["finished"] else " (unfinished: `hd train ... --resume` continues it)"),
        f"data      {r['dataset']}" + "".join(f" + {a}" for a in r["also"]),
        f"labels    {r['labels']} ({r['convention']} convention)",
        f"noise     {_noise_text(r)}",
    ]
    spec = r["input"]
    extra = spec["extra_channels"] if spec is not None else []
    if extra:
        lines.append(f"inputs    heights + {', '.join(extra)}")
    for label, row in (("last", r["last_epoch"]), ("best", r["best_epoch"])):
        if row:
            lines.append(
                f"{label:<9} epoch {int(row['epoch'])}: val loss {_metric(row, 'val_loss')}, val PA "
                f"{_metric(row, 'val_pixel_accuracy')}, val mIoU {_metric(row, 'val_miou')}"
            )
    lines.append(f"files     {', '.join(r['checkpoints']) or 'no checkpoint yet'}")
    if r["writer_pid"] is not None:
        lines.append(f"status    a training is at work in this run (PID {r['writer_pid']})")
    return "\n".join(lines)


def _metric(row: dict[str, float], column: str) -> str:
    """A validation metric to four decimals; ``n/a`` in a metrics.csv of an hd that did not write it."""
    return f"{row[column]:.4f}" if column in row else "n/a"
