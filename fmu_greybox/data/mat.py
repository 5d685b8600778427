"""MATLAB ``.mat`` recordings: v4 to v7 through scipy, v7.3 (HDF5) through h5py.

Variables are signals (one vector each, one of them the time), or the fields of a file's only
variable when that is a struct. scipy's compiled v5 reader trusts the element type codes and can
crash the interpreter on a damaged file, so a pure-Python walk over every v5 data element
(:func:`_scan_mat5`) runs first and turns such damage into an error; everything else (v4, the
values themselves) is left to scipy. See ``docs/recordings.md``.
"""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fmu_greybox.errors import RecordingError

__all__ = ["read_mat"]

_MI_INT32, _MI_UINT32, _MI_MATRIX, _MI_COMPRESSED = 5, 6, 14, 15
_MX_OPAQUE = 17
_MAT5_ELEMENT_TYPES = frozenset({1, 2, 3, 4, 5, 6, 7, 9, 12, 13, 14, 16, 17, 18})
# data parts after flags, dims and name (plus one if complex), by array class:
# char 4, sparse 5 (row indices, column pointers, values), double 6 ... uint64 15
_MAT5_DATA_PARTS = {4: 1, 5: 3, **dict.fromkeys(range(6, 16), 1)}
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
#: Groups MATLAB keeps at the root of a v7.3 file for its own bookkeeping.
_MATLAB_INTERNAL = ("#refs#", "#subsystem#")


def read_mat(path: Path, data: bytes) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """The signal vectors of a MATLAB file and notes on what was left out.

    Parameters
    ----------
    path : Path
        The file (named in errors).
    data : bytes
        Its content.

    Returns
    -------
    columns : dict of str to ndarray, each shape (n,)
        Variables (or the fields of a lone struct) that are numeric vectors.
    notes : dict of str to str
        ``struct`` (the struct read), ``ignored_variables`` (what is not a vector).

    Raises
    ------
    RecordingError
        A damaged file, or one with several structs and no vectors (which struct holds the
        signals cannot be told).
    """
    top = _read_hdf5(path, data) if _is_hdf5(data) else _read_mat5(path, data)
    return _signals(path, top)


def _is_hdf5(data: bytes) -> bool:
    return data[:8] == _HDF5_SIGNATURE or data[512:520] == _HDF5_SIGNATURE


def _read_mat5(path: Path, data: bytes) -> dict[str, Any]:
    """Top-level variables of a v4-v7 file; a scalar struct becomes a dict of its fields."""
    from scipy.io import loadmat

    try:
        if data[126:128] in (b"IM", b"MI"):
            _scan_mat5(data)
        content = loadmat(io.BytesIO(data), squeeze_me=False, struct_as_record=True)
    except Exception as error:  # scipy raises many types on damaged files
        raise RecordingError(
            f"is not a readable MATLAB file ({type(error).__name__}: {error}); save it from "
            "MATLAB with save(FILE, ..., '-v7') or save(FILE, ..., '-v7.3')",
            str(path),
        ) from error
    top: dict[str, Any] = {}
    for name, value in content.items():
        if name.startswith("__"):
            continue
        if isinstance(value, np.ndarray) and value.dtype.names and value.size == 1:
            record = value.reshape(-1)[0]
            value = {field: record[field] for field in value.dtype.names}
        top[name] = value
    return top


def _read_hdf5(path: Path, data: bytes) -> dict[str, Any]:
    """Top-level variables of a v7.3 (HDF5) file; a struct becomes a dict of its fields.

    MATLAB writes arrays column-major, so an n-by-1 vector is a (1, n) dataset: both
    orientations are vectors to :func:`_mat_vector`.
    """
    import h5py

    try:
        with h5py.File(io.BytesIO(data), "r") as handle:
            return {
                name: _hdf5_value(item)
                for name, item in handle.items()
                if name not in _MATLAB_INTERNAL
            }
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise RecordingError(
            f"is not a readable MATLAB v7.3 (HDF5) file ({type(error).__name__}: {error}); "
            "save it again from MATLAB, or export it to CSV or Parquet",
            str(path),
        ) from error


def _hdf5_value(item: Any) -> Any:
    """A dataset as an array (``None`` for text and cells), a group as a dict of its fields."""
    import h5py

    kind = item.attrs.get("MATLAB_class", b"double")
    kind = kind.decode() if isinstance(kind, bytes) else str(kind)
    if isinstance(item, h5py.Group):
        return {name: _hdf5_value(child) for name, child in item.items()}
    if kind in ("char", "cell") or item.attrs.get("MATLAB_empty", 0):
        return None
    return item[()]


def _signals(path: Path, top: Mapping[str, Any]) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Vectors among the top-level variables, or among the fields of a lone struct."""
    notes: dict[str, str] = {}
    variables = dict(top)
    structs = [name for name, value in top.items() if isinstance(value, dict)]
    if len(top) == 1 and structs:
        notes["struct"] = structs[0]
        variables = dict(top[structs[0]])
    columns: dict[str, np.ndarray] = {}
    ignored = []
    for name, value in variables.items():
        vector = _mat_vector(value)
        if vector is None:
            ignored.append(name)
        else:
            columns[name] = vector
    if not columns and structs:
        shown = ", ".join(repr(s) for s in structs)
        raise RecordingError(
            f"holds {len(structs)} structs ({shown}) and no signal vector at its top level; "
            "signals are read from top-level variables, or from the fields of a struct that "
            "is the file's only variable. Save one struct per file (in MATLAB: "
            f"save(FILE, '-struct', {structs[0]!r}) saves its fields as variables)",
            str(path),
        )
    if ignored:
        notes["ignored_variables"] = ", ".join(ignored)
    return columns, notes


def _mat_vector(value: Any) -> np.ndarray | None:
    """A numeric vector (n,), (n, 1) or (1, n) with n >= 2 as shape (n,); else ``None``."""
    if not isinstance(value, np.ndarray) or value.dtype.kind not in "fiubc":
        return None
    if value.size < 2 or value.ndim > 2 or (value.ndim == 2 and min(value.shape) != 1):
        return None
    return value.reshape(-1)


def _mat_tag(data: bytes, pos: int, end: int, order: str) -> tuple[int, int, int, int]:
    """Decode a v5 data-element tag at ``pos``: (type, size, body start, next element start)."""
    if pos + 8 > end:
        raise ValueError(f"truncated element tag at byte {pos}")
    first, second = struct.unpack_from(order + "II", data, pos)
    if first >> 16:  # small data element: type and size share one word, data in the next
        return first & 0xFFFF, first >> 16, pos + 4, pos + 8
    body = pos + 8
    if body + second > end:
        raise ValueError(f"element at byte {pos} runs past the end of its container")
    return first, second, body, body + second + (-second % 8)


def _mat5_elements(data: bytes, pos: int, end: int, order: str) -> list[tuple[int, int, int]]:
    """The (type, size, body start) of the elements that exactly fill ``data[pos:end]``."""
    elements = []
    while pos < end:
        kind, size, body, pos = _mat_tag(data, pos, end, order)
        if kind not in _MAT5_ELEMENT_TYPES:
            raise ValueError(f"unknown data type {kind} at byte {body - 8}")
        elements.append((kind, size, body))
    if pos != end:
        raise ValueError(f"element sizes do not add up to their container ending at byte {end}")
    return elements


def _scan_mat5_matrix(data: bytes, pos: int, end: int, order: str) -> None:
    """Check one miMATRIX body, recursing into cells, structs and objects.

    scipy reads the parts of an array one after the other without checking the array's own
    size, so a numeric, char or sparse array must hold exactly its header (flags, dims, name)
    and its data parts, none of them a nested array.
    """
    elements = _mat5_elements(data, pos, end, order)
    if not elements:
        return  # an empty array
    kind, size, body = elements[0]
    if kind != _MI_UINT32 or size < 8:
        raise ValueError(f"array flags missing at byte {body - 8}")
    flags = struct.unpack_from(order + "I", data, body)[0]
    array_class, is_complex = flags & 0xFF, bool(flags & 0x800)
    if array_class != _MX_OPAQUE:
        kind, size, body = elements[1] if len(elements) > 1 else (0, 0, end + 8)
        if kind not in (_MI_INT32, _MI_UINT32) or size < 8 or size % 4:
            raise ValueError(f"array dimensions missing at byte {body - 8}")
    parts = _MAT5_DATA_PARTS.get(array_class)
    if parts is not None:
        expected = 3 + parts + (1 if is_complex else 0)
        if len(elements) != expected or any(k == _MI_MATRIX for k, _, _ in elements):
            raise ValueError(f"array at byte {pos - 8} does not have {expected} parts")
        return
    for kind, size, body in elements[1:]:
        if kind == _MI_MATRIX:
            _scan_mat5_matrix(data, body, body + size, order)


def _scan_mat5(data: bytes) -> None:
    """Walk every data element of a v5/v7 MAT file before scipy reads it.

    scipy's compiled reader trusts the element type codes and can crash the interpreter on a
    damaged file (it indexes a table with them); this pure-Python walk raises ``ValueError``
    instead.
    """
    order = "<" if data[126:128] == b"IM" else ">"
    pos = 128
    while pos < len(data):
        kind, size, body, _ = _mat_tag(data, pos, len(data), order)
        pos = body + size
        if kind == _MI_COMPRESSED:
            try:
                inner = zlib.decompress(data[body:pos])
            except zlib.error as error:
                raise ValueError(f"damaged compressed element at byte {body - 8}") from error
            kind, size, body, _ = _mat_tag(inner, 0, len(inner), order)
            if kind != _MI_MATRIX:
                raise ValueError(f"compressed element at byte {body - 8} holds no array")
            _scan_mat5_matrix(inner, body, body + size, order)
        elif kind == _MI_MATRIX:
            _scan_mat5_matrix(data, body, pos, order)
        else:
            raise ValueError(f"unexpected data type {kind} at byte {body - 8}")
