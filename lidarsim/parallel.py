"""Running independent shard tasks: in this process, on a local process pool, or on a Dask cluster.

The local pool gives every worker one contiguous, balanced group of tasks (consecutive shards
cover neighbouring terrain, so a worker reuses what it cached for the previous shard, such as a
tile's ray-casting BVH); results are reported task by task through a queue so progress bars
move smoothly. ``--scheduler ADDRESS`` sends the same tasks to ``dask.distributed``.
"""

from __future__ import annotations

import queue as queue_module
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any, TypeVar

from lidarsim.errors import LidarsimError

T = TypeVar("T")
R = TypeVar("R")


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


def _run_group(func: Callable[[Any], Any], indexed: list[tuple[int, Any]], results: Any) -> None:
    for index, task in indexed:
        results.put((index, func(task)))


def run_tasks(
    func: Callable[[T], R], tasks: Sequence[T], workers: int = 1, scheduler: str | None = None
) -> Iterator[tuple[int, R]]:
    """Run ``func`` on every task; yields ``(position in tasks, result)`` as each task finishes.

    Args:
        func: a module-level (picklable) function.
        tasks: picklable task descriptions.
        workers: local processes (1 runs in this process); ignored with ``scheduler``.
        scheduler: a Dask scheduler address, or None.

    Raises:
        LidarsimError: the Dask scheduler cannot be reached. A task's own exception is re-raised.
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


def _run_pool(func: Callable[[T], R], tasks: Sequence[T], workers: int) -> Iterator[tuple[int, R]]:
    ctx = get_context("spawn")
    with ctx.Manager() as manager, ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        results = manager.Queue()
        futures = [
            pool.submit(_run_group, func, [(i, tasks[i]) for i in group], results)
            for group in balanced_groups(len(tasks), workers)
        ]
        remaining = len(tasks)
        try:
            while remaining:
                try:
                    index, result = results.get(timeout=0.2)
                except queue_module.Empty:
                    for future in futures:
                        if future.done() and future.exception() is not None:
                            raise future.exception()  # type: ignore[misc]
                    continue
                remaining -= 1
                yield index, result
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _run_dask(func: Callable[[T], R], tasks: Sequence[T], scheduler: str) -> Iterator[tuple[int, R]]:
    from distributed import Client
    from distributed import as_completed as dask_completed

    try:
        client = Client(scheduler, timeout="20s")
    except (OSError, TimeoutError) as exc:
        raise LidarsimError(f"cannot reach the Dask scheduler at {scheduler} ({exc.__class__.__name__})") from None
    try:
        futures = client.map(func, list(tasks), pure=False)
        position = {future.key: i for i, future in enumerate(futures)}
        for future in dask_completed(futures):
            yield position[future.key], future.result()
    finally:
        client.close()
