"""Recordings of a real or simulated component: load, check, slice, save.

A :class:`Recording` is a set of named signals sampled on one uniform time grid, each with a unit.
It is the input to simulation, training and diagnosis, so it is checked once, on construction,
and every problem is reported as a :class:`~fmu_greybox.errors.RecordingError` naming the file,
the column and the row, with a way to mend it.

Formats, one module each, chosen by the file's suffix: CSV (header row; units from
``name [unit]`` headers or a ``FILE.units.json`` sidecar; :mod:`fmu_greybox.data.csv`), Parquet
(units in the schema metadata; :mod:`fmu_greybox.data.parquet`), MATLAB ``.mat`` v4 to v7.3
(variables as signals; :mod:`fmu_greybox.data.mat`) and ASAM MDF (channels with their units;
:mod:`fmu_greybox.data.mdf`). The checks of names, cells, columns and time are
:mod:`fmu_greybox.data.checks`, shared by the constructor and the readers. Units other than the
ones wanted are converted by :meth:`Recording.converted`. See ``docs/recordings.md``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from fmu_greybox.data.checks import (
    TIME,
    UNIFORM_RTOL,
    check_names,
    check_samples,
    check_uniform,
    check_unit_names,
    float_column,
    listing,
    not_found,
    split_header,
    time_seconds,
    units_mapping,
)
from fmu_greybox.data.csv import read_csv, write_csv
from fmu_greybox.data.mat import read_mat
from fmu_greybox.data.mdf import read_mdf
from fmu_greybox.data.parquet import UNITS_KEY, read_parquet, write_parquet
from fmu_greybox.data.sidecar import read_sidecar, sidecar_path
from fmu_greybox.data.table import Rows, Table
from fmu_greybox.errors import RecordingError, UnitMismatchError
from fmu_greybox.suggest import did_you_mean
from fmu_greybox.units import UnitSyntaxError, conversion, normalise_unit, units_compatible

__all__ = [
    "SAVE_FORMATS",
    "SUPPORTED_FORMATS",
    "TIME",
    "UNIFORM_RTOL",
    "UNITS_KEY",
    "Recording",
    "load_recording",
    "normalise_unit",
    "save_recording",
    "units_compatible",
]

SUPPORTED_FORMATS = (".csv", ".mat", ".mdf", ".mf4", ".parquet")
SAVE_FORMATS = (".csv", ".parquet")

_MAX_UPSAMPLING = 100
_TIME_NAMES = {"t", "tout", "time_s", "timestamp", "times", "zeit", "temps"}
_TIME_COLUMN_HINT = "time_column='NAME' (project file: time_column under [recording])"
_log = logging.getLogger(__name__)


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
        check_names(self.signals, path)
        time = float_column(self.time, TIME, path, None)
        signals = {n: float_column(v, n, path, None) for n, v in self.signals.items()}
        check_samples(time, signals, TIME, path, None)
        check_uniform(time, TIME, path, None)
        given = units_mapping(self.units, "units", path)
        check_unit_names(given, signals, "units", path)
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
            message = not_found(missing, list(self.signals), "column", context)
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
        attrs = units_mapping(frame.attrs.get("units", {}), 'frame.attrs["units"]', path)
        given = units_mapping(units or {}, "units", path)
        check_unit_names(given, columns, "units", path)
        given = {**{n: u for n, u in attrs.items() if n in columns}, **given}
        table = Table(columns, given, dict(metadata or {}), None, "column")
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


def _missing_time(table: Table, time_column: str) -> str:
    kind = table.kind
    found = list(table.columns)
    likely = [name for name in found if name.lower() in _TIME_NAMES]
    return (
        f"no time {kind} {time_column!r}{did_you_mean(time_column, found, likely)} ({kind}s found: "
        f"{listing(found)}). Name the time {kind} with {_TIME_COLUMN_HINT}"
    )


def _assemble(table: Table, *, time_column: str, source: str, resample: float | None) -> Recording:
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
    check_names(raw, path)
    time_unit = table.units.get(time_column, "")
    time, notes = time_seconds(table.columns[time_column], time_column, time_unit, path, table.rows)
    signals = {n: float_column(v, n, path, table.rows) for n, v in raw.items()}
    check_samples(time, signals, time_column, path, table.rows)
    if resample is None:
        check_uniform(time, time_column, path, table.rows)
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


# -- MATLAB and MDF4: own modules, which return plain columns ---------------------------------


def _read_mat(path: Path, data: bytes) -> Table:
    columns, notes = read_mat(path, data)
    return Table(columns, {}, notes, Rows("MATLAB index", 1), "variable")


def _read_mdf(path: Path, data: bytes) -> Table:
    columns, units, notes = read_mdf(path, data)
    return Table(columns, units, notes, None, "channel")


_READERS: dict[str, Callable[[Path, bytes], Table]] = {
    ".csv": read_csv,
    ".mat": _read_mat,
    ".mf4": _read_mdf,
    ".mdf": _read_mdf,
    ".parquet": read_parquet,
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
    sidecar = read_sidecar(file)
    check_unit_names(sidecar, table.columns, "the units file", str(sidecar_path(file)))
    given = units_mapping(units or {}, "the units argument", str(file))
    check_unit_names(given, table.columns, "the units argument", str(file))
    table.units = {**table.units, **sidecar, **given}
    return _assemble(table, time_column=time_column, source=str(file), resample=resample)


# --------------------------------------------------------------------------------------------
# Saving
# --------------------------------------------------------------------------------------------


def _check_header_names(recording: Recording, path: Path) -> None:
    """Names that would read back differently (``"x [m]"``) cannot be written."""
    for name in recording.names:
        if split_header(name) != (name, ""):
            raise RecordingError(
                "the name ends in '[...]', which would be read back as a unit; rename the "
                "signal and put its unit in Recording.units",
                str(path),
                name,
            )


def _write_csv(recording: Recording, path: Path) -> None:
    write_csv({TIME: recording.time, **recording.signals}, {TIME: "s", **recording.units}, path)


def _write_parquet(recording: Recording, path: Path) -> None:
    columns = {TIME: recording.time, **recording.signals}
    write_parquet(columns, {TIME: "s", **recording.units}, recording.metadata, path)


_WRITERS: dict[str, Callable[[Recording, Path], None]] = {
    ".csv": _write_csv,
    ".parquet": _write_parquet,
}


def save_recording(recording: Recording, path: str | os.PathLike[str]) -> Path:
    """Write a recording to ``.csv`` (with a ``.units.json`` sidecar) or ``.parquet``, atomically.

    CSV values are written as the shortest text that reads back to the same float (17
    significant digits at most), so both formats load back equal, bit for bit.

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
