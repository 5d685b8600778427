"""Synthetic recordings of the reference actuator, made the way a flight test makes them.

The truth FMU (the white-box physics plus optional concealed effects) runs in closed loop: a
position controller follows a pilot-like reference (steps, ramps, multi-sines), the ram carries
an aerodynamic spring load plus turbulence, the supply pressure ripples and drifts. The recording
keeps the valve current the controller produced, so driving the white-box open-loop with it
reproduces a flight-test situation: small mismatches drift.

Sensors add white noise of realistic size (scaled by ``noise``; 0 gives a clean recording) to
every recorded signal, the recorded inputs included: the logged valve current carries the noise
of its current sensor (the valve received the controller's value), as a flight-test log does.
Faults around the plant (an amplifier that saturates, a sensor that reads high, a load nobody
recorded) are switched on by name beside the truth FMU's effects (:mod:`.loop`).
Columns carry the white-box FMU's own variable names and units.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from fmu_greybox.data.recording import Recording
from fmu_greybox.errors import ConfigError
from fmu_greybox.fmi.archive import FmuArchive, FmuVariable, real_outputs
from fmu_greybox.fmi.instance import fmu_instance
from fmu_greybox.progress import track
from fmu_greybox.suggest import did_you_mean
from fmu_greybox.synth.loop import Loop, is_loop_effect, parse_loop_effects
from fmu_greybox.units import normalise_unit

#: Standard deviation of each sensor's white noise at ``noise = 1`` [SI units of the signal].
SENSOR_NOISE: dict[str, float] = {
    "valve_current": 0.02,
    "engage": 0.01,
    "supply_pressure": 2.0e4,
    "load_force": 20.0,
    "spool_position": 1.0e-6,
    "spool_velocity": 3.0e-4,
    "ram_position": 2.0e-5,
    "ram_velocity": 1.0e-3,
    "itfv_pressure": 2.0e4,
    "pressure_a": 2.0e4,
    "pressure_b": 2.0e4,
    "load_flow": 3.0e-7,
    "relief_flow": 3.0e-7,
    "supply_flow": 3.0e-7,
}

INPUTS = ("valve_current", "supply_pressure", "load_force", "engage")


#: A small and a large magnitude of each truth effect of the reference actuator, in the truth
#: model's units: small is near what a diagnosis can just see through sensor noise, large is a
#: clear fault. The demo draws from this range; the concealed-effects benchmark uses both ends.
TYPICAL_MAGNITUDES: dict[str, tuple[float, ...]] = {
    "gain_error": (0.03, 0.1),
    "offset": (0.1, 0.3),
    "deadband": (5e-6, 2e-5),
    "coulomb_friction": (300.0, 900.0),
    "stribeck_friction": (500.0, 1200.0),
    "internal_leakage": (3e-13, 1.5e-12),
    "compliance": (0.2, 0.4),
    "supply_pressure_droop": (5e9, 2e10),
    "time_delay": (0.002, 0.005),
}


@dataclass(frozen=True)
class FlightTestProfile:
    """The closed-loop test: controller, reference, load and supply settings.

    Attributes
    ----------
    duration : float
        Length of the recording [s].
    dt : float
        Sample time [s] (1 kHz by default).
    position_gain : float
        Proportional position-loop gain [mA/m].
    current_limit : float
        Controller output saturation [mA].
    reference_amplitude : float
        Largest commanded ram position [m].
    aero_stiffness : float
        Aerodynamic spring load per metre of ram travel [N/m].
    turbulence_force : float
        Standard deviation of the turbulence load [N].
    turbulence_time : float
        Correlation time of the turbulence load [s].
    supply_pressure : float
        Nominal supply pressure [Pa].
    supply_ripple : float
        Amplitude of the pump ripple [Pa].
    supply_ripple_frequency : float
        Pump ripple frequency [Hz].
    supply_drift : float
        Standard deviation of the slow supply drift [Pa].
    ramp_rate : float or None
        ``None``: the pilot-like reference (:func:`pilot_reference`); a rate [m/s]: holds and
        ramps at this one rate only (:func:`ramp_reference`), a test with few velocity levels.
    """

    duration: float = 30.0
    dt: float = 1e-3
    position_gain: float = 2000.0
    current_limit: float = 10.0
    reference_amplitude: float = 0.03
    aero_stiffness: float = 8.0e4
    turbulence_force: float = 1500.0
    turbulence_time: float = 0.3
    supply_pressure: float = 20.7e6
    supply_ripple: float = 1.0e5
    supply_ripple_frequency: float = 37.0
    supply_drift: float = 2.0e5
    ramp_rate: float | None = None

    @property
    def n_samples(self) -> int:
        """Number of samples in the recording."""
        return round(self.duration / self.dt) + 1


@dataclass(frozen=True)
class SynthRequest:
    """What to record: effects switched on in the truth model, seed, noise level.

    Attributes
    ----------
    effects : dict[str, float]
        Truth-model effect parameter -> value (units as the truth FMU declares).
    seed : int
        Seed of every random choice (reference, turbulence, noise).
        Names with ``@`` are effects around the FMU (:mod:`.loop`), e.g.
        ``sensor_gain@ram_position``.
    seed : int
        Seed of every random choice (reference, turbulence, noise).
    noise : float
        Sensor-noise scale factor (0 = noise-free).
    profile : FlightTestProfile
        The closed-loop test.
    input_noise : bool
        Whether the recorded inputs carry sensor noise too (the outputs always do, at
        ``noise``).
    """

    effects: dict[str, float] = field(default_factory=dict)
    seed: int = 0
    noise: float = 1.0
    profile: FlightTestProfile = field(default_factory=FlightTestProfile)
    input_noise: bool = True


def list_effects(truth: FmuArchive, whitebox: FmuArchive) -> list[FmuVariable]:
    """The concealed effects the truth FMU offers: its parameters the white-box lacks.

    Returns
    -------
    list of FmuVariable
        In declaration order, each with its unit and description.
    """
    known = set(whitebox.variables)
    return [
        v for v in truth.variables.values() if v.causality == "parameter" and v.name not in known
    ]


def typical_range(effect: FmuVariable) -> str:
    """An effect's :data:`TYPICAL_MAGNITUDES` with its unit, as ``synth --list-effects`` shows it.

    Returns
    -------
    str
        E.g. ``"typical 300 to 900 N"`` (no unit for a dimensionless one); ``"-"`` for an
        effect without typical magnitudes (a shape parameter of another, or one not drawn).
    """
    if effect.name not in TYPICAL_MAGNITUDES:
        return "-"
    low, high = TYPICAL_MAGNITUDES[effect.name][0], TYPICAL_MAGNITUDES[effect.name][-1]
    unit = "" if normalise_unit(effect.unit) == "" else f" {effect.unit}"
    return f"typical {low:g} to {high:g}{unit}"


def parse_effects(texts: list[str] | tuple[str, ...]) -> dict[str, float]:
    """Parse ``NAME=VALUE`` items of the command line.

    Raises
    ------
    ConfigError
        If an item is not of that form or its value is not a finite number.
    """
    effects: dict[str, float] = {}
    for text in texts:
        name, sep, value = text.partition("=")
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not sep or not name.strip() or not math.isfinite(number):
            raise ConfigError(
                f"effect {text!r} is not NAME=VALUE with a finite number, e.g. "
                "--effect coulomb_friction=800",
                field="--effect",
            )
        effects[name.strip()] = number
    return effects


def check_effects(effects: Mapping[str, float], truth: FmuArchive, whitebox: FmuArchive) -> None:
    """Raise :class:`ConfigError` for an effect the truth FMU does not offer, or a loop effect
    (:mod:`.loop`) on a variable it lacks."""
    offered = [v.name for v in list_effects(truth, whitebox)]
    parse_loop_effects(effects, truth.inputs, real_outputs(truth))
    for name in effects:
        if name not in offered and not is_loop_effect(name):
            raise ConfigError(
                f"unknown effect {name!r}{did_you_mean(name, offered)}; effects offered: "
                f"{', '.join(offered)} "
                "(see 'fmu-greybox synth --list-effects')",
                field="--effect",
            )


def pilot_reference(n: int, dt: float, amplitude: float, rng: np.random.Generator) -> np.ndarray:
    """A pilot-like position reference: holds, steps, ramps and multi-sine segments.

    Parameters
    ----------
    n : int
        Number of samples.
    dt : float
        Sample time [s].
    amplitude : float
        Largest commanded position [m].
    rng : numpy.random.Generator
        Source of the random choices.

    Returns
    -------
    ndarray, shape (n,)
        Commanded ram position [m].
    """
    r = np.empty(n)
    level, k = 0.0, 0
    while k < n:
        kind = rng.choice(("step", "ramp", "multisine"), p=(0.4, 0.3, 0.3))
        length = int(rng.uniform(0.6, 2.5) / dt)
        end = min(n, k + length)
        t = np.arange(end - k) * dt
        target = rng.uniform(-0.8, 0.8) * amplitude
        if kind == "step":
            r[k:end] = target
            level = target
        elif kind == "ramp":
            ramp_time = rng.uniform(0.3, 0.8) * length * dt
            r[k:end] = level + (target - level) * np.clip(t / ramp_time, 0.0, 1.0)
            level = target if end - k > 0 and t[-1] >= ramp_time else float(r[end - 1])
        else:
            freqs = np.exp(rng.uniform(np.log(0.2), np.log(6.0), size=5))
            phases = rng.uniform(0, 2 * np.pi, size=5)
            weights = rng.uniform(0.3, 1.0, size=5)
            weights *= 0.25 * amplitude / weights.sum()
            wave = (
                weights[:, None] * np.sin(2 * np.pi * freqs[:, None] * t + phases[:, None])
            ).sum(0)
            r[k:end] = np.clip(level + wave - wave[0], -amplitude, amplitude)
            level = float(r[end - 1])
        k = end
    return r


def ramp_reference(
    n: int, dt: float, amplitude: float, rate: float, rng: np.random.Generator
) -> np.ndarray:
    """A reference with few velocity levels: holds, and ramps at ``+/- rate`` between them.

    Parameters
    ----------
    n : int
        Number of samples.
    dt : float
        Sample time [s].
    amplitude : float
        Largest commanded position [m].
    rate : float
        The one ramp rate [m/s].
    rng : numpy.random.Generator
        Source of the random choices.

    Returns
    -------
    ndarray, shape (n,)
        Commanded position [m].
    """
    r = np.empty(n)
    level, k = 0.0, 0
    while k < n:
        target = rng.uniform(-0.8, 0.8) * amplitude
        ramp = max(1, round(abs(target - level) / rate / dt))
        hold = int(rng.uniform(0.3, 1.0) / dt)
        end = min(n, k + ramp)
        r[k:end] = level + (target - level) * np.arange(1, end - k + 1) / ramp
        level = float(r[end - 1])
        r[end : min(n, end + hold)] = level
        k = min(n, end + hold)
    return r


def coloured_noise(
    n: int, dt: float, std: float, tau: float, rng: np.random.Generator
) -> np.ndarray:
    """First-order (Ornstein-Uhlenbeck) noise with standard deviation ``std``, time ``tau``.

    Returns
    -------
    ndarray, shape (n,)
    """
    a = math.exp(-dt / tau)
    w = rng.standard_normal(n) * std * math.sqrt(1 - a * a)
    x = np.empty(n)
    x[0] = rng.standard_normal() * std
    for k in range(1, n):
        x[k] = a * x[k - 1] + w[k]
    return x


def synthesise(
    truth: FmuArchive, whitebox: FmuArchive, request: SynthRequest, progress: bool = False
) -> Recording:
    """Record the truth FMU in closed loop.

    Parameters
    ----------
    truth, whitebox : FmuArchive
        The truth FMU that is run, and the white-box FMU whose variable names and units the
        recording carries.
    request : SynthRequest
        Effects, seed, noise level and the test profile.
    progress : bool
        Show a progress bar.

    Returns
    -------
    Recording
        Columns: every white-box input then every white-box Real output.
    """
    check_effects(request.effects, truth, whitebox)
    profile = request.profile
    rng = np.random.default_rng(request.seed)
    n, dt = profile.n_samples, profile.dt
    time = np.arange(n) * dt
    if profile.ramp_rate is None:
        reference = pilot_reference(n, dt, profile.reference_amplitude, rng)
    else:
        reference = ramp_reference(n, dt, profile.reference_amplitude, profile.ramp_rate, rng)
    turbulence = coloured_noise(n, dt, profile.turbulence_force, profile.turbulence_time, rng)
    supply = (
        profile.supply_pressure
        + profile.supply_ripple * np.sin(2 * np.pi * profile.supply_ripple_frequency * time)
        + coloured_noise(n, dt, profile.supply_drift, 2.0, rng)
    )
    outputs = real_outputs(whitebox)
    sensor = {name: SENSOR_NOISE.get(name, 0.0) * request.noise for name in (*INPUTS, *outputs)}
    if not request.input_noise:
        sensor.update(dict.fromkeys(INPUTS, 0.0))
    noise = {name: rng.standard_normal(n) * s for name, s in sensor.items()}
    u, y = _closed_loop(truth, request, outputs, reference, turbulence, supply, noise, progress)
    signals = {name: u[:, j] + noise[name] for j, name in enumerate(INPUTS)}
    signals.update({name: y[:, j] + noise[name] for j, name in enumerate(outputs)})
    units = {name: whitebox.variable(name).unit for name in signals}
    stride = max(1, n // 2000)
    metadata = {
        "generator": "fmu-greybox synth",
        "truth_fmu": truth.path.name,
        "effects": json.dumps(request.effects, sort_keys=True),
        "seed": str(request.seed),
        "noise": repr(request.noise),
        "input_noise": str(request.input_noise).lower(),
        "reference_step": repr(dt * stride),
        "reference": json.dumps(reference[::stride].round(6).tolist()),
    }
    return Recording(time=time, signals=signals, units=units, source="synth", metadata=metadata)


def _closed_loop(
    truth: FmuArchive,
    request: SynthRequest,
    outputs: list[str],
    reference: np.ndarray,
    turbulence: np.ndarray,
    supply: np.ndarray,
    noise: Mapping[str, np.ndarray],
    progress: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Run the controller and the truth FMU sample by sample, with the loop effects.

    Returns
    -------
    u : ndarray, shape (n, 4)
        Inputs the loop commanded (valve current, supply pressure, load force, engage), before
        any loop effect on the inputs.
    y : ndarray, shape (n, n_outputs)
        Noise-free outputs as the sensors report them, ``y[k]`` observed before ``u[k]`` acts.
    """
    profile = request.profile
    n = reference.size
    ram = outputs.index("ram_position")
    u = np.empty((n, len(INPUTS)))
    y = np.empty((n, len(outputs)))
    loop = Loop(request.effects, INPUTS, outputs, profile.dt)
    parameters = {k: v for k, v in request.effects.items() if not is_loop_effect(k)}
    start = {"supply_pressure": float(supply[0]), "engage": 1.0}
    with fmu_instance(truth, INPUTS, outputs, parameters, start, "synth") as inst:
        true = inst.read_outputs().copy()
        for k in track(range(n), "Recording the truth model in closed loop", n, progress):
            y[k] = loop.sensed(true)
            measured = y[k, ram] + noise["ram_position"][k]
            current = profile.position_gain * (reference[k] - measured)
            current = min(max(current, -profile.current_limit), profile.current_limit)
            force = profile.aero_stiffness * true[ram] + turbulence[k]
            u[k] = (current, supply[k], force, 1.0)
            if k + 1 < n:
                true = inst.step(loop.applied(u[k], true), profile.dt).copy()
    return u, y
