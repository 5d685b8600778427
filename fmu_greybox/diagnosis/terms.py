"""Named correction terms and the runner that steps a white-box FMU with them.

A term corrects the white-box where the physics enters, step by step, the way a co-simulation
master would apply it:

* at an FMU **input**, from the recorded input (:meth:`Term.on_input`): a gain, an offset, a
  deadband or a delay of a command, applied once per communication step; or fed back from the
  FMU outputs (``feedback`` terms): a missing force from a velocity, a supply pressure drooping
  with a flow. Feedback terms are explicit couplings, so the runner splits each communication
  step into ``substeps`` FMU steps (the recorded input held) and recomputes them at each: a stiff
  feedback such as a Coulomb force around zero velocity then neither chatters nor lags;
* as FMU **parameter** values set before initialisation (:meth:`Term.parameters`);
* at the FMU **outputs** the sensors see (:meth:`Term.on_output`): a sensor delay.

A term acts on the stages from its ``entry`` stage on: stages before it keep the plain white-box
outputs. A term entering after the first stage models physics between two stages (e.g. a dead
zone between a valve's spool and its metering edges): :func:`simulate_with_terms` runs one FMU
instance per distinct entry stage and takes each observed output from the instance of its stage.

Terms are small dataclasses, picklable, and round-trip through :meth:`Term.to_dict` /
:func:`term_from_dict` so that a later run (or the co-simulation master) can rebuild them from
``diagnosis.json``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields

import numpy as np

from ..fmu_archive import FmuArchive
from ..fmu_instance import FmuInstance


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
    """

    entry: int = field(default=0, kw_only=True)

    #: Vocabulary identifier of the effect the term models (DESIGN.md section 5).
    effect = ""
    #: Whether :meth:`on_input` / :meth:`on_output` do anything (the runner skips the others).
    acts_on_inputs = False
    acts_on_outputs = False
    #: Whether :meth:`on_input` reads the FMU outputs (then it is applied at every sub-step).
    feedback = False

    def parameters(self) -> dict[str, float]:
        """FMU parameter values this term sets before initialisation."""
        return {}

    def needs(self) -> tuple[str, ...]:
        """FMU outputs the term reads in :meth:`on_input`."""
        return ()

    def bind(self, inputs: Sequence[str], outputs: Sequence[str], dt: float) -> None:
        """Resolve names to positions and reset any memory before a run."""

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        """Correct this step's FMU inputs ``u`` in place, given the outputs ``y`` at its start."""

    def on_output(self, y: np.ndarray) -> None:
        """Correct the outputs the sensors report, in place, after a step."""

    def to_dict(self) -> dict:
        """The term as plain data (``kind`` names the class)."""
        return {"kind": type(self).__name__, **asdict(self)}


@dataclass
class ParameterChange(Term):
    """A mis-set FMU parameter: ``name`` takes ``value``."""

    name: str = ""
    value: float = 0.0
    effect = "parameter_mismatch"

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

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        u[self._i] *= 1.0 + self.gain


@dataclass
class InputOffset(_InputTerm):
    """A constant ``offset`` is added to the input (a null bias)."""

    offset: float = 0.0
    effect = "offset"

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        u[self._i] += self.offset


@dataclass
class InputDeadband(_InputTerm):
    """Inputs within ``+/- width`` of zero act as zero; larger ones lose ``width``."""

    width: float = 0.0
    effect = "deadband"

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        x = u[self._i]
        u[self._i] = math.copysign(max(abs(x) - self.width, 0.0), x)


@dataclass
class InputDelay(_InputTerm):
    """The input acts ``delay`` seconds late."""

    delay: float = 0.0
    effect = "time_delay"

    def bind(self, inputs: Sequence[str], outputs: Sequence[str], dt: float) -> None:
        super().bind(inputs, outputs, dt)
        self._line = DelayLine(max(self.delay, 0.0) / dt, 1)
        self._x = np.empty(1)

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        self._x[0] = u[self._i]
        u[self._i] = self._line(self._x)[0]


@dataclass
class _FeedbackInput(_InputTerm):
    """An input term computed from one FMU output of the previous (sub-)step."""

    source: str = ""
    feedback = True

    def needs(self) -> tuple[str, ...]:
        return (self.source,)

    def bind(self, inputs: Sequence[str], outputs: Sequence[str], dt: float) -> None:
        super().bind(inputs, outputs, dt)
        self._o = list(outputs).index(self.source)

    def on_input(self, u: np.ndarray, y: np.ndarray) -> None:
        u[self._i] += self.value(float(y[self._o]))

    def value(self, x: float) -> float:
        """What is added to the input for the source output at ``x``."""
        raise NotImplementedError


@dataclass
class CoulombForce(_FeedbackInput):
    """A force ``force * tanh(v / smoothing)`` added to a force input (``v``: the source)."""

    force: float = 0.0
    smoothing: float = 1e-3
    effect = "coulomb_friction"

    def value(self, x: float) -> float:
        return self.force * math.tanh(x / self.smoothing)


@dataclass
class ViscousForce(_FeedbackInput):
    """A force ``coefficient * v`` added to a force input."""

    coefficient: float = 0.0
    effect = "viscous_friction"

    def value(self, x: float) -> float:
        return self.coefficient * x


@dataclass
class StribeckForce(_FeedbackInput):
    """A breakaway force ``force * exp(-(v / velocity)^2) * tanh(v / smoothing)``."""

    force: float = 0.0
    velocity: float = 1e-2
    smoothing: float = 1e-3
    effect = "stribeck_friction"

    def value(self, x: float) -> float:
        return self.force * math.exp(-((x / self.velocity) ** 2)) * math.tanh(x / self.smoothing)


@dataclass
class FlowDroop(_FeedbackInput):
    """A pressure input drops by ``resistance * Q`` (``Q``: the source flow)."""

    resistance: float = 0.0
    effect = "supply_pressure_droop"

    def value(self, x: float) -> float:
        return -self.resistance * x


@dataclass
class SensorDelay(Term):
    """The sensors of ``outputs`` report their values ``delay`` seconds late (those of them
    that a run reads)."""

    outputs: tuple[str, ...] = ()
    delay: float = 0.0
    effect = "time_delay"
    acts_on_outputs = True

    def bind(self, inputs: Sequence[str], outputs: Sequence[str], dt: float) -> None:
        self._j = np.array([j for j, n in enumerate(outputs) if n in self.outputs], dtype=int)
        self._line = DelayLine(max(self.delay, 0.0) / dt, self._j.size)

    def on_output(self, y: np.ndarray) -> None:
        y[self._j] = self._line(y[self._j])

    def to_dict(self) -> dict:
        return {**super().to_dict(), "outputs": list(self.outputs)}


#: Largest number of runs :func:`simulate_with_terms` keeps in a cache.
CACHE_SIZE = 8

TERM_KINDS: dict[str, type[Term]] = {
    cls.__name__: cls
    for cls in (
        ParameterChange,
        InputGain,
        InputOffset,
        InputDeadband,
        InputDelay,
        CoulombForce,
        ViscousForce,
        StribeckForce,
        FlowDroop,
        SensorDelay,
    )
}


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
    if "outputs" in data:
        data["outputs"] = tuple(data["outputs"])
    return cls(**data)


def simulate_with_terms(
    archive: FmuArchive,
    inputs: Sequence[str],
    u: np.ndarray,
    dt: float,
    outputs: Sequence[str],
    terms: Sequence[Term] = (),
    parameters: Mapping[str, float] | None = None,
    stages: Sequence[int] | None = None,
    start_time: float = 0.0,
    substeps: int = 4,
    cache: dict | None = None,
) -> np.ndarray:
    """Run the white-box open-loop over recorded inputs with correction terms applied.

    Timing as :func:`fmu_greybox.simulate.run_open_loop`: row 0 is the initial output, row
    ``k + 1`` the output after the step that applied (the corrected) ``u[k]``; a feedback term
    computes its correction from the outputs at the start of each sub-step.

    Parameters
    ----------
    archive : FmuArchive
        The white-box FMU.
    inputs : sequence of str
        FMU inputs, one per column of ``u``.
    u : ndarray, shape (n, len(inputs))
        Recorded inputs.
    dt : float
        Communication step [s].
    outputs : sequence of str
        FMU outputs returned.
    terms : sequence of Term
        Corrections applied.
    parameters : mapping, optional
        Project parameter values (terms' parameter values override them).
    stages : sequence of int, optional
        Stage index of every output (default 0): an output of stage ``s`` sees the terms with
        ``entry <= s`` only.
    start_time : float
        Time of row 0 [s].
    substeps : int
        FMU steps per communication step when a feedback term is active.
    cache : dict, optional
        Results of earlier runs by (terms, outputs, rows): a run whose active terms, outputs
        and length match one in it is not repeated (the stages before a late-entering term
        usually match the plain run). Bounded to :data:`CACHE_SIZE` entries.

    Returns
    -------
    ndarray, shape (n, len(outputs))

    Raises
    ------
    FmuError
        If the FMU fails (e.g. a correction drives it out of its valid range).
    """
    stages = list(stages) if stages is not None else [0] * len(outputs)
    levels = sorted({0, *(t.entry for t in terms)})
    y = np.empty((u.shape[0], len(outputs)))
    for i, level in enumerate(levels):
        upper = levels[i + 1] if i + 1 < len(levels) else math.inf
        cols = [j for j, s in enumerate(stages) if level <= s < upper]
        if not cols:
            continue
        active = [t for t in terms if t.entry <= level]
        names = [outputs[j] for j in cols]
        key = (repr([t.to_dict() for t in active]), tuple(names), u.shape[0])
        if cache is not None and key in cache:
            y[:, cols] = cache[key]
            continue
        y[:, cols] = _run(archive, inputs, u, dt, names, active, parameters, start_time, substeps)
        if cache is not None:
            while len(cache) >= CACHE_SIZE:
                cache.pop(next(iter(cache)))
            cache[key] = y[:, cols].copy()
    return y


def _run(
    archive: FmuArchive,
    inputs: Sequence[str],
    u: np.ndarray,
    dt: float,
    outputs: list[str],
    terms: list[Term],
    parameters: Mapping[str, float] | None,
    start_time: float,
    substeps: int,
) -> np.ndarray:
    """One FMU instance stepped with ``terms``; returns the columns of ``outputs``."""
    bound = list(outputs)
    for term in terms:
        bound += [name for name in term.needs() if name not in bound]
    values = dict(parameters or {})
    for term in terms:
        values.update(term.parameters())
    once = [t for t in terms if t.acts_on_inputs and not t.feedback]
    fed = [t for t in terms if t.acts_on_inputs and t.feedback]
    after = [t for t in terms if t.acts_on_outputs]
    sub = max(1, int(substeps)) if fed else 1
    h = dt / sub
    n, m = u.shape[0], len(outputs)
    y = np.empty((n, m))
    with FmuInstance(
        archive,
        inputs=inputs,
        outputs=bound,
        parameters=values,
        start_values=dict(zip(inputs, u[0], strict=True)),
        start_time=start_time,
    ) as instance:
        for term in terms:
            term.bind(inputs, bound, dt)
        current = instance.read_outputs().copy()
        sensed = current.copy()
        for term in after:
            term.on_output(sensed)
        y[0] = sensed[:m]
        held = np.empty(u.shape[1])
        row = np.empty(u.shape[1])
        for k in range(n - 1):
            held[:] = u[k]
            for term in once:
                term.on_input(held, current)
            for _ in range(sub):
                row[:] = held
                for term in fed:
                    term.on_input(row, current)
                current = instance.step(row, h)
            if after:
                sensed[:] = current
                for term in after:
                    term.on_output(sensed)
                y[k + 1] = sensed[:m]
            else:
                y[k + 1] = current[:m]
    return y
