"""A long recording is diagnosed on its most excited stretch, and says so."""

from __future__ import annotations

import numpy as np
from test_diagnosis import ACTUATOR, actuator_recording

from fmu_greybox.diagnosis import Diagnosis
from fmu_greybox.diagnosis.report import diagnosis_payload
from fmu_greybox.diagnosis.window import excitation, most_excited
from fmu_greybox.project.config import load_config


def test_the_most_excited_stretch_is_chosen_whatever_the_units() -> None:
    """Two inputs of very different units; one stretch where both vary and step: it is the
    one chosen, its share of the excitation is reported, and a recording no longer than the
    stretch is diagnosed whole."""
    rng = np.random.default_rng(4)
    n = 20_000
    current = 1e-3 * rng.normal(size=n) * 0.01  # mA-scale, almost still
    force = 5.0 + 0.01 * rng.normal(size=n)  # N-scale offset, almost still
    current[12_000:15_000] += 1e-3 * np.sign(np.sin(np.arange(3000) / 40.0))
    force[12_000:15_000] += 3e3 * np.sin(np.arange(3000) / 25.0)
    window = most_excited([current, force], rows=4000)
    assert window is not None and window.rows == 4000 and window.of_rows == n
    assert window.first <= 12_000 and window.last >= 14_999
    assert window.share_of_excitation > 0.9
    assert excitation([current, force]).shape == (n,)
    assert most_excited([current, force], rows=n) is None
    assert window.to_dict()["rows"] == 4000


def test_a_long_recording_is_diagnosed_on_a_stretch_that_still_names_the_effect(
    whitebox_fmu, truth_fmu
) -> None:
    """With ``max_rows`` below the recording's length the diagnosis runs on that many rows,
    the payload says which, and the concealed effect is still named (within its interval)."""
    recording = actuator_recording(whitebox_fmu, truth_fmu, {"coulomb_friction": 700.0}, 31, 12.0)
    diagnosis = Diagnosis(load_config(ACTUATOR), greybox=None, max_rows=6000).fit(recording)
    window = diagnosis.window_
    assert window is not None and window.rows == 6000 and window.of_rows == recording.n_samples
    assert diagnosis.experiment_.n_samples == 6000
    payload = diagnosis_payload(diagnosis, recording)
    assert payload["recording"]["window"]["first_row"] == window.first
    assert payload["recording"]["n_samples"] == recording.n_samples
    top = diagnosis.findings_[0]
    assert top.effect == "coulomb_friction", top.effect
    assert abs(top.magnitude["value"] - 700.0) < 0.15 * 700.0, top.magnitude
