"""Schemas and side files: schema checks, bounded reads of regular files, JSON."""

from __future__ import annotations

import json
import math
import os
import stat
from pathlib import Path
from typing import Any

from hdcore.errors import DamagedFileError, FormatError, StorageError
from hdcore.storage.oserrors import describe_os_error


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
