"""Errors keep their cause and their kind: a storage error reaches the caller of hdnet as itself,
with the exception that caused it attached, and no package re-raises ``from None``."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

from hdcore.errors import DamagedFileError, HdError
from hdnet.data import open_labeling

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("lidarsim", "hdlabels", "hdnet")


def _raises(package: str) -> list[tuple[Path, ast.Raise]]:
    out = []
    for path in sorted((ROOT / package).glob("*.py")):
        out += [(path, n) for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, ast.Raise)]
    return out


@pytest.mark.parametrize("package", PACKAGES)
def test_no_re_raise_drops_its_cause(package: str) -> None:
    dropped = [
        f"{path.name}:{node.lineno}"
        for path, node in _raises(package)
        if isinstance(node.cause, ast.Constant) and node.cause.value is None
    ]
    assert dropped == []


@pytest.mark.parametrize("package", PACKAGES)
def test_no_error_is_re_worded_from_its_text_alone(package: str) -> None:
    # SomeError(str(exc)): the same sentence under a vaguer kind (a LockedError becoming a generic one)
    reworded = [
        f"{path.name}:{node.lineno}"
        for path, node in _raises(package)
        if isinstance(node.exc, ast.Call) and node.exc.args and ast.unparse(node.exc.args[0]).startswith("str(exc)")
    ]
    assert reworded == []


def test_a_damaged_manifest_reaches_hdnet_callers_as_damage_with_its_cause(tmp_path: Path) -> None:
    (tmp_path / "manifest.json").write_text('{"schema": "hd.lidar-scans", ')  # cut short
    with pytest.raises(DamagedFileError, match=r"manifest\.json") as caught:
        open_labeling(tmp_path)
    assert isinstance(caught.value.__cause__, json.JSONDecodeError)
    assert isinstance(caught.value, HdError)  # still the one root the hd command reports as one line
