"""Class A: workers never outlive their command; SIGKILL, SIGTERM and Ctrl-C at defined moments.

Each test starts ``hd`` with 2 worker processes, waits for a precise moment (a file half written,
held there by the fault injector), records every process the command started, signals the
command alone, checks that all of them are gone, then resumes and compares the result with the
uninterrupted reference byte for byte.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import time

import pytest
from reliability_kit import (
    BUILD_ARGS,
    LABEL_ARGS,
    alive,
    assert_one_line_error,
    descendants,
    hd_process,
    invoke,
    kill_and_check_no_orphans,
    partials,
    shard_sums,
    wait_for,
)

EXIT = {signal.SIGKILL: -signal.SIGKILL, signal.SIGTERM: 128 + signal.SIGTERM, signal.SIGINT: 128 + signal.SIGINT}
# Both workers (shards 0-1 and 2-3) stop half-way through their second file.
BOTH_SECOND_SHARDS = "scans-0000[13].h5:60"


def _partials(directory, *patterns):
    """True once every pattern matches a file in ``directory``."""
    return lambda: directory.is_dir() and all(list(directory.glob(p)) for p in patterns)


SECOND_SHARDS = (".scans-00001.h5.partial-*", ".scans-00003.h5.partial-*")


def build(out, dtm, workers):
    return ["build-dataset", "--out", out, "--dtm", dtm, "--workers", str(workers), *BUILD_ARGS]


def read_labelings(data):
    return json.loads((data / "manifest.json").read_text())["labelings"]


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM, signal.SIGINT], ids=["KILL", "TERM", "INT"])
def test_build_stopped_while_a_worker_writes_a_shard(tmp_path, dtm, reference, sig):
    out = tmp_path / "data"
    proc = hd_process(build(out, dtm, 2), env={"HD_TEST_WRITE_PAUSE": BOTH_SECOND_SHARDS})
    wait_for(_partials(out / "shards", *SECOND_SHARDS), what="two half-written shards", proc=proc)
    code, err = kill_and_check_no_orphans(proc, sig, workers=2)
    assert code == EXIT[sig], err
    assert not (out / "manifest.json").exists()
    if sig != signal.SIGKILL:  # a clean stop: one line, partial files removed
        assert "Traceback" not in err and "re-run the same command to resume" in err
        assert partials(out) == []
    result = invoke(*build(out, dtm, 1))
    assert result.exit_code == 0, result.output
    assert shard_sums(out) == shard_sums(reference)
    assert partials(out) == [] and not (out / ".hd-build.json").exists() and not (out / ".hd-lock").exists()


def test_build_killed_while_writing_its_manifest(tmp_path, dtm, reference):
    out = tmp_path / "data"
    proc = hd_process(build(out, dtm, 2), env={"HD_TEST_WRITE_PAUSE": "manifest.json:60"})
    wait_for(_partials(out, ".manifest.json.partial-*"), what="a half-written manifest", proc=proc)
    code, _ = kill_and_check_no_orphans(proc, signal.SIGKILL)
    assert code == -signal.SIGKILL and not (out / "manifest.json").exists()
    unfinished = invoke("inspect", out)
    assert_one_line_error(unfinished, "unfinished build (4 of 4 shards complete)", "re-run the same")
    result = invoke(*build(out, dtm, 1))
    assert result.exit_code == 0 and "4 shards were already complete" in result.output, result.output
    assert shard_sums(out) == shard_sums(reference)


def test_build_killed_while_generating_the_terrain_leaves_nothing(tmp_path):
    out = tmp_path / "parent" / "data"
    out.parent.mkdir()
    marks = tmp_path / "marks"
    marks.mkdir()
    proc = hd_process(
        ["build-dataset", "--out", out, "--workers", "2", *BUILD_ARGS],
        env={"HD_TEST_SLEEP": "lidarsim.build._procedural_terrain_bytes:60", "HD_TEST_MARK_DIR": str(marks)},
    )
    wait_for(lambda: (marks / "_procedural_terrain_bytes").exists(), what="terrain generation", proc=proc)
    code, _ = kill_and_check_no_orphans(proc, signal.SIGKILL)
    assert code == -signal.SIGKILL
    assert list(out.parent.iterdir()) == []  # no output directory, no hidden staging directory beside it


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["KILL", "TERM"])
def test_label_stopped_while_a_worker_writes_a_label_shard(tmp_path, reference, labelled, sig):
    data = tmp_path / "data"
    shutil.copytree(reference, data)
    proc = hd_process(
        ["label", data, "--workers", "2", *LABEL_ARGS], env={"HD_TEST_WRITE_PAUSE": "labels-0000[13].h5:60"}
    )
    wait_for(
        lambda: all(list(data.glob(f"labels/*/.labels-0000{k}.h5.partial-*")) for k in (1, 3)),
        what="two half-written label shards",
        proc=proc,
    )
    code, err = kill_and_check_no_orphans(proc, sig, workers=2)
    assert code == EXIT[sig], err
    if sig != signal.SIGKILL:
        assert "Traceback" not in err and partials(data) == []
    assert read_labelings(data) == []
    result = invoke("label", data, "--workers", "1", *LABEL_ARGS)
    assert result.exit_code == 0, result.output
    assert shard_sums(data) == shard_sums(labelled)
    assert partials(data) == [] and not (data / ".hd-lock").exists()


def test_a_worker_killed_by_the_system_fails_the_build_cleanly(tmp_path, dtm, reference):
    out = tmp_path / "data"
    proc = hd_process(build(out, dtm, 2), env={"HD_TEST_WRITE_PAUSE": BOTH_SECOND_SHARDS})
    wait_for(_partials(out / "shards", *SECOND_SHARDS), what="two half-written shards", proc=proc)
    victim = int(next((out / "shards").glob(".scans-00003.h5.partial-*")).name.rsplit("-", 1)[1])
    tracked = {p: s for p, s in descendants(proc.pid).items() if p != victim}
    os.kill(victim, signal.SIGKILL)  # the kernel's OOM killer, say
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 1, err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("Error: ") and "worker process" in last and "SIGKILL" in last, err
    wait_for(lambda: not alive(tracked), timeout=10, what="the other worker to stop")
    assert partials(out) == []
    result = invoke(*build(out, dtm, 1))
    assert result.exit_code == 0, result.output
    assert shard_sums(out) == shard_sums(reference)


def test_label_killed_while_adding_its_labelling_to_the_manifest(tmp_path, reference, labelled):
    data = tmp_path / "data"
    shutil.copytree(reference, data)
    proc = hd_process(["label", data, "--workers", "2", *LABEL_ARGS], env={"HD_TEST_WRITE_PAUSE": "manifest.json:60"})
    wait_for(_partials(data, ".manifest.json.partial-*"), what="the manifest being rewritten", proc=proc)
    code, _ = kill_and_check_no_orphans(proc, signal.SIGKILL)
    assert code == -signal.SIGKILL and read_labelings(data) == []
    result = invoke("label", data, "--workers", "1", *LABEL_ARGS)
    assert result.exit_code == 0, result.output
    assert shard_sums(data) == shard_sums(labelled) and partials(data) == []


def test_build_with_overwrite_killed_half_way_resumes_the_new_build(tmp_path, dtm, reference):
    data = tmp_path / "data"
    shutil.copytree(reference, data)
    args = ["build-dataset", "--out", data, "--dtm", dtm, *BUILD_ARGS[:-2], "--seed", "4"]
    proc = hd_process([*args, "--workers", "2", "--overwrite"], env={"HD_TEST_WRITE_PAUSE": "scans-00001.h5:60"})
    wait_for(_partials(data / "shards", ".scans-00001.h5.partial-*"), what="a half-written shard", proc=proc)
    code, _ = kill_and_check_no_orphans(proc, signal.SIGKILL)
    assert code == -signal.SIGKILL and not (data / "manifest.json").exists()
    result = invoke(*args, "--workers", "1")  # the same command without --overwrite resumes the new build
    assert result.exit_code == 0, result.output
    fresh = tmp_path / "fresh"
    assert invoke("build-dataset", "--out", fresh, "--dtm", dtm, *BUILD_ARGS[:-2], "--seed", "4").exit_code == 0
    assert shard_sums(data) == shard_sums(fresh) != shard_sums(reference)


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["KILL", "TERM"])
def test_eval_stopped_while_writing_the_report(tmp_path, labelled, trained, sig):
    report = tmp_path / "report"
    args = ["eval", trained, "--data", labelled, "--out", report, "--mc-samples", "2"]
    proc = hd_process(args, env={"HD_TEST_WRITE_PAUSE": "report.json:60"})
    wait_for(
        lambda: list(report.glob(".report.partial-*/.report.json.partial-*")),
        what="report.json being written",
        proc=proc,
    )
    code, err = kill_and_check_no_orphans(proc, sig)
    assert code == EXIT[sig]
    assert not (report / "report.json").exists() and not (report / "report.md").exists()
    if sig != signal.SIGKILL:
        assert not report.exists() and "Traceback" not in err  # staging and the directory it created removed
    result = invoke(*args)
    assert result.exit_code == 0, result.output
    assert (report / "report.json").is_file() and partials(report) == [] and not (report / ".hd-lock").exists()


def test_train_killed_while_dataloader_workers_read(tmp_path, labelled):
    """Forked DataLoader workers die with the command too."""
    marks = tmp_path / "marks"
    marks.mkdir()
    run = tmp_path / "run"
    proc = hd_process(
        ["train", labelled, "--out", run, "--profile", "tiny", "--epochs", "1", "--num-workers", "2"],
        env={
            "HD_TEST_SLEEP": "hdnet.data.HazardDataset.dem_sample:60",
            "HD_TEST_MARK_DIR": str(marks),
            "HD_TEST_SLEEP_FORKED_ONLY": "1",
        },
    )
    wait_for(
        lambda: (marks / "dem_sample").exists() and len(descendants(proc.pid)) >= 2,
        what="DataLoader workers reading",
        proc=proc,
    )
    code, _ = kill_and_check_no_orphans(proc, signal.SIGKILL, workers=2)
    assert code == -signal.SIGKILL


def test_make_dtm_killed_while_writing_then_rerun(tmp_path):
    target = tmp_path / "mars.tif"
    proc = hd_process(["make-dtm", target, "--size", "64"], env={"HD_TEST_WRITE_PAUSE": "mars.tif:60"})
    wait_for(_partials(tmp_path, ".mars.tif.partial-*"), what="mars.tif being written", proc=proc)
    code, _ = kill_and_check_no_orphans(proc, signal.SIGKILL)
    assert code == -signal.SIGKILL and not target.exists()
    result = invoke("make-dtm", target, "--size", "64")
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mars.tif"]  # the killed write's leftover is gone


def test_repeated_signals_do_not_interrupt_the_clean_up(tmp_path, dtm, reference):
    """Ctrl-C pressed again and again while the command stops: still one clean stop."""
    out = tmp_path / "data"
    proc = hd_process(build(out, dtm, 2), env={"HD_TEST_WRITE_PAUSE": BOTH_SECOND_SHARDS})
    wait_for(_partials(out / "shards", *SECOND_SHARDS), what="two half-written shards", proc=proc)
    tracked = descendants(proc.pid)
    for sig in (signal.SIGINT, signal.SIGINT, signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        os.kill(proc.pid, sig)
    _, err = proc.communicate(timeout=60)
    # pending signals are handled in signal-number order: the first one handled sets the status
    assert proc.returncode in (128 + signal.SIGHUP, 128 + signal.SIGINT, 128 + signal.SIGTERM), err
    assert "Traceback" not in err and err.count("re-run the same command to resume") == 1, err
    wait_for(lambda: not alive(tracked), timeout=10, what="the workers to stop")
    assert partials(out) == [] and not (out / ".hd-lock").exists()
    assert invoke(*build(out, dtm, 1)).exit_code == 0 and shard_sums(out) == shard_sums(reference)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["TERM", "INT"])
def test_signals_until_the_end_still_give_128_plus_the_signal(tmp_path, dtm, sig):
    """Five quick signals, then one every 10 ms until the process is gone (it exited -15 when one
    arrived after the command had returned, its default handler back in place)."""
    out = tmp_path / "data"
    proc = hd_process(build(out, dtm, 2), env={"HD_TEST_WRITE_PAUSE": BOTH_SECOND_SHARDS})
    wait_for(_partials(out / "shards", *SECOND_SHARDS), what="two half-written shards", proc=proc)
    tracked = descendants(proc.pid)
    for _ in range(5):  # the process is not reaped before communicate(): its PID cannot be reused
        os.kill(proc.pid, sig)
        time.sleep(0.05)
    deadline = time.monotonic() + 60.0
    while proc.poll() is None and time.monotonic() < deadline:
        os.kill(proc.pid, sig)
        time.sleep(0.01)
    _, err = proc.communicate(timeout=10)
    assert proc.returncode == 128 + sig, (proc.returncode, err)
    assert "Traceback" not in err and "race condition" not in err, err
    assert err.count("re-run the same command to resume") == 1, err
    wait_for(lambda: not alive(tracked), timeout=10, what="the workers to stop")
    assert partials(out) == [] and not (out / ".hd-lock").exists()


MOSAIC_ARGS = ["--workers", "1", "--dem-size", "40", "--convention", "paper"]


def test_mosaic_killed_mid_run_resumes_per_descent_to_the_same_bytes(tmp_path, dtm):
    """hd mosaic staged its whole output and its next run removed a killed run's staging: a kill
    lost every descent. Killed while its third descent is kept, it now resumes with two descents
    kept and writes the bytes of an uninterrupted run."""
    source = tmp_path / "descents"
    build = ["build-dataset", "--out", source, "--dtm", dtm, "--scans", "4", "--descent-frames", "3"]
    result = invoke(*build, "--descent-altitudes", "120:60", "--resolution", "32", "--sigma", "0.02", "--workers", "1")
    assert result.exit_code == 0, result.output
    fresh = tmp_path / "fresh"
    assert invoke("mosaic", source, "--out", fresh, *MOSAIC_ARGS).exit_code == 0
    out = tmp_path / "m"
    args = ["mosaic", source, "--out", out, *MOSAIC_ARGS]
    proc = hd_process(args, env={"HD_TEST_WRITE_PAUSE": "mosaics-00000.d000002.npz:60"})
    kept = out / ".hd-mosaic-resume"
    wait_for(_partials(kept, ".mosaics-00000.d000002.npz.partial-*"), what="the third descent being kept", proc=proc)
    code, _ = kill_and_check_no_orphans(proc, signal.SIGKILL)
    assert code == -signal.SIGKILL and not (out / "manifest.json").exists()
    result = invoke(*args)
    assert result.exit_code == 0, result.output
    assert "(2 descents kept from the interrupted run)" in result.output
    files = {p.name: p.read_bytes() for p in out.iterdir()}
    assert files == {p.name: p.read_bytes() for p in fresh.iterdir()}
    assert partials(out) == [] and sorted(files) == ["manifest.json", "mosaics-00000.h5"]


def test_descend_killed_mid_run_leaves_nothing_half_written_and_resumes_to_the_same_maps(tmp_path, dtm):
    """hd descend SIGKILLed while it writes the first descent's site track (its frame maps staged): the
    output directory holds no file under a final name (only the hidden staging directory, no
    descend.json); the same command then writes every frame's maps and track with the bytes of an
    uninterrupted run."""
    source, mosaics, run = tmp_path / "source", tmp_path / "mosaics", tmp_path / "run"
    build = ["build-dataset", "--out", source, "--dtm", dtm, "--scans", "4", "--descent-frames", "3"]
    result = invoke(*build, "--descent-altitudes", "120:60", "--resolution", "32", "--sigma", "0.02", "--workers", "1")
    assert result.exit_code == 0, result.output
    assert invoke("mosaic", source, "--out", mosaics, *MOSAIC_ARGS).exit_code == 0
    assert invoke("label", mosaics, "--workers", "1", *MOSAIC_ARGS[2:]).exit_code == 0
    assert invoke("train", mosaics, "--out", run, "--profile", "tiny", "--epochs", "1").exit_code == 0
    fly = ["descend", run, "--data", source, "--descent", "all", "--mc-samples", "2", "--threshold", "nats:1"]
    fresh = tmp_path / "fresh"
    assert invoke(*fly, "--out", fresh).exit_code == 0
    out = tmp_path / "d"
    proc = hd_process([*fly, "--out", out], env={"HD_TEST_WRITE_PAUSE": "descent-00000-track.geojson:60"})
    wait_for(lambda: list(out.glob(".descend.partial-*/.descent-00000-track.geojson.partial-*")), proc=proc)
    code, _ = kill_and_check_no_orphans(proc, signal.SIGKILL)
    assert code == -signal.SIGKILL
    assert [p.name for p in out.iterdir() if not p.name.startswith(".")] == []  # nothing under a final name
    result = invoke(*fly, "--out", out)
    assert result.exit_code == 0, result.output
    maps = {p.name: p.read_bytes() for p in out.iterdir() if p.suffix in (".npz", ".geojson")}
    assert maps == {p.name: p.read_bytes() for p in fresh.iterdir() if p.suffix in (".npz", ".geojson")}
    assert len(maps) == 4 * 4 and (out / "descend.json").is_file() and partials(out) == []
    recorded = json.loads((out / "descend.json").read_text())["descents"]
    assert [d["descent"] for d in recorded] == [
        d["descent"] for d in json.loads((fresh / "descend.json").read_text())["descents"]
    ]
