"""One line for an OS error or an exception (``describe_os_error``, ``short_message``)."""

from __future__ import annotations

import errno
import os


def describe_os_error(exc: OSError, path: str | os.PathLike | None = None) -> str:
    """One line for an OS error: ``PATH: no space left on device...`` (``path``, else the one the error names)."""
    where = path if path is not None else exc.filename
    reason = exc.strerror or (errno.errorcode.get(exc.errno or 0, "") if exc.errno else "") or str(exc)
    if exc.errno == errno.ENOSPC:
        reason = "no space left on device; free some space and re-run the same command to resume"
    elif exc.errno == errno.EDQUOT:
        reason = "disk quota exceeded; free some space and re-run the same command to resume"
    return f"{where}: {reason}" if where is not None else reason


def short_message(exc: BaseException) -> str:
    """The first line of an exception's message, trimmed (h5py messages are long)."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text if len(text) <= 160 else text[:157] + "..."
