"""GDAL writes: GeoTIFFs written window by window with GDAL's messages captured."""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from hdcore.errors import StorageError
from hdcore.storage.oserrors import describe_os_error, short_message

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
    return StorageError(f"{path}: GDAL could not write it ({short_message(Exception(first))})")


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
