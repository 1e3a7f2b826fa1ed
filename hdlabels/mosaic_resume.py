"""Resuming ``hd mosaic`` after a kill: the settings and every finished descent, kept beside the output.

While a mosaic dataset is made, its output directory holds the hidden directory
:data:`RESUME_DIR` (``.hd-mosaic-resume``):

* ``state.json``: the settings' fingerprint (:func:`settings_fingerprint`: the sha256 of the
  ``mosaic`` record the manifest will hold - the source's shards by sha256, its settings hash, the
  poses, the frames, the DEM grid, the ICP scales - and of the mosaic shards' file attributes), and
  that record;
* ``mosaics-NNNNN.dDDDDD.npz``: the arrays of each descent mosaicked (its mosaics, poses and
  registration record), written atomically as soon as the descent is done.

A run that finds a state of the same fingerprint reads each kept descent back instead of mosaicking
it again; the shard is then written from the same arrays, so its bytes are those of an uninterrupted
run. A descent file that does not read back whole (the zip's CRC-32 of each array, another
fingerprint, another descent or a missing array) is mosaicked again. A state of other settings is
refused unless the run overwrites (then it is cleared). The directory is removed once the output is
whole in its staging directory, just before the commit moves it into place (a rename per file), and
by a run that fails before it kept any descent.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import zipfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from hdcore.errors import OutputExistsError, StorageError
from hdcore.storage import (
    make_subdir,
    read_regular_text,
    remove_partials,
    sha256_bytes,
    write_bytes_atomic,
    write_json_atomic,
)

RESUME_DIR = ".hd-mosaic-resume"
STATE_NAME = "state.json"
_FINGERPRINT = "fingerprint"


def _plain(value: object) -> object:
    """A value as JSON holds it (NumPy arrays and scalars as lists and numbers)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def settings_fingerprint(record: Mapping[str, object], attrs: Mapping[str, object]) -> str:
    """The sha256 (hex) of a mosaic dataset's settings: its manifest's ``mosaic`` record and its
    shards' file attributes, as sorted JSON."""
    text = json.dumps({"mosaic": _plain(record), "attrs": _plain(attrs)}, sort_keys=True)
    return sha256_bytes(text.encode())


def _read_state(resume: Path) -> dict[str, object]:
    """``state.json`` of a resume directory ({} when missing or unreadable)."""
    try:
        state = json.loads(read_regular_text(resume / STATE_NAME))
    except (ValueError, RecursionError):  # StorageError and JSONDecodeError are ValueErrors
        return {}
    return state if isinstance(state, dict) else {}


def _difference(recorded: object, record: Mapping[str, object]) -> str:
    """The mosaic settings that differ, for the refusal (``poses "registered" -> "nav"``)."""
    if not isinstance(recorded, dict):
        return "its settings are not recorded"
    mine = _plain(record)
    assert isinstance(mine, dict)
    changed = [
        f"{k} {json.dumps(recorded.get(k))} -> {json.dumps(mine.get(k))}"
        for k in sorted(set(recorded) | set(mine))
        if recorded.get(k) != mine.get(k)
    ]
    return "; ".join(changed) if changed else "the same settings, another settings hash (another hd version)"


def resumable(out: Path, fingerprint: str, record: Mapping[str, object], overwrite: bool) -> bool:
    """True when ``out`` holds an unfinished mosaic of these settings (its descents will be kept).

    Raises:
        OutputExistsError: an unfinished mosaic of other settings, without ``overwrite``.
    """
    resume = out / RESUME_DIR
    if not resume.is_dir() or resume.is_symlink():
        return False
    state = _read_state(resume)
    if state.get(_FINGERPRINT) == fingerprint:
        return True
    if not overwrite:
        raise OutputExistsError(
            f"{out} holds an unfinished hd mosaic with other settings ({_difference(state.get('mosaic'), record)}); "
            "rerun that command to resume it, or pass --overwrite to start again"
        )
    return False


def start(out: Path, fingerprint: str, record: Mapping[str, object]) -> Path:
    """The resume directory of ``out`` for these settings (under the output's lock): one of other
    settings is cleared, partial files of a killed run and directories in it (where a descent file goes)
    removed, ``state.json`` written."""
    resume = out / RESUME_DIR
    if os.path.lexists(resume) and (resume.is_symlink() or _read_state(resume).get(_FINGERPRINT) != fingerprint):
        discard(out)
    make_subdir(out, RESUME_DIR)
    remove_partials(resume)
    for entry in resume.iterdir():  # hd's own directory: a link or directory where a descent file goes is cleared
        if entry.is_symlink() or entry.is_file():
            continue
        shutil.rmtree(entry, ignore_errors=True)
    if _read_state(resume).get(_FINGERPRINT) != fingerprint:
        write_json_atomic(resume / STATE_NAME, {_FINGERPRINT: fingerprint, "mosaic": _plain(record)})
    return resume


def kept_descents(out: Path) -> int:
    """The number of descent files a resume directory holds."""
    resume = out / RESUME_DIR
    return len(list(resume.glob("*.npz"))) if resume.is_dir() else 0


def discard(out: Path) -> None:
    """Remove the resume directory of ``out`` (after the commit, or of other settings)."""
    resume = out / RESUME_DIR
    if resume.is_symlink() or resume.is_file():
        resume.unlink()
    else:
        shutil.rmtree(resume, ignore_errors=True)


def descent_path(resume: str | os.PathLike, shard: str, row: int) -> Path:
    """Where the descent at ``row`` of the mosaic shard named ``shard`` is kept."""
    return Path(resume) / f"{Path(shard).stem}.d{row:06d}.npz"


def save_descent(path: Path, fingerprint: str, arrays: Mapping[str, np.ndarray]) -> None:
    """Keep one descent's arrays (atomically; an uncompressed ``.npz`` with the settings' fingerprint).

    Raises:
        StorageError: a full disk or an unwritable directory (nothing is half-written).
    """
    buffer = io.BytesIO()
    everything: dict[str, np.ndarray] = {_FINGERPRINT: np.asarray(fingerprint), **arrays}
    np.savez(buffer, allow_pickle=False, **everything)
    write_bytes_atomic(path, buffer.getvalue())


def load_descent(path: Path, fingerprint: str, names: tuple[str, ...]) -> dict[str, np.ndarray] | None:
    """A kept descent's arrays ``names``, or None when there is none that reads back whole with this
    ``fingerprint`` (the descent is then mosaicked again)."""
    if not path.is_file() or path.is_symlink():
        return None
    try:
        with np.load(path, allow_pickle=False) as kept:
            if str(kept[_FINGERPRINT]) != fingerprint or not set(names) <= set(kept.files):
                return None
            return {name: kept[name] for name in names}  # each array read whole: its CRC-32 is checked
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, StorageError):
        return None
