"""croissant.json: hd card writes Croissant 1.0 metadata that the mlcroissant library validates,
naming every file with its sha256 and every array of the shards as a field."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import h5py
import pytest
from click.testing import CliRunner

from cli import main
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
