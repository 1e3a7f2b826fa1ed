"""``hd mosaic``: the mosaic dataset of a descent build, and what to say.

The settings are :class:`hdlabels.mosaic_dataset.MosaicSettings`' fields; with a recipe, the DEM
grid (side, spacing, convention and gridding) is the recipe's ``[label]`` section's, so that the
mosaics are made on the grid the recipe labels on.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hdcore.outcome import Done


def mosaic_job(
    source: Path,
    out: Path,
    settings: dict[str, Any],
    recipe: Path | None,
    workers: int | None,
    scheduler: str | None,
    overwrite: bool,
    progress: Callable[[int, int], None] | None,
) -> Done:
    """Mosaic the descents of ``source`` into the dataset ``out`` with ``settings`` (MosaicSettings'
    fields); ``recipe`` replaces the DEM settings by its ``[label]`` section's.

    Raises:
        HdLabelsError: a bad value, an unreachable scheduler, before anything is written; and whatever
            ``mosaic_dataset`` refuses.
    """
    from hdlabels.mosaic_dataset import MosaicSettings, mosaic_dataset

    if recipe is not None:
        from hdlabels.settings import LabelSettings
        from lidarsim.recipe import load_recipe

        loaded = load_recipe(recipe)
        label = LabelSettings.from_recipe(loaded.label, str(loaded.path))
        settings = {
            **settings,
            "dem_size": label.dem_size,
            "dem_spacing_m": label.dem_spacing_m,
            "convention": label.convention,
            "gridding": label.gridding,
        }
    chosen = MosaicSettings(**settings)
    if scheduler is not None:
        from lidarsim.parallel import probe_scheduler

        probe_scheduler(scheduler)
    summary = mosaic_dataset(
        source, out, chosen, workers=workers, scheduler=scheduler, overwrite=overwrite, progress=progress
    )
    return Done([summary.paragraph()], {"command": "mosaic", **dataclasses.asdict(summary)})
