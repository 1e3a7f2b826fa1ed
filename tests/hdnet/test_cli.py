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
    assert result.exit_code == 2 and "0.7 (noise levels are in metres" in result.output  # refused as it is parsed


@pytest.mark.parametrize(
    "args",
    [
        ["build-dataset", "--sigma", "7", "--scans", "4"],
        ["detect", "RUN", "--dtm", "RUN/x.tif", "--sigma", "7"],
        ["train", "DATA", "--train-sigma", "7"],
        ["train", "DATA", "--train-sigma-range", "0:7"],
        ["eval", "RUN", "--data", "DATA", "--sigma-sweep", "0:15:1"],
        ["export", "DATA", "--cloud", "noisy", "--sigma", "7"],
    ],
)
def test_a_noise_level_in_centimetres_is_refused_with_its_unit_before_any_work(tmp_path, args):
    """σ is in metres everywhere, bounded by one limit (lidarsim.limits.MAX_SIGMA_M = 0.7 m): 7 (cm
    typed as metres) is refused by every command with the unit in the message, and nothing is written."""
    for d in ("RUN", "DATA"):
        (tmp_path / d).mkdir()
    out = tmp_path / "out"
    argv = [str(tmp_path / a) if a in ("RUN", "DATA", "RUN/x.tif") else a for a in args]
    result = CliRunner().invoke(main, [*argv, "--out", str(out)])
    assert result.exit_code != 0
    assert "0.7" in result.output and "noise levels are in metres: 7 cm is 0.07" in result.output, result.output
    assert not out.exists()


def test_a_recipe_noise_level_in_centimetres_is_refused_with_its_unit(tmp_path):
    recipe = tmp_path / "r"
    recipe.mkdir()
    (recipe / "recipe.toml").write_text('[dataset]\nname = "r"\nversion = 1\n\n[build]\nscans = 4\nsigmas_m = [7]\n')
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["build-dataset", "--recipe", str(recipe), "--out", str(out)])
    assert result.exit_code != 0 and "noise levels are in metres: 7 cm is 0.07" in result.output, result.output
    assert not out.exists()


@pytest.mark.parametrize("command", ["eval", "detect"])
def test_eval_and_detect_offer_the_uncertainty_score(command):
    result = CliRunner().invoke(main, [command, "--help"], terminal_width=200)
    assert result.exit_code == 0 and "--uncertainty [entropy|mutual-information]" in result.output
    assert "[default: entropy]" in result.output.split("--uncertainty", 1)[1]
    bad = CliRunner().invoke(main, [command, "run", "--out", "out", "--uncertainty", "bald"])
    assert bad.exit_code != 0 and "'bald' is not one of 'entropy', 'mutual-information'" in bad.output


@pytest.mark.parametrize(
    "args",
    [
        ["inspect", "s3://bucket/x"],
        ["verify", "s3://bucket/x"],
        ["eval", "s3://bucket/run", "--data", "DATA", "--out", "OUT"],
        ["eval", "RUN", "--data", "https://host/data", "--out", "OUT"],
        ["detect", "RUN", "--dtm", "gs://bucket/dtm.tif", "--out", "OUT"],
        ["train", "s3://bucket/x", "--out", "OUT"],
        ["label", "file:///data/x"],
        ["build-dataset", "--out", "s3://bucket/new"],
    ],
)
def test_a_url_is_refused_with_its_name_intact_never_read_as_a_path(tmp_path, monkeypatch, args):
    """Every path argument is a NonEmptyPath: s3://bucket/x is not read as the local path s3:/bucket/x
    (which build-dataset would create in the current directory)."""
    monkeypatch.chdir(tmp_path)
    for name in ("RUN", "DATA"):
        (tmp_path / name).mkdir()
    argv = [str(tmp_path / a) if a in ("RUN", "DATA", "OUT") else a for a in args]
    result = CliRunner().invoke(main, argv)
    url = next(a for a in args if "://" in a)
    assert result.exit_code == 2, result.output
    last = result.output.strip().splitlines()[-1]
    assert f"{url} is a URL" in last and "URLs are not read yet" in last, result.output
    assert url.replace("//", "/", 1) not in result.output.replace(url, "")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DATA", "RUN"]  # nothing created
