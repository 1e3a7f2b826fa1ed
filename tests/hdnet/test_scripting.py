"""Output made for scripts: -q, --no-progress, plain progress lines in logs, inspect --json, inspect RUN."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner
from hdnet_datasets import build_labelled

from hdcli.cli import main
from hdnet.fit import FitConfig, fit
from hdnet.profiles import TINY

HD = [sys.executable, "-c", "import sys; from hdcli.cli import main; sys.exit(main())"]
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def data_and_run(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("scripting")
    data = build_labelled(root / "d", n_scans=20)
    run = root / "run"
    fit(data, run, FitConfig(profile=TINY, epochs=2, progress=False))
    return data, run


def _hd(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*HD, *args], cwd=cwd, capture_output=True, text=True, timeout=600, env=None)


def test_quiet_prints_nothing_and_logs_get_lines_not_carriage_returns(tmp_path):
    build = ["build-dataset", "--scans", "6", "--shard-size", "3", "--resolution", "32", "--workers", "1"]
    logged = subprocess.run(
        [*HD, *build, "--out", str(tmp_path / "a")], cwd=REPO, capture_output=True, text=True, timeout=600
    )
    assert logged.returncode == 0, logged.stderr
    assert "\r" not in logged.stderr and "scans: 6/6 (100%)" in logged.stderr
    assert logged.stdout.startswith("Built 6 scans")
    quiet = subprocess.run(
        [*HD, "-q", *build, "--out", str(tmp_path / "b")], cwd=REPO, capture_output=True, text=True, timeout=600
    )
    assert quiet.returncode == 0 and quiet.stdout == "" and quiet.stderr == ""
    again = subprocess.run(
        [*HD, "--no-progress", *build, "--out", str(tmp_path / "b")], cwd=REPO, capture_output=True, text=True
    )
    assert again.returncode == 0 and again.stderr == "" and "already holds this dataset" in again.stdout


def test_inspect_describes_datasets_and_runs_in_json_too(data_and_run):
    data, run = data_and_run
    runner = CliRunner()
    record = json.loads(runner.invoke(main, ["inspect", str(data), "--json"]).output)
    assert record["kind"] == "hd.dataset" and record["n_scans"] == 20 and record["intact"] is True
    assert record["labelings"][0]["name"].startswith("paper-") and record["sigmas_m"] == [0.0167, 0.07]
    text = runner.invoke(main, ["inspect", str(run)])
    assert text.exit_code == 0 and "epochs    2 of 2 done" in text.output and "profile   tiny" in text.output
    as_json = json.loads(runner.invoke(main, ["inspect", str(run), "--json"]).output)
    assert as_json["kind"] == "hd.run" and as_json["epochs_done"] == 2 and as_json["finished"] is True
    assert as_json["dataset"] == str(data.resolve()) and as_json["train_sigma_m"] == 0.0167


def test_a_dataset_given_where_a_run_is_expected_is_named_as_such(data_and_run, tmp_path):
    data, _ = data_and_run
    result = CliRunner().invoke(main, ["eval", str(data), "--data", str(data), "--out", str(tmp_path / "r")])
    assert result.exit_code != 0 and "is a dataset, not a run" in result.output
    assert not (tmp_path / "r").exists()


def test_a_usage_error_is_one_line_with_exit_status_2():
    for args, needle in (
        (["eval", "run", "--thresold", "mean"], "No such option '--thresold'"),
        (["nocommand"], "No such command 'nocommand'"),
        (["train", "data", "--epochs", "0"], "--epochs"),
    ):
        result = subprocess.run([*HD, *args], cwd=REPO, capture_output=True, text=True, timeout=120)
        lines = result.stderr.strip().splitlines()
        assert result.returncode == 2 and len(lines) == 1, result.stderr
        assert lines[0].startswith("Error: ") and needle in lines[0] and "--help')" in lines[0]


def test_an_identical_finished_training_run_again_is_done_already(data_and_run):
    data, run = data_and_run
    before = (run / "last.pt").stat().st_mtime_ns
    args = ["train", str(data), "--out", str(run), "--profile", "tiny", "--epochs", "2"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0 and "already holds this training" in result.output, result.output
    assert (run / "last.pt").stat().st_mtime_ns == before
    other = CliRunner().invoke(main, [*args[:-1], "3"])  # more epochs: not the same training
    assert other.exit_code != 0 and "--resume" in other.output


def test_an_identical_evaluation_run_again_is_done_already(data_and_run, tmp_path):
    data, run = data_and_run
    args = ["eval", str(run), "--data", str(data), "--out", str(tmp_path / "r"), "--mc-samples", "1"]
    first = CliRunner().invoke(main, args)
    assert first.exit_code == 0, first.output
    stamp = (tmp_path / "r" / "report.json").stat().st_mtime_ns
    again = CliRunner().invoke(main, args)
    assert again.exit_code == 0 and "already holds this evaluation's report" in again.output, again.output
    assert (tmp_path / "r" / "report.json").stat().st_mtime_ns == stamp
    other = CliRunner().invoke(main, [*args, "--seed", "1"])
    assert other.exit_code != 0 and "--overwrite" in other.output


def test_every_summary_comes_as_json_with_hd_json(data_and_run, tmp_path):
    data, run = data_and_run
    runner = CliRunner()

    def record(*args: str) -> dict:
        result = runner.invoke(main, ["--json", *args])
        assert result.exit_code == 0, result.output
        lines = [line for line in result.stdout.splitlines() if line.startswith("{")]
        assert len(lines) == 1, result.stdout
        return json.loads(lines[0])

    build = ["build-dataset", "--out", str(tmp_path / "d"), "--scans", "6", "--shard-size", "3"]
    built = record(*build, "--resolution", "32", "--workers", "1")
    assert built["command"] == "build-dataset" and built["n_scans"] == 6 and built["already_built"] is False
    labelled = record("label", str(tmp_path / "d"), "--workers", "1")
    assert labelled["command"] == "label" and labelled["n_scans"] == 6
    trained = record("train", str(data), "--out", str(run), "--profile", "tiny", "--epochs", "2")
    assert trained["already_done"] is True and trained["epochs_done"] == 2
    evaluated = record("eval", str(run), "--data", str(data), "--out", str(tmp_path / "r"), "--mc-samples", "1")
    assert evaluated["command"] == "eval" and {r["method"] for r in evaluated["rows"]} >= {"uncertainty_aware"}


def test_the_global_json_flag_is_honoured_by_inspect(data_and_run):
    runner = CliRunner()
    for directory, kind in zip(data_and_run, ("hd.dataset", "hd.run"), strict=True):
        result = runner.invoke(main, ["--json", "inspect", str(directory)])
        assert result.exit_code == 0, result.output
        assert json.loads(result.stdout)["kind"] == kind


@pytest.mark.parametrize("command", ["make-dtm", "verify", "card", "demo", "reproduce"])
def test_the_global_json_flag_is_refused_by_a_command_without_json_output(data_and_run, tmp_path, command):
    data, _ = data_and_run
    args = {
        "make-dtm": [str(tmp_path / "t.tif")],
        "verify": [str(data)],
        "card": [str(data), "--recipe", str(tmp_path)],
        "demo": ["--out", str(tmp_path / "demo"), "--scans", "2"],  # settings refused quickly, were it to run
        "reproduce": ["--out", str(tmp_path / "repro"), "--recipe", str(tmp_path)],
    }[command]
    result = CliRunner().invoke(main, ["--json", command, *args])
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1, result.output
    assert lines[0].startswith("Error: ") and f" {command} has no JSON output; run it without --json" in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # refused before anything is written
    help_text = CliRunner().invoke(main, ["--json", command, "--help"])
    assert help_text.exit_code == 0 and "Usage:" in help_text.output


def test_a_summary_ends_a_live_progress_bar_before_it_is_printed(capsys, monkeypatch):
    from hdcli import terminal

    monkeypatch.delenv("TQDM_DISABLE", raising=False)
    for name, value in (("progress", True), ("lines", False), ("quiet", False), ("json", False)):
        monkeypatch.setattr(terminal.OUTPUT, name, value)
    with terminal.ScanProgress("scans") as progress:  # a bar on a terminal, as hd build-dataset draws it
        progress(3, 3)
        assert not capsys.readouterr().err.endswith("\n")  # the bar's line is still open
        terminal.say("Built 3 scans")
        captured = capsys.readouterr()
    assert captured.err.endswith("\n") and captured.out == "Built 3 scans\n"  # the bar ended first
    progress(3, 3)  # a late update of the ended bar draws nothing
    assert capsys.readouterr().err == ""


def test_a_progress_line_names_its_unit_once():
    from hdcli.terminal import ScanProgress

    assert ScanProgress("descents", unit="descent").line(20, 200) == "descents: 20/200"
    assert ScanProgress("scans").line(3, 6) == "scans: 3/6"
    assert ScanProgress("eval", unit="image").line(3, 8) == "eval: 3/8 images"
