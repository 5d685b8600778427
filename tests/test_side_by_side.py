"""Work side by side: one BLAS thread while it runs, and a core spare only for a task alone."""

from __future__ import annotations

import threading

from fmu_greybox import side_by_side


def test_no_core_is_spare_while_two_tasks_run_side_by_side(two_cores: None) -> None:
    both_running = threading.Barrier(2)

    def ask() -> bool:
        both_running.wait(timeout=10)
        spare = side_by_side.spare_core()
        both_running.wait(timeout=10)
        return spare

    assert side_by_side.run_side_by_side([ask, ask]) == [False, False]
    assert side_by_side.run_side_by_side([side_by_side.spare_core]) == [True]
    assert not side_by_side.spare_core()  # BLAS is free again outside
