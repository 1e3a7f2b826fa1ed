"""Every HDF5 attribute and dataset the docs name for scan and label shards exists in a fresh build.

What is read from the docs:

* ``docs/shard-format.md``, section "Scan shard": the names in backticks in the first column of its
  tables (``attribute`` tables: file attributes; ``dataset`` tables: datasets), and the dataset
  attributes named as "(attribute `NAME`)" in a dataset's row;
* ``docs/labels-format.md``, sections "File attributes" and "Datasets": the same for label shards,
  and "its attribute `NAME`" in a dataset's row;
* ``docs/user-guide.md``, section "Reading shards without hd": every ``f["D"]``, ``f.attrs["A"]``
  and ``f["D"].attrs["A"]`` in its code (of the shard the last ``h5py.File`` opened: a label shard
  when its path comes from a labelling) and in backticks in its prose (of a label shard when the
  sentence speaks of one), and every "shard's attribute `NAME`".

A name with ``*`` (``dtm_*``) stands for at least one attribute with that prefix. Names marked as
optional in the docs (1.2 sensor realism, 1.3 descents, the terrain truth) are looked for in builds
made with those settings too.
"""

from __future__ import annotations

import re
from pathlib import Path

import h5py
import pytest
from click.testing import CliRunner

from hdcli.cli import main
from lidarsim.shards import read_manifest

DOCS = Path(__file__).resolve().parents[2] / "docs"
NAME = re.compile(r"^[a-z][a-z0-9_]*\*?$")


def _section(text: str, heading: str) -> str:
    """From ``heading`` to the next heading of the same or a higher level."""
    start = text.index(heading)
    level = heading.split(" ")[0]
    rest = text[start + len(heading) :]
    ends = [m.start() for m in re.finditer(r"^(#+) ", rest, re.M) if len(m.group(1)) <= len(level)]
    return rest[: ends[0]] if ends else rest


def _table_names(section: str) -> dict[str, set[str]]:
    """``{"attribute": names, "dataset": names, "dataset_attribute": "DATASET.NAME"}`` of a section's tables."""
    found: dict[str, set[str]] = {"attribute": set(), "dataset": set(), "dataset_attribute": set()}
    kind = None
    for line in section.splitlines():
        if not line.startswith("|"):
            kind = None
            continue
        cells = [c.strip() for c in line.strip("|").split("|")]
        if cells[0] in ("attribute", "dataset"):
            kind = cells[0]
            continue
        if kind is None or set(cells[0]) <= {"-"}:
            continue
        first = re.sub(r"\([^)]*\)", "", cells[0])  # a remark in parentheses names no field: "(only with `snr`)"
        names = [n for n in re.findall(r"`([^`]+)`", first) if NAME.match(n)]
        found[kind] |= set(names)
        if kind == "dataset":
            meaning = " ".join(cells[1:])
            for attr in re.findall(r"attribute `([a-z_]+)`", meaning):
                found["dataset_attribute"] |= {f"{name}.{attr}" for name in names}
    return found


ACCESS = re.compile(r'f(?:\["(\w+)"\])?(?:\.attrs\["(\w+)"\])?')


def _accesses(text: str) -> set[str]:
    """``D``, ``.A`` (a file attribute) and ``D.A`` of every ``f["D"]``, ``f.attrs["A"]``, ``f["D"].attrs["A"]``."""
    out = set()
    for dataset, attr in ACCESS.findall(text):
        if dataset or attr:
            out.add(f"{dataset}.{attr}" if attr else dataset)
    return out


def _user_guide_names() -> dict[str, set[str]]:
    """``{"scan": names, "label": names}`` named by the user guide's section on reading shards."""
    section = _section((DOCS / "user-guide.md").read_text(), "## Reading shards without hd")
    found: dict[str, set[str]] = {"scan": set(), "label": set()}
    parts = re.split(r"```python\n(.*?)```", section, flags=re.S)
    for k, part in enumerate(parts):
        if k % 2:  # code: the shard the last h5py.File opened
            kind = "scan"
            for line in part.splitlines():
                if "h5py.File(" in line:
                    kind = "label" if "lab" in line.split("h5py.File(")[1] else "scan"
                found[kind] |= _accesses(line)
            continue
        for sentence in re.split(r"(?<=[.;])\s", " ".join(part.split())):
            kind = "label" if "label shard" in sentence else "scan"
            for code in re.findall(r"`([^`]+)`", sentence):
                found[kind] |= _accesses(code)
            for which, name in re.findall(r"(label|scan) shard's attribute `(\w+)`", sentence):
                found[which].add(f".{name}")
    return found


def _documented() -> dict[str, set[str]]:
    """Every name the docs give, per shard kind: ``NAME`` a dataset, ``.NAME`` a file attribute
    (``.dtm_*`` a prefix), ``DATASET.NAME`` a dataset's attribute."""
    scan = _table_names(_section((DOCS / "shard-format.md").read_text(), "## Scan shard"))
    labels_text = (DOCS / "labels-format.md").read_text()
    label = _table_names(_section(labels_text, "## File attributes") + _section(labels_text, "## Datasets"))
    guide = _user_guide_names()
    names = {}
    for kind, tables in (("scan", scan), ("label", label)):
        names[kind] = (
            {f".{a}" for a in tables["attribute"]} | tables["dataset"] | tables["dataset_attribute"] | guide[kind]
        )
    return names


def _held(path: Path) -> set[str]:
    """The names a shard holds, in the notation of :func:`_documented`."""
    with h5py.File(path, "r") as f:
        names = {f".{a}" for a in f.attrs}
        for name, dataset in f.items():
            names |= {name, *(f"{name}.{a}" for a in dataset.attrs)}
    return names


@pytest.fixture(scope="module")
def shards(tmp_path_factory) -> dict[str, set[str]]:
    """The names held by the first scan and label shards of fresh tiny builds: the default sensor and
    labels, a realistic sensor (shard schema 1.2), a descent (1.3), and a labelling of the terrain truth."""
    root = tmp_path_factory.mktemp("names")
    runner = CliRunner()
    small = ["--scans", "3", "--shard-size", "3", "--resolution", "32", "--workers", "1"]
    realistic = ["--footprint-samples", "2", "--noise-model", "snr", "--altitude", "400:600", "--tilt", "0:1"]
    descent = ["--descent-frames", "3", "--descent-altitudes", "600:400", "--nav-position-sigma", "1"]
    for args in (
        ["build-dataset", "--out", str(root / "plain"), *small],
        ["label", str(root / "plain"), "--workers", "1"],
        ["label", str(root / "plain"), "--workers", "1", "--truth", "terrain"],
        ["build-dataset", "--out", str(root / "realistic"), *small, *realistic, "--jitter", "0:0.01"],
        ["build-dataset", "--out", str(root / "descent"), *small[2:], "--scans", "1", *descent],
    ):
        result = runner.invoke(main, args)
        assert result.exit_code == 0, result.output
    held: dict[str, set[str]] = {"scan": set(), "label": set()}
    for data in (root / "plain", root / "realistic", root / "descent"):
        manifest = read_manifest(data)
        held["scan"] |= _held(data / manifest["shards"][0]["path"])
        for lab in manifest["labelings"]:
            held["label"] |= _held(data / lab["shards"][0]["path"])
    return held


def test_the_docs_name_the_shards_attributes_and_datasets():
    names = _documented()
    # the parser reads what it should: a few names of each kind from each document
    assert {".sigmas_m", "points_noisy", "split.names", ".dtm_*", "noise_scale"} <= names["scan"]
    assert {".labeling", ".lander_*", ".truth_dtm", "p_safe", "label.codes", "dem_noisy"} <= names["label"]


@pytest.mark.parametrize("kind", ["scan", "label"])
def test_every_name_the_docs_give_exists_in_a_fresh_build(shards, kind):
    held = shards[kind]
    missing = sorted(
        n
        for n in _documented()[kind]
        if not (any(h.startswith(n[:-1]) for h in held) if n.endswith("*") else n in held)
    )
    assert not missing, f"named in the docs, absent from a fresh {kind} shard: {missing}"
