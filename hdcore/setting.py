"""Each setting described once: a settings dataclass's field carries its help, unit, default and range.

A field made with :func:`setting` holds a :class:`Described` in its metadata. From it come

- :func:`check`: the checks of a settings object (its ``__post_init__`` calls it): the value's kind
  (``true``/``false``, an integer, a finite number, one of the choices) and its range;
- :func:`from_mapping`: a settings object from a recipe section (unknown keys refused, a TOML
  integer taken for a number, a list for a repeated setting), checked as above;
- :func:`click_options`: the ``hd`` command's options (name, type with its range, default, help
  with its unit), so that ``--help`` shows the range and click refuses a value outside it before
  any work.

Ranges are :class:`hdcore.bounds.Bound` values, declared in each package's ``limits`` module.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
import re
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import click

from hdcore.bounds import Bound, parse_integer
from hdcore.errors import HdError
from hdcore.redact import printable_location

_KEY = "hd.setting"
T = TypeVar("T")
Decorator = Callable[[Callable[..., Any]], Callable[..., Any]]


@dataclasses.dataclass(frozen=True)
class Described:
    """One setting's description.

    ``help``: one sentence for ``--help``; ``unit``: of the value (``metres``, ``degrees``,
    ``metres/pixel``; empty for counts and names), appended to the help; ``bound``: its range;
    ``choices``: the values a name may take; ``kind``: ``bool``, ``int``, ``float``, ``str`` (of
    each value when ``multiple``) or a value type of its own, whose instances say what is wrong with
    them (``problem()``: None, or what was expected; ``lidarsim.map_window.MapWindow``);
    ``multiple``: a tuple of values (a repeatable option, a TOML list); ``optional``: None is
    allowed (the default is then worked out elsewhere); ``flag``: the option's name when it is not
    the field's name dashed; ``cli``: whether the command line takes it; ``click_type``: the
    option's type when it is not made from the kind (a path that must exist); ``checked``: whether
    :func:`check` checks it (not for a value that may also be an object, e.g. a training profile
    given by name or as itself, or one number or a range drawn per scan, which
    ``lidarsim.trajectory`` checks with the range's own messages).
    """

    help: str
    unit: str = ""
    bound: Bound | None = None
    choices: tuple[str, ...] | None = None
    kind: type = str
    multiple: bool = False
    optional: bool = False
    flag: str = ""
    show_default: bool = True
    metavar: str | None = None
    cli: bool = True
    click_type: Any = None
    checked: bool = True

    def option_name(self, field_name: str) -> str:
        """The command-line flag of the setting (``--dem-size``)."""
        return self.flag or "--" + field_name.replace("_", "-")

    def help_text(self) -> str:
        """The ``--help`` text: the sentence with its unit, at ``{unit}`` in the help or after it (click
        adds a number's range; ``{bound}`` writes it where click cannot, e.g. for a span)."""
        if "{unit}" in self.help or "{bound}" in self.help:
            bound = self.bound.interval() if self.bound is not None else ""
            text = self.help.replace("{unit}", self.unit).replace("{bound}", bound)
            return text if text.endswith(".") else f"{text}."
        text = self.help.rstrip(".")
        return f"{text}, {self.unit}." if self.unit else f"{text}."

    def expected(self, value: Any) -> str | None:
        """What one value should have been, when it is wrong (``"an integer in [1, 360]"``); None
        when it is right."""
        if self.kind is bool:
            ok = value is True or value is False
            expected = "true or false"
        elif self.kind is int:
            ok = isinstance(value, numbers.Integral) and not isinstance(value, bool)
            expected = "an integer"
        elif self.kind is float:
            ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
            expected = "a finite number"
        elif self.kind is Path:
            ok = isinstance(value, str | os.PathLike)
            expected = "a path"
        elif self.kind is not str:  # a value type of its own (lidarsim.map_window.MapWindow): its problem()
            ok = isinstance(value, self.kind)
            expected = f"a {self.kind.__name__}"
            problem = value.problem() if ok and hasattr(value, "problem") else None
            if problem is not None:
                ok, expected = False, problem
        else:
            ok = isinstance(value, str)
            expected = "a string"
        if ok and self.choices is not None and value not in self.choices:
            ok, expected = False, "one of " + ", ".join(self.choices)
        if ok and self.bound is not None and not self.bound.contains(float(value)):
            hint = f" ({self.bound.hint})" if self.bound.hint else ""
            ok, expected = False, f"{expected} in {self.bound.interval()}{hint}"
        return None if ok else expected


def setting(
    default: Any,
    help: str,
    *,
    unit: str = "",
    bound: Bound | None = None,
    choices: Iterable[str] | None = None,
    kind: type | None = None,
    optional: bool | None = None,
    flag: str = "",
    show_default: bool | None = None,
    metavar: str | None = None,
    cli: bool = True,
    click_type: Any = None,
    checked: bool = True,
) -> Any:
    """A dataclass field described once (see :class:`Described`). ``kind`` is taken from the range
    (integer or not), the choices or the default when not given; a tuple default makes a repeated
    setting; a None default an optional one."""
    multiple = isinstance(default, tuple)
    sample = (default[0] if default else None) if multiple else default
    if kind is None:
        if bound is not None:
            kind = int if bound.integer else float
        elif choices is not None:
            kind = str
        elif sample is not None:
            kind = type(sample)
        else:
            raise TypeError(f"setting {help!r}: give its kind (no range, choices or default to take it from)")
    described = Described(
        help=help,
        unit=unit,
        bound=bound,
        choices=tuple(choices) if choices is not None else None,
        kind=kind,
        multiple=multiple,
        optional=default is None if optional is None else optional,
        flag=flag,
        show_default=default not in (None, ()) if show_default is None else show_default,
        metavar=metavar,
        cli=cli,
        click_type=click_type,
        checked=checked,
    )
    return dataclasses.field(default=default, metadata={_KEY: described})


def described_as(cls: Any, name: str, **changes: Any) -> Any:
    """A field described as the field ``name`` of ``cls`` is (the same help, unit, default and range),
    with ``changes`` to its description (e.g. the ``flag`` and ``cli`` of a flat record that fills
    ``cls``)."""
    f = next(f for f in dataclasses.fields(cls) if f.name == name)
    return dataclasses.field(default=f.default, metadata={_KEY: dataclasses.replace(f.metadata[_KEY], **changes)})


def described_fields(cls: Any) -> list[tuple[dataclasses.Field[Any], Described]]:
    """The described fields of a settings dataclass, in their order."""
    return [(f, f.metadata[_KEY]) for f in dataclasses.fields(cls) if _KEY in f.metadata]


def check(settings: Any, error: type[HdError], name: Callable[[str, Described], str] | None = None) -> None:
    """Check every described field of ``settings`` (its kind, choices and range).

    ``name`` gives the name a message uses for a field (default: its option, ``--dem-size``, or
    the field's name for a setting the command line does not take).

    Raises:
        error: the first wrong value, naming the setting.
    """
    for f, d in described_fields(type(settings)):
        value = getattr(settings, f.name)
        if (value is None and d.optional) or not d.checked:
            continue
        label = name(f.name, d) if name is not None else d.option_name(f.name) if d.cli else f.name
        if d.multiple:
            if not isinstance(value, tuple | list):
                raise error(f"{label} must be a sequence of values, got {value!r}")
            values: tuple[Any, ...] = tuple(value)
        else:
            values = (value,)
        for v in values:
            expected = d.expected(v)
            if expected is not None:
                raise error(f"{label} must be {expected}, got {v!r}")


def from_mapping(
    cls: type[T], values: Mapping[str, Any], where: str, section: str, error: type[HdError], **fixed: Any
) -> T:
    """A settings object from a recipe's ``[section]`` (keys are the field names): unknown keys
    refused, an integer taken for a number, a list for a repeated setting, then checked by the
    class. ``fixed``: values of fields that the section does not give (defaults of the recipe's own).

    Raises:
        error: an unknown key or a wrong value, naming ``where`` (the recipe), the section and the key.
    """
    described = {f.name: d for f, d in described_fields(cls)}
    unknown = sorted(set(values) - set(described))
    if unknown:
        raise error(f"{where}: unknown [{section}] key(s) {unknown}")
    for key, value in values.items():
        d = described[key]
        many = d.multiple and isinstance(value, list | tuple)
        given = tuple(_number(d, v) for v in value) if many else _number(d, value)
        for v in given if many else (given,):
            expected = d.expected(v)
            if expected is not None and d.checked and not (v is None and d.optional):
                raise error(f"{where}: [{section}] {key} = {v!r} is not {expected}")
        fixed[key] = given
    return cls(**fixed)


def _number(d: Described, value: Any) -> Any:
    """A TOML integer where a number is expected is that number."""
    integral = isinstance(value, int) and not isinstance(value, bool)
    return float(value) if d.kind is float and integral else value


# ------------------------------------------------------------------------------------ click options
# A URL (``s3://bucket/x``, ``https://host/x``): a scheme (RFC 3986: a letter, then letters, digits,
# "+", "-", ".") and "://". pathlib would read it as a path and collapse "//" into "/".
_URL = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*://")


class NonEmptyPath(click.Path):
    """click.Path that refuses an empty string (which click would turn into the current directory) and
    a URL (as a path, ``s3://bucket/x`` would become ``s3:/bucket/x``): the arguments that read a
    URL are :class:`DatasetOrUrl`. Every other path argument and option of ``hd`` is of this type."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and not value.strip():
            self.fail("must not be empty", param, ctx)
        if isinstance(value, str) and _URL.match(value):
            self.fail(
                f"{printable_location(value)} is a URL; this argument takes a local path (a dataset is read from a "
                "URL by hd inspect, verify, train, eval --data and detect --data; hd pull URL DIR copies one here): "
                "give a local path",
                param,
                ctx,
            )
        return super().convert(value, param, ctx)


class DatasetOrUrl(NonEmptyPath):
    """A dataset to read: a local directory (as :class:`NonEmptyPath` takes it, a ``Path``) or a URL
    (``s3://bucket/prefix``, ``https://host/path``...), kept as the string, never read as a path."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and _URL.match(value):
            return value.rstrip("/")
        return super().convert(value, param, ctx)


class Finite(click.FloatRange):
    """A float option that must be a finite number (``nan`` and ``inf`` are refused), within the
    range when one is given."""

    name = "float"

    def _describe_range(self) -> str:
        return super()._describe_range() if (self.min is not None or self.max is not None) else "finite"

    hint = ""  # said after a refusal of a value outside the range (Bound.hint)

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        try:
            number = super().convert(value, param, ctx)
        except click.BadParameter as exc:
            if not self.hint:
                raise
            self.fail(f"{exc.message.rstrip('.')} ({self.hint})", param, ctx)
        if not math.isfinite(number):
            self.fail(f"{number} is not a finite number", param, ctx)
        return number


class Integer(click.IntRange):
    """An integer option written with the ASCII digits 0-9 and an optional leading ``-``
    (:func:`hdcore.bounds.parse_integer`; click's own ``int()`` also takes other scripts' digits
    such as ``'٣'``, ``'1_000'``, ``'+8'`` and blanks), within the range when one is given."""

    def _describe_range(self) -> str:
        return super()._describe_range() if (self.min is not None or self.max is not None) else "integer"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str):
            try:
                value = parse_integer(value, negative=True)
            except HdError as exc:
                self.fail(str(exc), param, ctx)
        return super().convert(value, param, ctx)


def bounded(bound: Bound) -> click.ParamType:
    """The click type of a numeric option within ``bound``: click shows the range in ``--help`` and
    refuses a value outside it with a usage error, before any work."""
    if bound.integer:
        return Integer(
            None if bound.low is None else int(bound.low),
            None if bound.high is None else int(bound.high),
            min_open=bound.low_open,
            max_open=bound.high_open,
        )
    finite = Finite(min=bound.low, max=bound.high, min_open=bound.low_open, max_open=bound.high_open)
    finite.hint = bound.hint
    return finite


DIRECTORY = NonEmptyPath(file_okay=False, path_type=Path)
FILE_OR_DIRECTORY = NonEmptyPath(path_type=Path)
DATASET_OR_URL = DatasetOrUrl(file_okay=False, path_type=Path)


def _option(name: str, d: Described, default: Any, help: str | None = None) -> tuple[list[str], dict[str, Any]]:
    """The declarations and keywords of the click option of one described setting."""
    text = help if help is not None else d.help_text()
    if d.kind is bool:
        return [d.option_name(name), name], {"is_flag": True, "default": default, "help": text}
    if d.click_type is not None:
        kind: Any = d.click_type
    elif d.bound is not None:
        kind = bounded(d.bound)
    elif d.choices is not None:
        kind = click.Choice(d.choices)
    elif d.kind is int:
        kind = Integer()
    else:
        kind = d.kind
    return [d.option_name(name), name], {
        "type": kind,
        "multiple": d.multiple,
        "default": default,
        "show_default": d.show_default,
        "metavar": d.metavar,
        "help": text,
    }


def _chosen(cls: Any, skip: Iterable[str]) -> list[tuple[dataclasses.Field[Any], Described]]:
    skipped = set(skip)
    return [(f, d) for f, d in described_fields(cls) if d.cli and f.name not in skipped]


def click_options(cls: Any, *, skip: Iterable[str] = (), help: Mapping[str, str] | None = None) -> Decorator:
    """The options of every described field of ``cls`` that the command line takes (in the fields'
    order, less ``skip``); ``help`` replaces a field's generated text (e.g. to name another option)."""
    texts = help or {}
    chosen = _chosen(cls, skip)

    def apply(func: Callable[..., Any]) -> Callable[..., Any]:
        for f, d in reversed(chosen):
            decls, kwargs = _option(f.name, d, f.default, texts.get(f.name))
            func = click.option(*decls, **kwargs)(func)
        return func

    return apply


class SettingsCommand(click.Command):
    """A command whose options of settings dataclasses (``settings=("package.module:Class", ...)``) are
    made when first needed (``--help``, parsing), so that a module that is slow to import (one that
    imports PyTorch) is imported only by the command that needs it. They follow the arguments and
    come before the command's other options; ``skip`` and ``help_texts`` as for :func:`click_options`."""

    def __init__(
        self,
        *args: Any,
        settings: tuple[str, ...],
        skip: Iterable[str] = (),
        help_texts: Mapping[str, str] | None = None,
        **kwargs: Any,
    ) -> None:
        self._settings = settings
        self._skip = tuple(skip)
        self._help_texts = dict(help_texts or {})
        self._params: list[click.Parameter] | None = None
        super().__init__(*args, **kwargs)

    @property
    def params(self) -> list[click.Parameter]:
        if self._params is None:
            import importlib

            made: list[click.Parameter] = []
            for spec in self._settings:
                module, _, name = spec.partition(":")
                for f, d in _chosen(getattr(importlib.import_module(module), name), self._skip):
                    decls, kwargs = _option(f.name, d, f.default, self._help_texts.get(f.name))
                    made.append(click.Option(decls, **kwargs))
            given = self._given
            self._params = [p for p in given if isinstance(p, click.Argument)] + made
            self._params += [p for p in given if not isinstance(p, click.Argument)]
        return self._params

    @params.setter
    def params(self, value: list[click.Parameter]) -> None:
        self._given = value
        self._params = None


def settings_from_options(cls: type[T], options: dict[str, Any], **more: Any) -> T:
    """The settings object of the command line's values (the described fields are taken out of
    ``options``, which keeps the rest)."""
    names = [f.name for f, d in described_fields(cls) if d.cli]
    return cls(**{n: options.pop(n) for n in names if n in options}, **more)
