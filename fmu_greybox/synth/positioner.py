"""Synthetic recordings of the electro-mechanical positioner, made in closed loop.

The truth FMU ``ElectroMechanicalPositionerTruth`` (the white-box physics plus optional concealed
effects) is driven by a digital PI position controller at the sample rate: it follows a
pilot-like reference (holds, steps, ramps, multi-sines) against a turbulent external load. The
drive saturates the armature voltage at the bus voltage and limits the armature current through
the back-EMF it expects from the motor's nominal data. The recording keeps the voltage the drive
applied, so driving the white-box open-loop with it shows how the mismatches drift.

The generic pieces (reference, coloured noise, effect check, FMU instance) are the actuator
recorder's (:mod:`fmu_greybox.synth.actuator`); only the controller and the sensor set are this
model's.
Columns carry the white-box FMU's variable names and units.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from fmu_greybox.data.recording import Recording
from fmu_greybox.fmi.archive import FmuArchive, real_outputs
from fmu_greybox.fmi.instance import fmu_instance
from fmu_greybox.synth.actuator import check_effects, coloured_noise, pilot_reference

INPUTS = ("motor_voltage", "load_force")

#: Standard deviation of each sensor's white noise at ``noise = 1`` [SI units of the signal].
SENSOR_NOISE: dict[str, float] = {
    "motor_voltage": 0.02,
    "load_force": 5.0,
    "motor_current": 0.05,
    "motor_speed": 0.5,
    "position": 5.0e-6,
    "velocity": 5.0e-4,
    "transmission_deflection": 2.0e-8,
    "transmission_force": 5.0,
}


@dataclass(frozen=True)
class PositionerProfile:
    """The closed-loop test of the positioner: controller, drive limits, reference, load.

    Attributes
    ----------
    dt : float
        Sample and control period [s].
    position_gain : float
        Proportional gain K_p of the position controller [V/m].
    integral_time : float
        Integral time T_i of the position controller [s].
    bus_voltage : float
        Drive supply: the voltage is saturated to +/- this [V].
    current_limit : float
        Armature current the drive allows in steady state [A].
    reference_amplitude : float
        Largest commanded load position [m].
    turbulence_force : float
        Standard deviation of the external (turbulence) load [N].
    turbulence_time : float
        Correlation time of the turbulence load [s].
    """

    dt: float = 1e-3
    position_gain: float = 1.5e4
    integral_time: float = 0.05
    bus_voltage: float = 28.0
    current_limit: float = 20.0
    reference_amplitude: float = 0.03
    turbulence_force: float = 200.0
    turbulence_time: float = 0.3


def synthesise_positioner(
    truth_archive: FmuArchive,
    whitebox_archive: FmuArchive,
    effects: Mapping[str, float],
    seed: int,
    duration: float,
    noise: float,
    *,
    profile: PositionerProfile | None = None,
) -> Recording:
    """Record the truth positioner under PI position control.

    Parameters
    ----------
    truth_archive, whitebox_archive : FmuArchive
        The truth FMU that is run, and the white-box FMU whose variable names and units the
        recording carries (its start values are the drive's nominal motor data).
    effects : mapping of str to float
        Truth-model effect parameter -> value (units as the truth FMU declares).
    seed : int
        Seed of every random choice (reference, load, noise).
    duration : float
        Length of the recording [s].
    noise : float
        Sensor-noise scale factor (0 = noise-free; 1 = :data:`SENSOR_NOISE`).
    profile : PositionerProfile, optional
        Controller, limits, reference and load; the defaults if omitted.

    Returns
    -------
    Recording
        Columns: ``motor_voltage``, ``load_force``, then every white-box Real output. The
        metadata ``reference`` holds the commanded position, thinned to at most about 2000
        samples (every ``reference_stride``-th one).

    Raises
    ------
    ConfigError
        If an effect is not a parameter the truth FMU has and the white-box lacks.
    """
    check_effects(effects, truth_archive, whitebox_archive)
    profile = profile or PositionerProfile()
    rng = np.random.default_rng(seed)
    dt = profile.dt
    n = round(duration / dt) + 1
    time = np.arange(n) * dt
    reference = pilot_reference(n, dt, profile.reference_amplitude, rng)
    load = coloured_noise(n, dt, profile.turbulence_force, profile.turbulence_time, rng)
    outputs = real_outputs(whitebox_archive)
    noise_of = {
        name: rng.standard_normal(n) * SENSOR_NOISE.get(name, 0.0) * noise
        for name in (*INPUTS, *outputs)
    }
    nominal = {
        name: whitebox_archive.variable(name).start for name in ("resistance", "back_emf_constant")
    }
    u, y = _closed_loop(
        truth_archive, dict(effects), profile, nominal, outputs, reference, load, noise_of
    )
    signals = {name: u[:, j] + noise_of[name] for j, name in enumerate(INPUTS)}
    signals.update({name: y[:, j] + noise_of[name] for j, name in enumerate(outputs)})
    stride = max(1, n // 2000)
    metadata = {
        "generator": "fmu_greybox.synth.positioner",
        "truth_fmu": truth_archive.path.name,
        "effects": json.dumps(dict(effects), sort_keys=True),
        "seed": str(seed),
        "noise": repr(noise),
        "reference": json.dumps(reference[::stride].round(7).tolist()),
        "reference_stride": str(stride),
    }
    return Recording(
        time=time,
        signals=signals,
        units={name: whitebox_archive.variable(name).unit for name in signals},
        source="positioner synth",
        metadata=metadata,
    )


def _closed_loop(
    truth: FmuArchive,
    effects: dict[str, float],
    profile: PositionerProfile,
    nominal: Mapping[str, float],
    outputs: list[str],
    reference: np.ndarray,
    load: np.ndarray,
    noise: Mapping[str, np.ndarray],
) -> tuple[np.ndarray, np.ndarray]:
    """Run the drive and the truth FMU sample by sample.

    Returns
    -------
    u : ndarray, shape (n, 2)
        True inputs applied (motor voltage, load force).
    y : ndarray, shape (n, n_outputs)
        True (noise-free) outputs, ``y[k]`` observed before ``u[k]`` acts.
    """
    n, dt = reference.size, profile.dt
    at = {name: outputs.index(name) for name in ("position", "motor_speed")}
    # Voltage window around the expected back-EMF that keeps |current| <= current_limit.
    headroom = nominal["resistance"] * profile.current_limit
    u = np.empty((n, len(INPUTS)))
    y = np.empty((n, len(outputs)))
    integral = 0.0  # integral of the position error [m.s]
    with fmu_instance(truth, INPUTS, outputs, effects, {}, "positioner synth") as inst:
        y[0] = inst.read_outputs()
        for k in range(n):
            error = reference[k] - (y[k, at["position"]] + noise["position"][k])
            speed = y[k, at["motor_speed"]] + noise["motor_speed"][k]
            emf = nominal["back_emf_constant"] * speed
            low = max(-profile.bus_voltage, emf - headroom)
            high = min(profile.bus_voltage, emf + headroom)
            demand = profile.position_gain * (error + integral / profile.integral_time)
            voltage = min(max(demand, low), high)
            if voltage == demand:  # anti-windup: integrate only while unsaturated
                integral += error * dt
            u[k] = (voltage, load[k])
            if k + 1 < n:
                y[k + 1] = inst.step(u[k], dt)
    return u, y
