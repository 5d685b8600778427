"""Figures that reproduce: the median of repeated runs, with their range, the date and the load.

A speed figure from one run on a shared machine says little: another process can double it.
Every speed figure a benchmark prints is the median of ``--repeat`` runs (at least 3 for a
figure written into the README or the docs), with the range of the runs, the date and the load
average before and after, so that a reader can tell a figure measured on a busy machine.
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from typing import TypeVar

T = TypeVar("T")


def median_range(values: Sequence[float]) -> dict[str, float]:
    """``{"median", "min", "max"}`` of the runs' values."""
    return {
        "median": float(statistics.median(values)),
        "min": float(min(values)),
        "max": float(max(values)),
    }


def summary(runs: Sequence[dict], keys: Sequence[str]) -> dict[str, dict[str, float]]:
    """Per key, :func:`median_range` of that figure over the runs (each run a dict)."""
    return {key: median_range([run[key] for run in runs]) for key in keys}


def shown(figure: dict[str, float], digits: int = 3, unit: str = "") -> str:
    """``median (min-max)`` of a :func:`median_range`, e.g. ``5.7x (5.2-5.7x)``."""
    median, low, high = (f"{figure[k]:.{digits}g}" for k in ("median", "min", "max"))
    return f"{median}{unit} ({low}-{high}{unit})"


def conditions(load_before: float) -> dict[str, object]:
    """When and under what load the runs were made."""
    return {
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "cpus": os.cpu_count(),
        "load_before": load_before,
        "load_after": os.getloadavg()[0],
    }


def conditions_line(facts: dict[str, object], repeat: int) -> str:
    """One line saying how many runs, when, and under what load."""
    return (
        f"median of {repeat} run(s), range in brackets; {facts['date']}, {facts['cpus']} CPUs, "
        f"load average {facts['load_before']:.2f} before, {facts['load_after']:.2f} after"
    )


def alternated(
    ways: Mapping[str, Callable[[], T]], repeat: int
) -> tuple[dict[str, dict[str, float]], dict[str, T]]:
    """Each way run ``repeat`` times, the ways taking turns (a drift of the machine falls on
    all alike): per way, the :func:`median_range` of its seconds, and what its last run gave."""
    seconds: dict[str, list[float]] = {name: [] for name in ways}
    last: dict[str, T] = {}
    for _ in range(repeat):
        for name, way in ways.items():
            started = time.perf_counter()
            last[name] = way()
            seconds[name].append(time.perf_counter() - started)
    return {name: median_range(values) for name, values in seconds.items()}, last


def against(figures: Mapping[str, dict[str, float]], ours: str, peer: str) -> str:
    """``ours 1.13 s (1.06-2.18 s), peer 11.8 s (10.6-13.4 s): 10.5x`` (the peer's median over
    ours) from :func:`alternated`'s figures."""
    ratio = figures[peer]["median"] / figures[ours]["median"]
    return (
        f"{ours} {shown(figures[ours], unit=' s')}, {peer} {shown(figures[peer], unit=' s')}: "
        f"{ratio:.{1 if ratio >= 10 else 2}f}x"
    )


def yes(ok: bool) -> str:
    """``yes`` or ``NO``: a benchmark's check of its results, shouting when it fails."""
    return "yes" if ok else "NO"


def print_against(
    what: str,
    figures: Mapping[str, dict[str, float]],
    ours: str,
    peer: str,
    checked: str,
    load_before: float,
    repeat: int,
) -> None:
    """Print a two-way benchmark's lines: ``what: ours ..., peer ...: ratio; checked``
    (:func:`against`), then the conditions of its runs (:func:`conditions_line`)."""
    print(f"{what}: {against(figures, ours, peer)}; {checked}")
    print(conditions_line(conditions(load_before), repeat))
