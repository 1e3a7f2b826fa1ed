"""``hd label``: DEMs, ALHAT labels and the baseline P(safe) of a dataset, and what to say.

The settings are :class:`hdlabels.settings.LabelSettings`' fields (each described once, as field
metadata: the options, the recipe's ``[label]`` reading and the checks are made from them);
:func:`label_job` makes the lander and the DEM grid and labels.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lidarsim.outcome import Done


def label_job(
    directory: Path,
    settings: dict[str, Any],
    recipe: Path | None,
    workers: int | None,
    scheduler: str | None,
    progress: Callable[[int, int], None] | None,
    truth: str | None = None,
) -> Done:
    """Label the dataset ``directory`` with ``settings`` (LabelSettings' fields), or with the
    ``[label]`` section of ``recipe``; ``truth`` (given: ``clean-scan`` or ``terrain``) replaces the
    recipe's truth, so that one recipe's lander and DEM can be labelled against either truth.

    Raises:
        HdLabelsError: a bad value or lander, an unreachable scheduler, before anything is written;
            and whatever ``label_dataset`` refuses.
    """
    from hdlabels.labeling import label_dataset
    from hdlabels.settings import LabelSettings

    if recipe is not None:
        from lidarsim.recipe import load_recipe

        loaded = load_recipe(recipe)
        label = LabelSettings.from_recipe(loaded.label, str(loaded.path))
        if truth is not None:
            label = dataclasses.replace(label, truth=truth)
    else:
        label = LabelSettings(**settings)
    lander = label.to_lander()
    if scheduler is not None:
        from lidarsim.parallel import probe_scheduler

        probe_scheduler(scheduler)  # a malformed or unreachable address, before anything is written
    grid = label.to_dem_spec()
    summary = label_dataset(
        directory, lander, grid, workers=workers, scheduler=scheduler, progress=progress, truth=label.truth
    )
    return Done([summary.paragraph()], {"command": "label", **dataclasses.asdict(summary)})
