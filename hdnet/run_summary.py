"""What a run directory holds (``hd inspect RUN``): profile, training data and noise, epochs, metrics.

Reads ``config.json`` and ``metrics.csv`` only (never the checkpoints' tensors), so it answers at
once and works on a run whose checkpoints are being written.
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path
from typing import Any

from hdnet.errors import HdNetError
from hdnet.fit import is_run_dir
from hdnet.train import BEST, CONFIG, LAST, METRICS

__all__ = ["describe_run", "is_run_dir", "run_record"]


def _metrics(path: Path) -> list[dict[str, float]]:
    if not path.is_file():
        return []
    try:
        with path.open(newline="") as f:
            return [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]
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
    try:
        config = json.loads((d / CONFIG).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise HdNetError(f"{d / CONFIG}: unreadable run config ({exc}).") from exc
    if not isinstance(config, dict):
        raise HdNetError(f"{d / CONFIG}: not a JSON object.")
    extra = config.get("extra_config") or {}
    profile = config.get("profile") or {}
    rows = _metrics(d / METRICS)
    best = min(rows, key=lambda r: r.get("val_loss", float("inf"))) if rows else None
    return {
        "run": str(d.resolve()),
        "kind": "hd.run",
        "schema_version": config.get("schema_version"),
        "profile": profile.get("name"),
        "model": config.get("model_config"),
        "epochs_planned": config.get("epochs"),
        "epochs_done": len(rows),
        "finished": bool(rows) and len(rows) >= int(config.get("epochs") or 0),
        "checkpoints": [name for name in (LAST, BEST) if (d / name).is_file()],
        "dataset": extra.get("dataset"),
        "also": [e.get("dataset") for e in extra.get("also", []) if isinstance(e, dict)],
        "labels": extra.get("labels"),
        "convention": (extra.get("labeling") or {}).get("convention"),
        "train_sigma_m": extra.get("train_sigma_m"),
        "train_noise": extra.get("train_noise"),
        "input": extra.get("input"),
        "last_epoch": rows[-1] if rows else None,
        "best_epoch": best,
        "hd_version": config.get("hd_version"),
        "torch_version": config.get("torch_version"),
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
