"""One storage layer for every file hd writes or reads (shards, manifests, checkpoints, reports).

Writing:

* every file is built under a hidden temporary name beside its final name
  (``.NAME.partial-PID``), flushed to disk (``fsync``), renamed into place and the directory
  flushed; on any error (a full disk included) or interruption the temporary file is removed and
  the error is one :class:`StorageError` line naming the path (``write_bytes_atomic``,
  ``write_json_atomic``, ``atomic_path``);
* HDF5 files are built in memory (h5py's ``core`` driver without backing store, :class:`H5Image`)
  and written to disk with plain file I/O. The HDF5 library therefore never sees a failed write:
  after one (``ENOSPC``) HDF5 2.0 crashes the process (segmentation fault) when the file is closed
  or when the interpreter exits, whatever the caller does;
* GeoTIFFs too large to build in memory (``hd detect``'s maps) are written window by window by
  GDAL through :class:`GeoTiffWriter`: GDAL's and libtiff's messages are captured, never printed,
  and a failed write or flush (a full disk) is one :class:`StorageError` line naming the file;
* :func:`check_output_dir` / :func:`check_output_file` check an output path before any work starts
  (not under a regular file, not empty, a writable file system: ``/proc`` and read-only mounts are
  refused) without creating it.

Reading:

* :func:`confine` keeps every path read from a manifest inside its dataset (no absolute paths, no
  ``..``, no symbolic link leading out);
* :func:`verify_sha256` compares a file with the checksum its manifest records before it is
  opened; :func:`open_h5` opens HDF5 files whose every later read error (a damaged chunk, whose
  fletcher32 checksum fails) becomes one :class:`DamagedFileError` line naming the file, the
  dataset and the scan;
* :func:`check_schema` refuses another schema or an unknown major version;
* :func:`read_regular_bytes` (and :func:`read_json`, :func:`read_regular_text`) read side files
  only when they are regular files (a FIFO, socket, device or directory is refused at once, never
  waited on) and of a bounded size; :func:`check_regular_file` is the same check for files opened
  by a library (HDF5, GeoTIFF).

One writer per directory: :class:`WriterLock` holds an exclusive ``flock`` on ``DIR/.hd-lock``
(the holder's PID written in it) for as long as a command writes there; the kernel releases it
when the holder dies, even by SIGKILL. A second writer fails at once with the holder's PID;
readers never take the lock (:func:`lock_holder` probes it with a shared lock released at once).

One output transaction: every command writes its output directory inside an
:class:`OutputTransaction` (create, lock, check, stage, commit or roll back); :class:`OutputDir`
adds the rules of a command whose whole output is replaced at once (``hd eval``'s report,
``hd detect``).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import math
import os
import re
import shutil
import stat
import tempfile
import time
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from lidarsim.errors import (
    DamagedFileError,
    FormatError,
    LidarsimError,
    LockedError,
    OutputExistsError,
    StorageError,
)
from lidarsim.limits import parse_integer

LOCK_NAME = ".hd-lock"
PARTIAL_MARK = ".partial-"
# Longest file-name component most file systems accept, bytes (NAME_MAX on Linux).
NAME_MAX_BYTES = 255
_HASH_CHUNK_BYTES = 1 << 22
_SHA256_RE = re.compile(r"^[0-9a-f]{64}$")


# --------------------------------------------------------------------------------------- errors
def describe_os_error(exc: OSError, path: str | os.PathLike | None = None) -> str:
    """One line for an OS error: ``PATH: no space left on device...`` (``path``, else the one the error names)."""
    where = path if path is not None else exc.filename
    reason = exc.strerror or (errno.errorcode.get(exc.errno or 0, "") if exc.errno else "") or str(exc)
    if exc.errno == errno.ENOSPC:
        reason = "no space left on device; free some space and re-run the same command to resume"
    elif exc.errno == errno.EDQUOT:
        reason = "disk quota exceeded; free some space and re-run the same command to resume"
    return f"{where}: {reason}" if where is not None else reason


def _short(exc: BaseException) -> str:
    """The first line of an exception's message, trimmed (h5py messages are long)."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text if len(text) <= 160 else text[:157] + "..."


# --------------------------------------------------------------------------------------- hashes
def sha256_file(path: str | os.PathLike, chunk_bytes: int = _HASH_CHUNK_BYTES) -> str:
    """Hex SHA-256 of a file's bytes, streamed.

    Raises:
        StorageError: the file cannot be read.
    """
    h = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            while block := fh.read(chunk_bytes):
                h.update(block)
    except OSError as exc:
        raise StorageError(describe_os_error(exc, path)) from exc
    return h.hexdigest()


def sha256_bytes(data: bytes | memoryview) -> str:
    """Hex SHA-256 of bytes in memory."""
    return hashlib.sha256(data).hexdigest()


def is_sha256(value: Any) -> bool:
    """True for a lower-case 64-digit hex string."""
    return isinstance(value, str) and bool(_SHA256_RE.match(value))


_VERIFIED: dict[tuple[str, int, int, int, str], bool] = {}


def verify_sha256(path: str | os.PathLike, expected: str, what: str | None = None) -> None:
    """Refuse a file whose SHA-256 differs from ``expected`` (the manifest's).

    A file verified once is not hashed again by the same process while its size, mtime and inode
    stay the same.

    Raises:
        DamagedFileError: the checksum differs (the file was damaged or replaced).
        StorageError: the file is missing or unreadable.
    """
    p = Path(path)
    name = what or str(p)
    try:
        st = p.stat()
    except FileNotFoundError as exc:
        raise DamagedFileError(f"{name}: missing (the manifest lists it); run `hd verify`") from exc
    except OSError as exc:
        raise StorageError(describe_os_error(exc, p)) from exc
    if not stat.S_ISREG(st.st_mode):
        raise FormatError(f"{name}: not a regular file")
    key = (str(p), st.st_size, st.st_mtime_ns, st.st_ino, expected)
    if _VERIFIED.get(key):
        return
    digest = sha256_file(p)
    if digest != expected:
        raise DamagedFileError(
            f"{name}: checksum mismatch (sha256 {digest[:12]}..., the manifest says {str(expected)[:12]}...): "
            "the file is damaged or was replaced; run `hd verify`"
        )
    _VERIFIED[key] = True


# --------------------------------------------------------------------------------------- atomic writes
def partial_path(final: Path) -> Path:
    """Temporary name used while ``final`` is being written (hidden, unique to this process)."""
    final = Path(final)
    return final.with_name(f".{final.name}{PARTIAL_MARK}{os.getpid()}")


def remove_partials(directory: Path) -> int:
    """Delete leftovers of interrupted writes (``.*.partial-*``) in ``directory``; returns the count.

    Call it only while holding the directory's :class:`WriterLock` (or from the single writer).
    """
    n = 0
    directory = Path(directory)
    if directory.is_dir():
        for p in directory.glob(f".*{PARTIAL_MARK}*"):
            try:
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p, ignore_errors=True)
                else:
                    p.unlink(missing_ok=True)
                n += 1
            except OSError:
                pass
    return n


def fsync_dir(directory: Path) -> None:
    """Flush a directory entry (a rename) to disk; a no-op where directories cannot be opened."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def commit_file(tmp: Path, final: Path) -> None:
    """Flush ``tmp`` to disk and rename it to ``final`` (atomic on POSIX); ``tmp`` is removed on failure.

    Raises:
        StorageError: the flush or the rename failed.
    """
    try:
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, final)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise StorageError(describe_os_error(exc, final)) from exc
    fsync_dir(Path(final).parent)


def _write_all(fd: int, data: bytes | memoryview) -> None:
    """Write every byte of ``data`` to ``fd`` (the single place hd writes file contents)."""
    view = memoryview(data).cast("B")
    while view:
        n = os.write(fd, view[: 1 << 24])
        view = view[n:]


def remove_stale_partials(final: Path) -> None:
    """Remove temporary files of ``final`` left by processes that no longer run (killed writers)."""
    final = Path(final)
    prefix = f".{final.name}{PARTIAL_MARK}"
    with contextlib.suppress(OSError):
        for p in final.parent.glob(f"{glob_escape(prefix)}*"):
            try:
                pid = parse_integer(p.name[len(prefix) :])
            except LidarsimError:
                continue  # not a PID in ASCII digits: not a name hd writes
            if pid != os.getpid() and not _pid_alive(pid):
                with contextlib.suppress(OSError):
                    p.unlink()


def glob_escape(text: str) -> str:
    """``text`` with glob's special characters escaped."""
    import glob

    return glob.escape(text)


def _open_new(tmp: Path) -> int:
    """Create ``tmp`` exclusively, never through a symbolic link (a stale one is removed first)."""
    tmp.unlink(missing_ok=True)
    return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)


def write_bytes_atomic(path: str | os.PathLike, data: bytes | memoryview) -> None:
    """Write ``data`` to ``path`` atomically: temporary file, fsync, rename, directory fsync.

    Temporary files of the same path left by killed processes are removed first.

    Raises:
        StorageError: any OS error (disk full, read-only, permission); no temporary file is left.
    """
    final = Path(path)
    tmp = partial_path(final)
    remove_stale_partials(final)
    try:
        fd = _open_new(tmp)
        try:
            _write_all(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, final)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise StorageError(describe_os_error(exc, final)) from exc
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(final.parent)


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write UTF-8 text atomically (see :func:`write_bytes_atomic`)."""
    write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: str | os.PathLike, data: Any, indent: int | None = 2) -> None:
    """Write JSON (``indent`` spaces, 2 by default; a trailing newline) atomically: the one JSON
    writer of hd (see :func:`write_bytes_atomic`).

    Raises:
        StorageError: a value JSON cannot hold, or any OS error; no temporary file is left.
    """
    try:
        text = json.dumps(data, indent=indent, sort_keys=False) + "\n"
    except (TypeError, ValueError) as exc:
        raise StorageError(f"{path}: cannot be written as JSON ({exc})") from exc
    write_text_atomic(path, text)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Context manager for writers that need a file name (matplotlib, GDAL): yields the temporary path.

    On a clean exit the temporary file is flushed and renamed to ``path``; on any exception it is
    removed and an ``OSError`` becomes a :class:`StorageError` naming ``path``.
    """
    final = Path(path)
    tmp = partial_path(final)
    remove_stale_partials(final)
    tmp.unlink(missing_ok=True)
    try:
        yield tmp
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise StorageError(describe_os_error(exc, final)) from exc
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    commit_file(tmp, final)


# --------------------------------------------------------------------------------------- HDF5 in memory
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

    def put(self, k: int, values: dict[str, Any]) -> None:
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


# --------------------------------------------------------------------------------------- checked HDF5 reads
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
                f"({_short(exc)}); the file is damaged, run `hd verify`"
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
            raise DamagedFileError(f"{self.what}: no readable dataset {name!r} ({_short(exc)})") from exc
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
            f"{name}: cannot open as HDF5 ({_short(exc)}); the file is damaged or not an hd file"
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


# --------------------------------------------------------------------------------------- schemas, JSON
def check_schema(name: str, version: str, expected_name: str, expected_version: str, where: str) -> None:
    """Refuse a schema of another name or of an unknown major version (minor versions are compatible).

    Raises:
        FormatError: naming ``where``.
    """
    if name != expected_name:
        raise FormatError(f"{where}: schema is {name!r}, expected {expected_name!r}")
    major = str(version).split(".")[0]
    if major != expected_version.split(".")[0]:
        raise FormatError(
            f"{where}: schema {name} version {version} is not supported by this hd "
            f"(reads major version {expected_version.split('.')[0]}); upgrade hd"
        )


# hd choice: the largest side file (JSON, CSV, TOML) hd reads whole: its own are kilobytes (a
# manifest of 10,000 shards is about 3 MB); anything larger is not one of them.
MAX_SIDE_FILE_BYTES = 64 << 20


def _kind_of(mode: int) -> str:
    """A file type's name for messages (``stat`` mode bits)."""
    for test, name in (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def check_regular_file(path: str | os.PathLike, what: str | None = None) -> os.stat_result:
    """The ``stat`` of ``path`` (symbolic links followed) if it is a regular file.

    A FIFO, socket, device or directory where hd expects a file is refused at once, before it is
    opened (opening a FIFO for reading blocks until a writer comes).

    Raises:
        StorageError: missing or unreadable. FormatError: not a regular file.
    """
    p = Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        raise StorageError(describe_os_error(exc, p)) from exc
    if not stat.S_ISREG(st.st_mode):
        raise FormatError(f"{what or p}: is {_kind_of(st.st_mode)}, not a regular file; hd reads only regular files")
    return st


def read_regular_bytes(path: str | os.PathLike, what: str | None = None, max_bytes: int = MAX_SIDE_FILE_BYTES) -> bytes:
    """The bytes of the regular file ``path`` (at most ``max_bytes``).

    Opened without blocking and checked with ``fstat`` on the open descriptor, so a FIFO put in the
    file's place between a check and the open is refused too, never waited on.

    Raises:
        StorageError: missing or unreadable. FormatError: not a regular file, or larger than
        ``max_bytes``.
    """
    p = Path(path)
    name = what or str(p)
    check_regular_file(p, name)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise StorageError(describe_os_error(exc, p)) from exc
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise FormatError(f"{name}: is {_kind_of(st.st_mode)}, not a regular file; hd reads only regular files")
        if st.st_size > max_bytes:
            raise FormatError(f"{name}: {st.st_size} bytes, more than the {max_bytes} this file can hold")
        chunks: list[bytes] = []
        total = 0
        while True:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                break
            total += len(chunk)
            if total > max_bytes:
                raise FormatError(f"{name}: more than the {max_bytes} bytes this file can hold")
            chunks.append(chunk)
        return b"".join(chunks)
    except OSError as exc:
        raise StorageError(describe_os_error(exc, p)) from exc
    finally:
        os.close(fd)


def read_regular_text(path: str | os.PathLike, what: str | None = None, max_bytes: int = MAX_SIDE_FILE_BYTES) -> str:
    """The UTF-8 text of the regular file ``path`` (:func:`read_regular_bytes`).

    Raises:
        StorageError, FormatError: as :func:`read_regular_bytes`. DamagedFileError: not UTF-8.
    """
    data = read_regular_bytes(path, what, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DamagedFileError(f"{what or path}: unreadable (not UTF-8 text)") from exc


def read_json(path: str | os.PathLike, what: str = "file") -> Any:
    """Parse a JSON file (a regular file: :func:`read_regular_bytes`).

    Raises:
        StorageError: unreadable. FormatError: not a regular file. DamagedFileError: not valid JSON.
    """
    p = Path(path)
    try:
        text = read_regular_bytes(p).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DamagedFileError(f"{p}: unreadable {what} (not UTF-8 text)") from exc
    try:
        return json.loads(text)
    except ValueError as exc:  # JSONDecodeError, and an integer literal past Python's digit limit
        raise DamagedFileError(f"{p}: unreadable {what} ({exc})") from exc
    except RecursionError as exc:
        raise DamagedFileError(f"{p}: unreadable {what} (nested too deeply)") from exc


def require(mapping: Any, key: str, kind: type | tuple[type, ...], where: str) -> Any:
    """``mapping[key]`` if it is of type ``kind`` (bool is not an int), else a FormatError naming ``where``."""
    if not isinstance(mapping, dict):
        raise FormatError(f"{where}: expected a JSON object, got {type(mapping).__name__}")
    if key not in mapping:
        raise FormatError(f"{where}: the key {key!r} is missing")
    value = mapping[key]
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if isinstance(value, bool) and bool not in kinds:
        raise FormatError(f"{where}: {key!r} must be {' or '.join(k.__name__ for k in kinds)}, got {value!r}")
    if not isinstance(value, kinds):
        raise FormatError(
            f"{where}: {key!r} must be {' or '.join(k.__name__ for k in kinds)}, got {type(value).__name__}"
        )
    if isinstance(value, float) and not math.isfinite(value):
        raise FormatError(f"{where}: {key!r} must be finite, got {value!r}")
    return value


# --------------------------------------------------------------------------------------- paths
def check_relative(relative: Any, where: str) -> str:
    """A manifest path: a non-empty relative POSIX path without ``..``, ``.`` or empty parts.

    Raises:
        FormatError: anything else (absolute paths, ``../../etc/passwd``...).
    """
    if not isinstance(relative, str) or not relative or "\x00" in relative or "\\" in relative:
        raise FormatError(f"{where}: {relative!r} is not a relative path inside the dataset")
    parts = relative.split("/")
    if relative.startswith("/") or any(p in ("", ".", "..") for p in parts):
        raise FormatError(f"{where}: the path {relative!r} leaves the dataset; refused")
    return relative


def confine(root: str | os.PathLike, relative: Any, where: str | None = None) -> Path:
    """``root / relative``, refused unless it stays inside ``root`` once symbolic links are resolved.

    Raises:
        FormatError: an absolute path, ``..``, or a link leading outside the dataset.
    """
    label = where or str(relative)
    check_relative(relative, label)
    base = Path(root).resolve()
    full = base / relative
    try:
        resolved = full.resolve()
    except (OSError, RuntimeError) as exc:
        raise FormatError(f"{label}: the path {relative!r} cannot be resolved (a symbolic link loop?)") from exc
    if not resolved.is_relative_to(base):
        raise FormatError(f"{label}: the path {relative!r} leads outside the dataset (to {resolved}); refused")
    return full


def _check_text_path(path: Any, flag: str) -> Path:
    text = os.fspath(path)
    if text.strip() == "":
        raise StorageError(f"{flag} must not be empty")
    if "\x00" in text:
        raise StorageError(f"{flag} {text!r} contains a NUL character")
    p = Path(os.path.abspath(text))
    for part in p.parts:
        if len(os.fsencode(part)) > NAME_MAX_BYTES:
            raise StorageError(f"{flag} {text}: the name {part[:20]}... is longer than {NAME_MAX_BYTES} bytes")
    return p


def _probe_writable(directory: Path, flag: str, target: Path) -> None:
    """Create and remove a probe file in ``directory``; refuses /proc, read-only file systems..."""
    try:
        fd, name = tempfile.mkstemp(prefix=".hd-probe-", dir=directory)
    except OSError as exc:
        raise StorageError(f"{flag} {target}: cannot create files in {directory} ({exc.strerror or exc})") from exc
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(name)


def _nearest_existing(p: Path) -> Path:
    anc = p.parent
    while not os.path.lexists(anc):
        anc = anc.parent
    return anc


def check_output_dir(path: str | os.PathLike, flag: str = "--out") -> Path:
    """Check that ``path`` can become (or already is) a writable directory, without creating it.

    Returns the absolute path.

    Raises:
        StorageError: empty, NUL, over-long name, an existing non-directory, a path under a regular
            file, a broken symbolic link, or a location that cannot be written (``/proc``, a
            read-only mount, no permission).
    """
    p = _check_text_path(path, flag)
    if os.path.lexists(p) and not p.exists():
        raise StorageError(f"{flag} {p} is a broken symbolic link")
    if p.exists():
        if not p.is_dir():
            raise StorageError(f"{flag} {p} exists and is not a directory")
        _probe_writable(p, flag, p)
        return p
    anc = _nearest_existing(p)
    if not anc.is_dir():
        raise StorageError(f"{flag} {p}: {anc} is not a directory")
    _probe_writable(anc, flag, p)
    return p


def check_not_input(out: str | os.PathLike, inputs: dict[str, str | os.PathLike | None], flag: str = "--out") -> None:
    """Refuse an output location that is, contains or lies inside one of a command's inputs.

    ``inputs`` maps a description ("the run", "the DTM", "the dataset") to a path (file or
    directory; None entries are skipped). Paths are compared after resolving symbolic links, so a
    link to an input is the input. Call it before any work and again under the writer lock.

    Raises:
        StorageError: one line naming both paths.
    """
    target = Path(os.path.realpath(os.path.abspath(out)))
    for what, value in inputs.items():
        if value is None or re.match(r"^[A-Za-z][A-Za-z0-9+.-]*://", str(value)):
            continue  # a URL is never where a local output lies
        source = Path(os.path.realpath(os.path.abspath(value)))
        if target == source:
            relation = "is"
        elif source.is_relative_to(target):
            relation = "contains"
        elif target.is_relative_to(source):
            relation = "lies inside"
        else:
            continue
        raise StorageError(
            f"{flag} {out} {relation} {what} ({source}): an output never replaces or mixes with an input; "
            f"choose another {flag}"
        )


class OutputTransaction:
    """The one way hd writes an output directory: create, lock, stage, then commit or roll back.

    Entering the block creates the directory when it is missing (``mkdir -p``), takes its
    :class:`WriterLock`, runs ``check`` (the command's rules for its output - never an input, no
    foreign files, ``--overwrite`` - checked again now that no other writer can run; its result is
    :attr:`checked`) and removes the leftovers of killed writers (``.*.partial-*``); with
    ``staged`` it also makes an empty hidden staging directory (:attr:`staging`,
    ``.WHAT.partial-PID``) whose files :meth:`commit` moves into place one by one. Writers that
    build their output in place, file by file and each file atomically (a resumable build, a
    training's checkpoints, a labelling's shards), leave ``staged`` off: their output is committed
    when the block ends without an exception.

    On failure - an exception (a full disk, SIGTERM/SIGINT raised as an exception), or a staged
    block that ends without :meth:`commit` - the transaction rolls back: ``rollback`` (the
    command's own clean-up of what it wrote, called under the lock), the staging directory
    removed, the lock released, and the directories the block created removed again while empty.
    While staged, an ``OSError`` becomes one :class:`StorageError` line and a staged file is named
    by its final path.

    ``wait_s``: how long to wait for another writer's lock (seconds; 0, the default, fails at once
    with :class:`LockedError`, as every command does).

    Usage::

        with OutputTransaction(out, "dataset", rollback=clean) as tx:   # in place
            ...write files into tx.path...
        with OutputTransaction(out, "report", staged=True) as tx:       # staged
            ...write files into tx.staging...
            tx.commit(last="report.json")
    """

    def __init__(
        self,
        path: str | os.PathLike,
        what: str = "directory",
        *,
        staged: bool = False,
        check: Callable[[], Any] | None = None,
        rollback: Callable[[], None] | None = None,
        wait_s: float = 0.0,
    ) -> None:
        self.path = Path(os.path.abspath(path))
        self.what = what
        self.staged = staged
        self.rollback = rollback
        self._check = check
        self.checked: Any = None
        self.wait_s = float(wait_s)
        self.staging = self.path / f".{what}{PARTIAL_MARK}{os.getpid()}"
        self.created: Path | None = None  # the top-most directory this transaction created
        self.committed = False
        self._lock: WriterLock | None = None

    def _acquire(self) -> WriterLock:
        deadline = time.monotonic() + self.wait_s
        while True:
            try:
                return WriterLock(self.path, self.what).acquire()
            except LockedError:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(0.1)

    def __enter__(self) -> OutputTransaction:
        self.created = first_missing(self.path)
        make_dirs(self.path)
        try:
            self._lock = self._acquire()
            if self._check is not None:
                self.checked = self._check()
            remove_partials(self.path)  # of a killed writer
            if self.staged:
                make_dirs(self.staging)
        except BaseException:
            self._close(ok=False)
            raise
        self.committed = False
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        ok = exc_type is None and (self.committed or not self.staged)
        try:
            if not ok and self.rollback is not None and self._lock is not None:
                self.rollback()
        finally:
            self._close(ok)
        if self.staged and isinstance(exc, StorageError):
            text = self.final_names(str(exc))
            if text != str(exc):
                raise type(exc)(text) from exc
        elif self.staged and isinstance(exc, OSError):
            where = self.final_names(exc.filename) if isinstance(exc.filename, str) else self.path
            raise StorageError(describe_os_error(exc, where)) from exc

    def _close(self, ok: bool) -> None:
        """Remove the staging directory, release the lock, and (after a failure) the directories created."""
        if self.staged:
            shutil.rmtree(self.staging, ignore_errors=True)
        if self._lock is not None:
            self._lock.release()
            self._lock = None
        if not ok:
            remove_empty_dirs(self.path, self.created)

    def final_names(self, text: str) -> str:
        """``text`` with the paths of staged files replaced by their final paths."""
        return text.replace(f"{self.staging}{os.sep}", f"{self.path}{os.sep}")

    def commit(self, last: str | None = None, replaces: Callable[[str], bool] | None = None) -> list[Path]:
        """Move every staged file into place (``last`` - the output's marker - last); returns the final paths.

        ``replaces``: names of the previous output's files (those the new output does not replace
        are removed first; other files in the directory are never touched).
        """
        if not self.staged or self._lock is None:
            raise StorageError(f"{self.path}: nothing staged to commit")
        staged = sorted((p for p in self.staging.iterdir() if p.is_file()), key=lambda p: (p.name == last, p.name))
        new = {p.name for p in staged}
        if last is not None and last in new:
            (self.path / last).unlink(missing_ok=True)  # from here on the old output is incomplete
        if replaces is not None:
            for p in self.path.iterdir():
                if replaces(p.name) and p.name not in new and p.is_file() and not p.is_symlink():
                    p.unlink()
        final = []
        for p in staged:
            commit_file(p, self.path / p.name)
            final.append(self.path / p.name)
        self.committed = True
        return final


class OutputDir:
    """One command's output directory as a transaction: checked, locked, staged, committed.

    The rules every command follows for its ``--out`` (docs/reliability.md):

    * the directory is not, does not contain and does not lie inside one of the command's inputs
      (:func:`check_not_input`), checked before any work, under the lock and again at commit;
    * it is missing, empty, or holds an output of the same command, recognised by ``marker`` (or, for
      an output whose commit was interrupted, by every entry being one of the command's files); an
      existing output is replaced only with ``overwrite``, and a directory holding anything else is
      never written, ``overwrite`` or not;
    * while the block runs the directory's :class:`WriterLock` is held and files are written into
      :attr:`staging` (a hidden ``.WHAT.partial-PID`` directory inside it, removed by the next
      writer if this one is killed); :meth:`commit` moves them into place one by one, ``marker``
      last, after removing the previous output's files that the new output does not replace. Other
      files in the directory are never touched; a directory this block created is removed again
      when the block fails.

    Usage::

        out = OutputDir(path, what="detect", marker="detect.json", owns=is_detect_file, inputs={...})
        out.check(overwrite)                 # before any work
        with out.open(overwrite) as staging: # locked; staging is empty
            ...write files into staging...
            out.commit()
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        what: str,
        marker: str,
        owns: Any,
        inputs: dict[str, str | os.PathLike | None] | None = None,
        flag: str = "--out",
    ) -> None:
        self.raw = path
        self.what = what
        self.marker = marker
        self.owns = owns
        self.inputs: dict[str, str | os.PathLike | None] = dict(inputs or {})
        self.flag = flag
        self.path = Path(os.path.abspath(path))
        self.staging = self.path / f".{what}{PARTIAL_MARK}{os.getpid()}"
        self._tx: OutputTransaction | None = None
        self._overwrite = False

    def add_inputs(self, inputs: dict[str, str | os.PathLike | None]) -> None:
        """Inputs known only after work started (a run's dataset); checked at once and at commit."""
        self.inputs.update(inputs)
        check_not_input(self.raw, self.inputs, self.flag)

    def _content(self) -> list[str]:
        return [
            p.name
            for p in self.path.iterdir()
            if p.name != LOCK_NAME and not (p.name.startswith(".") and PARTIAL_MARK in p.name)
        ]

    def holds_output(self) -> bool:
        """True when the directory holds an output of this command."""
        if not self.path.is_dir():
            return False
        names = self._content()
        return self.marker in names or (bool(names) and all(self.owns(n) for n in names))

    def check_place(self) -> Path:
        """The path alone: usable (:func:`check_output_dir`) and no input; returns the absolute path."""
        path = check_output_dir(self.raw, self.flag)
        check_not_input(self.raw, self.inputs, self.flag)
        return path

    def check(self, overwrite: bool) -> Path:
        """Every rule that can be checked before work starts; returns the absolute path.

        Raises:
            StorageError / OutputExistsError: the path is unusable, is or holds an input, holds an
                output of this command (without ``overwrite``) or anything else.
        """
        path = self.check_place()
        if not path.exists():
            return path
        names = self._content()
        if not names:
            return path
        if self.holds_output():
            if not overwrite:
                raise OutputExistsError(
                    f"{path} already holds an hd {self.what} output ({self.marker}); pass --overwrite to replace "
                    f"it, or choose another {self.flag}"
                )
            return path
        raise OutputExistsError(
            f"{path} is not empty and holds no hd {self.what} output ({self.marker}); hd writes only into a new "
            f"or empty directory or over its own output (--overwrite never replaces other files): choose another "
            f"{self.flag}"
        )

    @contextlib.contextmanager
    def open(self, overwrite: bool) -> Iterator[Path]:
        """Lock the directory (created if missing) and yield an empty staging directory inside it
        (an :class:`OutputTransaction`, staged)."""
        self.check(overwrite)
        self._overwrite = overwrite
        with OutputTransaction(self.path, self.what, staged=True, check=lambda: self.check(overwrite)) as tx:
            self._tx = tx
            try:
                yield tx.staging
            finally:
                self._tx = None

    def commit(self) -> list[Path]:
        """Move every staged file into place (``marker`` last); returns the final paths."""
        if self._tx is None:
            raise StorageError(f"{self.path}: commit outside OutputDir.open")
        self.check(self._overwrite)  # inputs and ownership once more, at commit
        return self._tx.commit(last=self.marker, replaces=self.owns)


def check_output_file(path: str | os.PathLike, flag: str = "output") -> Path:
    """Check that a file can be written at ``path`` (its directory exists and is writable).

    Raises:
        StorageError: like :func:`check_output_dir`; also an existing directory at ``path`` or a
            missing parent directory.
    """
    p = _check_text_path(path, flag)
    if p.is_dir():
        raise StorageError(f"{flag} {p} is a directory")
    parent = p.parent
    if not parent.exists():
        anc = _nearest_existing(p)
        if not anc.is_dir():
            raise StorageError(f"{flag} {p}: {anc} is not a directory")
        raise StorageError(f"{flag} {p}: the directory {parent} does not exist")
    if not parent.is_dir():
        raise StorageError(f"{flag} {p}: {parent} is not a directory")
    _probe_writable(parent, flag, p)
    return p


def make_subdir(root: Path, name: str) -> Path:
    """``root/name`` as a real directory inside ``root`` (created if missing; a symbolic link is refused)."""
    path = Path(root) / name
    if path.is_symlink():
        raise StorageError(f"{path} is a symbolic link; hd writes only real directories inside its output")
    if os.path.lexists(path) and not path.is_dir():
        raise StorageError(f"{path} exists and is not a directory")
    make_dirs(path)
    return path


def first_missing(path: Path) -> Path | None:
    """The top-most directory that ``mkdir -p path`` would create (None when ``path`` exists)."""
    path = Path(os.path.abspath(path))
    if os.path.lexists(path):
        return None
    top = path
    while not os.path.lexists(top.parent):
        top = top.parent
    return top


def remove_empty_dirs(path: Path, top: Path | None) -> None:
    """Remove ``path`` and its parents up to ``top`` while they are empty (undo a ``mkdir -p``)."""
    if top is None:
        return
    path, top = Path(os.path.abspath(path)), Path(os.path.abspath(top))
    while path.is_relative_to(top):
        try:
            path.rmdir()
        except OSError:
            return
        if path == top:
            return
        path = path.parent


def make_dirs(path: Path) -> None:
    """``mkdir -p`` whose OS errors become a StorageError naming the path."""
    try:
        Path(path).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StorageError(describe_os_error(exc, path)) from exc


# --------------------------------------------------------------------------------------- GDAL writes
# OS errors GDAL and libtiff report only as text (their strerror), most likely first.
_GDAL_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EIO)


@contextlib.contextmanager
def captured_gdal_errors() -> Iterator[list[str]]:
    """GDAL's and libtiff's error messages while the block runs, collected into the yielded list
    (filled when the block ends) instead of being printed; their other messages are dropped.

    GDAL reports a failed write as messages, not as an exception (a failed flush on close is
    silent): through rasterio's logger, through GDAL's default handler (``ERROR 1: ...`` on
    standard error) and, for libtiff's own I/O, straight to file descriptor 2
    (``_tiffWriteProc: No space left on device.``). All three are captured: the logger's records,
    and descriptor 2, redirected for the block to an in-memory file (``memfd``; an unlinked
    temporary file where there is none). Keep the block short: whatever else is written to
    descriptor 2 meanwhile is captured too.
    """
    import logging
    import sys

    import rasterio

    messages: list[str] = []

    class _Collect(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            text = record.getMessage()
            if record.levelno >= logging.ERROR or "signalled an error" in text:
                messages.append(text)

    logger = logging.getLogger("rasterio")
    handler = _Collect(logging.DEBUG)
    previous = (logger.level, logger.propagate)
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    logger.propagate = False
    sys.stderr.flush()
    sink = _memory_file()
    saved = os.dup(2)
    os.dup2(sink, 2)
    try:
        with rasterio.Env():
            yield messages
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        logger.removeHandler(handler)
        logger.setLevel(previous[0])
        logger.propagate = previous[1]
        os.lseek(sink, 0, os.SEEK_SET)
        chunks = []
        while chunk := os.read(sink, 1 << 16):
            chunks.append(chunk)
        os.close(sink)
        lines = b"".join(chunks).decode(errors="replace").splitlines()
        messages.extend(
            line.strip()
            for line in lines
            if line.startswith("ERROR") or any(os.strerror(code) in line for code in _GDAL_ERRNOS)
        )


def _memory_file() -> int:
    """A readable and writable descriptor of a file that lives in memory, or at least has no name."""
    if hasattr(os, "memfd_create"):
        return os.memfd_create("hd-gdal-messages", os.MFD_CLOEXEC)
    fd, name = tempfile.mkstemp(prefix="hd-gdal-messages-")
    os.unlink(name)
    return fd


def gdal_write_error(path: str | os.PathLike, messages: list[str]) -> StorageError:
    """One line for GDAL's messages about a failed write of ``path``: the OS error they name (``PATH:
    no space left on device; ...``), else the first message."""
    text = " ".join(messages)
    for code in _GDAL_ERRNOS:
        if os.strerror(code).lower() in text.lower():
            return StorageError(describe_os_error(OSError(code, os.strerror(code)), path))
    first = messages[0] if messages else "unknown error"
    return StorageError(f"{path}: GDAL could not write it ({_short(Exception(first))})")


class GeoTiffWriter:
    """A GeoTIFF written window by window through GDAL (maps too large to build in memory), whose
    every failure - a full disk included - is one :class:`StorageError` naming the file.

    ``path`` is where GDAL writes; ``profile`` the creation options (``rasterio.open(path, "w",
    **profile)``). Each call runs under :func:`captured_gdal_messages`, so nothing of GDAL's is
    printed; an exception or an error message becomes the error, and :meth:`close` (which flushes
    GDAL's block cache, where most write errors surface) raises too. The caller removes the file
    after an error (hd writes these files into a staging directory).
    """

    def __init__(self, path: str | os.PathLike, profile: dict[str, Any]) -> None:
        import rasterio
        from rasterio.errors import NotGeoreferencedWarning

        self.path = Path(path)
        self._dst: Any = None
        with self._checked(), warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)  # maps in local metres are intended
            self._dst = rasterio.open(self.path, "w", **profile)

    @contextlib.contextmanager
    def _checked(self) -> Iterator[None]:
        from rasterio.errors import RasterioError

        with captured_gdal_errors() as messages:
            try:
                yield
            except OSError as exc:  # RasterioIOError included
                messages.append(exc.strerror or str(exc) or type(exc).__name__)
            except RasterioError as exc:
                messages.append(str(exc) or type(exc).__name__)
        if messages:
            self.abandon()
            raise gdal_write_error(self.path, messages)

    def abandon(self) -> None:
        """Close GDAL's handle after a failure, its messages discarded (a no-op once closed)."""
        if self._dst is not None:
            dst, self._dst = self._dst, None
            with captured_gdal_errors(), contextlib.suppress(Exception):  # it has already failed
                dst.close()

    def write(self, array: np.ndarray, window: Any) -> None:
        """Write ``array`` into band 1 at ``window`` (a rasterio Window)."""
        if self._dst is None:
            raise StorageError(f"{self.path}: already closed")
        with self._checked():
            self._dst.write(array, 1, window=window)

    def close(self) -> None:
        """Flush and close the file (idempotent; raises when the flush failed)."""
        if self._dst is None:
            return
        with self._checked():
            dst, self._dst = self._dst, None
            dst.close()


# --------------------------------------------------------------------------------------- writer lock
_HELD_LOCK_FDS: set[int] = set()


def _close_inherited_locks() -> None:
    """In a forked child: close (never unlock) the lock descriptors, so the lock dies with its holder."""
    for fd in list(_HELD_LOCK_FDS):
        with contextlib.suppress(OSError):
            os.close(fd)
    _HELD_LOCK_FDS.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_close_inherited_locks)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OSError:
        return False
    try:  # a zombie (dead, not yet reaped) holds no lock
        with open(f"/proc/{pid}/stat", "rb") as fh:
            return fh.read().rsplit(b")", 1)[-1].split()[0] != b"Z"
    except OSError:
        return True


def lock_holder(directory: str | os.PathLike) -> int | None:
    """PID of the live process that holds ``directory``'s writer lock, or None.

    The lock counts as held only while some process holds the ``flock`` (probed with a shared,
    non-blocking lock that is released at once, so a writer is never kept waiting): a stale lock
    file naming a PID that now belongs to an unrelated live process is not a writer at work.
    """
    try:
        fd = os.open(Path(directory) / LOCK_NAME, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            pass  # held: read the holder's PID below
        except OSError:
            return None
        else:
            fcntl.flock(fd, fcntl.LOCK_UN)
            return None  # nobody holds it: a stale file
        text = os.pread(fd, 32, 0).decode(errors="replace").strip()
    finally:
        os.close(fd)
    try:
        pid = int(text.split()[0])
    except (ValueError, IndexError):
        return None
    return pid if pid > 0 and _pid_alive(pid) else None


class WriterLock:
    """Exclusive writer lock of a directory: ``flock`` on ``DIR/.hd-lock``, the holder's PID inside.

    Use as a context manager around everything a command writes in ``directory`` (which must
    exist). The lock file is removed on release; the kernel releases the lock when the holder
    dies. Forked children close their copy of the descriptor (they never hold the lock).

    Raises:
        LockedError: another live process holds the lock (message names its PID).
        StorageError: the lock file cannot be created (read-only, permission, disk full).
    """

    def __init__(self, directory: str | os.PathLike, what: str = "directory") -> None:
        self.directory = Path(directory)
        self.path = self.directory / LOCK_NAME
        self.what = what
        self._fd: int | None = None

    def acquire(self) -> WriterLock:
        for _ in range(20):
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o644)
            except OSError as exc:
                raise StorageError(
                    f"cannot lock {self.directory} for writing: {describe_os_error(exc, self.path)}"
                ) from exc
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:  # never truncate another file through a link
                os.close(fd)
                raise StorageError(
                    f"cannot lock {self.directory} for writing: {self.path} is not a plain file; remove it"
                )
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError as exc:
                try:
                    holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
                finally:
                    os.close(fd)
                raise LockedError(
                    f"{self.directory} is being written by another hd process (PID {holder}); "
                    "wait for it to finish or stop it, then re-run"
                ) from exc
            except OSError as exc:
                os.close(fd)
                raise StorageError(
                    f"cannot lock {self.directory} for writing: {describe_os_error(exc, self.path)}"
                ) from exc
            try:  # the file may have been removed by the previous holder between open and flock
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if not same:
                os.close(fd)
                continue
            with contextlib.suppress(OSError):  # the PID is informational; a full disk must not stop here
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            self._fd = fd
            _HELD_LOCK_FDS.add(fd)
            return self
        raise StorageError(f"cannot lock {self.directory} for writing: the lock file keeps changing")

    def release(self) -> None:
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            with contextlib.suppress(OSError):
                if os.stat(self.path).st_ino == os.fstat(fd).st_ino:
                    os.unlink(self.path)
        finally:
            _HELD_LOCK_FDS.discard(fd)
            os.close(fd)

    @property
    def held(self) -> bool:
        return self._fd is not None

    def __enter__(self) -> WriterLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()
