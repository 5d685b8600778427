"""What a recording's format reader hands on: the raw columns it found in file order, their
units and notes, and how a data row is shown in a message (a CSV file line, a MATLAB index).

:mod:`fmu_greybox.data.recording` checks a :class:`Table` and builds the recording from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Rows:
    """How a 0-based data row is shown for one file format, e.g. as a CSV file line."""

    label: str
    offset: int

    def at(self, row: int) -> str:
        return f" ({self.label} {row + self.offset})"


@dataclass
class Table:
    """What a format reader found: raw columns in file order, units and notes."""

    columns: dict[str, Any]
    units: dict[str, str]
    metadata: dict[str, str]
    rows: Rows | None
    kind: str  # "column" or "variable"
