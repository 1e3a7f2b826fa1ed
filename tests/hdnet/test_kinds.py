"""No string dispatch on a kind outside the module that defines it.

A kind (a threshold rule, a noise model, a label convention...) is a registered object that callers
ask (``spec.rule.calibrated``, ``model.law.stored_fields``); comparing its name with a literal
(``spec.kind == "risk"``, ``kind != "nats"``, ``kind in ("snr", ...)``) elsewhere scatters one change
over many files. This test parses the packages with ``ast`` and fails on such a comparison when the
literal is not defined in the same module, i.e. does not also appear there as a string outside any
comparison (a registered name, a returned or sent value). numpy's one-letter dtype kind codes
(``dtype.kind == "f"``) are numpy's vocabulary, not the project's, and are left alone.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SOURCES = ("hdcore", "lidarsim", "hdlabels", "hdnet", "hdcli")


def _is_kind(node: ast.expr) -> bool:
    """``kind``, ``x.kind``, ``spec_kind``, ``x.noise_kind``: an expression naming a kind."""
    if isinstance(node, ast.Name):
        return node.id == "kind" or node.id.endswith("_kind")
    if isinstance(node, ast.Attribute):
        return node.attr == "kind" or node.attr.endswith("_kind")
    return False


def _literals(node: ast.expr, op: ast.cmpop) -> list[str] | None:
    """The word literals a comparison tests against (None when it is not a literal or a tuple of them)."""
    if isinstance(op, ast.In | ast.NotIn) and isinstance(node, ast.Constant) and isinstance(node.value, str):
        return None if len(node.value) <= 4 else [node.value]  # kind in "iub": one-letter dtype codes
    items = node.elts if isinstance(node, ast.Tuple | ast.List | ast.Set) else [node]
    words = [i.value for i in items if isinstance(i, ast.Constant) and isinstance(i.value, str)]
    if len(words) != len(items) or not words:
        return None
    return None if all(len(w) == 1 for w in words) else words  # numpy's dtype kind codes: "f", "u", "b"


def violations(source: str, where: str) -> list[str]:
    """``where:line: the comparison`` for every kind compared with a word this module does not define."""
    tree = ast.parse(source)
    compared: list[tuple[ast.Compare, list[str]]] = []
    in_comparisons: set[int] = set()
    for node in ast.walk(tree):
        if not isinstance(node, ast.Compare) or len(node.ops) != 1:
            continue
        left, op, right = node.left, node.ops[0], node.comparators[0]
        if isinstance(op, ast.Eq | ast.NotEq) and _is_kind(right):
            left, right = right, left  # "risk" == kind
        if not _is_kind(left) or not isinstance(op, ast.Eq | ast.NotEq | ast.In | ast.NotIn):
            continue
        words = _literals(right, op)
        if words is None:
            continue
        compared.append((node, words))
        in_comparisons.update(id(n) for n in ast.walk(right))
    defined = {
        n.value
        for n in ast.walk(tree)
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in in_comparisons
    }
    return [
        f"{where}:{node.lineno}: {ast.unparse(node)}"
        for node, words in compared
        if any(word not in defined for word in words)
    ]


def _package_files() -> list[Path]:
    files: list[Path] = []
    for name in SOURCES:
        path = REPO / name
        files += sorted(path.rglob("*.py")) if path.is_dir() else [path]
    return files


def test_no_kind_dispatch_outside_its_module() -> None:
    found = [v for f in _package_files() for v in violations(f.read_text(), str(f.relative_to(REPO)))]
    assert not found, "kind compared with a name defined elsewhere (ask the kind's object):\n" + "\n".join(found)


def test_guard_catches_a_planted_violation() -> None:
    planted = (
        "from hdnet.threshold_spec import parse_threshold_spec\n"
        "spec = parse_threshold_spec('risk:0.1')\n"
        "if spec.kind == 'risk':\n"
        "    pass\n"
        "if 'nats' != spec.kind:\n"
        "    pass\n"
        "ok = model.kind in ('constant', 'snr')\n"
    )
    assert violations(planted, "planted.py") == [
        "planted.py:3: spec.kind == 'risk'",
        "planted.py:5: 'nats' != spec.kind",
        "planted.py:7: model.kind in ('constant', 'snr')",
    ]


def test_guard_allows_the_defining_module_and_dtype_codes() -> None:
    defining = (
        "class Level:\n"
        "    @property\n"
        "    def kind(self):\n"
        "        return 'single' if self.n == 1 else 'levels'\n"
        "    def single(self):\n"
        "        return self.kind == 'single'\n"
        "float_array = array.dtype.kind == 'f'\n"
        "integer = array.dtype.kind in 'iub'\n"
        "text = kind == label\n"  # not a literal
    )
    assert violations(defining, "defining.py") == []
    assert violations(defining.replace("'single' if", "'one' if"), "defining.py") == [
        "defining.py:6: self.kind == 'single'"
    ]


def test_guard_reads_every_package() -> None:
    files = {str(f.relative_to(REPO)) for f in _package_files()}
    assert {"hdnet/threshold_spec.py", "lidarsim/noise.py", "hdlabels/conventions.py", "hdcli/cli.py"} <= files
