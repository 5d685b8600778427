"""A white-box FMU in the style of a third party, its project and its recordings.

The DC servo axis of ``tests/data/dc_servo`` declares no units and has terse names (``u``,
``tl``, ``th``, ``w``, ``ia``) with descriptions only. It is built here with the package's FMU
builder; :func:`record` drives its truth model in a closed loop written for this file alone (a
cascade of a position and a speed controller on the sensed angle and speed), with every sensor
noisy, the logged drive voltage and load torque included, and the loop effects of
:mod:`fmu_greybox.synth.loop` where asked. The tests and ``benchmarks/concealed_effects.py``
use it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from fmu_greybox.data.recording import Recording
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.fmi.build import build_model_pair
from fmu_greybox.fmi.instance import FmuInstance
from fmu_greybox.project.config import ProjectConfig, parse_config
from fmu_greybox.synth.actuator import coloured_noise, pilot_reference
from fmu_greybox.synth.loop import Loop, is_loop_effect

SOURCES = Path(__file__).resolve().parent / "data" / "dc_servo"
INPUTS = ("u", "tl")
OUTPUTS = ("th", "w", "ia")
#: Sensor noise (standard deviation) of every recorded signal at ``noise = 1``, in SI units.
SENSOR_NOISE = {"u": 0.01, "tl": 0.002, "th": 1e-3, "w": 0.05, "ia": 0.004}
#: The loop: position gain [1/s], speed gain [V.s/rad], voltage limit [V].
POSITION_GAIN, SPEED_GAIN, VOLTAGE_LIMIT = 20.0, 0.5, 24.0
#: Reference amplitude [rad], load torque standard deviation [N.m] and correlation time [s].
AMPLITUDE, LOAD_TORQUE, LOAD_TIME = 2.0, 0.01, 0.3


def build_fmus(out_dir: Path) -> dict[str, Path]:
    """Build ``DCServo``, ``DCAxis`` (no speed output) and ``DCServoTruth`` into ``out_dir``."""
    return build_model_pair(SOURCES, out_dir)


def record(
    truth: FmuArchive,
    effects: Mapping[str, float],
    seed: int,
    duration: float = 20.0,
    noise: float = 1.0,
    input_noise: bool = True,
    amplitude: float = AMPLITUDE,
) -> Recording:
    """Record the truth servo in its closed loop.

    Parameters
    ----------
    truth : FmuArchive
        ``DCServoTruth``.
    effects : mapping of str to float
        Truth parameters (``fc``, ``fa``) and loop effects (``sensor_offset@ia``, ...).
    seed : int
    duration : float
        Length [s] at 1 kHz.
    noise : float
        Scale of :data:`SENSOR_NOISE`.
    input_noise : bool
        Whether the logged inputs carry their sensor noise.
    amplitude : float
        Amplitude [rad] of the angle reference.

    Returns
    -------
    Recording
        Columns ``u``, ``tl``, ``th``, ``w``, ``ia`` (no units, as the FMU declares none).
    """
    dt = 1e-3
    n = round(duration / dt) + 1
    rng = np.random.default_rng(seed)
    reference = pilot_reference(n, dt, amplitude, rng)
    load = coloured_noise(n, dt, LOAD_TORQUE, LOAD_TIME, rng)
    scale = {k: v * noise * (input_noise or k not in INPUTS) for k, v in SENSOR_NOISE.items()}
    sensor = {k: rng.standard_normal(n) * s for k, s in scale.items()}
    loop = Loop(effects, INPUTS, OUTPUTS, dt)
    parameters = {k: v for k, v in effects.items() if not is_loop_effect(k)}
    u = np.empty((n, len(INPUTS)))
    y = np.empty((n, len(OUTPUTS)))
    with FmuInstance(truth, INPUTS, OUTPUTS, parameters, {}, "dcs record") as inst:
        true = inst.read_outputs().copy()
        for k in range(n):
            y[k] = loop.sensed(true)
            angle = y[k, 0] + sensor["th"][k]
            speed = y[k, 1] + sensor["w"][k]
            demand = SPEED_GAIN * (POSITION_GAIN * (reference[k] - angle) - speed)
            u[k] = (min(max(demand, -VOLTAGE_LIMIT), VOLTAGE_LIMIT), load[k])
            if k + 1 < n:
                true = inst.step(loop.applied(u[k], true), dt).copy()
    signals = {name: u[:, j] + sensor[name] for j, name in enumerate(INPUTS)}
    signals.update({name: y[:, j] + sensor[name] for j, name in enumerate(OUTPUTS)})
    return Recording(
        time=np.arange(n) * dt,
        signals=signals,
        units=dict.fromkeys(signals, ""),
        source="dcs record",
        metadata={"effects": json.dumps(dict(effects), sort_keys=True), "seed": str(seed)},
    )


def project(fmu: Path, declare_speed: bool = False) -> ProjectConfig:
    """The project a user of the servo writes: the recorded voltage, load torque, angle and
    current under ``[signals]`` (with the units the user knows), stages ELEC (current from the
    voltage) and MECH (angle from the load torque, fed by ELEC). The FMU's speed output ``w`` is
    not declared unless ``declare_speed`` (then as a recorded velocity signal)."""
    signals = {
        "u": {"role": "voltage", "unit": "V"},
        "tl": {"role": "force", "unit": "N.m"},
        "th": {"role": "position", "unit": "rad"},
        "ia": {"role": "current", "unit": "A"},
    }
    if declare_speed:
        signals["w"] = {"role": "velocity", "unit": "rad/s"}
    raw = {
        "format_version": 1,
        "name": "dc servo",
        "whitebox": {"fmu": str(fmu)},
        "signals": signals,
        "stages": [
            {"name": "ELEC", "target": "ia", "inputs": ["u"], "feeds_from": []},
            {"name": "MECH", "target": "th", "inputs": ["tl"], "feeds_from": ["ELEC"]},
        ],
        "gp": {"inducing": 100, "max_iter": 60},
        "split": {"train_fraction": 0.8},
    }
    return parse_config(raw)
