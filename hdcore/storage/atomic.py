"""Atomic writes: a file built under a hidden temporary name beside its final name, flushed, renamed into place."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from hdcore.bounds import parse_integer
from hdcore.errors import HdError, StorageError
from hdcore.storage.lock import pid_alive
from hdcore.storage.oserrors import describe_os_error

PARTIAL_MARK = ".partial-"


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
            except HdError:
                continue  # not a PID in ASCII digits: not a name hd writes
            if pid != os.getpid() and not pid_alive(pid):
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
