"""The documentation's "read it without hd" snippets run as printed on a default build."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from hdcli.cli import main
from lidarsim.shards import read_manifest

DOCS = Path(__file__).resolve().parents[2] / "docs"


def snippet(doc: str, heading: str) -> str:
    """The first ```python block after ``heading`` in ``docs/doc``."""
    text = (DOCS / doc).read_text()
    start = text.index(heading)
    match = re.search(r"```python\n(.*?)```", text[start:], re.S)
    assert match, f"{doc}: no python block after {heading!r}"
    return match.group(1)


@pytest.fixture(scope="module")
def default_build(tmp_path_factory) -> Path:
    """``hd build-dataset`` and ``hd label`` with their defaults (one noise level, 1.67 cm), 6 scans."""
    root = tmp_path_factory.mktemp("docs")
    runner = CliRunner()
    for args in (
        ["build-dataset", "--out", str(root / "data"), "--scans", "6", "--shard-size", "3", "--workers", "1"],
        ["label", str(root / "data"), "--workers", "1"],
    ):
        result = runner.invoke(main, args)
        assert result.exit_code == 0, result.output
    return root


@pytest.mark.parametrize(
    ("doc", "heading"),
    [
        ("user-guide.md", "## Reading shards without hd"),
        ("shard-format.md", "## Reading a shard without hd"),
        ("labels-format.md", "How DEMs and labels are computed"),
    ],
)
def test_the_snippet_runs_as_printed(default_build: Path, doc: str, heading: str) -> None:
    code = snippet(doc, heading)
    name = read_manifest(default_build / "data")["labelings"][0]["name"]
    code = code.replace("DATASET/", "data/").replace("<name>", name)
    cwd = os.getcwd()
    os.chdir(default_build)
    try:
        scope: dict[str, object] = {}
        exec(compile(code, f"{doc} snippet", "exec"), scope)
    finally:
        os.chdir(cwd)
    if doc == "user-guide.md":
        assert scope["sigmas"] == [0.0167] and scope["k"] == 0
        assert scope["label"].shape == (100, 100) and set(scope["label"].ravel()) <= {0, 1, 255}  # type: ignore[attr-defined]  # numpy arrays from exec
