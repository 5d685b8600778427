"""Named correction terms: physics the white-box left out, applied where it enters.

A term corrects the white-box where the physics enters, step by step, the way a co-simulation
master would apply it (:class:`fmu_greybox.model.whitebox.NamedModel` steps a white-box with its
terms):

* at an FMU **input**, from the recorded input (:meth:`Term.on_input`): a gain, an offset, a
  deadband, a saturation, a play (hysteresis), a first-order lag or a delay of a command, a
  constant force on a force input, applied once per communication step; or fed back from the
  FMU outputs (``feedback`` terms): a missing force from a velocity (or from the rate of a
  position, where the FMU has no velocity output) or from a position (a spring), a supply
  pressure drooping with a flow. Feedback terms are explicit couplings, so the runner splits
  each communication step into ``substeps`` FMU steps (the recorded input held) and recomputes
  them at each: a stiff feedback such as a Coulomb force around zero velocity then neither
  chatters nor lags;
* as FMU **parameter** values set before initialisation (:meth:`Term.parameters`);
* at the FMU **outputs** the sensors see (:meth:`Term.on_output`): a delay of every sensor, or
  one sensor channel delayed, scaled or biased. What the sensors report is what the stages see;
  feedback terms read the FMU's own outputs, untouched by sensor faults.

A term acts on the stages from its ``entry`` stage on: stages before it keep the plain white-box
outputs, and so do the stages in its ``stages_off`` (those for which training found the plain
white-box better, :mod:`fmu_greybox.workflow.parts`). A term entering after the first stage
models physics between two stages (e.g. a dead zone between a valve's spool and its metering
edges): the named model runs one FMU instance per distinct set of terms acting on a stage and
takes each observed output from the instance of its stage.

Terms are small dataclasses, picklable, and round-trip through :meth:`Term.to_dict` /
:func:`term_from_dict` so that a later run (training, the co-simulation master, an exported
FMU) can rebuild them from ``diagnosis.json`` or a model folder. The native grey-box FMU
implements every kind in :data:`TERM_KINDS` in C with the same arithmetic; a term's memory
(:meth:`Term.memory`) is part of the FMU state.

A kind is declared once, here: its class (a dataclass deriving from :class:`Term`, which
registers it in :data:`TERM_KINDS`) computes it in Python, names the C function that computes
it in the native FMU and the numbers that function reads (:class:`Native`; the native data
layout and the C kind table are made from it, :mod:`fmu_greybox.model.native_terms`) and, for a
hypothesis of one magnitude, how the diagnosis proposes it (:class:`Proposal`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from operator import attrgetter
from typing import ClassVar

import numpy as np

#: Every term kind by class name, in the order of definition (a class whose name starts with
#: ``_`` is a family, not a kind); :class:`Term` fills it.
TERM_KINDS: dict[str, type[Term]] = {}


@dataclass(frozen=True)
class Native:
    """How the native grey-box FMU computes a kind (``native/terms.c``): one C function and the
    numbers it reads.

    Attributes
    ----------
    function : str or None
        The C function of ``terms.c`` that computes the kind, ``(Term *t, double *x)``: what
        the kind makes of the value ``x`` (the input, the source of a feedback term, the
        sensed output; every sensed output of a multi-channel kind), in place. Kinds may share
        one. ``None`` for a kind acting through FMU parameters only.
    reals : tuple of str
        Attributes of the term after :meth:`Term.bind` (dotted paths allowed), in the order
        the C function reads them as ``t->p[0]``, ``t->p[1]``...; a feedback term's sub-step
        is added last (``native_terms.TERM_REALS`` reals in all).
    line : bool
        The kind keeps a delay line; its reals are then the line's whole steps and fraction.
    channels : bool
        The kind acts on several outputs at once (its ``x`` holds them all).
    """

    function: str | None
    reals: tuple[str, ...] = ()
    line: bool = False
    channels: bool = False

    def numbers(self, bound: Term) -> list[float]:
        """The reals of a bound term, in the C function's order."""
        return [float(attrgetter(name)(bound)) for name in self.reals]


@dataclass(frozen=True)
class Proposal:
    """How the diagnosis proposes a kind as a hypothesis of one magnitude
    (:mod:`fmu_greybox.diagnosis.hypotheses`).

    Attributes
    ----------
    at : str
        Where: ``"command"`` (each current or voltage input, at the input and downstream of the
        stage it drives), ``"force"`` (each force input) or ``"sensor"`` (each observed
        output's sensor alone).
    field : str
        The term's field the magnitude sets.
    magnitude : str
        The magnitude's name in the findings.
    unit : str
        The magnitude's unit: ``"1"``, ``"s"``, or ``""`` for the signal's own unit.
    scale, lower, upper : float
        Typical size and admissible range of the magnitude, in units of its reference: 1 (unit
        ``"1"``), the sample time (``"s"``), the signal's RMS (the signal's unit).
    phrase : str
        What was found, with ``{signal}``, ``{quantity}`` (the magnitude and its unit),
        ``{percent}`` (100 times its size), ``{ms}`` (the magnitude in ms) and ``{sign}``.
    signs : tuple of str
        ``{sign}`` for a positive magnitude, and for another.
    """

    at: str
    field: str
    magnitude: str
    unit: str
    scale: float
    phrase: str
    lower: float = -math.inf
    upper: float = math.inf
    signs: tuple[str, str] = ("", "")


#: How the native FMU computes a delay (its line's whole steps and fraction, as bound).
DELAY_LINE = Native("kind_delay", ("_line.whole", "_line.frac"), line=True)


def _delay(at: str, phrase: str) -> Proposal:
    """A delay proposed at ``at``: typically two samples, at most fifty."""
    return Proposal(
        at=at,
        field="delay",
        magnitude="delay",
        unit="s",
        scale=2.0,
        phrase=phrase,
        upper=50.0,
        lower=0.0,
    )


class DelayLine:
    """A fractional delay of a vector signal sampled every step (linear interpolation).

    Before ``delay`` has elapsed the first value holds (the system rests before the start).

    Parameters
    ----------
    steps : float
        Delay in samples (>= 0).
    width : int
        Length of the vector.
    """

    def __init__(self, steps: float, width: int) -> None:
        self.whole = math.floor(steps)
        self.frac = float(steps - self.whole)
        self.size = self.whole + 2
        self.buffer = np.zeros((self.size, width))
        self.count = 0
        self.head = -1

    @classmethod
    def late(cls, delay: float, dt: float, width: int = 1) -> DelayLine:
        """A line for signals sampled every ``dt`` [s] that makes them ``delay`` [s] late (no
        delay for a negative one)."""
        return cls(max(delay, 0.0) / dt, width)

    def memory(self) -> np.ndarray:
        """Everything the line remembers, as one float64 vector (for FMU state)."""
        return np.concatenate([[self.count, self.head], self.buffer.ravel()])

    def restore(self, memory: np.ndarray) -> None:
        """Take back what :meth:`memory` returned."""
        self.count, self.head = int(memory[0]), int(memory[1])
        self.buffer[:] = np.reshape(memory[2:], self.buffer.shape)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Push this step's value and return the delayed one (a new array)."""
        self.head = (self.head + 1) % self.size
        if self.count == 0:
            self.buffer[:] = x
        else:
            self.buffer[self.head] = x
        self.count += 1
        newer = self.buffer[(self.head - self.whole) % self.size]
        older = self.buffer[(self.head - self.whole - 1) % self.size]
        return newer + self.frac * (older - newer)


@dataclass
class Term:
    """Base class of the correction terms (every hook does nothing unless overridden).

    Attributes
    ----------
    entry : int
        Index of the first stage the term acts on (0: every stage).
    stages_off : tuple of int
        Stages from ``entry`` on that take the white-box without this term (chosen per stage
        at training; empty: every stage from ``entry`` on).
    """

    entry: int = field(default=0, kw_only=True)
    stages_off: tuple[int, ...] = field(default=(), kw_only=True)

    #: Vocabulary identifier of the effect the term models (docs/diagnosis.md).
    effect = ""
    #: Whether :meth:`on_input` / :meth:`on_output` do anything (the runner skips the others).
    acts_on_inputs = False
    acts_on_outputs = False
    #: Whether :meth:`on_input` reads the FMU outputs (then it is applied at every sub-step).
    feedback = False
    #: How the native FMU computes the kind (``None``: it does not; export refuses it).
    native: ClassVar[Native | None] = None
    #: How the diagnosis proposes the kind alone, if it is a hypothesis of one magnitude.
    proposal: ClassVar[Proposal | None] = None

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        if not cls.__name__.startswith("_"):
            TERM_KINDS[cls.__name__] = cls

    def parameters(self) -> dict[str, float]:
        """FMU parameter values this term sets before initialisation."""
        return {}

    def needs(self) -> tuple[str, ...]:
        """FMU outputs the term reads in :meth:`on_input`."""
        return ()

    def bind(self, inputs: Sequence[str], outputs: Sequence[str], dt: float) -> None:
        """Resolve names to positions and reset any memory before a run.

        ``dt`` is the time between two calls of the term: the communication step, or the
        sub-step for ``feedback`` terms.
        """

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        """Correct this step's FMU inputs ``u`` in place, given the outputs ``y`` at its start."""

    def on_output(self, y: np.ndarray) -> None:
        """Correct the outputs the sensors report, in place, after a step."""

    def memory(self) -> np.ndarray:
        """What the term remembers between steps, as one float64 vector (empty if nothing);
        valid after :meth:`bind`."""
        line = getattr(self, "_line", None)
        return line.memory() if line is not None else np.zeros(0)

    def restore(self, memory: np.ndarray) -> None:
        """Take back what :meth:`memory` returned."""
        line = getattr(self, "_line", None)
        if line is not None:
            line.restore(memory)

    def acts_at(self, stage: int) -> bool:
        """Whether the term acts on the outputs of stage ``stage``."""
        return self.entry <= stage and stage not in self.stages_off

    def to_dict(self) -> dict:
        """The term as plain data (``kind`` names the class; ``stages_off`` only when some
        stage is off)."""
        data = {"kind": type(self).__name__, **asdict(self)}
        if self.stages_off:
            data["stages_off"] = list(self.stages_off)
        else:
            del data["stages_off"]
        return data


@dataclass
class ParameterChange(Term):
    """A mis-set FMU parameter: ``name`` takes ``value``."""

    name: str = ""
    value: float = 0.0
    effect = "parameter_mismatch"
    native = Native(None)

    def parameters(self) -> dict[str, float]:
        return {self.name: self.value}


@dataclass
class _InputTerm(Term):
    """A term acting on one FMU input."""

    input: str = ""
    acts_on_inputs = True

    def bind(self, inputs: Sequence[str], outputs: Sequence[str], dt: float) -> None:
        self._i = list(inputs).index(self.input)


@dataclass
class InputGain(_InputTerm):
    """The input acts ``1 + gain`` times as strongly as recorded."""

    gain: float = 0.0
    effect = "gain_error"
    native = Native("kind_gain", ("gain",))
    proposal = Proposal(
        at="command",
        field="gain",
        magnitude="gain_error",
        unit="1",
        scale=0.05,
        phrase="The response to {signal} is about {percent} % {sign}",
        lower=-0.9,
        upper=9.0,
        signs=("stronger", "weaker"),
    )

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        u[self._i] *= 1.0 + self.gain


@dataclass
class InputOffset(_InputTerm):
    """A constant ``offset`` is added to the input (a null bias)."""

    offset: float = 0.0
    effect = "offset"
    native = Native("kind_offset", ("offset",))
    proposal = Proposal(
        at="command",
        field="offset",
        magnitude="offset",
        unit="",
        scale=0.02,
        phrase="An offset (null bias) of about {quantity} acts on {signal}",
    )

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        u[self._i] += self.offset


@dataclass
class ForceOffset(InputOffset):
    """A constant force ``offset`` on a force input (a load the white-box leaves out)."""

    effect = "force_offset"
    proposal = Proposal(
        at="force",
        field="offset",
        magnitude="force",
        unit="",
        scale=0.05,
        phrase="A constant force of about {quantity} on {signal} is missing",
    )


@dataclass
class InputSaturation(_InputTerm):
    """The input is limited to ``[lower, upper]`` (an amplifier that saturates; symmetric when
    ``lower == -upper``)."""

    lower: float = -math.inf
    upper: float = math.inf
    effect = "saturation"
    native = Native("kind_clamp", ("lower", "upper"))

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        u[self._i] = min(max(u[self._i], self.lower), self.upper)


@dataclass
class InputDeadband(_InputTerm):
    """Inputs within ``+/- width`` of zero act as zero; larger ones lose ``width``."""

    width: float = 0.0
    effect = "deadband"
    native = Native("kind_deadband", ("width",))
    proposal = Proposal(
        at="command",
        field="width",
        magnitude="half_width",
        unit="",
        scale=0.02,
        phrase="A deadband of about +/-{quantity} of {signal} is missing",
        lower=0.0,
        upper=10.0,
    )

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        x = u[self._i]
        u[self._i] = math.copysign(max(abs(x) - self.width, 0.0), x)


@dataclass
class InputDelay(_InputTerm):
    """The input acts ``delay`` seconds late."""

    delay: float = 0.0
    effect = "time_delay"
    native = DELAY_LINE
    proposal = _delay("command", "{signal} acts about {ms} ms later than the white-box assumes")

    def bind(self, inputs: Sequence[str], outputs: Sequence[str], dt: float) -> None:
        super().bind(inputs, outputs, dt)
        self._line, self._x = DelayLine.late(self.delay, dt), np.empty(1)

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        self._x[0] = u[self._i]
        u[self._i] = self._line(self._x)[0]


@dataclass
class _ActingInput(_InputTerm):
    """An input term that remembers the value acting (NaN before the first input)."""

    def bind(self, inputs: Sequence[str], outputs: Sequence[str], dt: float) -> None:
        super().bind(inputs, outputs, dt)
        self._acting = math.nan

    def memory(self) -> np.ndarray:
        return np.array([self._acting])

    def restore(self, memory: np.ndarray) -> None:
        self._acting = float(memory[0])


@dataclass
class InputHysteresis(_ActingInput):
    """A play of total ``width`` between the recorded input and what acts: the acting value
    moves only when the input pulls it beyond ``width / 2`` (backlash in a command path,
    hysteresis of a valve). The acting value starts at the first input."""

    width: float = 0.0
    effect = "hysteresis"
    native = Native("kind_play", ("width",))
    proposal = Proposal(
        at="command",
        field="width",
        magnitude="width",
        unit="",
        scale=0.02,
        phrase="A play (hysteresis or backlash) of about {quantity} in total acts on {signal}",
        lower=0.0,
        upper=2.0,
    )

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        x, half = float(u[self._i]), 0.5 * abs(self.width)
        acting = x if math.isnan(self._acting) else self._acting
        self._acting = min(max(acting, x - half), x + half)
        u[self._i] = self._acting


@dataclass
class InputLag(_ActingInput):
    """The input acts through a first-order lag of time constant ``tau`` [s] (exact for an
    input held over the step); the lag starts settled at the first input."""

    tau: float = 0.0
    effect = "lag"
    native = Native("kind_lag", ("_alpha",))

    def bind(self, inputs: Sequence[str], outputs: Sequence[str], dt: float) -> None:
        super().bind(inputs, outputs, dt)
        self._alpha = 1.0 - math.exp(-dt / self.tau) if self.tau > 0.0 else 1.0

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        x = float(u[self._i])
        acting = x if math.isnan(self._acting) else self._acting
        self._acting = acting + self._alpha * (x - acting)
        u[self._i] = self._acting


@dataclass
class _FeedbackInput(_InputTerm):
    """An input term computed from one FMU output of the previous (sub-)step.

    With ``rate`` the term reads the rate of change of the source instead of the source itself
    (a velocity from a position output, for an FMU that has none): the difference of the source
    over the last sub-step divided by the sub-step, zero at the first call.
    """

    source: str = ""
    rate: bool = False
    feedback = True

    def needs(self) -> tuple[str, ...]:
        return (self.source,)

    def bind(self, inputs: Sequence[str], outputs: Sequence[str], dt: float) -> None:
        super().bind(inputs, outputs, dt)
        self._o = list(outputs).index(self.source)
        self._h = dt
        self._last = math.nan

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        x = float(y[self._o])
        if self.rate:
            last, self._last = self._last, x
            x = 0.0 if math.isnan(last) else (x - last) / self._h
        u[self._i] += self.value(x)

    def memory(self) -> np.ndarray:
        return np.array([self._last]) if self.rate else np.zeros(0)

    def restore(self, memory: np.ndarray) -> None:
        if self.rate:
            self._last = float(memory[0])

    def value(self, x: float) -> float:
        """What is added to the input for the source output at ``x``."""
        raise NotImplementedError


@dataclass
class CoulombForce(_FeedbackInput):
    """A force ``(force + asymmetry * sign(v)) * tanh(v / smoothing)`` added to a force input
    (``v``: the source): ``force + asymmetry`` while ``v > 0``, ``force - asymmetry`` while
    ``v < 0`` (friction stronger in one direction)."""

    force: float = 0.0
    smoothing: float = 1e-3
    asymmetry: float = 0.0
    effect = "coulomb_friction"
    native = Native("kind_coulomb", ("force", "smoothing", "asymmetry"))

    def value(self, x: float) -> float:
        t = math.tanh(x / self.smoothing)
        return self.force * t + self.asymmetry * abs(t)


@dataclass
class ViscousForce(_FeedbackInput):
    """A force ``coefficient * v`` added to a force input."""

    coefficient: float = 0.0
    effect = "viscous_friction"
    native = Native("kind_viscous", ("coefficient",))

    def value(self, x: float) -> float:
        return self.coefficient * x


@dataclass
class StribeckForce(_FeedbackInput):
    """A breakaway force ``force * exp(-(v / velocity)^2) * tanh(v / smoothing)``."""

    force: float = 0.0
    velocity: float = 1e-2
    smoothing: float = 1e-3
    effect = "stribeck_friction"
    native = Native("kind_stribeck", ("force", "velocity", "smoothing"))

    def value(self, x: float) -> float:
        r = x / self.velocity  # squared as r * r, which is what C compilers make of pow(r, 2)
        return self.force * math.exp(-(r * r)) * math.tanh(x / self.smoothing)


@dataclass
class SpringForce(_FeedbackInput):
    """A force ``coefficient * (x - rest)`` added to a force input (``x``: a position source;
    a spring or a structural stiffness the white-box leaves out)."""

    coefficient: float = 0.0
    rest: float = 0.0
    effect = "stiffness"
    native = Native("kind_spring", ("coefficient", "rest"))

    def value(self, x: float) -> float:
        return self.coefficient * (x - self.rest)


@dataclass
class FlowDroop(_FeedbackInput):
    """A pressure input drops by ``resistance * Q`` (``Q``: the source flow)."""

    resistance: float = 0.0
    effect = "supply_pressure_droop"
    native = Native("kind_droop", ("resistance",))

    def value(self, x: float) -> float:
        return -self.resistance * x


@dataclass
class SensorDelay(Term):
    """The sensors of ``outputs`` report their values ``delay`` seconds late (those of them
    that a run reads)."""

    outputs: tuple[str, ...] = ()
    delay: float = 0.0
    effect = "time_delay"
    native = replace(DELAY_LINE, channels=True)
    acts_on_outputs = True

    def bind(self, inputs: Sequence[str], outputs: Sequence[str], dt: float) -> None:
        self._j = np.array([j for j, n in enumerate(outputs) if n in self.outputs], dtype=int)
        self._line = DelayLine.late(self.delay, dt, self._j.size)

    def on_output(self, y: np.ndarray) -> None:
        y[self._j] = self._line(y[self._j])

    def to_dict(self) -> dict:
        return {**super().to_dict(), "outputs": list(self.outputs)}


@dataclass
class _SensorChannel(Term):
    """A fault of the sensor of one output (no effect on a run that does not read it)."""

    output: str = ""
    acts_on_outputs = True

    def bind(self, inputs: Sequence[str], outputs: Sequence[str], dt: float) -> None:
        self._j = list(outputs).index(self.output) if self.output in outputs else -1

    def on_output(self, y: np.ndarray) -> None:
        if self._j >= 0:
            y[self._j] = self.sensed(float(y[self._j]))

    def sensed(self, x: float) -> float:
        """What the sensor reports when the output is ``x``."""
        raise NotImplementedError


@dataclass
class SensorGain(_SensorChannel):
    """The sensor reports ``1 + gain`` times the output."""

    gain: float = 0.0
    effect = "sensor_gain"
    native = Native("kind_gain", ("gain",))
    proposal = Proposal(
        at="sensor",
        field="gain",
        magnitude="gain_error",
        unit="1",
        scale=0.01,
        phrase="The sensor of {signal} reads about {percent} % {sign}",
        lower=-0.5,
        upper=1.0,
        signs=("high", "low"),
    )

    def sensed(self, x: float) -> float:
        return x * (1.0 + self.gain)


@dataclass
class SensorOffset(_SensorChannel):
    """The sensor reports the output plus ``offset``."""

    offset: float = 0.0
    effect = "sensor_offset"
    native = Native("kind_offset", ("offset",))
    proposal = Proposal(
        at="sensor",
        field="offset",
        magnitude="offset",
        unit="",
        scale=0.01,
        phrase="The sensor of {signal} is offset by about {quantity}",
    )

    def sensed(self, x: float) -> float:
        return x + self.offset


@dataclass
class SensorChannelDelay(_SensorChannel):
    """The sensor of one output reports ``delay`` seconds late (the others on time)."""

    delay: float = 0.0
    effect = "sensor_delay"
    native = DELAY_LINE
    proposal = _delay("sensor", "The sensor of {signal} reports about {ms} ms late")

    def bind(self, inputs: Sequence[str], outputs: Sequence[str], dt: float) -> None:
        super().bind(inputs, outputs, dt)
        self._line, self._x = DelayLine.late(self.delay, dt), np.empty(1)

    def sensed(self, x: float) -> float:
        self._x[0] = x
        return float(self._line(self._x)[0])


def term_from_dict(data: Mapping) -> Term:
    """Rebuild a term from :meth:`Term.to_dict` output.

    Raises
    ------
    ValueError
        For an unknown ``kind`` or field.
    """
    data = dict(data)
    kind = data.pop("kind", None)
    cls = TERM_KINDS.get(kind)
    if cls is None:
        raise ValueError(f"unknown term kind {kind!r}; known: {', '.join(TERM_KINDS)}")
    known = {f.name for f in fields(cls)}
    unknown = set(data) - known
    if unknown:
        raise ValueError(f"term {kind} has no field(s) {', '.join(sorted(unknown))}")
    for name in ("outputs", "stages_off"):
        if name in data:
            data[name] = tuple(data[name])
    return cls(**data)
