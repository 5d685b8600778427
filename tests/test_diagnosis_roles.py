"""Roles of FMU variables from their units, names and descriptions; the third-party servo's roles
as the diagnosis reads them."""

from __future__ import annotations

import numpy as np
import pytest
from third_party import project

from fmu_greybox.data.recording import Recording
from fmu_greybox.diagnosis.signals import SignalMap
from fmu_greybox.fmi.archive import FmuVariable, open_fmu
from fmu_greybox.project.roles import infer_role, role_from_text


@pytest.mark.parametrize(
    ("text", "role", "word"),
    [
        ("Valve load flow (Q_A + Q_B)/2", "flow", "flow"),
        ("Load torque, opposing positive rotation", "force", "torque"),
        ("External load force on the ram; positive opposes positive ram motion", "force", "force"),
        ("Speed of the output shaft", "velocity", "speed"),
        ("Current position of the carriage", "position", "position"),
        ("Armature current", "current", "current"),
        ("Drive voltage command to the armature", "voltage", "voltage"),
        ("ITFV-monitored differential pressure: first-order lag", "pressure", "pressure"),
        ("Flow drawn from the supply through the valve", "flow", "flow"),
        ("Shaft angle", "position", "angle"),
        ("ram_velocity", "velocity", "velocity"),
        ("motorSpeed", "velocity", "speed"),
        ("x_pos", "position", "pos"),
        ("ITFV engagement command: >= 0.5 engaged (valve drives the ram)", "other", ""),
        ("ia", "other", ""),
    ],
)
def test_role_from_a_name_or_a_description(text: str, role: str, word: str) -> None:
    assert role_from_text(text) == (role, word)


def _variable(name: str, unit: str, description: str) -> FmuVariable:
    return FmuVariable(name, 0, "Real", "output", "continuous", unit, description, None)


def test_unit_first_then_description_head_then_name() -> None:
    by_unit = infer_role(_variable("x", "m/s", "Load position"))
    assert (by_unit.role, by_unit.source, by_unit.evidence) == ("velocity", "unit", "m/s")
    # a dimensionless unit names nothing: the description's head noun decides over the name
    described = infer_role(_variable("load", "1", "Load position in the guide"))
    assert (described.role, described.source) == ("position", "description")
    named = infer_role(_variable("load_flow", "", "Measured by the flow meter upstream"))
    assert (named.role, named.source, named.evidence) == ("flow", "name", "flow")
    nothing = infer_role(_variable("k", "", "Switch"))
    assert nothing.role == "other"


def test_third_party_servo_roles_come_from_its_descriptions(dc_servo_fmus) -> None:
    """The servo declares no units: the project declares its recorded signals, and the
    undeclared speed output is read as a velocity from its description; declaring it in the
    project overrides what is read."""
    recording = Recording(
        time=np.array([0.0, 1e-3]),
        signals={name: np.zeros(2) for name in ("u", "tl", "th", "ia")},
        units=dict.fromkeys(("u", "tl", "th", "ia"), ""),
    )
    with open_fmu(dc_servo_fmus["DCServo"]) as fmu:
        signals = SignalMap.from_project(project(dc_servo_fmus["DCServo"]), fmu, recording)
        declared = SignalMap.from_project(
            project(dc_servo_fmus["DCServo"], declare_speed=True), fmu, recording
        )
    inferred = {r.variable: r for r in signals.inferred_roles}
    assert set(inferred) == {"w"}
    assert (inferred["w"].role, inferred["w"].source, inferred["w"].evidence) == (
        "velocity",
        "description",
        "speed",
    )
    assert signals.output_roles == {"th": "position", "w": "velocity", "ia": "current"}
    assert signals.input_roles == {"u": "voltage", "tl": "force"}
    assert signals.units["tl"] == "N.m"  # the FMU declares none: the project's unit
    assert declared.inferred_roles == []
