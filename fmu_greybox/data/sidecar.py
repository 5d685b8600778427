"""The units file beside a recording, ``FILE.units.json`` (``{"signal": "unit"}``): read beside
a file of any format, written beside a CSV file (:mod:`fmu_greybox.data.csv`).
"""

from __future__ import annotations

import json
from pathlib import Path

from fmu_greybox.data.checks import units_mapping
from fmu_greybox.errors import RecordingError

SIDECAR_SUFFIX = ".units.json"


def sidecar_path(path: Path) -> Path:
    """``FILE.units.json`` beside ``FILE``."""
    return path.with_name(path.name + SIDECAR_SUFFIX)


def read_sidecar(path: Path) -> dict[str, str]:
    """Units from ``FILE.units.json`` beside the recording, or nothing if there is none."""
    sidecar = sidecar_path(path)
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
    return units_mapping(data, "the units file", str(sidecar))
