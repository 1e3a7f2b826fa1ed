"""Class B: one writer per dataset (and per run, per report); readers are never blocked.

A second writer fails at once with one line naming the first one's PID and touches nothing. The
lock is an ``flock`` on ``DIR/.hd-lock``: separate opens conflict even inside one process, so
most cases hold the lock in the test process and run the command in it too.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time

import pytest
from reliability_kit import (
    BUILD_ARGS,
    REPO,
    assert_one_line_error,
    hd_process,
    invoke,
    partials,
    shard_sums,
    wait_for,
)

from hdcore.storage import LOCK_NAME, WriterLock, lock_holder


def test_two_builds_on_one_directory(tmp_path, dtm, reference):
    out = tmp_path / "data"
    release = tmp_path / "release"
    first = hd_process(
        ["build-dataset", "--out", out, "--dtm", dtm, "--workers", "2", *BUILD_ARGS],
        env={"HD_TEST_WRITE_PAUSE": "scans-00001.h5:60", "HD_TEST_RELEASE": str(release)},
    )
    wait_for(
        lambda: list((out / "shards").glob(".scans-00001.h5.partial-*")),
        what="the first build's partial shard",
        proc=first,
    )
    held = sorted(p.name for p in (out / "shards").iterdir() if p.name.startswith((".scans-00001", "scans-")))
    for extra in ([], ["--overwrite"]):
        second = invoke("build-dataset", "--out", out, "--dtm", dtm, "--workers", "1", *BUILD_ARGS, *extra)
        assert_one_line_error(second, "being written by another hd process", f"PID {first.pid}")
        assert set(held) <= {p.name for p in (out / "shards").iterdir()}  # nothing of the first build was removed
    release.touch()
    _, err = first.communicate(timeout=120)
    assert first.returncode == 0, err
    assert shard_sums(out) == shard_sums(reference) and partials(out) == []


@pytest.mark.parametrize("command", ["build", "build-overwrite", "label", "label-other-lander"])
def test_a_second_writer_of_a_dataset_is_refused(tmp_path, labelled, dtm, command):
    data = tmp_path / "data"
    shutil.copytree(labelled, data)
    before = {p: p.read_bytes() for p in data.rglob("*") if p.is_file()}
    args = {
        "build": ["build-dataset", "--out", data, "--dtm", dtm, *BUILD_ARGS],
        "build-overwrite": ["build-dataset", "--out", data, "--dtm", dtm, "--overwrite", *BUILD_ARGS],
        "label": ["label", data, "--workers", "1"],
        "label-other-lander": ["label", data, "--workers", "1", "--max-slope-deg", "8"],
    }[command]
    with WriterLock(data):
        result = invoke(*args)
    if command == "build":  # the same complete dataset: nothing to do, said before the lock is even needed
        assert result.exit_code == 0 and "already holds this dataset" in result.output, result.output
    else:
        assert_one_line_error(result, "being written by another hd process", f"PID {os.getpid()}")
    assert {p: p.read_bytes() for p in data.rglob("*") if p.is_file()} == before


def test_a_second_training_of_one_run_and_a_second_report_are_refused(tmp_path, labelled, trained):
    run = tmp_path / "run"
    shutil.copytree(trained, run)
    with WriterLock(run):
        result = invoke("train", labelled, "--out", run, "--profile", "tiny", "--epochs", "2", "--resume")
    assert_one_line_error(result, "being written by another hd process", f"PID {os.getpid()}")
    report = tmp_path / "report"
    report.mkdir()
    with WriterLock(report):
        result = invoke("eval", run, "--data", labelled, "--out", report, "--mc-samples", "2")
    assert_one_line_error(result, "being written by another hd process", f"PID {os.getpid()}")
    assert sorted(p.name for p in report.iterdir()) == []


def test_readers_are_never_blocked_by_a_writer(data_copy):
    with WriterLock(data_copy):
        verify = invoke("verify", data_copy)
        assert verify.exit_code == 0, verify.output
        inspect = invoke("inspect", data_copy)
        assert inspect.exit_code == 0, inspect.output
        assert f"another hd process (PID {os.getpid()}) is writing this dataset now" in inspect.output
        assert lock_holder(data_copy) == os.getpid()
    assert lock_holder(data_copy) is None and not (data_copy / LOCK_NAME).exists()


def test_the_lock_dies_with_its_holder(tmp_path):
    """SIGKILL of the holder frees the lock at once; a stale lock file with a dead PID blocks nobody."""
    d = tmp_path / "d"
    d.mkdir()
    code = (
        "import sys, time; from hdcore.storage import WriterLock; "
        f"WriterLock({str(d)!r}).acquire(); print('held', flush=True); time.sleep(60)"
    )
    holder = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(REPO)}
    )
    assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
    with pytest.raises(Exception, match=f"PID {holder.pid}"):
        WriterLock(d).acquire()
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    assert (d / LOCK_NAME).exists() and lock_holder(d) is None  # stale file, dead holder
    with WriterLock(d):
        assert lock_holder(d) == os.getpid()


def test_a_stale_lock_naming_a_live_unrelated_pid_is_not_a_writer(data_copy):
    """A lock file left by a killed writer whose PID now belongs to another live process (here PID 1)."""
    from lidarsim.inspect import describe_dataset

    (data_copy / LOCK_NAME).write_text("1\n")
    assert lock_holder(data_copy) is None
    assert "is writing this dataset" not in describe_dataset(data_copy)
    with WriterLock(data_copy):  # and a real writer still shows
        assert lock_holder(data_copy) == os.getpid()
        assert f"PID {os.getpid()}) is writing this dataset" in describe_dataset(data_copy)


def test_a_forked_child_does_not_keep_the_lock(tmp_path):
    """DataLoader workers are forked: they must not hold the lock after their parent dies."""
    d = tmp_path / "d"
    d.mkdir()
    lock = WriterLock(d).acquire()
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child outlives the lock holder's release below
        os.close(r)
        os.write(w, b"x")
        time.sleep(3)
        os._exit(0)
    os.close(w)
    os.read(r, 1)
    lock.release()  # as if the parent had died: the child still runs
    try:
        with WriterLock(d):
            pass
    finally:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
