"""Bind recorded signals to an FMU's inputs and outputs.

By default a recorded column feeds the FMU input of the same name. A mapping renames
(``{"valve_current": "ehv_cmd_mA"}``) and fixed values stand in for inputs that were not
recorded. Units declared by the recording are checked against the units the FMU declares.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from fmu_greybox.data.recording import Recording
from fmu_greybox.errors import ConfigError, RecordingError, UnitMismatchError
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.suggest import did_you_mean
from fmu_greybox.units import UnitSyntaxError, conversion, units_compatible

#: How to mend an unfed input or a conflict on the ``simulate`` command line.
COMMAND_LINE_REMEDY = (
    "map the input to a recorded column (--map INPUT=COLUMN) or hold it constant "
    "(--fix INPUT=VALUE)"
)


@dataclass(frozen=True)
class InputBinding:
    """Where each FMU input's values come from.

    Attributes
    ----------
    inputs : list of str
        FMU input names, in FMU declaration order.
    columns : dict[str, str]
        FMU input -> recorded column, for recorded inputs.
    fixed : dict[str, float]
        FMU input -> constant value, for inputs held constant.
    """

    inputs: list[str]
    columns: dict[str, str]
    fixed: dict[str, float]

    def matrix(self, recording: Recording) -> np.ndarray:
        """Input values over the recording.

        Returns
        -------
        ndarray, shape (n_samples, n_inputs)
            Column ``j`` holds the values of ``inputs[j]``.
        """
        u = np.empty((recording.n_samples, len(self.inputs)))
        for j, name in enumerate(self.inputs):
            if name in self.columns:
                u[:, j] = recording[self.columns[name]]
            else:
                u[:, j] = self.fixed[name]
        return u


def bind_inputs(
    archive: FmuArchive,
    recording: Recording,
    mapping: Mapping[str, str] | None = None,
    fixed: Mapping[str, float] | None = None,
    remedy: str = COMMAND_LINE_REMEDY,
) -> InputBinding:
    """Decide, for every Real input of the FMU, which recorded column or constant feeds it.

    Parameters
    ----------
    archive : FmuArchive
        The FMU.
    recording : Recording
        The recording whose signals drive it.
    mapping : mapping of str to str, optional
        FMU input name -> recorded column name, where they differ.
    fixed : mapping of str to float, optional
        FMU input name -> constant value, for inputs not recorded (a recorded column of an
        input held constant is not used: the ``simulate`` command's explicit override; a
        project refuses the conflict, see :func:`fmu_greybox.project.data.prepare`).
    remedy : str
        How the caller's user maps an input or holds it constant (command-line options by
        default; a project names its fields), ending the message of an unfed input.

    Returns
    -------
    InputBinding

    Raises
    ------
    RecordingError
        If an FMU input has no column and no constant (the message names the closest columns
        of a compatible unit and how to mend it), or a mapped column is missing.
    UnitMismatchError
        If a recorded column declares a unit different from the FMU input's unit.
    ConfigError
        If ``mapping`` or ``fixed`` name something that is not an FMU input.
    """
    mapping = dict(mapping or {})
    fixed = {k: float(v) for k, v in (fixed or {}).items()}
    inputs = [v.name for v in archive.variables.values() if v.causality == "input"]
    for name in [*mapping, *fixed]:
        if name not in inputs:
            raise ConfigError(
                f"{name!r} is not an input of {archive.path.name}; its inputs are "
                f"{', '.join(inputs)}"
            )
    columns: dict[str, str] = {}
    missing: list[str] = []
    for name in inputs:
        if name in fixed:
            continue
        column = mapping.get(name, name)
        if column in recording.signals:
            columns[name] = column
        else:
            missing.append(name)
    if missing:
        message = _missing_message(archive, missing, mapping, recording, remedy)
        raise RecordingError(message, path=recording.source)
    for name, column in columns.items():
        check_unit(archive, name, recording, column)
    return InputBinding(inputs=inputs, columns=columns, fixed=fixed)


def input_units(archive: FmuArchive, mapping: Mapping[str, str] | None = None) -> dict[str, str]:
    """Column -> unit of the FMU input it feeds by name or through ``mapping``.

    What :meth:`Recording.converted <fmu_greybox.data.recording.Recording.converted>` needs to
    bring a recording into the FMU's units before :func:`bind_inputs`; inputs without a
    declared unit are left out.
    """
    mapping = mapping or {}
    return {
        mapping.get(v.name, v.name): v.unit
        for v in archive.variables.values()
        if v.causality == "input" and v.unit
    }


def check_unit(archive: FmuArchive, variable: str, recording: Recording, column: str) -> None:
    """Raise :class:`UnitMismatchError` if ``column``'s unit differs from ``variable``'s.

    An undeclared unit on either side is accepted.
    """
    declared = archive.variable(variable).unit
    recorded = recording.units.get(column, "")
    if declared and recorded and not units_compatible(declared, recorded):
        raise UnitMismatchError(
            f"recorded column {column!r} is in {recorded!r} but FMU variable {variable!r} of "
            f"{archive.path.name} is in {declared!r}; convert the column or fix its unit",
            path=recording.source,
        )


def _missing_message(
    archive: FmuArchive,
    missing: list[str],
    mapping: Mapping[str, str],
    recording: Recording,
    remedy: str,
) -> str:
    """Which inputs lack a column, each with the closest recorded columns of a fitting unit."""
    parts = []
    for name in missing:
        column = mapping.get(name, name)
        unit = archive.variable(name).unit
        fitting = [c for c in recording.names if _convertible(recording.units[c], unit)]
        parts.append(f"{name!r} needs column {column!r}{did_you_mean(column, fitting)}")
    return f"the FMU's inputs are not all recorded: {'; '.join(parts)}. To mend it, {remedy}"


def _convertible(recorded: str, declared: str) -> bool:
    """Whether a column in unit ``recorded`` may feed a variable in unit ``declared`` (an
    undeclared unit on either side may)."""
    if not recorded or not declared:
        return True
    try:
        conversion(recorded, declared)
    except UnitSyntaxError:
        return False
    return True
