"""Class G: no overwrite of what is not hd's, no leftovers after a failure, consistent runs after a kill."""

from __future__ import annotations

import csv
import shutil
import signal

import pytest
import torch
from reliability_kit import (
    BUILD_ARGS,
    assert_one_line_error,
    hd_process,
    invoke,
    kill_and_check_no_orphans,
    partials,
    wait_for,
)


def _train(data, run, *more):
    return invoke("train", data, "--out", run, "--profile", "tiny", "--epochs", "1", *more)


def _files(d):
    return {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}


# ------------------------------------------------------------------------------------- train --out
def test_train_refuses_a_foreign_directory_even_with_overwrite(tmp_path, labelled):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "config.json").write_text('{"my": "settings"}')
    (mine / "metrics.csv").write_text("my,metrics\n")
    (mine / "notes.txt").write_text("keep me")
    before = _files(mine)
    assert_one_line_error(_train(labelled, mine), "not an hd run", "--out")
    assert _files(mine) == before
    assert_one_line_error(_train(labelled, mine, "--overwrite"), "not an hd run", "never other files")
    assert _files(mine) == before  # --overwrite replaces runs only, never a user's config.json


def test_train_refuses_an_existing_run_without_resume_or_overwrite(tmp_path, labelled, trained):
    run = tmp_path / "run"
    shutil.copytree(trained, run)
    before = _files(run)
    same = _train(labelled, run)  # the same finished training again: nothing to do, nothing touched
    assert same.exit_code == 0 and "already holds this training" in same.output, same.output
    assert _files(run) == before
    assert_one_line_error(_train(labelled, run, "--seed", "1"), "already holds a checkpoint", "--resume", "--overwrite")
    assert _files(run) == before
    result = _train(labelled, run, "--overwrite", "--seed", "1")
    assert result.exit_code == 0, result.output
    assert _files(run)["last.pt"] != before["last.pt"]


# ------------------------------------------------------------------------------------- eval --out
def test_eval_refuses_an_existing_report_and_a_foreign_directory(tmp_path, labelled, trained):
    report = tmp_path / "report"
    args = ["eval", trained, "--data", labelled, "--out", report, "--mc-samples", "2"]
    assert invoke(*args).exit_code == 0
    before = _files(report)
    same = invoke(*args)  # the same evaluation again: nothing to do, nothing touched
    assert same.exit_code == 0 and "already holds this evaluation's report" in same.output, same.output
    assert_one_line_error(invoke(*args, "--seed", "3"), "already holds an hd report", "--overwrite")
    assert _files(report) == before
    result = invoke(*args, "--overwrite", "--seed", "5")
    assert result.exit_code == 0, result.output
    assert sorted(_files(report)) == sorted(before) and partials(report) == []
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "report.md").write_text("my own report")
    assert_one_line_error(invoke("eval", trained, "--data", labelled, "--out", foreign), "already holds an hd report")
    (foreign / "report.md").rename(foreign / "thesis.md")
    for more in ([], ["--overwrite"]):
        result = invoke("eval", trained, "--data", labelled, "--out", foreign, *more)
        assert_one_line_error(result, "holds no hd report")
    assert (foreign / "thesis.md").read_text() == "my own report"


# ------------------------------------------------------------------------------------- outputs never hold inputs
def _tree(path):
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def test_train_eval_and_build_refuse_an_output_that_is_holds_or_lies_inside_an_input(tmp_path, labelled, trained, dtm):
    data_before, run_before = _tree(labelled), _tree(trained)
    for out, needle in ((labelled, "is the dataset"), (labelled / "run", "lies inside the dataset")):
        for more in ([], ["--overwrite"]):
            assert_one_line_error(_train(labelled, out, *more), needle, "an output never replaces")
    for out, needle in (
        (trained, "is the run"),
        (trained / "report", "lies inside the run"),
        (labelled, "is the dataset"),
        (labelled.parent, "contains the dataset"),
    ):
        for more in ([], ["--overwrite"]):
            result = invoke("eval", trained, "--data", labelled, "--out", out, "--mc-samples", "1", *more)
            assert_one_line_error(result, needle, "an output never replaces")
    site = tmp_path / "site"
    site.mkdir()
    shutil.copy(dtm, site / "site.tif")
    site_before = _tree(site)
    for more in ([], ["--overwrite"]):
        result = invoke("build-dataset", "--dtm", site / "site.tif", "--out", site, *BUILD_ARGS, *more)
        assert_one_line_error(result, "contains the DTM", "an output never replaces")
    assert (_tree(labelled), _tree(trained), _tree(site)) == (data_before, run_before, site_before)
    assert not (labelled / "run").exists() and not (trained / "report").exists()


# ------------------------------------------------------------------------------------- failed commands leave nothing
def test_a_failed_labelling_leaves_no_empty_directory(tmp_path, reference, monkeypatch):
    data = tmp_path / "data"
    shutil.copytree(reference, data)

    def fails(task):
        from hdlabels.store import LabelStoreError

        raise LabelStoreError("a clean DEM is all NaN")

    monkeypatch.setattr("hdlabels.labeling.run_label_task", fails)
    assert_one_line_error(invoke("label", data, "--workers", "1"), "all NaN")
    assert not (data / "labels").exists() and partials(data) == [] and not (data / ".hd-lock").exists()


@pytest.mark.slow
def test_an_unreachable_scheduler_leaves_nothing(tmp_path, dtm):
    out = tmp_path / "data"
    assert_one_line_error(
        invoke("build-dataset", "--out", out, "--dtm", dtm, "--scheduler", "tcp://127.0.0.1:1", *BUILD_ARGS),
        "cannot reach the Dask scheduler",
    )
    assert list(tmp_path.iterdir()) == []


def test_a_build_failing_before_any_shard_removes_its_directory(tmp_path, dtm, monkeypatch):
    def fails(task):
        raise MemoryError

    monkeypatch.setattr("lidarsim.build.run_shard", fails)
    out = tmp_path / "new" / "deep" / "data"  # three directories created, all removed again
    assert_one_line_error(
        invoke("build-dataset", "--out", out, "--dtm", dtm, "--workers", "1", *BUILD_ARGS), "out of memory"
    )
    assert list(tmp_path.iterdir()) == []


def test_failed_train_and_eval_remove_the_directories_they_created(tmp_path, labelled, trained, monkeypatch):
    from reliability_kit import inject_enospc

    inject_enospc(monkeypatch, "config.json")
    assert_one_line_error(_train(labelled, tmp_path / "a" / "b" / "run"), "no space left")
    inject_enospc(monkeypatch, "report.json")
    assert_one_line_error(
        invoke("eval", trained, "--data", labelled, "--out", tmp_path / "c" / "report", "--mc-samples", "2"),
        "no space left",
    )
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------- run consistency after kills
def _epochs(path):
    return int(torch.load(path, weights_only=True)["epoch"])


def _rows(run):
    with open(run / "metrics.csv") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("moment", ["best.pt", "metrics.csv"])
def test_train_killed_after_the_last_checkpoint_is_consistent_after_resume(tmp_path, labelled, moment):
    """SIGKILL right after last.pt's rename (while best.pt or metrics.csv is written), then --resume."""
    run = tmp_path / "run"
    args = ["train", labelled, "--out", run, "--profile", "tiny", "--epochs", "1"]
    proc = hd_process(args, env={"HD_TEST_WRITE_PAUSE": f"{moment}:60"})
    partial = f".{moment}.partial-*"
    wait_for(lambda: run.is_dir() and list(run.glob(partial)), what=f"{moment} being written", proc=proc)
    code, _ = kill_and_check_no_orphans(proc, signal.SIGKILL)
    assert code == -signal.SIGKILL
    assert _epochs(run / "last.pt") == 1
    result = invoke(*args, "--resume")  # the run is already complete: only reconciled
    assert result.exit_code == 0, result.output
    rows = _rows(run)
    assert [int(r["epoch"]) for r in rows] == [1]
    assert _epochs(run / "best.pt") == 1 and partials(run) == [] and not (run / ".hd-lock").exists()


def test_train_stopped_by_sigterm_is_clean_and_resumes(tmp_path, labelled, trained):
    run = tmp_path / "run"
    args = ["train", labelled, "--out", run, "--profile", "tiny", "--epochs", "1"]
    proc = hd_process(args, env={"HD_TEST_WRITE_PAUSE": "last.pt:60"})
    wait_for(lambda: run.is_dir() and list(run.glob(".last.pt.partial-*")), what="last.pt being written", proc=proc)
    code, err = kill_and_check_no_orphans(proc, signal.SIGTERM)
    assert code == 128 + signal.SIGTERM and "re-run the same command to resume" in err and "Traceback" not in err
    assert partials(run) == [] and not (run / "last.pt").exists() and not (run / ".hd-lock").exists()
    result = invoke(*args, "--resume")
    assert result.exit_code == 0, result.output
    a = torch.load(run / "last.pt", weights_only=True)["model"]
    b = torch.load(trained / "last.pt", weights_only=True)["model"]  # the same seed, uninterrupted
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert [int(r["epoch"]) for r in _rows(run)] == [1]


# ------------------------------------------------------------------------------------- a run's record stays true
@pytest.fixture(scope="module")
def mix(tmp_path_factory, labelled):
    """Two labelled datasets of other data (the second: ``labelled`` with its manifest in another
    layout, so another sha256) and a one-epoch tiny run on their mix."""
    import json

    root = tmp_path_factory.mktemp("mix")
    other = root / "other"
    shutil.copytree(labelled, other)
    manifest = other / "manifest.json"
    manifest.write_text(json.dumps(json.loads(manifest.read_text()), indent=1))
    run = root / "run"
    result = _train(labelled, run, "--also", other)
    assert result.exit_code == 0, result.output
    return other, run


RESUMES = [
    # (case, the run resumed: "mix" or "plain", the call's changes, what the error line names)
    ("without-its-also", "mix", [], ["--also", "no --also dataset"]),
    ("with-a-new-also", "plain", ["--also", "{other}"], ["--also", "{other}"]),
    ("on-another-dataset", "plain", ["DATASET={other}"], ["dataset", "{other}", "{data}"]),
    ("with-another-noise", "plain", ["--train-sigma", "0.05"], ["training noise", "1.67 cm", "5 cm"]),
    ("with-another-seed", "plain", ["--seed", "7"], ["--seed 7", "seed 0", "--seed 0"]),
]


@pytest.mark.parametrize(("case", "which", "changes", "needles"), RESUMES, ids=[c[0] for c in RESUMES])
def test_resume_refuses_data_the_run_was_not_trained_on(
    tmp_path, labelled, trained, mix, case, which, changes, needles
):
    """hd train --resume took whatever data it was given and rewrote config.json to say the whole
    run was trained on them (and a finished run 'resumed' so was relabelled at no cost)."""
    other, mixed = mix
    run = tmp_path / "run"
    shutil.copytree(mixed if which == "mix" else trained, run)
    places = {"other": str(other), "data": str(labelled)}
    data = other if "DATASET={other}" in changes else labelled
    more = [c.format(**places) for c in changes if not c.startswith("DATASET=")]
    before = _files(run)
    line = assert_one_line_error(_train(data, run, "--resume", *more), "train a new run")
    for needle in needles:
        assert needle.format(**places) in line, (needle, line)
    assert _files(run) == before


def test_resume_refuses_a_dataset_changed_since(tmp_path, data_copy):
    """The same dataset directory, its manifest no longer the one the run recorded."""
    run = tmp_path / "run"
    assert _train(data_copy, run).exit_code == 0
    manifest = data_copy / "manifest.json"
    manifest.write_text(manifest.read_text() + "\n")
    before = _files(run)
    line = assert_one_line_error(_train(data_copy, run, "--resume"), "manifest", "sha256", "train a new run")
    assert str(data_copy) in line
    assert _files(run) == before


def test_resume_refuses_another_labelling(tmp_path, data_copy):
    """A run trained on one labelling of a dataset, resumed with --labels naming another."""
    result = invoke("label", data_copy, "--max-slope-deg", "8", "--workers", "1")
    assert result.exit_code == 0, result.output
    names = [p.name for p in sorted((data_copy / "labels").iterdir())]
    assert len(names) == 2
    run = tmp_path / "run"
    assert _train(data_copy, run, "--labels", names[0]).exit_code == 0
    before = _files(run)
    line = assert_one_line_error(
        _train(data_copy, run, "--resume", "--labels", names[1]), "labelling", "train a new run"
    )
    assert names[0] in line and names[1] in line
    assert _files(run) == before


def test_resume_on_the_runs_own_data_continues(tmp_path, labelled, mix):
    other, mixed = mix
    run = tmp_path / "run"
    shutil.copytree(mixed, run)
    result = invoke("train", labelled, "--out", run, "--profile", "tiny", "--epochs", "2", "--resume", "--also", other)
    assert result.exit_code == 0, result.output
    assert [int(r["epoch"]) for r in _rows(run)] == [1, 2]
    assert invoke("inspect", run).exit_code == 0


def test_resume_with_a_fifo_for_metrics_is_refused_at_once(tmp_path, labelled, trained, no_hang):
    """A FIFO in the place of metrics.csv was replaced by a new file without a word."""
    import os

    run = tmp_path / "run"
    shutil.copytree(trained, run)
    (run / "metrics.csv").unlink()
    os.mkfifo(run / "metrics.csv")
    line = assert_one_line_error(_train(labelled, run, "--resume", "--epochs", "2"), "not a regular file")
    assert "metrics.csv" in line
    assert not (run / "metrics.csv").is_file() and (run / "metrics.csv").exists()  # the FIFO is left alone


@pytest.mark.parametrize("damage", ["forged-value", "missing"])
def test_a_finished_run_with_damaged_metrics_is_not_already_done(tmp_path, labelled, trained, damage):
    """The same hd train command took a finished run whose metrics.csv had as many lines as epochs for
    done, whatever they held; now the damage is named and --resume writes the file again from last.pt."""
    run = tmp_path / "run"
    shutil.copytree(trained, run)
    metrics = run / "metrics.csv"
    if damage == "missing":
        metrics.unlink()
    else:
        header, row = metrics.read_text().splitlines()
        metrics.write_text(header + "\n" + row.replace(row.split(",")[2], "0.001", 1) + "\n")
    assert_one_line_error(invoke("inspect", run), "metrics.csv", "--resume")
    assert_one_line_error(_train(labelled, run), "already holds a checkpoint", "--resume")
    result = _train(labelled, run, "--resume")
    assert result.exit_code == 0, result.output
    assert metrics.read_bytes() == (trained / "metrics.csv").read_bytes()
    assert invoke("inspect", run).exit_code == 0
