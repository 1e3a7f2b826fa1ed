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

from hdcore.outcome import Done


def refuse_url(directory: Path | str) -> None:
    """Refuse to label a dataset at a URL: labels are written into the dataset (label shards and its
    manifest), and hd writes nothing at a URL but through ``hd publish``. The URL's manifest is read
    first, so that a URL that holds no dataset is named as such.

    Raises:
        HdLabelsError: one line with the three commands that label it (pull, label, publish).
        StorageError: the URL holds no dataset, is unreachable, has no credentials.
    """
    from hdlabels.errors import HdLabelsError
    from lidarsim.location import dataset_label, is_url
    from lidarsim.shards import read_manifest

    if not is_url(directory):
        return
    read_manifest(directory)
    url = dataset_label(directory)  # named without its secrets
    raise HdLabelsError(
        f"{url}: hd label writes the labels into the dataset, and a URL is never written to but by "
        f"hd publish; label a local copy: hd pull {url} DIR, hd label DIR, then hd publish DIR "
        f"{url} --overwrite to share the labels"
    )


def label_job(
    directory: Path | str,
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
        HdLabelsError: a dataset at a URL (:func:`refuse_url`), a bad value or lander, an unreachable
            scheduler, before anything is written; and whatever ``label_dataset`` refuses.
    """
    from hdlabels.labeling import label_dataset
    from hdlabels.settings import LabelSettings

    refuse_url(directory)
    if recipe is not None:
        from lidarsim.recipe import load_recipe

        loaded = load_recipe(recipe)
        label = LabelSettings.from_recipe(loaded.label, str(loaded.path))
        if truth is not None:
            label = dataclasses.replace(label, truth=truth)
    else:
        label = LabelSettings(**settings)
    label.to_lander()  # an invalid lander, before the scheduler is probed
    if scheduler is not None:
        from lidarsim.parallel import probe_scheduler

        probe_scheduler(scheduler)  # a malformed or unreachable address, before anything is written
    label.to_dem_spec()  # an invalid grid, before anything is written
    summary = label_dataset(directory, label, workers=workers, scheduler=scheduler, progress=progress)
    return Done([summary.paragraph()], {"command": "label", **dataclasses.asdict(summary)})
