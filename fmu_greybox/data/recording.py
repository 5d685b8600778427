"""Recordings of a real or simulated component: load, check, slice, save.

A :class:`Recording` is a set of named signals sampled on one uniform time grid, each with a unit.
It is the input to simulation, training and diagnosis, so it is checked once, on construction,
and every problem is reported as a :class:`~fmu_greybox.errors.RecordingError` naming the file,
the column and the row, with a way to mend it.

Formats: CSV (header row; units from ``name [unit]`` headers or a ``FILE.units.json`` sidecar),
Parquet (units in the schema metadata), MATLAB ``.mat`` v4 to v7.3 (variables as signals;
:mod:`fmu_greybox.data.mat`) and ASAM MDF (channels with their units; :mod:`fmu_greybox.data.mdf`).
Units other than the ones wanted are converted by :meth:`Recording.converted`. See
``docs/recordings.md``.
"""

from __future__ import annotations

import csv
import decimal
import hashlib
import io
import json
import logging
import math
import numbers
import os
import re
import unicodedata
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from fmu_greybox.atomic import atomic_write
from fmu_greybox.data.mat import read_mat
from fmu_greybox.data.mdf import read_mdf
from fmu_greybox.errors import RecordingError, UnitMismatchError
from fmu_greybox.suggest import did_you_mean
from fmu_greybox.units import UnitSyntaxError, conversion, normalise_unit, units_compatible

__all__ = [
    "SAVE_FORMATS",
    "SUPPORTED_FORMATS",
    "TIME",
    "UNIFORM_RTOL",
    "Recording",
    "load_recording",
    "normalise_unit",
    "save_recording",
    "units_compatible",
]

TIME = "time"
"""Name of the time axis: reserved, never a signal name; its unit is always seconds."""

UNIFORM_RTOL = 1e-6
"""Largest relative deviation of one time step from the median step on a uniform grid."""

SUPPORTED_FORMATS = (".csv", ".mat", ".mdf", ".mf4", ".parquet")
SAVE_FORMATS = (".csv", ".parquet")
SIDECAR_SUFFIX = ".units.json"
UNITS_KEY = b"fmu_greybox.units"
METADATA_KEY = b"fmu_greybox.metadata"

_MAX_UPSAMPLING = 100
_HEADER_UNIT = re.compile(r"^(?P<name>.*?\S)\s*\[(?P<unit>[^\[\]]*)\]$")
_PANDAS_INDEX = re.compile(r"^__index_level_\d+__$")
_DECIMAL_COMMA = re.compile(r"^\s*[-+]?\d+,\d+\s*$")
_RESAMPLE_HINT = (
    "load with resample=DT (CLI: --resample DT; project file: resample under [recording]) to "
    "interpolate onto a uniform grid"
)
_TIME_NAMES = {"t", "tout", "time_s", "timestamp", "times", "zeit", "temps"}
_TIME_COLUMN_HINT = "time_column='NAME' (project file: time_column under [recording])"
_log = logging.getLogger(__name__)


# --------------------------------------------------------------------------------------------
# Where a row is in the user's file
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Rows:
    """How a 0-based data row is shown for one file format, e.g. as a CSV file line."""

    label: str
    offset: int

    def at(self, row: int) -> str:
        return f" ({self.label} {row + self.offset})"


def _at(rows: _Rows | None, row: int) -> str:
    """Text locating ``row`` in the file, or nothing for in-memory data."""
    return rows.at(row) if rows is not None else ""


# --------------------------------------------------------------------------------------------
# Names and suggestions
# --------------------------------------------------------------------------------------------


def _listing(names: Iterable[str], limit: int = 20) -> str:
    """``'a', 'b', ... (and 7 more)`` for an error message."""
    names = list(names)
    shown = ", ".join(repr(n) for n in names[:limit])
    more = f" (and {len(names) - limit} more)" if len(names) > limit else ""
    return (shown + more) if names else "(none)"


def _not_found(missing: list[str], available: list[str], what: str, context: str | None) -> str:
    """Message for names that are not among ``available``, with close matches."""
    needed = f" (needed by {context})" if context else ""
    if len(missing) == 1:
        name = missing[0]
        head = f"{what} {name!r} not found{needed}{did_you_mean(name, available)}"
        return f"{head} (available: {_listing(available)})"
    parts = []
    for name in missing:
        hint = did_you_mean(name, available)
        parts.append(f"{name!r} ({hint[2:]})" if hint else repr(name))
    head = f"{len(missing)} {what}s not found{needed}: " + ", ".join(parts)
    return f"{head} (available: {_listing(available)})"


def _check_names(names: Iterable[Any], path: str | None) -> None:
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


def _split_header(text: str) -> tuple[str, str]:
    """Split a header cell ``"name [unit]"`` into ``("name", "unit")``; no unit gives ``""``."""
    text = text.strip()
    match = _HEADER_UNIT.match(text)
    if match is None:
        return text, ""
    return match["name"], match["unit"].strip()


def _header_columns(cells: list[str], path: str, kind: str) -> tuple[list[str], dict[str, str]]:
    """Names and units from header cells; every name present and unique."""
    names: list[str] = []
    units: dict[str, str] = {}
    for j, cell in enumerate(cells):
        name, unit = _split_header(cell)
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


def _cell_value(cell: Any) -> float | None:
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


def _bad_cell_message(cell: Any, count: int, row: int, rows: _Rows | None) -> str:
    shown = repr(cell) if len(repr(cell)) <= 40 else repr(cell)[:37] + "..."
    hint = ""
    if isinstance(cell, str) and _DECIMAL_COMMA.match(cell):
        hint = " It looks like a decimal comma: write 1.5, not 1,5."
    others = f"; {count - 1} more cells in this column are not numbers" if count > 1 else ""
    return (
        f"value {shown} is not a number{_at(rows, row)}{others}. "
        f"Correct the cell or remove the row.{hint}"
    )


def _parse_cells(cells: list[Any], name: str, path: str | None, rows: _Rows | None) -> np.ndarray:
    """Convert a list of cells of any type to float64, naming the first cell that is no number."""
    out = np.empty(len(cells), dtype=np.float64)
    first_bad: int | None = None
    count = 0
    for i, cell in enumerate(cells):
        value = _cell_value(cell)
        if value is None:
            count += 1
            first_bad = i if first_bad is None else first_bad
        else:
            out[i] = value
    if first_bad is not None:
        message = _bad_cell_message(cells[first_bad], count, first_bad, rows)
        raise RecordingError(message, path, name, first_bad)
    return out


def _float_column(values: Any, name: str, path: str | None, rows: _Rows | None) -> np.ndarray:
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


def _time_seconds(
    values: Any, name: str, unit: str, path: str | None, rows: _Rows | None
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
    return _float_column(array, name, path, rows) * scale, {}


# --------------------------------------------------------------------------------------------
# Checks (shared by the constructor and the loaders, which add file-line information)
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


def _check_finite(values: np.ndarray, name: str, path: str | None, rows: _Rows | None) -> None:
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


def _check_increasing(time: np.ndarray, name: str, path: str | None, rows: _Rows | None) -> None:
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


def _check_uniform(time: np.ndarray, name: str, path: str | None, rows: _Rows | None) -> None:
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


def _check_samples(
    time: np.ndarray,
    signals: Mapping[str, np.ndarray],
    time_name: str,
    path: str | None,
    rows: _Rows | None,
) -> None:
    """All checks but uniformity, in the order that gives the most useful first error."""
    _check_lengths(time, signals, path)
    _check_count(len(time), path)
    _check_finite(time, time_name, path, rows)
    _check_increasing(time, time_name, path, rows)
    for name, values in signals.items():
        _check_finite(values, name, path, rows)


def _check_unit_names(
    units: Mapping[str, str], known: Iterable[str], where: str, path: str | None
) -> None:
    """Every name given a unit must exist; a typo would otherwise be silently ignored."""
    known = list(known)
    for name in units:
        if name not in known:
            raise RecordingError(
                f"{where} gives a unit for {name!r}, which is not a signal"
                f"{did_you_mean(name, known)} (available: {_listing(known)})",
                path,
                name,
            )


def _units_mapping(data: Any, where: str, path: str | None) -> dict[str, str]:
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


# --------------------------------------------------------------------------------------------
# The recording
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Recording:
    """Named signals on one uniform time grid, with units. Immutable; checked on construction.

    Parameters
    ----------
    time : array_like, shape (n,)
        Time [s], finite, strictly increasing and uniform to :data:`UNIFORM_RTOL`; ``n >= 2``.
    signals : mapping of str to array_like, each shape (n,)
        Real, finite values, at least one signal. Names are clean non-empty strings other than
        ``"time"``. Order is kept.
    units : mapping of str to str
        Unit of each signal (missing ones become ``""``, unknown). Time is always in seconds.
    source : str
        The file it came from, or a description; shown in every error.
    metadata : mapping of str to str
        Free provenance notes (e.g. ``"resampled_dt"``).

    Raises
    ------
    RecordingError
        If any of the above does not hold; the message names the column and the row.

    Notes
    -----
    Arrays are copied to float64 and made read-only. Two recordings are equal (``==``) when
    their time, signals and units are equal, whatever their source and metadata; this is what
    :meth:`sha256` hashes.
    """

    time: np.ndarray
    signals: dict[str, np.ndarray]
    units: dict[str, str] = field(default_factory=dict)
    source: str = ""
    metadata: dict[str, str] = field(default_factory=dict)

    __hash__ = None  # type: ignore[assignment]  # holds mutable dicts

    def __post_init__(self) -> None:
        source = str(self.source)
        path = source or None
        if not isinstance(self.signals, Mapping) or not self.signals:
            raise RecordingError(
                "a recording needs at least one signal besides time, given as a mapping "
                "{name: values}",
                path,
            )
        _check_names(self.signals, path)
        time = _float_column(self.time, TIME, path, None)
        signals = {n: _float_column(v, n, path, None) for n, v in self.signals.items()}
        _check_samples(time, signals, TIME, path, None)
        _check_uniform(time, TIME, path, None)
        given = _units_mapping(self.units, "units", path)
        _check_unit_names(given, signals, "units", path)
        for array in (time, *signals.values()):
            array.setflags(write=False)
        object.__setattr__(self, "time", time)
        object.__setattr__(self, "signals", signals)
        object.__setattr__(self, "units", {n: given.get(n, "") for n in signals})
        object.__setattr__(self, "source", source)
        notes = {str(k): str(v) for k, v in dict(self.metadata).items()}
        object.__setattr__(self, "metadata", notes)

    # -- shape -----------------------------------------------------------------------------

    @property
    def n_samples(self) -> int:
        """Number of time samples ``n``."""
        return len(self.time)

    @property
    def dt(self) -> float:
        """Sampling step [s]: the mean step over the whole grid."""
        return float((self.time[-1] - self.time[0]) / (len(self.time) - 1))

    @property
    def duration(self) -> float:
        """Recorded span ``time[-1] - time[0]`` [s]."""
        return float(self.time[-1] - self.time[0])

    @property
    def names(self) -> tuple[str, ...]:
        """Signal names in file order (time excluded)."""
        return tuple(self.signals)

    def __contains__(self, name: object) -> bool:
        return name == TIME or name in self.signals

    def __getitem__(self, name: str) -> np.ndarray:
        """Signal ``name`` (or ``"time"``), shape (n,), read-only.

        Raises
        ------
        RecordingError
            If there is no such signal; suggests the closest names.
        """
        if name == TIME:
            return self.time
        if name not in self.signals:
            self.require([name])
        return self.signals[name]

    def require(self, names: Iterable[str], context: str | None = None) -> None:
        """Check that every signal in ``names`` is present.

        Parameters
        ----------
        names : iterable of str
            Signal names (``"time"`` is always present).
        context : str, optional
            Who needs them, e.g. ``"stage 'RAM'"``; shown in the message.

        Raises
        ------
        RecordingError
            Listing every missing name with close matches and the available names.
        """
        if isinstance(names, str):
            names = [names]
        missing = [n for n in names if n not in self]
        if missing:
            column = missing[0] if len(missing) == 1 else None
            message = _not_found(missing, list(self.signals), "column", context)
            raise RecordingError(message, self.source or None, column)

    # -- new recordings from this one ------------------------------------------------------

    def _replace(
        self, time: np.ndarray, signals: Mapping[str, Any], units: Mapping[str, str]
    ) -> Recording:
        return Recording(time, signals, units, self.source, self.metadata)

    def _take(self, index: slice | np.ndarray, what: str) -> Recording:
        time = self.time[index]
        if len(time) < 2:
            raise RecordingError(
                f"{what} keeps {len(time)} sample(s); at least 2 are needed. The recording "
                f"spans {self.time[0]:.9g} s to {self.time[-1]:.9g} s with step {self.dt:.6g} s",
                self.source or None,
            )
        signals = {name: values[index] for name, values in self.signals.items()}
        return self._replace(time, signals, self.units)

    def slice_time(self, t0: float, t1: float) -> Recording:
        """The samples with ``t0 <= time <= t1`` (both ends included, to within 1e-9 dt).

        Raises
        ------
        RecordingError
            If ``t0 > t1`` or fewer than 2 samples remain.
        """
        if not t0 <= t1:
            raise RecordingError(
                f"slice_time needs t0 <= t1, got t0={t0!r}, t1={t1!r}", self.source or None
            )
        slack = 1e-9 * self.dt
        keep = (self.time >= t0 - slack) & (self.time <= t1 + slack)
        return self._take(keep, f"the time slice [{t0:g}, {t1:g}] s")

    def split(self, fraction: float) -> tuple[Recording, Recording]:
        """Split by time into (train, validation): the first ``fraction`` of the samples, the rest.

        Raises
        ------
        RecordingError
            If ``fraction`` is not in (0, 1) or a part would hold fewer than 2 samples.
        """
        if not 0 < fraction < 1:
            raise RecordingError(
                f"split needs a fraction between 0 and 1 (exclusive), got {fraction!r}",
                self.source or None,
            )
        k = round(fraction * self.n_samples)
        train = self._take(slice(0, k), f"split({fraction:g}), training part,")
        validation = self._take(slice(k, None), f"split({fraction:g}), validation part,")
        return train, validation

    def select(self, names: Iterable[str]) -> Recording:
        """Only the signals ``names`` (in that order); ``"time"`` is kept implicitly.

        Raises
        ------
        RecordingError
            If a name is missing (see :meth:`require`).
        """
        wanted = [n for n in dict.fromkeys(names) if n != TIME]
        self.require(wanted, context="select")
        signals = {n: self.signals[n] for n in wanted}
        return self._replace(self.time, signals, {n: self.units[n] for n in wanted})

    def converted(self, units: Mapping[str, str]) -> Recording:
        """A copy with columns converted to the given units (a note for each in the log).

        Parameters
        ----------
        units : mapping of str to str
            Column -> the unit it is wanted in. Columns absent from the recording, without a
            recorded unit, or wanted without a unit are left as they are.

        Returns
        -------
        Recording
            Converted columns carry their new unit; ``metadata["unit_conversions"]`` lists
            what was converted (``self`` when nothing was).

        Raises
        ------
        UnitMismatchError
            If a recorded unit cannot be converted to the wanted one (another quantity, or a
            unit symbol this tool does not know); the message names the file and the column.
        """
        signals: dict[str, np.ndarray] = {}
        new_units: dict[str, str] = {}
        notes = []
        for name, wanted in units.items():
            recorded = self.units.get(name, "")
            if not (recorded and wanted) or units_compatible(recorded, wanted):
                continue
            try:
                change = conversion(recorded, wanted)
            except UnitSyntaxError as error:
                raise UnitMismatchError(
                    f"column {name!r} is recorded in {recorded!r}, which cannot be converted to "
                    f"{wanted!r} ({error}); record it in {wanted!r} or correct its unit",
                    path=self.source or None,
                ) from error
            signals[name] = self.signals[name] * change.scale + change.offset
            new_units[name] = wanted
            notes.append(f"{name}: {recorded} -> {wanted}")
            _log.warning(
                "%s: column %r converted from %r to %r (x %.9g%s)",
                self.source or "recording",
                name,
                recorded,
                wanted,
                change.scale,
                f" + {change.offset:.9g}" if change.offset else "",
            )
        if not signals:
            return self
        converted = self.with_signals(signals, new_units)
        metadata = {**self.metadata, "unit_conversions": "; ".join(notes)}
        return Recording(converted.time, converted.signals, converted.units, self.source, metadata)

    def with_signals(
        self, signals: Mapping[str, Any], units: Mapping[str, str] | None = None
    ) -> Recording:
        """A copy with ``signals`` added or replaced.

        Parameters
        ----------
        signals : mapping of str to array_like, each shape (n,)
            New or replacing signals.
        units : mapping of str to str, optional
            Their units. A replaced signal keeps its old unit unless given; a new one gets ``""``.
        """
        merged = {**self.signals, **signals}
        merged_units = {**self.units, **(dict(units) if units else {})}
        return self._replace(self.time, merged, merged_units)

    # -- export ----------------------------------------------------------------------------

    def to_frame(self) -> pd.DataFrame:
        """A DataFrame with a ``"time"`` column then the signals, shape (n, 1 + n_signals).

        ``frame.attrs["units"]`` maps every column (time included, ``"s"``) to its unit.
        """
        frame = pd.DataFrame({TIME: self.time, **self.signals})
        frame.attrs["units"] = {TIME: "s", **self.units}
        frame.attrs["source"] = self.source
        return frame

    @classmethod
    def from_frame(
        cls,
        frame: pd.DataFrame,
        *,
        time_column: str = TIME,
        units: Mapping[str, str] | None = None,
        source: str = "",
        metadata: Mapping[str, str] | None = None,
    ) -> Recording:
        """Build a recording from a DataFrame with a time column.

        Units come from ``frame.attrs["units"]`` (as written by :meth:`to_frame`; entries for
        absent columns are ignored), overridden by ``units``.
        """
        columns = {str(name): frame[name].to_numpy() for name in frame.columns}
        path = source or None
        attrs = _units_mapping(frame.attrs.get("units", {}), 'frame.attrs["units"]', path)
        given = _units_mapping(units or {}, "units", path)
        _check_unit_names(given, columns, "units", path)
        given = {**{n: u for n, u in attrs.items() if n in columns}, **given}
        table = _Table(columns, given, dict(metadata or {}), None, "column")
        return _assemble(table, time_column=time_column, source=source, resample=None)

    def sha256(self) -> str:
        """Hex SHA-256 of time, signals (in sorted name order) and units, for traceability."""
        digest = hashlib.sha256(b"fmu_greybox.data.recording/1\0")
        names = sorted(self.signals)
        header = {"n": self.n_samples, "signals": [[n, self.units[n]] for n in names]}
        digest.update(json.dumps(header, ensure_ascii=False, separators=(",", ":")).encode())
        digest.update(b"\0")
        for array in (self.time, *(self.signals[n] for n in names)):
            digest.update(np.ascontiguousarray(array, dtype="<f8").tobytes())
        return digest.hexdigest()

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Recording):
            return NotImplemented
        return (
            self.units == other.units
            and set(self.signals) == set(other.signals)
            and np.array_equal(self.time, other.time)
            and all(np.array_equal(v, other.signals[n]) for n, v in self.signals.items())
        )

    def __repr__(self) -> str:
        shown = [f"{n} [{u}]" if u else n for n, u in self.units.items()]
        return (
            f"Recording(source={self.source!r}, n_samples={self.n_samples}, "
            f"dt={self.dt:.6g}, signals={shown})"
        )


# --------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------


@dataclass
class _Table:
    """What a format reader found: raw columns in file order, units and notes."""

    columns: dict[str, Any]
    units: dict[str, str]
    metadata: dict[str, str]
    rows: _Rows | None
    kind: str  # "column" or "variable"


def _resample(
    time: np.ndarray, signals: dict[str, np.ndarray], dt: Any, path: str | None
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Linear interpolation onto ``time[0] + k dt`` within the recorded span; shapes (m,)."""
    try:
        step = float(dt)
    except (TypeError, ValueError):
        step = math.nan
    if not (math.isfinite(step) and step > 0):
        raise RecordingError(
            f"resample step must be a positive number of seconds, got {dt!r}", path
        )
    span = float(time[-1] - time[0])
    count = math.floor(span / step + 1e-9) + 1
    if count < 2:
        raise RecordingError(
            f"resample step {step:g} s is longer than the recorded span {span:g} s; "
            "choose a smaller step",
            path,
        )
    if count > _MAX_UPSAMPLING * len(time):
        raise RecordingError(
            f"resample step {step:g} s would turn {len(time)} samples into {count}; "
            f"the step is in seconds (the recording's median step is "
            f"{float(np.median(np.diff(time))):.6g} s)",
            path,
        )
    grid = time[0] + step * np.arange(count)
    return grid, {name: np.interp(grid, time, values) for name, values in signals.items()}


def _missing_time(table: _Table, time_column: str) -> str:
    kind = table.kind
    found = list(table.columns)
    likely = [name for name in found if name.lower() in _TIME_NAMES]
    return (
        f"no time {kind} {time_column!r}{did_you_mean(time_column, found, likely)} ({kind}s found: "
        f"{_listing(found)}). Name the time {kind} with {_TIME_COLUMN_HINT}"
    )


def _assemble(table: _Table, *, time_column: str, source: str, resample: float | None) -> Recording:
    """Check raw columns (naming file rows), resample if asked, and build the recording."""
    path = source or None
    if time_column not in table.columns:
        raise RecordingError(_missing_time(table, time_column), path, time_column)
    raw = {n: v for n, v in table.columns.items() if n != time_column}
    if not raw:
        raise RecordingError(
            f"holds no signal {table.kind}s besides the time {table.kind} {time_column!r}; "
            "a recording needs at least one recorded signal",
            path,
        )
    _check_names(raw, path)
    time_unit = table.units.get(time_column, "")
    time, notes = _time_seconds(
        table.columns[time_column], time_column, time_unit, path, table.rows
    )
    signals = {n: _float_column(v, n, path, table.rows) for n, v in raw.items()}
    _check_samples(time, signals, time_column, path, table.rows)
    if resample is None:
        _check_uniform(time, time_column, path, table.rows)
    else:
        time, signals = _resample(time, signals, resample, path)
        notes["resampled_dt"] = repr(float(resample))
    units = {n: u for n, u in table.units.items() if n != time_column}
    return Recording(time, signals, units, source, {**table.metadata, **notes})


def _read_bytes(path: Path) -> bytes:
    """The whole file, read once (a named pipe or a stream can be read only once), turning any
    OS problem into a clear error."""
    try:
        with path.open("rb") as handle:
            return handle.read()
    except OSError as error:
        reason = error.strerror or str(error)
        where = "" if path.is_absolute() else f" (relative to {os.getcwd()})"
        raise RecordingError(
            f"cannot read the file: {reason}; check the path{where} and its permissions",
            str(path),
        ) from error


def _sidecar_path(path: Path) -> Path:
    return path.with_name(path.name + SIDECAR_SUFFIX)


def _read_sidecar(path: Path) -> dict[str, str]:
    """Units from ``FILE.units.json`` beside the recording, or nothing if there is none."""
    sidecar = _sidecar_path(path)
    if not sidecar.exists():
        return {}
    try:
        text = sidecar.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise RecordingError(f"cannot read the units file: {error}", str(sidecar)) from error
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise RecordingError(
            f"is not valid JSON ({error.msg} at line {error.lineno} column {error.colno}); it "
            'must map signal names to units, e.g. {"valve_current": "A", "time": "s"}',
            str(sidecar),
        ) from error
    return _units_mapping(data, "the units file", str(sidecar))


# -- CSV ---------------------------------------------------------------------------------------


def _sniff_delimiter(line: str) -> str:
    """Comma if the header has one outside quotes, else semicolon, else tab, else comma."""
    bare = re.sub(r'"(?:[^"]|"")*"', "", line)
    return next((d for d in (",", ";", "\t") if d in bare), ",")


def _csv_header(path: Path, text: str) -> tuple[str, list[str]]:
    """Delimiter and header cells of a CSV file's text."""
    line = io.StringIO(text, newline="").readline()
    if not line.strip():
        what = "the file is empty" if not line else "the first line is empty"
        raise RecordingError(
            f"{what}; a CSV recording needs a header line naming the columns (e.g. "
            "'time,valve_current') followed by at least 2 rows of numbers",
            str(path),
        )
    delimiter = _sniff_delimiter(line)
    cells = next(csv.reader([line.rstrip("\r\n")], delimiter=delimiter))
    if all(cell.strip() and _cell_value(cell) is not None for cell in cells):
        raise RecordingError(
            f"has no header line: the first line {line.strip()[:60]!r} holds numbers. Add a "
            "first line naming the columns, e.g. 'time,valve_current,ram_position'",
            str(path),
        )
    return delimiter, cells


def _not_utf8(path: Path, error: UnicodeDecodeError) -> RecordingError:
    return RecordingError(
        f"is not UTF-8 text (byte {error.start} cannot be decoded); save the file as UTF-8",
        str(path),
    )


def _first_ragged_line(text: str, delimiter: str, width: int) -> str | None:
    """Describe the first line whose field count differs from the header's, if any."""
    reader = csv.reader(io.StringIO(text, newline=""), delimiter=delimiter)
    next(reader, None)
    for fields in reader:
        if fields and len(fields) > width:
            return (
                f"line {reader.line_num} has {len(fields)} fields but the header has "
                f"{width}; remove the extra fields or name the column in the header"
            )
    return None


def _csv_body(path: Path, text: str, delimiter: str, width: int) -> pd.DataFrame:
    """All data rows as a DataFrame; blank lines kept so that row r is file line r + 2."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", pd.errors.ParserWarning)
            frame = pd.read_csv(
                io.StringIO(text, newline=""),
                sep=delimiter,
                header=0,
                index_col=False,
                skip_blank_lines=False,
                skipinitialspace=True,
                low_memory=False,
            )
    except (pd.errors.ParserError, pd.errors.ParserWarning, ValueError, csv.Error) as error:
        raise RecordingError(_parse_failure(text, delimiter, width, error), str(path)) from error
    blank = frame.isna().all(axis=1).to_numpy()
    end = len(blank)
    while end and blank[end - 1]:
        end -= 1
    return frame.iloc[:end]


def _parse_failure(text: str, delimiter: str, width: int, error: Exception) -> str:
    """Why pandas could not parse the file: the first over-long line if there is one."""
    try:
        ragged = _first_ragged_line(text, delimiter, width)
    except csv.Error:
        ragged = None
    return ragged or f"cannot be parsed as CSV ({error}); check quotes and delimiters"


def _read_csv(path: Path, data: bytes) -> _Table:
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise _not_utf8(path, error) from error
    delimiter, cells = _csv_header(path, text)
    trailing = len(cells) > 1 and not cells[-1].strip()  # "a,b," lines from some loggers
    names, units = _header_columns(cells[:-1] if trailing else cells, str(path), "column")
    frame = _csv_body(path, text, delimiter, len(cells))
    if trailing and not frame.iloc[:, -1].isna().all():
        raise RecordingError(
            f"column {len(cells)} holds values but has no name in the header; name it",
            str(path),
        )
    columns = {name: frame.iloc[:, j].to_numpy() for j, name in enumerate(names)}
    return _Table(columns, units, {}, _Rows("file line", 2), "column")


# -- Parquet -----------------------------------------------------------------------------------


def _json_metadata(raw: bytes | None, key: bytes, path: Path) -> dict[str, str]:
    if raw is None:
        return {}
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise RecordingError(
            f"schema metadata {key.decode()!r} is not valid JSON ({error}); rewrite the file",
            str(path),
        ) from error
    return _units_mapping(data, f"schema metadata {key.decode()!r}", str(path))


def _arrow_column(column: Any, name: str, path: Path) -> np.ndarray:
    """One Parquet column as numpy (nulls become NaN or None), shape (n,)."""
    import pyarrow as pa

    if pa.types.is_nested(column.type):
        raise RecordingError(
            f"holds values of type {column.type}; every column must hold plain numbers",
            str(path),
            name,
        )
    try:
        return column.to_numpy()
    except pa.ArrowException as error:
        raise RecordingError(
            f"holds values of type {column.type} that cannot be read as numbers ({error})",
            str(path),
            name,
        ) from error


def _read_parquet(path: Path, data: bytes) -> _Table:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(pa.BufferReader(data))
    except (pa.ArrowException, OSError, ValueError, TypeError) as error:
        raise RecordingError(
            f"is not a readable Parquet file ({error}); re-export it, e.g. with "
            "pandas.DataFrame.to_parquet",
            str(path),
        ) from error
    keep = [j for j, name in enumerate(table.column_names) if not _PANDAS_INDEX.match(name)]
    names, header_units = _header_columns(
        [table.column_names[j] for j in keep], str(path), "column"
    )
    metadata = table.schema.metadata or {}
    units = {**header_units, **_field_units(table.schema, keep, names)}
    units.update(_json_metadata(metadata.get(UNITS_KEY), UNITS_KEY, path))
    notes = _json_metadata(metadata.get(METADATA_KEY), METADATA_KEY, path)
    columns = {
        name: _arrow_column(table.column(j), name, path)
        for name, j in zip(names, keep, strict=True)
    }
    return _Table(columns, units, notes, None, "column")


def _field_units(schema: Any, keep: list[int], names: list[str]) -> dict[str, str]:
    """Per-field ``unit`` metadata, keyed by the (unit-stripped) column name."""
    units = {}
    for name, j in zip(names, keep, strict=True):
        unit = (schema.field(j).metadata or {}).get(b"unit")
        if unit is not None:
            units[name] = unit.decode("utf-8", errors="replace")
    return units


# -- MATLAB and MDF4: own modules, which return plain columns ---------------------------------


def _read_mat(path: Path, data: bytes) -> _Table:
    columns, notes = read_mat(path, data)
    return _Table(columns, {}, notes, _Rows("MATLAB index", 1), "variable")


def _read_mdf(path: Path, data: bytes) -> _Table:
    columns, units, notes = read_mdf(path, data)
    return _Table(columns, units, notes, None, "channel")


_READERS: dict[str, Callable[[Path, bytes], _Table]] = {
    ".csv": _read_csv,
    ".mat": _read_mat,
    ".mf4": _read_mdf,
    ".mdf": _read_mdf,
    ".parquet": _read_parquet,
}


def load_recording(
    path: str | os.PathLike[str],
    *,
    time_column: str = TIME,
    resample: float | None = None,
    units: Mapping[str, str] | None = None,
) -> Recording:
    """Load a recording from CSV, Parquet, MATLAB ``.mat`` (v4 to v7.3) or MDF (``.mf4``).

    The file is read once, so a named pipe or a stream works as a path.

    Parameters
    ----------
    path : str or path-like
        The file; its extension selects the format (see :data:`SUPPORTED_FORMATS`).
    time_column : str
        Name of the time column or variable. Its unit (``[ms]`` etc.) converts it to seconds.
    resample : float, optional
        If given, interpolate linearly onto a uniform grid with this step [s] from the first
        sample to the end of the recording; the time must still be strictly increasing.
    units : mapping of str to str, optional
        Units by column name; they override those from the file and its ``.units.json`` sidecar.

    Returns
    -------
    Recording

    Raises
    ------
    RecordingError
        For an unreadable file, an unsupported format, or any problem with its content; the
        message names the file, the column and the row, and how to mend it.
    """
    file = Path(path)
    reader = _READERS.get(file.suffix.lower())
    if reader is None:
        raise RecordingError(
            f"unsupported recording format {file.suffix or '(no extension)'!r}; supported: "
            f"{', '.join(SUPPORTED_FORMATS)}. Export the data to one of these",
            str(file),
        )
    table = reader(file, _read_bytes(file))
    sidecar = _read_sidecar(file)
    _check_unit_names(sidecar, table.columns, "the units file", str(_sidecar_path(file)))
    given = _units_mapping(units or {}, "the units argument", str(file))
    _check_unit_names(given, table.columns, "the units argument", str(file))
    table.units = {**table.units, **sidecar, **given}
    return _assemble(table, time_column=time_column, source=str(file), resample=resample)


# --------------------------------------------------------------------------------------------
# Saving
# --------------------------------------------------------------------------------------------


def _check_header_names(recording: Recording, path: Path) -> None:
    """Names that would read back differently (``"x [m]"``) cannot be written."""
    for name in recording.names:
        if _split_header(name) != (name, ""):
            raise RecordingError(
                "the name ends in '[...]', which would be read back as a unit; rename the "
                "signal and put its unit in Recording.units",
                str(path),
                name,
            )


def _write_csv(recording: Recording, path: Path) -> None:
    units = {TIME: "s", **recording.units}
    with (
        atomic_write(path, "w", newline="") as table,
        atomic_write(_sidecar_path(path), "w") as sidecar,
    ):
        recording.to_frame().to_csv(table, index=False, lineterminator="\n")
        json.dump(units, sidecar, indent=2, ensure_ascii=False)
        sidecar.write("\n")


def _write_parquet(recording: Recording, path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    units = {TIME: "s", **recording.units}
    columns = {TIME: recording.time, **recording.signals}
    fields = [
        pa.field(name, pa.float64(), nullable=False, metadata={b"unit": units[name].encode()})
        for name in columns
    ]
    schema = pa.schema(
        fields,
        metadata={
            UNITS_KEY: json.dumps(units, ensure_ascii=False).encode(),
            METADATA_KEY: json.dumps(recording.metadata, ensure_ascii=False).encode(),
        },
    )
    table = pa.Table.from_arrays([pa.array(v) for v in columns.values()], schema=schema)
    with atomic_write(path, "wb") as handle:
        pq.write_table(table, handle)


_WRITERS: dict[str, Callable[[Recording, Path], None]] = {
    ".csv": _write_csv,
    ".parquet": _write_parquet,
}


def save_recording(recording: Recording, path: str | os.PathLike[str]) -> Path:
    """Write a recording to ``.csv`` (with a ``.units.json`` sidecar) or ``.parquet``, atomically.

    CSV values are written with 17 significant digits at most (shortest exact repr), so both
    formats load back equal (``==``).

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    RecordingError
        For an unsupported extension, a name that cannot be written, or an OS error.
    """
    file = Path(path)
    writer = _WRITERS.get(file.suffix.lower())
    if writer is None:
        raise RecordingError(
            f"cannot save as {file.suffix or '(no extension)'!r}; supported: "
            f"{', '.join(SAVE_FORMATS)}",
            str(file),
        )
    _check_header_names(recording, file)
    try:
        writer(recording, file)
    except OSError as error:
        raise RecordingError(
            f"cannot write the file: {error.strerror or error}; check that the folder exists "
            "and is writable",
            str(file),
        ) from error
    return file
