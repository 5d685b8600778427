"""A recording seen through a project: stage targets, exogenous inputs, white-box predictions.

Training, validation and diagnosis all start from the same arrays; this module checks a
recording against the project and binds it to the FMU's inputs;
:func:`fmu_greybox.model.stage_data.prepare` makes the arrays once, running the white-box FMU
open-loop over the recorded inputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fmu_greybox.data.recording import Recording, load_recording
from fmu_greybox.errors import ConfigError, RecordingError
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.fmi.binding import InputBinding, bind_inputs
from fmu_greybox.fmi.builtin import resolve_fmu
from fmu_greybox.project.config import ProjectConfig


@dataclass
class ProjectData:
    """Arrays of one recording, arranged for the chain.

    Attributes
    ----------
    recording : Recording
        The recording.
    binding : InputBinding
        How the FMU's inputs are fed.
    exo : ndarray, shape (n, n_exo)
        Exogenous inputs (columns as ``chain.exo_names``).
    outputs : ndarray, shape (n, Q)
        Recorded stage targets.
    y_wb : ndarray, shape (n, Q)
        White-box predictions of the stage targets (with the named terms, if any).
    """

    recording: Recording
    binding: InputBinding
    exo: np.ndarray
    outputs: np.ndarray
    y_wb: np.ndarray

    @property
    def n_samples(self) -> int:
        """Number of rows."""
        return self.exo.shape[0]


def load_project_recording(config: ProjectConfig, override: str | Path | None = None) -> Recording:
    """The recording named on the command line, or else the project's default one, in the
    project's units.

    A column recorded in another unit than its signal's (``mm`` for ``m``, ``bar`` for ``Pa``)
    is converted, with a note in the log.

    Raises
    ------
    ConfigError
        If neither is given.
    UnitMismatchError
        If a column's unit cannot be converted to its signal's.
    """
    path = Path(override) if override is not None else config.recording
    if path is None:
        raise ConfigError(
            "no recording given; pass --recording FILE or set [recording] path",
            field="recording.path",
            path=str(config.path) if config.path else None,
        )
    recording = load_recording(path, time_column=config.time_column, resample=config.resample)
    return recording.converted({s.column: s.unit for s in config.signals.values()})


def check_sample_time(recording: Recording, step: float, owner: str) -> None:
    """A recording must be sampled at the step of what it drives.

    Parameters
    ----------
    recording : Recording
    step : float
        The communication step [s] it must match (to a relative 1e-6).
    owner : str
        Whose step it is, for the message (e.g. ``"the model (the step it was trained at)"``).

    Raises
    ------
    RecordingError
        With both steps and how to resample; a time column in milliseconds without a unit
        (a step of exactly 1000 times the expected one) is pointed out.
    """
    if math.isclose(recording.dt, step, rel_tol=1e-6):
        return
    hint = ""
    if math.isclose(recording.dt, 1000.0 * step, rel_tol=1e-3):
        hint = (
            " (is its time column in milliseconds? Give its unit, e.g. a header 'time [ms]', and"
            " it is converted to seconds)"
        )
    raise RecordingError(
        f"sampled every {recording.dt:g} s but {owner} runs at {step:g} s{hint}; resample the "
        f"recording onto {step:g} s (project file: resample = {step:g} under [recording])",
        path=recording.source,
    )


def check_step(config: ProjectConfig, recording: Recording) -> None:
    """The communication step must equal the recording's sample time when both are given."""
    if config.step is not None:
        check_sample_time(recording, config.step, "the project (whitebox.step)")


def check_fixed_inputs(config: ProjectConfig, recording: Recording) -> None:
    """An FMU input the project holds constant must not be recorded as well.

    Raises
    ------
    ConfigError
        Naming the ``[whitebox] fixed_inputs`` entry and the column: held constant, the
        recorded values would be silently ignored.
    """
    mapping = config.input_mapping()
    for name, value in config.fixed_inputs.items():
        column = mapping.get(name, name)
        if column in recording.signals:
            raise ConfigError(
                f"FMU input {name!r} is held constant at {value:g} but {recording.source} records "
                f"it (column {column!r}), and the recording would be ignored; remove {name!r} "
                "from [whitebox] fixed_inputs to use the recording, or drop the column from the "
                "recording to hold the input constant on purpose",
                field=f"whitebox.fixed_inputs.{name}",
                path=str(config.path) if config.path else None,
            )


def bind_project_inputs(
    config: ProjectConfig, archive: FmuArchive, recording: Recording
) -> InputBinding:
    """The FMU's inputs fed as the project says (its signals' columns, its constants).

    Raises
    ------
    ConfigError
        An input held constant is recorded as well (:func:`check_fixed_inputs`).
    RecordingError
        An input is neither recorded nor held constant; the message says which project fields
        mend it (not the ``simulate`` command's options).
    """
    check_fixed_inputs(config, recording)
    where = f"in {config.path}, " if config.path else ""
    remedy = (
        f"{where}give each a [signals.NAME] table whose variable is the input and whose column "
        "is the recorded one, or hold it constant in [whitebox] fixed_inputs"
    )
    return bind_inputs(
        archive, recording, config.input_mapping(), config.fixed_inputs, remedy=remedy
    )


def split_row(config: ProjectConfig, n: int) -> int:
    """Last training row: rows ``0..split`` train, ``split+1..n-1`` are held out."""
    return max(1, min(n - 2, int(config.train_fraction * n) - 1))


def whitebox_path(config: ProjectConfig) -> Path:
    """The white-box FMU file of a project (built-ins are built on first use)."""
    spec = config.fmu
    if not spec.startswith("builtin:"):
        spec = str(config.resolve_path(spec))
    return resolve_fmu(spec)
