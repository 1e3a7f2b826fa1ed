"""The forms of the uncertainty threshold H_t (``--threshold``), parsed and checked: ``mean``,
``quantile:Q``, ``risk:ALPHA`` and ``nats:H`` (the rules themselves: ``hdnet.thresholds``).

A leaf module without PyTorch or NumPy: the settings of ``hd eval`` and ``hd detect``
(``hdnet.eval_settings``, ``hdnet.detect_settings``) check a threshold as the command line is read,
before anything heavy is imported or loaded.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

from hdnet.errors import HdNetError


@dataclass(frozen=True)
class ThresholdSpec:
    """How to pick H_t: ``kind`` "mean", "quantile" (value = Q), "risk" (value = alpha) or "nats"
    (value = H_t itself, in nats: fixed, no calibration)."""

    kind: Literal["mean", "quantile", "risk", "nats"]
    value: float | None = None

    def __str__(self) -> str:
        return self.kind if self.value is None else f"{self.kind}:{self.value:g}"


_SPEC = re.compile(r"^(mean|quantile|risk|nats)(?::(.+))?$")
# The threshold forms, worded once for every command's errors and help.
SPEC_FORMS = "'mean', 'quantile:Q', 'risk:ALPHA' or 'nats:H'"


def parse_threshold_spec(spec: str) -> ThresholdSpec:
    """Parse ``mean``, ``quantile:Q`` (Q in [0, 1]), ``risk:ALPHA`` (alpha in (0, 1)) or ``nats:H``
    (a fixed H_t >= 0 nats; ``inf`` keeps every pixel)."""
    match = _SPEC.match(spec.strip().lower()) if isinstance(spec, str) else None
    if match is None:
        raise HdNetError(f"threshold spec {spec!r} is not one of {SPEC_FORMS}.")
    kind, arg = match.group(1), match.group(2)
    if kind == "mean":
        if arg is not None:
            raise HdNetError(f"threshold spec {spec!r}: 'mean' takes no value.")
        return ThresholdSpec("mean")
    if arg is None:
        raise HdNetError(f"threshold spec {spec!r}: '{kind}' needs a value, e.g. '{kind}:0.1'.")
    try:
        value = float(arg)
    except ValueError as exc:
        raise HdNetError(f"threshold spec {spec!r}: {arg!r} is not a number.") from exc
    if kind == "quantile" and not 0.0 <= value <= 1.0:
        raise HdNetError(f"threshold spec {spec!r}: the quantile Q must be in [0, 1].")
    if kind == "risk" and not 0.0 < value < 1.0:
        raise HdNetError(f"threshold spec {spec!r}: the risk level alpha must be in (0, 1).")
    if kind == "nats" and not value >= 0.0:
        raise HdNetError(f"threshold spec {spec!r}: the entropy threshold H must be >= 0 nats.")
    return ThresholdSpec(kind, value)  # type: ignore[arg-type]  # kind: one of KINDS, checked above


def unreachable_risk_words(spec: str, n_images: int, needed: int) -> str:
    """One sentence: the risk level of ``spec`` cannot be certified with ``n_images`` calibration
    images and how many it needs (the console warning, the report and ``hd detect``'s summary)."""
    return (
        f"{spec} cannot be certified with {n_images} validation image(s): conformal risk control needs "
        f"alpha >= 1/(n+1), i.e. at least {needed} validation images, so H_t = 0 nats and every pixel is "
        f"uncertain (V/C 0 %); calibrate on more validation images or use alpha >= "
        f"{1.0 / (n_images + 1):.3g}"
    )
