"""croissant.json: hd card writes Croissant 1.0 metadata that the mlcroissant library validates,
naming every file with its sha256 and every array of the shards as a field."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import h5py
import pytest
from click.testing import CliRunner

from hdcli.cli import main
from lidarsim.croissant import CONFORMS_TO, croissant_metadata
from lidarsim.shards import read_manifest
from tests.hdnet.hdnet_datasets import hills_dtm


@pytest.fixture(scope="module")
def carded(tmp_path_factory) -> tuple[Path, Path]:
    """A tiny dataset built, labelled and carded from a recipe: (dataset, recipe directory)."""
    root = tmp_path_factory.mktemp("croissant")
    dtm = hills_dtm(root / "hills.tif", n=200)
    recipe = root / "recipe"
    recipe.mkdir()
    (recipe / "recipe.toml").write_text(
        '[dataset]\nname = "tiny"\ndescription = "A tiny test set."\nversion = 3\n'
        f'[build]\nscans = 6\nsigmas_m = [0.03]\nresolution = 32\nshard_size = 3\ndtm = "{dtm}"\n'
    )
    out = root / "tiny"
    runner = CliRunner()
    for args in (
        ["build-dataset", "--recipe", str(recipe), "--out", str(out), "--workers", "1"],
        ["label", str(out), "--workers", "1", "--recipe", str(recipe)],
    ):
        result = runner.invoke(main, args)
        assert result.exit_code == 0, result.output
    result = runner.invoke(main, ["card", str(out), "--recipe", str(recipe)])
    assert result.exit_code == 0 and "croissant.json" in result.output, result.output
    return out, recipe


def test_hd_card_writes_croissant_that_mlcroissant_validates(carded, caplog):
    import mlcroissant as mlc

    _, recipe = carded
    path = recipe / "croissant.json"
    data = json.loads(path.read_text())
    assert data["conformsTo"] == CONFORMS_TO and data["@type"] == "sc:Dataset"
    assert data["name"] == "tiny" and data["version"] == "3.0.0" and data["description"] == "A tiny test set."
    for key in ("rai:dataCollection", "rai:dataLimitations", "rai:personalSensitiveInformation", "license"):
        assert data[key], key
    assert "sigma 0.03 m" in data["rai:dataCollection"]
    with caplog.at_level(logging.WARNING):
        metadata = mlc.Dataset(jsonld=path).metadata  # raises mlc.ValidationError on any error
    assert not metadata.ctx.issues.errors, metadata.ctx.issues.report()
    assert [r.name for r in metadata.record_sets] == ["scans", "labels-0"]


def test_croissant_names_every_file_and_every_array(carded):
    dataset, recipe = carded
    data = json.loads((recipe / "croissant.json").read_text())
    m = read_manifest(dataset)
    entries = m["shards"] + [e for lab in m["labelings"] for e in lab["shards"]]
    files = {d["contentUrl"]: d for d in data["distribution"] if d["@type"] == "cr:FileObject"}
    assert set(files) == {"manifest.json", *(e["path"] for e in entries)}
    for e in entries:
        assert files[e["path"]]["sha256"] == e["sha256"]
        assert files[e["path"]]["contentSize"] == f"{(dataset / e['path']).stat().st_size} B"
    scans = next(r for r in data["recordSet"] if r["@id"] == "scans")
    with h5py.File(dataset / m["shards"][0]["path"], "r") as f:
        arrays = sorted(n for n in f if isinstance(f[n], h5py.Dataset) and f[n].shape)
        assert [fl["name"] for fl in scans["field"]] == arrays
        noisy = next(fl for fl in scans["field"] if fl["name"] == "points_noisy")
        assert noisy["dataType"] == "sc:Float" and "1 x 32 x 32 x 3" in noisy["description"]
    assert croissant_metadata(dataset, "tiny", "A tiny test set.", 3, data["license"], data["citeAs"]) == data


def test_a_recipes_croissant_from_its_checksums_is_the_built_datasets_without_sizes(carded):
    """recipe_croissant reads no build: the recipe and checksums.json give the same record as the built
    dataset, less what the checksums do not hold (file sizes, the manifest)."""
    from lidarsim.croissant import recipe_croissant

    _, recipe = carded
    built = json.loads((recipe / "croissant.json").read_text())
    from_sums = recipe_croissant(recipe, built["license"], built["citeAs"])
    expected = dict(built)
    expected["distribution"] = [
        {k: v for k, v in d.items() if k != "contentSize"} for d in built["distribution"] if d["@id"] != "manifest.json"
    ]
    assert from_sums == expected
    assert len(from_sums["distribution"]) == len(built["distribution"]) - 1


SHIPPED = sorted(p.parent for p in (Path(__file__).resolve().parents[2] / "datasets").glob("*/checksums.json"))


@pytest.mark.parametrize("recipe", SHIPPED, ids=[p.name for p in SHIPPED])
def test_every_published_recipe_ships_a_croissant_that_mlcroissant_validates(recipe, caplog):
    """datasets/NAME/croissant.json is the one `hd card --recipe datasets/NAME` writes from the checksums
    (in step with them: every shard with its published sha256), and valid Croissant 1.0."""
    import mlcroissant as mlc

    from lidarsim.card import PAPER_CITATION

    path = recipe / "croissant.json"
    shipped = json.loads(path.read_text())
    sums = json.loads((recipe / "checksums.json").read_text())
    from lidarsim.croissant import recipe_croissant

    assert shipped == recipe_croissant(recipe, shipped["license"], PAPER_CITATION)
    files = {d["contentUrl"]: d["sha256"] for d in shipped["distribution"] if d["@type"] == "cr:FileObject"}
    published = sums["shards"] + [e for lab in sums.get("labelings", []) for e in lab["shards"]]
    assert files == {e["path"]: e["sha256"] for e in published}
    with caplog.at_level(logging.WARNING):
        metadata = mlc.Dataset(jsonld=path).metadata
    assert not metadata.ctx.issues.errors, metadata.ctx.issues.report()
    labelings = sums.get("labelings", [])
    assert [r.name for r in metadata.record_sets] == ["scans", *(f"labels-{k}" for k in range(len(labelings)))]
