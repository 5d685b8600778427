"""The data file of a native grey-box FMU (``resources/greybox.dat``): its trained numbers.

Written here, read by ``fmu_greybox/native/greybox_data.c`` (which documents the layout):
little-endian, a magic, a format version, then named sections of int64, float64 or UTF-8 text.
The file's SHA-256 is compiled into the FMU's binary, which refuses a file that differs.
Plain data, never code, like the model folder it comes from.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping

import numpy as np

MAGIC = b"FGBXDATA"
#: ``DATA_VERSION`` of greybox_data.h.
DATA_VERSION = 1
NAME_SIZE = 24
_TYPES = {"int64": 1, "float64": 2, "text": 3}

Section = np.ndarray | str


def data_file_bytes(sections: Mapping[str, Section]) -> bytes:
    """The data file holding ``sections``, in their order.

    Parameters
    ----------
    sections : mapping of str to ndarray or str
        Section name (at most 24 ASCII characters) -> an int64 or float64 array (flattened) or
        text.

    Returns
    -------
    bytes

    Raises
    ------
    ValueError
        A name too long or not ASCII, or an array of another type.
    """
    parts = [MAGIC, struct.pack("<II", DATA_VERSION, len(sections))]
    for name, value in sections.items():
        key = name.encode("ascii")
        if len(key) > NAME_SIZE:
            raise ValueError(f"section name {name!r} is longer than {NAME_SIZE} characters")
        if isinstance(value, str):
            payload = value.encode("utf-8")
            kind, count = _TYPES["text"], len(payload)
            payload += b"\0" * (-len(payload) % 8)
        else:
            array = np.ascontiguousarray(value).ravel()
            if array.dtype.kind not in "if":
                raise ValueError(f"section {name!r}: {array.dtype} is neither int64 nor float64")
            dtype = "<i8" if array.dtype.kind == "i" else "<f8"
            kind, count = _TYPES["int64" if dtype == "<i8" else "float64"], array.size
            payload = array.astype(dtype).tobytes()
        parts.append(key.ljust(NAME_SIZE, b"\0") + struct.pack("<IIQ", kind, 0, count) + payload)
    return b"".join(parts)
