"""Helpers of the fuzzing campaign (class I): mutations of hd's files, a forked runner and the invariant.

Every example mutates a private copy of a file hd reads (a manifest, a scan or label shard, a
checkpoint, a recipe, a GeoTIFF) and runs one ``hd`` command on it in a forked child process, so
that a crash of the HDF5 library (a signal) or a hang (past a bound in seconds) is seen and does
not take the test session with it. The invariant (:func:`check`): exit status 0, or a non-zero
status whose last line is one ``Error: ...`` line; never a traceback, a signal, a hang or a
``.partial-`` file left behind; and exit 0 only where the mutation leaves a correct input (a
mutation that ``must_fail`` - a damaged file, a checksum that no longer matches - accepted with
exit 0 is a silently wrong result; one that ``must_pass`` - a correct option value - refused is a
wrong refusal). Targets that call a function in process instead of a command log through
:func:`report`.

Sizes: ``HD_FUZZ_CAMPAIGN=long`` selects the long campaign's numbers of examples,
``HD_FUZZ_EXAMPLES=target=N,...`` sets some targets' numbers, ``HD_FUZZ_SCALE`` (default 1)
multiplies them all, ``HD_FUZZ_SEED=N`` draws another deterministic sequence. ``HD_FUZZ_LOG`` names a
JSON-lines file that receives one line per example (target, mutation, exit status, seconds,
verdict; ``python tests/reliability/fuzz_kit.py LOG`` summarises it); with ``HD_FUZZ_COLLECT=1`` a
violation is logged and the campaign goes on instead of failing the test (the long run,
docs/reliability.md).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import resource
import select
import signal
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from hypothesis import HealthCheck, seed, settings
from hypothesis import strategies as st

from lidarsim.shards import sha256_file

# ---------------------------------------------------------------------------------------- sizes
LONG_CAMPAIGN = os.environ.get("HD_FUZZ_CAMPAIGN", "") == "long"
SCALE = float(os.environ.get("HD_FUZZ_SCALE", "1"))
COLLECT = os.environ.get("HD_FUZZ_COLLECT", "") == "1"
LOG = os.environ.get("HD_FUZZ_LOG", "")
# Address space of one forked command, bytes: an input that makes hd allocate more fails the example
# with an "out of memory" line instead of taking the machine's memory.
MEMORY_BOUND_BYTES = 8 << 30


SEED = os.environ.get("HD_FUZZ_SEED", "")


def fuzz_settings(examples: int) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Deterministic hypothesis settings: ``examples`` x ``HD_FUZZ_SCALE`` examples, no deadline (the
    forked runner bounds each example), no example database. The draws follow from the test's source;
    ``HD_FUZZ_SEED=N`` draws another deterministic sequence (a second campaign without repeats)."""
    chosen = settings(
        max_examples=max(1, round(examples * SCALE)),
        deadline=None,
        derandomize=not SEED,
        database=None,
        suppress_health_check=list(HealthCheck),
        print_blob=False,
    )

    def apply(test: Callable[..., Any]) -> Callable[..., Any]:
        return chosen(seed(int(SEED))(test) if SEED else test)

    return apply


# ---------------------------------------------------------------------------------------- runner
@dataclass
class Outcome:
    """What one forked ``hd`` command did."""

    exit_code: int | None  # None when it died by a signal or was killed after the time bound
    output: str = ""
    error: str = ""  # the traceback of an exception that escaped the command, else ""
    signal: int | None = None
    timed_out: bool = False
    seconds: float = 0.0


def run_forked(args: list[Any], timeout_s: float) -> Outcome:
    """Run ``hd ARGS`` (in process, through click's runner) in a forked child; killed after ``timeout_s`` seconds."""
    read_fd, write_fd = os.pipe()
    start = time.monotonic()
    pid = os.fork()
    if pid == 0:  # the child: run, report as JSON on the pipe, leave without running the parent's exit handlers
        code = 0
        try:
            # Imported here (the test process has it already): the summary (``__main__``) runs without the tests' path.
            from reliability_kit import invoke

            os.close(read_fd)
            os.setpgid(0, 0)
            resource.setrlimit(resource.RLIMIT_AS, (MEMORY_BOUND_BYTES, MEMORY_BOUND_BYTES))
            result = invoke(*args)
            error = ""
            if result.exception is not None and not isinstance(result.exception, SystemExit):
                error = "".join(traceback.format_exception(result.exception))
            payload = json.dumps({"exit_code": result.exit_code, "output": result.output[-20000:], "error": error})
            with os.fdopen(write_fd, "w") as pipe:
                pipe.write(payload)
        except BaseException:  # noqa: BLE001 - the child must never return into pytest
            code = 70
        finally:
            os._exit(code)
    os.close(write_fd)
    chunks: list[bytes] = []
    timed_out = False
    with os.fdopen(read_fd, "rb") as pipe:
        while True:
            left = timeout_s - (time.monotonic() - start)
            if left <= 0:
                timed_out = True
                break
            ready, _, _ = select.select([pipe], [], [], left)
            if ready:
                block = os.read(pipe.fileno(), 1 << 16)
                if not block:
                    break
                chunks.append(block)
    if timed_out:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(pid, signal.SIGKILL)
    _, status = os.waitpid(pid, 0)
    seconds = time.monotonic() - start
    if timed_out:
        return Outcome(None, timed_out=True, seconds=seconds)
    if os.WIFSIGNALED(status):
        return Outcome(None, signal=os.WTERMSIG(status), seconds=seconds)
    try:
        data = json.loads(b"".join(chunks).decode())
    except ValueError:
        return Outcome(
            None, error=f"the child reported nothing (exit status {os.WEXITSTATUS(status)})", seconds=seconds
        )
    return Outcome(data["exit_code"], data["output"], data["error"], seconds=seconds)


class Hang(Exception):
    """An in-process call ran past its bound (:func:`bounded`)."""


@contextlib.contextmanager
def bounded(seconds: float) -> Iterator[None]:
    """Raise :class:`Hang` in the main thread after ``seconds``: the bound of a target that runs in process
    (SIGALRM interrupts a blocking open or read, of a FIFO say)."""

    def expire(signum: int, frame: Any) -> None:
        raise Hang(f"still running after {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


# ---------------------------------------------------------------------------------------- invariant
def terminal_lines(text: str) -> list[str]:
    """The non-blank lines a terminal shows of ``text``: broken at \\n and \\r only (str.splitlines also breaks
    at \\x1c-\\x1e, \\x85 and \\u2028, which a terminal prints inside a line)."""
    return [line for line in re.split(r"\r\n?|\n", text) if line.strip()]


def violation(outcome: Outcome, must_fail: bool, roots: list[Path], must_pass: bool = False) -> str | None:
    """The broken part of the invariant, or None when the outcome is a correct result or a one-line error
    (``must_pass``: an input the command must accept, where a one-line error is a wrong refusal)."""
    if outcome.timed_out:
        return f"hang: still running after {outcome.seconds:.0f} s"
    if outcome.signal is not None:
        return f"crash: killed by signal {signal.Signals(outcome.signal).name}"
    if outcome.error:
        return "traceback: " + outcome.error.strip().splitlines()[-1]
    if "Traceback (most recent call last)" in outcome.output:
        return "traceback in the output"
    left = [str(p) for root in roots if root.exists() for p in root.rglob("*") if ".partial" in p.name]
    if left:
        return f"partial files left: {left[:3]}"
    if outcome.exit_code == 0:
        return "silently wrong: exit 0 on a damaged input" if must_fail else None
    lines = terminal_lines(outcome.output)
    if not lines or not lines[-1].startswith("Error: "):
        return f"exit {outcome.exit_code} without a one-line error: {lines[-1:]!r}"
    if must_pass:
        return "refused a correct input: " + lines[-1][:200]
    return None


def check(
    target: str,
    args: list[Any],
    mutation: Any,
    must_fail: bool = False,
    timeout_s: float = 120.0,
    roots: tuple[Path, ...] = (),
    accept: Callable[[Outcome], str | None] | None = None,
    must_pass: bool = False,
) -> Outcome:
    """Run ``args`` forked and hold the invariant (``accept`` adds a target's own check of an exit 0;
    ``must_pass``: the mutation leaves a correct input, which must not be refused)."""
    outcome = run_forked(args, timeout_s)
    problem = violation(outcome, must_fail, list(roots), must_pass)
    if problem is None and outcome.exit_code == 0 and accept is not None:
        problem = accept(outcome)
    report(target, mutation, problem, outcome)
    return outcome


def report(target: str, mutation: Any, problem: str | None, outcome: Outcome) -> None:
    """Log one example (``HD_FUZZ_LOG``) and fail on its violation ``problem`` (unless ``HD_FUZZ_COLLECT``).
    Targets that call a function in process (no command, no fork) report through it too."""
    last = terminal_lines(outcome.output)[-1:]
    if LOG:
        with open(LOG, "a") as fh:
            record = {
                "target": target,
                "mutation": repr(mutation)[:2000],
                "exit_code": outcome.exit_code,
                "seconds": round(outcome.seconds, 3),
                "last_line": last[0][:500] if last else "",
                "violation": problem,
                "error": outcome.error[-4000:],
            }
            fh.write(json.dumps(record) + "\n")
    if problem is not None and not COLLECT:
        raise AssertionError(f"{target}: {problem}\nmutation: {mutation!r}\n{outcome.output[-3000:]}\n{outcome.error}")


# ---------------------------------------------------------------------------------------- values
NASTY_STRINGS = ["", " ", "../x", "/etc/passwd", "2.0", "1.0", "hd.labels", "x" * 300, "\x00", "nan", "é€", "null"]
NASTY_INTS = [0, -1, 1, 2, 7, 255, 10**6, 10**12, 2**31, 2**63 - 1, -(2**63), 10**30]
NASTY_FLOATS = [0.0, -0.0, -1.0, 0.5, 1e-300, 1e300, math.nan, math.inf, -math.inf]


def scalars(big_ints: bool = True) -> st.SearchStrategy[Any]:
    """Edge-case JSON scalars: None, booleans, huge and negative integers, NaN and infinities, odd strings."""
    ints = NASTY_INTS if big_ints else [v for v in NASTY_INTS if abs(v) < 2**63]
    return st.one_of(
        st.none(),
        st.booleans(),
        st.sampled_from(ints),
        st.integers(-1000, 1000),
        st.sampled_from(NASTY_FLOATS),
        st.floats(allow_nan=True, allow_infinity=True),
        st.sampled_from(NASTY_STRINGS),
        st.text(max_size=12),
    )


def json_values() -> st.SearchStrategy[Any]:
    """Any JSON value, small, with the edge-case scalars."""
    return st.recursive(
        scalars(),
        lambda inner: st.one_of(
            st.lists(inner, max_size=3),
            st.dictionaries(st.sampled_from(["a", "path", "n_scans", ""]), inner, max_size=3),
        ),
        max_leaves=6,
    )


def tree_paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every path (keys and indices) to a value below ``node`` (dicts and lists), in document order."""
    out: list[tuple[Any, ...]] = []
    items: list[tuple[Any, Any]] = []
    if isinstance(node, dict):
        items = list(node.items())
    elif isinstance(node, list):
        items = list(enumerate(node))
    for key, value in items:
        out.append((*prefix, key))
        out += tree_paths(value, (*prefix, key))
    return out


def get_at(node: Any, path: tuple[Any, ...]) -> Any:
    for key in path:
        node = node[key]
    return node


def same(a: Any, b: Any) -> bool:
    """Equal values of the same JSON type (1 and 1.0 and True differ; NaN equals NaN)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, float) and math.isnan(a):
        return math.isnan(b)
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b)


@dataclass
class TreeEdit:
    """One edit of a JSON-like tree: ``delete`` the value at ``path``, or ``set`` it to ``value``."""

    action: str
    path: tuple[Any, ...]
    value: Any = None
    changed: bool = True  # False when ``set`` wrote the value that was there


def draw_tree_edits(
    data: st.DataObject,
    tree: Any,
    values: st.SearchStrategy[Any],
    max_edits: int = 3,
    skip: Callable[..., bool] | None = None,
) -> list[TreeEdit]:
    """Draw and apply (in place) 1..``max_edits`` edits of ``tree``: deletions, new values and numbers
    nudged (+-1, x 10^9, negated)."""
    edits: list[TreeEdit] = []
    for _ in range(data.draw(st.integers(1, max_edits), label="edits")):
        paths = [p for p in tree_paths(tree) if skip is None or not skip(p)]
        if not paths:
            break
        path = data.draw(st.sampled_from(paths), label="path")
        parent, key = get_at(tree, path[:-1]), path[-1]
        old = parent[key]
        action = data.draw(st.sampled_from(["delete", "set", "set", "nudge"]), label="action")
        if action == "delete":
            del parent[key]
            edits.append(TreeEdit("delete", path))
            continue
        if action == "nudge" and isinstance(old, (int, float)) and not isinstance(old, bool):
            how = data.draw(st.sampled_from(["+1", "-1", "*1e9", "neg"]), label="nudge")
            new: Any = {"+1": old + 1, "-1": old - 1, "*1e9": old * 10**9, "neg": -old}[how]
        else:
            new = data.draw(values, label="value")
        parent[key] = new
        edits.append(TreeEdit("set", path, new, changed=not same(old, new)))
    return edits


@dataclass
class ByteEdit:
    """Raw damage to a file: ``flip`` bytes, ``truncate``, ``append`` junk or ``zero`` a range
    (positions as fractions of the size)."""

    action: str
    at: list[float] = field(default_factory=list)
    size: int = 1


def byte_edits() -> st.SearchStrategy[ByteEdit]:
    fractions = st.floats(0.0, 1.0, exclude_max=True)
    return st.one_of(
        st.builds(ByteEdit, st.just("flip"), st.lists(fractions, min_size=1, max_size=8)),
        st.builds(ByteEdit, st.just("flip"), st.lists(st.floats(0.0, 0.01), min_size=1, max_size=4)),  # the header
        st.builds(ByteEdit, st.just("truncate"), st.lists(fractions, min_size=1, max_size=1)),
        st.builds(ByteEdit, st.just("append"), st.just([]), st.integers(1, 4096)),
        st.builds(ByteEdit, st.just("zero"), st.lists(fractions, min_size=1, max_size=1), st.integers(1, 4096)),
    )


def apply_bytes(path: Path, edit: ByteEdit) -> bool:
    """Damage ``path``; returns whether its bytes changed."""
    data = bytearray(path.read_bytes())
    before = bytes(data)
    n = len(data)
    if edit.action == "flip" and n:
        for f in edit.at:
            data[int(f * n)] ^= 0xFF
    elif edit.action == "truncate":
        del data[int(edit.at[0] * n) :]
    elif edit.action == "append":
        data += bytes((7 * k + 1) % 256 for k in range(edit.size))
    elif edit.action == "zero" and n:
        start = int(edit.at[0] * n)
        data[start : start + edit.size] = bytes(len(data[start : start + edit.size]))
    path.write_bytes(bytes(data))
    return bytes(data) != before


# ---------------------------------------------------------------------------------------- HDF5
@dataclass
class H5Edit:
    """A structural edit of an HDF5 shard: an attribute (file or dataset), a dataset, or a stored chunk."""

    kind: str  # attr-delete, attr-set, ds-delete, ds-dtype, ds-shape, ds-values, chunk-flip
    target: str  # attribute name ("dataset/attr" for a dataset's), or a dataset name
    value: Any = None


H5_DTYPES = ["float16", "float64", "int8", "uint8", "int64", "bool", "complex64"]
H5_SHAPES = ["drop-row", "add-row", "flatten", "empty", "scalar", "drop-axis", "grow-last"]
H5_VALUES = [math.nan, math.inf, -math.inf, 1e30, -1e30, 0.0, 7.0, 255.0, -1.0]


def h5_members(path: Path) -> tuple[list[str], list[str]]:
    """(attribute names, file's and datasets', as ``name`` / ``dataset/name``; dataset names) of a shard."""
    attrs: list[str] = []
    datasets: list[str] = []
    with h5py.File(path, "r") as f:
        attrs += sorted(f.attrs)
        for name in sorted(f):
            if isinstance(f[name], h5py.Dataset):
                datasets.append(name)
                attrs += [f"{name}/{a}" for a in sorted(f[name].attrs)]
    return attrs, datasets


def draw_h5_edit(data: st.DataObject, path: Path) -> H5Edit:
    attrs, datasets = h5_members(path)
    kind = data.draw(
        st.sampled_from(
            ["attr-delete", "attr-set", "attr-set", "ds-delete", "ds-dtype", "ds-shape", "ds-values", "chunk-flip"]
        ),
        label="h5 kind",
    )
    if kind.startswith("attr"):
        name = data.draw(st.sampled_from(attrs), label="attribute")
        value = None
        if kind == "attr-set":
            value = data.draw(
                st.one_of(
                    scalars(big_ints=False).filter(lambda v: v is not None),
                    st.sampled_from(["1.1", "2.0", "1.9", "hd.lidar-scans", "hd.labels"]),
                    st.lists(st.sampled_from(NASTY_FLOATS), max_size=4),
                    st.just(b"\xff\xfe"),
                ),
                label="attribute value",
            )
        return H5Edit(kind, name, value)
    name = data.draw(st.sampled_from(datasets), label="dataset")
    value = {
        "ds-dtype": st.sampled_from(H5_DTYPES),
        "ds-shape": st.sampled_from(H5_SHAPES),
        "ds-values": st.sampled_from(H5_VALUES),
        "chunk-flip": st.integers(0, 64),
    }.get(kind, st.none())
    return H5Edit(kind, name, data.draw(value, label="how"))


def _reshaped(arr: np.ndarray, how: str) -> np.ndarray:
    if how == "drop-row":
        return arr[:-1]
    if how == "add-row":
        return np.concatenate([arr, arr[-1:]]) if arr.ndim else arr
    if how == "flatten":
        return arr.reshape(-1)
    if how == "empty":
        return arr[:0]
    if how == "scalar":
        return np.asarray(arr.reshape(-1)[0] if arr.size else 0)
    if how == "drop-axis":
        return arr[..., 0] if arr.ndim > 1 else arr
    return np.concatenate([arr, arr[..., -1:]], axis=-1) if arr.ndim else arr  # grow-last


def apply_h5(path: Path, edit: H5Edit) -> None:
    """Apply ``edit`` to the HDF5 file at ``path`` (rewritten datasets lose their chunking, like 1.0 shards)."""
    if edit.kind == "chunk-flip":
        with h5py.File(path, "r") as f:
            ds = f[edit.target]
            n = ds.id.get_num_chunks() if ds.chunks else 0
            info = ds.id.get_chunk_info(edit.value % n) if n else None
        if info is not None and info.size:
            with open(path, "r+b") as fh:
                fh.seek(info.byte_offset + info.size // 2)
                b = fh.read(1)
                fh.seek(info.byte_offset + info.size // 2)
                fh.write(bytes([b[0] ^ 0xFF]))
        return
    with h5py.File(path, "r+") as f:
        if edit.kind.startswith("attr"):
            owner, _, name = edit.target.rpartition("/")
            obj = f[owner] if owner else f
            if edit.kind == "attr-delete":
                del obj.attrs[name]
            elif isinstance(edit.value, str) and "\x00" in edit.value:  # HDF5 strings hold no NUL: raw bytes
                obj.attrs[name] = np.void(edit.value.encode())
            else:
                obj.attrs[name] = np.void(edit.value) if isinstance(edit.value, bytes) else edit.value
            return
        if edit.kind == "ds-delete":
            del f[edit.target]
            return
        old = f[edit.target]
        arr, attrs = old[()], dict(old.attrs)
        if edit.kind == "ds-dtype":
            arr = arr.astype(edit.value)
        elif edit.kind == "ds-shape":
            arr = _reshaped(arr, edit.value)
        elif arr.dtype.kind in "biuf":  # ds-values: every other element
            flat = arr.reshape(-1)
            fill = edit.value if arr.dtype.kind == "f" or math.isfinite(edit.value) else 0
            with np.errstate(invalid="ignore", over="ignore"):
                flat[::2] = np.asarray(fill).astype(arr.dtype)
        del f[edit.target]
        new = f.create_dataset(edit.target, data=arr)
        for k, v in attrs.items():
            new.attrs[k] = v


def reseal(dataset: Path) -> None:
    """Record every listed file's current sha256 in the manifest (only the read-time checks remain)."""
    path = dataset / "manifest.json"
    m = json.loads(path.read_text())
    for e in m["shards"] + [e for lab in m["labelings"] for e in lab["shards"]]:
        if (dataset / e["path"]).is_file():
            e["sha256"] = sha256_file(dataset / e["path"])
            e["size_bytes"] = (dataset / e["path"]).stat().st_size
    path.write_text(json.dumps(m, indent=1))


# ---------------------------------------------------------------------------------------- the log
def summarise(log: Path) -> str:
    """A table of a campaign's log: examples, exit-0 results, one-line errors, violations and mean
    seconds per target, then each distinct violation once with its count and first mutation."""
    rows: dict[str, list[dict[str, Any]]] = {}
    for line in log.read_text().splitlines():
        record = json.loads(line)
        rows.setdefault(record["target"], []).append(record)
    out = [f"{'target':20} {'examples':>8} {'exit 0':>7} {'errors':>7} {'violations':>10} {'mean s':>7}"]
    seen: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for target, records in rows.items():
        ok = sum(1 for r in records if r["exit_code"] == 0 and not r["violation"])
        bad = [r for r in records if r["violation"]]
        mean = sum(r["seconds"] for r in records) / len(records)
        out.append(
            f"{target:20} {len(records):8d} {ok:7d} {len(records) - ok - len(bad):7d} {len(bad):10d} {mean:7.2f}"
        )
        for r in bad:
            seen.setdefault((target, r["violation"][:120]), []).append(r)
    total = sum(len(r) for r in rows.values())
    out.append(f"{'total':20} {total:8d}")
    for (target, what), records in seen.items():
        out.append(f"{len(records):5d} x {target}: {what}\n        first: {records[0]['mutation'][:300]}")
    return "\n".join(out)


if __name__ == "__main__":  # python tests/reliability/fuzz_kit.py LOG.jsonl
    import sys

    print(summarise(Path(sys.argv[1])))
