"""Correction terms and the runner that steps the white-box with them."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from fmu_greybox.fmi.instance import FmuInstance
from fmu_greybox.model.simulate import simulate_with_terms
from fmu_greybox.model.terms import (
    TERM_KINDS,
    CoulombForce,
    DelayLine,
    FlowDroop,
    ForceOffset,
    InputDeadband,
    InputDelay,
    InputGain,
    InputHysteresis,
    InputLag,
    InputOffset,
    InputSaturation,
    ParameterChange,
    SensorChannelDelay,
    SensorDelay,
    SensorGain,
    SensorOffset,
    SpringForce,
    StribeckForce,
    ViscousForce,
    term_from_dict,
)

ROOT = Path(__file__).resolve().parents[1]
INPUTS = ["valve_current", "supply_pressure", "load_force", "engage"]
OUTPUTS = ["spool_position", "ram_position", "itfv_pressure", "ram_velocity"]
DT = 1e-3


@pytest.fixture(scope="module")
def archive(whitebox_archive):
    return whitebox_archive


@pytest.fixture(scope="module")
def inputs(actuator_inputs) -> np.ndarray:
    return actuator_inputs


def plain(archive, u: np.ndarray, parameters=None) -> np.ndarray:
    """The bare FMU stepped directly: the reference the terms are measured against."""
    start = dict(zip(INPUTS, u[0], strict=True))
    with FmuInstance(archive, INPUTS, OUTPUTS, parameters, start) as instance:
        rows = [instance.read_outputs().copy()]
        rows += [instance.step(row, DT).copy() for row in u[:-1]]
        return np.array(rows)


def test_delay_line_interpolates_and_holds_the_first_value() -> None:
    line = DelayLine(2.5, 1)
    out = [line(np.array([float(k)]))[0] for k in range(8)]
    assert out[:3] == [0.0, 0.0, 0.0]
    assert out[3:] == pytest.approx([0.5, 1.5, 2.5, 3.5, 4.5])


def test_no_terms_is_the_open_loop_run(archive, inputs) -> None:
    y = simulate_with_terms(archive, INPUTS, inputs, DT, OUTPUTS)
    np.testing.assert_array_equal(y, plain(archive, inputs))


def test_static_input_terms_equal_modified_recordings(archive, inputs) -> None:
    shifted = inputs.copy()
    shifted[:, 0] = 1.1 * (inputs[:, 0] + 0.2)
    shifted[:, 0] = np.sign(shifted[:, 0]) * np.maximum(np.abs(shifted[:, 0]) - 0.3, 0.0)
    terms = [
        InputOffset(input="valve_current", offset=0.2),
        InputGain(input="valve_current", gain=0.1),
        InputDeadband(input="valve_current", width=0.3),
    ]
    y = simulate_with_terms(archive, INPUTS, inputs, DT, OUTPUTS, terms)
    np.testing.assert_allclose(y, plain(archive, shifted), rtol=0, atol=1e-12)


def test_input_delay_shifts_the_command(archive, inputs) -> None:
    delayed = inputs.copy()
    delayed[3:, 0] = inputs[:-3, 0]
    delayed[:3, 0] = inputs[0, 0]
    y = simulate_with_terms(
        archive, INPUTS, inputs, DT, OUTPUTS, [InputDelay(input="valve_current", delay=3 * DT)]
    )
    np.testing.assert_allclose(y, plain(archive, delayed), atol=1e-12)


def test_parameter_change_equals_the_parameter_set(archive, inputs) -> None:
    y = simulate_with_terms(
        archive, INPUTS, inputs, DT, OUTPUTS, [ParameterChange(name="bulk_modulus", value=7e8)]
    )
    np.testing.assert_array_equal(y, plain(archive, inputs, {"bulk_modulus": 7e8}))


def test_sensor_delay_shifts_every_sensed_output(archive, inputs) -> None:
    base = plain(archive, inputs)
    y = simulate_with_terms(
        archive,
        INPUTS,
        inputs,
        DT,
        OUTPUTS,
        [SensorDelay(outputs=("spool_position", "ram_position"), delay=4 * DT)],
    )
    np.testing.assert_allclose(y[4:, :2], base[:-4, :2], atol=1e-15)
    np.testing.assert_array_equal(y[:, 2:], base[:, 2:])


def test_a_term_entering_later_leaves_earlier_stages_alone(archive, inputs) -> None:
    base = plain(archive, inputs)
    term = InputGain(input="valve_current", gain=0.2, entry=1)
    y = simulate_with_terms(archive, INPUTS, inputs, DT, OUTPUTS, [term], stages=[0, 1, 2, 1])
    np.testing.assert_array_equal(y[:, 0], base[:, 0])
    assert np.max(np.abs(y[:, 1] - base[:, 1])) > 1e-4


def test_coulomb_force_opposes_motion_through_the_load_input(archive, inputs) -> None:
    base = plain(archive, inputs)
    term = CoulombForce(input="load_force", source="ram_velocity", force=3000.0, smoothing=1e-3)
    y = simulate_with_terms(archive, INPUTS, inputs, DT, OUTPUTS, [term])
    assert np.mean(np.abs(y[:, 3])) < np.mean(np.abs(base[:, 3]))


def test_cache_returns_the_same_run(archive, inputs) -> None:
    cache: dict = {}
    term = [InputOffset(input="valve_current", offset=0.1)]
    first = simulate_with_terms(archive, INPUTS, inputs, DT, OUTPUTS, term, cache=cache)
    again = simulate_with_terms(archive, INPUTS, inputs, DT, OUTPUTS, term, cache=cache)
    np.testing.assert_array_equal(first, again)
    assert len(cache) == 1


@pytest.mark.parametrize(
    "term",
    [
        ParameterChange(name="bulk_modulus", value=7e8),
        InputGain(input="u", gain=0.1, entry=1),
        InputOffset(input="u", offset=-0.2),
        InputDeadband(input="u", width=0.3),
        InputDelay(input="u", delay=0.002),
        CoulombForce(input="f", source="v", force=600.0, smoothing=1e-3),
        ViscousForce(input="f", source="v", coefficient=50.0),
        StribeckForce(input="f", source="v", force=900.0, velocity=0.01, smoothing=1e-3),
        FlowDroop(input="p", source="q", resistance=1e10),
        SensorDelay(outputs=("a", "b"), delay=0.003),
        ForceOffset(input="f", offset=120.0),
        InputSaturation(input="u", lower=-4.0, upper=5.0),
        InputHysteresis(input="u", width=0.2),
        InputLag(input="u", tau=0.004),
        CoulombForce(input="f", source="x", force=-500.0, asymmetry=100.0, rate=True),
        SpringForce(input="f", source="x", coefficient=-2e5, rest=0.01),
        SensorGain(output="a", gain=0.03),
        SensorOffset(output="a", offset=1e-4),
        SensorChannelDelay(output="b", delay=0.002),
    ],
)
def test_terms_round_trip_through_plain_data(term) -> None:
    assert term_from_dict(term.to_dict()) == term


def test_every_term_kind_has_a_round_trip_case() -> None:
    """A new kind must be added to the round-trip cases above (and to the native FMU)."""
    cases = test_terms_round_trip_through_plain_data.pytestmark[0].args[1]
    assert {type(t).__name__ for t in cases} == set(TERM_KINDS)


def test_saturation_and_force_offset_equal_modified_recordings(archive, inputs) -> None:
    changed = inputs.copy()
    changed[:, 0] = np.clip(inputs[:, 0], -1.0, 1.5)
    changed[:, 2] += 800.0
    terms = [
        InputSaturation(input="valve_current", lower=-1.0, upper=1.5),
        ForceOffset(input="load_force", offset=800.0),
    ]
    y = simulate_with_terms(archive, INPUTS, inputs, DT, OUTPUTS, terms)
    np.testing.assert_allclose(y, plain(archive, changed), rtol=0, atol=1e-12)


def play(x: np.ndarray, width: float) -> np.ndarray:
    """The play operator written out: the acting value follows within +/- width / 2."""
    out = np.empty_like(x)
    acting = x[0]
    for k, v in enumerate(x):
        if v - acting > width / 2:
            acting = v - width / 2
        elif acting - v > width / 2:
            acting = v + width / 2
        out[k] = acting
    return out


def test_hysteresis_and_lag_equal_modified_recordings(archive, inputs) -> None:
    hysteretic = inputs.copy()
    hysteretic[:, 0] = play(inputs[:, 0], 0.6)
    y = simulate_with_terms(
        archive, INPUTS, inputs, DT, OUTPUTS, [InputHysteresis(input="valve_current", width=0.6)]
    )
    np.testing.assert_allclose(y, plain(archive, hysteretic), rtol=0, atol=1e-12)

    tau = 0.005
    lagged = inputs.copy()
    alpha = 1.0 - np.exp(-DT / tau)
    for k in range(1, len(lagged)):
        lagged[k, 0] = lagged[k - 1, 0] + alpha * (inputs[k, 0] - lagged[k - 1, 0])
    y = simulate_with_terms(
        archive, INPUTS, inputs, DT, OUTPUTS, [InputLag(input="valve_current", tau=tau)]
    )
    np.testing.assert_allclose(y, plain(archive, lagged), rtol=0, atol=1e-12)


def test_sensor_channel_faults_change_one_output_only(archive, inputs) -> None:
    base = plain(archive, inputs)
    terms = [
        SensorGain(output="ram_position", gain=0.04),
        SensorOffset(output="itfv_pressure", offset=2e4),
        SensorChannelDelay(output="spool_position", delay=3 * DT),
    ]
    y = simulate_with_terms(archive, INPUTS, inputs, DT, OUTPUTS, terms)
    np.testing.assert_allclose(y[:, 1], 1.04 * base[:, 1], rtol=1e-14, atol=0)
    np.testing.assert_allclose(y[:, 2], base[:, 2] + 2e4, rtol=1e-14, atol=0)
    np.testing.assert_allclose(y[3:, 0], base[:-3, 0], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(y[:, 3], base[:, 3])


def test_sensor_faults_do_not_reach_the_physics(archive, inputs) -> None:
    """A feedback term reads the FMU's own output, not what a faulty sensor reports."""
    friction = CoulombForce(input="load_force", source="ram_velocity", force=2000.0)
    faulty = SensorGain(output="ram_velocity", gain=0.5)
    alone = simulate_with_terms(archive, INPUTS, inputs, DT, OUTPUTS, [friction])
    both = simulate_with_terms(archive, INPUTS, inputs, DT, OUTPUTS, [friction, faulty])
    np.testing.assert_array_equal(both[:, :3], alone[:, :3])
    np.testing.assert_allclose(both[:, 3], 1.5 * alone[:, 3], rtol=1e-14)


def test_rate_of_a_position_stands_in_for_a_velocity(archive, inputs) -> None:
    """Viscous damping from the rate of the ram position matches damping from its velocity."""
    by_velocity = ViscousForce(input="load_force", source="ram_velocity", coefficient=1e5)
    by_rate = ViscousForce(input="load_force", source="ram_position", coefficient=1e5, rate=True)
    base = plain(archive, inputs)
    ref = simulate_with_terms(archive, INPUTS, inputs, DT, OUTPUTS, [by_velocity])
    y = simulate_with_terms(archive, INPUTS, inputs, DT, OUTPUTS, [by_rate])
    effect = np.max(np.abs(ref[:, 1] - base[:, 1]))
    assert effect > 1e-4
    assert np.max(np.abs(y[:, 1] - ref[:, 1])) < 0.01 * effect


def test_spring_pulls_towards_rest(archive, inputs) -> None:
    """A stiff spring on the ram holds it nearer its rest position than the plain model."""
    base = plain(archive, inputs)
    spring = SpringForce(input="load_force", source="ram_position", coefficient=2e6)
    y = simulate_with_terms(archive, INPUTS, inputs, DT, OUTPUTS, [spring])
    assert np.std(y[:, 1]) < 0.8 * np.std(base[:, 1])


def test_asymmetric_coulomb_differs_by_direction() -> None:
    term = CoulombForce(input="f", source="v", force=500.0, asymmetry=100.0, smoothing=1e-3)
    assert term.value(1.0) == pytest.approx(600.0)
    assert term.value(-1.0) == pytest.approx(-400.0)


def test_unknown_term_kind_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown term kind"):
        term_from_dict({"kind": "Magic"})


def test_every_proposal_sets_a_field_of_its_kind_at_a_known_place() -> None:
    """A kind's ``proposal`` (the diagnosis' hypothesis built from it) names one of the kind's
    own fields and one of the places ``generate_hypotheses`` proposes at."""
    for name, kind in TERM_KINDS.items():
        if kind.proposal is not None:
            assert kind.proposal.at in ("command", "force", "sensor"), name
            assert kind.proposal.field in {f.name for f in fields(kind)}, name


def test_the_architecture_page_shows_a_kind_as_the_code_has_it() -> None:
    """docs/architecture.md, "Adding a term kind": its excerpts are the code's, verbatim."""
    page = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    section = page.split("## Adding a term kind")[1].split("\n## ")[0]
    python = section.split("```python\n")[1].split("```")[0]
    c = section.split("```text\n")[1].split("```")[0]
    assert python in (ROOT / "fmu_greybox" / "model" / "terms.py").read_text(encoding="utf-8")
    assert c in (ROOT / "fmu_greybox" / "native" / "terms.c").read_text(encoding="utf-8")
