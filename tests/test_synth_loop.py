"""Effects around the truth FMU in the recorder's closed loop, and noise on the logged inputs."""

from __future__ import annotations

import numpy as np
import pytest

from fmu_greybox.errors import ConfigError
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.model.simulate import simulate_with_terms
from fmu_greybox.synth.actuator import (
    INPUTS,
    SENSOR_NOISE,
    FlightTestProfile,
    SynthRequest,
    synthesise,
)
from fmu_greybox.synth.loop import Loop, parse_loop_effects

OUTPUTS = ("spool_position", "ram_position", "itfv_pressure", "ram_velocity")


def test_loop_effects_act_on_inputs_and_sensors() -> None:
    effects = {
        "saturation_upper@valve_current": 5.0,
        "saturation_lower@valve_current": -8.0,
        "force_offset@load_force": 1000.0,
        "stiffness@load_force(ram_position)": 2e4,
        "sensor_gain@ram_position": 0.05,
        "sensor_offset@itfv_pressure": 3e5,
        "coulomb_friction": 100.0,  # an FMU parameter: not the loop's
    }
    loop = Loop(effects, INPUTS, OUTPUTS, 1e-3)
    y = np.array([1e-4, 0.01, 2e6, 0.05])
    applied = loop.applied(np.array([9.0, 2e7, 500.0, 1.0]), y)
    assert applied.tolist() == [5.0, 2e7, 500.0 + 1000.0 + 2e4 * 0.01, 1.0]
    assert loop.applied(np.array([-9.0, 2e7, 0.0, 1.0]), y)[0] == -8.0
    assert loop.sensed(y).tolist() == pytest.approx([1e-4, 0.0105, 2.3e6, 0.05])


def test_a_sensor_delay_reports_one_channel_late() -> None:
    loop = Loop({"sensor_delay@ram_velocity": 0.002}, INPUTS, OUTPUTS, 1e-3)
    readings = [loop.sensed(np.array([0.0, k, 0.0, k])) for k in range(5)]
    assert [r[3] for r in readings] == [0.0, 0.0, 0.0, 1.0, 2.0]
    assert [r[1] for r in readings] == [0.0, 1.0, 2.0, 3.0, 4.0]


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("sensor_gain@valve_current", "not an FMU output"),
        ("saturation@ram_position", "not an FMU input"),
        ("stiffness@load_force", "names the output it reads"),
        ("wobble@load_force", "KIND@VARIABLE"),
    ],
)
def test_loop_effects_are_checked(name: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        parse_loop_effects({name: 1.0}, INPUTS, OUTPUTS)


def test_recorded_command_is_the_controllers_the_fmu_received_the_amplifiers(
    whitebox_fmu, truth_fmu
) -> None:
    """An amplifier saturating at 4 mA: the log keeps the controller's current (beyond 4 mA),
    and the truth FMU driven open-loop by the clipped log reproduces the recording."""
    profile = FlightTestProfile(duration=3.0)
    request = SynthRequest({"saturation@valve_current": 4.0}, seed=3, noise=0.0, profile=profile)
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        recording = synthesise(truth, whitebox, request)
        u = np.column_stack([recording[name] for name in INPUTS])
        assert np.max(np.abs(u[:, 0])) > 6.0
        clipped = u.copy()
        clipped[:, 0] = np.clip(u[:, 0], -4.0, 4.0)
        y = simulate_with_terms(truth, INPUTS, clipped, recording.dt, ["ram_position"])
    np.testing.assert_allclose(y[:, 0], recording["ram_position"], rtol=0, atol=1e-12)


def test_logged_inputs_carry_sensor_noise_unless_switched_off(whitebox_fmu, truth_fmu) -> None:
    profile = FlightTestProfile(duration=2.0)
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        noisy = synthesise(truth, whitebox, SynthRequest({}, seed=4, profile=profile))
        clean = synthesise(
            truth, whitebox, SynthRequest({}, seed=4, profile=profile, input_noise=False)
        )
    for name in INPUTS:
        error = noisy[name] - clean[name]
        assert np.std(error) == pytest.approx(SENSOR_NOISE[name], rel=0.1), name
    assert clean.metadata["input_noise"] == "false"
    np.testing.assert_array_equal(noisy["ram_position"], clean["ram_position"])
