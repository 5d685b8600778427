"""The checks of a recording's names, cells, columns, time axis and units, shared by the
:class:`~fmu_greybox.data.recording.Recording` constructor and the format readers (which add
where a row is in the file).

Every problem is a :class:`~fmu_greybox.errors.RecordingError` naming the file, the column and
the row, with a way to mend it.
"""

from __future__ import annotations

import decimal
import math
import numbers
import re
import unicodedata
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import pandas as pd

from fmu_greybox.data.table import Rows
from fmu_greybox.errors import RecordingError
from fmu_greybox.suggest import did_you_mean
from fmu_greybox.units import UnitSyntaxError, conversion, normalise_unit

TIME = "time"
"""Name of the time axis: reserved, never a signal name; its unit is always seconds."""

UNIFORM_RTOL = 1e-6
"""Largest relative deviation of one time step from the median step on a uniform grid."""

_HEADER_UNIT = re.compile(r"^(?P<name>.*?\S)\s*\[(?P<unit>[^\[\]]*)\]$")
_DECIMAL_COMMA = re.compile(r"^\s*[-+]?\d+,\d+\s*$")
_RESAMPLE_HINT = (
    "load with resample=DT (CLI: --resample DT; project file: resample under [recording]) to "
    "interpolate onto a uniform grid"
)


def _at(rows: Rows | None, row: int) -> str:
    """Text locating ``row`` in the file, or nothing for in-memory data."""
    return rows.at(row) if rows is not None else ""


# --------------------------------------------------------------------------------------------
# Names and suggestions
# --------------------------------------------------------------------------------------------


def listing(names: Iterable[str], limit: int = 20) -> str:
    """``'a', 'b', ... (and 7 more)`` for an error message."""
    names = list(names)
    shown = ", ".join(repr(n) for n in names[:limit])
    more = f" (and {len(names) - limit} more)" if len(names) > limit else ""
    return (shown + more) if names else "(none)"


def not_found(missing: list[str], available: list[str], what: str, context: str | None) -> str:
    """Message for names that are not among ``available``, with close matches."""
    needed = f" (needed by {context})" if context else ""
    if len(missing) == 1:
        name = missing[0]
        head = f"{what} {name!r} not found{needed}{did_you_mean(name, available)}"
        return f"{head} (available: {listing(available)})"
    parts = []
    for name in missing:
        hint = did_you_mean(name, available)
        parts.append(f"{name!r} ({hint[2:]})" if hint else repr(name))
    head = f"{len(missing)} {what}s not found{needed}: " + ", ".join(parts)
    return f"{head} (available: {listing(available)})"


def check_names(names: Iterable[Any], path: str | None) -> None:
    """Signal names must be clean, non-empty strings other than :data:`TIME`."""
    for name in names:
        if not isinstance(name, str):
            raise RecordingError(
                f"signal names must be strings, got {name!r} ({type(name).__name__})", path
            )
        if not name.strip():
            raise RecordingError("a signal has an empty name; name every column", path)
        if name != name.strip():
            raise RecordingError(
                "the signal name has leading or trailing spaces; remove them", path, name
            )
        if any(unicodedata.category(ch).startswith("C") for ch in name):
            raise RecordingError(
                "the signal name contains control or invisible characters; rename it", path, name
            )
        if name == TIME:
            raise RecordingError(
                f"a signal may not be called {TIME!r}, which is reserved for the time axis; "
                f"rename the column, or make it the time axis with time_column={TIME!r}",
                path,
                name,
            )


def split_header(text: str) -> tuple[str, str]:
    """Split a header cell ``"name [unit]"`` into ``("name", "unit")``; no unit gives ``""``."""
    text = text.strip()
    match = _HEADER_UNIT.match(text)
    if match is None:
        return text, ""
    return match["name"], match["unit"].strip()


def header_columns(cells: list[str], path: str, kind: str) -> tuple[list[str], dict[str, str]]:
    """Names and units from header cells; every name present and unique."""
    names: list[str] = []
    units: dict[str, str] = {}
    for j, cell in enumerate(cells):
        name, unit = split_header(cell)
        if not name:
            raise RecordingError(
                f"{kind} {j + 1} of the header has no name; name every {kind}", path
            )
        if name in units:
            first = names.index(name) + 1
            raise RecordingError(
                f"the name appears twice in the header ({kind}s {first} and {j + 1}); "
                "rename one of them",
                path,
                name,
            )
        names.append(name)
        units[name] = unit
    return names, {name: unit for name, unit in units.items() if unit}


# --------------------------------------------------------------------------------------------
# Values
# --------------------------------------------------------------------------------------------


def cell_value(cell: Any) -> float | None:
    """A cell as a float (NaN when empty or missing), or ``None`` when it is not a number."""
    if isinstance(cell, bytes):
        try:
            cell = cell.decode("ascii")
        except UnicodeDecodeError:
            return None
    if isinstance(cell, str):
        text = cell.strip()
        if not text:
            return math.nan
        try:
            return float(text)
        except ValueError:
            return None
    if isinstance(cell, numbers.Real | decimal.Decimal | np.bool_):
        try:
            return float(cell)
        except OverflowError:
            return math.copysign(math.inf, cell)
    if cell is None or cell is pd.NA or cell is pd.NaT:
        return math.nan
    return None


def _bad_cell_message(cell: Any, count: int, row: int, rows: Rows | None) -> str:
    shown = repr(cell) if len(repr(cell)) <= 40 else repr(cell)[:37] + "..."
    hint = ""
    if isinstance(cell, str) and _DECIMAL_COMMA.match(cell):
        hint = " It looks like a decimal comma: write 1.5, not 1,5."
    others = f"; {count - 1} more cells in this column are not numbers" if count > 1 else ""
    return (
        f"value {shown} is not a number{_at(rows, row)}{others}. "
        f"Correct the cell or remove the row.{hint}"
    )


def _parse_cells(cells: list[Any], name: str, path: str | None, rows: Rows | None) -> np.ndarray:
    """Convert a list of cells of any type to float64, naming the first cell that is no number."""
    out = np.empty(len(cells), dtype=np.float64)
    first_bad: int | None = None
    count = 0
    for i, cell in enumerate(cells):
        value = cell_value(cell)
        if value is None:
            count += 1
            first_bad = i if first_bad is None else first_bad
        else:
            out[i] = value
    if first_bad is not None:
        message = _bad_cell_message(cells[first_bad], count, first_bad, rows)
        raise RecordingError(message, path, name, first_bad)
    return out


def float_column(values: Any, name: str, path: str | None, rows: Rows | None) -> np.ndarray:
    """One column as a fresh float64 vector, shape (n,).

    Raises
    ------
    RecordingError
        If it is not one-dimensional or holds anything but real numbers (missing cells become
        NaN here and are reported by the finiteness check).
    """
    array = np.asarray(values)
    if array.ndim != 1:
        raise RecordingError(
            f"holds an array of shape {array.shape}; a signal must be a vector with one value "
            "per time sample",
            path,
            name,
        )
    kind = array.dtype.kind
    if kind in "fiub":
        return array.astype(np.float64)
    if kind == "c":
        raise RecordingError(
            "holds complex numbers; store the real and imaginary parts as two signals", path, name
        )
    if kind in "mM":
        raise RecordingError(
            "holds dates or durations; only the time column may, and it must be the time axis",
            path,
            name,
        )
    return _parse_cells(array.tolist(), name, path, rows)


def _time_scale(unit: str, name: str, path: str | None) -> float:
    """Factor converting the time column's unit to seconds (no unit: seconds)."""
    if not normalise_unit(unit):
        return 1.0
    try:
        return conversion(unit, "s").scale
    except UnitSyntaxError as error:
        raise RecordingError(
            f"time unit {unit!r} is not a unit of time ({error}); use e.g. s, ms, us, ns, min "
            "or h (time is converted to seconds)",
            path,
            name,
        ) from error


def time_seconds(
    values: Any, name: str, unit: str, path: str | None, rows: Rows | None
) -> tuple[np.ndarray, dict[str, str]]:
    """The time column in seconds, shape (n,), and metadata (the origin of date-times)."""
    array = np.asarray(values)
    if array.ndim == 1 and array.dtype.kind == "M":
        stamps = array.astype("datetime64[ns]")
        valid = stamps[~np.isnat(stamps)]
        if valid.size == 0:
            return np.full(stamps.shape, np.nan), {}
        origin = valid[0]
        return (stamps - origin) / np.timedelta64(1, "s"), {"time_origin": str(origin)}
    if array.ndim == 1 and array.dtype.kind == "m":
        return array / np.timedelta64(1, "s"), {}
    scale = _time_scale(unit, name, path)
    return float_column(array, name, path, rows) * scale, {}


# --------------------------------------------------------------------------------------------
# Samples, and units by name
# --------------------------------------------------------------------------------------------


def _check_lengths(time: np.ndarray, signals: Mapping[str, np.ndarray], path: str | None) -> None:
    for name, values in signals.items():
        if len(values) != len(time):
            raise RecordingError(
                f"has {len(values)} values but the time axis has {len(time)}; every signal "
                "needs exactly one value per time sample",
                path,
                name,
            )


def _check_count(n: int, path: str | None) -> None:
    if n < 2:
        raise RecordingError(
            f"holds {n} sample{'s' if n != 1 else ''}; a recording needs at least 2 "
            "(is the file empty, or does it hold only a header?)",
            path,
        )


def _check_finite(values: np.ndarray, name: str, path: str | None, rows: Rows | None) -> None:
    bad = ~np.isfinite(values)
    if not bad.any():
        return
    first = int(np.argmax(bad))
    count = int(bad.sum())
    raise RecordingError(
        f"{count} of {len(values)} values are missing or not finite (empty, NaN or inf); "
        f"the first is {float(values[first])!r} at row {first}{_at(rows, first)}. Fill the gaps "
        "(e.g. by interpolation) or cut them out of the file",
        path,
        name,
        first,
    )


def _check_increasing(time: np.ndarray, name: str, path: str | None, rows: Rows | None) -> None:
    bad = np.diff(time) <= 0
    if not bad.any():
        return
    row = int(np.argmax(bad)) + 1
    before, after = float(time[row - 1]), float(time[row])
    how = "repeats" if before == after else "goes back"
    count = int(bad.sum())
    more = f" ({count} steps like this in all)" if count > 1 else ""
    raise RecordingError(
        f"time is not strictly increasing: it {how} from {before!r} s at row {row - 1} to "
        f"{after!r} s at row {row}{_at(rows, row)}{more}. Sort the rows by time and drop "
        "repeated time stamps",
        path,
        name,
        row,
    )


def check_uniform(time: np.ndarray, name: str, path: str | None, rows: Rows | None) -> None:
    """Every step within :data:`UNIFORM_RTOL` of the median step (time strictly increasing)."""
    steps = np.diff(time)
    typical = float(np.median(steps))
    deviation = np.abs(steps - typical) / typical
    bad = deviation > UNIFORM_RTOL
    if not bad.any():
        return
    row = int(np.argmax(bad)) + 1
    raise RecordingError(
        f"time step is not uniform: the step into row {row}{_at(rows, row)} is "
        f"{steps[row - 1]:.9g} s, {100 * deviation[row - 1]:.3g} % away from the typical step "
        f"{typical:.9g} s (tolerance {100 * UNIFORM_RTOL:.2g} %); {int(bad.sum())} of "
        f"{len(steps)} steps are off, the worst by {100 * deviation.max():.3g} %. "
        f"To use it anyway, {_RESAMPLE_HINT}, e.g. resample={typical:.6g}",
        path,
        name,
        row,
    )


def check_samples(
    time: np.ndarray,
    signals: Mapping[str, np.ndarray],
    time_name: str,
    path: str | None,
    rows: Rows | None,
) -> None:
    """All checks but uniformity, in the order that gives the most useful first error."""
    _check_lengths(time, signals, path)
    _check_count(len(time), path)
    _check_finite(time, time_name, path, rows)
    _check_increasing(time, time_name, path, rows)
    for name, values in signals.items():
        _check_finite(values, name, path, rows)


def check_unit_names(
    units: Mapping[str, str], known: Iterable[str], where: str, path: str | None
) -> None:
    """Every name given a unit must exist; a typo would otherwise be silently ignored."""
    known = list(known)
    for name in units:
        if name not in known:
            raise RecordingError(
                f"{where} gives a unit for {name!r}, which is not a signal"
                f"{did_you_mean(name, known)} (available: {listing(known)})",
                path,
                name,
            )


def units_mapping(data: Any, where: str, path: str | None) -> dict[str, str]:
    """Validate a ``{signal: unit}`` mapping read from a file or given by the caller."""
    if not isinstance(data, Mapping):
        raise RecordingError(
            f'{where} must map signal names to unit strings, e.g. {{"valve_current": "A"}}; '
            f"got {type(data).__name__}",
            path,
        )
    for name, unit in data.items():
        if not isinstance(name, str) or not isinstance(unit, str):
            raise RecordingError(
                f"{where} must map signal names to unit strings; the entry {name!r}: {unit!r} "
                "is not a pair of strings",
                path,
            )
    return dict(data)
