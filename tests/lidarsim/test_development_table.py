"""docs/development.md's "To change X, edit Y" table names real files and real definitions: every
backticked ``*.py`` path exists, every backticked name after it is defined at the top level of that
file, and every document it points to exists."""

from __future__ import annotations

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
TOPICS = {
    "a noise model",
    "the sensor",
    "a descent",
    "the terrain",
    "the gridding",
    "the label rule",
    "the baseline",
    "the landing outcome",
    "descent mosaics",
    "the network",
    "a training profile",
    "a threshold rule",
    "an uncertainty score",
    "a detect map",
    "a CLI setting",
    "a shard field",
}
# The worked examples: each kind's change and the code files it touches besides test and doc.
EXAMPLES = ("A noise model", "A threshold rule", "A detect map")


def _section() -> str:
    text = (REPO / "docs" / "development.md").read_text()
    start = text.index("## To change X, edit Y")
    end = text.index("\n## ", start + 1)
    return text[start:end]


def _rows() -> list[list[str]]:
    lines = [line for line in _section().splitlines() if line.startswith("| ")]
    return [[cell.strip() for cell in line.strip("|").split(" | ")] for line in lines[1:]]  # header skipped


def _defined(path: Path) -> set[str]:
    """Top-level names a module defines: functions, classes and assigned constants."""
    names: set[str] = set()
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Assign):
            names |= {t.id for t in node.targets if isinstance(t, ast.Name)}
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
    return names


def test_the_table_covers_every_part_a_change_starts_from() -> None:
    assert {row[0] for row in _rows()} == TOPICS


def test_every_file_and_name_of_the_table_exists() -> None:
    checked, missing = 0, []
    for row in _rows():
        for cell in row[1:]:
            current: Path | None = None
            for token in re.findall(r"`([^`]+)`", cell):
                if token.endswith(".py"):
                    current = REPO / token
                    if not current.is_file():
                        missing.append(token)
                elif re.fullmatch(r"[A-Za-z_]\w*", token):
                    assert current is not None, f"{token!r} is named before any file in {cell!r}"
                    checked += 1
                    if current.is_file() and token not in _defined(current):
                        missing.append(f"{current.relative_to(REPO)}: {token}")
    assert missing == []
    assert checked >= 40  # the table names definitions, not only files


def test_every_document_and_file_the_section_mentions_exists() -> None:
    section = _section()
    documents = set(re.findall(r"docs/[\w-]+\.md", section))
    files = set(re.findall(r"`([^`\s]+\.py)`", section))
    assert documents and files
    assert [p for p in sorted(documents | files) if not (REPO / p).is_file()] == []


def test_each_worked_example_touches_at_most_two_code_files() -> None:
    text = (REPO / "docs" / "development.md").read_text()
    start = text.index("### Worked examples")
    section = text[start : text.index("\n## ", start)]
    for title in EXAMPLES:
        block = section[section.index(f"**{title}**") :]
        line = next(ln for ln in block.splitlines() if ln.startswith("code: "))
        code = re.findall(r"`([^`\s]+\.py)`", line.split("; test:")[0])
        tests = re.findall(r"`([^`\s]+\.py)`", line.split("; test:")[1])
        assert 1 <= len(code) <= 2, (title, code)
        assert all(not c.startswith("tests/") for c in code), (title, code)
        assert [p for p in code + tests if not (REPO / p).is_file()] == [], title
