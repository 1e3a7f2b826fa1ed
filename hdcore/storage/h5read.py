"""Checked HDF5 reads: every read error of an opened file becomes one ``DamagedFileError`` line."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from hdcore.errors import DamagedFileError, FormatError, StorageError
from hdcore.storage.oserrors import describe_os_error, short_message


def _selection_row(selection: Any) -> int | None:
    first = selection[0] if isinstance(selection, tuple) and selection else selection
    if isinstance(first, (int, np.integer)):
        return int(first)
    return None


class CheckedDataset:
    """An h5py dataset whose reads raise :class:`DamagedFileError` naming file, dataset and scan."""

    def __init__(self, dataset: h5py.Dataset, owner: CheckedH5File) -> None:
        self._ds = dataset
        self._owner = owner

    def __getitem__(self, selection: Any) -> Any:
        try:
            return self._ds[selection]
        except (OSError, RuntimeError, KeyError) as exc:
            row = _selection_row(selection)
            if row is None:
                row = self._first_bad_row(selection)
            raise DamagedFileError(
                f"{self._owner.what}: cannot read {self._ds.name.lstrip('/')}{self._owner.scan_text(row)} "
                f"({short_message(exc)}); the file is damaged, run `hd verify`"
            ) from exc

    def _first_bad_row(self, selection: Any) -> int | None:
        """After a failed read of a range of rows: the first row that cannot be read, if any."""
        first, rest = (selection[0], selection[1:]) if isinstance(selection, tuple) and selection else (selection, ())
        if not isinstance(first, slice) or not self._ds.shape:
            return None
        for row in range(*first.indices(self._ds.shape[0])):
            try:
                self._ds[(row, *rest)]
            except (OSError, RuntimeError, KeyError):
                return row
            except Exception:  # noqa: BLE001 - a selection that does not take an integer row
                return None
        return None

    def __getattr__(self, name: str) -> Any:
        return getattr(self._ds, name)

    def __len__(self) -> int:
        return len(self._ds)

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        arr = self[()]
        return arr if dtype is None else arr.astype(dtype)


class CheckedH5File:
    """A read-only ``h5py.File`` whose dataset reads are checked (see :class:`CheckedDataset`).

    Attribute access (``attrs``, ``filename``, ``close``...) goes to the h5py file.
    """

    def __init__(self, f: h5py.File, what: str) -> None:
        self._f = f
        self.what = what

    def __getitem__(self, name: str) -> Any:
        try:
            obj = self._f[name]
        except (KeyError, OSError, RuntimeError) as exc:
            raise DamagedFileError(f"{self.what}: no readable dataset {name!r} ({short_message(exc)})") from exc
        return CheckedDataset(obj, self) if isinstance(obj, h5py.Dataset) else obj

    def __contains__(self, name: str) -> bool:
        return name in self._f

    def __iter__(self) -> Iterator[str]:
        """The names of the file's members, as ``h5py.File`` iterates them."""
        return iter(self._f)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)

    def scan_text(self, row: int | None) -> str:
        """``of scan N (row k)`` for error messages, best effort."""
        if row is None:
            return ""
        try:
            return f" of scan {int(self._f['scan_index'][row])} (row {row})"
        except Exception:  # noqa: BLE001 - the index itself may be what is damaged
            return f" row {row}"

    def __enter__(self) -> CheckedH5File:
        return self

    def __exit__(self, *exc: object) -> None:
        self._f.close()


def open_h5(path: str | os.PathLike, what: str | None = None) -> CheckedH5File:
    """Open an HDF5 file read-only with checked reads.

    Raises:
        StorageError: missing or unreadable file. DamagedFileError: not HDF5 or damaged metadata.
    """
    p = Path(path)
    name = what or str(p)
    if not p.is_file():
        if not os.path.lexists(p):
            raise DamagedFileError(f"{name}: missing; run `hd verify`")
        raise FormatError(f"{name}: not a regular file")
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        if isinstance(exc, PermissionError):
            raise StorageError(describe_os_error(exc, p)) from exc
        raise DamagedFileError(
            f"{name}: cannot open as HDF5 ({short_message(exc)}); the file is damaged or not an hd file"
        ) from exc
    return CheckedH5File(f, name)


def check_h5_data(path: str | os.PathLike, what: str | None = None) -> None:
    """Read every chunk of every dataset (fletcher32 and decompression checks on all the data).

    Raises:
        DamagedFileError: a chunk cannot be read back.
    """
    with open_h5(path, what) as f:
        names: list[str] = []
        f._f.visit(lambda n: names.append(n) if isinstance(f._f[n], h5py.Dataset) else None)
        for name in names:
            ds = f[name]
            if ds.shape and ds.chunks:
                for k in range(0, ds.shape[0], ds.chunks[0]):
                    ds[k : k + ds.chunks[0]]
            else:
                ds[()]


def attr_int(value: object) -> int:
    """An HDF5 attribute's value (as h5py or a reader's plain copy gives it) as an integer.

    Raises:
        TypeError: it is no integer (a string, a float, a list, None), as ``int()`` would of most.
    """
    if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        return int(value)
    raise TypeError(f"{value!r} is not an integer")


def attr_float(value: object) -> float:
    """An HDF5 attribute's value as a number (an integer or a float).

    Raises:
        TypeError: it is no number (a string, a list, None, a boolean).
    """
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_)):
        return float(value)
    raise TypeError(f"{value!r} is not a number")
