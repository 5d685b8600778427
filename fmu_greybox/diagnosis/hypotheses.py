"""Physically named hypotheses: what the white-box may have left out or got wrong.

Each hypothesis is a small strategy object with one or two magnitudes ``theta``: it turns them
into correction terms (:mod:`.terms`) that enter where the physics enters (an FMU parameter, an
FMU input, the sensors), so the white-box's own dynamics carry their effect to the outputs. It
knows its magnitudes' typical size (``scale``), their admissible range and how to say what it
found in a sentence. A hypothesis of one magnitude whose term kind declares how the diagnosis
proposes it (:class:`~fmu_greybox.model.terms.Proposal`: a command's gain error, offset,
deadband, delay and play, a constant force, a sensor's gain error, offset and delay) is an
:class:`InputError` or a :class:`SensorFault` made from that declaration; the others (a
parameter, a saturation, forces fed back from the outputs, a supply droop, a delay of every
sensor) have logic of their own and classes of their own.

:func:`generate_hypotheses` builds the vocabulary for a project from signal roles and the FMU's
declarations only: every tunable Real parameter; at command inputs (current or voltage) a gain
error, an offset, a deadband, a delay and a play (hysteresis), acting either at the input or only
downstream of the stage the input drives, and a saturation (symmetric or not); at force inputs a
constant force, a spring from each position output, and a missing Coulomb (symmetric or
stronger in one direction), viscous or Stribeck force fed back from each velocity output (from
the rate of each position output when the FMU has no velocity output); at pressure inputs a
droop with each flow output; a delay of every sensor together, and a gain error, an offset and a
delay of each observed signal's sensor alone.
"""

from __future__ import annotations

import math
import re
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from fmu_greybox.diagnosis.signals import SignalMap
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.model.terms import (
    TERM_KINDS,
    CoulombForce,
    FlowDroop,
    InputSaturation,
    ParameterChange,
    Proposal,
    SensorDelay,
    SpringForce,
    StribeckForce,
    Term,
    ViscousForce,
)

#: Physics a parameter's name or description points to (first match wins).
PHYSICS_KEYWORDS: tuple[tuple[str, str], ...] = (
    (r"leak", "internal_leakage"),
    (r"bulk.?modulus|compressib|entrained air|stiffness", "compliance"),
    (r"natural.?frequency|time.?constant|damping ratio|bandwidth", "lag"),
    (r"viscous|damping coefficient", "viscous_friction"),
    (r"stribeck|breakaway", "stribeck_friction"),
    (r"coulomb", "coulomb_friction"),
    (r"dead.?band|dead.?zone|overlap", "deadband"),
    (r"backlash|free.?play", "backlash"),
    (r"delay|latency", "time_delay"),
    (r"offset|bias", "offset"),
    (r"gain|torque.?constant", "gain_error"),
)


def physics_label(name: str, description: str) -> str | None:
    """The effect a parameter's name or description names, or ``None``.

    Examples
    --------
    >>> physics_label("bulk_modulus", "Effective bulk modulus beta")
    'compliance'
    >>> physics_label("ram_mass", "Moving mass m")
    """
    text = f"{name.replace('_', ' ')} {description}".lower()
    for pattern, label in PHYSICS_KEYWORDS:
        if re.search(pattern, text):
            return label
    return None


@dataclass
class Hypothesis(ABC):
    """Base class of the hypotheses.

    Attributes
    ----------
    entry : int
        Stage index from which on its terms act.
    scale : tuple of float
        Typical size of each magnitude (sets finite-difference steps and conditioning).
    lower, upper : tuple of float
        Admissible range of each magnitude (one value stands for every magnitude).
    """

    entry: int = field(default=0, kw_only=True)
    scale: tuple[float, ...] = field(default=(1.0,), kw_only=True)
    lower: tuple[float, ...] = field(default=(-math.inf,), kw_only=True)
    upper: tuple[float, ...] = field(default=(math.inf,), kw_only=True)

    #: Vocabulary identifier (docs/diagnosis.md).
    effect = ""
    #: Names of the magnitudes.
    names: ClassVar[tuple[str, ...]] = ("value",)

    def __post_init__(self) -> None:
        n = len(self.scale)
        self.lower = self.lower * n if len(self.lower) == 1 else self.lower
        self.upper = self.upper * n if len(self.upper) == 1 else self.upper

    @property
    def n_params(self) -> int:
        """Number of magnitudes."""
        return len(self.scale)

    @property
    @abstractmethod
    def key(self) -> str:
        """A unique, readable identifier, e.g. ``offset@valve_current``."""

    @abstractmethod
    def terms(self, theta: np.ndarray) -> list[Term]:
        """The correction terms for magnitudes ``theta``."""

    @property
    @abstractmethod
    def units(self) -> tuple[str, ...]:
        """Unit of each magnitude."""

    @abstractmethod
    def phrase(self, theta: np.ndarray) -> str:
        """What was found, as the start of a sentence (no trailing period)."""

    @property
    def location(self) -> str:
        """Where it enters, in words."""
        return ""

    def start(self) -> np.ndarray:
        """Magnitudes of 'no effect' (clipped into the admissible range)."""
        return np.clip(np.zeros(self.n_params), self.lower, self.upper)

    def clip(self, theta: np.ndarray) -> np.ndarray:
        """``theta`` clipped into the admissible range."""
        return np.clip(theta, self.lower, self.upper)

    def extra(self, theta: np.ndarray) -> dict:
        """Further facts for ``diagnosis.json`` (e.g. a parameter's old and new value)."""
        return {}


def quantity(value: float, unit: str = "") -> str:
    """A number with 2-3 significant digits and its unit."""
    text = f"{value:.3g}" if abs(value) >= 1e-3 and abs(value) < 1e5 else f"{value:.2e}"
    return f"{text} {unit}".strip() if unit and unit != "1" else text


# ---------------------------------------------------------------------------- parameters
#: Relative changes a parameter mismatch may take by default: a tenth to a hundred times the
#: set value.
PARAMETER_RANGE = (-0.9, 99.0)


@dataclass
class ParameterMismatch(Hypothesis):
    """A tunable FMU parameter is mis-set; ``theta`` is its relative change."""

    name: str = ""
    nominal: float = 1.0
    unit: str = ""
    description: str = ""
    effect = "parameter_mismatch"
    names = ("relative_change",)

    @property
    def key(self) -> str:
        return f"parameter_mismatch@{self.name}"

    @property
    def physics(self) -> str | None:
        """The effect the parameter stands for, if its name or description says."""
        return physics_label(self.name, self.description)

    @property
    def units(self) -> tuple[str, ...]:
        return ("1",)

    @property
    def location(self) -> str:
        return f"parameter {self.name}"

    def terms(self, theta: np.ndarray) -> list[Term]:
        return [ParameterChange(name=self.name, value=self.nominal * (1.0 + float(theta[0])))]

    def phrase(self, theta: np.ndarray) -> str:
        change = float(theta[0])
        direction = "higher" if change > 0 else "lower"
        value = self.nominal * (1.0 + change)
        physics = f" ({self.physics.replace('_', ' ')})" if self.physics else ""
        return (
            f"Parameter {self.name}{physics} is about {abs(100 * change):.3g} % {direction} "
            f"than set: {quantity(value, self.unit)} instead of {quantity(self.nominal, self.unit)}"
        )

    def extra(self, theta: np.ndarray) -> dict:
        return {
            "parameter": self.name,
            "physics": self.physics,
            "nominal": self.nominal,
            "estimate": self.nominal * (1.0 + float(theta[0])),
            "parameter_unit": self.unit,
        }


# ---------------------------------------------------------------------------- command inputs
@dataclass
class _CommandHypothesis(Hypothesis):
    """An error of a command input, at the input or only downstream of the stage it drives."""

    input: str = ""
    unit: str = ""
    downstream_of: str = ""

    @property
    def key(self) -> str:
        suffix = f">{self.downstream_of}" if self.downstream_of else ""
        return f"{self.effect}@{self.input}{suffix}"

    @property
    def location(self) -> str:
        if self.downstream_of:
            return f"input {self.input}, as seen downstream of stage {self.downstream_of}"
        return f"input {self.input}"

    def _path(self) -> str:
        if self.downstream_of:
            return f" between stage {self.downstream_of} and the stages after it"
        return ""


class _Declared:
    """A hypothesis of one magnitude that its term kind declares (its
    :class:`~fmu_greybox.model.terms.Proposal`): the kind's effect, the magnitude's name, unit
    and phrase, the term it makes."""

    kind: type[Term]
    unit: str
    entry: int

    @property
    def proposal(self) -> Proposal:
        """The kind's declaration."""
        return self.kind.proposal

    @property
    def effect(self) -> str:
        return self.kind.effect

    @property
    def names(self) -> tuple[str, ...]:
        return (self.proposal.magnitude,)

    @property
    def units(self) -> tuple[str, ...]:
        return (self.proposal.unit or self.unit,)

    def _term(self, theta: np.ndarray, **where: str) -> Term:
        """The kind's term at ``where`` with the magnitude ``theta[0]``."""
        return self.kind(**where, **{self.proposal.field: float(theta[0])}, entry=self.entry)

    def _said(self, theta: np.ndarray, signal: str) -> str:
        """The kind's phrase for the magnitude ``theta[0]`` of ``signal``."""
        value = float(theta[0])
        positive, other = self.proposal.signs
        return self.proposal.phrase.format(
            signal=signal,
            quantity=quantity(value, self.units[0]),
            percent=f"{abs(100 * value):.3g}",
            ms=f"{1e3 * value:.3g}",
            sign=positive if value > 0 else other,
        )


@dataclass
class InputError(_Declared, _CommandHypothesis):
    """An error of one magnitude at a command or force input, of a term kind proposed there
    (``kind.proposal.at``: ``"command"`` or ``"force"``), e.g. a gain error, an offset, a
    deadband, a delay, a play of a command, a constant force."""

    kind: type[Term] = field(kw_only=True)

    def terms(self, theta: np.ndarray) -> list[Term]:
        return [self._term(theta, input=self.input)]

    def phrase(self, theta: np.ndarray) -> str:
        return self._said(theta, self.input) + self._path()


@dataclass
class Saturation(_CommandHypothesis):
    """What acts is limited to ``+/- limit`` (an amplifier that saturates); ``theta`` is the
    limit, and "no effect" is the largest recorded magnitude."""

    effect = "saturation"
    names = ("limit",)

    @property
    def units(self) -> tuple[str, ...]:
        return (self.unit,)

    def start(self) -> np.ndarray:
        return self.clip(np.array(self.upper, dtype=np.float64))

    def terms(self, theta: np.ndarray) -> list[Term]:
        limit = abs(float(theta[0]))
        return [InputSaturation(input=self.input, lower=-limit, upper=limit, entry=self.entry)]

    def phrase(self, theta: np.ndarray) -> str:
        return (
            f"{self.input} saturates at about +/-{quantity(abs(float(theta[0])), self.unit)}"
            f"{self._path()}"
        )


@dataclass
class AsymmetricSaturation(_CommandHypothesis):
    """What acts is limited to ``[lower, upper]``; "no effect" is the recorded range."""

    effect = "saturation"
    names = ("upper", "lower")

    @property
    def key(self) -> str:
        return f"{super().key}+asymmetric"

    @property
    def units(self) -> tuple[str, ...]:
        return (self.unit, self.unit)

    def start(self) -> np.ndarray:
        return self.clip(np.array([self.upper[0], self.lower[1]], dtype=np.float64))

    def terms(self, theta: np.ndarray) -> list[Term]:
        upper, lower = float(theta[0]), float(theta[1])
        return [InputSaturation(input=self.input, lower=lower, upper=upper, entry=self.entry)]

    def phrase(self, theta: np.ndarray) -> str:
        return (
            f"{self.input} saturates at about {quantity(float(theta[0]), self.unit)} and "
            f"{quantity(float(theta[1]), self.unit)}{self._path()}"
        )


# ---------------------------------------------------------------------------- forces
@dataclass
class _ForceHypothesis(Hypothesis):
    """A missing force at a force input, a function of a velocity output fed back (or, with
    ``rate``, of the rate of a position output: for an FMU without a velocity output)."""

    input: str = ""
    velocity: str = ""
    force_unit: str = ""
    velocity_unit: str = ""
    smoothing: float = 1e-3
    rate: bool = False
    #: +1 when a positive input force opposes positive velocity, -1 when it aids it.
    opposes: float = 1.0

    @property
    def source(self) -> str:
        """The velocity fed back, in words."""
        return f"d/dt {self.velocity}" if self.rate else self.velocity

    @property
    def key(self) -> str:
        return f"{self.effect}@{self.input}({self.source})"

    @property
    def location(self) -> str:
        return f"input {self.input}, fed back from {self.source}"

    def _sense(self, value: float) -> str:
        return "opposing" if value * self.opposes >= 0 else "aiding"

    def _feedback(self) -> dict:
        """Fields every feedback term of this hypothesis takes."""
        return {
            "input": self.input,
            "source": self.velocity,
            "rate": self.rate,
            "entry": self.entry,
        }


@dataclass
class CoulombFriction(_ForceHypothesis):
    """A constant-magnitude force against the direction of motion."""

    effect = "coulomb_friction"
    names = ("force",)

    @property
    def units(self) -> tuple[str, ...]:
        return (self.force_unit,)

    def terms(self, theta: np.ndarray) -> list[Term]:
        return [CoulombForce(**self._feedback(), force=float(theta[0]), smoothing=self.smoothing)]

    def phrase(self, theta: np.ndarray) -> str:
        f = float(theta[0])
        return (
            f"A Coulomb-like friction force of about {quantity(abs(f), self.force_unit)} "
            f"{self._sense(f)} {self.source} is missing"
        )


@dataclass
class AsymmetricCoulombFriction(_ForceHypothesis):
    """A Coulomb force of different magnitudes in the two directions of motion:
    ``force + asymmetry`` while the velocity is positive, ``force - asymmetry`` while negative."""

    effect = "coulomb_friction"
    names = ("force", "asymmetry")

    @property
    def key(self) -> str:
        return f"{super().key}+asymmetric"

    @property
    def units(self) -> tuple[str, ...]:
        return (self.force_unit, self.force_unit)

    def terms(self, theta: np.ndarray) -> list[Term]:
        return [
            CoulombForce(
                **self._feedback(),
                force=float(theta[0]),
                asymmetry=float(theta[1]),
                smoothing=self.smoothing,
            )
        ]

    def phrase(self, theta: np.ndarray) -> str:
        f, a = float(theta[0]), float(theta[1])
        return (
            f"A Coulomb-like friction force stronger in one direction is missing: about "
            f"{quantity(abs(f + a), self.force_unit)} {self._sense(f + a)} positive {self.source}, "
            f"{quantity(abs(f - a), self.force_unit)} {self._sense(f - a)} negative"
        )


@dataclass
class ViscousFriction(_ForceHypothesis):
    """A force proportional to velocity."""

    effect = "viscous_friction"
    names = ("coefficient",)

    @property
    def units(self) -> tuple[str, ...]:
        return (f"{self.force_unit}/({self.velocity_unit})",)

    def terms(self, theta: np.ndarray) -> list[Term]:
        return [ViscousForce(**self._feedback(), coefficient=float(theta[0]))]

    def phrase(self, theta: np.ndarray) -> str:
        c = float(theta[0])
        return (
            f"A viscous force of about {quantity(abs(c), self.units[0])} {self._sense(c)} "
            f"{self.source} is missing"
        )


@dataclass
class StribeckFriction(_ForceHypothesis):
    """A breakaway force that fades above a Stribeck velocity (two magnitudes)."""

    effect = "stribeck_friction"
    names = ("force", "stribeck_velocity")

    @property
    def units(self) -> tuple[str, ...]:
        return (self.force_unit, self.velocity_unit)

    def terms(self, theta: np.ndarray) -> list[Term]:
        return [
            StribeckForce(
                **self._feedback(),
                force=float(theta[0]),
                velocity=max(float(theta[1]), 1e-12),
                smoothing=self.smoothing,
            )
        ]

    def start(self) -> np.ndarray:
        return self.clip(np.array([0.0, self.scale[1]]))

    def phrase(self, theta: np.ndarray) -> str:
        f = float(theta[0])
        return (
            f"A breakaway (Stribeck) friction force of about {quantity(abs(f), self.force_unit)} "
            f"{self._sense(f)} {self.source}, fading above "
            f"{quantity(float(theta[1]), self.velocity_unit)}, is missing"
        )


@dataclass
class Stiffness(Hypothesis):
    """A force proportional to a position output, on a force input (a spring the white-box
    leaves out), relaxed at the position's initial value ``rest``."""

    input: str = ""
    position: str = ""
    force_unit: str = ""
    position_unit: str = ""
    rest: float = 0.0
    #: +1 when a positive input force opposes positive motion, -1 when it aids it.
    opposes: float = 1.0
    effect = "stiffness"
    names = ("coefficient",)

    @property
    def key(self) -> str:
        return f"{self.effect}@{self.input}({self.position})"

    @property
    def location(self) -> str:
        return f"input {self.input}, fed back from {self.position}"

    @property
    def units(self) -> tuple[str, ...]:
        return (f"{self.force_unit}/{self.position_unit}",)

    def terms(self, theta: np.ndarray) -> list[Term]:
        return [
            SpringForce(
                input=self.input,
                source=self.position,
                coefficient=float(theta[0]),
                rest=self.rest,
                entry=self.entry,
            )
        ]

    def phrase(self, theta: np.ndarray) -> str:
        k = float(theta[0])
        sense = "restoring" if k * self.opposes >= 0 else "destabilising"
        return (
            f"A {sense} spring of about {quantity(abs(k), self.units[0])} from {self.position} "
            f"onto {self.input} is missing"
        )


# ---------------------------------------------------------------------------- pressure
@dataclass
class SupplyDroop(Hypothesis):
    """A pressure input droops in proportion to a flow output (a line resistance)."""

    input: str = ""
    flow: str = ""
    pressure_unit: str = ""
    flow_unit: str = ""
    effect = "supply_pressure_droop"
    names = ("resistance",)

    @property
    def key(self) -> str:
        return f"{self.effect}@{self.input}({self.flow})"

    @property
    def location(self) -> str:
        return f"input {self.input}, fed back from {self.flow}"

    @property
    def units(self) -> tuple[str, ...]:
        return (f"{self.pressure_unit}/({self.flow_unit})",)

    def terms(self, theta: np.ndarray) -> list[Term]:
        return [
            FlowDroop(
                input=self.input, source=self.flow, resistance=float(theta[0]), entry=self.entry
            )
        ]

    def phrase(self, theta: np.ndarray) -> str:
        return (
            f"{self.input} droops with {self.flow}: a line resistance of about "
            f"{quantity(float(theta[0]), self.units[0])}"
        )


# ---------------------------------------------------------------------------- sensors
@dataclass
class SensorLag(Hypothesis):
    """Every observed sensor reports late (a pure delay)."""

    outputs: tuple[str, ...] = ()
    effect = "time_delay"
    names = ("delay",)

    @property
    def key(self) -> str:
        return "time_delay@sensors"

    @property
    def location(self) -> str:
        return f"sensors of {', '.join(self.outputs)}"

    @property
    def units(self) -> tuple[str, ...]:
        return ("s",)

    def terms(self, theta: np.ndarray) -> list[Term]:
        return [SensorDelay(outputs=self.outputs, delay=float(theta[0]), entry=self.entry)]

    def phrase(self, theta: np.ndarray) -> str:
        return f"The sensors report about {1e3 * float(theta[0]):.3g} ms late"


@dataclass
class SensorFault(_Declared, Hypothesis):
    """A fault of one magnitude of the sensor of one observed output alone, of a term kind
    proposed there (``kind.proposal.at == "sensor"``): a gain error, an offset, a delay."""

    output: str = ""
    unit: str = ""
    kind: type[Term] = field(kw_only=True)

    @property
    def key(self) -> str:
        return f"{self.effect}@{self.output}"

    @property
    def location(self) -> str:
        return f"sensor of {self.output}"

    def terms(self, theta: np.ndarray) -> list[Term]:
        return [self._term(theta, output=self.output)]

    def phrase(self, theta: np.ndarray) -> str:
        return self._said(theta, self.output)


# ---------------------------------------------------------------------------- vocabulary
@dataclass(frozen=True)
class DataScales:
    """Typical sizes of the signals, which set every hypothesis' scale.

    Attributes
    ----------
    input_rms : dict[str, float]
        FMU input -> RMS of its recorded values.
    output_rms : dict[str, float]
        FMU output -> RMS of its white-box prediction.
    dt : float
        Sample time [s].
    force_sense : dict[tuple[str, str], float]
        (force input, velocity or position output) -> +1 when a positive input force opposes
        positive velocity (of the position), -1 when it aids it.
    input_span : dict[str, tuple[float, float]]
        FMU input -> least and largest recorded value.
    output_start : dict[str, float]
        FMU output -> its white-box value at the start.
    rate_rms : dict[str, float]
        Position output -> RMS of the rate of its white-box prediction.
    """

    input_rms: dict[str, float]
    output_rms: dict[str, float]
    dt: float
    force_sense: dict[tuple[str, str], float] = field(default_factory=dict)
    input_span: dict[str, tuple[float, float]] = field(default_factory=dict)
    output_start: dict[str, float] = field(default_factory=dict)
    rate_rms: dict[str, float] = field(default_factory=dict)


def generate_hypotheses(
    signals: SignalMap,
    archive: FmuArchive,
    scales: DataScales,
    parameters: dict[str, float],
) -> list[Hypothesis]:
    """The hypotheses a project's roles and its FMU's declarations allow.

    Parameters
    ----------
    signals : SignalMap
    archive : FmuArchive
    scales : DataScales
    parameters : dict[str, float]
        Project parameter values (override the FMU's start values as nominal values).

    Returns
    -------
    list of Hypothesis
    """
    hypotheses: list[Hypothesis] = []
    hypotheses += _parameter_hypotheses(archive, parameters)
    hypotheses += _command_hypotheses(signals, scales)
    hypotheses += _force_hypotheses(signals, scales)
    hypotheses += _droop_hypotheses(signals, scales)
    hypotheses += _sensor_hypotheses(signals, scales)
    return hypotheses


def _parameter_hypotheses(archive: FmuArchive, parameters: dict[str, float]) -> list[Hypothesis]:
    found = []
    for var in archive.variables.values():
        if var.causality != "parameter" or var.variability != "tunable" or var.type != "Real":
            continue
        nominal = parameters.get(var.name, var.start)
        if nominal is None or nominal == 0.0 or not math.isfinite(nominal):
            continue
        lower, upper = _relative_range(float(nominal), var.minimum, var.maximum)
        if lower >= upper:
            continue
        found.append(
            ParameterMismatch(
                name=var.name,
                nominal=float(nominal),
                unit=var.unit,
                description=var.description,
                scale=(0.05,),
                lower=(lower,),
                upper=(upper,),
            )
        )
    return found


def _relative_range(
    nominal: float, minimum: float | None, maximum: float | None
) -> tuple[float, float]:
    """Admissible relative changes of a parameter: a tenth to a hundred times its set value
    (leakages and friction coefficients drift by orders of magnitude), within the range the FMU
    declares for it."""
    lower, upper = PARAMETER_RANGE
    for value, is_minimum in ((minimum, True), (maximum, False)):
        if value is None:
            continue
        change = value / nominal - 1.0
        if is_minimum == (nominal > 0):
            lower = max(lower, change)
        else:
            upper = min(upper, change)
    return lower, upper


def _command_hypotheses(signals: SignalMap, scales: DataScales) -> list[Hypothesis]:
    found: list[Hypothesis] = []
    n_stages = len(signals.stage_names)
    dt = scales.dt
    for name in signals.inputs_with_role("current", "voltage"):
        rms = scales.input_rms.get(name, 0.0)
        stage = signals.input_stage.get(name)
        if rms <= 0 or stage is None:
            continue
        unit = signals.units.get(name, "")
        entries = [(stage, "")]
        if stage + 1 < n_stages:
            entries.append((stage + 1, signals.stage_names[stage]))
        for entry, after in entries:
            common = {"input": name, "unit": unit, "downstream_of": after, "entry": entry}
            found += [
                InputError(**common, kind=kind, **_range(kind.proposal, rms, dt))
                for kind in proposed("command")
            ]
        found += _saturations(name, unit, stage, scales.input_span.get(name, (0.0, 0.0)))
    return found


def _saturations(name: str, unit: str, stage: int, span: tuple[float, float]) -> list[Hypothesis]:
    """Saturations of a command input whose recorded values span ``span``: "no effect" is the
    recorded range, the limits may come down to a twentieth of it."""
    low, high = span
    largest = max(abs(low), abs(high))
    if largest <= 0:
        return []
    common = {"input": name, "unit": unit, "entry": stage}
    found: list[Hypothesis] = [
        Saturation(**common, scale=(0.1 * largest,), lower=(0.05 * largest,), upper=(largest,))
    ]
    if low < 0 < high:
        found.append(
            AsymmetricSaturation(
                **common,
                scale=(0.1 * high, 0.1 * -low),
                lower=(0.05 * high, low),
                upper=(high, 0.05 * low),
            )
        )
    return found


def _force_hypotheses(signals: SignalMap, scales: DataScales) -> list[Hypothesis]:
    """At every force input: a constant force, a spring from each position output, and the
    friction forces fed back from each velocity output (from the rate of each position output
    when the FMU has no velocity output)."""
    found: list[Hypothesis] = []
    positions = [p for p in signals.outputs_with_role("position") if p in scales.output_rms]
    sources = [(v, False) for v in signals.outputs_with_role("velocity")]
    sources = sources or [(p, True) for p in positions]
    for name in signals.inputs_with_role("force"):
        stage = signals.input_stage.get(name)
        if stage is None:
            continue
        force = max(scales.input_rms.get(name, 0.0), 1e-12)
        unit = signals.units.get(name, "")
        found += [
            InputError(input=name, unit=unit, kind=kind, **_range(kind.proposal, force, scales.dt))
            for kind in proposed("force")
        ]
        for position in positions:
            x_rms = scales.output_rms[position]
            if x_rms <= 0:
                continue
            found.append(
                Stiffness(
                    input=name,
                    position=position,
                    force_unit=unit,
                    position_unit=signals.units.get(position, ""),
                    rest=scales.output_start.get(position, 0.0),
                    opposes=scales.force_sense.get((name, position), 1.0),
                    scale=(0.05 * force / x_rms,),
                )
            )
        for source, rate in sources:
            found += _frictions(signals, scales, name, source, rate, force)
    return found


def _frictions(
    signals: SignalMap, scales: DataScales, force_input: str, source: str, rate: bool, force: float
) -> list[Hypothesis]:
    """Coulomb (symmetric or not), viscous and Stribeck forces on ``force_input`` fed back from
    ``source`` (a velocity output, or a position output's rate)."""
    v_rms = (scales.rate_rms if rate else scales.output_rms).get(source, 0.0)
    if v_rms <= 0:
        return []
    unit = signals.units.get(source, "")
    common = {
        "input": force_input,
        "velocity": source,
        "force_unit": signals.units.get(force_input, ""),
        "velocity_unit": f"{unit}/s" if rate and unit else unit,
        "smoothing": 0.03 * v_rms,
        "rate": rate,
        "opposes": scales.force_sense.get((force_input, source), 1.0),
    }
    return [
        CoulombFriction(**common, scale=(0.05 * force,)),
        AsymmetricCoulombFriction(**common, scale=(0.05 * force, 0.05 * force)),
        ViscousFriction(**common, scale=(0.05 * force / v_rms,)),
        StribeckFriction(
            **common,
            scale=(0.05 * force, 0.3 * v_rms),
            lower=(-math.inf, 0.05 * v_rms),
            upper=(math.inf, 5.0 * v_rms),
        ),
    ]


def _droop_hypotheses(signals: SignalMap, scales: DataScales) -> list[Hypothesis]:
    found: list[Hypothesis] = []
    for name in signals.inputs_with_role("pressure"):
        p_rms = scales.input_rms.get(name, 0.0)
        stage = signals.input_stage.get(name)
        if p_rms <= 0 or stage is None:
            continue
        for flow in signals.outputs_with_role("flow"):
            q_rms = scales.output_rms.get(flow, 0.0)
            if q_rms <= 0:
                continue
            found.append(
                SupplyDroop(
                    input=name,
                    flow=flow,
                    pressure_unit=signals.units.get(name, ""),
                    flow_unit=signals.units.get(flow, ""),
                    scale=(0.01 * p_rms / q_rms,),
                )
            )
    return found


def _sensor_hypotheses(signals: SignalMap, scales: DataScales) -> list[Hypothesis]:
    """A delay of every observed sensor together, and a gain error, an offset and a delay of
    each observed signal's sensor alone."""
    if not signals.observed:
        return []
    dt = scales.dt
    delay = {"scale": (2 * dt,), "lower": (0.0,), "upper": (50 * dt,)}
    found: list[Hypothesis] = [SensorLag(outputs=tuple(signals.observed_variables), **delay)]
    for sig in signals.observed:
        size = scales.output_rms.get(sig.variable, 0.0) or 1.0
        found += [
            SensorFault(
                output=sig.variable, unit=sig.unit, kind=kind, **_range(kind.proposal, size, dt)
            )
            for kind in proposed("sensor")
        ]
    return found


def proposed(at: str) -> list[type[Term]]:
    """The term kinds the diagnosis proposes alone at ``at`` (``"command"``, ``"force"``,
    ``"sensor"``), in the order of :data:`~fmu_greybox.model.terms.TERM_KINDS`."""
    return [k for k in TERM_KINDS.values() if k.proposal is not None and k.proposal.at == at]


def _range(proposal: Proposal, size: float, dt: float) -> dict[str, tuple[float]]:
    """A proposed magnitude's scale and admissible range: the proposal's, in units of its
    reference (1 for a unit ``"1"``, the sample time ``dt`` for ``"s"``, the signal's typical
    ``size`` for the signal's own unit)."""
    reference = {"1": 1.0, "s": dt}.get(proposal.unit, size)
    return {
        "scale": (proposal.scale * reference,),
        "lower": (proposal.lower * reference,),
        "upper": (proposal.upper * reference,),
    }
