"""ASAM MDF recordings (``.mf4``, ``.mdf``), as bench loggers write them, through asammdf.

Every channel group's master channel is its time axis; the channels become signals with the
units the file declares. A recording has one time grid, so every group must share one time
base: a file logged at several rates is refused with the rates found (resample it onto one
raster first). See ``docs/recordings.md``.
"""

from __future__ import annotations

import gc
import io
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np

from fmu_greybox.errors import RecordingError

__all__ = ["read_mdf"]

#: How asammdf names the in-memory file it was given, in its messages.
_BUFFER = re.compile(r"'?<_io\.BytesIO object at 0x[0-9a-fA-F]+>'?")


def _ignore(unraisable: object) -> None:
    """Drop the complaint of asammdf's ``MDF4.__del__`` about a file it could not read."""


def read_mdf(
    path: Path, data: bytes
) -> tuple[dict[str, np.ndarray], dict[str, str], dict[str, str]]:
    """The channels of an MDF file on its one time base.

    Parameters
    ----------
    path : Path
        The file (named in errors).
    data : bytes
        Its content.

    Returns
    -------
    columns : dict of str to ndarray, each shape (n,)
        The master channel (the time, under its own name, e.g. ``"time"``) then every numeric
        channel.
    units : dict of str to str
        The units the file declares, by channel (the master's too).
    notes : dict of str to str
        ``ignored_channels``: channels that hold text or structures, not numbers.

    Raises
    ------
    RecordingError
        A file asammdf cannot read, a channel name in two groups, groups on different time
        bases, or no numeric channel.
    """
    from asammdf import MDF

    if not data.startswith(b"MDF"):
        raise RecordingError(
            "is not an MDF file (it does not start with 'MDF'); export it again from the logger",
            str(path),
        )
    failure = ""
    kept_hook = sys.unraisablehook
    sys.unraisablehook = _ignore  # asammdf's __del__ fails on a half-read file
    try:
        try:
            with MDF(io.BytesIO(data)) as mdf:
                return _channels(path, mdf)
        except RecordingError:
            raise
        except Exception as error:  # asammdf raises many types on damaged files
            failure = _BUFFER.sub("the file", f"{type(error).__name__}: {error}")
        gc.collect()  # the half-read file sits in a reference cycle: collect it here
    finally:
        sys.unraisablehook = kept_hook
    raise RecordingError(
        f"is not a readable MDF file ({failure}); export it again from the logger, or convert "
        "it to MDF 4 with asammdf",
        str(path),
    )


def _channels(path: Path, mdf: Any) -> tuple[dict[str, np.ndarray], dict[str, str], dict[str, str]]:
    columns: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    group_of: dict[str, int] = {}
    ignored: list[str] = []
    time: np.ndarray | None = None
    time_group = 0
    for g, group in enumerate(mdf.groups):
        master = mdf.masters_db.get(g)
        for c in range(len(group.channels)):
            if c == master:
                continue
            signal = mdf.get(group=g, index=c, raw=False)
            if signal.samples.ndim != 1 or signal.samples.dtype.kind not in "fiub":
                ignored.append(signal.name)
                continue
            if signal.name in group_of:
                raise RecordingError(
                    f"channel {signal.name!r} appears in channel groups {group_of[signal.name]} "
                    f"and {g}; rename one of them (or drop one) before loading",
                    str(path),
                )
            if time is None:
                time, time_group = signal.timestamps, g
                name = group.channels[master].name if master is not None else "time"
                columns[name] = time
                units[name] = mdf.get(group=g, index=master).unit if master is not None else "s"
            elif not np.array_equal(signal.timestamps, time):
                raise RecordingError(_rates_message(signal, time, time_group, g), str(path))
            group_of[signal.name] = g
            columns[signal.name] = signal.samples
            if signal.unit:
                units[signal.name] = signal.unit
    if time is None:
        raise RecordingError(
            "holds no numeric channel; a recording needs a time base and at least one signal",
            str(path),
        )
    notes = {"ignored_channels": ", ".join(ignored)} if ignored else {}
    return columns, units, notes


def _rates_message(signal: Any, time: np.ndarray, first: int, group: int) -> str:
    """Channel groups on different time bases: which, at which steps, and how to mend it."""

    def step(stamps: np.ndarray) -> str:
        return f"{float(np.median(np.diff(stamps))):.6g} s" if len(stamps) > 1 else "one sample"

    return (
        f"channel group {group} (channel {signal.name!r}) is sampled on another time base than "
        f"channel group {first}: {len(signal.timestamps)} samples every "
        f"{step(signal.timestamps)} against {len(time)} every {step(time)}; a recording has "
        "one time grid. Resample the file onto one raster first (asammdf: "
        "MDF.resample(raster=STEP)), or export the groups as separate files"
    )
