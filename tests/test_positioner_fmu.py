"""The electro-mechanical positioner: build, interface, physics, numerics, truth effects, synth."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import simulate_fmu_loop
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from fmu_greybox.errors import ConfigError, FmuArchiveError
from fmu_greybox.fmi import builtin
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.build import SOURCES_DIR, build_model_pair, load_variable_table
from fmu_greybox.model.simulate import simulate_recording
from fmu_greybox.project.config import load_config
from fmu_greybox.synth.positioner import synthesise_positioner

MODEL_DIR = SOURCES_DIR / "ElectroMechanicalPositioner"
CONFIG = Path(__file__).resolve().parents[1] / "bench_configs" / "positioner.toml"
WHITEBOX, TRUTH = "ElectroMechanicalPositioner", "ElectroMechanicalPositionerTruth"
INPUTS = ("motor_voltage", "load_force")
OUTPUTS = (
    "motor_current",
    "motor_speed",
    "position",
    "velocity",
    "transmission_deflection",
    "transmission_force",
)
EFFECTS = ("gain_error", "offset", "coulomb_friction", "viscous_friction_extra", "backlash")

# Start values of the white-box parameters (variables.toml).
R, KT, KE = 0.3, 0.03, 0.03  # Ohm, N.m/A, V.s/rad
RATIO = 4.0e-3 / (2 * math.pi * 3.0)  # screw_lead / (2 pi gear_ratio) [m/rad]
LOSS = (1.0 - 0.9) / 0.9  # mesh friction per transmitted torque, (1 - eta) / eta
VISCOUS, STIFFNESS = 500.0, 5.0e7  # N.s/m, N/m
# Stiff mount, no mesh friction: a voltage step settles in about 35 ms (with eta = 0.9 the mesh
# friction, tanh-smoothed near standstill, lets a loaded screw creep for a quarter second).
STIFF_MOUNT = {"mount_stiffness": 2.0e6, "transmission_efficiency": 1.0}
FREE_MOUNT = {"mount_stiffness": 0.0}  # steady speed under constant voltage

# Largest change of each output, relative to its range, when solver_step is halved from 1e-4 s
# (measured: 1e-4 white-box, 7.4e-4 truth with every effect on).
HALVING_TOLERANCE_WHITEBOX = 3e-4
HALVING_TOLERANCE_TRUTH = 3e-3

ALL_EFFECTS = {
    "gain_error": 0.05,
    "offset": 0.3,
    "coulomb_friction": 80.0,
    "viscous_friction_extra": 300.0,
    "backlash": 2e-5,
}


@pytest.fixture(scope="module")
def fmus(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Both positioner FMUs, built once for this module."""
    return build_model_pair(MODEL_DIR, tmp_path_factory.mktemp("positioner"))


def run(
    fmu: Path, stop_time: float, parameters: dict | None = None, **inputs: object
) -> dict[str, np.ndarray]:
    """Simulate at 1 ms communication steps; inputs are constants or functions of time."""
    return simulate_fmu_loop(
        fmu, stop_time, inputs=inputs, parameters=parameters, outputs=OUTPUTS, name="positioner"
    )


def busy_inputs() -> dict:
    """Multi-sine voltage up to 61 Hz and a sine load: both directions, driving and back-driven."""
    return {
        "motor_voltage": lambda t: (
            12 * np.sin(2 * np.pi * 1.3 * t)
            + 6 * np.sin(2 * np.pi * 7.1 * t + 0.4)
            + 4 * np.sin(2 * np.pi * 23 * t + 1.0)
            + 2 * np.sin(2 * np.pi * 61 * t + 2.0)
        ),
        "load_force": lambda t: 600 * np.sin(2 * np.pi * 0.7 * t),
    }


def final(result: dict[str, np.ndarray], name: str) -> float:
    """Last sample of an output."""
    return float(result[name][-1])


# ------------------------------------------------------------------------------------------------
# Build, interface, configuration


@pytest.mark.parametrize("identifier", [WHITEBOX, TRUTH])
def test_validates_and_declares_its_interface(fmus: dict[str, Path], identifier: str) -> None:
    fmu = fmus[identifier]
    assert validate_fmu(str(fmu)) == []
    description = read_model_description(str(fmu))
    variables = {v.name: v for v in description.modelVariables}
    assert [v.name for v in description.modelVariables if v.causality == "input"] == list(INPUTS)
    assert [v.name for v in description.modelVariables if v.causality == "output"] == list(OUTPUTS)
    assert {name: variables[name].unit for name in (*INPUTS, *OUTPUTS)} == {
        "motor_voltage": "V",
        "load_force": "N",
        "motor_current": "A",
        "motor_speed": "rad/s",
        "position": "m",
        "velocity": "m/s",
        "transmission_deflection": "m",
        "transmission_force": "N",
    }
    assert all(v.unit for v in description.modelVariables)
    effects = [name for name in EFFECTS if name in variables]
    assert effects == (list(EFFECTS) if identifier == TRUTH else [])
    assert all(float(variables[name].start) == 0.0 for name in effects)


def test_truth_only_variables_do_not_collide(fmus: dict[str, Path]) -> None:
    white = {
        v.name: v.valueReference for v in read_model_description(str(fmus[WHITEBOX])).modelVariables
    }
    truth = {
        v.name: v.valueReference for v in read_model_description(str(fmus[TRUTH])).modelVariables
    }
    assert all(truth[name] == vr for name, vr in white.items())
    assert set(truth) - set(white) == {
        *EFFECTS,
        "friction_smoothing_velocity",
        "backlash_smoothing",
    }


def test_readme_documents_every_variable() -> None:
    readme = (MODEL_DIR / "README.md").read_text(encoding="utf-8")
    for v in load_variable_table(MODEL_DIR / "variables.toml").variables:
        assert f"`{v.name}`" in readme, v.name


def test_project_file_matches_the_fmu(fmus: dict[str, Path]) -> None:
    config = load_config(CONFIG)
    assert config.fmu == "builtin:ElectroMechanicalPositioner"
    assert [(s.name, s.target, s.feeds_from) for s in config.stages] == [
        ("MOTOR", "motor_current", ()),
        ("DRIVE", "position", ("MOTOR",)),
    ]
    assert {s.role for s in config.signals.values()} == {
        "voltage",
        "force",
        "current",
        "velocity",
        "position",
    }
    with open_fmu(fmus[WHITEBOX]) as archive:
        config.check_against_fmu(archive)


def test_builtin_names_resolve_to_the_cache(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, fmus: dict[str, Path]
) -> None:
    monkeypatch.setenv("FMU_GREYBOX_CACHE", str(tmp_path))
    cache = builtin.cache_dir()
    cache.mkdir(parents=True)
    for fmu in fmus.values():  # as a first use would have built them
        shutil.copy(fmu, cache / fmu.name)
    assert builtin.resolve_fmu(f"builtin:{WHITEBOX}") == cache / f"{WHITEBOX}.fmu"
    assert builtin.resolve_fmu(f"builtin:{TRUTH}") == cache / f"{TRUTH}.fmu"
    with pytest.raises(FmuArchiveError, match="builtin:ElectroMechanicalPositionerTruth"):
        builtin.resolve_fmu("builtin:ElectroMechanicalPositionr")


# ------------------------------------------------------------------------------------------------
# White-box physics and numerics


@pytest.mark.parametrize("voltage", [10.0, -10.0])
def test_steady_speed_under_constant_voltage(fmus: dict[str, Path], voltage: float) -> None:
    """u = R i + k_e w, k_t i = r F_t (1 +/- loss), F_t = b r w + F_L (no mount spring)."""
    load = 100.0
    result = run(fmus[WHITEBOX], 0.3, FREE_MOUNT, motor_voltage=voltage, load_force=load)
    # Driving (+10 V): the motor supplies r F_t / eta. Back-driven (-10 V, the load pushes the
    # nut back): the mesh friction flips, the motor receives r F_t (1 - loss).
    efficiency = 1.0 + LOSS if voltage > 0 else 1.0 - LOSS
    speed = (voltage - R * RATIO * efficiency * load / KT) / (
        KE + R * RATIO**2 * efficiency * VISCOUS / KT
    )
    force = VISCOUS * RATIO * speed + load
    assert voltage < 0 < force or voltage > 0  # the -10 V case is back-driven indeed
    assert final(result, "motor_speed") == pytest.approx(speed, rel=1e-6)
    assert final(result, "motor_current") == pytest.approx(
        RATIO * efficiency * force / KT, rel=1e-6
    )
    assert final(result, "transmission_force") == pytest.approx(force, rel=1e-6)


@pytest.mark.parametrize(("gear_ratio", "screw_lead"), [(3.0, 4.0e-3), (5.0, 1.0e-2)])
def test_gear_and_screw_kinematics(
    fmus: dict[str, Path], gear_ratio: float, screw_lead: float
) -> None:
    parameters = {**FREE_MOUNT, "gear_ratio": gear_ratio, "screw_lead": screw_lead}
    result = run(fmus[WHITEBOX], 0.3, parameters, motor_voltage=8.0)
    ratio = screw_lead / (2 * math.pi * gear_ratio)
    assert final(result, "velocity") / final(result, "motor_speed") == pytest.approx(
        ratio, rel=1e-9
    )
    # Steady motion: the deflection rate is zero, the spring alone carries the force.
    assert final(result, "transmission_force") == pytest.approx(
        STIFFNESS * final(result, "transmission_deflection"), rel=1e-9
    )


def test_position_integrates_velocity(fmus: dict[str, Path]) -> None:
    result = run(fmus[WHITEBOX], 2.0, **busy_inputs())
    time, velocity = result["time"], result["velocity"]
    integral = np.concatenate(
        ([0.0], np.cumsum(0.5 * np.diff(time) * (velocity[1:] + velocity[:-1])))
    )
    assert np.max(np.abs(integral - result["position"])) < 1e-3 * np.ptp(result["position"])
    # Nut travel r * integral(omega) minus load travel is the transmission deflection.
    speed = result["motor_speed"]
    nut = RATIO * np.concatenate(([0.0], np.cumsum(0.5 * np.diff(time) * (speed[1:] + speed[:-1]))))
    deflection = result["transmission_deflection"]
    assert np.max(np.abs(nut - result["position"] - deflection)) < 0.1 * np.ptp(deflection)


def test_mount_spring_holds_the_load_against_the_motor(fmus: dict[str, Path]) -> None:
    """At rest: i = u / R, k_t i = r F_t (no mesh friction at standstill), F_t = k_m x."""
    result = run(fmus[WHITEBOX], 0.6, STIFF_MOUNT, motor_voltage=2.0)
    assert final(result, "motor_current") == pytest.approx(2.0 / R, rel=1e-6)
    assert final(result, "position") == pytest.approx(KT * 2.0 / (R * RATIO * 2.0e6), rel=1e-6)


def test_end_stop_holds_the_load(fmus: dict[str, Path]) -> None:
    result = run(fmus[WHITEBOX], 0.6, {"transmission_efficiency": 1.0}, motor_voltage=28.0)
    assert np.max(result["position"]) == 0.05 and final(result, "velocity") == 0.0
    # Stalled at the stop: the motor pushes with its stall torque.
    assert final(result, "motor_current") == pytest.approx(28.0 / R, rel=1e-6)
    assert final(result, "transmission_force") == pytest.approx(KT * 28.0 / (R * RATIO), rel=1e-6)


@pytest.mark.parametrize(
    ("model", "tolerance"),
    [(WHITEBOX, HALVING_TOLERANCE_WHITEBOX), (TRUTH, HALVING_TOLERANCE_TRUTH)],
)
def test_halving_solver_step_changes_little(
    fmus: dict[str, Path], model: str, tolerance: float
) -> None:
    effects = ALL_EFFECTS if model == TRUTH else {}
    coarse = run(fmus[model], 2.0, {**effects, "solver_step": 1e-4}, **busy_inputs())
    fine = run(fmus[model], 2.0, {**effects, "solver_step": 5e-5}, **busy_inputs())
    for name in OUTPUTS:
        assert np.max(np.abs(coarse[name] - fine[name])) <= tolerance * np.ptp(fine[name]), name


# ------------------------------------------------------------------------------------------------
# Truth model


def test_truth_with_effects_off_is_the_whitebox(fmus: dict[str, Path]) -> None:
    inputs = busy_inputs()
    sine = inputs["motor_voltage"]
    inputs["motor_voltage"] = lambda t: np.where(t < 1.5, sine(t), 28.0)  # ends at the stop
    white = run(fmus[WHITEBOX], 2.0, **inputs)
    truth = run(fmus[TRUTH], 2.0, **inputs)
    assert np.max(white["position"]) == 0.05
    for name in OUTPUTS:
        assert np.max(np.abs(truth[name] - white[name])) <= 1e-12 * np.ptp(white[name]), name


def test_gain_error_scales_the_torque(fmus: dict[str, Path]) -> None:
    white = run(fmus[WHITEBOX], 0.6, STIFF_MOUNT, motor_voltage=2.0)
    truth = run(fmus[TRUTH], 0.6, {**STIFF_MOUNT, "gain_error": 0.1}, motor_voltage=2.0)
    assert final(truth, "motor_current") == pytest.approx(final(white, "motor_current"), rel=1e-6)
    assert final(truth, "position") == pytest.approx(1.1 * final(white, "position"), rel=1e-6)


def test_offset_drives_the_motor_at_zero_voltage(fmus: dict[str, Path]) -> None:
    white = run(fmus[WHITEBOX], 0.6, STIFF_MOUNT)
    truth = run(fmus[TRUTH], 0.6, {**STIFF_MOUNT, "offset": 0.5})
    assert np.all(white["position"] == 0.0) and np.all(white["motor_current"] == 0.0)
    assert final(truth, "motor_current") == pytest.approx(0.5 / R, rel=1e-6)
    assert final(truth, "position") == pytest.approx(KT * 0.5 / (R * RATIO * 2.0e6), rel=1e-6)


@pytest.mark.parametrize("voltage", [10.0, -10.0])
def test_coulomb_friction_acts_as_a_load_opposing_motion(
    fmus: dict[str, Path], voltage: float
) -> None:
    friction = 100.0
    truth = run(
        fmus[TRUTH], 0.3, {**FREE_MOUNT, "coulomb_friction": friction}, motor_voltage=voltage
    )
    white = run(
        fmus[WHITEBOX],
        0.3,
        FREE_MOUNT,
        motor_voltage=voltage,
        load_force=math.copysign(friction, voltage),
    )
    for name in ("motor_current", "motor_speed", "transmission_force"):
        assert final(truth, name) == pytest.approx(final(white, name), rel=1e-6), name


def test_extra_viscous_friction_adds_to_viscous_friction(fmus: dict[str, Path]) -> None:
    truth = run(fmus[TRUTH], 1.0, {"viscous_friction_extra": 300.0}, **busy_inputs())
    white = run(fmus[WHITEBOX], 1.0, {"viscous_friction": 800.0}, **busy_inputs())
    for name in OUTPUTS:
        assert np.max(np.abs(truth[name] - white[name])) <= 1e-9 * np.ptp(white[name]), name


@pytest.mark.parametrize("voltage", [2.0, -2.0])
def test_backlash_adds_free_play_to_the_deflection(fmus: dict[str, Path], voltage: float) -> None:
    backlash = 4e-5
    white = run(fmus[WHITEBOX], 0.6, STIFF_MOUNT, motor_voltage=voltage)
    truth = run(fmus[TRUTH], 0.6, {**STIFF_MOUNT, "backlash": backlash}, motor_voltage=voltage)
    # Same force balance at rest, so the same position; the nut travels half the play further.
    assert final(truth, "position") == pytest.approx(final(white, "position"), rel=1e-6)
    shift = final(truth, "transmission_deflection") - final(white, "transmission_deflection")
    assert shift == pytest.approx(math.copysign(backlash / 2, voltage), rel=1e-2)


def test_backlash_decouples_motor_and_load_inside_the_gap(fmus: dict[str, Path]) -> None:
    backlash = 1e-4  # the nut starts centred, 50 um from either flank
    white = run(fmus[WHITEBOX], 0.03, motor_voltage=1.0)
    truth = run(fmus[TRUTH], 0.03, {"backlash": backlash}, motor_voltage=1.0)
    contact = int(np.argmax(truth["transmission_deflection"] >= backlash / 2 - 5e-6))
    assert 5 < contact < 20  # ms: the free motor crosses the gap at about 7 mm/s
    free = slice(0, contact)
    assert np.max(np.abs(truth["transmission_force"][free])) < 2.0  # white-box: kN
    assert np.max(np.abs(truth["position"][free])) < 1e-6
    assert white["position"][contact - 1] > 20e-6  # the white-box load moved with the motor
    assert final(truth, "position") > 1e-4  # after contact the nut drives the load


# ------------------------------------------------------------------------------------------------
# Closed-loop recordings


def test_synthesised_recording_tracks_the_reference(fmus: dict[str, Path]) -> None:
    with open_fmu(fmus[TRUTH]) as truth, open_fmu(fmus[WHITEBOX]) as white:
        recording = synthesise_positioner(
            truth, white, {"coulomb_friction": 50.0}, seed=3, duration=6.0, noise=1.0
        )
        with pytest.raises(ConfigError, match="unknown effect 'backlsh'"):
            synthesise_positioner(truth, white, {"backlsh": 1e-5}, 0, 0.1, 0.0)
    assert list(recording.signals) == [*INPUTS, *OUTPUTS]
    assert recording.units["motor_voltage"] == "V" and recording.units["motor_speed"] == "rad/s"
    assert recording.dt == pytest.approx(1e-3) and recording.time[-1] == pytest.approx(6.0)
    stride = int(recording.metadata["reference_stride"])
    reference = np.array(json.loads(recording.metadata["reference"]))
    error = np.abs(recording.signals["position"][::stride] - reference)
    assert np.median(error) < 1e-4  # 0.2 % of the stroke; steps are rate-limited
    assert np.sqrt(np.mean(error**2)) < 0.3 * np.std(reference)
    assert np.max(np.abs(recording.signals["motor_voltage"])) < 28.2  # bus plus sensor noise


def test_noise_free_recording_replays_open_loop(fmus: dict[str, Path]) -> None:
    effects = {"backlash": 3e-5, "gain_error": -0.1}
    with open_fmu(fmus[TRUTH]) as truth, open_fmu(fmus[WHITEBOX]) as white:
        recording = synthesise_positioner(truth, white, effects, seed=1, duration=2.0, noise=0.0)
        replay = simulate_recording(truth, recording, parameters=effects, outputs=OUTPUTS)
    for name in OUTPUTS:
        assert np.array_equal(replay.signals[name], recording.signals[name]), name
