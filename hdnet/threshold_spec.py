"""The threshold rules of H_t (``--threshold``) as registered objects, and their parsed form.

One class per rule (``mean``, ``quantile:Q``, ``risk:ALPHA``, ``nats:H``), as
``hdlabels.conventions`` does for label conventions: each knows the form it is written in, how to
check its value, how to select H_t (nats) from a calibration set, and what it adds to the
threshold's record. ``RULES`` registers them; the parser, the error wording (``SPEC_FORMS``) and the
command-line help (:func:`help_text`) are written from it, so a new rule is one class here (its
calibration arithmetic, when it needs new arithmetic, in ``hdnet.thresholds``). Callers ask
``spec.rule``, never compare rule names.

A leaf module without PyTorch or NumPy: the settings of ``hd eval`` and ``hd detect``
(``hdnet.eval_settings``, ``hdnet.detect_settings``) check a threshold as the command line is read,
before anything heavy is imported or loaded.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import ClassVar, Protocol

from hdnet.errors import HdNetError
from hdnet.report_json import ThresholdJson

LOSS_BOUND = 1.0  # B: the false-safe rate is a fraction of pixels


class Calibration(Protocol):
    """What a rule reads from a calibration set (``hdnet.thresholds.EntropyCalibration``); nats."""

    def mean(self) -> float: ...

    def quantile(self, q: float) -> float: ...

    def fraction_below(self, threshold_nats: float) -> float: ...

    def risk_control_threshold(self, alpha: float) -> float: ...


class ThresholdRule:
    """One way of picking H_t. Subclasses set the class attributes and override what differs.

    Attributes:
        name: the rule's word in a spec (``risk`` in ``risk:0.05``).
        form: how it is written, with its value's letter (``risk:ALPHA``).
        words: what it means, for the command-line help.
        takes_value: True when the spec carries a number.
        calibrated: False for a fixed H_t that no calibration changes (and no guard lowers).
        is_mean: True when H_t is the mean validation score (the paper's rule): its record gives the
            mean's own quantile (``mean_quantile``) and no ``value_quantile``.
        certifies_risk: True when the rule certifies a false-safe rate (its record says whether the
            calibration images reach it; ``hd eval`` measures the achieved rate).
    """

    name: ClassVar[str]
    form: ClassVar[str]
    words: ClassVar[str]
    takes_value: ClassVar[bool] = True
    calibrated: ClassVar[bool] = True
    is_mean: ClassVar[bool] = False
    certifies_risk: ClassVar[bool] = False

    def check(self, spec: str, value: float) -> None:
        """Raise ``HdNetError`` (one line naming ``spec``) when ``value`` is out of the rule's range."""

    def select(self, value: float | None, calibration: Calibration) -> float:
        """H_t (nats) for the rule's ``value`` from ``calibration``."""
        raise NotImplementedError

    def quantile_entry(self, calibration: Calibration, h_t: float) -> ThresholdJson:
        """The record's ``value_quantile``: where H_t lies among the validation scores (the fraction below it)."""
        return {"value_quantile": calibration.fraction_below(h_t)}

    def reach(self, value: float | None, n_images: int) -> ThresholdJson:
        """The record's reachability entries on ``n_images`` calibration images (none by default)."""
        return {}


class MeanRule(ThresholdRule):
    """The mean score over the valid validation pixels (paper default, after Mukhoti & Gal 2018)."""

    name = "mean"
    form = "mean"
    words = "the validation split's mean entropy, the paper's"
    takes_value = False
    is_mean = True

    def select(self, value: float | None, calibration: Calibration) -> float:
        return calibration.mean()

    def quantile_entry(self, calibration: Calibration, h_t: float) -> ThresholdJson:
        return {}  # the record's mean_quantile says it


class QuantileRule(ThresholdRule):
    """The Q-quantile (Q in [0, 1]) of the valid validation scores (paper, "Effect of Varying the
    Uncertainty Threshold")."""

    name = "quantile"
    form = "quantile:Q"
    words = "the validation split's Q-quantile, Q in [0, 1]"

    def check(self, spec: str, value: float) -> None:
        if not 0.0 <= value <= 1.0:
            raise HdNetError(f"threshold spec {spec!r}: the quantile Q must be in [0, 1].")

    def select(self, value: float | None, calibration: Calibration) -> float:
        return calibration.quantile(float(value))  # type: ignore[arg-type]  # parse gives it a value


class RiskRule(ThresholdRule):
    """Conformal risk control of the false-safe rate at level alpha in (0, 1) (``hdnet.thresholds``)."""

    name = "risk"
    form = "risk:ALPHA"
    words = "false-safe rate at most ALPHA, by conformal risk control"
    certifies_risk = True

    def check(self, spec: str, value: float) -> None:
        if not 0.0 < value < 1.0:
            raise HdNetError(f"threshold spec {spec!r}: the risk level alpha must be in (0, 1).")

    def select(self, value: float | None, calibration: Calibration) -> float:
        return calibration.risk_control_threshold(float(value))  # type: ignore[arg-type]  # parse gives it one

    def reach(self, value: float | None, n_images: int) -> ThresholdJson:
        return {} if value is None else risk_reach(value, n_images)


class NatsRule(ThresholdRule):
    """A fixed H_t >= 0 nats (``inf`` keeps every pixel): no calibration."""

    name = "nats"
    form = "nats:H"
    words = "fixed, in nats, no calibration"
    calibrated = False

    def check(self, spec: str, value: float) -> None:
        if not value >= 0.0:
            raise HdNetError(f"threshold spec {spec!r}: the entropy threshold H must be >= 0 nats.")

    def select(self, value: float | None, calibration: Calibration) -> float:
        return float(value)  # type: ignore[arg-type]  # parse gives it a value


# The registry: one instance per rule, in the order the help lists them.
RULES: dict[str, ThresholdRule] = {rule.name: rule for rule in (MeanRule(), QuantileRule(), RiskRule(), NatsRule())}


def _forms() -> str:
    quoted = [f"'{rule.form}'" for rule in RULES.values()]
    return ", ".join(quoted[:-1]) + f" or {quoted[-1]}"


# The threshold forms, worded once for every command's errors.
SPEC_FORMS = _forms()


def help_text() -> str:
    """The command-line help of ``--threshold``: every registered rule, its form and meaning."""
    rules = "; ".join(f"{rule.form} ({rule.words})" for rule in RULES.values())
    return f"Uncertainty threshold: {rules}. The calibrated ones use a validation split."


@dataclass(frozen=True)
class ThresholdSpec:
    """How to pick H_t: ``kind`` names a registered rule (``RULES``), ``value`` is its number
    (Q, alpha or H_t in nats) or None for a rule that takes none."""

    kind: str
    value: float | None = None

    def __str__(self) -> str:
        return self.kind if self.value is None else f"{self.kind}:{self.value:g}"

    @property
    def rule(self) -> ThresholdRule:
        """The registered rule this spec names."""
        return RULES[self.kind]

    def select(self, calibration: Calibration) -> float:
        """H_t (nats) from ``calibration``, by the spec's rule."""
        return self.rule.select(self.value, calibration)

    def reach(self, n_images: int) -> ThresholdJson:
        """The record's reachability entries on ``n_images`` calibration images (``ThresholdRule.reach``)."""
        return self.rule.reach(self.value, n_images)


_SPEC = re.compile(r"^(" + "|".join(map(re.escape, RULES)) + r")(?::(.+))?$")


def parse_threshold_spec(spec: str) -> ThresholdSpec:
    """Parse one of the registered forms (``SPEC_FORMS``): ``mean``, ``quantile:Q`` (Q in [0, 1]),
    ``risk:ALPHA`` (alpha in (0, 1)) or ``nats:H`` (a fixed H_t >= 0 nats; ``inf`` keeps every pixel)."""
    match = _SPEC.match(spec.strip().lower()) if isinstance(spec, str) else None
    if match is None:
        raise HdNetError(f"threshold spec {spec!r} is not one of {SPEC_FORMS}.")
    rule, arg = RULES[match.group(1)], match.group(2)
    if not rule.takes_value:
        if arg is not None:
            raise HdNetError(f"threshold spec {spec!r}: '{rule.name}' takes no value.")
        return ThresholdSpec(rule.name)
    if arg is None:
        raise HdNetError(f"threshold spec {spec!r}: '{rule.name}' needs a value, e.g. '{rule.name}:0.1'.")
    try:
        value = float(arg)
    except ValueError as exc:
        raise HdNetError(f"threshold spec {spec!r}: {arg!r} is not a number.") from exc
    rule.check(spec, value)
    return ThresholdSpec(rule.name, value)


def risk_images_needed(alpha: float) -> int:
    """The fewest calibration images n with which ``risk:alpha`` can certify any pixel.

    Conformal risk control keeps H_t = 0 (every pixel uncertain) unless B/(n+1) <= alpha, whatever
    the network does: even a network with no false-safe pixel adds the bound B = 1 of the unseen
    image, weighted 1/(n+1). So n >= B/alpha - 1 (19 images for alpha = 0.05, 99 for 0.01); n counts
    the calibration images, every image of the validation split(s) at the calibration noise level
    (``EntropyCalibration.n_images``), not their pixels.
    """
    if not 0.0 < alpha < 1.0:
        raise HdNetError(f"the risk level alpha must be in (0, 1), got {alpha}.")
    n = max(1, math.ceil(LOSS_BOUND / alpha) - 1)
    while LOSS_BOUND / (n + 1) > alpha:  # floating point: the exact condition decides
        n += 1
    while n > 1 and LOSS_BOUND / n <= alpha:
        n -= 1
    return n


def risk_reach(alpha: float, n_images: int) -> ThresholdJson:
    """The reachability entries of a ``risk:alpha`` threshold's record calibrated on ``n_images``
    images: ``unreachable`` (True when H_t is 0 by construction: alpha < B/(n+1)) and
    ``needs_images`` (``risk_images_needed``)."""
    needed = risk_images_needed(alpha)
    return {"unreachable": n_images < needed, "needs_images": needed}


def unreachable_risk_words(spec: str, n_images: int, needed: int) -> str:
    """One sentence: the risk level of ``spec`` cannot be certified with ``n_images`` calibration
    images and how many it needs (the console warning, the report and ``hd detect``'s summary)."""
    return (
        f"{spec} cannot be certified with {n_images} validation image(s): conformal risk control needs "
        f"alpha >= 1/(n+1), i.e. at least {needed} validation images, so H_t = 0 nats and every pixel is "
        f"uncertain (V/C 0 %); calibrate on more validation images or use alpha >= "
        f"{1.0 / (n_images + 1):.3g}"
    )
