"""Ranges of numeric settings (:class:`Bound`) and the one parser of integers in user text.

Each package declares its settings' ranges once, as ``Bound`` values in its ``limits`` module
(``lidarsim.limits``, ``hdlabels.limits``, ``hdnet.limits``); the packages' checks and the ``hd``
command line (click ranges, ``hdcore.setting``) are made from them.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from hdcore.errors import HdError


@dataclass(frozen=True)
class Bound:
    """The range of one numeric setting, declared once where the value belongs and used by the
    package's own checks and by the ``hd`` command line (click ranges: the bound is shown in
    ``--help`` and a value outside it is a usage error before any work).

    ``low``/``high``: the ends (None: unbounded on that side), in the setting's unit; ``low_open``/
    ``high_open``: the end itself is excluded. ``integer``: the setting is a count or an index.
    ``hint``: a sentence said with every refusal of a value outside the range.
    """

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    integer: bool = False
    hint: str = ""  # said after the range when a value falls outside it (e.g. the unit it is in)

    def contains(self, value: float) -> bool:
        """True when ``value`` is a finite number within the range."""
        if not math.isfinite(value):
            return False
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        return not (self.high is not None and (value >= self.high if self.high_open else value > self.high))

    def interval(self) -> str:
        """The range in interval notation: ``(0, 170)``, ``[0, 5)``, ``[1, inf)``."""

        def end(v: float | None, default: str) -> str:
            return default if v is None else (f"{int(v)}" if self.integer else f"{v:g}")

        left = "(" if self.low_open or self.low is None else "["
        right = ")" if self.high_open or self.high is None else "]"
        return f"{left}{end(self.low, '-inf')}, {end(self.high, 'inf')}{right}"


def int_bound(low: int, high: int | None = None) -> Bound:
    """The range [low, high] of a count or an index (``high`` None: unbounded)."""
    return Bound(low, high, integer=True)


_DIGITS = re.compile(r"[0-9]+")
_SIGNED_DIGITS = re.compile(r"-?[0-9]+")
# hd's counts and indices have at most 10 digits; Python's int() refuses more than 4300.
_MAX_DIGITS = 100


def parse_integer(
    text: str, what: str = "", *, negative: bool = False, hint: str = "", error: type[HdError] = HdError
) -> int:
    """The integer written in ``text`` with the ASCII digits 0-9 only (and a leading ``-`` when
    ``negative``): Python's ``int()`` also takes other scripts' digits (``'٣'``), superscripts
    (``'²'``, then fails), underscores (``'1_000'``), a ``+`` and blanks around the number, none of
    which hd's options, lists and specs take. Every parser of an integer in user text goes through here.

    ``what`` names where the text comes from (``"--scans '0,²': scan"``), ``hint`` is said after the
    refusal (the form expected, with an example); ``error`` is the kind of error raised (the caller's
    package's own, e.g. ``LidarsimError``).

    Raises:
        error: ``{what} {text!r} is not ...``, one line naming the text.
    """
    pattern = _SIGNED_DIGITS if negative else _DIGITS
    if isinstance(text, str) and pattern.fullmatch(text) and len(text.lstrip("-")) <= _MAX_DIGITS:
        return int(text)
    shown = repr(text) if not isinstance(text, str) or len(text) <= 40 else repr(text[:37] + "...")
    if isinstance(text, str) and pattern.fullmatch(text):
        problem = f"has {len(text.lstrip('-'))} digits, more than any count or index hd takes"
    elif negative:
        problem = "is not an integer written with the digits 0-9 and an optional leading '-'"
    else:
        problem = "is not a whole number written with the digits 0-9"
    tail = f"; {hint}" if hint else ""
    raise error(f"{what} {shown} {problem}{tail}".strip())
