"""The dataset recipes come with an installed hd: datasets/ is shipped as the package data
``lidarsim/datasets`` (pyproject.toml), where ``lidarsim.recipe`` looks for a recipe by name."""

from __future__ import annotations

import fnmatch
import json
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from lidarsim.errors import RecipeError
from lidarsim.recipe import SOURCE_RECIPES, shipped_recipe, shipped_recipe_dirs

REPO = Path(__file__).resolve().parents[2]
PACKAGE = "lidarsim.datasets"
TOP_PACKAGES = ("hdcore", "lidarsim", "hdlabels", "hdnet", "hdcli")  # the packages a wheel holds


def test_every_file_of_the_recipes_is_package_data() -> None:
    setuptools = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert PACKAGE in setuptools["packages"] and setuptools["package-dir"][PACKAGE] == "datasets"
    patterns = setuptools["package-data"][PACKAGE]
    files = [p.relative_to(REPO / "datasets").as_posix() for p in (REPO / "datasets").rglob("*") if p.is_file()]
    assert "mars-paper/recipe.toml" in files
    missed = [f for f in files if not any(fnmatch.fnmatch(f, pattern) for pattern in patterns)]
    assert missed == []


def test_every_sub_package_is_installed() -> None:
    """pyproject lists its packages by name: a new sub-package (``hdcore.storage``) must be listed
    too, or a wheel (a non-editable install) would lack it."""
    listed = set(tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {
        ".".join(init.parent.relative_to(REPO).parts)
        for top in TOP_PACKAGES
        for init in (REPO / top).rglob("__init__.py")
    }
    assert "hdcore.storage" in found
    assert found - listed == set()


def test_a_shipped_recipe_is_found_by_name_and_only_among_the_shipped_ones(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mars-paper").mkdir()  # a folder of the user's that happens to share the name
    assert shipped_recipe_dirs()[0] == SOURCE_RECIPES
    assert shipped_recipe("mars-paper") == SOURCE_RECIPES / "mars-paper"
    with pytest.raises(RecipeError, match="hd ships no such recipe"):
        shipped_recipe("mars-nowhere")


def test_an_installed_wheel_finds_its_recipes(tmp_path) -> None:
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, src / name)
    for name in (*TOP_PACKAGES, "datasets"):
        shutil.copytree(REPO / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    wheels = tmp_path / "wheels"
    pip = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "--no-index"]
    built = subprocess.run([*pip, "-w", str(wheels), str(src)], capture_output=True, text=True)
    assert built.returncode == 0, built.stderr  # needs setuptools >= 77 in the venv (the test extra)
    (wheel,) = wheels.glob("hd-*.whl")
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as z:
        z.extractall(site)
    assert not (site / "datasets").exists()  # no top-level folder: the recipes live inside lidarsim
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    probe = (
        "import json, lidarsim, lidarsim.recipe as r\n"
        "paper = r.load_recipe('mars-paper')\n"
        "jezero = r.load_recipe('mars-jezero')\n"
        "print(json.dumps({'package': lidarsim.__file__, 'paper': str(paper.path),\n"
        "    'shipped': str(r.shipped_recipe('mars-paper')), 'scans': paper.build.trajectory.n_scans,\n"
        "    'jezero_dtm': jezero.build.dtm_path, 'checksums': paper.checksums() is not None}))\n"
    )
    env = {"PYTHONPATH": str(site), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", probe], cwd=elsewhere, env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    found = json.loads(out.stdout.strip().splitlines()[-1])
    packaged = site / "lidarsim" / "datasets"
    assert Path(found["package"]).parent == site / "lidarsim"
    assert Path(found["paper"]) == packaged / "mars-paper" / "recipe.toml"
    assert Path(found["shipped"]) == packaged / "mars-paper"
    assert found["scans"] == 1000 and found["checksums"]
    assert Path(found["jezero_dtm"]) == (packaged / "mars-jezero" / "jezero-hirise-3.69m.tif").resolve()
