"""The wider vocabulary on the reference actuator, with effects put around its truth FMU in the
recorder's closed loop, where another explanation lurks."""

from __future__ import annotations

from pathlib import Path

import pytest

from fmu_greybox.diagnosis import Diagnosis
from fmu_greybox.diagnosis.report import diagnosis_payload
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.project.config import load_config
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise

ACTUATOR = Path(__file__).resolve().parents[1] / "bench_configs" / "hydraulic_actuator.toml"


def diagnose(whitebox_fmu, truth_fmu, effects: dict, seed: int, duration: float = 10.0):
    profile = FlightTestProfile(duration=duration)
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        recording = synthesise(truth, whitebox, SynthRequest(effects, seed=seed, profile=profile))
    diagnosis = Diagnosis(load_config(ACTUATOR), greybox=None).fit(recording)
    return diagnosis, diagnosis_payload(diagnosis, recording)


@pytest.mark.parametrize(
    ("effects", "seed", "effect", "value"),
    [
        # a position sensor reading high, not a valve flow gain: the velocity sensor disagrees
        ({"sensor_gain@ram_position": 0.05}, 41, "sensor_gain", 0.05),
        # one sensor late, the others on time
        ({"sensor_delay@itfv_pressure": 0.003}, 42, "sensor_delay", 0.003),
        # a load nobody recorded, not a current offset
        ({"force_offset@load_force": 2500.0}, 43, "force_offset", 2500.0),
    ],
)
def test_loop_effects_are_named_with_their_magnitude(
    whitebox_fmu, truth_fmu, effects: dict, seed: int, effect: str, value: float
) -> None:
    _, payload = diagnose(whitebox_fmu, truth_fmu, effects, seed)
    top = payload["findings"][0]
    assert top["effect"] == effect
    assert top["magnitude"]["value"] == pytest.approx(value, rel=0.1)


def test_a_saturating_amplifier_is_not_named_a_supply_droop(whitebox_fmu, truth_fmu) -> None:
    """The amplifier saturates only on the large commands of the test's later part; a droop
    also lowers the flow there, but worsens the held-out pressure: it is rejected, and says
    why."""
    diagnosis, payload = diagnose(
        whitebox_fmu, truth_fmu, {"saturation@valve_current": 5.0}, seed=44, duration=12.0
    )
    top = payload["findings"][0]
    assert (top["effect"], top["stage"]) == ("saturation", "EHV")
    assert top["magnitude"]["value"] == pytest.approx(5.0, rel=0.05)
    assert top["magnitude"]["unit"] == "mA"
    assert [f["effect"] for f in payload["findings"]] == ["saturation"]
    first = payload["selection"][0]
    assert first["screen_rows"] > 4000  # the window reaches the large commands
    for entry in first["refined"]:
        if entry["key"].startswith("supply_pressure_droop"):
            assert entry["rejected"].startswith("worsens the held-out fit")
    for stage in ("EHV", "RAM", "ITFV"):
        assert diagnosis.fit_[stage]["named_rmse"] <= 1.05 * diagnosis.fit_[stage]["wb_rmse"]
