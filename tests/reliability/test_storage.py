"""The storage layer itself (hdcore.storage) and the worker pool's safety nets (lidarsim.parallel)."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import textwrap
import time

import h5py
import numpy as np
import pytest
from reliability_kit import REPO, alive, inject_enospc

from hdcore import storage
from hdcore.storage import (
    DamagedFileError,
    FormatError,
    H5Image,
    LockedError,
    OutputTransaction,
    StorageError,
    atomic_path,
    check_schema,
    confine,
    describe_os_error,
    remove_partials,
    verify_sha256,
    write_bytes_atomic,
    write_json_atomic,
)
from lidarsim.errors import LidarsimError
from lidarsim.parallel import check_scheduler_address


def test_atomic_write_replaces_or_keeps_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / "f.bin"
    write_bytes_atomic(path, b"old")
    inject_enospc(monkeypatch, "f.bin")
    with pytest.raises(StorageError, match=r"f\.bin: no space left on device"):
        write_bytes_atomic(path, b"new content " * 1000)
    assert path.read_bytes() == b"old" and sorted(os.listdir(tmp_path)) == ["f.bin"]
    monkeypatch.undo()
    write_bytes_atomic(path, b"new")
    assert path.read_bytes() == b"new" and sorted(os.listdir(tmp_path)) == ["f.bin"]


def test_an_interrupted_write_leaves_no_temporary_file(tmp_path, monkeypatch):
    def interrupted(fd, data):
        os.write(fd, bytes(data)[:3])
        raise KeyboardInterrupt

    monkeypatch.setattr(storage.atomic, "_write_all", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_json_atomic(tmp_path / "m.json", {"a": 1})
    assert os.listdir(tmp_path) == []


def _write_half_then_fill_the_disk(path):
    with atomic_path(path) as tmp:
        tmp.write_bytes(b"half")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_atomic_path_for_writers_that_need_a_name(tmp_path):
    with atomic_path(tmp_path / "fig.png") as tmp:
        tmp.write_bytes(b"png")
        assert tmp.name.startswith(".fig.png.partial-")
    assert (tmp_path / "fig.png").read_bytes() == b"png"
    with pytest.raises(StorageError, match=r"No space|no space"):
        _write_half_then_fill_the_disk(tmp_path / "g.png")
    assert sorted(os.listdir(tmp_path)) == ["fig.png"]


def _interrupted_while_locked(out, undone):
    with OutputTransaction(out, "dataset", rollback=lambda: undone.append(1)):
        assert storage.lock_holder(out) == os.getpid()
        with pytest.raises(LockedError, match=r"being written by another hd process \(PID \d+\)"):
            OutputTransaction(out, "dataset").__enter__()
        raise KeyboardInterrupt  # SIGINT in the middle of the work


def _disk_full_while_staged(out):
    with OutputTransaction(out, "report", staged=True) as tx:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tx.staging / "report.md"))


def test_an_output_transaction_commits_in_place_or_rolls_back(tmp_path):
    out = tmp_path / "a" / "b"
    undone: list[int] = []
    with pytest.raises(KeyboardInterrupt):
        _interrupted_while_locked(out, undone)
    assert undone == [1] and not (tmp_path / "a").exists()  # the directories it created are gone again
    with OutputTransaction(out, "dataset", check=lambda: "resume", rollback=lambda: undone.append(2)) as tx:
        assert tx.checked == "resume"
        write_json_atomic(out / "manifest.json", {"n": 1})
    assert undone == [1] and sorted(os.listdir(out)) == ["manifest.json"]  # lock released, nothing rolled back
    assert storage.lock_holder(out) is None


def test_a_failed_check_under_the_lock_writes_nothing(tmp_path):
    def refuse() -> None:
        raise StorageError("holds something else")

    with pytest.raises(StorageError, match="holds something else"), OutputTransaction(tmp_path / "x", check=refuse):
        pass
    assert os.listdir(tmp_path) == []


def test_a_staged_output_appears_whole_or_not_at_all(tmp_path):
    out = tmp_path / "report"
    out.mkdir()
    (out / "old.png").write_bytes(b"old")
    (out / "notes.txt").write_text("mine")
    with OutputTransaction(out, "report", staged=True) as tx:
        (tx.staging / "report.md").write_text("# new")
        (tx.staging / "report.json").write_text("{}")
        assert sorted(os.listdir(out)) == [".hd-lock", ".report.partial-" + str(os.getpid()), "notes.txt", "old.png"]
        final = tx.commit(last="report.json", replaces=lambda name: name.endswith((".png", ".md", ".json")))
    assert [p.name for p in final] == ["report.md", "report.json"]  # the marker last
    assert sorted(os.listdir(out)) == ["notes.txt", "report.json", "report.md"]  # old.png replaced, notes kept
    with pytest.raises(StorageError, match=r"report/report\.md: no space left on device"):  # named by its final path
        _disk_full_while_staged(out)
    assert sorted(os.listdir(out)) == ["notes.txt", "report.json", "report.md"]
    with OutputTransaction(out, "report", staged=True) as tx:  # a block that never commits rolls back
        (tx.staging / "report.json").write_text("[]")
    assert (out / "report.json").read_text() == "{}"


def test_hdf5_is_built_in_memory_and_written_once(tmp_path):
    def make(path):
        with H5Image(path) as img:
            img.file.create_dataset(
                "a",
                data=np.arange(100, dtype=np.float32).reshape(10, 10),
                chunks=(1, 10),
                **storage.h5_chunk_kwargs("gzip"),
            )
            assert not path.exists()  # nothing on disk until commit
            return img.commit()

    a, b = make(tmp_path / "a.h5"), make(tmp_path / "b.h5")
    assert a == b == storage.sha256_file(tmp_path / "a.h5")  # deterministic bytes
    with h5py.File(tmp_path / "a.h5") as f:
        assert f["a"].fletcher32 and f["a"][3, 4] == 34
    with H5Image(tmp_path / "c.h5") as img:
        img.file.create_dataset("a", data=[1])
        img.discard()
    assert sorted(os.listdir(tmp_path)) == ["a.h5", "b.h5"]


@pytest.mark.parametrize(
    ("relative", "ok"),
    [
        ("shards/scans-00000.h5", True),
        ("../etc/passwd", False),
        ("/etc/passwd", False),
        ("a/../../b", False),
        ("a/./b", False),
        ("", False),
        ("a//b", False),
        ("link-out/x", False),
        ("link-in/x", True),
        (7, False),
    ],
)
def test_manifest_paths_are_confined_to_the_dataset(tmp_path, relative, ok):
    root = tmp_path / "data"
    (root / "shards").mkdir(parents=True)
    (root / "link-out").symlink_to(tmp_path)
    (root / "link-in").symlink_to(root / "shards")
    if ok:
        assert confine(root, relative) == root / relative
    else:
        with pytest.raises(FormatError):
            confine(root, relative)


def test_verify_sha256(tmp_path):
    p = tmp_path / "x"
    p.write_bytes(b"abc")
    good = storage.sha256_bytes(b"abc")
    verify_sha256(p, good)
    p.write_bytes(b"abd")
    with pytest.raises(DamagedFileError, match="checksum mismatch"):
        verify_sha256(p, good)
    p.unlink()
    with pytest.raises(DamagedFileError, match="missing"):
        verify_sha256(p, good)


def test_schema_versions():
    check_schema("hd.x", "1.7", "hd.x", "1.1", "f")  # minor versions are compatible
    with pytest.raises(FormatError, match=r"version 2\.0 is not supported"):
        check_schema("hd.x", "2.0", "hd.x", "1.1", "f")
    with pytest.raises(FormatError, match=r"schema is 'hd\.y'"):
        check_schema("hd.y", "1.0", "hd.x", "1.1", "f")


def test_remove_partials_and_error_lines(tmp_path):
    (tmp_path / ".a.h5.partial-12").write_bytes(b"x")
    (tmp_path / ".report.partial-13").mkdir()
    (tmp_path / "keep.h5").write_bytes(b"x")
    assert remove_partials(tmp_path) == 2 and os.listdir(tmp_path) == ["keep.h5"]
    assert describe_os_error(OSError(errno.EROFS, "Read-only file system"), "/x") == "/x: Read-only file system"
    assert "free some space" in describe_os_error(OSError(errno.ENOSPC, "No space left on device"), "/x")


@pytest.mark.parametrize(
    ("address", "ok"),
    [
        ("tcp://127.0.0.1:8786", True),
        ("127.0.0.1:8786", True),
        ("tls://host.example:443", True),
        ("inproc://x", True),
        ("garbage", False),
        ("tcp://host", False),
        ("tcp://host:0", False),
        ("tcp://host:abc", False),
        ("http://host:80", False),
        ("", False),
        ("tcp://:8786", False),
    ],
)
def test_scheduler_addresses(address, ok):
    if ok:
        assert check_scheduler_address(address) == address
    else:
        with pytest.raises(LidarsimError, match="scheduler"):
            check_scheduler_address(address)


@pytest.mark.parametrize("prctl", [True, False], ids=["pdeathsig", "watchdog-only"])
def test_a_worker_dies_with_its_parent(tmp_path, prctl):
    """A worker whose parent is SIGKILLed exits: through PR_SET_PDEATHSIG, or through the watchdog
    thread alone where that is not available."""
    script = textwrap.dedent(f"""
        import multiprocessing as mp, os, sys, time
        sys.path.insert(0, {str(REPO)!r})

        def worker(parent):
            if not {prctl}:
                sys.platform = "not-linux"  # no prctl: the watchdog must do it
            from lidarsim.parallel import die_with_parent
            die_with_parent(parent)
            time.sleep(60)

        if __name__ == "__main__":
            p = mp.get_context("spawn").Process(target=worker, args=(os.getpid(),))
            p.start()
            print(p.pid, flush=True)
            time.sleep(60)
    """)
    (tmp_path / "parent.py").write_text(script)
    parent = subprocess.Popen([sys.executable, str(tmp_path / "parent.py")], stdout=subprocess.PIPE, text=True)
    assert parent.stdout is not None
    child = int(parent.stdout.readline())
    time.sleep(1.0)  # the child has called die_with_parent
    with open(f"/proc/{child}/stat", "rb") as fh:
        start = int(fh.read().rsplit(b")", 1)[1].split()[19])
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    deadline = time.monotonic() + 5
    while alive({child: start}) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = alive({child: start})
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    assert not left


def test_checksums_published_for_an_older_shard_schema_are_named_as_such(labelled):
    """`hd verify --recipe` against checksums published before shard schema 1.1 says why they differ."""
    import json

    from lidarsim.recipe import check_against_checksums
    from lidarsim.shards import read_manifest

    published = json.loads((REPO / "datasets" / "mars-paper" / "checksums.json").read_text())
    manifest = read_manifest(labelled)
    problems = check_against_checksums({**manifest, "config_sha256": published["config_sha256"]}, published)
    if published.get("shard_schema_version") == manifest["shards"][0]["schema_version"]:
        pytest.skip("the published checksums are of the current shard schema")
    assert len(problems) == 1 and "published for scan shards of schema version 1.0" in problems[0]


# ---------------------------------------------------------------------------------------- not regular files
@pytest.mark.parametrize("kind", ["fifo", "directory", "device", "socket"])
def test_side_files_that_are_not_regular_files_are_refused_at_once(tmp_path, no_hang, kind):
    import socket

    path = tmp_path / "config.json"
    keep = None
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "directory":
        path.mkdir()
    elif kind == "device":
        path.symlink_to("/dev/zero")
    else:
        keep = socket.socket(socket.AF_UNIX)
        keep.bind(str(path))
    expected = {"fifo": "a FIFO", "directory": "a directory", "device": "a character device", "socket": "a socket"}
    try:
        for read in (storage.read_regular_bytes, storage.read_regular_text, storage.read_json):
            with pytest.raises(FormatError, match=f"is {expected[kind]}, not a regular file"):
                read(path)
        with pytest.raises(FormatError, match="not a regular file"):
            storage.check_regular_file(path)
    finally:
        if keep is not None:
            keep.close()


def test_side_files_are_read_whole_up_to_their_bound(tmp_path):
    path = tmp_path / "f.json"
    path.write_text('{"a": 1}')
    assert storage.read_json(path) == {"a": 1}
    assert storage.read_regular_bytes(path, max_bytes=8) == b'{"a": 1}'
    with pytest.raises(FormatError, match="8 bytes, more than the 7"):
        storage.read_regular_bytes(path, max_bytes=7)
    with pytest.raises(StorageError, match=r"f\.missing"):
        storage.read_regular_bytes(tmp_path / "f.missing")
    path.write_text('{"n": 1' + "0" * 5000 + "}")  # past Python's 4300-digit limit: ValueError, not JSON's
    with pytest.raises(DamagedFileError, match="unreadable"):
        storage.read_json(path)
    path.write_bytes(b"\xff\xfe")
    with pytest.raises(DamagedFileError, match="not UTF-8"):
        storage.read_regular_text(path)
