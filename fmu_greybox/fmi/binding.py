"""Bind recorded signals to an FMU's inputs and outputs.

By default a recorded column feeds the FMU input of the same name. A mapping renames
(``{"valve_current": "ehv_cmd_mA"}``) and fixed values stand in for inputs that were not
recorded. Units declared by the recording are checked against the units the FMU declares.
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from fmu_greybox.data.recording import Recording, units_compatible
from fmu_greybox.errors import ConfigError, RecordingError, UnitMismatchError
from fmu_greybox.fmi.archive import FmuArchive


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
        FMU input name -> constant value, for inputs not recorded.

    Returns
    -------
    InputBinding

    Raises
    ------
    RecordingError
        If an FMU input has no column and no constant (the message names the closest columns
        and the options that mend it), or a mapped column is missing.
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
        raise RecordingError(_missing_message(missing, mapping, recording), path=recording.source)
    for name, column in columns.items():
        check_unit(archive, name, recording, column)
    return InputBinding(inputs=inputs, columns=columns, fixed=fixed)


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


def _missing_message(missing: list[str], mapping: Mapping[str, str], recording: Recording) -> str:
    parts = []
    for name in missing:
        column = mapping.get(name, name)
        close = difflib.get_close_matches(column, recording.names, n=3, cutoff=0.5)
        hint = f" (closest: {', '.join(map(repr, close))})" if close else ""
        parts.append(f"{name!r} needs column {column!r}{hint}")
    return (
        "the FMU's inputs are not all recorded: "
        + "; ".join(parts)
        + ". Map them to recorded columns (--map INPUT=COLUMN) or hold them constant "
        "(--fix INPUT=VALUE)"
    )
