"""The FMI 3.0 face of a native grey-box's model description, from its FMI 2.0 one.

One description is made (:func:`fmu_greybox.export.native.model_description`, completed by
:meth:`~fmu_greybox.export.fmu.ExportPlan.fix`); the FMI 3.0 one is derived from it element
by element, so both faces of a grey-box carry the same variables, value references, units,
descriptions, start values and provenance. What FMI 3.0 adds or names otherwise:

* ``instantiationToken`` for ``guid``; the co-simulation flags under their FMI 3.0 names;
* typed variables (``Float64``, ``Boolean``) for ``ScalarVariable`` and its child;
* the independent variable ``time``, one value reference past the grey-box's own (the FMI 3.0
  face, ``native/fmi3_shell.c``, serves it);
* ``Output`` and ``InitialUnknown`` by value reference for ``Unknown`` by index;
* the provenance as ``Annotations/Annotation[@type="fmu-greybox"]`` for
  ``VendorAnnotations/Tool[@name="fmu-greybox"]``.
"""

from __future__ import annotations

from lxml import etree

#: FMI 2.0 co-simulation flags and their FMI 3.0 names; flags FMI 3.0 lacks are dropped.
FLAGS = {
    "modelIdentifier": "modelIdentifier",
    "needsExecutionTool": "needsExecutionTool",
    "canBeInstantiatedOnlyOncePerProcess": "canBeInstantiatedOnlyOncePerProcess",
    "canGetAndSetFMUstate": "canGetAndSetFMUState",
    "canSerializeFMUstate": "canSerializeFMUState",
    "providesDirectionalDerivative": "providesDirectionalDerivatives",
    "canHandleVariableCommunicationStepSize": "canHandleVariableCommunicationStepSize",
}
#: Root attributes kept as they are (``guid`` becomes ``instantiationToken``).
ROOT_ATTRIBUTES = (
    "modelName",
    "description",
    "author",
    "version",
    "generationTool",
    "generationDateAndTime",
    "variableNamingConvention",
)
#: Variable attributes kept (the typed child's ``unit`` and ``start`` move onto the variable).
VARIABLE_ATTRIBUTES = ("name", "valueReference", "description", "causality", "variability")
#: FMI 2.0 types and their FMI 3.0 elements (a grey-box has no others).
TYPES = {"Real": "Float64", "Boolean": "Boolean"}
#: The name of the independent variable FMI 3.0 requires.
TIME = "time"


def fmi3_description(fmi2: etree._Element) -> etree._Element:
    """The FMI 3.0 co-simulation ``fmiModelDescription`` of a grey-box's FMI 2.0 one.

    Parameters
    ----------
    fmi2 : lxml element
        The completed FMI 2.0 ``fmiModelDescription`` (unchanged).

    Returns
    -------
    lxml element
    """
    root = etree.Element("fmiModelDescription", fmiVersion="3.0")
    for name in ROOT_ATTRIBUTES:
        if fmi2.get(name) is not None:
            root.set(name, fmi2.get(name))
    root.set("instantiationToken", fmi2.get("guid"))
    cosim = etree.SubElement(root, "CoSimulation")
    for old, new in FLAGS.items():
        cosim.set(new, fmi2.find("CoSimulation").get(old))
    for flag in ("providesIntermediateUpdate", "hasEventMode"):
        cosim.set(flag, "false")
    for tag in ("UnitDefinitions", "LogCategories", "DefaultExperiment"):
        if fmi2.find(tag) is not None:
            root.append(_copy(fmi2.find(tag)))
    variables = etree.SubElement(root, "ModelVariables")
    scalars = fmi2.find("ModelVariables").findall("ScalarVariable")
    etree.SubElement(
        variables,
        "Float64",
        name=TIME,
        valueReference=str(time_reference(fmi2)),
        description="Simulation time",
        causality="independent",
        variability="continuous",
    )
    for scalar in scalars:
        variables.append(_variable(scalar))
    structure = etree.SubElement(root, "ModelStructure")
    outputs = [s.get("valueReference") for s in scalars if s.get("causality") == "output"]
    for tag in ("Output", "InitialUnknown"):
        for reference in outputs:
            etree.SubElement(structure, tag, valueReference=reference)
    tool = fmi2.find("VendorAnnotations/Tool")
    if tool is not None:
        annotation = etree.SubElement(etree.SubElement(root, "Annotations"), "Annotation")
        annotation.set("type", tool.get("name"))
        annotation.extend(_copy(child) for child in tool)
    return root


def time_reference(fmi2: etree._Element) -> int:
    """The value reference of ``time``: one past the grey-box's variables."""
    references = [int(s.get("valueReference")) for s in fmi2.iter("ScalarVariable")]
    return max(references) + 1


def _variable(scalar: etree._Element) -> etree._Element:
    """One ``ScalarVariable`` as its FMI 3.0 typed element."""
    typed = scalar[0]
    variable = etree.Element(TYPES[typed.tag])
    for name in VARIABLE_ATTRIBUTES:
        if scalar.get(name) is not None:
            variable.set(name, scalar.get(name))
    if scalar.get("initial") is not None:
        variable.set("initial", scalar.get("initial"))
    for name in ("unit", "start"):
        if typed.get(name) is not None:
            variable.set(name, typed.get(name))
    return variable


def _copy(element: etree._Element) -> etree._Element:
    return etree.fromstring(etree.tostring(element))
