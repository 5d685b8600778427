"""Parquet recordings: units in the schema metadata (per field ``unit``, and the whole table's
``fmu_greybox.units``), notes in ``fmu_greybox.metadata``.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fmu_greybox.atomic import atomic_write
from fmu_greybox.data.checks import header_columns, units_mapping
from fmu_greybox.data.table import Table
from fmu_greybox.errors import RecordingError

UNITS_KEY = b"fmu_greybox.units"
METADATA_KEY = b"fmu_greybox.metadata"

_PANDAS_INDEX = re.compile(r"^__index_level_\d+__$")


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
    return units_mapping(data, f"schema metadata {key.decode()!r}", str(path))


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


def read_parquet(path: Path, data: bytes) -> Table:
    """The columns of a Parquet file's bytes ``data`` (a pandas index left out), with the
    units and notes of its schema."""
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
    names, header_units = header_columns([table.column_names[j] for j in keep], str(path), "column")
    metadata = table.schema.metadata or {}
    units = {**header_units, **_field_units(table.schema, keep, names)}
    units.update(_json_metadata(metadata.get(UNITS_KEY), UNITS_KEY, path))
    notes = _json_metadata(metadata.get(METADATA_KEY), METADATA_KEY, path)
    columns = {
        name: _arrow_column(table.column(j), name, path)
        for name, j in zip(names, keep, strict=True)
    }
    return Table(columns, units, notes, None, "column")


def _field_units(schema: Any, keep: list[int], names: list[str]) -> dict[str, str]:
    """Per-field ``unit`` metadata, keyed by the (unit-stripped) column name."""
    units = {}
    for name, j in zip(names, keep, strict=True):
        unit = (schema.field(j).metadata or {}).get(b"unit")
        if unit is not None:
            units[name] = unit.decode("utf-8", errors="replace")
    return units


def write_parquet(
    columns: Mapping[str, np.ndarray],
    units: Mapping[str, str],
    metadata: Mapping[str, str],
    path: Path,
) -> None:
    """Write ``columns`` (time first, each shape (n,)) as float64 fields with their ``units``
    and the recording's ``metadata`` in the schema, atomically."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    fields = [
        pa.field(name, pa.float64(), nullable=False, metadata={b"unit": units[name].encode()})
        for name in columns
    ]
    schema = pa.schema(
        fields,
        metadata={
            UNITS_KEY: json.dumps(units, ensure_ascii=False).encode(),
            METADATA_KEY: json.dumps(metadata, ensure_ascii=False).encode(),
        },
    )
    table = pa.Table.from_arrays([pa.array(v) for v in columns.values()], schema=schema)
    with atomic_write(path, "wb") as handle:
        pq.write_table(table, handle)
