"""Independent fits side by side, one BLAS thread each.

A sparse-GP fit spends its time in a few large BLAS calls (a triangular solve, a rank-k
update, a product, all over M x N), which release the GIL. Two fits in two Python threads, each
limited to one BLAS thread, keep both cores busy with no more threads than cores. Left to
itself, OpenBLAS gives every call a thread per core, and its threads spin while they wait:
beside any other busy process a fit then runs several times slower (measured: 92 s instead of
15 s for the same fit with one BLAS thread, on this project's 2-core machine with two other
processes running; ``docs/speed.md``). So training runs with one BLAS thread throughout
(:func:`one_blas_thread`) and gets its parallelism from fits that do not depend on each other,
and a fit that runs alone splits its own work over two threads (:func:`spare_core`).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import TypeVar

from threadpoolctl import threadpool_limits

T = TypeVar("T")

_lock = threading.Lock()
#: Tasks of :func:`run_side_by_side` running now, in this process.
_running = 0
#: Nested :func:`one_blas_thread` blocks open now, in this process.
_one_thread_blocks = 0


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
            futures = [pool.submit(_counted, task) for task in tasks]
            return [future.result() for future in futures]


def _counted(task: Callable[[], T]) -> T:
    """Run ``task``, counted in :data:`_running` while it runs."""
    global _running
    with _lock:
        _running += 1
    try:
        return task()
    finally:
        with _lock:
            _running -= 1


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """A context in which BLAS calls use one thread (process-wide; nested uses keep it at
    one until the outermost ends)."""
    global _one_thread_blocks
    with threadpool_limits(limits=1, user_api="blas"):
        with _lock:
            _one_thread_blocks += 1
        try:
            yield
        finally:
            with _lock:
                _one_thread_blocks -= 1


def spare_core() -> bool:
    """Whether a computation may split itself over two threads now: BLAS is held to one thread
    (:func:`one_blas_thread`, so the threads do not multiply BLAS's own), at most one task of
    :func:`run_side_by_side` is running (the one asking, or none), and the process may use two
    cores or more."""
    return _one_thread_blocks > 0 and _running <= 1 and available_cores() >= 2


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1
