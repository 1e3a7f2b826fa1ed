"""Settings that are one number or a range drawn per scan (``--altitude 250:1000``), or a pair of
numbers in a given order (``--descent-altitudes 1000:250``): the parsers shared by recipes and
settings objects, and the click types of the ``hd`` options."""

from __future__ import annotations

import math
from typing import Any

import click

from hdcore.bounds import Bound
from lidarsim.errors import LidarsimError


class SpanType(click.ParamType):
    """The click type of a setting that is one number or a range ``LOW:HIGH`` drawn per scan
    (``--altitude 250:1000``), each end within ``bound``: a value outside it is a usage error
    before any work. Converts to a float or a ``(low, high)`` tuple (:func:`parse_span`)."""

    name = "number or LOW:HIGH"

    def __init__(self, bound: Bound) -> None:
        self.bound = bound

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        try:
            low, high = parse_span(param.name if param is not None and param.name else "value", value)
        except LidarsimError:
            self.fail(f"{value!r} is not a number or a range LOW:HIGH", param, ctx)
        for end in (low, high):
            if end is not None and not self.bound.contains(end):
                self.fail(f"{end:g} is not in the range {self.bound.interval()}", param, ctx)
        if high is not None and high < low:
            self.fail(f"the range {low:g}:{high:g} runs backwards; give LOW:HIGH", param, ctx)
        return low if high is None else (low, high)


def parse_span(name: str, value: object) -> tuple[float, float | None]:
    """A setting that is one number or a range drawn per scan: ``500``, ``"250:1000"``, ``[250, 1000]``
    or ``(250.0, 1000.0)``; returns ``(low, high)``, ``high`` None for one number (a range whose
    ends are equal is that one number).

    Raises:
        LidarsimError: anything else, naming the setting.
    """
    ends: list[object]
    if isinstance(value, str):
        ends = list(value.split(":")) if ":" in value else [value]
    elif isinstance(value, (list, tuple)):
        ends = list(value)
    else:
        ends = [value]
    try:
        if len(ends) != (1 if isinstance(value, str) and ":" not in value else 2) and not isinstance(
            value, (int, float)
        ):
            raise ValueError
        if any(isinstance(e, bool) for e in ends):
            raise ValueError
        numbers = [float(e) for e in ends]  # type: ignore[arg-type]  # str, int or float, else ValueError
    except (TypeError, ValueError) as exc:
        raise LidarsimError(f"{name} must be a number or a range LOW:HIGH, got {value!r}") from exc
    if len(numbers) == 1 or numbers[0] == numbers[1]:
        return numbers[0], None
    return numbers[0], numbers[1]


class DescendingPairType(click.ParamType):
    """The click type of a setting that is two numbers ``START:END`` with ``START > END``
    (``--descent-altitudes 1000:250``), each within ``bound``: anything else is a usage error before
    any work. Converts to a ``(start, end)`` tuple (:func:`parse_pair`)."""

    name = "START:END"

    def __init__(self, bound: Bound) -> None:
        self.bound = bound

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        try:
            start, end = parse_pair(param.name if param is not None and param.name else "value", value)
        except LidarsimError:
            self.fail(f"{value!r} is not two numbers START:END", param, ctx)
        for number in (start, end):
            if not self.bound.contains(number):
                self.fail(f"{number:g} is not in the range {self.bound.interval()}", param, ctx)
        if not start > end:
            self.fail(f"{start:g}:{end:g} does not descend; give START:END with START > END", param, ctx)
        return start, end


def parse_pair(name: str, value: object) -> tuple[float, float]:
    """A setting that is two numbers: ``"1000:250"``, ``[1000, 250]`` or ``(1000.0, 250.0)``; returns
    them in their order (which the setting's own check judges).

    Raises:
        LidarsimError: anything but two finite numbers, naming the setting.
    """
    ends: list[object] = []
    if isinstance(value, str):
        ends = list(value.split(":"))
    elif isinstance(value, (list, tuple)):
        ends = list(value)
    try:
        if len(ends) != 2 or any(isinstance(e, bool) for e in ends):
            raise ValueError
        numbers = [float(e) for e in ends]  # type: ignore[arg-type]  # str, int or float, else ValueError
    except (TypeError, ValueError) as exc:
        raise LidarsimError(f"{name} must be two numbers START:END, got {value!r}") from exc
    if not all(math.isfinite(x) for x in numbers):
        raise LidarsimError(f"{name} must be two finite numbers START:END, got {value!r}")
    return numbers[0], numbers[1]
