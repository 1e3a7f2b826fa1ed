"""Helpers of the fault catalogue: a tiny terrain, running ``hd`` in or out of process, process
tracking, tmpfs mounts and disk-full injection (the fixtures are in ``conftest.py``)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result
from scipy import ndimage

from hdcli.cli import main
from lidarsim.shards import read_manifest
from tests.geotiff import write_geotiff

REPO = Path(__file__).resolve().parents[2]
FAULTS = Path(__file__).resolve().parent / "faultinject"
# One small build: 8 scans of a 32 x 32 detector in 4 shards of 2, one noise level.
BUILD_ARGS = ["--scans", "8", "--shard-size", "2", "--resolution", "32", "--sigma", "0.0167", "--seed", "3"]
LABEL_ARGS: list[str] = []


def hills(path: Path, n: int = 300, seed: int = 3, fill_rows: int = 0, fill: float = 0.0) -> Path:
    """Smooth seeded hills with a few rocks, 1 m/px, float32 GeoTIFF; the first ``fill_rows`` rows
    (the north) are set to ``fill``."""
    rng = np.random.default_rng(seed)
    z = ndimage.gaussian_filter(rng.normal(0.0, 1.0, (n, n)), 12)
    z = z / z.std() * 2.0
    rocks = np.zeros((n, n))
    idx = rng.integers(0, n, (30, 2))
    rocks[idx[:, 0], idx[:, 1]] = 1.0
    z += ndimage.gaussian_filter(rocks, 1.5) * 8.0
    z = z.astype(np.float32)
    z[:fill_rows] = fill
    return write_geotiff(path, z)


def invoke(*args: str | os.PathLike[str]) -> Result:
    """Run ``hd ARGS`` in this process."""
    return CliRunner().invoke(main, [str(a) for a in args])


def assert_one_line_error(result: Result, *needles: str) -> str:
    """A refused command: exit status 1 (2 for click's usage errors), no traceback, the last line
    ``Error: ...`` holding every needle."""
    assert result.exit_code in (1, 2), (result.exit_code, result.output, result.exception)
    assert "Traceback" not in result.output, result.output
    assert not isinstance(result.exception, (AssertionError, TypeError, AttributeError, KeyError)), result.exception
    last = result.output.strip().splitlines()[-1]
    assert last.startswith("Error: "), result.output
    for needle in needles:  # "a|b": either
        assert any(n.lower() in last.lower() for n in needle.split("|")), (needle, last)
    return last


def shard_sums(dataset: Path) -> dict[str, str]:
    """path -> sha256 of every file the manifest lists (scan and label shards)."""
    m = read_manifest(dataset)
    entries = m["shards"] + [e for lab in m["labelings"] for e in lab["shards"]]
    return {e["path"]: e["sha256"] for e in entries}


def partials(root: Path) -> list[Path]:
    """Leftovers of interrupted writes anywhere under ``root``."""
    return [p for p in root.rglob("*") if ".partial" in p.name] if root.exists() else []


# ---------------------------------------------------------------------------------------- processes
def hd_process(
    args: Sequence[str | os.PathLike[str]], env: dict[str, str] | None = None, cwd: Path | None = None
) -> subprocess.Popen:
    """Start ``hd ARGS`` as a separate process (own session) with the fault injector loaded."""
    full_env = {
        **os.environ,
        "PYTHONPATH": f"{FAULTS}{os.pathsep}{REPO}",
        "HD_TEST_FAULTS": "1",
        "OMP_NUM_THREADS": "1",
        **(env or {}),
    }
    return subprocess.Popen(
        [sys.executable, "-m", "hdcli", *[str(a) for a in args]],
        env=full_env,
        cwd=cwd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )


def _stat(pid: int) -> tuple[int, str, int] | None:
    """(parent PID, state, start time) of a process, or None when it is gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            fields = fh.read().rsplit(b")", 1)[1].split()
    except OSError:
        return None
    return int(fields[1]), fields[0].decode(), int(fields[19])


def descendants(pid: int) -> dict[int, int]:
    """PID -> start time of every live descendant of ``pid`` (from /proc parent links)."""
    children: dict[int, list[int]] = {}
    starts: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            st = _stat(int(entry))
            if st is not None and st[1] != "Z":
                children.setdefault(st[0], []).append(int(entry))
                starts[int(entry)] = st[2]
    out: dict[int, int] = {}
    todo = list(children.get(pid, []))
    while todo:
        p = todo.pop()
        out[p] = starts[p]
        todo += children.get(p, [])
    return out


def alive(tracked: dict[int, int]) -> list[int]:
    """The tracked processes (PID -> start time) still running (zombies count as dead)."""
    out = []
    for pid, start in tracked.items():
        st = _stat(pid)
        if st is not None and st[1] != "Z" and st[2] == start:
            out.append(pid)
    return out


def wait_for(
    condition: Callable[[], object],
    timeout: float = 60.0,
    what: str = "condition",
    proc: subprocess.Popen | None = None,
) -> object:
    """Poll ``condition`` every 10 ms until it is truthy; fails after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        if proc is not None and proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"the process ended ({proc.returncode}) before {what}:\n{out}\n{err}")
        time.sleep(0.01)
    pytest.fail(f"timed out waiting for {what}")


def kill_and_check_no_orphans(proc: subprocess.Popen, sig: int, workers: int | None = None) -> tuple[int, str]:
    """Send ``sig`` to ``proc`` only; returns (exit status, stderr) after checking that every
    process it had started is gone within 10 s."""
    tracked = descendants(proc.pid)
    if workers is not None:
        assert len(tracked) >= workers, f"expected {workers} workers, found {tracked}"
    os.kill(proc.pid, sig)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail("the command did not stop after the signal")
    deadline = time.monotonic() + 10.0
    while alive(tracked) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = alive(tracked)
    if left:
        for pid in left:
            os.kill(pid, signal.SIGKILL)
        pytest.fail(f"orphan processes left running: {left}")
    return proc.returncode, err


# ---------------------------------------------------------------------------------------- tmpfs
@contextmanager
def tmpfs(path: Path, size: str, options: str = "") -> Iterator[Path]:
    """A tmpfs of ``size`` mounted at ``path`` (skips the test where mounting is not possible)."""
    path.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    opts = f"size={size}" + (f",{options}" if options else "")
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(path)], capture_output=True, text=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({res.stderr.strip() or res.returncode})")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


def remount(path: Path, size: str) -> None:
    res = subprocess.run(["mount", "-o", f"remount,size={size}", str(path)], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr


def inject_enospc(monkeypatch: pytest.MonkeyPatch, pattern: str) -> list[str]:
    """Make hd's writes of files whose final name matches ``pattern`` fail with ENOSPC half-way
    (in this process); returns the list of names that failed."""
    import errno
    import fnmatch

    from hdcore.storage import atomic as storage

    real = storage._write_all
    failed: list[str] = []

    def write_all(fd: int, data: bytes | memoryview) -> None:
        name = os.path.basename(os.readlink(f"/proc/self/fd/{fd}"))
        if name.startswith(".") and ".partial-" in name:
            name = name[1:].rsplit(".partial-", 1)[0]
        if fnmatch.fnmatch(name, pattern):
            view = memoryview(data).cast("B")
            real(fd, view[: len(view) // 2])
            failed.append(name)
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(fd, data)

    monkeypatch.setattr(storage, "_write_all", write_all)
    return failed
