"""Independent fits spread over the machine's cores: one forked process per core, results in task order.

Forked, so every worker shares the parent's flights and compiled kernels without copying or compiling
them again; only the tasks and the results (small: parameter sets, error figures) cross the process
boundary. With one core or one task the work runs in this process. ``say`` gets one line per finished
task with the time left, estimated from the mean time per task so far.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any, TypeVar

__all__ = ["cores", "run_tasks"]

T = TypeVar("T")
R = TypeVar("R")

_SHARED: Any = None


def cores() -> int:
    """Cores this process may run on."""
    return len(os.sched_getaffinity(0))


def _call(fn: Callable[[Any, Any], Any], task: Any) -> Any:
    return fn(_SHARED, task)


def _remember(shared: Any) -> None:
    global _SHARED
    _SHARED = shared


def run_tasks(
    fn: Callable[[Any, T], R],
    shared: Any,
    tasks: Sequence[T],
    label: str,
    say: Callable[[str], None] | None = None,
    workers: int | None = None,
) -> list[R]:
    """``[fn(shared, task) for task in tasks]``, the tasks on up to ``workers`` (default: every core)
    processes; ``fn`` must be a module-level function."""
    workers = min(workers or cores(), len(tasks))
    started = time.perf_counter()

    def report(done: int) -> None:
        if say is not None:
            elapsed = time.perf_counter() - started
            left = elapsed / done * (len(tasks) - done)
            say(f"{label}: {done}/{len(tasks)} done in {elapsed:.0f} s, about {left:.0f} s left")

    if workers <= 1:
        results = []
        for task in tasks:
            results.append(fn(shared, task))
            report(len(results))
        return results
    _remember(shared)  # a forked worker inherits it
    out: dict[int, R] = {}
    context = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
        pending = {pool.submit(_call, fn, task): k for k, task in enumerate(tasks)}
        while pending:
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in finished:
                out[pending.pop(future)] = future.result()
            report(len(out))
    _remember(None)
    return [out[k] for k in range(len(tasks))]
