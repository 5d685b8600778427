"""Property-based tests of the exported FMU's inputs, in both runtimes.

Whatever a bench sets its inputs to, ``fmi2DoStep`` accepts the step exactly when every input is
finite and within the input domain (:class:`fmu_greybox.model.domain.InputDomain`, the
oracle), and then gives finite outputs; a refused step changes nothing (the next outputs are
those of the state before it). Each example starts from the same saved FMU state, 20 steps into
the validation recording. Uses the session's model and FMUs of ``test_export``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_export import INPUTS, STAGE_OUTPUTS, Slave, input_rows, trained

from fmu_greybox.export.fmu import RUNTIMES
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.model.domain import InputDomain, beyond_training
from fmu_greybox.model.store import load_model

START = 20  # steps run before the saved state


@pytest.fixture(scope="module")
def domain(tmp_path_factory: pytest.TempPathFactory) -> InputDomain:
    model = load_model(trained(tmp_path_factory)["model_dir"])
    with open_fmu(model.whitebox_fmu) as archive:
        return InputDomain.of(archive, list(INPUTS), model.training.input_ranges)


@pytest.fixture(scope="module", params=RUNTIMES)
def started(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory):
    """An FMU of each runtime, its state after START steps, and its outputs then."""
    cache = trained(tmp_path_factory)
    u = input_rows(cache["validation"])[: START + 1]
    slave = Slave(cache["fmus"][request.param], f"inputs_{request.param}", u)
    slave.run(u[:START])
    state = slave.slave.getFMUstate()
    outputs = slave.slave.getReal(slave.outputs)
    yield slave, state, outputs
    slave.slave.freeFMUstate(state)
    slave.close()


def input_values(low: float, high: float) -> st.SearchStrategy[float]:
    """Values a bench might set: inside the domain, near and beyond its bounds, absurd."""
    finite = [b for b in (low, high) if math.isfinite(b)]
    inside = st.floats(min_value=max(low, -1e12), max_value=min(high, 1e12))
    beyond = [st.floats(min_value=b - abs(b) - 1.0, max_value=b + abs(b) + 1.0) for b in finite]
    absurd = st.sampled_from([math.nan, math.inf, -math.inf, 1e30, -1e30])
    return st.one_of(inside, *beyond, absurd, st.floats(allow_nan=True, allow_infinity=True))


@st.composite
def bench_inputs(draw, domain: InputDomain) -> np.ndarray:
    """One row of inputs, each drawn by :func:`input_values`."""
    bounds = zip(domain.low, domain.high, strict=True)
    return np.array([draw(input_values(low, high)) for low, high in bounds])


def test_a_step_is_accepted_exactly_within_the_input_domain(started, domain) -> None:
    slave, state, before = started
    dt = float(slave.dt)

    @settings(
        max_examples=60,
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    )
    @given(u=bench_inputs(domain))
    def check(u: np.ndarray) -> None:
        slave.slave.setFMUstate(state)
        slave.slave.setReal(slave.inputs, list(u))
        refusal = domain.refusal(list(u), START * dt)
        try:
            slave.slave.doStep(START * dt, dt)
            accepted = True
        except Exception:
            accepted = False
        after = np.array(slave.slave.getReal(slave.outputs))
        assert accepted == (refusal is None), refusal
        if accepted:
            assert np.all(np.isfinite(after)), dict(zip(STAGE_OUTPUTS, after, strict=False))
        else:
            np.testing.assert_array_equal(after, before)

    check()


def test_inputs_beyond_their_training_range_are_named_with_both_ranges() -> None:
    """What ``validate`` tells an engineer to record: each input whose range reaches beyond the
    training one by more than the features' clipping margin (5 % of its span), with the range
    seen and the range trained on."""
    ranges = {"valve_current": [-1.64, 0.81], "load_force": [0.0, 1000.0]}
    rows = np.array([[-3.2, 0.0], [0.5, 1045.0], [2.1, 500.0]])
    assert beyond_training(ranges, ["valve_current", "load_force"], rows) == (
        "valve_current -3.2 to 2.1 (trained on -1.64 to 0.81)"
    )
    rows[1, 1] = 1060.0  # 6 % of the span beyond
    assert beyond_training(ranges, ["valve_current", "load_force"], rows).endswith(
        "; load_force 0 to 1.06e+03 (trained on 0 to 1e+03)"
    )
    assert beyond_training(ranges, ["other", "load_force"], rows[:, ::-1][:0]) == ""
