"""The ``modelDescription.xml`` of an FMU built from a variable table: FMI 2.0 and FMI 3.0
co-simulation, and the model-exchange one made from either (its states and their derivatives
added), with one ``Unit`` element per unit used (:func:`unit_element`, for the
co-simulation descriptions' units and the model-exchange one's added ones alike).
"""

from __future__ import annotations

from xml.etree import ElementTree as ET

from fmu_greybox import __version__
from fmu_greybox.fmi.kinds import FmuKind
from fmu_greybox.fmi.variables import (
    Variable,
    VariableTable,
    parse_unit,
    state_references,
    time_reference,
)
from fmu_greybox.units import BASE_UNITS

#: The log categories of every FMU built here (``native/fmi2_shell.c``, ``SHELL_CATEGORIES``,
#: accepts these in fmi2SetDebugLogging) and what each carries.
LOG_CATEGORIES = (
    ("logStatusWarning", "Warnings (sent while debug logging is on)."),
    ("logStatusDiscard", "Discards (none: a refused call answers an error)."),
    ("logStatusError", "Errors, what failed and how to mend it: sent at any logging level."),
    ("logStatusFatal", "Fatal errors (none)."),
    ("logAll", "Every message of the FMU (and of an FMU it embeds)."),
)


def unit_element(unit: str) -> ET.Element:
    """The ``Unit`` element of a unit string: its SI base-unit exponents, factor and offset
    (:func:`parse_unit`)."""
    exps, factor, offset = parse_unit(unit)
    element = ET.Element("Unit", {"name": unit})
    attributes = {k: str(exps[k]) for k in BASE_UNITS if k in exps}
    if factor != 1.0:
        attributes["factor"] = number_text(factor)
    if offset != 0.0:
        attributes["offset"] = number_text(offset)
    ET.SubElement(element, "BaseUnit", attributes)
    return element


def number_text(value: float) -> str:
    """Shortest text that reads back as the same double."""
    return repr(float(value))


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
        {experiment[k]: number_text(v) for k, v in table.default_experiment.items()},
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
        typed["min"] = number_text(v.min)
    if v.max is not None:
        typed["max"] = number_text(v.max)
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
        return number_text(float(v.start))  # type: ignore[arg-type]
    if v.type == "Boolean":
        return "true" if v.start else "false"
    return str(v.start)


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
