"""The diagnosis on a white-box written in the style of a third party (``tests/third_party.py``):
no units, terse names, noisy logged inputs, no speed output in one variant."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from third_party import project, record

from fmu_greybox.diagnosis import Diagnosis
from fmu_greybox.diagnosis.report import write_outputs
from fmu_greybox.fmi.archive import open_fmu


def servo_recording(fmus: dict, effects: dict, seed: int, duration: float = 8.0):
    with open_fmu(fmus["DCServoTruth"]) as truth:
        return record(truth, effects, seed, duration)


def test_a_right_servo_model_with_a_noisy_drive_voltage_is_right(dc_servo_fmus) -> None:
    """The logged drive voltage carries sensor noise; the angle integrates the speed, so the
    open-loop white-box drifts far beyond the angle sensor's noise. Judged against the drift
    that input noise alone explains, the exact model gets ``none``."""
    recording = servo_recording(dc_servo_fmus, {}, seed=11)
    diagnosis = Diagnosis(project(dc_servo_fmus["DCServo"]), greybox=None).fit(recording)
    angle = next(s for s in diagnosis.locator_.stages_[1].signals if s.name == "th")
    assert angle.rms > 10 * angle.noise  # the drift
    assert angle.drift > 10  # ... which input noise explains
    assert diagnosis.origin_stage_ is None
    assert [f.effect for f in diagnosis.findings_] == ["none"]


def test_a_current_sensor_offset_of_two_noise_levels_is_named(dc_servo_fmus) -> None:
    """The current's fast dynamics do not pass for noise (its noise level comes from its
    residual), and the offset stands out in its band though input-noise drift of the current
    is larger than the offset over the whole spectrum."""
    recording = servo_recording(dc_servo_fmus, {"sensor_offset@ia": 0.008}, seed=12)
    diagnosis = Diagnosis(project(dc_servo_fmus["DCServo"]), greybox=None).fit(recording)
    current = diagnosis.experiment_.sigma[diagnosis.experiment_.outputs.index("ia")]
    assert current == pytest.approx(0.004, rel=0.3)
    assert diagnosis.origin_stage_ == "ELEC"
    top = diagnosis.findings_[0].to_dict()
    assert (top["effect"], top["stage"]) == ("sensor_offset", "ELEC")
    assert top["magnitude"]["value"] == pytest.approx(0.008, rel=0.15)
    assert top["magnitude"]["unit"] == "A"  # the project's unit: the FMU declares none


@pytest.mark.parametrize("model", ["DCServo", "DCAxis"])
def test_missing_friction_is_named_from_roles_read_in_descriptions(
    dc_servo_fmus, tmp_path, model: str
) -> None:
    """The project declares the recorded signals only: the speed output ``w`` is a velocity by
    its description, and where the FMU has no speed output (``DCAxis``) the friction is fed back
    from the rate of the angle."""
    recording = servo_recording(dc_servo_fmus, {"fc": 0.02}, seed=13)
    diagnosis = Diagnosis(project(dc_servo_fmus[model]), greybox=None).fit(recording)
    payload = write_outputs(diagnosis, recording, tmp_path)
    top = payload["findings"][0]
    assert top["effect"] == "coulomb_friction"
    assert top["magnitude"]["value"] == pytest.approx(0.02, rel=0.1)
    source = top["terms"][0]
    if model == "DCServo":
        assert payload["inferred_roles"] == [
            {
                "variable": "w",
                "causality": "output",
                "role": "velocity",
                "source": "description",
                "evidence": "speed",
            }
        ]
        assert (
            "Roles read from the FMU's names and descriptions: w velocity"
            in (payload["verdict"][0])
        )
        assert (source["source"], source["rate"]) == ("w", False)
    else:
        assert payload["inferred_roles"] == []
        assert (source["source"], source["rate"]) == ("th", True)
    assert payload["fit"]["MECH"]["named_rmse"] < 0.1 * payload["fit"]["MECH"]["wb_rmse"]
    # no kept finding worsens a held-out signal; rejected candidates say why
    json.dumps(payload)
    for round_ in payload["selection"]:
        for entry in round_["refined"]:
            if "rejected" in entry:
                assert entry["rejected"].startswith("worsens the held-out fit of ")
    kept = diagnosis.selection_.selected_
    rows = diagnosis.experiment_.train_rows
    with open_fmu(dc_servo_fmus[model]) as whitebox:  # the diagnosis closed its own
        experiment = dataclasses.replace(diagnosis.experiment_, archive=whitebox, _cache={})
        kept_rms = np.sqrt(np.mean(experiment.residual(kept.simulated[rows:], rows) ** 2, axis=0))
        for i in range(len(kept.hypotheses)):
            others = [
                t
                for j, (h, theta) in enumerate(zip(kept.hypotheses, kept.split(), strict=True))
                if j != i
                for t in h.terms(theta)
            ]
            without = experiment.simulate(others)[rows:]
            rms = np.sqrt(np.mean(experiment.residual(without, rows) ** 2, axis=0))
            assert np.all(kept_rms <= 1.05 * rms)
