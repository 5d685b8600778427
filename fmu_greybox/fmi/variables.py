"""The variable table of a model folder, ``variables.toml``: read and checked into a
:class:`VariableTable` (the models it describes, their variables in value-reference order, the
continuous states a model-exchange build declares), and the value references past the table's
that the FMI 3.0 ``time`` and a model-exchange build's states take.

:mod:`fmu_greybox.fmi.description` writes the model descriptions from it and
:mod:`fmu_greybox.fmi.build` the C tables, the binary and the FMU.
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fmu_greybox.errors import FmuBuildError
from fmu_greybox.units import PREFIXES, SYMBOLS, UnitSyntaxError, si_unit

_CAUSALITIES = ("input", "output", "parameter")
_VARIABILITIES = ("continuous", "discrete", "fixed", "tunable")
TYPES = ("Real", "Integer", "Boolean", "String")
"""The FMI 2.0 base types a variable may have."""
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


@dataclass(frozen=True)
class Variable:
    """One row of the variable table.

    Attributes
    ----------
    name : str
        Variable name (a C identifier).
    value_reference : int
        Position in the table (0-based), the same in every model of the table.
    causality, variability, type : str
        FMI 2.0 causality, variability and base type.
    unit : str or None
        Unit of a Real variable, e.g. ``"m3/(s.Pa)"`` (``""``: none declared).
    description : str
        What the variable is.
    start : float, int, bool, str or None
        Start value (inputs and parameters).
    min, max : float or None
        Declared range.
    dependencies : tuple of str or None
        Inputs an output depends on directly (``None``: all).
    models : tuple of str or None
        Model identifiers having the variable (``None``: all models of the table).
    """

    name: str
    value_reference: int
    causality: str
    variability: str
    type: str
    unit: str | None
    description: str
    start: float | int | bool | str | None
    min: float | None
    max: float | None
    dependencies: tuple[str, ...] | None
    models: tuple[str, ...] | None

    def in_model(self, identifier: str) -> bool:
        """Whether the model ``identifier`` has this variable."""
        return self.models is None or identifier in self.models


@dataclass(frozen=True)
class State:
    """One continuous state of a model (a ``[[state]]`` row of the table), in the order of the
    model's ``config.h``; a model-exchange build declares it and its derivative ``der(NAME)``.

    Attributes
    ----------
    name, unit, derivative_unit, description : str
    """

    name: str
    unit: str
    derivative_unit: str
    description: str


@dataclass(frozen=True)
class ModelEntry:
    """One model built from a table: identifier, description, preprocessor defines."""

    identifier: str
    description: str
    defines: tuple[str, ...]


@dataclass(frozen=True)
class VariableTable:
    """A parsed ``variables.toml``.

    Attributes
    ----------
    path : Path
        The table file.
    model_name : str
        ``modelName`` of the model descriptions.
    description : str
        Common description.
    default_experiment : dict of str to float
        ``start_time``, ``stop_time``, ``step_size`` (each optional).
    models : tuple of ModelEntry
        The models the table describes; the first is the default.
    variables : tuple of Variable
        All variables in value-reference order.
    states : tuple of State
        The continuous states (needed by model-exchange builds only).
    """

    path: Path
    model_name: str
    description: str
    default_experiment: dict[str, float]
    models: tuple[ModelEntry, ...]
    variables: tuple[Variable, ...]
    states: tuple[State, ...] = ()

    def model(self, identifier: str | None) -> ModelEntry:
        """The model entry ``identifier`` (the first one if ``None``).

        Raises
        ------
        FmuBuildError
            If the table has no such model.
        """
        if identifier is None:
            return self.models[0]
        for entry in self.models:
            if entry.identifier == identifier:
                return entry
        known = ", ".join(m.identifier for m in self.models)
        raise FmuBuildError(f"{self.path}: no model {identifier!r} in the table (it has {known}).")

    def variables_of(self, identifier: str) -> list[Variable]:
        """The variables of model ``identifier`` in value-reference order."""
        return [v for v in self.variables if v.in_model(identifier)]


def _table_error(path: Path, where: str, message: str) -> FmuBuildError:
    return FmuBuildError(f"{path}: {where}: {message}")


def _parse_variable(path: Path, index: int, raw: dict[str, Any], identifiers: set[str]) -> Variable:
    where = f"variable #{index} ({raw.get('name', '?')!r})"
    known_keys = {
        "name",
        "causality",
        "variability",
        "type",
        "unit",
        "description",
        "start",
        "min",
        "max",
        "dependencies",
        "models",
    }
    unknown = set(raw) - known_keys
    if unknown:
        raise _table_error(
            path, where, f"unknown keys {sorted(unknown)}; allowed: {sorted(known_keys)}."
        )
    name = raw.get("name")
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise _table_error(path, where, "name must be a C identifier (letters, digits, _).")
    causality = raw.get("causality")
    variability = raw.get("variability")
    vtype = raw.get("type", "Real")
    if causality not in _CAUSALITIES:
        raise _table_error(path, where, f"causality must be one of {_CAUSALITIES}.")
    if variability not in _VARIABILITIES:
        raise _table_error(path, where, f"variability must be one of {_VARIABILITIES}.")
    if vtype not in TYPES:
        raise _table_error(path, where, f"type must be one of {TYPES}.")
    legal = {
        "input": {"continuous", "discrete"},
        "output": {"continuous", "discrete"},
        "parameter": {"fixed", "tunable"},
    }[causality]
    if variability not in legal:
        raise _table_error(path, where, f"a {causality} must have variability in {sorted(legal)}.")
    if vtype != "Real" and variability == "continuous":
        raise _table_error(path, where, f"a {vtype} variable cannot be continuous.")
    description = raw.get("description")
    if not isinstance(description, str) or not description.strip():
        raise _table_error(path, where, "description is required.")
    unit = raw.get("unit")
    if vtype == "Real":
        if not isinstance(unit, str):
            raise _table_error(
                path,
                where,
                'unit is required for Real variables ("1" if dimensionless; "" declares none, '
                "as some third-party FMUs do).",
            )
        if unit:
            parse_unit(unit, path, where)
    elif unit is not None:
        raise _table_error(path, where, "only Real variables have a unit.")
    start = raw.get("start")
    if causality in ("input", "parameter"):
        if start is None:
            raise _table_error(path, where, f"a {causality} needs a start value.")
        start = _check_start(path, where, vtype, start)
    elif start is not None:
        raise _table_error(path, where, f"a {causality} has no start value (it is calculated).")
    bounds = []
    for key in ("min", "max"):
        value = raw.get(key)
        if value is not None and (vtype != "Real" or not isinstance(value, int | float)):
            raise _table_error(path, where, f"{key} must be a number of a Real variable.")
        bounds.append(None if value is None else float(value))
    low, high = bounds
    if start is not None and vtype == "Real":
        if (low is not None and start < low) or (high is not None and start > high):
            raise _table_error(path, where, f"start {start} lies outside [min, max].")
    dependencies = raw.get("dependencies")
    if dependencies is not None:
        if causality != "output" or not isinstance(dependencies, list):
            raise _table_error(path, where, "dependencies is a list, for outputs only.")
        dependencies = tuple(dependencies)
    models = raw.get("models")
    if models is not None:
        if not isinstance(models, list) or not set(models) <= identifiers or not models:
            raise _table_error(
                path, where, f"models must be a non-empty list out of {sorted(identifiers)}."
            )
        models = tuple(models)
    return Variable(
        name=name,
        value_reference=index,
        causality=causality,
        variability=variability,
        type=vtype,
        unit=unit,
        description=description,
        start=start,
        min=low,
        max=high,
        dependencies=dependencies,
        models=models,
    )


def _parse_states(path: Path, raw: list[Any], names: set[str]) -> tuple[State, ...]:
    """The ``[[state]]`` rows of a table: names unique (and no variable's), units valid."""
    states = []
    for index, row in enumerate(raw):
        where = f"state #{index} ({row.get('name', '?') if isinstance(row, dict) else '?'!r})"
        keys = {"name", "unit", "derivative_unit", "description"}
        if not isinstance(row, dict) or set(row) != keys:
            raise _table_error(path, where, f"a state has exactly the keys {sorted(keys)}.")
        if not all(isinstance(row[k], str) for k in keys):
            raise _table_error(path, where, "each key of a state is a string.")
        if not _NAME.fullmatch(row["name"]) or row["name"] in names:
            raise _table_error(
                path, where, "name must be a C identifier no variable or other state has."
            )
        names.add(row["name"])
        for key in ("unit", "derivative_unit"):
            parse_unit(row[key], path, where)
        states.append(State(row["name"], row["unit"], row["derivative_unit"], row["description"]))
    return tuple(states)


def _check_start(path: Path, where: str, vtype: str, start: Any) -> float | int | bool | str:
    if vtype == "Real" and isinstance(start, int | float) and not isinstance(start, bool):
        return float(start)
    if vtype == "Integer" and isinstance(start, int) and not isinstance(start, bool):
        return start
    if vtype == "Boolean" and isinstance(start, bool):
        return start
    if vtype == "String" and isinstance(start, str) and len(start.encode()) < 256:
        return start
    raise _table_error(path, where, f"start {start!r} is not a valid {vtype} value.")


def load_variable_table(path: Path) -> VariableTable:
    """Read and check a model's ``variables.toml``.

    Parameters
    ----------
    path : Path
        The table file.

    Returns
    -------
    VariableTable
        The checked table.

    Raises
    ------
    FmuBuildError
        If the file is missing, is not TOML, or a model or variable entry is invalid.
    """
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise FmuBuildError(f"{path}: cannot read the variable table: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise FmuBuildError(f"{path}: not valid TOML: {exc}") from exc

    fmu = raw.get("fmu", {})
    if not isinstance(fmu.get("model_name"), str):
        raise FmuBuildError(f"{path}: [fmu] model_name is required.")
    models = []
    for i, entry in enumerate(raw.get("model", [])):
        identifier = entry.get("identifier")
        if not isinstance(identifier, str) or not _NAME.fullmatch(identifier):
            raise _table_error(path, f"model #{i}", "identifier must be a C identifier.")
        defines = entry.get("defines", [])
        if not all(isinstance(d, str) and _NAME.fullmatch(d) for d in defines):
            raise _table_error(path, f"model {identifier!r}", "defines must be C identifiers.")
        models.append(
            ModelEntry(
                identifier, entry.get("description", fmu.get("description", "")), tuple(defines)
            )
        )
    if not models:
        raise FmuBuildError(f"{path}: declare at least one [[model]] with an identifier.")
    if len({m.identifier for m in models}) != len(models):
        raise FmuBuildError(f"{path}: model identifiers must be unique.")
    identifiers = {m.identifier for m in models}

    variables = tuple(
        _parse_variable(path, i, v, identifiers) for i, v in enumerate(raw.get("variable", []))
    )
    by_name: dict[str, Variable] = {}
    for v in variables:
        if v.name in by_name:
            raise _table_error(path, f"variable {v.name!r}", "the name is not unique.")
        by_name[v.name] = v
    for v in variables:
        for dep in v.dependencies or ():
            known = by_name.get(dep)
            if known is None or known.causality != "input":
                raise _table_error(
                    path,
                    f"variable {v.name!r}",
                    f"dependency {dep!r} is not an input of the table.",
                )
    for m in models:
        solver = by_name.get("solver_step")
        if (
            solver is None
            or not solver.in_model(m.identifier)
            or solver.type != "Real"
            or solver.causality != "parameter"
        ):
            raise FmuBuildError(
                f"{path}: model {m.identifier!r} needs the Real parameter "
                "solver_step [s]: the framework's longest internal step."
            )

    experiment = {k: float(v) for k, v in fmu.get("default_experiment", {}).items()}
    unknown = set(experiment) - {"start_time", "stop_time", "step_size"}
    if unknown:
        raise FmuBuildError(f"{path}: unknown default_experiment keys {sorted(unknown)}.")
    return VariableTable(
        path=path,
        model_name=fmu["model_name"],
        description=fmu.get("description", ""),
        default_experiment=experiment,
        models=tuple(models),
        variables=variables,
        states=_parse_states(path, raw.get("state", []), set(by_name)),
    )


def parse_unit(
    unit: str, path: Path | None = None, where: str = ""
) -> tuple[dict[str, int], float, float]:
    """SI base-unit exponents, factor and offset of a unit string (see :mod:`fmu_greybox.units`).

    Raises
    ------
    FmuBuildError
        If the string does not parse or names an unknown symbol.
    """
    try:
        resolved = si_unit(unit)
    except UnitSyntaxError as error:
        raise _unit_error(unit, path, where, str(error)) from error
    return resolved.exponents, resolved.factor, resolved.offset


def _unit_error(unit: str, path: Path | None, where: str, detail: str) -> FmuBuildError:
    prefix = f"{path}: {where}: " if path else ""
    return FmuBuildError(
        f"{prefix}unit {unit!r}: {detail}. Use SI symbols joined by '.' and "
        f"'/', exponents as digits (m3, s-2), e.g. 'm3/(s.Pa)'; known symbols: "
        f"{', '.join(SYMBOLS)}; prefixes: {', '.join(PREFIXES)}."
    )


def time_reference(table: VariableTable, identifier: str) -> int:
    """The value reference of the FMI 3.0 ``time``: one past the model's variables."""
    return max(v.value_reference for v in table.variables_of(identifier)) + 1


def state_references(table: VariableTable, identifier: str) -> tuple[list[int], list[int]]:
    """Value references of a model-exchange build's states and of their derivatives: past the
    table's (the first one past it is the FMI 3.0 ``time``), as ``framework/me`` numbers them.
    """
    first = time_reference(table, identifier) + 1
    n = len(table.states)
    return list(range(first, first + n)), list(range(first + n, first + 2 * n))
