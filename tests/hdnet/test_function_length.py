"""No function longer than 80 lines in the packages, numba kernels aside.

A long function is split into named steps (private functions whose docstrings say "Step N"), so that
each can be read, tested and changed on its own. This test parses the packages with ``ast`` and fails
on any function or method whose span (``def`` line to last line, docstring included) exceeds
``MAX_LINES``; a numba kernel (a compiled function, written as loops on purpose) is exempt: one
decorated with numba's ``njit``/``jit``, or handed to such a compiler in the module
(``_compile(_maps_loops)``, ``numba.njit(f)``: a call whose function's name ends in ``jit`` or is
``_compile``).

``PACKAGES`` lists the packages held to it: all of them.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("hdcore", "lidarsim", "hdlabels", "hdnet", "hdcli")
MAX_LINES = 80
COMPILERS = ("_compile",)  # the modules' own wrappers around numba.njit


def _name(node: ast.expr) -> str:
    """The called or decorating name (``njit`` of ``numba.njit``), "" for anything else."""
    target = node.func if isinstance(node, ast.Call) else node
    return target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")


def _is_compiler(name: str) -> bool:
    return name.endswith("jit") or name in COMPILERS or name in ("vectorize", "guvectorize")


def _kernels(tree: ast.Module) -> set[str]:
    """Names of the functions handed to a numba compiler anywhere in the module (``_compile(f)``,
    ``njit(f)``, ``_compile(_named_copy(f, ...))``)."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and _is_compiler(_name(node)):
            for arg in node.args:
                names |= {n.id for n in ast.walk(arg) if isinstance(n, ast.Name)}
    return names


def _is_numba(node: ast.FunctionDef | ast.AsyncFunctionDef, kernels: set[str]) -> bool:
    """True for a kernel: decorated by numba (``@njit``, ``@numba.njit(...)``) or compiled by name."""
    return node.name in kernels or any(_is_compiler(_name(dec)) for dec in node.decorator_list)


def long_functions(source: str, max_lines: int = MAX_LINES) -> list[tuple[str, int, int]]:
    """(name, first line, length in lines) of each function of ``source`` longer than ``max_lines``."""
    found = []
    tree = ast.parse(source)
    kernels = _kernels(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not _is_numba(node, kernels):
            length = (node.end_lineno or node.lineno) - node.lineno + 1
            if length > max_lines:
                found.append((node.name, node.lineno, length))
    return found


def test_the_counter_counts_lines_and_exempts_numba_kernels():
    body = "".join(f"    x = {i}\n" for i in range(80))
    source = f"def long():\n{body}\ndef short():\n    pass\n\n@numba.njit(cache=True)\ndef kernel():\n{body}"
    assert long_functions(source) == [("long", 1, 81)]
    compiled = f"def loops():\n{body}\n_jit = _compile(_named_copy(loops, 'p'))\n"
    assert long_functions(compiled) == []
    assert long_functions(compiled.replace("_compile(", "print(")) == [("loops", 1, 81)]
    assert long_functions(f"def exact():\n{body[: -len('    x = 79') - 1]}") == []


def test_no_function_in_the_packages_is_over_80_lines():
    over = [
        f"{path.relative_to(REPO)}:{line} {name} ({n} lines)"
        for package in PACKAGES
        for path in sorted((REPO / package).rglob("*.py"))
        for name, line, n in long_functions(path.read_text())
    ]
    assert not over, "split into named steps: " + "; ".join(over)
