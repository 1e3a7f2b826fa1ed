"""One writer per directory: an exclusive ``flock`` on ``DIR/.hd-lock``."""

from __future__ import annotations

import contextlib
import fcntl
import os
import stat
from pathlib import Path

from hdcore.errors import LockedError, StorageError
from hdcore.storage.oserrors import describe_os_error

LOCK_NAME = ".hd-lock"


_HELD_LOCK_FDS: set[int] = set()


def _close_inherited_locks() -> None:
    """In a forked child: close (never unlock) the lock descriptors, so the lock dies with its holder."""
    for fd in list(_HELD_LOCK_FDS):
        with contextlib.suppress(OSError):
            os.close(fd)
    _HELD_LOCK_FDS.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_close_inherited_locks)


def pid_alive(pid: int) -> bool:
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
    return pid if pid > 0 and pid_alive(pid) else None


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
