"""White-box physics and numerics of the compiled reference FMU."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fmpy.fmi1 import FMICallException

PISTON_AREA = 2.0e-3  # m2, start value of piston_area
RAM_STROKE = 0.05  # m
SPOOL_STROKE = 5.0e-4  # m
CRACKING = 18.0e6  # Pa
VALVE_GAIN = 4.0e-5  # m/mA

# Tolerances on the change of each output, relative to its range, when solver_step is halved
# from its default 1e-4 s (the integrator is third order; measured: 1.2e-5 white-box, 3e-4 truth
# with every effect on).
HALVING_TOLERANCE_WHITEBOX = 1e-4
HALVING_TOLERANCE_TRUTH = 1e-3

ALL_EFFECTS = {
    "gain_error": 0.05,
    "offset": 0.2,
    "deadband": 1e-5,
    "coulomb_friction": 600.0,
    "stribeck_friction": 400.0,
    "internal_leakage": 5e-13,
    "compliance": 0.2,
    "supply_pressure_droop": 2e10,
    "time_delay": 0.002,
}


def multisine_current(t: np.ndarray) -> np.ndarray:
    """Valve current [mA] exciting the valve and the hydraulic resonance."""
    return (
        4.0 * np.sin(2 * np.pi * 1.3 * t)
        + 2.5 * np.sin(2 * np.pi * 7.1 * t + 0.4)
        + 1.5 * np.sin(2 * np.pi * 23.0 * t + 1.0)
        + 1.0 * np.sin(2 * np.pi * 61.0 * t + 2.0)
    )


def sine_load(t: np.ndarray) -> np.ndarray:
    """Load force [N]."""
    return 8000.0 * np.sin(2 * np.pi * 0.7 * t)


@pytest.mark.parametrize(
    ("model", "tolerance"),
    [("whitebox", HALVING_TOLERANCE_WHITEBOX), ("truth", HALVING_TOLERANCE_TRUTH)],
)
def test_halving_solver_step_changes_little(
    simulate, whitebox_fmu: Path, truth_fmu: Path, model: str, tolerance: float
) -> None:
    fmu, effects = (whitebox_fmu, {}) if model == "whitebox" else (truth_fmu, ALL_EFFECTS)
    inputs = {"valve_current": multisine_current, "load_force": sine_load}
    coarse = simulate(fmu, 2.0, inputs=inputs, parameters={**effects, "solver_step": 1e-4})
    fine = simulate(fmu, 2.0, inputs=inputs, parameters={**effects, "solver_step": 5e-5})
    for name in (
        "spool_position",
        "ram_position",
        "itfv_pressure",
        "ram_velocity",
        "load_flow",
        "pressure_a",
        "pressure_b",
        "spool_velocity",
        "supply_flow",
    ):
        spread = np.ptp(fine[name])
        assert np.max(np.abs(coarse[name] - fine[name])) <= tolerance * spread, name


#: Largest difference allowed, relative to each output's range, between one long communication
#: step and the same time in 1 ms steps (measured 4.8e-10 on the ram position; with one
#: Jacobian kept for all 1 000 internal steps of the long step it was 8.3e-7).
LONG_STEP_TOLERANCE = 1e-8


@pytest.mark.parametrize("model", ["whitebox", "truth"])
def test_a_long_communication_step_renews_its_jacobian(
    simulate, whitebox_fmu: Path, truth_fmu: Path, model: str
) -> None:
    """The integrator keeps a Jacobian for at most ten internal steps, however long the master's
    communication step: two 0.1 s steps land where two hundred 1 ms steps do."""
    fmu = whitebox_fmu if model == "whitebox" else truth_fmu
    inputs = {"valve_current": 0.5, "supply_pressure": 20.7e6, "load_force": 2000.0}
    short = simulate(fmu, 0.2, step_size=1e-3, inputs=inputs)
    long = simulate(fmu, 0.2, step_size=0.1, inputs=inputs)
    for name in ("ram_position", "itfv_pressure", "ram_velocity", "pressure_a", "pressure_b"):
        spread = np.ptp(short[name])
        difference = np.abs(short[name][[100, 200]] - long[name][[1, 2]])
        assert np.max(difference) <= LONG_STEP_TOLERANCE * spread, name


def test_no_load_velocity_equals_load_flow_over_area(simulate, whitebox_fmu: Path) -> None:
    for current in (10.0, 3.0, -5.0):
        run = simulate(whitebox_fmu, 0.2, inputs={"valve_current": current})
        velocity, flow = run["ram_velocity"][-1], run["load_flow"][-1]
        assert velocity == pytest.approx(flow / PISTON_AREA, rel=0.01)
    rated = simulate(whitebox_fmu, 0.2, inputs={"valve_current": 10.0})
    assert rated["ram_velocity"][-1] == pytest.approx(0.15, rel=0.05)


@pytest.mark.parametrize("current", [8.0, -8.0])
def test_end_stops_hold(simulate, whitebox_fmu: Path, current: float) -> None:
    run = simulate(whitebox_fmu, 1.0, inputs={"valve_current": current})
    assert np.all(np.abs(run["ram_position"]) <= RAM_STROKE)
    assert run["ram_position"][-1] == np.sign(current) * RAM_STROKE
    assert np.all(run["ram_velocity"][-300:] == 0.0)
    # against the stop, the driven chamber pressure rises (relief cracks at 18 MPa)
    assert abs(run["itfv_pressure"][-1]) > 17e6


def test_relief_caps_differential_pressure_when_stalled(simulate, whitebox_fmu: Path) -> None:
    # The valve drives against a load above the relief force A p_crack = 36 kN and below the
    # stall force A (p_S - p_T) = 40.8 kN: without relief the ram creeps on at dp = F/A.
    load = 39e3
    inputs = {"valve_current": 5.0, "load_force": lambda t: load * np.clip(t / 0.3, 0.0, 1.0)}
    relieved = simulate(whitebox_fmu, 1.5, inputs=inputs)
    blocked = simulate(whitebox_fmu, 1.5, inputs=inputs, parameters={"relief_gain": 0.0})
    dp = relieved["pressure_a"] - relieved["pressure_b"]
    assert CRACKING < dp[-1] <= 1.02 * CRACKING
    assert relieved["itfv_pressure"][-1] == pytest.approx(dp[-1], rel=1e-3)  # monitor settled
    assert relieved["relief_flow"][-1] > 0.0
    assert relieved["ram_position"][-1] == -RAM_STROKE  # pushed back onto its stop
    assert np.max(np.abs(dp)) <= 1.01 * load / PISTON_AREA
    dp_blocked = blocked["pressure_a"] - blocked["pressure_b"]
    assert dp_blocked[-1] == pytest.approx(load / PISTON_AREA, rel=0.01)
    assert np.all(blocked["relief_flow"] == 0.0)
    assert blocked["ram_velocity"][-1] > 0.0


def test_disengaged_ram_is_a_damper(simulate, whitebox_fmu: Path) -> None:
    engaged = simulate(whitebox_fmu, 1.0, inputs={"valve_current": 5.0})
    loose = simulate(whitebox_fmu, 1.0, inputs={"valve_current": 5.0, "engage": 0.0})
    assert engaged["ram_position"][-1] > 0.04
    assert abs(loose["ram_position"][-1]) < 1e-9  # does not follow the current
    assert loose["load_flow"][-1] == 0.0 and loose["supply_flow"][-1] == 0.0
    pushed = simulate(whitebox_fmu, 1.0, inputs={"engage": 0.0, "load_force": 1000.0})
    damping = PISTON_AREA**2 / (2.0e-11 + 2.0e-13) + 2000.0  # A^2/(K_byp + C_l) + b
    assert pushed["ram_velocity"][-1] == pytest.approx(-1000.0 / damping, rel=0.01)


def test_spool_limited_to_stroke(simulate, whitebox_fmu: Path) -> None:
    run = simulate(whitebox_fmu, 0.3, inputs={"valve_current": lambda t: 20.0 * np.sin(8 * t)})
    assert np.max(np.abs(run["spool_position"])) == SPOOL_STROKE
    small = simulate(whitebox_fmu, 0.2, inputs={"valve_current": 2.0})
    assert small["spool_position"][-1] == pytest.approx(VALVE_GAIN * 2.0, rel=1e-6)


def test_hydraulic_natural_frequency_is_about_100_hz(simulate, whitebox_fmu: Path) -> None:
    # a load step on the blocked ram (valve at null) rings at the hydraulic natural frequency
    run = simulate(
        whitebox_fmu,
        0.2,
        step_size=1e-4,
        inputs={"load_force": lambda t: np.where(t >= 0.01, 2000.0, 0.0)},
    )
    ringing = run["ram_velocity"][run["time"] > 0.012]
    crossings = np.flatnonzero(np.diff(np.sign(ringing - ringing.mean())))
    frequency = 1.0 / (2 * 1e-4 * np.mean(np.diff(crossings)))
    assert frequency == pytest.approx(100.0, rel=0.03)


def test_tunable_parameter_acts_between_steps(instantiate, whitebox_fmu: Path) -> None:
    slave, refs = instantiate(whitebox_fmu, inputs={"valve_current": 5.0})
    slave.doStep(0.0, 0.1)
    slave.setReal([refs["valve_gain"]], [2.0 * VALVE_GAIN])
    slave.doStep(0.1, 0.1)
    assert slave.getReal([refs["spool_position"]])[0] == pytest.approx(10.0 * VALVE_GAIN, 1e-6)
    with pytest.raises(FMICallException):  # fixed parameter after initialisation
        slave.setReal([refs["solver_step"]], [1e-5])
    slave.terminate()
    slave.freeInstance()


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("ram_mass", 0.0),
        ("valve_damping", -0.1),
        ("solver_step", -1e-4),
        ("initial_ram_position", 0.06),
    ],
)
def test_invalid_parameters_are_refused(
    instantiate, whitebox_fmu: Path, name: str, value: float
) -> None:
    with pytest.raises(FMICallException, match="fmi2ExitInitializationMode"):
        instantiate(whitebox_fmu, name=f"bad-{name}", parameters={name: value})
