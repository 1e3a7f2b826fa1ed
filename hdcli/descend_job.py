"""``hd descend``: the descents of a descent build flown frame by frame by a run trained on mosaics.

:func:`descend_job` runs ``hdnet.descend.descend`` with the command's settings
(:class:`~hdnet.descend_settings.DescendSettings`, described once there) and says what it flew.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from hdcore.outcome import Done


def descend_job(
    run_dir: Path,
    data: Path,
    out_dir: Path,
    settings: dict[str, Any],
    overwrite: bool,
    progress: Callable[[int, int], None] | None = None,
) -> Done:
    """Fly the descents ``settings`` names (``DescendSettings``' fields) of ``data`` with ``run_dir`` into ``out_dir``.

    Raises:
        HdNetError / StorageError: a bad setting before anything is loaded; then what
            ``hdnet.descend.descend`` refuses, before anything is written.
    """
    from hdnet.descend_settings import DescendSettings

    chosen = DescendSettings(**settings, overwrite=overwrite)  # checked before PyTorch is imported

    from hdnet.descend import descend

    result = descend(run_dir, data, out_dir, chosen, progress)
    return Done(result.summary(), {"command": "descend", "out": str(out_dir), **result.record})
