"""hd's errors: one root for the whole project, and the storage layer's errors under it.

Every error hd raises for bad input or a bad file derives from :class:`HdError`; its message is
one sentence that names the value, option or file and what is wrong with it, and the ``hd``
command prints it as one ``Error: ...`` line with exit status 1. A program using hd as a library
catches ``HdError`` for "the input was refused" and lets everything else through as a bug.
``HdError`` subclasses ``ValueError``, so code written against the earlier hierarchies still
catches them. An error keeps its kind and its cause on its way up: the domain packages let a
``LockedError`` or ``DamagedFileError`` of the storage layer pass as it is (never re-worded into
their own error from its text), code that adds context raises the same kind
(``raise type(exc)(f"{where}: {exc}") from exc``), and every re-raise names its cause
(``from exc``; ``tests/hdnet/test_error_causes.py`` checks every package). The core holds the root
and the errors of its storage layer (``hdcore.storage``); each domain package keeps a small
hierarchy under the root in its ``errors`` module::

    HdError
    ├── OutputExistsError          an output directory that must not be overwritten (this module)
    ├── StorageError               a file or directory that cannot be written or read (this module)
    │   ├── LockedError            another hd process is writing the directory
    │   └── FormatError            not a format (or major version) this hd reads
    │       └── DamagedFileError   checksum mismatch, unreadable chunk, truncated file
    ├── LidarsimError              lidarsim.errors
    │   ├── TerrainError           a DTM file or terrain request that cannot be used
    │   └── RecipeError            a dataset recipe that cannot be read or holds invalid settings
    ├── HdLabelsError              hdlabels.errors
    │   └── LabelStoreError        missing labels, a label shard of an unknown format
    └── HdNetError                 hdnet.errors

Until hd 0.1 the storage errors and ``OutputExistsError`` sat under ``LidarsimError``; catch
``HdError`` (or the error itself) for them.

:class:`WorkerError` is not an input error: a task that failed in a worker process with an
unexpected exception (a bug), re-raised in the parent with the worker's traceback attached.
"""

from __future__ import annotations


class HdError(ValueError):
    """Root of every error hd raises for bad input or a bad file (one-line message)."""


class OutputExistsError(HdError):
    """The output directory already holds something the command must not overwrite."""


class StorageError(HdError):
    """A file or directory that cannot be written or read (the message names the path and the cause)."""


class FormatError(StorageError):
    """A file that is not of a format (or major version) this hd reads."""


class DamagedFileError(FormatError):
    """A file whose bytes are damaged: checksum mismatch, unreadable chunk, truncated."""


class LockedError(StorageError):
    """Another hd process is writing the directory."""


class HdWarning(UserWarning):
    """Something the user should know that does not stop the command (one-line message); the ``hd``
    command prints it as one ``Warning: ...`` line on standard error."""


class WorkerError(RuntimeError):
    """A task failed in a worker with an exception that is not one of hd's input errors."""
