"""The options that several ``hd`` commands share, declared once (the ``*_option`` factories).

The options of one command's settings are generated from the settings dataclass
(:func:`hdcore.setting.click_options`); these are the ones around them: where to write, how many
workers, the scheduler, the recipe, the DTM.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from hdcore.setting import DIRECTORY, FILE_OR_DIRECTORY, bounded
from lidarsim import limits

Decorator = Callable[[Callable[..., Any]], Callable[..., Any]]


def workers_option() -> Decorator:
    return click.option(
        "--workers",
        type=bounded(limits.WORKERS),
        default=None,
        help="Local worker processes (default: all cores).",
    )


def scheduler_option() -> Decorator:
    return click.option(
        "--scheduler", default=None, help="Dask scheduler address (tcp://host:8786) to run the tasks on a cluster."
    )


def overwrite_option(what: str) -> Decorator:
    return click.option("--overwrite", is_flag=True, help=what)


def out_option(
    dest: str, what: str, required: bool = True, directory: bool = True, default: Path | None = None
) -> Decorator:
    return click.option(
        "--out",
        dest,
        required=required,
        default=default,
        show_default=default is not None,
        type=DIRECTORY if directory else FILE_OR_DIRECTORY,
        help=what,
    )


def recipe_option(what: str, required: bool = False) -> Decorator:
    if required:  # click 8.5 takes a required option's explicit default=None as given: omitting it enforces it
        return click.option("--recipe", type=FILE_OR_DIRECTORY, required=True, help=what)
    return click.option("--recipe", type=FILE_OR_DIRECTORY, default=None, help=what)


def dtm_option(what: str) -> Decorator:
    return click.option("--dtm", "dtm_path", type=FILE_OR_DIRECTORY, default=None, help=what)
