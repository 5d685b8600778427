"""Effects a recorder applies around the truth FMU in its closed loop.

Some faults are not in a plant model at all but in the loop around it: an amplifier between the
controller and the plant that saturates, a play in a command path, a load the recording does not
see, a sensor that reads high, off or late. A recorder switches them on by name, next to the
truth FMU's own effect parameters:

================================  ============================================================
name                              effect
================================  ============================================================
``saturation@INPUT``              INPUT limited to +/- value (an amplifier saturating)
``saturation_upper@INPUT``        INPUT limited to at most value (asymmetric saturation)
``saturation_lower@INPUT``        INPUT limited to at least value (asymmetric saturation)
``hysteresis@INPUT``              a play of total width value between the command and INPUT
``force_offset@INPUT``            value added to INPUT (a constant load nobody recorded)
``stiffness@INPUT(OUTPUT)``       value * OUTPUT added to INPUT (a spring nobody recorded)
``sensor_gain@OUTPUT``            the sensor of OUTPUT reads (1 + value) times it
``sensor_offset@OUTPUT``          the sensor of OUTPUT reads it plus value
``sensor_delay@OUTPUT``           the sensor of OUTPUT reads it value seconds late
================================  ============================================================

The recorded command is what the controller asked for; the FMU receives it after the input
effects. The recorded outputs, and what the controller reads back, are what the faulty sensors
report. The arithmetic is that of the correction terms (:mod:`fmu_greybox.model.terms`), the
one place where these effects are written down.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from fmu_greybox.errors import ConfigError
from fmu_greybox.model.terms import (
    ForceOffset,
    InputHysteresis,
    InputSaturation,
    SensorChannelDelay,
    SensorGain,
    SensorOffset,
    SpringForce,
    Term,
)

#: Loop-effect kinds acting on an FMU input (the rest act on an output's sensor).
INPUT_KINDS = (
    "saturation",
    "saturation_upper",
    "saturation_lower",
    "hysteresis",
    "force_offset",
    "stiffness",
)
#: Loop-effect kinds acting on the sensor of an FMU output.
SENSOR_KINDS = ("sensor_gain", "sensor_offset", "sensor_delay")

_NAME = re.compile(r"^(?P<kind>\w+)@(?P<variable>\w+)(?:\((?P<source>\w+)\))?$")


@dataclass(frozen=True)
class LoopEffect:
    """One effect around the FMU.

    Attributes
    ----------
    kind : str
        One of :data:`INPUT_KINDS` or :data:`SENSOR_KINDS`.
    variable : str
        The FMU input or output it acts on.
    source : str
        The FMU output a ``stiffness`` reads (empty otherwise).
    value : float
        Its magnitude.
    """

    kind: str
    variable: str
    source: str
    value: float


def is_loop_effect(name: str) -> bool:
    """Whether an effect name is a loop effect (``KIND@VARIABLE``), not an FMU parameter."""
    return "@" in name


def parse_loop_effects(
    effects: Mapping[str, float], inputs: Sequence[str], outputs: Sequence[str]
) -> list[LoopEffect]:
    """The loop effects among ``effects`` (names with ``@``), checked against the FMU.

    Raises
    ------
    ConfigError
        For an unknown kind, a variable the FMU lacks, a missing or unexpected source.
    """
    found = []
    for name, value in effects.items():
        if not is_loop_effect(name):
            continue
        match = _NAME.match(name)
        kind = match["kind"] if match else ""
        if kind not in INPUT_KINDS + SENSOR_KINDS:
            raise ConfigError(
                f"loop effect {name!r}: write KIND@VARIABLE with KIND one of "
                f"{', '.join(INPUT_KINDS + SENSOR_KINDS)} (stiffness@INPUT(OUTPUT))",
                field="--effect",
            )
        variable, source = match["variable"], match["source"] or ""
        allowed = inputs if kind in INPUT_KINDS else outputs
        where = "input" if kind in INPUT_KINDS else "output"
        if variable not in allowed:
            raise ConfigError(
                f"loop effect {name!r}: {variable!r} is not an FMU {where}; "
                f"{where}s: {', '.join(allowed)}",
                field="--effect",
            )
        if (kind == "stiffness") != bool(source) or (source and source not in outputs):
            raise ConfigError(
                f"loop effect {name!r}: a stiffness names the output it reads, "
                "e.g. stiffness@load_force(ram_position); other kinds name none",
                field="--effect",
            )
        found.append(LoopEffect(kind, variable, source, float(value)))
    return found


def loop_terms(effects: Sequence[LoopEffect]) -> list[Term]:
    """The correction terms that perform the loop effects."""
    terms: list[Term] = []
    limits: dict[str, list[float]] = {}
    for e in effects:
        if e.kind.startswith("saturation"):
            low, high = limits.setdefault(e.variable, [-math.inf, math.inf])
            if e.kind != "saturation_lower":
                high = abs(e.value) if e.kind == "saturation" else e.value
            if e.kind != "saturation_upper":
                low = -abs(e.value) if e.kind == "saturation" else e.value
            limits[e.variable] = [low, high]
        elif e.kind == "hysteresis":
            terms.append(InputHysteresis(input=e.variable, width=e.value))
        elif e.kind == "force_offset":
            terms.append(ForceOffset(input=e.variable, offset=e.value))
        elif e.kind == "stiffness":
            terms.append(SpringForce(input=e.variable, source=e.source, coefficient=e.value))
        elif e.kind == "sensor_gain":
            terms.append(SensorGain(output=e.variable, gain=e.value))
        elif e.kind == "sensor_offset":
            terms.append(SensorOffset(output=e.variable, offset=e.value))
        else:
            terms.append(SensorChannelDelay(output=e.variable, delay=e.value))
    saturations = [
        InputSaturation(input=name, lower=low, upper=high) for name, (low, high) in limits.items()
    ]
    return [*saturations, *terms]


class Loop:
    """The loop effects of a recording, stepped with the truth FMU.

    Parameters
    ----------
    effects : mapping of str to float
        Effect name -> value; names without ``@`` (FMU parameters) are ignored here.
    inputs, outputs : sequence of str
        The FMU inputs in the order of the rows given to :meth:`applied`, and the outputs in
        the order of the rows given to :meth:`sensed`.
    dt : float
        Sample time [s].
    """

    def __init__(
        self, effects: Mapping[str, float], inputs: Sequence[str], outputs: Sequence[str], dt: float
    ) -> None:
        self.terms = loop_terms(parse_loop_effects(effects, inputs, outputs))
        for term in self.terms:
            term.bind(inputs, outputs, dt)
        self._inputs = [t for t in self.terms if t.acts_on_inputs]
        self._sensors = [t for t in self.terms if t.acts_on_outputs]

    def applied(self, command: np.ndarray, y: np.ndarray) -> np.ndarray:
        """What the FMU receives when the loop commands ``command`` and the FMU's true outputs
        are ``y`` (a new array, shape (n_inputs,)); call once per step."""
        u = np.array(command, dtype=np.float64)
        for term in self._inputs:
            term.on_input(u, y)
        return u

    def sensed(self, y: np.ndarray) -> np.ndarray:
        """What the sensors report when the true outputs are ``y`` (a new array, shape
        (n_outputs,)); call once per step."""
        reading = np.array(y, dtype=np.float64)
        for term in self._sensors:
            term.on_output(reading)
        return reading
