"""Open-loop simulation of an FMU over a recording (issue 2, section 6)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fmu_greybox.data.recording import Recording
from fmu_greybox.errors import ConfigError, FmuError, RecordingError, UnitMismatchError
from fmu_greybox.fmi.archive import open_fmu, real_outputs
from fmu_greybox.model.simulate import simulate_recording
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise


@pytest.fixture(scope="module")
def recording(whitebox_fmu: Path, truth_fmu: Path) -> Recording:
    """One noisy second of closed-loop flight test with friction."""
    request = SynthRequest(
        effects={"coulomb_friction": 800.0}, seed=4, profile=FlightTestProfile(duration=1.0)
    )
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        return synthesise(truth, whitebox, request)


def renamed(
    recording: Recording,
    names: dict[str, str],
    units: dict[str, str] | None = None,
    drop: tuple[str, ...] = (),
) -> Recording:
    """``recording`` with columns renamed, units overridden and some columns dropped."""
    units = units or {}
    keep = [n for n in recording.names if n not in drop]
    return Recording(
        time=recording.time,
        signals={names.get(n, n): recording[n] for n in keep},
        units={names.get(n, n): units.get(n, recording.units[n]) for n in keep},
        source="edited.csv",
    )


def test_simulation_equals_stepping_fmpy_directly(
    instantiate, whitebox_fmu: Path, recording: Recording
) -> None:
    """Row 0 is the initial output, row k + 1 the output after applying the inputs of row k."""
    result = simulate_recording(whitebox_fmu, recording, parameters={"viscous_damping": 3000.0})
    inputs = ("valve_current", "supply_pressure", "load_force", "engage")
    outputs = list(result.names)
    u = np.column_stack([recording[n] for n in inputs])
    slave, refs = instantiate(
        whitebox_fmu,
        parameters={"viscous_damping": 3000.0},
        inputs=dict(zip(inputs, u[0], strict=True)),
    )
    expected = np.empty((recording.n_samples, len(outputs)))
    try:
        expected[0] = slave.getReal([refs[n] for n in outputs])
        t, dt = float(recording.time[0]), recording.dt
        for k in range(recording.n_samples - 1):
            slave.setReal([refs[n] for n in inputs], list(u[k]))
            slave.doStep(currentCommunicationPoint=t, communicationStepSize=dt)
            t += dt
            expected[k + 1] = slave.getReal([refs[n] for n in outputs])
    finally:
        slave.terminate()
        slave.freeInstance()
    assert np.array_equal(result.time, recording.time)
    for j, name in enumerate(outputs):
        assert np.array_equal(result[name], expected[:, j]), name
        assert result.units[name] == recording.units[name]
    assert not np.array_equal(result["ram_position"], recording["ram_position"])


def test_default_outputs_are_every_real_output(whitebox_fmu: Path, recording: Recording) -> None:
    with open_fmu(whitebox_fmu) as archive:
        result = simulate_recording(archive, recording)
        assert list(result.names) == real_outputs(archive)
        chosen = simulate_recording(archive, recording, outputs=["ram_position", "pressure_a"])
    assert chosen.names == ("ram_position", "pressure_a")
    assert np.array_equal(chosen["ram_position"], result["ram_position"])


def test_mapping_and_fixed_inputs(whitebox_fmu: Path, recording: Recording) -> None:
    reference = simulate_recording(whitebox_fmu, recording)
    edited = renamed(recording, {"valve_current": "i_cmd"}, drop=("engage",))
    result = simulate_recording(
        whitebox_fmu, edited, mapping={"valve_current": "i_cmd"}, fixed={"engage": 1.0}
    )
    assert result == reference
    disengaged = simulate_recording(whitebox_fmu, recording, fixed={"engage": 0.0})
    assert np.all(disengaged["load_flow"] == 0.0)  # valve ports blocked by the ITFV
    assert np.ptp(reference["load_flow"]) > 0.0


def test_missing_input_names_input_closest_column_and_options(
    whitebox_fmu: Path, recording: Recording
) -> None:
    edited = renamed(recording, {"load_force": "load_force_N"})
    with pytest.raises(RecordingError) as info:
        simulate_recording(whitebox_fmu, edited)
    message = str(info.value)
    for part in ("edited.csv", "'load_force'", "'load_force_N'", "--map", "--fix"):
        assert part in message
    assert "valve_current" not in message
    # load_flow looks like load_force but is a flow (m3/s), not a force: never suggested
    assert "load_flow" not in message


def test_mapped_column_missing(whitebox_fmu: Path, recording: Recording) -> None:
    with pytest.raises(RecordingError, match="'valve_current' needs column 'i_cmd'"):
        simulate_recording(whitebox_fmu, recording, mapping={"valve_current": "i_cmd"})


@pytest.mark.parametrize("option", ["mapping", "fixed"])
def test_mapping_a_non_input_is_refused(
    whitebox_fmu: Path, recording: Recording, option: str
) -> None:
    value = {"ram_position": "valve_current" if option == "mapping" else 1.0}
    with pytest.raises(ConfigError, match="'ram_position' is not an input"):
        simulate_recording(whitebox_fmu, recording, **{option: value})


def test_compatible_unit_is_converted_with_a_note(
    whitebox_fmu: Path, recording: Recording, caplog: pytest.LogCaptureFixture
) -> None:
    """Supply pressure recorded in bar and valve current in A: converted to Pa and mA."""
    reference = simulate_recording(whitebox_fmu, recording)
    edited = Recording(
        time=recording.time,
        signals={
            **recording.signals,
            "supply_pressure": recording["supply_pressure"] / 1e5,
            "valve_current": recording["valve_current"] / 1e3,
        },
        units={**recording.units, "supply_pressure": "bar", "valve_current": "A"},
        source="edited.csv",
    )
    with caplog.at_level("WARNING", logger="fmu_greybox"):
        result = simulate_recording(whitebox_fmu, edited)
    # Dividing and converting back moves a recorded input by an ulp; where input noise flips
    # the sign of a friction force, such an ulp moves the outputs by up to ~1e-7 (relative).
    for name in result.names:
        np.testing.assert_allclose(result[name], reference[name], rtol=1e-6, atol=1e-12)
    notes = caplog.text
    assert "'supply_pressure' converted from 'bar' to 'Pa'" in notes
    assert "'valve_current' converted from 'A' to 'mA'" in notes


def test_incompatible_unit_names_both_units(whitebox_fmu: Path, recording: Recording) -> None:
    edited = renamed(recording, {}, units={"supply_pressure": "m"})
    with pytest.raises(UnitMismatchError) as info:
        simulate_recording(whitebox_fmu, edited)
    message = str(info.value)
    for part in ("'supply_pressure'", "'m'", "'Pa'", "edited.csv", "different quantities"):
        assert part in message


def test_equivalent_unit_spelling_and_unknown_unit_are_accepted(
    whitebox_fmu: Path, recording: Recording
) -> None:
    reference = simulate_recording(whitebox_fmu, recording)
    edited = renamed(recording, {}, units={"engage": "-", "load_force": ""})
    assert simulate_recording(whitebox_fmu, edited) == reference


@pytest.mark.parametrize(
    ("fmu", "parameters", "current", "time"),
    [
        # 4096 delay-line samples cover only 41 ms at 10 us internal steps
        ("truth", {"time_delay": 0.05, "solver_step": 1e-5}, None, 0.04),
        # an absurd valve current from row 100 on breaks the integrator
        ("whitebox", {}, 1e300, 0.1),
    ],
)
def test_fmu_failing_mid_run_raises_fmu_error(
    whitebox_fmu: Path,
    truth_fmu: Path,
    recording: Recording,
    fmu: str,
    parameters: dict,
    current: float | None,
    time: float,
) -> None:
    if current is not None:
        signals = dict(recording.signals)
        signals["valve_current"] = np.where(
            np.arange(recording.n_samples) >= 100, current, recording["valve_current"]
        )
        recording = Recording(recording.time, signals, recording.units, source="absurd.csv")
    path = truth_fmu if fmu == "truth" else whitebox_fmu
    with pytest.raises(FmuError) as info:
        simulate_recording(path, recording, parameters=parameters)
    error = info.value
    assert (error.call, error.status) == ("fmi2DoStep", "fmi2Error")
    assert error.time == pytest.approx(time, abs=1e-9)
    message = str(error)
    assert "fmi2DoStep" in message and "fmi2Error" in message and f"t = {time:g} s" in message
    assert "[fmi2Error] fmi2DoStep failed: " in message  # the FMU's own log message is quoted


def test_parameter_out_of_range_fails_at_initialisation(
    truth_fmu: Path, recording: Recording
) -> None:
    with pytest.raises(
        FmuError,
        match=r"fmi2ExitInitializationMode returned fmi2Error at t = 0 "
        r"s.*time_delay = 0.06 is outside its range",
    ):
        simulate_recording(truth_fmu, recording, parameters={"time_delay": 0.06})
