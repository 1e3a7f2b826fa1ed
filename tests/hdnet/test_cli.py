"""`hd train` and `hd eval` through the command line: the whole chain at tiny size, and its errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner
from hdnet_datasets import build_labelled

from cli import main


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return build_labelled(tmp_path_factory.mktemp("cli"))


def test_train_then_eval_writes_the_report(dataset, tmp_path):
    runner = CliRunner()
    run, report = tmp_path / "run", tmp_path / "report"
    result = runner.invoke(main, ["train", str(dataset), "--out", str(run), "--profile", "tiny", "--epochs", "1"])
    assert result.exit_code == 0, result.output
    assert (run / "last.pt").is_file() and (run / "metrics.csv").is_file()
    stamp = (run / "last.pt").stat().st_mtime_ns
    again = runner.invoke(main, ["train", str(dataset), "--out", str(run), "--profile", "tiny", "--epochs", "1"])
    assert again.exit_code == 0 and "already holds this training" in again.output  # done: nothing overwritten
    other = runner.invoke(main, ["train", str(dataset), "--out", str(run), "--profile", "tiny", "--epochs", "2"])
    assert other.exit_code != 0 and "resume" in other.output  # an existing run is never overwritten
    assert (run / "last.pt").stat().st_mtime_ns == stamp
    result = runner.invoke(
        main,
        ["eval", str(run), "--data", str(dataset), "--out", str(report), "--mc-samples", "2", "--drop-pixels", "3"],
    )
    assert result.exit_code == 0, result.output
    assert "uncertainty_aware" in result.output
    rows = json.loads((report / "report.json").read_text())["rows"]
    assert {r["table"] for r in rows} == {"noise", "dead_pixels"}
    assert (report / "report.md").is_file()


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--mc-samples", "0"], "M"),
        (["--drop-pixels", "-1"], "drop"),
        (["--threshold", "risk:1.5"], "alpha"),
    ],
)
def test_eval_bad_options_are_one_line_errors(dataset, tmp_path, args, needle):
    runner = CliRunner()
    run = tmp_path / "run"
    assert (
        runner.invoke(main, ["train", str(dataset), "--out", str(run), "--profile", "tiny", "--epochs", "1"]).exit_code
        == 0
    )
    result = runner.invoke(main, ["eval", str(run), "--data", str(dataset), "--out", str(tmp_path / "r"), *args])
    assert result.exit_code != 0 and "Traceback" not in result.output
    assert result.output.strip().splitlines()[-1].startswith("Error: ")
    assert needle.lower() in result.output.lower()
    assert not (tmp_path / "r" / "report.json").exists()


def test_train_on_an_unlabelled_dataset_or_an_impossible_sigma_fails_clearly(tmp_path):
    bare = build_labelled(tmp_path / "bare", label=False)
    runner = CliRunner()
    result = runner.invoke(main, ["train", str(bare), "--out", str(tmp_path / "run")])
    assert result.exit_code != 0 and "hd label" in result.output
    labelled = build_labelled(tmp_path / "lab")
    result = runner.invoke(main, ["train", str(labelled), "--out", str(tmp_path / "run2"), "--train-sigma", "0.9"])
    assert result.exit_code != 0 and "must be in [0, 0.7] metres" in result.output
