"""What a run directory holds (``hd inspect RUN``): profile, training data and noise, epochs, metrics.

Reads ``config.json`` (``hdnet.run_record``) and ``metrics.csv`` only (never the checkpoints' tensors), so it answers at
once and works on a run whose checkpoints are being written.
"""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path
from typing import Any

from hdnet.errors import HdNetError
from hdnet.fit import is_run_dir
from hdnet.run_record import CONFIG, TrainingData, read_run_record
from hdnet.train import BEST, LAST, METRICS
from lidarsim.storage import read_regular_text

__all__ = ["describe_run", "is_run_dir", "run_record"]


def _metrics(path: Path) -> list[dict[str, float]]:
    if not os.path.lexists(path):
        return []
    try:
        text = read_regular_text(path)
        return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(io.StringIO(text, newline=""))]
    except (OSError, ValueError, TypeError, csv.Error) as exc:
        raise HdNetError(f"{path}: unreadable metrics ({exc}).") from exc


def run_record(directory: str | os.PathLike) -> dict[str, Any]:
    """A JSON-ready description of the run at ``directory``.

    Raises:
        HdNetError: not a run, or an unreadable ``config.json``/``metrics.csv``.
    """
    d = Path(directory)
    if not is_run_dir(d):
        raise HdNetError(f"{d} is not an hd run (no {CONFIG} or {LAST}).")
    record = read_run_record(d)
    try:
        data: TrainingData | None = record.data
    except HdNetError:  # a run of hdnet.train alone records no training data
        data = None
    rows = _metrics(d / METRICS)
    best = min(rows, key=lambda r: r.get("val_loss", float("inf"))) if rows else None
    return {
        "run": str(d.resolve()),
        "kind": "hd.run",
        "schema_version": record.file_version,
        "profile": record.profile_name,
        "model": record.model_config,
        "epochs_planned": record.epochs,
        "epochs_done": len(rows),
        "finished": bool(rows) and len(rows) >= record.epochs,
        "checkpoints": [name for name in (LAST, BEST) if (d / name).is_file()],
        "dataset": None if data is None else data.dataset,
        "also": [] if data is None else [a.dataset for a in data.also],
        "labels": None if data is None else data.labels,
        "convention": None if data is None else (data.labeling or {}).get("convention"),
        "train_sigma_m": None if data is None else data.train_sigma_m,
        "train_noise": None if data is None else data.train_noise.to_dict(),
        "input": None if data is None else data.input.to_dict(),
        "last_epoch": rows[-1] if rows else None,
        "best_epoch": best,
        "hd_version": record.hd_version,
        "torch_version": record.torch_version,
    }


def _noise_text(record: dict[str, Any]) -> str:
    noise = record.get("train_noise") or {}
    if noise.get("kind") == "range":
        lo, hi = noise.get("range_m") or (None, None)
        return f"{lo:g} to {hi:g} m, drawn per sample (reference {record.get('train_sigma_m'):g} m)"
    levels = noise.get("levels_m") or [record.get("train_sigma_m")]
    return ", ".join(f"{s:g} m" for s in levels if s is not None)


def describe_run(directory: str | os.PathLike) -> str:
    """A multi-line summary of the run at ``directory`` (``hd inspect RUN``)."""
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
    extra = (r.get("input") or {}).get("extra_channels") or []
    if extra:
        lines.append(f"inputs    heights + {', '.join(extra)}")
    for label, row in (("last", r["last_epoch"]), ("best", r["best_epoch"])):
        if row:
            lines.append(
                f"{label:<9} epoch {int(row['epoch'])}: val loss {row['val_loss']:.4f}, val PA "
                f"{row['val_pixel_accuracy']:.4f}, val mIoU {row['val_miou']:.4f}"
            )
    lines.append(f"files     {', '.join(r['checkpoints']) or 'no checkpoint yet'}")
    return "\n".join(lines)
