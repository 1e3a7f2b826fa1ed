"""hd inspect --plot: the dataset at a glance (footprints by split on the terrain, safe fraction per σ and
split, heights, altitudes), on a labelled and an unlabelled tiny dataset, and its refusals."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from hdnet_datasets import build_labelled
from matplotlib.collections import PolyCollection
from matplotlib.patches import Rectangle

from hdcli.cli import main
from hdlabels.store import find_labeling
from hdnet.dataset_figure import PANELS, chosen_labeling, dataset_figure, dataset_overview
from lidarsim.shards import SPLIT_NAMES, read_manifest

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def datasets(tmp_path_factory) -> dict[str, Path]:
    """The tiny labelled dataset of the hdnet tests (20 scans at 500 m, 16/2/2) and an unlabelled one of 6 scans."""
    root = tmp_path_factory.mktemp("glance")
    return {
        "labelled": build_labelled(root / "lab"),
        "unlabelled": build_labelled(root / "unl", n_scans=6, label=False),
    }


def listing(path: Path) -> dict[str, int]:
    """Every file under ``path`` with its size (what a refused command must leave as it was)."""
    return {str(p.relative_to(path)): p.stat().st_size for p in sorted(path.rglob("*")) if p.is_file()}


def split_labels(path: Path, code: int) -> np.ndarray:
    """The labels (N, H, W) of a label shard's scans of the split ``code``."""
    with h5py.File(path, "r") as f:
        return f["label"][:][f["split"][:] == code]


def test_the_overview_holds_what_the_manifest_says(datasets):
    data = datasets["labelled"]
    manifest = read_manifest(data)
    lab = chosen_labeling(data, None)
    assert lab is not None
    overview = dataset_overview(data, lab)
    # (a) one footprint and centre per scan, the splits of the manifest; the terrain it was built on
    s = overview.scans
    assert overview.split_counts() == manifest["splits"] == {"train": 16, "val": 2, "test": 2}
    assert sorted(s.scan_index.tolist()) == list(range(20))
    half = 500.0 * math.tan(math.radians(6.0))  # a 12-degree detector at nadir from 500 m: 52.55 m
    expected = s.origin_map[:, None, :2] + half * np.array([[-1, 1], [1, 1], [1, -1], [-1, -1]])
    np.testing.assert_allclose(s.footprints_map, expected, atol=1e-6)
    assert overview.terrain == "hillshade of hills.tif" and overview.backdrop is not None
    left, right, bottom, top = overview.backdrop.extent
    assert (left, right, bottom, top) == (1000.0, 1400.0, 1600.0, 2000.0)  # footprints to the edges: all of it
    assert overview.backdrop.heights_m.shape == (400, 400) and np.isfinite(overview.backdrop.heights_m).all()
    # (b) the labels' counts per split add up to the labelling's own, and its baseline fractions
    assert overview.labels is not None and overview.labels.labeling == lab.name
    splits = overview.labels.splits
    assert [splits[n].scans for n in SPLIT_NAMES] == [16, 2, 2]
    totals = {k: sum(getattr(splits[n], k) for n in SPLIT_NAMES) for k in ("unsafe", "safe", "invalid")}
    assert (totals["unsafe"], totals["safe"], totals["invalid"]) == lab.label_counts
    labelled = totals["unsafe"] + totals["safe"]
    for k, sigma in enumerate(overview.labels.sigmas_m):
        safe = sum(splits[n].baseline_safe[k] for n in SPLIT_NAMES)
        assert safe / labelled == lab.baseline_safe_fraction[f"{sigma:g}"]
    # ... and the test split's by hand from its label shards
    test_label = np.concatenate([split_labels(data / e.path, 2) for e in lab.shards])
    assert splits["test"].safe == int((test_label == 1).sum()) and splits["test"].unsafe == int((test_label == 0).sum())
    # (c) the clean points of every scan (fewer than 24 per split), (d) every scan at 500 m
    assert overview.height_scans == {"train": 16, "val": 2, "test": 2}
    assert all(v.size > 0 and np.isfinite(v).all() for v in overview.heights.values())
    np.testing.assert_array_equal(s.altitude_m, 500.0)


def test_the_figure_has_its_four_panels(datasets):
    data = datasets["labelled"]
    overview = dataset_overview(data, chosen_labeling(data, None))
    fig = dataset_figure(overview)
    axes = fig.get_axes()
    assert [ax.get_title().split(" ")[0] for ax in axes] == ["(a)", "(b)", "(c)", "(d)"] and len(PANELS) == 4
    footprints = [c for c in axes[0].collections if isinstance(c, PolyCollection)]
    assert [len(c.get_paths()) for c in footprints] == [16, 2, 2]  # one outline per scan, by split
    legend = axes[0].get_legend()
    assert legend is not None and [t.get_text() for t in legend.get_texts()] == ["train (16)", "val (2)", "test (2)"]
    assert len(axes[0].get_images()) == 1  # the hillshade
    lines = axes[1].get_lines()
    assert len(lines) == 6  # per split: the baseline over the 2 sigmas, the labels' level
    # Each split's points shifted sideways, with its own marker: splits of equal fractions stay apart.
    xs = {line.get_label(): np.round(np.asarray(line.get_xdata(), float), 6).tolist() for line in lines}
    assert xs["train: ALHAT baseline, P(safe) ≥ 0.5"] == [-0.12, 0.88] and xs["val: ALHAT baseline, P(safe) ≥ 0.5"] == [
        0,
        1,
    ]
    assert len({tuple(x) for x in xs.values()}) == 3  # a split's baseline and labels share their x
    assert len({line.get_marker() for line in lines}) == 3
    # (d) says what it draws: one altitude, so the scans per split, each bar with its count.
    assert axes[3].get_title() == "(d) scans per split, all at one altitude: 500 m above the reference"
    assert axes[3].get_ylabel() == "scans" and [t.get_text() for t in axes[3].texts] == ["16", "2", "2"]
    assert [p.get_height() for p in axes[3].patches if isinstance(p, Rectangle)] == [16, 2, 2]


def test_hd_inspect_plot_writes_the_figure_atomically_and_reports_it(datasets, tmp_path):
    data = datasets["labelled"]
    before = listing(data)
    out = tmp_path / "glance.png"
    runner = CliRunner()
    result = runner.invoke(main, ["inspect", str(data), "--plot", str(out)])
    assert result.exit_code == 0, result.output
    assert out.read_bytes().startswith(PNG_MAGIC) and sorted(p.name for p in tmp_path.iterdir()) == ["glance.png"]
    assert f"figure    {out}: footprints of 20 scans on the hillshade of hills.tif; safe fraction per σ of paper-" in (
        result.output
    )
    assert "heights of 20 scans; altitude 500 m\n" in result.output
    assert "status    intact" in result.output and listing(data) == before  # nothing written into the dataset
    again = runner.invoke(main, ["inspect", str(data), "--plot", str(out)])  # an existing file stays
    assert again.exit_code == 1 and "exists; pass --overwrite" in again.output.strip().splitlines()[-1]
    as_json = runner.invoke(main, ["--json", "inspect", str(data), "--plot", str(out), "--overwrite"])
    assert as_json.exit_code == 0, as_json.output
    figure = json.loads(as_json.output)["figure"]
    assert figure["path"] == str(out.resolve()) and figure["scans_per_split"] == {"train": 16, "val": 2, "test": 2}
    fractions = figure["labels"]["safe_fraction"]
    assert list(fractions) == list(SPLIT_NAMES) and list(fractions["test"]["baseline"]) == ["0.0167", "0.07"]
    assert sum(f["labelled_pixels"] for f in fractions.values()) == sum(
        json.loads(as_json.output)["labelings"][0]["label_counts"][k] for k in ("safe", "unsafe")
    )
    pdf = runner.invoke(main, ["inspect", str(data), "--plot", str(tmp_path / "glance.pdf")])
    assert pdf.exit_code == 0 and (tmp_path / "glance.pdf").read_bytes().startswith(b"%PDF")


def test_an_unlabelled_dataset_says_so_in_its_figure(datasets, tmp_path):
    data = datasets["unlabelled"]
    assert chosen_labeling(data, None) is None
    overview = dataset_overview(data, None)
    assert overview.labels is None and sum(overview.split_counts().values()) == 6
    fig = dataset_figure(overview)
    assert any("not labelled" in t.get_text() for t in fig.get_axes()[1].texts)
    result = CliRunner().invoke(main, ["--json", "inspect", str(data), "--plot", str(tmp_path / "u.svg")])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["figure"]["labels"] is None
    assert (tmp_path / "u.svg").read_text().lstrip().startswith("<?xml")


def test_a_missing_or_changed_terrain_is_said_and_the_footprints_drawn_alone(tmp_path):
    data = build_labelled(tmp_path / "d", n_scans=4, label=False)
    dtm = tmp_path / "d" / "hills.tif"
    good = dtm.read_bytes()
    dtm.write_bytes(good[:-4] + b"\x00\x00\x00\x01")  # other bytes than the build read
    changed = dataset_overview(data, None)
    assert changed.backdrop is None and changed.terrain.startswith("terrain not shown: hills.tif changed since")
    dtm.unlink()
    missing = dataset_overview(data, None)
    assert missing.backdrop is None and missing.terrain == f"terrain not shown: {dtm} is not there"
    fig = dataset_figure(missing)
    ax = fig.get_axes()[0]
    assert not ax.get_images() and any("is not there" in t.get_text() for t in ax.texts)
    assert sum(len(c.get_paths()) for c in ax.collections if isinstance(c, PolyCollection)) == 4


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["{missing}", "--plot", "{out}"], "no such dataset directory"),
        (["{run}", "--plot", "{out}"], "is a run: --plot draws a dataset"),
        (["{labelled}", "--plot", "{tmp}/glance.jpg"], "ending in .png, .pdf or .svg"),
        (["{labelled}", "--plot", "{labelled}/glance.png"], "lies inside the dataset"),
        (["{labelled}", "--plot", "{tmp}/no/such/dir/glance.png"], "does not exist"),
        (["{labelled}", "--plot", "{out}", "--labels", "nope"], "no labelling named 'nope'"),
        (["{unlabelled}", "--plot", "{out}", "--labels", "paper"], "has no labels; run `hd label"),
        (["{labelled}", "--labels", "paper"], "--labels and --overwrite go with --plot"),
    ],
)
def test_a_bad_plot_is_refused_with_one_line_and_nothing_written(datasets, tmp_path, args, needle):
    run = tmp_path / "run"
    run.mkdir()
    (run / "last.pt").write_bytes(b"not read")
    names = {k: str(v) for k, v in datasets.items()} | {
        "missing": str(tmp_path / "nope"),
        "run": str(run),
        "tmp": str(tmp_path),
        "out": str(tmp_path / "glance.png"),
    }
    before = {k: listing(v) for k, v in datasets.items()}
    result = CliRunner().invoke(main, ["inspect", *[a.format(**names) for a in args]])
    assert result.exit_code in (1, 2) and "Traceback" not in result.output, result.output
    last = result.output.strip().splitlines()[-1]
    assert last.startswith("Error: ") and needle in last, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no figure, no temporary file
    assert {k: listing(v) for k, v in datasets.items()} == before


def test_of_two_truths_the_figure_takes_the_terrains_and_of_others_asks_in_one_line(datasets, tmp_path):
    from hdlabels.labeling import label_dataset
    from hdlabels.settings import LabelSettings

    data = tmp_path / "data"
    shutil.copytree(datasets["labelled"], data)
    clean = find_labeling(data).name
    terrain = label_dataset(data, LabelSettings(truth="terrain"), workers=1).name
    chosen, named = chosen_labeling(data, None), chosen_labeling(data, "paper")
    assert chosen is not None and chosen.name == terrain  # both truths of the paper's convention: the terrain's
    assert named is not None and named.name == clean  # --labels still chooses
    result = CliRunner().invoke(main, ["--json", "inspect", str(data), "--plot", str(tmp_path / "g.png")])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["figure"]["labels"]["labelling"] == terrain
    label_dataset(data, LabelSettings(convention="hd"), workers=1)  # a third labelling: no obvious choice
    result = CliRunner().invoke(main, ["inspect", str(data), "--plot", str(tmp_path / "h.png")])
    lines = result.output.strip().splitlines()
    assert result.exit_code == 1 and len(lines) == 1 and len(lines[0]) < 200, result.output
    assert lines[0] == f"Error: {data} has 3 labellings: choose the figure's with --labels (paper, paper+terrain, hd)"
    assert not (tmp_path / "h.png").exists()
