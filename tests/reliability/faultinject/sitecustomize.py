"""Fault injection for the reliability catalogue, loaded by every Python process of a test run.

Tests put this directory first on PYTHONPATH and set ``HD_TEST_FAULTS=1``; Python imports
``sitecustomize`` at start-up, so the command under test *and its worker processes* (spawned
interpreters) install the same faults. Nothing here is part of hd.

Environment (all optional):

* ``HD_TEST_WRITE_PAUSE=GLOB:SECONDS`` - when hd writes a file whose final name matches GLOB,
  write half of it, then pause (the moment a kill test waits for: a partial file on disk) until
  SECONDS have passed or the file ``$HD_TEST_RELEASE`` exists;
* ``HD_TEST_ENOSPC=GLOB`` - writing a file whose final name matches GLOB fails with ENOSPC after
  half of it is written (a full disk);
* ``HD_TEST_SLEEP=MODULE.[CLASS.]FUNCTION:SECONDS`` - sleep before each call of that function (e.g.
  the terrain generator, to kill a build while it runs); a marker file ``$HD_TEST_MARK_DIR/FUNCTION``
  is created when the call starts; with ``HD_TEST_SLEEP_FORKED_ONLY=1`` only in forked children
  (DataLoader workers).
"""

from __future__ import annotations

import errno
import fnmatch
import functools
import importlib
import os
import time


def _final_name(fd: int) -> str:
    """Final name of the file hd is writing through ``fd`` (its temporary name is .NAME.partial-PID)."""
    try:
        name = os.path.basename(os.readlink(f"/proc/self/fd/{fd}"))
    except OSError:
        return ""
    if name.startswith(".") and ".partial-" in name:
        name = name[1:].rsplit(".partial-", 1)[0]
    return name


def _install() -> None:
    from hdcore.storage import atomic as storage

    pause = os.environ.get("HD_TEST_WRITE_PAUSE", "")
    enospc = os.environ.get("HD_TEST_ENOSPC", "")
    real_write = storage._write_all

    def write_all(fd: int, data: bytes | memoryview) -> None:
        name = _final_name(fd)
        view = memoryview(data).cast("B")
        if enospc and fnmatch.fnmatch(name, enospc):
            real_write(fd, view[: len(view) // 2])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        if pause:
            pattern, seconds = pause.rsplit(":", 1)
            if fnmatch.fnmatch(name, pattern):
                real_write(fd, view[: len(view) // 2])
                os.fsync(fd)
                release = os.environ.get("HD_TEST_RELEASE", "")
                deadline = time.monotonic() + float(seconds)
                while time.monotonic() < deadline and not (release and os.path.exists(release)):
                    time.sleep(0.01)
                real_write(fd, view[len(view) // 2 :])
                return
        real_write(fd, view)

    storage._write_all = write_all

    sleep = os.environ.get("HD_TEST_SLEEP", "")
    if sleep:
        target, seconds = sleep.rsplit(":", 1)
        parts = target.split(".")
        for cut in range(len(parts) - 1, 0, -1):  # the longest importable prefix, then attributes
            try:
                module = importlib.import_module(".".join(parts[:cut]))
                break
            except ImportError:
                continue
        for attr in parts[cut:-1]:
            module = getattr(module, attr)
        func_name = parts[-1]
        real = getattr(module, func_name)
        mark_dir = os.environ.get("HD_TEST_MARK_DIR", "")
        forked_only = os.environ.get("HD_TEST_SLEEP_FORKED_ONLY") == "1"
        installer = os.getpid()

        @functools.wraps(real)
        def slow(*args, **kwargs):
            if forked_only and os.getpid() == installer:
                return real(*args, **kwargs)
            if mark_dir:
                open(os.path.join(mark_dir, func_name), "w").close()
            time.sleep(float(seconds))
            return real(*args, **kwargs)

        setattr(module, func_name, slow)


if os.environ.get("HD_TEST_FAULTS"):
    _install()
