"""``hd demo`` and ``hd reproduce``: the whole chain (build, label, train, evaluate) as one command.

:class:`DemoSettings` and :class:`ReproduceSettings` describe each command's own settings once
(field metadata: options and checks are made from them); :func:`run_demo` and :func:`run_reproduce`
make the :class:`hdcli.pipeline.Pipeline` and run it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hdcore.setting import check, setting
from hdnet import limits
from hdnet.checkpoint_json import EpochProgress
from hdnet.errors import HdNetError
from lidarsim import limits as lidar_limits

# hd reproduce's recipe, one that comes with hd (lidarsim.recipe.shipped_recipe).
PAPER_RECIPE = "mars-paper"


@dataclass(frozen=True)
class DemoSettings:
    """``hd demo``'s scale: scans and epochs (the cpu profile)."""

    scans: int = setting(200, "Scans in the demo dataset", bound=lidar_limits.SCANS)
    epochs: int = setting(10, "Training epochs (cpu profile)", bound=limits.EPOCHS)

    def __post_init__(self) -> None:
        check(self, HdNetError)


@dataclass(frozen=True)
class ReproduceSettings:
    """``hd reproduce``'s training: the profile and its length."""

    profile: str = setting(
        "cpu",
        "Training profile: cpu (about 13 min on 2 cores, trained at 1.67 cm as the paper), robust (about 45 min "
        "on 2 cores, trained across 0 to 10 cm, scored with the robust rule and a noise sweep) or paper (GPU)",
        choices=("cpu", "robust", "paper"),
    )
    epochs: int | None = setting(None, "Training epochs (default: the profile's)", bound=limits.EPOCHS)

    def __post_init__(self) -> None:
        check(self, HdNetError)


def run_demo(
    out_dir: Path,
    settings: DemoSettings,
    workers: int | None,
    echo: Callable[[str], Any],
    progress: Any,
    train_progress: EpochProgress = True,
) -> str:
    """Run the demo chain into ``out_dir`` (re-running resumes); returns what to try next.
    ``train_progress``: how the training shows its epochs (``hdnet.train.train``'s ``progress``)."""
    from hdcli.pipeline import demo_next_steps, demo_pipeline, run_pipeline

    pipeline = demo_pipeline(out_dir, settings.scans, settings.epochs)
    run_pipeline(pipeline, workers, echo=echo, progress=progress, train_progress=train_progress)
    return demo_next_steps(out_dir)


def run_reproduce(
    out_dir: Path,
    recipe: Path | None,
    dtm: Path | None,
    settings: ReproduceSettings,
    workers: int | None,
    echo: Callable[[str], Any],
    progress: Any,
    train_progress: EpochProgress = True,
) -> None:
    """Reproduce the paper from ``recipe`` (default: the shipped mars-paper), optionally on ``dtm``;
    ``train_progress`` as :func:`run_demo`'s."""
    from hdcli.pipeline import reproduce_pipeline, run_pipeline
    from lidarsim.recipe import shipped_recipe

    recipe = recipe if recipe is not None else shipped_recipe(PAPER_RECIPE)
    pipeline = reproduce_pipeline(out_dir, recipe, settings.profile, settings.epochs, dtm)
    run_pipeline(pipeline, workers, echo=echo, progress=progress, train_progress=train_progress)
