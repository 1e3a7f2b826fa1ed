"""The names of a run directory's files (``hd train --out``), in a leaf module that imports nothing
heavy, so that a command can look at a run before PyTorch is imported: the run record
``config.json`` (``hdnet.run_record``), the checkpoints ``last.pt`` and ``best.pt`` and the epochs'
``metrics.csv`` (``hdnet.train``), and the words that say which checkpoint a command read and why
(``checkpoint_words``)."""

from __future__ import annotations

CONFIG = "config.json"
LAST, BEST, METRICS = "last.pt", "best.pt", "metrics.csv"

# Why hd eval, hd detect, hd descend and hd export-model read a run's last.pt, not best.pt: in one clause.
LAST_WHY = (
    "the end of the training schedule; best.pt is not scored because it is the epoch chosen on the "
    "validation split, which also calibrates H_t"
)


def checkpoint_reason(checkpoint: str) -> str:
    """Why a command read the checkpoint ``checkpoint`` (a path): ``LAST_WHY`` for a run's ``last.pt``,
    ``the file given`` for another file (``RUN`` given as a checkpoint file, ``run/best.pt`` say)."""
    return LAST_WHY if _file_name(checkpoint) == LAST else "the file given"


def checkpoint_words(checkpoint: str) -> str:
    """The checkpoint a command read, by file name, and why: ``checkpoint: last.pt (the end of the
    training schedule; best.pt ...)``, or ``checkpoint: best.pt (the file given)``."""
    return f"checkpoint: {_file_name(checkpoint)} ({checkpoint_reason(checkpoint)})"


def _file_name(path: str) -> str:
    """The last part of a path, POSIX or Windows."""
    return path.replace("\\", "/").rsplit("/", 1)[-1]
