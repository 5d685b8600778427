"""CSV recordings: a header row naming the columns (units as ``name [unit]`` or in the
``FILE.units.json`` sidecar, :mod:`fmu_greybox.data.sidecar`), then one row of numbers per time
sample; comma, semicolon or tab delimited.
"""

from __future__ import annotations

import csv
import io
import json
import re
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pa_compute
import pyarrow.csv as pa_csv

from fmu_greybox.atomic import atomic_write
from fmu_greybox.data.checks import cell_value, header_columns
from fmu_greybox.data.sidecar import sidecar_path
from fmu_greybox.data.table import Rows, Table
from fmu_greybox.errors import RecordingError


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
    if all(cell.strip() and cell_value(cell) is not None for cell in cells):
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


def read_csv(path: Path, data: bytes) -> Table:
    """The columns of a CSV file's bytes ``data``, with the units of its header; a row is
    shown as its file line."""
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise _not_utf8(path, error) from error
    delimiter, cells = _csv_header(path, text)
    trailing = len(cells) > 1 and not cells[-1].strip()  # "a,b," lines from some loggers
    names, units = header_columns(cells[:-1] if trailing else cells, str(path), "column")
    frame = _csv_body(path, text, delimiter, len(cells))
    if trailing and not frame.iloc[:, -1].isna().all():
        raise RecordingError(
            f"column {len(cells)} holds values but has no name in the header; name it",
            str(path),
        )
    columns = {name: frame.iloc[:, j].to_numpy() for j, name in enumerate(names)}
    return Table(columns, units, {}, Rows("file line", 2), "column")


def _column(values: np.ndarray) -> pa.Array:
    """A float64 column as Arrow writes it; with its negative zeros, which Arrow writes ``-0``
    and pandas reads back as 0, as text: the numbers as Arrow's CSV writer formats them (its
    cast to string gives the same text), the negative zeros ``-0.0``."""
    column = pa.array(values)
    negative_zero = np.signbit(values) & (values == 0.0)
    if not negative_zero.any():
        return column
    return pa_compute.if_else(pa.array(negative_zero), "-0.0", pa_compute.cast(column, pa.string()))


def write_csv(columns: Mapping[str, np.ndarray], units: Mapping[str, str], path: Path) -> None:
    """Write ``columns`` (the time column then the signals, float64 arrays of one length n) to
    ``path`` and every column's unit to its sidecar, both atomically.

    The header is written as Python's :mod:`csv` quotes it; the numbers by Arrow's CSV writer,
    each the shortest text that reads back to the same float (``1e-7``, ``0``), about ten times
    faster than pandas's writer (``benchmarks/bench_csv.py``). A negative zero, which Arrow
    writes ``-0`` and pandas reads back as 0, is written ``-0.0`` (:func:`_column`).
    """
    header = io.StringIO()
    csv.writer(header, lineterminator="\n").writerow(columns)
    body = pa.Table.from_arrays(
        [_column(np.asarray(values, dtype=np.float64)) for values in columns.values()],
        names=[f"c{j}" for j in range(len(columns))],  # not written: the header above is
    )
    options = pa_csv.WriteOptions(include_header=False, quoting_style="none")  # numbers only
    with (
        atomic_write(path, "wb") as table,
        atomic_write(sidecar_path(path), "w") as sidecar,
    ):
        table.write(header.getvalue().encode("utf-8"))
        pa_csv.write_csv(body, table, options)
        json.dump(units, sidecar, indent=2, ensure_ascii=False)
        sidecar.write("\n")
