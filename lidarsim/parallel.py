"""Running independent shard tasks: in this process, on local worker processes, or on a Dask cluster.

The local pool gives every worker one contiguous, balanced group of tasks (consecutive shards
cover neighbouring terrain, so a worker reuses what it cached for the previous shard, such as a
tile's ray-casting BVH); each worker reports task by task through its own pipe so progress bars
move smoothly. ``--scheduler ADDRESS`` sends the same tasks to ``dask.distributed``.

Workers never outlive the command (docs/reliability.md):

* each worker asks the kernel for SIGKILL when its parent dies (Linux ``PR_SET_PDEATHSIG``), and a
  watchdog thread also exits it when its parent process changes (any POSIX system);
* workers ignore SIGINT (Ctrl-C reaches the whole process group): the parent decides. When the
  parent stops early (Ctrl-C, SIGTERM, a failed task, a dead worker) it kills the remaining workers
  and waits for them before the exception propagates, so the caller can remove partial files
  knowing that nobody writes any more.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import pickle
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Generator, Iterator, Sequence
from multiprocessing import get_context
from multiprocessing.connection import Connection, wait
from typing import Any, TypeVar, cast

from hdcore.bounds import parse_integer
from hdcore.errors import WorkerError
from lidarsim.errors import LidarsimError

T = TypeVar("T")
R = TypeVar("R")

# Linux prctl option: signal delivered to this process when its parent dies.
_PR_SET_PDEATHSIG = 1
# Seconds between two checks of the parent by a worker's watchdog thread.
_WATCHDOG_PERIOD_S = 0.5
# Seconds the parent waits for killed workers to exit.
_JOIN_TIMEOUT_S = 10.0


class RemoteTraceback(Exception):
    """The traceback of a worker's exception, attached as ``__cause__``."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


def balanced_groups(n_tasks: int, n_groups: int) -> list[range]:
    """Split ``range(n_tasks)`` into ``n_groups`` contiguous ranges whose sizes differ by at most one."""
    n_groups = max(1, min(n_groups, n_tasks))
    base, extra = divmod(n_tasks, n_groups)
    groups, start = [], 0
    for g in range(n_groups):
        size = base + (1 if g < extra else 0)
        groups.append(range(start, start + size))
        start += size
    return groups


# ------------------------------------------------------------------------------------ worker side
def _watch_parent(parent_pid: int) -> None:
    while True:
        time.sleep(_WATCHDOG_PERIOD_S)
        if os.getppid() != parent_pid:
            os._exit(1)


def die_with_parent(parent_pid: int) -> None:
    """Make this process exit when ``parent_pid`` (its parent) dies, SIGKILL of the parent included."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(Exception):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    if os.getppid() != parent_pid:  # the parent died before the request above
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid,), name="hd-parent-watchdog", daemon=True).start()


_FORK_HOOK_INSTALLED = False


def _kill_me_with_parent() -> None:
    with contextlib.suppress(Exception):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)


def forked_children_die_with_parent() -> None:
    """From now on, every child this process forks (e.g. PyTorch DataLoader workers) is killed by
    the kernel when its parent dies (Linux; elsewhere a no-op). Used by the ``hd`` command."""
    global _FORK_HOOK_INSTALLED
    if not _FORK_HOOK_INSTALLED and sys.platform.startswith("linux") and hasattr(os, "register_at_fork"):
        os.register_at_fork(after_in_child=_kill_me_with_parent)
        _FORK_HOOK_INSTALLED = True


def _portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a WorkerError with its text."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 - any pickling failure
        return WorkerError(f"{type(exc).__name__}: {exc}")


def _worker_main(func: Callable[[Any], Any], indexed: list[tuple[int, Any]], conn: Connection, parent_pid: int) -> None:
    die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        for index, task in indexed:
            try:
                result = func(task)
            except BaseException as exc:  # noqa: BLE001 - reported to the parent, which decides
                conn.send(("error", index, _portable(exc), traceback.format_exc()))
                return
            conn.send(("ok", index, result, None))
        conn.send(("done", None, None, None))
    finally:
        conn.close()


# ------------------------------------------------------------------------------------ parent side
def run_tasks(
    func: Callable[[T], R], tasks: Sequence[T], workers: int = 1, scheduler: str | None = None
) -> Generator[tuple[int, R], None, None]:
    """Run ``func`` on every task; yields ``(position in tasks, result)`` as each task finishes.

    Use it with ``contextlib.closing`` when the loop body may raise, so that the workers are
    stopped before the exception propagates.

    Args:
        func: a module-level (picklable) function.
        tasks: picklable task descriptions.
        workers: local processes (1 runs in this process); ignored with ``scheduler``.
        scheduler: a Dask scheduler address, or None.

    Raises:
        LidarsimError: the Dask scheduler cannot be reached, or a worker process died. A task's
            own exception is re-raised (with the worker's traceback as its cause).
    """
    if not tasks:
        return
    if scheduler is not None:
        yield from _run_dask(func, tasks, scheduler)
    elif workers <= 1 or len(tasks) == 1:
        for i, task in enumerate(tasks):
            yield i, func(task)
    else:
        yield from _run_pool(func, tasks, workers)


def _signal_name(exitcode: int | None) -> str:
    if exitcode is None:
        return "still running"
    if exitcode < 0:
        with contextlib.suppress(ValueError):
            return f"killed by {signal.Signals(-exitcode).name}"
        return f"killed by signal {-exitcode}"
    return f"exit status {exitcode}"


def _stop(processes: list[Any]) -> None:
    """Kill every live worker and wait for it (SIGKILL: a worker holds no state worth saving)."""
    for p in processes:
        if p.is_alive():
            with contextlib.suppress(Exception):
                p.kill()
    deadline = time.monotonic() + _JOIN_TIMEOUT_S
    for p in processes:
        p.join(timeout=max(0.0, deadline - time.monotonic()))


def _run_pool(func: Callable[[T], R], tasks: Sequence[T], workers: int) -> Iterator[tuple[int, R]]:
    ctx = get_context("spawn")
    processes: list[Any] = []
    readers: dict[Connection, Any] = {}
    finished: set[Connection] = set()
    try:
        for group in balanced_groups(len(tasks), workers):
            reader, writer = ctx.Pipe(duplex=False)
            p = ctx.Process(
                target=_worker_main,
                args=(func, [(i, tasks[i]) for i in group], writer, os.getpid()),
                name="hd-worker",
                daemon=True,
            )
            p.start()
            writer.close()
            processes.append(p)
            readers[reader] = p
        remaining = len(tasks)
        open_readers = set(readers)
        while remaining:
            for conn in cast("list[Connection]", wait(list(open_readers), timeout=1.0)):
                try:
                    kind, index, payload, tb = conn.recv()
                except (EOFError, OSError) as exc:
                    open_readers.discard(conn)
                    proc = readers[conn]
                    proc.join(timeout=_JOIN_TIMEOUT_S)
                    if conn not in finished:
                        raise LidarsimError(
                            f"a worker process (PID {proc.pid}) died ({_signal_name(proc.exitcode)}) before finishing "
                            "its tasks; re-run the same command to resume"
                        ) from exc
                    continue
                if kind == "ok":
                    remaining -= 1
                    yield index, payload
                elif kind == "done":
                    finished.add(conn)
                else:
                    raise payload from RemoteTraceback(tb)
            if not open_readers and remaining:
                raise LidarsimError("the worker processes ended before every task was done; re-run the same command")
        for p in processes:
            p.join(timeout=_JOIN_TIMEOUT_S)
    finally:
        _stop(processes)
        for conn in readers:
            conn.close()


def _run_dask(func: Callable[[T], R], tasks: Sequence[T], scheduler: str) -> Iterator[tuple[int, R]]:
    from distributed import as_completed as dask_completed

    client = connect_scheduler(scheduler)
    futures: list[Any] = []
    try:
        futures = client.map(func, list(tasks), pure=False)
        position = {future.key: i for i, future in enumerate(futures)}
        for future in dask_completed(futures):
            yield position[future.key], future.result()
    finally:
        with contextlib.suppress(Exception):
            client.cancel(futures)
        client.close()


def check_scheduler_address(address: str) -> str:
    """Refuse a malformed Dask scheduler address before anything is written.

    Accepted: ``[PROTOCOL://]HOST:PORT`` with a Dask protocol (tcp, tls, inproc, ucx, ws, wss) and
    a port in 1..65535, or a scheduler file path ending in ``.json`` that exists.

    Raises:
        LidarsimError: naming the address and the expected form.
    """
    text = str(address).strip()
    hint = "use tcp://HOST:PORT, e.g. tcp://127.0.0.1:8786"
    if not text:
        raise LidarsimError(f"--scheduler must not be empty; {hint}")
    protocol, sep, rest = text.partition("://")
    if not sep:
        protocol, rest = "tcp", text
    if protocol not in ("tcp", "tls", "inproc", "ucx", "ws", "wss"):
        raise LidarsimError(f"--scheduler {text!r}: unknown protocol {protocol!r}; {hint}")
    if protocol == "inproc":
        return text
    host, colon, port = rest.rpartition(":")
    if not colon or not host or "/" in rest or " " in rest:
        raise LidarsimError(f"--scheduler {text!r} is not a scheduler address; {hint}")
    if not 0 < parse_integer(port, f"--scheduler {text!r}: the port", hint=hint, error=LidarsimError) < 65536:
        raise LidarsimError(f"--scheduler {text!r}: port {port!r} must be a number in 1..65535; {hint}")
    return text


def connect_scheduler(address: str, timeout_s: float = 20.0) -> Any:
    """A ``distributed.Client`` connected to ``address``.

    Raises:
        LidarsimError: malformed address or no scheduler answering within ``timeout_s``.
    """
    from distributed import Client

    check_scheduler_address(address)
    try:
        return Client(address, timeout=f"{timeout_s}s")
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise LidarsimError(f"cannot reach the Dask scheduler at {address} ({exc.__class__.__name__})") from exc


def probe_scheduler(address: str, timeout_s: float = 10.0) -> None:
    """Connect to the scheduler and disconnect (a check before anything is written)."""
    client = connect_scheduler(address, timeout_s)
    client.close()
