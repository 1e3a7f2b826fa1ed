"""`hd train` and `hd eval` through the command line: the whole chain at tiny size, and its errors."""

from __future__ import annotations

import importlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner
from hdnet_datasets import build_labelled

from hdcli.cli import main
from hdnet.run_files import LAST_WHY
from tests.geotiff import write_geotiff


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
    assert f"checkpoint: last.pt ({LAST_WHY})" in result.output.splitlines()  # which one, and why not best.pt
    rows = json.loads((report / "report.json").read_text())["rows"]
    assert {r["table"] for r in rows} == {"noise", "dead_pixels"}
    checkpoint = next(x for x in (report / "report.md").read_text().splitlines() if x.startswith("- checkpoint:"))
    assert checkpoint.endswith(f"profile `tiny`; {LAST_WHY})") and "last.pt`" in checkpoint


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


# --- options and inputs checked before anything heavy; labellings by alias; URLs -------------------------
ROOT = Path(__file__).resolve().parents[2]
NO_TORCH = "import sys; sys.modules['torch'] = None; from hdcli.cli import main; main(sys.argv[1:], prog_name='hd')"


def hd_without_torch(*args: str) -> subprocess.CompletedProcess[str]:
    """``hd ARGS`` in a process where importing PyTorch fails: what it refuses, it refuses before."""
    return subprocess.run(
        [sys.executable, "-c", NO_TORCH, *args], cwd=ROOT, capture_output=True, text=True, check=False, timeout=120
    )


def fake_run(path: Path) -> Path:
    """A directory shaped like a run (a ``last.pt``), which no test may load."""
    path.mkdir()
    (path / "last.pt").write_bytes(b"not loaded")
    return path


@pytest.mark.parametrize("command", ["eval", "detect"])
@pytest.mark.parametrize(("value", "needle"), [("quantil:0.9", "is not one of"), ("quantile:2", "must be in [0, 1]")])
def test_a_threshold_typo_is_refused_before_the_network_library_is_imported(tmp_path, command, value, needle):
    """hd eval and hd detect check --threshold as they read it: no PyTorch import, no run, no data read."""
    run, data = tmp_path / "run", tmp_path / "data"  # neither exists: the option comes first
    where = ["--data", str(data)] if command == "eval" else ["--dtm", str(tmp_path / "x.tif")]
    result = hd_without_torch(command, str(run), *where, "--out", str(tmp_path / "o"), "--threshold", value)
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith(f"Error: threshold spec {value!r}") and needle in last, result.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["eval", "{run}", "--data", "{tmp}/nope"], "nope: no such dataset directory"),
        (["eval", "{tmp}/empty", "--data", "{data}"], "is not an hd run (no config.json or last.pt)"),
        (["eval", "{data}", "--data", "{data}"], "is a dataset, not a run"),
        (["eval", "{run}", "--data", "{data}", "--labels", "nope"], "no labelling named 'nope'"),
        (["eval", "{run}", "--data", "{data}", "--calibrate-on", "{tmp}/empty"], "not an hd dataset"),
        (["detect", "{run}", "--data", "{tmp}/nope", "--scan", "1"], "nope: no such dataset directory"),
        (["detect", "{run}", "--data", "{data}", "--scan", "1", "--labels", "nope"], "no labelling named 'nope'"),
        (["detect", "{run}", "--dtm", "{tmp}/nope.tif"], "nope.tif: no such file"),
    ],
)
def test_run_and_dataset_paths_are_checked_before_the_network_library_is_imported(dataset, tmp_path, args, needle):
    (tmp_path / "empty").mkdir()
    names = {"run": str(fake_run(tmp_path / "run")), "data": str(dataset), "tmp": str(tmp_path)}
    result = hd_without_torch(*[a.format(**names) for a in args], "--out", str(tmp_path / "o"))
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("Error: ") and needle in last, result.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("window", "code", "needle"),
    [
        ("1040,1960,1000,2000", 2, "XMIN 1040 must be less than XMAX 1000"),  # a usage error of --window
        ("0,0,10,10", 1, "lies outside site.tif, whose bounds are x 1000 to 1040, y 1960 to 2000 (map metres)"),
    ],
)
def test_a_window_is_checked_before_the_network_library_is_imported(tmp_path, window, code, needle):
    """hd detect --window: its form as the option is read, whether it overlaps the DTM from the DTM's header."""
    dtm = write_geotiff(tmp_path / "site.tif", np.zeros((40, 40)))  # top-left (1000, 2000), 1 m cells
    run = fake_run(tmp_path / "run")
    result = hd_without_torch("detect", str(run), "--dtm", str(dtm), "--window", window, "--out", str(tmp_path / "o"))
    assert result.returncode == code and "Traceback" not in result.stderr, result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("Error: ") and needle in last, result.stderr
    assert not (tmp_path / "o").exists()


def test_eval_and_detect_check_their_inputs_before_the_run_is_loaded(dataset, tmp_path, monkeypatch):
    """In the library too (hdnet.evaluate.evaluate, hdnet.detect.detect): a typo in a path or a labelling
    is refused before the checkpoint is read."""
    detect_module = importlib.import_module("hdnet.detect")  # the modules: hdnet.detect is the function
    trained_run_module = importlib.import_module("hdnet.trained_run")  # where hd eval loads a checkpoint

    def never(*args, **kwargs):
        raise AssertionError("the run was loaded before the inputs were checked")

    monkeypatch.setattr(detect_module, "load_run", never)
    monkeypatch.setattr(trained_run_module, "load_trained_model", never)
    run = fake_run(tmp_path / "run")
    cases = [
        (["eval", run, "--data", dataset, "--calibrate-on", tmp_path / "nope"], "no such dataset directory"),
        (["eval", run, "--data", dataset, "--labels", "nope"], "no labelling named 'nope'"),
        (["detect", run, "--data", tmp_path / "nope", "--scan", "1"], "no such dataset directory"),
        (["detect", run, "--data", dataset, "--scan", "1", "--labels", "nope"], "no labelling named 'nope'"),
        (["detect", run, "--dtm", tmp_path / "nope.tif"], "no such file"),
    ]
    for args, needle in cases:
        result = CliRunner().invoke(main, [*map(str, args), "--out", str(tmp_path / "o")])
        assert result.exit_code == 1 and not isinstance(result.exception, AssertionError), result.output
        assert result.output.strip().splitlines()[-1].startswith("Error: ") and needle in result.output
    assert not (tmp_path / "o").exists()


def test_train_checks_its_dataset_and_labelling_before_the_run_directory(dataset, tmp_path, monkeypatch):
    """hd train refuses an unknown labelling, and takes an alias, before it looks at its run directory."""
    fit_module = importlib.import_module("hdnet.fit")  # the module: hdnet.fit is the function

    def never(*args, **kwargs):
        raise AssertionError("the run directory was prepared before the labelling was checked")

    monkeypatch.setattr(fit_module, "prepare_run_dir", never)
    result = CliRunner().invoke(main, ["train", str(dataset), "--out", str(tmp_path / "run"), "--labels", "nope"])
    assert result.exit_code == 1 and not isinstance(result.exception, AssertionError), result.output
    last = result.output.strip().splitlines()[-1]
    assert last.startswith("Error: ") and "no labelling named 'nope'" in last and "(aliases: paper" in last
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    "args",
    [
        ["eval", "s3://bucket/run", "--data", "DATA", "--out", "OUT"],
        ["eval", "RUN", "--data", "DATA", "--out", "https://host/report"],
        ["detect", "RUN", "--dtm", "gs://bucket/dtm.tif", "--out", "OUT"],
        ["train", "DATA", "--out", "s3://bucket/run"],
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
    assert f"{url} is a URL" in last and "this argument takes a local path" in last, result.output
    assert url.replace("//", "/", 1) not in result.output.replace(url, "")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DATA", "RUN"]  # nothing created


def split_scans(dataset: Path, labels: str, split: str) -> list[int]:
    """The scan indices of one split of a labelling (0 train, 1 val, 2 test in the label shards)."""
    from hdlabels.store import find_labeling

    code = ("train", "val", "test").index(split)
    scans: list[int] = []
    for path in find_labeling(dataset, labels).shard_paths(dataset):
        with h5py.File(path) as f:
            scans += [int(s) for s, k in zip(f["scan_index"][:], f["split"][:], strict=True) if k == code]
    return scans


@pytest.fixture(scope="module")
def two_truths(dataset, tmp_path_factory):
    """A copy of the dataset labelled twice by one lander: the clean scan's labelling (the run's) and
    the terrain's, whose name the clean one's is a prefix of; and a run trained on the clean one."""
    from hdlabels.labeling import label_dataset
    from hdlabels.settings import LabelSettings

    root = tmp_path_factory.mktemp("two-truths")
    copy = root / "data"
    shutil.copytree(dataset, copy)
    terrain = label_dataset(copy, LabelSettings(truth="terrain"), workers=1).name
    run = root / "run"
    result = CliRunner().invoke(main, ["train", str(dataset), "--out", str(run), "--profile", "tiny", "--epochs", "1"])
    assert result.exit_code == 0, result.output
    clean = json.loads((run / "config.json").read_text())["extra_config"]["labels"]
    assert terrain.startswith(clean) and terrain != clean
    return copy, run, clean, terrain


def test_eval_defaults_to_the_runs_labelling_and_detect_takes_an_alias(two_truths, tmp_path):
    """With the clean-scan and terrain labellings side by side, hd eval scores against the labelling
    the run was trained on without --labels, and --labels paper+terrain picks the terrain's."""
    data, run, clean, terrain = two_truths
    report = tmp_path / "report"
    result = CliRunner().invoke(
        main, ["eval", str(run), "--data", str(data), "--out", str(report), "--mc-samples", "2"]
    )
    assert result.exit_code == 0, result.output
    assert json.loads((report / "report.json").read_text())["run"]["labels"] == clean
    again = CliRunner().invoke(
        main, ["eval", str(run), "--data", str(data), "--out", str(report), "--mc-samples", "2", "--labels", "paper"]
    )
    assert again.exit_code == 0 and "already holds this evaluation's report" in again.output, again.output
    out = tmp_path / "maps"
    scan = split_scans(data, clean, "test")[0]
    args = ["detect", str(run), "--data", str(data), "--scan", str(scan), "--out", str(out), "--mc-samples", "2"]
    result = CliRunner().invoke(main, [*args, "--threshold", "nats:0.3", "--labels", "paper+terrain"])
    assert result.exit_code == 0, result.output
    assert json.loads((out / "detect.json").read_text())["input"]["labels"] == terrain


def test_train_resume_says_where_it_resumes_before_its_epoch_lines(dataset, tmp_path):
    from hdnet.fit import FitConfig, fit

    run = tmp_path / "run"
    fit(dataset, run, FitConfig(profile="tiny", epochs=2, stop_after=1, progress=False))  # stopped after epoch 1
    args = ["train", str(dataset), "--out", str(run), "--profile", "tiny", "--epochs", "2", "--resume"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0] == f"train: resuming at epoch 2 of 2 (1 done, from {run.resolve() / 'last.pt'})", result.output
    assert lines[1].startswith("train: epoch 2/2, train loss ") and lines[2].startswith("training done: ")
