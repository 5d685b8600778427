"""Build FMI 2.0 co-simulation FMUs from the C sources in ``fmu_sources/`` (FMI 3.0, and
model exchange, with the framework's shells: :func:`build_fmu`'s ``kind``).

A model is a folder holding ``variables.toml`` (the variable table), ``config.h`` (state layout)
and ``model.c`` (physics); ``fmu_sources/framework/`` supplies the FMI plumbing and the
integrator. For one model identifier of the table the builder

1. reads and checks the variable table,
2. generates ``fmu_variables.h`` / ``fmu_variables.c`` (value references, storage indices,
   start values, ranges) and ``modelDescription.xml`` (units, variables, model structure),
3. compiles everything with gcc into one shared library (``-O2``, IEEE arithmetic: no
   ``-ffast-math``, no floating-point contraction), and
4. zips ``modelDescription.xml``, ``binaries/<platform>/<identifier>.<ext>`` and
   ``documentation/`` into ``<out_dir>/<identifier>.fmu``, written atomically.

The FMI 2 headers are the ones fmpy ships (``fmpy/c-code``).
"""

from __future__ import annotations

import hashlib
import html
import re
import tempfile
import tomllib
import uuid
import zipfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

from fmu_greybox import __version__
from fmu_greybox.atomic import atomic_write
from fmu_greybox.errors import FmuBuildError
from fmu_greybox.fmi.compiler import (
    FRAMEWORK_FLAGS,
    NATIVE_DIR,
    SHELL_CONFIG,
    CBuild,
    compile_library,
    shell_config,
)
from fmu_greybox.fmi.kinds import ACCEPTED, FMI2_CS, MODEL_EXCHANGE, FmuKind
from fmu_greybox.fmi.platforms import (
    BinaryPlatform,
    host_platform,
)
from fmu_greybox.resources import data_path
from fmu_greybox.units import BASE_UNITS, PREFIXES, SYMBOLS, UnitSyntaxError, si_unit

SOURCES_DIR = data_path("fmu_sources")
"""Root of the C sources: ``framework/`` and one folder per model."""

FRAMEWORK_DIR = SOURCES_DIR / "framework"
"""The generic FMI 2.0 co-simulation framework."""
FMI3_SHELL = NATIVE_DIR / "fmi3_shell.c"
"""The FMI 3.0 co-simulation face over an FMI 2.0 co-simulation core (the framework's here,
the native grey-box's at export)."""

ME_SHELL_DIR = FRAMEWORK_DIR / "me"
"""The model-exchange functions (FMI 2.0, and the FMI 3.0 shell over them), which the
framework's files include when compiled with ``-DFW_MODEL_EXCHANGE``."""
SHARED_SOURCES = tuple(
    NATIVE_DIR / n for n in ("fmi2_shell.c", "fmi2_shell.h", "sha256.c", "sha256.h")
)
"""What the framework shares with the native grey-box FMU: the FMI 2.0 shell (phases, logging,
serialised states, the unsupported calls) and the SHA-256 its serialised states carry."""

#: The log categories of every FMU built here (``native/fmi2_shell.c``, ``SHELL_CATEGORIES``,
#: accepts these in fmi2SetDebugLogging) and what each carries.
LOG_CATEGORIES = (
    ("logStatusWarning", "Warnings (sent while debug logging is on)."),
    ("logStatusDiscard", "Discards (none: a refused call answers an error)."),
    ("logStatusError", "Errors, what failed and how to mend it: sent at any logging level."),
    ("logStatusFatal", "Fatal errors (none)."),
    ("logAll", "Every message of the FMU (and of an FMU it embeds)."),
)

REFERENCE_MODEL_DIR = SOURCES_DIR / "HydraulicActuator"
"""The reference actuator: white-box ``HydraulicActuator`` and ``HydraulicActuatorTruth``."""


_CAUSALITIES = ("input", "output", "parameter")
_VARIABILITIES = ("continuous", "discrete", "fixed", "tunable")
_TYPES = ("Real", "Integer", "Boolean", "String")
_TYPE_PREFIX = {"Real": "R", "Integer": "I", "Boolean": "B", "String": "S"}
_C_TYPE = {
    "Real": "FW_REAL",
    "Integer": "FW_INTEGER",
    "Boolean": "FW_BOOLEAN",
    "String": "FW_STRING",
}
_C_CAUSALITY = {"parameter": "FW_PARAMETER", "input": "FW_INPUT", "output": "FW_OUTPUT"}
_C_VARIABILITY = {
    "fixed": "FW_FIXED",
    "tunable": "FW_TUNABLE",
    "discrete": "FW_DISCRETE",
    "continuous": "FW_CONTINUOUS",
}
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_GUID_NAMESPACE = uuid.UUID("6f1c2a0e-5b7d-4e21-9a57-1f0c3d8e4b62")
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # fixed: same sources give the same archive


# ------------------------------------------------------------------------------------------------
# Variable table
# ------------------------------------------------------------------------------------------------


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
    if vtype not in _TYPES:
        raise _table_error(path, where, f"type must be one of {_TYPES}.")
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
            _parse_unit(unit, path, where)
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
            _parse_unit(row[key], path, where)
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


# ------------------------------------------------------------------------------------------------
# Units: Modelica/FMI unit strings such as "m3/(s.Pa)" to SI base-unit exponents
# ------------------------------------------------------------------------------------------------


def _parse_unit(
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


# ------------------------------------------------------------------------------------------------
# Generated files
# ------------------------------------------------------------------------------------------------


def unit_element(unit: str) -> ET.Element:
    """The ``Unit`` element of a unit string: its SI base-unit exponents, factor and offset
    (:func:`_parse_unit`)."""
    exps, factor, offset = _parse_unit(unit)
    element = ET.Element("Unit", {"name": unit})
    attributes = {k: str(exps[k]) for k in BASE_UNITS if k in exps}
    if factor != 1.0:
        attributes["factor"] = _number(factor)
    if offset != 0.0:
        attributes["offset"] = _number(offset)
    ET.SubElement(element, "BaseUnit", attributes)
    return element


def _number(value: float) -> str:
    """Shortest text that reads back as the same double."""
    return repr(float(value))


def _guid(table: VariableTable, identifier: str, source_files: list[Path]) -> str:
    """Deterministic GUID over identifier, builder, table and sources: changes with any."""
    digest = hashlib.sha256(identifier.encode())
    for file in [Path(__file__), table.path, *source_files]:
        digest.update(file.name.encode())
        digest.update(file.read_bytes())
    digest.update(" ".join(FRAMEWORK_FLAGS).encode())
    return "{" + str(uuid.uuid5(_GUID_NAMESPACE, digest.hexdigest())) + "}"


def model_description(table: VariableTable, identifier: str, guid: str) -> bytes:
    """Generate ``modelDescription.xml`` for one model of a table.

    Parameters
    ----------
    table : VariableTable
        The variable table.
    identifier : str
        Model identifier (``modelIdentifier`` and binary name).
    guid : str
        The GUID the binary is compiled with.

    Returns
    -------
    bytes
        UTF-8 XML: one UnitDefinition per unit used, the variables, ModelStructure Outputs
        (with the declared dependencies) and InitialUnknowns (every output).
    """
    entry = table.model(identifier)
    variables = table.variables_of(identifier)
    root = ET.Element(
        "fmiModelDescription",
        {
            "fmiVersion": "2.0",
            "modelName": table.model_name,
            "guid": guid,
            "description": entry.description,
            "generationTool": f"fmu-greybox {__version__}",
            "variableNamingConvention": "flat",
            "numberOfEventIndicators": "0",
        },
    )
    ET.SubElement(
        root,
        "CoSimulation",
        {
            "modelIdentifier": identifier,
            "needsExecutionTool": "false",
            "canHandleVariableCommunicationStepSize": "true",
            "canInterpolateInputs": "false",
            "maxOutputDerivativeOrder": "0",
            "canRunAsynchronuously": "false",
            "canBeInstantiatedOnlyOncePerProcess": "false",
            "canNotUseMemoryManagementFunctions": "false",
            "canGetAndSetFMUstate": "true",
            "canSerializeFMUstate": "true",
            "providesDirectionalDerivative": "false",
        },
    )
    _units_logging_experiment(root, table, variables)
    scalars = ET.SubElement(root, "ModelVariables")
    index_of: dict[str, int] = {}
    for position, v in enumerate(variables, start=1):
        index_of[v.name] = position
        attributes = _variable_attributes(v)
        scalar = ET.SubElement(scalars, "ScalarVariable", attributes)
        ET.SubElement(scalar, v.type, _typed_attributes(v))
    structure = ET.SubElement(root, "ModelStructure")
    outputs = ET.SubElement(structure, "Outputs")
    initial = ET.SubElement(structure, "InitialUnknowns")
    for v in variables:
        if v.causality != "output":
            continue
        attributes = {"index": str(index_of[v.name])}
        if v.dependencies is not None:
            deps = [v2 for v2 in v.dependencies if v2 in index_of]
            attributes["dependencies"] = " ".join(str(index_of[d]) for d in deps)
            attributes["dependenciesKind"] = " ".join("dependent" for _ in deps)
        ET.SubElement(outputs, "Unknown", attributes)
        ET.SubElement(initial, "Unknown", {"index": str(index_of[v.name])})
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def _units_logging_experiment(root: ET.Element, table: VariableTable, variables: list) -> None:
    """Append the elements FMI 2.0 and 3.0 write alike: UnitDefinitions (one Unit per unit
    used), LogCategories and DefaultExperiment."""
    declared = sorted({v.unit for v in variables if v.unit})
    units = ET.SubElement(root, "UnitDefinitions") if declared else None
    for unit in declared:
        units.append(unit_element(unit))
    categories = ET.SubElement(root, "LogCategories")
    for name, text in LOG_CATEGORIES:
        ET.SubElement(categories, "Category", {"name": name, "description": text})
    experiment = {"start_time": "startTime", "stop_time": "stopTime", "step_size": "stepSize"}
    ET.SubElement(
        root,
        "DefaultExperiment",
        {experiment[k]: _number(v) for k, v in table.default_experiment.items()},
    )


def _variable_attributes(v: Variable) -> dict[str, str]:
    """The attributes a variable's element has in both FMI versions' model descriptions."""
    return {
        "name": v.name,
        "valueReference": str(v.value_reference),
        "description": v.description,
        "causality": v.causality,
        "variability": v.variability,
    }


def _typed_attributes(v: Variable) -> dict[str, str]:
    """Unit, start, min and max of a variable as XML attributes (those it declares)."""
    typed: dict[str, str] = {}
    if v.unit:
        typed["unit"] = v.unit
    if v.start is not None:
        typed["start"] = _start_text(v)
    if v.min is not None:
        typed["min"] = _number(v.min)
    if v.max is not None:
        typed["max"] = _number(v.max)
    return typed


def model_description_fmi3(table: VariableTable, identifier: str, token: str) -> bytes:
    """Generate an FMI 3.0 co-simulation ``modelDescription.xml`` for one model of a table.

    The same variables, value references, units and dependencies as
    :func:`model_description`, for the FMI 3.0 face (``native/fmi3_shell.c``): Real variables as
    ``Float64``, Integer as ``Int32``.

    Parameters
    ----------
    table : VariableTable
    identifier : str
        Model identifier.
    token : str
        The instantiation token the binary is compiled with (its GUID).

    Returns
    -------
    bytes
        UTF-8 XML, with the independent variable ``time`` (value reference one past the
        table's) that FMI 3.0 requires.
    """
    entry = table.model(identifier)
    time = Variable(  # FMI 3.0 requires the independent variable; the shell serves it
        name="time",
        value_reference=time_reference(table, identifier),
        causality="independent",
        variability="continuous",
        type="Real",
        unit="s",
        description="Simulation time",
        start=None,
        min=None,
        max=None,
        dependencies=None,
        models=None,
    )
    variables = [time, *table.variables_of(identifier)]
    root = ET.Element(
        "fmiModelDescription",
        {
            "fmiVersion": "3.0",
            "modelName": table.model_name,
            "instantiationToken": token,
            "description": entry.description,
            "generationTool": f"fmu-greybox {__version__}",
            "variableNamingConvention": "flat",
        },
    )
    ET.SubElement(
        root,
        "CoSimulation",
        {
            "modelIdentifier": identifier,
            "needsExecutionTool": "false",
            "canBeInstantiatedOnlyOncePerProcess": "false",
            "canGetAndSetFMUState": "true",
            "canSerializeFMUState": "true",
            "providesDirectionalDerivatives": "false",
            "canHandleVariableCommunicationStepSize": "true",
            "maxOutputDerivativeOrder": "0",
            "providesIntermediateUpdate": "false",
            "hasEventMode": "false",
        },
    )
    _units_logging_experiment(root, table, variables)
    element = {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean", "String": "String"}
    scalars = ET.SubElement(root, "ModelVariables")
    for v in variables:
        attributes = _variable_attributes(v)
        typed = _typed_attributes(v)
        if v.type == "String":  # an FMI 3.0 String's start value is a child element
            start = typed.pop("start", None)
            scalar = ET.SubElement(scalars, "String", {**attributes, **typed})
            if start is not None:
                ET.SubElement(scalar, "Start", {"value": start})
        else:
            ET.SubElement(scalars, element[v.type], {**attributes, **typed})
    structure = ET.SubElement(root, "ModelStructure")
    reference = {v.name: str(v.value_reference) for v in variables}
    outputs = [v for v in variables if v.causality == "output"]
    for v in outputs:
        attributes = {"valueReference": reference[v.name]}
        if v.dependencies is not None:
            deps = [d for d in v.dependencies if d in reference]
            attributes["dependencies"] = " ".join(reference[d] for d in deps)
            attributes["dependenciesKind"] = " ".join("dependent" for _ in deps)
        ET.SubElement(structure, "Output", attributes)
    for v in outputs:
        ET.SubElement(structure, "InitialUnknown", {"valueReference": reference[v.name]})
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def _start_text(v: Variable) -> str:
    if v.type == "Real":
        return _number(float(v.start))  # type: ignore[arg-type]
    if v.type == "Boolean":
        return "true" if v.start else "false"
    return str(v.start)


def _c_string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def variables_c_sources(table: VariableTable, identifier: str, guid: str) -> tuple[str, str]:
    """Generate ``fmu_variables.h`` and ``fmu_variables.c`` for one model of a table.

    The header defines ``MODEL_IDENTIFIER_STRING``, ``MODEL_GUID``, the counts per type,
    ``VR_<name>`` (value reference) and ``R_/I_/B_/S_<name>`` (index in the ``SimData`` array
    of its type) for every variable of the model, and ``FW_SOLVER_STEP``. The source holds the
    tables the framework reads: variable rows by value reference, start values and ranges.

    Parameters
    ----------
    table : VariableTable
        The variable table.
    identifier : str
        Model identifier.
    guid : str
        The model's GUID.

    Returns
    -------
    tuple of str
        Header text and source text.
    """
    variables = table.variables_of(identifier)
    n_vr = time_reference(table, identifier)
    index: dict[str, int] = {}
    counts = dict.fromkeys(_TYPES, 0)
    for v in variables:
        index[v.name] = counts[v.type]
        counts[v.type] += 1

    notice = (
        f"/* Generated by fmu_greybox.fmi.build from {table.path.parent.name}/"
        f"{table.path.name} for {identifier}. Do not edit. */\n"
    )
    header = [
        notice,
        "#ifndef FMU_VARIABLES_H",
        "#define FMU_VARIABLES_H",
        "",
        f"#define MODEL_IDENTIFIER_STRING {_c_string(identifier)}",
        f"#define MODEL_GUID {_c_string(guid)}",
        "",
        f"#define N_VALUE_REFERENCES {n_vr}",
        f"#define N_REAL {counts['Real']}",
        f"#define N_INTEGER {counts['Integer']}",
        f"#define N_BOOLEAN {counts['Boolean']}",
        f"#define N_STRING {counts['String']}",
        "",
        "/* Value references */",
    ]
    header += [f"#define VR_{v.name} {v.value_reference}" for v in variables]
    header += ["", "/* Positions in the SimData array of each type */"]
    header += [f"#define {_TYPE_PREFIX[v.type]}_{v.name} {index[v.name]}" for v in variables]
    header += [
        "",
        "/* The framework's internal step (parameter solver_step) */",
        "#define FW_SOLVER_STEP R_solver_step",
        "",
        "/* States the table declares (a model-exchange build checks them against N_STATES) */",
        f"#define FW_DECLARED_STATES {len(table.states)}",
        "",
        "#endif",
        "",
    ]

    rows = []
    by_vr = {v.value_reference: v for v in variables}
    for vr in range(n_vr):
        v = by_vr.get(vr)
        if v is None:
            rows.append(f"    /* {vr}: not in this model */ {{0, FW_ABSENT, 0, 0, -1}},")
        else:
            rows.append(
                f"    /* {vr} */ {{{_c_string(v.name)}, {_C_TYPE[v.type]}, "
                f"{_C_CAUSALITY[v.causality]}, {_C_VARIABILITY[v.variability]}, "
                f"{index[v.name]}}},"
            )

    def array(ctype: str, name: str, vtype: str, value: Any) -> list[str]:
        items = [f"    {value(v)}, /* {v.name} */" for v in variables if v.type == vtype]
        items.append(f"    {value(None)}, /* keeps the array non-empty */")
        return [f"const {ctype} {name}[N_{vtype.upper()} + 1] = {{", *items, "};", ""]

    def real_start(v: Variable | None) -> str:
        return _number(v.start) if v is not None and v.start is not None else "0.0"

    def bound(attribute: str, default: str) -> Any:
        def text(v: Variable | None) -> str:
            value = getattr(v, attribute) if v is not None else None
            return default if value is None else _number(value)

        return text

    source = [
        notice,
        "#include <math.h>",
        "",
        '#include "fmu_framework.h"',
        "",
        "const FwVariable fw_variables[N_VALUE_REFERENCES] = {",
        *rows,
        "};",
        "",
    ]
    source += array("double", "fw_real_start", "Real", real_start)
    source += array("double", "fw_real_min", "Real", bound("min", "-HUGE_VAL"))
    source += array("double", "fw_real_max", "Real", bound("max", "HUGE_VAL"))
    source += array(
        "int",
        "fw_integer_start",
        "Integer",
        lambda v: str(v.start) if v is not None and v.start is not None else "0",
    )
    source += array(
        "int", "fw_boolean_start", "Boolean", lambda v: "1" if v is not None and v.start else "0"
    )
    source += array(
        "char *const",
        "fw_string_start",
        "String",
        lambda v: _c_string(str(v.start or "")) if v is not None else '""',
    )
    return "\n".join(header), "\n".join(source)


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


def model_exchange_description(
    co_simulation: bytes, table: VariableTable, identifier: str, kind: FmuKind
) -> bytes:
    """The model-exchange ``modelDescription.xml`` of a model, from its co-simulation one.

    The ``CoSimulation`` element becomes ``ModelExchange`` (states gettable, settable and
    serialisable; completed integrator steps needed: they apply the stops and record the
    truth model's delay line); the table's states are added as local continuous variables
    (``initial="calculated"``) with their derivatives ``der(NAME)``, and the model structure
    lists the derivatives (``Derivatives`` / ``ContinuousStateDerivative``) and both among
    the initial unknowns.

    Parameters
    ----------
    co_simulation : bytes
        What :func:`model_description` (FMI 2.0) or :func:`model_description_fmi3` (FMI 3.0)
        wrote.
    table : VariableTable
    identifier : str
    kind : FmuKind
        :data:`~fmu_greybox.fmi.kinds.FMI2_ME` or :data:`~fmu_greybox.fmi.kinds.FMI3_ME`.

    Returns
    -------
    bytes
        UTF-8 XML.
    """
    root = ET.fromstring(co_simulation)
    fmi2 = kind.fmi_version == "2.0"
    position = list(root).index(root.find("CoSimulation"))
    root.remove(root.find("CoSimulation"))
    flags = {
        "modelIdentifier": identifier,
        "needsExecutionTool": "false",
        "canBeInstantiatedOnlyOncePerProcess": "false",
    }
    if fmi2:
        flags |= {
            "completedIntegratorStepNotNeeded": "false",
            "canNotUseMemoryManagementFunctions": "false",
            "canGetAndSetFMUstate": "true",
            "canSerializeFMUstate": "true",
            "providesDirectionalDerivative": "false",
        }
    else:
        flags |= {
            "canGetAndSetFMUState": "true",
            "canSerializeFMUState": "true",
            "providesDirectionalDerivatives": "false",
            "needsCompletedIntegratorStep": "true",
        }
    root.insert(position, ET.Element("ModelExchange", flags))
    _add_units(root, [u for s in table.states for u in (s.unit, s.derivative_unit)], position)

    states, derivatives = state_references(table, identifier)
    scalars = root.find("ModelVariables")
    index = len(scalars) + 1  # FMI 2.0: 1-based position in ModelVariables of the first state
    for i, state in enumerate(table.states):
        der = f"der({state.name})"
        rows = [
            (state.name, states[i], state.description, {"unit": state.unit}),
            (der, derivatives[i], f"Derivative of {state.name}", {"unit": state.derivative_unit}),
        ]
        for name, vr, text, typed in rows:
            if name == der:
                typed["derivative"] = str(index + 2 * i if fmi2 else states[i])
            attributes = {
                "name": name,
                "valueReference": str(vr),
                "description": text,
                "causality": "local",
                "variability": "continuous",
                "initial": "calculated",
            }
            if fmi2:
                ET.SubElement(ET.SubElement(scalars, "ScalarVariable", attributes), "Real", typed)
            else:
                ET.SubElement(scalars, "Float64", {**attributes, **typed})
    n = len(table.states)
    structure = root.find("ModelStructure")
    if fmi2:
        # appended as state, its derivative, the next state, ...
        state_keys = [str(index + 2 * i) for i in range(n)]
        der_keys = [str(index + 2 * i + 1) for i in range(n)]
        listed = ET.Element("Derivatives")
        for key in der_keys:
            ET.SubElement(listed, "Unknown", {"index": key})
        structure.insert(list(structure).index(structure.find("Outputs")) + 1, listed)
        initial = structure.find("InitialUnknowns")
        if initial is None:
            initial = ET.SubElement(structure, "InitialUnknowns")
        for key in sorted(state_keys + der_keys, key=int):
            ET.SubElement(initial, "Unknown", {"index": key})
    else:
        outputs = [e for e in structure if e.tag == "Output"]
        at = list(structure).index(outputs[-1]) + 1 if outputs else 0
        for offset, vr in enumerate(derivatives):
            element = ET.Element("ContinuousStateDerivative", {"valueReference": str(vr)})
            structure.insert(at + offset, element)
        for vr in [*states, *derivatives]:
            ET.SubElement(structure, "InitialUnknown", {"valueReference": str(vr)})
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def _add_units(root: ET.Element, units: list[str], interface_position: int) -> None:
    """Declare ``units`` in the ``UnitDefinitions`` (made after the interface element if
    missing), keeping them sorted by name as :func:`_units_logging_experiment` writes them."""
    definitions = root.find("UnitDefinitions")
    if definitions is None:
        definitions = ET.Element("UnitDefinitions")
        root.insert(interface_position + 1, definitions)
    known = {u.get("name"): u for u in definitions}
    for unit in units:
        if unit in known:
            continue
        known[unit] = unit_element(unit)
    for element in list(definitions):
        definitions.remove(element)
    for name in sorted(known):
        definitions.append(known[name])


# ------------------------------------------------------------------------------------------------
# Compiling and packaging
# ------------------------------------------------------------------------------------------------


def fmi2_headers() -> Path:
    """Folder of the FMI 2.0 C headers shipped with fmpy.

    Raises
    ------
    FmuBuildError
        If fmpy is not installed or lacks ``c-code/fmi2Functions.h``.
    """
    try:
        import fmpy
    except ImportError as exc:
        raise FmuBuildError("fmpy is needed for the FMI 2.0 headers: pip install fmpy") from exc
    folder = Path(fmpy.__file__).parent / "c-code"
    if not (folder / "fmi2Functions.h").is_file():
        raise FmuBuildError(f"{folder} lacks fmi2Functions.h; reinstall fmpy.")
    return folder


def _framework_sources(kind: FmuKind) -> list[Path]:
    """The framework's C files for ``kind``: the FMI 2.0 framework, plus the FMI 3.0 shell
    (model exchange: and, included by them, the files of :data:`ME_SHELL_DIR`)."""
    shell = [FMI3_SHELL] if kind.fmi_version == "3.0" else []
    return [*sorted(FRAMEWORK_DIR.glob("*.c")), *shell]


def _compile(
    model_dir: Path,
    entry: ModelEntry,
    generated: Path,
    library: Path,
    kind: FmuKind,
    target: BinaryPlatform,
) -> None:
    sources = [
        *_framework_sources(kind),
        *(f for f in SHARED_SOURCES if f.suffix == ".c"),
        *sorted(model_dir.glob("*.c")),
        generated / "fmu_variables.c",
    ]
    defines = [*entry.defines, *(["FW_MODEL_EXCHANGE"] if kind.interface == MODEL_EXCHANGE else [])]
    build = CBuild(
        what=entry.identifier,
        sources=tuple(sources),
        flags=FRAMEWORK_FLAGS,
        include_dirs=(generated, model_dir, FRAMEWORK_DIR, NATIVE_DIR, fmi2_headers()),
        defines=tuple(defines),
    )
    compile_library(build, library, target)


def _zip_write(archive: zipfile.ZipFile, name: str, data: bytes, executable: bool = False) -> None:
    info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = (0o755 if executable else 0o644) << 16
    archive.writestr(info, data)


def _index_html(entry: ModelEntry, readme: str) -> bytes:
    """``documentation/index.html`` (the FMI entry point): the README as preformatted text."""
    title = html.escape(entry.identifier)
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{title}'
        f"</title></head>\n<body><h1>{title}</h1><p>{html.escape(entry.description)}</p>"
        f"\n<pre>{html.escape(readme)}</pre></body></html>\n"
    ).encode()


def build_fmu(
    model_dir: Path,
    out_dir: Path,
    identifier: str | None = None,
    kind: FmuKind = FMI2_CS,
    target: BinaryPlatform | None = None,
) -> Path:
    """Build one co-simulation FMU from a model folder.

    Parameters
    ----------
    model_dir : Path
        Folder with ``variables.toml``, ``config.h`` and ``model.c`` (and optionally
        ``README.md``, packed as ``documentation/README.md`` and ``index.html``).
    out_dir : Path
        Where ``<identifier>.fmu`` is written (created if missing).
    identifier : str or None
        Which model of the table to build; the first one if ``None``.
    kind : FmuKind
        :data:`~fmu_greybox.fmi.kinds.FMI2_CS` (the framework) or
        :data:`~fmu_greybox.fmi.kinds.FMI3_CS` (the framework with its FMI 3.0 shell, the
        same numbers); :data:`~fmu_greybox.fmi.kinds.FMI2_ME` or
        :data:`~fmu_greybox.fmi.kinds.FMI3_ME` for model exchange (the framework's
        model-exchange functions, ``framework/me``: the model's states and derivatives, no
        integrator; the table must declare the states, ``[[state]]``).
    target : BinaryPlatform or None
        The platform of its binary: this machine's when ``None``, or
        :data:`~fmu_greybox.fmi.platforms.WIN64` (FMI 2.0 only: cross-compiled with mingw-w64
        into ``binaries/win64/<identifier>.dll``).

    Returns
    -------
    Path
        The FMU, replaced atomically if it existed.

    Raises
    ------
    FmuBuildError
        If the table is invalid, the platform unsupported, gcc missing or compilation fails
        (the message holds the compiler output).
    """
    model_dir = Path(model_dir).resolve()
    out_dir = Path(out_dir)
    table = load_variable_table(model_dir / "variables.toml")
    entry = table.model(identifier)
    if kind not in ACCEPTED:
        raise FmuBuildError(f"the builder makes no {kind.label} FMUs")
    me = kind.interface == MODEL_EXCHANGE
    if me and not table.states:
        raise FmuBuildError(
            f"{table.path}: a model-exchange build declares the model's continuous states; "
            "list them as [[state]] rows in the order of config.h (see "
            "HydraulicActuator/variables.toml)"
        )
    target = target or host_platform()
    if target.windows and kind != FMI2_CS:
        raise FmuBuildError(f"the {target.folder} build makes FMI 2.0 FMUs, not {kind.label}")
    extension = target.extension
    folder = target.folder if target.windows else kind.binary_folder
    c_files = sorted(
        [
            *FRAMEWORK_DIR.glob("*.h"),
            *_framework_sources(kind),
            *(ME_SHELL_DIR.glob("*.c") if me else ()),
            *SHARED_SOURCES,
            *model_dir.glob("*.[ch]"),
        ]
    )
    guid = _guid(table, entry.identifier, c_files)
    header, source = variables_c_sources(table, entry.identifier, guid)
    describe = model_description_fmi3 if kind.fmi_version == "3.0" else model_description
    description = describe(table, entry.identifier, guid)
    if me:
        description = model_exchange_description(description, table, entry.identifier, kind)

    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f"fmu-build-{entry.identifier}-") as tmp:
        generated = Path(tmp)
        (generated / "fmu_variables.h").write_text(header, encoding="utf-8")
        (generated / "fmu_variables.c").write_text(source, encoding="utf-8")
        time = time_reference(table, entry.identifier)
        (generated / SHELL_CONFIG).write_text(shell_config(entry.identifier, time), "ascii")
        library = generated / f"{entry.identifier}{extension}"
        _compile(model_dir, entry, generated, library, kind, target)
        target = out_dir / f"{entry.identifier}.fmu"
        with atomic_write(target, "wb") as stream, zipfile.ZipFile(stream, "w") as archive:
            _zip_write(archive, "modelDescription.xml", description)
            _zip_write(
                archive, f"binaries/{folder}/{library.name}", library.read_bytes(), executable=True
            )
            readme = model_dir / "README.md"
            if readme.is_file():
                text = readme.read_text(encoding="utf-8")
                _zip_write(archive, "documentation/README.md", text.encode())
                _zip_write(archive, "documentation/index.html", _index_html(entry, text))
    return target


def build_reference_fmus(
    out_dir: Path, kind: FmuKind = FMI2_CS, target: BinaryPlatform | None = None
) -> dict[str, Path]:
    """Build the reference actuator FMUs (white-box and truth), in parallel.

    Parameters
    ----------
    out_dir : Path
        Where the FMUs are written.
    kind : FmuKind
        Their kind (see :func:`build_fmu`).
    target : BinaryPlatform or None
        Their binaries' platform (see :func:`build_fmu`).

    Returns
    -------
    dict of str to Path
        ``{"HydraulicActuator": ..., "HydraulicActuatorTruth": ...}``.

    Raises
    ------
    FmuBuildError
        As :func:`build_fmu`.
    """
    return build_model_pair(REFERENCE_MODEL_DIR, out_dir, kind, target)


def build_model_pair(
    model_dir: Path, out_dir: Path, kind: FmuKind = FMI2_CS, target: BinaryPlatform | None = None
) -> dict[str, Path]:
    """Build every model a folder's table declares (white-box and truth), in parallel.

    Parameters
    ----------
    model_dir : Path
        Model folder (see :func:`build_fmu`); its ``variables.toml`` lists the white-box first
        and then the truth model, whose truth-only variables carry ``models``.
    out_dir : Path
        Where the FMUs are written.
    kind : FmuKind
        Their kind (see :func:`build_fmu`).
    target : BinaryPlatform or None
        Their binaries' platform (see :func:`build_fmu`).

    Returns
    -------
    dict of str to Path
        Model identifier -> ``.fmu`` path, in the table's order.

    Raises
    ------
    FmuBuildError
        As :func:`build_fmu`.
    """
    table = load_variable_table(Path(model_dir) / "variables.toml")
    identifiers = [m.identifier for m in table.models]
    with ThreadPoolExecutor(max_workers=len(identifiers)) as pool:
        paths = pool.map(lambda i: build_fmu(model_dir, out_dir, i, kind, target), identifiers)
        return dict(zip(identifiers, paths, strict=True))
