"""The packages' import graph: the layers import one way (hdcore → lidarsim → hdlabels → hdnet → hdcli) and
no two modules import each other, directly or round a longer loop.

Every import statement counts, also those inside functions and under ``TYPE_CHECKING``: a
deferred import hides a loop from Python, not from a reader.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LAYERS = ("hdcore", "lidarsim", "hdlabels", "hdnet", "hdcli")  # each may import only the ones before it


def import_graph(packages: tuple[str, ...] = LAYERS) -> dict[str, set[str]]:
    """Module name -> the modules of ``packages`` it imports (``from P import m`` counts as ``P.m``)."""
    files = {module_name(f): f for pkg in packages for f in (ROOT / pkg).rglob("*.py")}
    edges: dict[str, set[str]] = {name: set() for name in files}
    for name, path in files.items():
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = [node.module, *(f"{node.module}.{alias.name}" for alias in node.names)]
            else:
                continue
            edges[name] |= {t for t in targets if t in files and t != name}
    return edges


def module_name(path: Path) -> str:
    """A file's dotted module name, sub-packages included (``hdcore/storage/__init__.py`` -> ``hdcore.storage``)."""
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = [stack.pop()]
            while component[-1] != v:
                component.append(stack.pop())
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_loop_and_only_a_loop() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set(), "c": {"a", "b"}}) == []


def test_sub_packages_are_in_the_graph() -> None:
    edges = import_graph(("hdcore",))
    assert "hdcore.storage" in edges and "hdcore.storage.atomic" in edges
    # a sub-package's __init__ imports its modules; they never import it back
    assert "hdcore.storage.atomic" in edges["hdcore.storage"]
    assert not any("hdcore.storage" in targets for name, targets in edges.items() if name.startswith("hdcore.storage."))


@pytest.mark.parametrize("package", LAYERS)
def test_no_import_cycle_inside_a_package(package: str) -> None:
    assert cycles(import_graph((package,))) == []


def test_the_layers_import_one_way() -> None:
    edges = import_graph()
    upward = [
        (src, dst)
        for src, targets in edges.items()
        for dst in targets
        if LAYERS.index(dst.split(".")[0]) > LAYERS.index(src.split(".")[0])
    ]
    assert upward == []
