"""SHA-256 of files and bytes, and the check of a file against its recorded checksum."""

from __future__ import annotations

import hashlib
import os
import re
import stat
from pathlib import Path
from typing import Any

from hdcore.errors import DamagedFileError, FormatError, StorageError
from hdcore.storage.oserrors import describe_os_error

_HASH_CHUNK_BYTES = 1 << 22
_SHA256_RE = re.compile(r"^[0-9a-f]{64}$")


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
