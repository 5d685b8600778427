"""Independent fits side by side, one BLAS thread each.

A sparse-GP fit spends its time in a few large BLAS calls (a triangular solve, a rank-k
update, a product, all over M x N), which release the GIL. Two fits in two Python threads, each
limited to one BLAS thread, keep both cores busy with no more threads than cores. Left to
itself, OpenBLAS gives every call a thread per core, and its threads spin while they wait:
beside any other busy process a fit then runs several times slower (measured: 92 s instead of
15 s for the same fit with one BLAS thread, on this project's 2-core machine with two other
processes running; ``docs/speed.md``). So training runs with one BLAS thread throughout
(:func:`one_blas_thread`) and gets its parallelism from fits that do not depend on each other.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from threadpoolctl import threadpool_limits

T = TypeVar("T")


def run_side_by_side(tasks: Sequence[Callable[[], T]], workers: int | None = None) -> list[T]:
    """Run ``tasks`` in threads, at most ``workers`` at once (default: the cores this process
    may use), with one BLAS thread each; results in the order of ``tasks``.

    The first exception a task raises is raised here, after every task has ended.

    Parameters
    ----------
    tasks : sequence of callable
        Each called with no argument; they must share no mutable state.
    workers : int, optional

    Returns
    -------
    list
    """
    count = min(len(tasks), workers or available_cores())
    with one_blas_thread():
        if count <= 1:
            return [task() for task in tasks]
        with ThreadPoolExecutor(count) as pool:
            futures = [pool.submit(task) for task in tasks]
            return [future.result() for future in futures]


def one_blas_thread() -> threadpool_limits:
    """A context in which BLAS calls use one thread (process-wide; nested uses keep it at
    one until the outermost ends)."""
    return threadpool_limits(limits=1, user_api="blas")


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1
