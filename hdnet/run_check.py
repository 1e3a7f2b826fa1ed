"""Is a run directory what it says? Its files read and checked against one another (``hd inspect RUN``).

:func:`check_run` reads every file of a run and checks, before anything about the run is reported:

* each run file present is a regular file (a FIFO in its place is refused, never opened);
* ``config.json`` is a run record of a schema this hd reads (``hdnet.run_record.read_run_record``)
  whose training data, when it records them, are readable (``TrainingData``);
* each checkpoint present (``last.pt``, ``best.pt``) is an hdnet checkpoint whose content matches
  its ``content_sha256`` (``hdnet.train.load_checkpoint``), whose weights are those of its model
  config (``checked_model_config``: shapes on PyTorch's ``meta`` device), whose history holds one
  row of numbers per epoch, and which was trained with config.json's model, profile and data
  (``hdnet.run_record.extra_difference``); ``best.pt`` is an epoch of ``last.pt``'s run (its history
  the beginning of last.pt's);
* ``metrics.csv`` parses (a header of known columns with ``epoch`` and ``val_loss``, then numbers)
  and is ``last.pt``'s history epoch by epoch, as ``hdnet.train`` writes it (six significant
  digits); while a training holds the run's writer lock it may be one epoch apart from last.pt (the
  two are written one after the other);
* neither metrics rows nor ``best.pt`` without ``last.pt``.

Each failure is one :class:`~hdnet.errors.HdNetError` (a ``StorageError`` for a file that is not a
regular file) naming the file, what is wrong with it and what to do. The checkpoints are read whole
(their digest covers every byte of their tensors).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hdcore.errors import StorageError
from hdcore.storage import check_regular_file, lock_holder, read_regular_text
from hdnet.checkpoint_json import CheckpointJson
from hdnet.errors import HdNetError
from hdnet.run_record import CONFIG, RunRecord, TrainingData, extra_difference, json_difference, read_run_record
from hdnet.train import BEST, LAST, METRIC_FIELDS, METRICS, checked_model_config, load_checkpoint

__all__ = ["RUN_FILES", "CheckedRun", "check_run"]

RUN_FILES = (LAST, BEST, METRICS, CONFIG)
# What to do about each kind of damage (the end of the error line).
REWRITE = "re-run the run's `hd train` command with --resume: it writes it again from last.pt"
RESTORE = "restore the run from a copy, or train it again (`hd train ... --overwrite`)"
MOVE_AWAY = {
    CONFIG: f"move it away, then {REWRITE}",
    METRICS: f"move it away, then {REWRITE}",
    LAST: f"move it away and {RESTORE}",
    BEST: f"move it away and {RESTORE}",
}


@dataclass(frozen=True)
class CheckedRun:
    """A run directory whose files agree (:func:`check_run`).

    ``rows``: metrics.csv's rows (column -> number); ``epochs_done``: last.pt's epoch (0 without a
    checkpoint); ``checkpoints``: the checkpoints present, last.pt first; ``writer_pid``: the process
    training in the run now, if any; ``data``: the training data of a run of ``hdnet.fit`` (None for
    a run of ``hdnet.train.train`` alone).
    """

    record: RunRecord
    data: TrainingData | None
    rows: list[dict[str, float]]
    epochs_done: int
    checkpoints: tuple[str, ...]
    writer_pid: int | None


def check_run(directory: str | os.PathLike) -> CheckedRun:
    """Read the run at ``directory`` and check its files against one another (module docstring).

    Raises:
        HdNetError: a damaged, forged or missing run file, or run files that disagree; the message
            names the file, what is wrong and what to do.
        StorageError: a run file that is not a regular file.
    """
    d = Path(directory)
    for name in RUN_FILES:
        if os.path.lexists(d / name):
            try:
                check_regular_file(d / name)
            except StorageError as exc:
                raise type(exc)(f"{exc}; {MOVE_AWAY[name]}") from exc
    record, data = _read_record(d / CONFIG)
    rows = _read_metrics(d / METRICS)
    writer = lock_holder(d)
    last = _read_checkpoint(d / LAST, record) if (d / LAST).exists() else None
    best = _read_checkpoint(d / BEST, record) if (d / BEST).exists() else None
    if last is None:
        if rows or best is not None:
            held = f"{len(rows)} epoch(s) in {METRICS}" if rows else BEST
            raise HdNetError(f"{d / LAST} is missing, but the run holds {held}; {RESTORE}.")
        return CheckedRun(record, data, rows, 0, (), writer)
    _check_metrics(d / METRICS, rows, last, in_progress=writer is not None)
    if best is not None and (
        best["epoch"] > last["epoch"] or _plain(best["history"]) != _plain(last["history"][: best["epoch"]])
    ):
        raise HdNetError(f"{d / BEST} is not an epoch of the run {d / LAST} holds (its history differs); {RESTORE}.")
    names = (LAST,) + ((BEST,) if best is not None else ())
    return CheckedRun(record, data, rows, int(last["epoch"]), names, writer)


def _read_record(path: Path) -> tuple[RunRecord, TrainingData | None]:
    """Step 1: config.json and its training data (None for a run that records none)."""
    try:
        record = read_run_record(path.parent)
    except HdNetError as exc:
        raise HdNetError(f"{str(exc).rstrip('.')}; {REWRITE}.") from exc
    extra = record.extra_config
    if not extra or not ({"train_sigma_m", "input"} & set(extra)):
        return record, None  # hdnet.train.train alone: any JSON, no training data
    try:
        return record, TrainingData.from_dict(extra, "its training data")
    except HdNetError as exc:
        raise HdNetError(f"{path}: unreadable run record ({str(exc).rstrip('.')}); {REWRITE}.") from exc


def _read_metrics(path: Path) -> list[dict[str, float]]:
    """Step 2: metrics.csv's rows, every value a number (none when there is no file yet)."""
    if not os.path.lexists(path):
        return []
    problem = None
    try:
        reader = csv.DictReader(io.StringIO(read_regular_text(path), newline=""))
        columns = list(reader.fieldnames or [])
        unknown = [c for c in columns if c not in METRIC_FIELDS]
        if unknown or "epoch" not in columns or "val_loss" not in columns or len(set(columns)) != len(columns):
            problem = f"its header {','.join(columns)!r} is not hd's ({','.join(METRIC_FIELDS)})"
            rows: list[dict[str, float]] = []
        else:
            rows = [{k: _number(v) for k, v in row.items()} for row in reader]
            if any(not math.isfinite(r["epoch"]) or r["epoch"] != int(r["epoch"]) for r in rows):
                problem = "an epoch that is not a whole number"
    except (StorageError, ValueError, TypeError, csv.Error) as exc:
        problem = str(exc)
    if problem is not None:
        raise HdNetError(f"{path}: unreadable metrics ({problem}); {REWRITE}.")
    return rows


def _number(text: Any) -> float:
    if not isinstance(text, str):  # a row of more or fewer values than the header
        raise ValueError("a row whose values do not match the header")
    return float(text)


def _read_checkpoint(path: Path, record: RunRecord) -> CheckpointJson:
    """Step 3: a checkpoint, its content checked, trained with config.json's model, profile and data."""
    try:
        ckpt = load_checkpoint(path)
        checked_model_config(ckpt, path)
    except HdNetError as exc:
        raise HdNetError(f"{str(exc).rstrip('.')}; {RESTORE}.") from exc
    epoch, history = ckpt.get("epoch"), ckpt.get("history")
    if not (
        isinstance(epoch, int)
        and not isinstance(epoch, bool)
        and isinstance(history, list)
        and len(history) == epoch
        and all(isinstance(r, dict) and all(_is_number(v) for v in r.values()) for r in history)
        and [r.get("epoch") for r in history] == list(range(1, epoch + 1))
    ):
        raise HdNetError(
            f"{path}: its epoch {epoch!r} is not the number of rows of its history (one per epoch); {RESTORE}."
        )
    config = path.parent / CONFIG
    for difference in (
        json_difference(record.model_config, ckpt.get("model_config"), "model"),
        json_difference(record.profile, ckpt.get("profile"), "profile"),
        extra_difference(record.extra_config, ckpt.get("extra_config") or {}),
    ):
        if difference is not None:
            raise HdNetError(
                f"{config} and {path} disagree on the {difference.what}: {difference.recorded} in {CONFIG}, "
                f"{difference.given} in {path.name}; a file of the run was changed after training: {RESTORE}."
            )
    return ckpt


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _plain(value: Any) -> str:
    """A value as JSON text (NaN equal to NaN, tuples to lists), for comparisons."""
    return json.dumps(value, sort_keys=True, default=str)


def _check_metrics(path: Path, rows: list[dict[str, float]], last: CheckpointJson, in_progress: bool) -> None:
    """Step 4: metrics.csv is last.pt's history, as ``hdnet.train`` writes it (six significant digits);
    with a training at work, one epoch more or less (it writes last.pt, then metrics.csv)."""
    epochs = int(last["epoch"])
    if len(rows) != epochs and not (in_progress and abs(len(rows) - epochs) <= 1):
        if not os.path.lexists(path):
            raise HdNetError(f"{path} is missing ({path.parent / LAST} holds {epochs} epoch(s)); {REWRITE}.")
        raise HdNetError(
            f"{path} lists {len(rows)} epoch(s), {path.parent / LAST} holds {epochs}: the run's files are out of "
            f"step; {REWRITE}."
        )
    timing = last.get("timing")
    rates = {r.get("epoch"): r for r in (timing if isinstance(timing, list) else []) if isinstance(r, dict)}
    for k, (row, kept) in enumerate(zip(rows, last["history"], strict=False), start=1):
        expected: dict[str, Any] = {**kept, **rates.get(k, {}), "epoch": k}
        for column, value in row.items():
            want: Any = expected.get(column)
            if _is_number(want) and not _same_6g(value, float(want)):
                raise HdNetError(
                    f"{path}: epoch {k}'s {column} is {value:.6g}, {path.parent / LAST} says {float(want):.6g}: "
                    f"metrics.csv is not the run's history; {REWRITE}."
                )


def _same_6g(a: float, b: float) -> bool:
    """Equal as ``metrics.csv`` writes them (``%.6g``; NaN equals NaN)."""
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return f"{a:.6g}" == f"{b:.6g}"
