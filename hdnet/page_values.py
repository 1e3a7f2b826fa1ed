"""How ``hd view`` writes a recorded value for a reader: numbers rounded, lists as comma lists, JSON
objects as ``key: value`` phrases and machine paths relative to the page's folder.

A page is mailed, archived and opened on another machine: an absolute path of the machine that made
it says nothing there (and tells what it need not), so every path a page shows is written relative
to the folder the page is in (``../run``), or as its file name alone where that would climb more than
:data:`MAX_UP` folders. Numbers keep :data:`DIGITS` significant digits (``0.30000000000000004`` ->
``0.3``, ``0.0166666`` -> ``0.0167``); integers and words are written as they are.
"""

from __future__ import annotations

import math
import os
from pathlib import Path, PurePosixPath, PureWindowsPath

DIGITS = 4  # hd choice: significant digits of a recorded float on a page (a setting, not a measurement)
MAX_UP = 2  # hd choice: a relative path climbs at most this many folders; farther ones show their file name


def is_absolute_path(text: str) -> bool:
    """True for an absolute POSIX or Windows path (``/data/x.tif``, ``C:\\runs\\a``), never for a URL."""
    if "://" in text or "\n" in text:
        return False
    return PurePosixPath(text).is_absolute() or PureWindowsPath(text).is_absolute()


def shown_path(path: str | os.PathLike[str], base: Path) -> str:
    """``path`` as a page in the folder ``base`` shows it: relative to ``base`` (``../data/hills.tif``)
    when it climbs at most :data:`MAX_UP` folders, else its file name; a relative path as it is."""
    text = os.fspath(path)
    if not is_absolute_path(text):
        return text
    try:
        rel = os.path.relpath(os.path.normpath(text), os.path.abspath(base))
    except ValueError:  # another drive (Windows)
        rel = ""
    parts = Path(rel).parts
    if rel and parts.count("..") <= MAX_UP and not is_absolute_path(rel):
        return rel
    return PurePosixPath(text).name if PurePosixPath(text).is_absolute() else PureWindowsPath(text).name


def number(value: float, digits: int = DIGITS) -> str:
    """A float with ``digits`` significant digits, no exponent between 1e-4 and 1e9 (``0.3``, ``1992000``)."""
    if not math.isfinite(value):
        return str(value)
    if value == 0.0:
        return "0"
    text = f"{value:.{digits}g}"
    if "e" in text and 1e-4 <= abs(value) < 1e9:
        decimals = max(0, digits - 1 - math.floor(math.log10(abs(value))))
        text = f"{value:.{decimals}f}"
        text = text.rstrip("0").rstrip(".") if "." in text else text
    return text


def readable(value: object, base: Path) -> str:
    """A recorded value (JSON's kinds) as words: a float rounded (:func:`number`), a list as a comma
    list, an object as ``key: value`` phrases separated by semicolons, an absolute path relative to
    ``base`` (:func:`shown_path`), ``None`` as ``--``."""
    if value is None:
        return "--"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return number(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return shown_path(value, base) if is_absolute_path(value) else value
    if isinstance(value, (list, tuple)):
        return ", ".join(readable(v, base) for v in value) if value else "none"
    if isinstance(value, dict):
        return "; ".join(f"{k}: {readable(v, base)}" for k, v in value.items()) if value else "none"
    return str(value)


def without_paths(value: object, base: Path) -> object:
    """A JSON value with every absolute path in it (a string that is one) written relative to ``base``
    (:func:`shown_path`); everything else as it is, the keys in their order."""
    if isinstance(value, str):
        return shown_path(value, base) if is_absolute_path(value) else value
    if isinstance(value, list):
        return [without_paths(v, base) for v in value]
    if isinstance(value, dict):
        return {k: without_paths(v, base) for k, v in value.items()}
    return value
