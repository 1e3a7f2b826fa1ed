"""The names of a run directory's files (``hd train --out``), in a leaf module that imports nothing
heavy, so that a command can look at a run before PyTorch is imported: the run record
``config.json`` (``hdnet.run_record``), the checkpoints ``last.pt`` and ``best.pt`` and the epochs'
``metrics.csv`` (``hdnet.train``)."""

from __future__ import annotations

CONFIG = "config.json"
LAST, BEST, METRICS = "last.pt", "best.pt", "metrics.csv"
