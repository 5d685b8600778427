"""Synthetic closed-loop recordings of the truth actuator (issue 2, section 4) and their files."""

from __future__ import annotations

import json
import tomllib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from fmu_greybox.data.recording import Recording, load_recording, save_recording
from fmu_greybox.errors import ConfigError
from fmu_greybox.fmi.archive import FmuArchive, open_fmu, real_outputs
from fmu_greybox.model.simulate import simulate_recording
from fmu_greybox.synth.actuator import (
    SENSOR_NOISE,
    FlightTestProfile,
    SynthRequest,
    list_effects,
    parse_effects,
    synthesise,
)

VARIABLES = (
    Path(__file__).resolve().parents[1] / "fmu_sources" / "HydraulicActuator" / "variables.toml"
)
PROFILE = FlightTestProfile(duration=3.0)
#: One value per effect of DESIGN.md section 5, large enough to stand out of the sensor noise.
EFFECTS = {
    "gain_error": 0.1,
    "offset": 0.5,
    "deadband": 2e-5,
    "coulomb_friction": 800.0,
    "stribeck_friction": 800.0,
    "internal_leakage": 1e-12,
    "compliance": 0.5,
    "supply_pressure_droop": 1e10,
    "time_delay": 0.004,
    "friction_asymmetry": 400.0,
}
#: Truth parameters that only shape another effect (no change while that effect is off).
SHAPE_PARAMETERS = {"stribeck_velocity", "friction_smoothing_velocity"}


@pytest.fixture(scope="module")
def archives(whitebox_fmu: Path, truth_fmu: Path) -> Iterator[tuple[FmuArchive, FmuArchive]]:
    """The opened (truth, white-box) FMUs."""
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        yield truth, whitebox


def record(
    archives: tuple[FmuArchive, FmuArchive], profile: FlightTestProfile = PROFILE, **request: object
) -> Recording:
    truth, whitebox = archives
    return synthesise(truth, whitebox, SynthRequest(profile=profile, **request))


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def test_same_seed_gives_identical_recordings(archives) -> None:
    first, second = record(archives, seed=7), record(archives, seed=7)
    assert first == second
    for name in first.names:
        assert np.array_equal(first[name], second[name]), name
    assert first.metadata == second.metadata


def test_different_seeds_give_different_recordings(archives) -> None:
    first, second = record(archives, seed=7), record(archives, seed=8)
    for name in first.names:
        assert not np.array_equal(first[name], second[name]), name


def test_columns_are_whitebox_inputs_and_real_outputs_with_its_units(archives) -> None:
    _, whitebox = archives
    recording = record(archives)
    assert recording.names == (*whitebox.inputs, *real_outputs(whitebox))
    assert recording.units == {n: whitebox.variable(n).unit for n in recording.names}
    assert all(recording.units.values())
    assert recording.dt == pytest.approx(1e-3) and recording.n_samples == 3001
    assert json.loads(recording.metadata["effects"]) == {}
    assert recording.metadata["seed"] == "0"


def test_noise_free_truth_without_effects_is_the_whitebox(archives) -> None:
    """End to end: closed loop, recorded inputs, open-loop white-box replay agree exactly."""
    _, whitebox = archives
    recording = record(archives, seed=3, noise=0.0)
    assert np.ptp(recording["ram_position"]) > 5e-3  # the ram really moved
    simulated = simulate_recording(whitebox, recording)
    assert list(simulated.names) == real_outputs(whitebox)
    for name in simulated.names:
        scale = np.max(np.abs(recording[name]))
        np.testing.assert_allclose(
            simulated[name], recording[name], rtol=0, atol=1e-9 * scale, err_msg=name
        )


def test_noise_scales_with_the_factor(archives) -> None:
    """With the position loop open the trajectory does not depend on the sensor noise, so the
    difference between recordings is the noise itself."""
    open_loop = FlightTestProfile(duration=3.0, position_gain=0.0)
    clean, unit, double = (record(archives, open_loop, seed=5, noise=f) for f in (0.0, 1.0, 2.0))
    for name in clean.names:
        noise = unit[name] - clean[name]
        np.testing.assert_allclose(
            double[name] - clean[name],
            2 * noise,
            rtol=1e-6,
            atol=1e-6 * SENSOR_NOISE.get(name, 0.0),
            err_msg=name,
        )
        if name in SENSOR_NOISE:
            assert np.std(noise) == pytest.approx(SENSOR_NOISE[name], rel=0.1), name
            assert abs(np.mean(noise)) < 0.1 * SENSOR_NOISE[name], name
        else:  # the controller's own current and the engagement command are not measured
            assert np.array_equal(noise, np.zeros_like(noise)), name


def test_closed_loop_tracks_the_reference(archives) -> None:
    recording = record(archives, seed=0)
    reference = np.array(json.loads(recording.metadata["reference"]))
    position = recording["ram_position"][:: max(1, recording.n_samples // 2000)]
    assert reference.shape == position.shape
    assert np.std(reference) > 2e-3
    error = rms(position - reference)
    assert error < 3e-3 and error < 0.5 * np.std(reference)


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_each_effect_makes_a_measurable_difference(archives, name: str) -> None:
    _, whitebox = archives
    recording = record(archives, seed=0, noise=0.0, effects={name: EFFECTS[name]})
    simulated = simulate_recording(whitebox, recording)
    assert json.loads(recording.metadata["effects"]) == {name: EFFECTS[name]}
    ratios = {n: rms(recording[n] - simulated[n]) / SENSOR_NOISE[n] for n in simulated.names}
    assert max(ratios.values()) > 5.0, ratios


def test_effects_tested_cover_the_offered_effects(archives) -> None:
    offered = {v.name for v in list_effects(*archives)}
    assert offered == set(EFFECTS) | SHAPE_PARAMETERS


def test_gain_error_shows_in_the_spool_residual(archives) -> None:
    _, whitebox = archives
    recording = record(archives, seed=0, noise=0.0, effects={"gain_error": 0.1})
    simulated = simulate_recording(whitebox, recording)
    spool = recording["spool_position"]
    # truth spool = 1.1 x white-box spool for the same current (the stroke limit is not reached)
    assert rms(spool - simulated["spool_position"]) / rms(spool) == pytest.approx(
        0.1 / 1.1, rel=1e-3
    )


def test_unknown_effect_is_refused_with_a_suggestion(archives) -> None:
    with pytest.raises(ConfigError, match="did you mean 'coulomb_friction'") as info:
        record(archives, effects={"coulomb_frictoin": 800.0})
    assert "--list-effects" in str(info.value)


@pytest.mark.parametrize(
    "text", ["coulomb_friction", "=3", "offset=abc", "offset=nan", "offset=inf"]
)
def test_malformed_effect_is_refused(text: str) -> None:
    with pytest.raises(ConfigError, match="NAME=VALUE"):
        parse_effects([text])


def test_parse_effects() -> None:
    assert parse_effects(["gain_error=0.1", " offset =-0.5"]) == {"gain_error": 0.1, "offset": -0.5}


def test_list_effects_are_the_truth_only_parameters(archives) -> None:
    """Checked against the variable table the FMUs are generated from."""
    table = tomllib.loads(VARIABLES.read_text())["variable"]
    expected = [
        (v["name"], v["unit"])
        for v in table
        if v["causality"] == "parameter" and v.get("models") == ["HydraulicActuatorTruth"]
    ]
    effects = list_effects(*archives)
    assert [(v.name, v.unit) for v in effects] == expected
    assert all(
        v.unit and v.description and v.start == 0.0
        for v in effects
        if v.name not in SHAPE_PARAMETERS
    )


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_recording_files_load_back_equal(archives, tmp_path: Path, suffix: str) -> None:
    recording = record(archives, seed=2, effects={"coulomb_friction": 800.0})
    path = save_recording(recording, tmp_path / f"rec{suffix}")
    loaded = load_recording(path)
    assert loaded == recording
    assert loaded.names == recording.names and loaded.units == recording.units
    assert loaded.dt == pytest.approx(1e-3, rel=1e-12)
    if suffix == ".csv":
        assert path.read_text().splitlines()[0].split(",")[0] == "time"
        sidecar = json.loads(path.with_name("rec.csv.units.json").read_text())
        assert sidecar == {"time": "s", **recording.units}
    else:
        import pyarrow.parquet as pq

        schema = pq.read_schema(path)
        assert schema.names == ["time", *recording.names]
        units = json.loads(schema.metadata[b"fmu_greybox.units"])
        assert units == {"time": "s", **recording.units}
        assert loaded.metadata["effects"] == recording.metadata["effects"]
