"""The design card's usages, typed exactly as the card and the README give them, end to end.

``hd build-dataset --dtm sabrina.tif --sigma 0.07`` (no ``--out``: the directory is derived from
the DTM's name and printed), ``hd label``, ``hd train``, ``hd eval --drop-pixels 10``. The command
lines are the card's; only the amount of work is made tiny, by wrapping the package entry points
the commands call: the wrappers record the configuration the command line produced (so the test
checks the card's defaults reached the packages) and run it with 10 scans of a 32 x 32 detector
and one epoch of the tiny profile.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from hdnet_datasets import hills_dtm

import lidarsim.build
from hdcli.cli import main
from hdlabels import defaults as label_defaults
from hdnet.fit import FitConfig
from lidarsim import defaults as lidar_defaults

FIT_MODULE = importlib.import_module("hdnet.fit")  # the module: hdnet.fit is the function (hdcore.exports)


@pytest.fixture
def tiny_work(monkeypatch: pytest.MonkeyPatch) -> dict[str, list[Any]]:
    """Wrap build_dataset and fit: record what the command asked for, run it at tiny size."""
    seen: dict[str, list[Any]] = {"build": [], "fit": []}
    real_build, real_fit = lidarsim.build.build_dataset, FIT_MODULE.fit

    def build(out_dir: Any, config: lidarsim.build.BuildConfig, **kwargs: Any) -> Any:
        seen["build"].append(config)
        small = dataclasses.replace(
            config,
            sensor=dataclasses.replace(config.sensor, rows=32, cols=32),
            trajectory=dataclasses.replace(config.trajectory, n_scans=10),
            shard_size=5,
        )
        return real_build(out_dir, small, **{**kwargs, "workers": 1})

    def fit(dataset_dir: Any, run_dir: Any, config: FitConfig) -> Path:
        seen["fit"].append(config)
        return real_fit(dataset_dir, run_dir, dataclasses.replace(config, profile="tiny", epochs=1, progress=False))

    monkeypatch.setattr(lidarsim.build, "build_dataset", build)
    monkeypatch.setattr(FIT_MODULE, "fit", fit)
    return seen


def hd(*argv: str) -> Any:
    result = CliRunner().invoke(main, list(argv))
    assert result.exit_code == 0, result.output
    return result


def test_the_cards_usages_run_verbatim(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, tiny_work: dict) -> None:
    monkeypatch.chdir(tmp_path)
    hills_dtm(tmp_path / "sabrina.tif")

    built = hd("build-dataset", "--dtm", "sabrina.tif", "--sigma", "0.07")
    assert "no --out given: building into sabrina" in built.output
    (config,) = tiny_work["build"]
    assert config.sigmas_m == (0.07,) and Path(config.dtm_path).name == "sabrina.tif"
    assert config.trajectory.n_scans == lidar_defaults.N_SCANS  # the card's defaults reached the build
    manifest = json.loads((tmp_path / "sabrina" / "manifest.json").read_text())
    assert manifest["sigmas_m"] == [0.07] and manifest["n_scans"] == 10

    hd("label", "sabrina")
    manifest = json.loads((tmp_path / "sabrina" / "manifest.json").read_text())
    (labeling,) = manifest["labelings"]
    assert labeling["lander"]["convention"] == label_defaults.CONVENTION

    trained = hd("train", "sabrina", "--out", "run")  # the dataset's only noise level, 7 cm
    (fit_config,) = tiny_work["fit"]
    assert fit_config.profile == "cpu" and fit_config.train_sigma_m is None
    assert json.loads((tmp_path / "run" / "config.json").read_text())["extra_config"]["train_sigma_m"] == 0.07
    assert "training done" in trained.output
    assert (tmp_path / "run" / "last.pt").is_file()

    evaluated = hd("eval", "run", "--data", "sabrina", "--out", "report", "--drop-pixels", "10")
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    assert report["run"]["drop_pixels"] == 10 and report["run"]["sigmas_m"] == [0.07]
    tables = {row["table"] for row in report["rows"]}
    assert tables == {"noise", "dead_pixels"}  # Table 1 and Table 2
    assert "report.md" in evaluated.output


def test_building_again_without_out_refuses_to_overwrite(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, tiny_work: dict
) -> None:
    monkeypatch.chdir(tmp_path)
    hills_dtm(tmp_path / "sabrina.tif")
    hd("build-dataset", "--dtm", "sabrina.tif", "--sigma", "0.07")
    before = (tmp_path / "sabrina" / "manifest.json").read_bytes()
    again = CliRunner().invoke(main, ["build-dataset", "--dtm", "sabrina.tif", "--sigma", "0.03"])
    assert again.exit_code != 0 and again.output.strip().splitlines()[-1].startswith("Error:")
    assert (tmp_path / "sabrina" / "manifest.json").read_bytes() == before
