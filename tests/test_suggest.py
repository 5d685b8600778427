"""The one suggestion helper (issue 16): one matching rule and one phrase for every message."""

from __future__ import annotations

import pytest

from fmu_greybox.errors import ConfigError, FmuArchiveError, RecordingError
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.suggest import closest, did_you_mean


def test_a_match_but_for_case_is_the_one_suggestion():
    assert closest("RAM_POSITION", ["ram_position", "ram_velocity", "RAM_POSITIONS"]) == [
        "ram_position"
    ]


def test_close_names_best_first_at_most_three():
    names = ["load_force", "load_flow", "load_force_N", "load_forces", "valve_current"]
    assert closest("load_forc", names) == ["load_force", "load_forces", "load_force_N"]
    assert closest("pressure", names) == []


def test_phrase_and_fallback():
    assert did_you_mean("stagse", ["stages", "signals"]) == "; did you mean 'stages'?"
    assert did_you_mean("zzz", ["stages"]) == ""
    assert did_you_mean("zzz", ["stages"], fallback=["t"]) == "; did you mean 't'?"


def test_every_message_uses_the_same_rule(whitebox_fmu, truth_fmu):
    """Before: the project file suggested two names, the FMU archive three, the binding
    matched with another cutoff and the recordings ignored case; now all agree."""
    from fmu_greybox.data.recording import Recording
    from fmu_greybox.project.config import parse_config
    from fmu_greybox.synth.actuator import check_effects

    expected = did_you_mean("RAM_POSITON", ["ram_position"])
    with open_fmu(whitebox_fmu) as archive, open_fmu(truth_fmu) as truth:
        with pytest.raises(FmuArchiveError) as info:
            archive.variable("RAM_POSITON")
        assert expected.split("?")[0] in str(info.value)
        with pytest.raises(ConfigError) as info:
            check_effects({"Coulomb_Friction": 1.0}, truth, archive)
        assert "; did you mean 'coulomb_friction'?" in str(info.value)
    recording = Recording([0.0, 1.0], {"ram_position": [0.0, 1.0]}, source="r.csv")
    with pytest.raises(RecordingError) as info:
        recording["RAM_POSITON"]
    assert expected in str(info.value)
    raw = {
        "whitebox": {"fmu": "x.fmu"},
        "signals": {"ram_position": {"role": "position", "unit": "m"}},
        "stages": [{"name": "RAM", "target": "RAM_POSITON"}],
    }
    with pytest.raises(ConfigError) as info:
        parse_config(raw)
    assert expected in str(info.value)
