"""docs/api.md against the code: the worked example runs as printed, and the page documents exactly the
public names (each package's ``__all__``) with their real signatures.

The example's ```python blocks run in order in one namespace, in an empty directory, and what they
print is compared with the ```text block after each, numbers aside (they depend on the machine's
floating point; the shapes and counts are asserted on the objects themselves).

A public name is documented by a bullet ``- `NAME(PARAMS)` → `RETURN`: ...`` (functions, classes)
or ``- `NAME`: ...`` under its package's heading (``## `lidarsim```...). PARAMS are the parameter
names in order, ``*`` where the keyword-only ones begin; a default written there must be the
real one; ``...`` as the last one stands for the others (classes with many fields). RETURN is the
function's return annotation as written in the code.
"""

from __future__ import annotations

import ast
import contextlib
import inspect
import io
import math
import os
import re
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

import hdlabels
import hdnet
import lidarsim

DOC = Path(__file__).resolve().parents[2] / "docs" / "api.md"
PACKAGES: dict[str, ModuleType] = {"lidarsim": lidarsim, "hdlabels": hdlabels, "hdnet": hdnet}
NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?(?![\w.])")
SEVERAL = re.compile(r"^- (`\w+`(?:, `\w+`)+):")
ENTRY = re.compile(r"^- `([A-Za-z_][A-Za-z0-9_]*)(\(.*?\))?`(?: → `([^`]+)`)?[:,]", re.M)


def example_cells() -> list[tuple[str, str | None]]:
    """(code, the text block after it or None) of each ```python block of the worked example."""
    text = DOC.read_text()
    start = text.index("## A worked example")
    section = text[start : text.index("\n## ", start + 1)]
    blocks = re.findall(r"```(python|text)\n(.*?)```", section, re.S)
    cells: list[tuple[str, str | None]] = []
    for kind, body in blocks:
        if kind == "python":
            cells.append((body, None))
        else:
            assert cells and cells[-1][1] is None, "a text block follows the python block whose output it is"
            cells[-1] = (cells[-1][0], body)
    return cells


def same_but_numbers(printed: str, shown: str) -> bool:
    """True when ``printed`` is ``shown`` with possibly other numbers in the same places (a number: digits
    not inside a word, ``float32`` and ``dem100x100at1m`` are words)."""
    parts: list[str] = []
    last = 0
    shown = shown.rstrip("\n")
    for m in NUMBER.finditer(shown):
        parts += [re.escape(shown[last : m.start()]), NUMBER.pattern]
        last = m.end()
    return re.fullmatch("".join([*parts, re.escape(shown[last:])]), printed.rstrip("\n")) is not None


def test_numbers_aside_means_only_numbers():
    assert same_but_numbers("H_t = 0.612 nats, 3 sites\n", "H_t = 0.688 nats, 0 sites")
    assert same_but_numbers("(100, 100) float32", "(100, 100) float32")
    assert not same_but_numbers("H_t = 0.612 bits", "H_t = 0.688 nats")
    assert not same_but_numbers("(100, 100) float64", "(100, 100) float32")
    assert not same_but_numbers("paper-dem90x90at1m", "paper-dem100x100at1m")
    assert not same_but_numbers("extra line\n(100, 100) float32", "(100, 100) float32")


def test_the_worked_example_runs_as_printed(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scope: dict[str, Any] = {}
    cells = example_cells()
    assert len(cells) == 4 and all(shown is not None for _, shown in cells)
    for k, (code, shown) in enumerate(cells):
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            exec(compile(code, f"docs/api.md example cell {k + 1}", "exec"), scope)
        assert shown is not None and same_but_numbers(out.getvalue(), shown), (out.getvalue(), shown)
    maps = scope["maps"]
    assert isinstance(maps, hdnet.DetectMaps)
    for name in ("p_safe", "entropy_nats", "mutual_information_nats", "baseline_p_safe"):
        array = getattr(maps, name)
        assert array.shape == (100, 100) and array.dtype == np.float32
    assert maps.safety.dtype == np.uint8 and set(np.unique(maps.safety)) <= {0, 1, 2, 255}
    assert 0.0 <= maps.safe_fraction <= 1.0 and math.isfinite(maps.threshold_nats)
    assert scope["built"].n_scans == 24 and scope["checkpoint"] == tmp_path / "run" / "last.pt"
    assert sorted(os.listdir(tmp_path)) == ["mars", "run"]  # detect_dem wrote no maps


# --- the names ------------------------------------------------------------------------------------
def documented() -> dict[str, dict[str, tuple[str | None, str | None]]]:
    """Per package: NAME -> (its parenthesised parameters or None, its return or None), from the page."""
    text = DOC.read_text()
    found: dict[str, dict[str, tuple[str | None, str | None]]] = {}
    for package in PACKAGES:
        start = text.index(f"\n## `{package}`")
        end = text.find("\n## ", start + 1)
        section = text[start : end if end != -1 else len(text)]
        entries: dict[str, tuple[str | None, str | None]] = {}
        for line in section.splitlines():
            if not line.startswith("- `"):
                continue
            several = SEVERAL.match(line)
            if several:  # "- `PAPER`, `CPU`, ...: the profiles"
                entries |= dict.fromkeys(re.findall(r"`(\w+)`", several.group(1)), (None, None))
                continue
            m = ENTRY.match(line)
            assert m, f"docs/api.md: an entry of {package} that is not `NAME(...)` → `RETURN`: {line[:80]}"
            assert m.group(1) not in entries, f"{package}.{m.group(1)} is documented twice"
            entries[m.group(1)] = (m.group(2), m.group(3))
        found[package] = entries
    return found


@pytest.mark.parametrize("package", PACKAGES)
def test_the_page_documents_exactly_the_public_names(package):
    module = PACKAGES[package]
    assert set(documented()[package]) == set(module.__all__)
    assert sorted(module.__all__) == module.__all__ and len(set(module.__all__)) == len(module.__all__)


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_name_exists_and_every_class_and_function_has_its_own_docstring(package):
    module = PACKAGES[package]
    for name in module.__all__:
        value = getattr(module, name)
        if not (inspect.isclass(value) or inspect.isfunction(value)):
            continue  # constants (TINY, PROFILES, __version__): the page says what they are
        doc = value.__doc__ or ""
        assert doc.strip(), f"{package}.{name} has no docstring"
        assert not doc.startswith(f"{name}("), f"{package}.{name} has only the dataclass's generated docstring"


def _own_functions(value: Any) -> list[tuple[str, Any]]:
    """An exported function, or an exported class's public methods (and ``__init__``) defined in hd."""
    if inspect.isfunction(value):
        return [(value.__name__, value)]
    if not inspect.isclass(value):
        return []
    out = []
    for key, member in vars(value).items():
        if key.startswith("_") and key != "__init__":
            continue
        func = member.__func__ if isinstance(member, classmethod | staticmethod) else member
        func = func.fget if isinstance(func, property) else func
        if inspect.isfunction(func) and func.__module__.split(".")[0] in PACKAGES:
            out.append((f"{value.__name__}.{key}", func))
    return out


@pytest.mark.parametrize("package", PACKAGES)
def test_public_functions_and_methods_have_type_hints(package):
    module = PACKAGES[package]
    untyped = []
    for name in module.__all__:
        for qualified, func in _own_functions(getattr(module, name)):
            sig = inspect.signature(func)
            missing = [
                p.name
                for k, p in enumerate(sig.parameters.values())
                if p.annotation is inspect.Parameter.empty and not (k == 0 and p.name in ("self", "cls"))
            ]
            if sig.return_annotation is inspect.Signature.empty:
                missing.append("return")
            if missing:
                untyped.append(f"{qualified}: {missing}")
    assert untyped == []


def _split_params(text: str) -> list[str]:
    """The top-level comma-separated parts of a parameter list (without its parentheses)."""
    parts, depth, current = [], 0, ""
    for ch in text:
        if ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        if ch == "," and depth == 0:
            parts.append(current.strip())
            current = ""
        else:
            current += ch
    return [p for p in [*parts, current.strip()] if p]


def _real_params(value: Any) -> list[tuple[str, Any]]:
    """(name as the page writes it, default) of each parameter: ``*`` before the first keyword-only one."""
    out: list[tuple[str, Any]] = []
    star = False
    for p in inspect.signature(value).parameters.values():
        if p.kind is p.VAR_POSITIONAL:
            out.append((f"*{p.name}", p.default))
            star = True
        elif p.kind is p.VAR_KEYWORD:
            out.append((f"**{p.name}", p.default))
        else:
            if p.kind is p.KEYWORD_ONLY and not star:
                out.append(("*", inspect.Parameter.empty))
                star = True
            out.append((p.name, p.default))
    return out


@pytest.mark.parametrize("package", PACKAGES)
def test_documented_signatures_are_the_real_ones(package):
    module = PACKAGES[package]
    names = {n: getattr(module, n) for n in module.__all__}
    scope = {**names, "np": np, "nan": math.nan}
    for name, (params, returns) in documented()[package].items():
        value = names[name]
        if params is not None:
            written = _split_params(params[1:-1])
            real = _real_params(value)
            if written and written[-1] == "...":
                written = written[:-1]
                real = real[: len(written)]
            assert [w.split("=", 1)[0] for w in written] == [r[0] for r in real], f"{package}.{name}"
            for w, (param, default) in zip(written, real, strict=True):
                if "=" in w and w.split("=", 1)[1] != "...":  # "sensor=..." : a default too long to write
                    shown = eval(w.split("=", 1)[1], scope)
                    assert shown == default, f"{package}.{name}: {param}={default!r}, the page says {shown!r}"
        if returns is not None:
            assert inspect.signature(value).return_annotation == returns, f"{package}.{name} returns"
        elif inspect.isfunction(value):
            pytest.fail(f"docs/api.md: {package}.{name} is a function: give its return, `→ `TYPE``")


def test_the_example_and_the_reference_name_only_public_names():
    """Every ``package.NAME`` the page writes is public (or a module the page names as such)."""
    text = DOC.read_text()
    modules = {"hdnet.fit", "hdnet.evaluate", "hdnet.detect"}  # "the modules of the same names"
    for package, name in set(re.findall(r"\b(lidarsim|hdlabels|hdnet)\.([A-Za-z_][A-Za-z0-9_]*)", text)):
        if f"{package}.{name}" in modules or name.endswith("md"):
            continue
        assert name in PACKAGES[package].__all__, f"docs/api.md names {package}.{name}, which is not public"
    tree = ast.parse("\n".join(code for code, _ in example_cells()))
    assert not [n for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]  # the packages' own names only
