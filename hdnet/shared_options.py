"""The options that several ``hd`` commands share, declared once (the ``*_option`` factories).

The options of one command's settings are generated from the settings dataclass
(:func:`hdcore.setting.click_options`); these are the ones around them: where to write, how many
workers, the seed, the run's threshold.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from hdcore.setting import DIRECTORY, FILE_OR_DIRECTORY, bounded, setting
from hdnet import defaults as net_defaults
from hdnet import limits as net_limits
from hdnet import threshold_spec, uncertainty
from lidarsim import defaults as lidar_defaults
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
    return click.option("--recipe", type=FILE_OR_DIRECTORY, required=required, default=None, help=what)


def dtm_option(what: str) -> Decorator:
    return click.option("--dtm", "dtm_path", type=FILE_OR_DIRECTORY, default=None, help=what)


# The threshold forms, written from the registered rules (hdnet.threshold_spec.RULES).
THRESHOLD_FORMS = threshold_spec.help_text()


# ----------------------------------------------------- settings that several settings classes share
def mc_samples_setting() -> Any:
    """The MC-dropout samples M of an inference (``hd eval``, ``hd detect``)."""
    return setting(net_defaults.MC_SAMPLES, "MC-dropout samples M", bound=net_limits.MC_SAMPLES)


def batch_size_setting(what: str) -> Any:
    """Inputs per inference batch: ``what`` names them."""
    return setting(net_defaults.BATCH_SIZE, what, bound=net_limits.BATCH_SIZE)


def threshold_setting(what: str = "") -> Any:
    """The uncertainty threshold's form (``hdnet.thresholds.parse_threshold_spec``)."""
    return setting(net_defaults.THRESHOLD_SPEC, f"{THRESHOLD_FORMS} {what}".strip(), kind=str)


def uncertainty_setting(what: str = "") -> Any:
    """The uncertainty score the threshold applies to (one of ``hdnet.uncertainty.SCORES``)."""
    words = f"The per-pixel uncertainty score (nats) the threshold H_t applies to. {uncertainty.help_text()}"
    return setting(uncertainty.DEFAULT, f"{words}. {what}".strip(), choices=tuple(uncertainty.SCORES))


def seed_setting(what: str) -> Any:
    """A command's seed: ``what`` it seeds."""
    return setting(lidar_defaults.SEED, f"Seed of {what}", bound=limits.SEED)


# How a labelling is named on the command line (hdlabels.store.find_labeling), worded once.
LABELS_FORMS = (
    "a full name, or an alias: paper or hd (the convention's labelling, the clean scan's when it has both "
    "truths), paper+terrain or hd+terrain (its terrain truth's)"
)


def labels_setting(what: str) -> Any:
    """The labelling a command reads: ``what``, then how it is named (None: the default the command says)."""
    return setting(None, f"{what}: {LABELS_FORMS}", kind=str, metavar="NAME")


# Where a threshold is calibrated: at the run's reference noise level, or at each noise level.
CALIBRATIONS: tuple[str, ...] = ("reference", "each")


def calibrate_setting(what: str) -> Any:
    """Where the threshold is calibrated (one of :data:`CALIBRATIONS`)."""
    return setting(CALIBRATIONS[0], what, choices=CALIBRATIONS)
