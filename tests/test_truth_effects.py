"""The truth model: the white-box with every effect off; each effect as its physics says."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import OUTPUTS
from fmpy.fmi1 import FMICallException

PISTON_AREA = 2.0e-3  # m2
VALVE_GAIN = 4.0e-5  # m/mA
LEAKAGE = 2.0e-13  # m3/(s.Pa), white-box leakage_coefficient
SUPPLY, RETURN = 20.7e6, 3.0e5  # Pa
SENSED = (
    "spool_position",
    "ram_position",
    "itfv_pressure",
    "ram_velocity",
    "pressure_a",
    "pressure_b",
)


def busy_inputs() -> dict:
    """Inputs visiting every regime: multi-sine, load, end stop with relief, disengagement."""
    return {
        "valve_current": lambda t: np.where(
            t < 1.0, 3.0 * np.sin(2 * np.pi * 1.7 * t) + 1.2 * np.sin(2 * np.pi * 13.0 * t), 9.0
        ),
        "load_force": lambda t: 6000.0 * np.sin(2 * np.pi * 0.9 * t) + np.where(t > 1.5, 38e3, 0),
        "engage": lambda t: np.where((t > 0.6) & (t < 0.8), 0.0, 1.0),
    }


def steady(run: dict, name: str) -> float:
    """Mean of an output over the last 100 ms (ten periods of the hydraulic resonance)."""
    return float(np.mean(run[name][-100:]))


def test_truth_with_effects_off_is_the_whitebox(
    simulate, whitebox_fmu: Path, truth_fmu: Path
) -> None:
    white = simulate(whitebox_fmu, 2.5, inputs=busy_inputs())
    truth = simulate(truth_fmu, 2.5, inputs=busy_inputs())
    assert np.max(np.abs(white["relief_flow"])) > 0.0  # the relief valve was visited
    for name in OUTPUTS:
        assert np.max(np.abs(truth[name] - white[name])) <= 1e-12 * np.ptp(white[name]), name


def test_gain_error_scales_spool_position(simulate, truth_fmu: Path) -> None:
    run = simulate(truth_fmu, 0.2, inputs={"valve_current": 3.0}, parameters={"gain_error": 0.1})
    assert steady(run, "spool_position") == pytest.approx(1.1 * VALVE_GAIN * 3.0, rel=1e-6)


def test_offset_moves_spool_at_zero_current(simulate, whitebox_fmu: Path, truth_fmu: Path) -> None:
    white = simulate(whitebox_fmu, 0.3)
    truth = simulate(truth_fmu, 0.3, parameters={"offset": 0.5})
    assert steady(white, "spool_position") == 0.0 and steady(white, "ram_velocity") == 0.0
    assert steady(truth, "spool_position") == pytest.approx(VALVE_GAIN * 0.5, rel=1e-6)
    assert steady(truth, "ram_velocity") == pytest.approx(0.15 * 0.05, rel=0.05)


def test_deadband_blocks_small_openings(simulate, whitebox_fmu: Path, truth_fmu: Path) -> None:
    deadband = {"deadband": 2e-5}  # = 0.5 mA of current
    small = simulate(truth_fmu, 0.3, inputs={"valve_current": 0.4}, parameters=deadband)
    assert np.all(small["load_flow"] == 0.0)
    assert np.max(np.abs(small["ram_position"])) < 1e-12
    assert steady(simulate(whitebox_fmu, 0.3, inputs={"valve_current": 0.4}), "ram_position") > 1e-3
    white = simulate(whitebox_fmu, 0.3, inputs={"valve_current": 2.0})
    large = simulate(truth_fmu, 0.3, inputs={"valve_current": 2.0}, parameters=deadband)
    opening = (VALVE_GAIN * 2.0 - 2e-5) / (VALVE_GAIN * 2.0)
    assert steady(large, "load_flow") == pytest.approx(
        opening * steady(white, "load_flow"), rel=0.01
    )


def test_coulomb_friction_raises_load_pressure_and_lowers_velocity(
    simulate, whitebox_fmu: Path, truth_fmu: Path
) -> None:
    inputs = {"valve_current": 1.0}
    white = simulate(whitebox_fmu, 0.5, inputs=inputs)
    truth = simulate(truth_fmu, 0.5, inputs=inputs, parameters={"coulomb_friction": 1000.0})
    extra = steady(truth, "itfv_pressure") - steady(white, "itfv_pressure")
    assert extra == pytest.approx(1000.0 / PISTON_AREA, rel=0.02)
    assert steady(truth, "ram_velocity") < steady(white, "ram_velocity")


@pytest.mark.parametrize("current", [1.0, -1.0])
def test_friction_asymmetry_is_stronger_extending(
    simulate, whitebox_fmu: Path, truth_fmu: Path, current: float
) -> None:
    """F_c + F_a opposes extension, F_c - F_a retraction: the load pressure needed to move
    rises by (F_c + sign(v) F_a) / A beside the white-box's."""
    inputs = {"valve_current": current}
    friction = {"coulomb_friction": 800.0, "friction_asymmetry": 300.0}
    white = simulate(whitebox_fmu, 0.5, inputs=inputs)
    truth = simulate(truth_fmu, 0.5, inputs=inputs, parameters=friction)
    extra = steady(truth, "itfv_pressure") - steady(white, "itfv_pressure")
    force = 800.0 + 300.0 if current > 0 else -(800.0 - 300.0)
    assert extra == pytest.approx(force / PISTON_AREA, rel=0.02)


def test_stribeck_friction_adds_breakaway_at_low_speed_only(simulate, truth_fmu: Path) -> None:
    coulomb = {"coulomb_friction": 500.0}
    stribeck = {**coulomb, "stribeck_friction": 1500.0, "stribeck_velocity": 0.01}
    slow = {"valve_current": 0.2}  # about 3 mm/s, below stribeck_velocity = 10 mm/s
    fast = {"valve_current": 8.0}  # about 120 mm/s

    # slow: Coulomb friction alone slides smoothly, the breakaway friction makes it stick-slip
    smooth = simulate(truth_fmu, 0.5, inputs=slow, parameters=coulomb)
    jerky = simulate(truth_fmu, 0.5, inputs=slow, parameters=stribeck)
    v_smooth, v_jerky = smooth["ram_velocity"][-200:], jerky["ram_velocity"][-200:]
    assert np.std(v_smooth) < 1e-3 * np.mean(v_smooth)
    assert np.std(v_jerky) > 0.3 * np.mean(v_jerky)
    # starting from rest the breakaway friction is felt in full
    peak = np.max(jerky["itfv_pressure"][:100]) - np.max(smooth["itfv_pressure"][:100])
    assert peak > 0.8 * 1500.0 / PISTON_AREA

    # fast: no difference (0.3 s: before the end stop)
    base = simulate(truth_fmu, 0.3, inputs=fast, parameters=coulomb)
    run = simulate(truth_fmu, 0.3, inputs=fast, parameters=stribeck)
    extra = steady(run, "itfv_pressure") - steady(base, "itfv_pressure")
    assert abs(extra) < 1e-3 * 1500.0 / PISTON_AREA


def test_internal_leakage_increases_drift_under_load(
    simulate, whitebox_fmu: Path, truth_fmu: Path
) -> None:
    inputs = {"load_force": lambda t: 10e3 * np.clip(t / 0.1, 0.0, 1.0)}  # valve at null
    white = simulate(whitebox_fmu, 0.5, inputs=inputs)
    truth = simulate(truth_fmu, 0.5, inputs=inputs, parameters={"internal_leakage": 8e-13})
    drift = -10e3 / PISTON_AREA**2
    assert steady(white, "ram_velocity") == pytest.approx(drift * LEAKAGE, rel=0.01)
    assert steady(truth, "ram_velocity") == pytest.approx(drift * (LEAKAGE + 8e-13), rel=0.01)


def _ringing_frequency(run: dict) -> float:
    ringing = run["ram_velocity"][run["time"] > 0.012]
    crossings = np.flatnonzero(np.diff(np.sign(ringing - ringing.mean())))
    return 1.0 / (2 * 1e-4 * np.mean(np.diff(crossings)))


def test_compliance_lowers_hydraulic_natural_frequency(
    simulate, whitebox_fmu: Path, truth_fmu: Path
) -> None:
    inputs = {"load_force": lambda t: np.where(t >= 0.01, 2000.0, 0.0)}
    white = simulate(whitebox_fmu, 0.2, step_size=1e-4, inputs=inputs)
    truth = simulate(truth_fmu, 0.2, step_size=1e-4, inputs=inputs, parameters={"compliance": 0.5})
    ratio = _ringing_frequency(truth) / _ringing_frequency(white)
    assert ratio == pytest.approx(np.sqrt(0.5), rel=0.02)


def test_supply_droop_lowers_velocity_at_large_flow(
    simulate, whitebox_fmu: Path, truth_fmu: Path
) -> None:
    inputs = {"valve_current": 10.0}
    white = simulate(whitebox_fmu, 0.2, inputs=inputs)
    droop = 1e10
    truth = simulate(truth_fmu, 0.2, inputs=inputs, parameters={"supply_pressure_droop": droop})
    effective = SUPPLY - droop * steady(truth, "supply_flow")
    expected = np.sqrt((effective - RETURN) / (SUPPLY - RETURN))
    ratio = steady(truth, "ram_velocity") / steady(white, "ram_velocity")
    assert ratio < 0.95
    assert ratio == pytest.approx(expected, rel=0.01)


def test_time_delay_shifts_sensed_outputs(simulate, truth_fmu: Path) -> None:
    inputs = {
        "valve_current": lambda t: 3.0 * np.sin(2 * np.pi * 5.0 * t) + 1.0,
        "load_force": lambda t: 4000.0 * np.sin(2 * np.pi * 2.0 * t),
    }
    plain = simulate(truth_fmu, 0.5, inputs=inputs)
    delayed = simulate(truth_fmu, 0.5, inputs=inputs, parameters={"time_delay": 0.005})
    shift = 5  # samples of 1 ms
    for name in SENSED:
        spread = np.ptp(plain[name])
        assert np.max(np.abs(delayed[name][shift:] - plain[name][:-shift])) <= 1e-9 * spread
        assert np.all(delayed[name][:shift] == plain[name][0])  # initial value holds
    for name in set(OUTPUTS) - set(SENSED):
        assert np.array_equal(delayed[name], plain[name])


def test_time_delay_beyond_maximum_is_refused(instantiate, truth_fmu: Path) -> None:
    with pytest.raises(FMICallException, match="fmi2ExitInitializationMode"):
        instantiate(truth_fmu, name="late", parameters={"time_delay": 0.06})


def test_time_delay_longer_than_the_history_is_refused(instantiate, truth_fmu: Path) -> None:
    # 10 us communication steps: 0.05 s of delay needs 5000 samples, the history holds 4096
    slave, _ = instantiate(truth_fmu, name="short-history", parameters={"time_delay": 0.05})
    with pytest.raises(FMICallException, match="fmi2DoStep"):
        for k in range(5000):
            slave.doStep(k * 1e-5, 1e-5)
    assert 4000 < k < 4200
    slave.freeInstance()
