"""The noise levels a network is trained on, and noise sweeps: parsing, drawing, describing.

A run is trained at one noise level (the paper: 1.67 cm), at several levels (``hd train
--train-sigma 0.0167 --train-sigma 0.07``: each training sample takes one of them, drawn uniformly
per sample and epoch) or across a continuous range (``--train-sigma-range 0:0.10``: sigma drawn
uniformly in the range per sample and epoch). Levels that the dataset does not store are made on
the fly from its clean points (``hdlabels.noisy``). The draw is seeded by ``(training seed,
epoch, scan index)`` (``lidarsim.streams.Purpose.TRAINING_DRAW``): the same whatever the number of
DataLoader workers.

A noise sweep (``hd eval --sigma-sweep 0:0.12:0.01``) is a list of levels from START to STOP
inclusive in steps of STEP, metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hdnet import limits as net_limits
from hdnet.errors import HdNetError
from hdnet.run_json import TrainingNoiseJson
from lidarsim import limits as lidar_limits

# The largest noise level hd trains or sweeps at, metres (one bound for every command: lidarsim.limits).
MAX_SIGMA_M = lidar_limits.MAX_SIGMA_M
# hd choice: the validation levels of a range are this many evenly spaced points, ends included.
RANGE_VALIDATION_LEVELS = 3


def _check_sigma(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise HdNetError(f"{what} must be a finite number of metres, got {value!r}.")
    if not 0.0 <= value <= MAX_SIGMA_M:
        raise HdNetError(f"{what} must be in [0, {MAX_SIGMA_M:g}] metres, got {value:g} ({lidar_limits.SIGMA_HINT}).")
    return float(value)


@dataclass(frozen=True)
class TrainingNoise:
    """Noise levels of training: ``levels_m`` (one or more, metres) or ``range_m`` (lo, hi metres).

    Exactly one of the two is set. One level is the paper's protocol (no draw at all).
    """

    levels_m: tuple[float, ...] = ()
    range_m: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if bool(self.levels_m) == (self.range_m is not None):
            raise HdNetError("training noise needs either noise levels or a range, not both and not neither.")
        object.__setattr__(self, "levels_m", tuple(_check_sigma(s, "a training sigma") for s in self.levels_m))
        if self.range_m is not None:
            lo, hi = (_check_sigma(s, "the training sigma range") for s in self.range_m)
            if not lo < hi:
                raise HdNetError(f"the training sigma range needs LOW < HIGH, got {lo:g}:{hi:g} m.")
            object.__setattr__(self, "range_m", (lo, hi))
        if len(set(self.levels_m)) != len(self.levels_m):
            raise HdNetError(f"training sigmas must be distinct, got {list(self.levels_m)}.")

    @classmethod
    def single(cls, sigma_m: float) -> TrainingNoise:
        return cls(levels_m=(float(sigma_m),))

    @property
    def kind(self) -> str:
        """``single``, ``levels`` or ``range``."""
        if self.range_m is not None:
            return "range"
        return "single" if len(self.levels_m) == 1 else "levels"

    @property
    def is_single(self) -> bool:
        return self.kind == "single"

    @property
    def low_m(self) -> float:
        return self.range_m[0] if self.range_m is not None else min(self.levels_m)

    @property
    def high_m(self) -> float:
        return self.range_m[1] if self.range_m is not None else max(self.levels_m)

    def draw(self, rng: np.random.Generator) -> float:
        """One noise level, metres: uniform over the levels, or uniform in the range."""
        if self.range_m is not None:
            lo, hi = self.range_m
            return float(lo + (hi - lo) * rng.random())
        if len(self.levels_m) == 1:
            return self.levels_m[0]
        return self.levels_m[int(rng.integers(len(self.levels_m)))]

    def validation_levels(self) -> tuple[float, ...]:
        """The fixed levels the validation split is scored at during training (metres)."""
        if self.range_m is not None:
            lo, hi = self.range_m
            return tuple(float(v) for v in np.linspace(lo, hi, RANGE_VALIDATION_LEVELS))
        return self.levels_m

    def contains(self, sigma_m: float, tol_m: float = 1e-9) -> bool:
        """True when ``sigma_m`` lies in the training range or is one of the levels."""
        if self.range_m is not None:
            return self.range_m[0] - tol_m <= sigma_m <= self.range_m[1] + tol_m
        return any(abs(s - sigma_m) <= tol_m for s in self.levels_m)

    def describe(self) -> str:
        """In words, centimetres: ``1.67 cm``, ``1.67, 7 cm``, ``0 to 10 cm (uniform per sample)``."""
        if self.range_m is not None:
            return f"{self.range_m[0] * 100:.3g} to {self.range_m[1] * 100:.3g} cm (uniform per sample)"
        return ", ".join(f"{s * 100:.3g}" for s in self.levels_m) + " cm"

    def to_dict(self) -> TrainingNoiseJson:
        return {
            "kind": self.kind,
            "levels_m": list(self.levels_m),
            "range_m": None if self.range_m is None else list(self.range_m),
        }

    @classmethod
    def from_dict(cls, data: Any) -> TrainingNoise:
        if not isinstance(data, dict):
            raise HdNetError(f"a training noise record must be a dictionary, got {type(data).__name__}.")
        rng = data.get("range_m")
        try:
            return cls(
                levels_m=tuple(float(s) for s in data.get("levels_m") or ()),
                range_m=None if rng is None else (float(rng[0]), float(rng[1])),
            )
        except (TypeError, ValueError, IndexError) as exc:
            raise HdNetError(f"a training noise record holds non-numeric levels: {data!r}.") from exc


def parse_sigma_range(text: str) -> tuple[float, float]:
    """``LOW:HIGH`` (metres) as a tuple; e.g. ``0:0.10``."""
    parts = str(text).split(":")
    if len(parts) != 2:
        raise HdNetError(f"a sigma range is LOW:HIGH in metres (e.g. 0:0.10), got {text!r}.")
    try:
        lo, hi = float(parts[0]), float(parts[1])
    except ValueError as exc:
        raise HdNetError(f"a sigma range is LOW:HIGH in metres (e.g. 0:0.10), got {text!r}.") from exc
    TrainingNoise(range_m=(lo, hi))  # the checks
    return lo, hi


def parse_sigma_sweep(text: str, what: str = "--sigma-sweep") -> tuple[float, ...]:
    """``START:STOP:STEP`` (metres) as the levels START, START+STEP, ... <= STOP (STOP included when
    it falls on the grid within 1e-9 m); e.g. ``0:0.12:0.01`` gives 13 levels. The form, the ends
    (finite, within the noise bound), a finite STEP > 0 and the number of levels
    (``hdnet.limits.SWEEP_LEVELS``) are checked before any level is made. ``what``: the option named
    by the errors.

    Raises:
        HdNetError: one line naming ``what``, the text and the fix.
    """
    form = "START:STOP:STEP in metres"
    parts = str(text).split(":")
    if len(parts) == 2:
        raise HdNetError(f"{what} {text!r} has no STEP: give {form}, e.g. {text}:0.01")
    if len(parts) != 3:
        raise HdNetError(f"{what} is {form} (e.g. 0:0.12:0.01), got {text!r}.")
    try:
        start, stop, step = (float(p) for p in parts)
    except ValueError as exc:
        raise HdNetError(f"{what} is {form} (e.g. 0:0.12:0.01), got {text!r}.") from exc
    start = _check_sigma(start, f"{what}'s START")
    stop = _check_sigma(stop, f"{what}'s STOP")
    if not (math.isfinite(step) and step > 0):
        raise HdNetError(f"{what}'s STEP must be a positive number of metres, got {step:g}.")
    if step < net_limits.MIN_SWEEP_STEP_M and stop > start:
        raise HdNetError(
            f"{what}'s STEP {step:g} m is finer than noise levels are told apart "
            f"(at least {net_limits.MIN_SWEEP_STEP_M:g} m); use a coarser STEP."
        )
    if stop < start:
        raise HdNetError(f"{what}'s STOP ({stop:g}) is below its START ({start:g}).")
    steps = (stop - start) / step  # inf when STEP underflows against the span
    n = math.floor(steps + 1e-9) + 1 if math.isfinite(steps) else math.inf
    if not net_limits.SWEEP_LEVELS.contains(n):
        most = net_limits.MAX_SWEEP_LEVELS
        raise HdNetError(
            f"{what} {text!r} gives more than {most} levels (at most {most}: {net_limits.SWEEP_LEVELS.hint}); "
            f"use a STEP of at least {(stop - start) / (most - 1):.3g} m."
        )
    return tuple(round(start + k * step, 12) for k in range(int(n)))


def check_levels(levels: Sequence[float], what: str) -> tuple[float, ...]:
    """Levels (metres) checked one by one and returned as floats."""
    return tuple(_check_sigma(s, what) for s in levels)
