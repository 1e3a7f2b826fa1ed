"""The settings that several of hdnet's settings classes share, declared once (the ``*_setting``
factories: MC samples, batch size, threshold, uncertainty score, seed, labelling, calibration).

The command line's own shared options (where to write, how many workers) are ``hdcli.options``.
"""

from __future__ import annotations

from typing import Any

from hdcore.setting import setting
from hdnet import defaults as net_defaults
from hdnet import limits as net_limits
from hdnet import threshold_spec, uncertainty
from lidarsim import defaults as lidar_defaults
from lidarsim import limits

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
