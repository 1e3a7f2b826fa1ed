"""HDF5 files built in memory (h5py's ``core`` driver) and written to disk with plain file I/O."""

from __future__ import annotations

import contextlib
import math
import os
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from hdcore.errors import StorageError
from hdcore.storage.atomic import write_bytes_atomic
from hdcore.storage.hashes import sha256_bytes


class H5Image:
    """An HDF5 file built in memory and written to ``path`` atomically by :meth:`commit`.

    ``file`` is a writable ``h5py.File`` (``core`` driver, no backing store): nothing touches the
    disk until :meth:`commit`, which writes the finished image with plain file I/O (see the module
    docstring for why). Use as a context manager; leaving the block with an exception discards it.
    Memory: the size of the (compressed) file.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.file = h5py.File(f"{self.path}.{os.getpid()}.{id(self)}.inmemory", "w", driver="core", backing_store=False)

    def commit(self) -> str:
        """Write the file to ``path`` (temporary name, fsync, rename); returns its sha256."""
        self.file.flush()
        image = self.file.id.get_file_image()
        self.file.close()
        write_bytes_atomic(self.path, image)
        return sha256_bytes(image)

    def discard(self) -> None:
        """Drop the in-memory file (idempotent)."""
        with contextlib.suppress(Exception):
            if self.file.id.valid:
                self.file.close()

    def __enter__(self) -> H5Image:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is not None:
            self.discard()


# Bytes of rows a RowBlocks holds before writing them (a label shard's 50 scans at 3 sigma: 20 MB).
ROW_BLOCK_BYTES = 32 << 20


class RowBlocks:
    """The rows of a file's arrays, written in order: held in memory and written a block of rows at
    a time, one h5py call per array and block instead of one per array and row (far fewer HDF5
    calls). At most ``ROW_BLOCK_BYTES`` of rows (at least one row) are held; every row sets every
    array. The values are those row writes give, the bytes not always: HDF5 may place the chunks
    in another order. Label shards come out byte for byte as before (checked against mars-paper's
    published build); scan shards do not, so ``ScanShardWriter`` keeps writing row by row.

    Args:
        datasets: the arrays, by name, all with the same number of rows (first axis).
    """

    def __init__(self, datasets: dict[str, h5py.Dataset]) -> None:
        self._datasets = datasets
        n = min(ds.shape[0] for ds in datasets.values())
        row_bytes = sum(ds.dtype.itemsize * math.prod(ds.shape[1:]) for ds in datasets.values())
        rows = max(1, min(n, ROW_BLOCK_BYTES // max(1, row_bytes)))
        self._buffers = {name: np.zeros((rows, *ds.shape[1:]), ds.dtype) for name, ds in datasets.items()}
        self._start = self._next = 0

    def put(self, k: int, values: dict[str, object]) -> None:
        """Row ``k`` of every array (``values`` by name; rows in order from 0).

        Raises:
            ValueError: a row out of order, or not every array given.
        """
        if k != self._next:
            raise ValueError(f"rows are written in order: row {k} after {self._next - 1}")
        if values.keys() != self._buffers.keys():
            raise ValueError(f"row {k} gives {sorted(values)}, the file's arrays are {sorted(self._buffers)}")
        if k - self._start == len(next(iter(self._buffers.values()))):
            self.flush()
        for name, value in values.items():
            self._buffers[name][k - self._start] = value
        self._next = k + 1

    def flush(self) -> None:
        """Write the rows held so far."""
        end = self._next
        if end > self._start:
            for name, data in self._buffers.items():
                self._datasets[name][self._start : end] = data[: end - self._start]
        self._start = end


def h5_chunk_kwargs(compression: str) -> dict[str, Any]:
    """h5py keywords of a chunked, checksummed array: fletcher32 per chunk, plus gzip (deflate 1 +
    shuffle), lzf or no compression.

    Raises:
        StorageError: an unknown compression name.
    """
    base: dict[str, Any] = {"track_times": False, "fletcher32": True}
    if compression == "gzip":
        return {**base, "compression": "gzip", "compression_opts": 1, "shuffle": True}
    if compression == "lzf":
        return {**base, "compression": "lzf", "shuffle": True}
    if compression == "none":
        return base
    raise StorageError(f"unknown compression {compression!r}; use gzip, lzf or none")
