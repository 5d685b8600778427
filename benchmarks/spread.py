"""Figures that reproduce: the median of repeated runs, with their range, the date and the load.

A speed figure from one run on a shared machine says little: another process can double it.
Every speed figure a benchmark prints is the median of ``--repeat`` runs (at least 3 for a
figure written into the README or the docs), with the range of the runs, the date and the load
average before and after, so that a reader can tell a figure measured on a busy machine.
"""

from __future__ import annotations

import os
import statistics
from collections.abc import Sequence
from datetime import UTC, datetime


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
