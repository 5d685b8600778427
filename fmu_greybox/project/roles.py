"""What an FMU variable is, physically: its role, from the project, its unit, name or description.

The diagnosis generates its hypotheses from roles (a friction force needs a force input and a
velocity output, a droop a pressure input and a flow output). The project's ``[signals]``
declare roles; for the FMU variables the project does not mention, the role comes from the unit
the FMU declares (``m/s`` is a velocity, ``m3/s`` a flow); and where the FMU declares no unit
that names a role (third-party FMUs often declare none), from the variable's name and then its
description, read as English: the head noun of the leading phrase names the role ("valve load
flow" is a flow, "load torque on the shaft" a force, "current position" a position).

Nothing here knows a particular model's variable names.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from fmu_greybox.data.recording import normalise_unit
from fmu_greybox.fmi.archive import FmuVariable
from fmu_greybox.project.config import ROLE_UNITS

#: Roles that a declared unit alone identifies (dimensionless units identify nothing).
_UNIT_ROLES: dict[str, str] = {
    normalise_unit(unit): role
    for role, units in ROLE_UNITS.items()
    if role not in ("command", "other")
    for unit in units
}

#: Words (whole words of a name or a description) that name a role, with the usual
#: abbreviations of variable names.
ROLE_WORDS: dict[str, str] = {
    **dict.fromkeys(
        ("velocity", "velocities", "speed", "speeds", "rpm", "omega", "vel", "spd"), "velocity"
    ),
    **dict.fromkeys(
        (
            "position",
            "positions",
            "displacement",
            "displacements",
            "angle",
            "angles",
            "stroke",
            "travel",
            "extension",
            "deflection",
            "theta",
            "pos",
        ),
        "position",
    ),
    **dict.fromkeys(
        ("force", "forces", "load", "loads", "torque", "torques", "thrust", "frc", "trq"), "force"
    ),
    **dict.fromkeys(("pressure", "pressures", "press"), "pressure"),
    **dict.fromkeys(("current", "currents", "ampere", "amperes", "curr"), "current"),
    **dict.fromkeys(("voltage", "voltages", "volt", "volts", "emf"), "voltage"),
    **dict.fromkeys(("flow", "flows", "flowrate"), "flow"),
}

#: Words that end the leading noun phrase of a description ("speed *of* the shaft").
_PHRASE_END = frozenset(
    (
        "of on in at from to through into for by with between across over under per "
        "applied measured sensed drawn acting which that where when as is are"
    ).split()
)
_CLAUSE_END = re.compile(r"[;:,()\[\]{}=<>/+]")
_CAMEL = re.compile(r"(?<=[a-z0-9])(?=[A-Z])")


@dataclass(frozen=True)
class VariableRole:
    """The role of one FMU variable and where it came from.

    Attributes
    ----------
    variable : str
        FMU variable name.
    causality : str
        ``input`` or ``output``.
    role : str
        One of the roles of :data:`~fmu_greybox.project.config.ROLE_UNITS`.
    source : str
        ``project`` (declared under ``[signals]``), ``unit``, ``name`` or ``description``.
    evidence : str
        The unit or word the role was read from (empty for ``project``).
    """

    variable: str
    causality: str
    role: str
    source: str
    evidence: str

    def to_dict(self) -> dict:
        return {
            "variable": self.variable,
            "causality": self.causality,
            "role": self.role,
            "source": self.source,
            "evidence": self.evidence,
        }


def role_from_unit(unit: str) -> str:
    """The physical role a unit implies (``"other"`` when it implies none).

    Examples
    --------
    >>> role_from_unit("m3/s"), role_from_unit("N"), role_from_unit("1")
    ('flow', 'force', 'other')
    """
    return _UNIT_ROLES.get(normalise_unit(unit), "other") if unit else "other"


def _words(text: str) -> list[str]:
    """Lower-case words of a name or a sentence (``snake_case`` and ``camelCase`` split)."""
    return [w.lower() for w in re.findall(r"[A-Za-z]+", _CAMEL.sub(" ", text))]


def role_from_text(text: str, anywhere: bool = True) -> tuple[str, str]:
    """The role a variable's name or description names, and the word that names it.

    The last role word of the leading noun phrase wins (the head noun: "load flow" is a flow,
    "current position" a position); without one there, the first role word of the text (unless
    ``anywhere`` is false).

    Returns
    -------
    (str, str)
        Role (``"other"`` if none) and the word it was read from (``""`` if none).

    Examples
    --------
    >>> role_from_text("Valve load flow (Q_A + Q_B)/2")
    ('flow', 'flow')
    >>> role_from_text("Load torque on the output shaft")
    ('force', 'torque')
    >>> role_from_text("Speed of the shaft")
    ('velocity', 'speed')
    >>> role_from_text("ia")
    ('other', '')
    """
    leading = _CLAUSE_END.split(text, maxsplit=1)[0]
    phrase = []
    for word in _words(leading):
        if word in _PHRASE_END:
            break
        phrase.append(word)
    heads = [w for w in phrase if w in ROLE_WORDS]
    if heads:
        return ROLE_WORDS[heads[-1]], heads[-1]
    found = [w for w in _words(text) if w in ROLE_WORDS] if anywhere else []
    if found:
        return ROLE_WORDS[found[0]], found[0]
    return "other", ""


def infer_role(variable: FmuVariable) -> VariableRole:
    """The role of an FMU variable the project does not declare: from its unit; else from the
    head noun of its description's leading phrase, of its name, or any role word of its
    description, in that order (a description is a phrase, a name often an abbreviation).

    Examples
    --------
    >>> from fmu_greybox.fmi.archive import FmuVariable
    >>> w = FmuVariable("w", 3, "Real", "output", "continuous", "", "Output shaft speed", None)
    >>> infer_role(w).role, infer_role(w).source
    ('velocity', 'description')
    """
    by_unit = role_from_unit(variable.unit)
    if by_unit != "other":
        return VariableRole(variable.name, variable.causality, by_unit, "unit", variable.unit)
    for source, text, anywhere in (
        ("description", variable.description, False),
        ("name", variable.name, True),
        ("description", variable.description, True),
    ):
        role, word = role_from_text(text, anywhere)
        if role != "other":
            return VariableRole(variable.name, variable.causality, role, source, word)
    return VariableRole(variable.name, variable.causality, "other", "unit", variable.unit)
