"""``hd build-dataset``: a dataset from the command line's settings or from a recipe, and what to say.

The settings are :class:`lidarsim.recipe.BuildSettings`' fields (each described once, as field
metadata: the options and checks are made from them); :func:`build_job` checks where to write,
makes the configuration and builds.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hdcore.outcome import Done
from lidarsim import limits


def build_job(
    out_dir: Path | None,
    settings: dict[str, Any],
    recipe: Path | None,
    workers: int | None,
    scheduler: str | None,
    overwrite: bool,
    progress: Callable[[int, int], None] | None,
    echo: Callable[[str], None],
    max_shards: int = limits.MAX_SHARD_FILES,
    resized: dict[str, Any] | None = None,
) -> Done:
    """Build the dataset of ``settings`` (BuildSettings' fields), or of ``recipe``, into ``out_dir``
    (None: named after the recipe, the DTM or the procedural terrain; ``echo`` says which), writing
    at most ``max_shards`` shard files (``--max-shards``, a bound of this command only: the dataset
    records nothing of it).

    ``resized``: the size settings given with ``recipe`` (``scans``, ``shard_size``); a value other
    than the recipe's is a deviation from it, said here and recorded in the manifest
    (``lidarsim.recipe_deviation``).

    Raises:
        LidarsimError: an unusable output directory or scheduler address, a bad recipe or value,
            a recipe's DTM that is not there, before anything is written; and whatever
            ``build_dataset`` refuses.
    """
    from hdcore.storage import check_output_dir
    from lidarsim.build import build_dataset, default_out_dir
    from lidarsim.recipe import BuildSettings, check_recipe_dtm, load_recipe
    from lidarsim.recipe_deviation import deviate

    if out_dir is not None:
        check_output_dir(out_dir, "--out")
    if scheduler is not None:
        from lidarsim.parallel import check_scheduler_address

        check_scheduler_address(scheduler)
    name = None
    deviation = None
    if recipe is not None:
        loaded = load_recipe(recipe)
        check_recipe_dtm(loaded)
        config, deviation = deviate(loaded, resized or {})
        name = loaded.name if deviation is None else deviation.out_dir_name()
        if deviation is not None:
            echo(
                f"this build deviates from the recipe {loaded.name}: {deviation.words()} (recorded in its manifest; "
                "`hd verify --recipe` names it)"
            )
    else:
        dtm = settings.get("dtm_path")
        config = BuildSettings(**{**settings, "dtm_path": str(dtm) if dtm is not None else None}).to_config()
    if out_dir is None:
        out_dir = default_out_dir(config, name)
        check_output_dir(out_dir, "--out")
        echo(f"no --out given: building into {out_dir}")
    summary = build_dataset(
        out_dir,
        config,
        workers=workers,
        scheduler=scheduler,
        overwrite=overwrite,
        progress=progress,
        max_shards=max_shards,
        recipe_deviation=None if deviation is None else deviation.to_dict(),
    )
    record = {"command": "build-dataset", **dataclasses.asdict(summary)}
    if deviation is not None:
        record["recipe_deviation"] = deviation.to_dict()
    return Done([summary.paragraph()], record)
