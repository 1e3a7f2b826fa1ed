"""Paths: manifest paths confined to their dataset, output paths checked, output transactions."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from hdcore.errors import FormatError, LockedError, OutputExistsError, StorageError
from hdcore.storage.atomic import PARTIAL_MARK, commit_file, remove_partials
from hdcore.storage.lock import LOCK_NAME, WriterLock
from hdcore.storage.oserrors import describe_os_error

# Longest file-name component most file systems accept, bytes (NAME_MAX on Linux).
NAME_MAX_BYTES = 255


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
