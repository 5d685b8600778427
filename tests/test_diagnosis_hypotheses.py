"""Each hypothesis class, calibrated through the FMU, recovers a known concealed magnitude."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fmu_greybox.diagnosis.calibrate import Calibrator, Candidate
from fmu_greybox.diagnosis.diagnose import data_scales
from fmu_greybox.diagnosis.hypotheses import (
    PARAMETER_RANGE,
    Hypothesis,
    _parameter_hypotheses,
    _relative_range,
    generate_hypotheses,
)
from fmu_greybox.diagnosis.memo import Memo
from fmu_greybox.diagnosis.runner import Experiment, Simulator
from fmu_greybox.diagnosis.select import SCREEN_PROMISE, past_ripples
from fmu_greybox.diagnosis.signals import SignalMap
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.builtin import model_fmus
from fmu_greybox.model.terms import InputOffset
from fmu_greybox.project.config import load_config
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise
from fmu_greybox.synth.positioner import synthesise_positioner

CONFIGS = Path(__file__).resolve().parents[1] / "bench_configs"
VALVE_GAIN = 4e-5  # m/mA of the reference white-box


def experiment_and_hypothesis(
    config_name: str, whitebox, recording, key: str, train: int | None = None
) -> tuple[Experiment, Hypothesis]:
    """The diagnosis' experiment (its noise model: smoothed inputs, whitening) over
    ``train`` rows fitted (default: all), and its hypothesis ``key``."""
    experiment, (hypothesis,) = experiment_and_hypotheses(
        config_name, whitebox, recording, [key], train
    )
    return experiment, hypothesis


def experiment_and_hypotheses(
    config_name: str, whitebox, recording, keys: list[str], train: int | None = None
) -> tuple[Experiment, list[Hypothesis]]:
    """As :func:`experiment_and_hypothesis`, with the hypotheses ``keys``."""
    config = load_config(CONFIGS / config_name)
    signals = SignalMap.from_project(config, whitebox, recording)
    train = recording.n_samples if train is None else train
    experiment = Experiment.from_project(config, whitebox, recording, signals, train)
    signals.assign_stages(experiment.estimate_noise(), experiment.dt)
    experiment.stages = signals.observed_stages
    scales = data_scales(whitebox, signals, experiment, 4000)
    hypotheses = {h.key: h for h in generate_hypotheses(signals, whitebox, scales, {})}
    return experiment, [hypotheses[key] for key in keys]


def calibrate(config_name: str, whitebox, recording, key: str) -> Candidate:
    """Fit one hypothesis alone over the whole recording as the selection fits a kept one:
    with the noise model the diagnosis sets, on the low-passed residual, then finished on the
    raw one, with its covariance."""
    experiment, hypothesis = experiment_and_hypothesis(config_name, whitebox, recording, key)
    candidate = Candidate([hypothesis], hypothesis.start())
    with Simulator(experiment, workers=1) as simulator:
        smoothed = Calibrator(simulator, experiment.n_samples, smoothing=20.0)
        smoothed.evaluate([candidate])
        smoothed.fit([candidate], max_iter=8, tol=1e-5)
        raw = Calibrator(simulator, experiment.n_samples)
        raw.evaluate([candidate])
        raw.polish([candidate], max_iter=3)
    return candidate


def actuator_recording(whitebox_fmu, truth_fmu, effects: dict, seed: int = 11):
    profile = FlightTestProfile(duration=6.0)
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        return synthesise(truth, whitebox, SynthRequest(effects, seed=seed, profile=profile))


#: Relative difference allowed beyond the 95 % interval where a hypothesis's form differs from
#: the truth's effect (measured: deadband 0.381, 0.381 and 0.375 on seeds 11-13, for 0.375).
FORM_ERROR = {"deadband@valve_current>EHV": 0.03}


@pytest.mark.parametrize(
    ("effects", "key", "expected"),
    [
        ({"offset": 0.2}, "offset@valve_current", 0.2),
        ({"gain_error": 0.08}, "gain_error@valve_current", 0.08),
        # The truth's deadband is a spool overlap (after the valve's dynamics), the hypothesis a
        # deadband of the current (before them): equal only in steady state.
        ({"deadband": 1.5e-5}, "deadband@valve_current>EHV", 1.5e-5 / VALVE_GAIN),
        ({"compliance": 0.3}, "parameter_mismatch@bulk_modulus", -0.3),
        ({"internal_leakage": 6e-13}, "parameter_mismatch@leakage_coefficient", 3.0),
        ({"coulomb_friction": 700.0}, "coulomb_friction@load_force(ram_velocity)", 700.0),
        (
            {"supply_pressure_droop": 1e10},
            "supply_pressure_droop@supply_pressure(supply_flow)",
            1e10,
        ),
        ({"time_delay": 0.003}, "time_delay@sensors", 0.003),
    ],
)
def test_actuator_hypothesis_recovers_its_magnitude(
    whitebox_fmu, truth_fmu, effects, key, expected
) -> None:
    recording = actuator_recording(whitebox_fmu, truth_fmu, effects)
    with open_fmu(whitebox_fmu) as whitebox:
        fitted = calibrate("hydraulic_actuator.toml", whitebox, recording, key)
    low, high = fitted.ci95[0]
    # Where the hypothesis has another form than the truth's effect, its magnitude is the
    # truth's only to within that form's difference (FORM_ERROR).
    form = FORM_ERROR.get(key, 0.0) * abs(expected)
    assert low - form <= expected <= high + form, (fitted.theta, fitted.ci95)
    assert fitted.theta[0] == pytest.approx(expected, rel=0.05)


def test_command_delay_recovers_a_recording_shifted_early(whitebox_fmu, truth_fmu) -> None:
    recording = actuator_recording(whitebox_fmu, truth_fmu, {})
    current = recording["valve_current"]
    early = np.concatenate([current[3:], np.repeat(current[-1], 3)])  # recorded 3 ms early
    recording = recording.with_signals({"valve_current": early})
    with open_fmu(whitebox_fmu) as whitebox:
        key = "time_delay@valve_current"
        fitted = calibrate("hydraulic_actuator.toml", whitebox, recording, key)
    low, high = fitted.ci95[0]
    assert low <= 0.003 <= high
    assert fitted.theta[0] == pytest.approx(0.003, rel=0.05)


def test_viscous_force_on_the_positioner_recovers_extra_friction() -> None:
    paths = model_fmus("ElectroMechanicalPositioner")
    with (
        open_fmu(paths["ElectroMechanicalPositionerTruth"]) as truth,
        open_fmu(paths["ElectroMechanicalPositioner"]) as whitebox,
    ):
        recording = synthesise_positioner(
            truth, whitebox, {"viscous_friction_extra": 300.0}, seed=5, duration=6.0, noise=1.0
        )
        fitted = calibrate(
            "positioner.toml", whitebox, recording, "viscous_friction@load_force(velocity)"
        )
    low, high = fitted.ci95[0]
    assert low <= 300.0 <= high, (fitted.theta, fitted.ci95)
    assert fitted.theta[0] == pytest.approx(300.0, rel=0.1)


def test_parameter_ranges_follow_the_fmu_declaration() -> None:
    """A parameter is searched from a tenth to a hundred times its set value, inside the range
    its FMU declares (the positioner's efficiency 0.9 may not exceed its declared 1.0)."""
    with open_fmu(model_fmus("ElectroMechanicalPositioner")["ElectroMechanicalPositioner"]) as fmu:
        efficiency = fmu.variables["transmission_efficiency"]
        assert (efficiency.minimum, efficiency.maximum) == (None, 1.0)
        assert fmu.variables["viscous_friction"].minimum == 0.0
        ranges = {h.name: (h.lower[0], h.upper[0]) for h in _parameter_hypotheses(fmu, {})}
    assert ranges["transmission_efficiency"] == pytest.approx((-0.9, 1.0 / 0.9 - 1.0))
    assert ranges["viscous_friction"] == pytest.approx(PARAMETER_RANGE)
    # a negative set value: its declared minimum bounds the relative change from above
    assert _relative_range(-2.0, -3.0, None) == pytest.approx((-0.9, 0.5))
    assert _relative_range(-2.0, None, -1.0) == pytest.approx((-0.5, 99.0))


def test_simulator_runs_a_repeated_term_set_once(whitebox_fmu, truth_fmu) -> None:
    """The screening scores the same simulations on two views of the residual: a set of terms
    asked for again over the same rows is answered from memory (read-only), not run again."""
    recording = actuator_recording(whitebox_fmu, truth_fmu, {"offset": 0.2})
    config = load_config(CONFIGS / "hydraulic_actuator.toml")
    offset = [InputOffset(input="valve_current", offset=0.1)]
    with open_fmu(whitebox_fmu) as whitebox:
        signals = SignalMap.from_project(config, whitebox, recording)
        train = int(0.8 * recording.n_samples)  # as the diagnosis holds out the last 20 %
        experiment = Experiment.from_project(config, whitebox, recording, signals, train)
        with Simulator(experiment, workers=2) as simulator:
            first = simulator.run([[], offset], rows=500)
            again = simulator.run([offset, [], offset], rows=500)
            assert simulator.runs == 2
            simulator.run([offset], rows=600)
            assert simulator.runs == 3
        direct = experiment.simulate(offset, 500)
    assert again[0] is first[1] and again[2] is first[1] and again[1] is first[0]
    np.testing.assert_array_equal(first[1], direct)
    assert not np.allclose(first[0], first[1])
    assert not first[1].flags.writeable


def test_simulation_workers_score_their_simulations(whitebox_fmu, truth_fmu) -> None:
    """A scored batch's training-row residuals come from the worker processes, equal to the
    residual computed here; another span of rows, or an unscored batch, is computed here."""
    recording = actuator_recording(whitebox_fmu, truth_fmu, {"offset": 0.2})
    config = load_config(CONFIGS / "hydraulic_actuator.toml")
    offsets = [[InputOffset(input="valve_current", offset=x)] for x in (0.1, 0.2)]
    with open_fmu(whitebox_fmu) as whitebox:
        signals = SignalMap.from_project(config, whitebox, recording)
        experiment = Experiment.from_project(config, whitebox, recording, signals, 2000)
        with Simulator(experiment, workers=2) as simulator:
            scored = simulator.run(offsets, 2500, scored=True)
            plain = simulator.run([[], *offsets[:1]], 1500)
            for sim in scored:
                residual = simulator.training_residual(sim, 2000)
                assert simulator.training_residual(sim, 2000) is residual
                assert not residual.flags.writeable
                np.testing.assert_array_equal(residual, experiment.residual(sim[:2000]))
                shorter = simulator.training_residual(sim, 1000)
                np.testing.assert_array_equal(shorter, experiment.residual(sim[:1000]))
            assert simulator.training_residual(plain[0], 1500) is not (
                simulator.training_residual(plain[0], 1500)
            )


def test_a_calibrator_scores_a_simulation_once(whitebox_fmu, truth_fmu) -> None:
    """A screen's candidates all start from one simulation: its residual is computed once per
    view (and read-only), and is the residual computed afresh, on the raw and low-passed views."""
    recording = actuator_recording(whitebox_fmu, truth_fmu, {"offset": 0.2})
    config = load_config(CONFIGS / "hydraulic_actuator.toml")
    with open_fmu(whitebox_fmu) as whitebox:
        signals = SignalMap.from_project(config, whitebox, recording)
        experiment = Experiment.from_project(config, whitebox, recording, signals, 2000)
        with Simulator(experiment, workers=1) as simulator:
            sims = simulator.run([[], [InputOffset(input="valve_current", offset=0.1)]], 2500)
            for smoothing in (0.0, 20.0):
                calibrator = Calibrator(simulator, 2500, smoothing)
                computed: list[np.ndarray] = []
                fresh = calibrator._residual
                calibrator._residual = lambda sim, f=fresh, c=computed: c.append(sim) or f(sim)
                first = [calibrator.residual(sim) for sim in sims]
                again = [calibrator.residual(sim) for sim in [*sims, sims[0]]]
                assert len(computed) == 2
                assert again[0] is first[0] and again[2] is first[0] and again[1] is first[1]
                assert not first[0].flags.writeable
                np.testing.assert_array_equal(first[1], fresh(sims[1].copy()))
                assert not np.allclose(first[0], first[1])


def test_a_memo_forgets_its_oldest_beyond_its_budget() -> None:
    """The simulator's and the calibrators' memory: within its bytes, oldest out first, each
    forgotten value handed on (the simulator drops its residual with it), the latest kept
    whatever its size."""
    forgotten: list[str] = []
    memo: Memo[str, bytes] = Memo(10, len, lambda value: forgotten.append(value.decode()))
    for key in "abc":
        memo.keep(key, key.encode() * 4)
    assert ("a" in memo, "b" in memo, "c" in memo) == (False, True, True)
    assert (memo.bytes, forgotten) == (8, ["aaaa"])
    memo.keep("b", b"bb")  # kept again: counted once, now the latest
    memo.keep("d", b"dddd")
    assert (memo.bytes, sorted(forgotten), len(memo)) == (10, ["aaaa"], 3)
    memo.keep("e", b"e" * 12)
    assert (memo.get("e"), memo.get("d"), memo.bytes) == (b"e" * 12, None, 12)
    assert forgotten == ["aaaa", "cccc", "bb", "dddd"]


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_one_screening_step_finds_an_offset_of_either_sign(whitebox_fmu, truth_fmu, sign) -> None:
    """A command offset drifts the simulated ram to an end stop. The screen's one Gauss-Newton
    step from "no effect" must land near the offset whatever its sign: a secant taken only
    upwards sees the ram reach its stop sooner for a negative one, barely changes the misfit,
    and stepped to 5 % of -0.15 mA (measured on this recording; the 20 s recording of the
    concealed suite's case offset=-0.15 was named "unexplained" for it)."""
    profile = FlightTestProfile(duration=20.0)
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        request = SynthRequest({"offset": 0.15 * sign}, seed=11, profile=profile)
        recording = synthesise(truth, whitebox, request)
    train = int(0.8 * recording.n_samples)  # as the diagnosis holds out the last 20 %
    with open_fmu(whitebox_fmu) as whitebox:
        experiment, offset = experiment_and_hypothesis(
            "hydraulic_actuator.toml", whitebox, recording, "offset@valve_current", train
        )
        with Simulator(experiment, workers=1) as simulator:
            window = Calibrator(simulator, train, 20.0, difference_step=2.0)  # the screen's
            candidate = Candidate([offset], offset.start())
            window.evaluate([candidate])
            before = candidate.cost
            window.fit([candidate], max_iter=1, tries=1, both_sides=True)
    assert candidate.theta[0] == pytest.approx(0.15 * sign, rel=0.1)
    assert candidate.cost < 0.05 * before


def test_the_screen_tries_no_step_that_promises_nothing(whitebox_fmu, truth_fmu) -> None:
    """A screen's step costs two simulations a candidate (two step lengths). A candidate whose
    linearised step promises less than :data:`SCREEN_PROMISE` of the window's cost stays at "no
    effect" without them; a promising one steps exactly as without the rule. Here the pressure
    sensor's offset cannot explain a command offset: tried anyway, its step would not have
    reached the 1 % a screened candidate must explain to go on."""
    recording = actuator_recording(whitebox_fmu, truth_fmu, {"offset": 0.2})
    train = int(0.8 * recording.n_samples)
    keys = ["offset@valve_current", "sensor_offset@itfv_pressure"]
    outcome = {}
    with open_fmu(whitebox_fmu) as whitebox:
        experiment, hypotheses = experiment_and_hypotheses(
            "hydraulic_actuator.toml", whitebox, recording, keys, train
        )
        for promise in (0.0, SCREEN_PROMISE):
            with Simulator(experiment, workers=1) as simulator:
                window = Calibrator(simulator, train, 20.0, difference_step=2.0)  # the screen's
                candidates = [Candidate([h], h.start()) for h in hypotheses]
                window.evaluate(candidates)
                start = [c.cost for c in candidates]
                runs = simulator.runs
                window.fit(
                    candidates, max_iter=1, tries=1, both_sides=True, min_predicted_gain=promise
                )
                outcome[promise] = (
                    simulator.runs - runs,
                    [
                        (c.theta.copy(), c.cost / cost)
                        for c, cost in zip(candidates, start, strict=True)
                    ],
                )
    (runs_all, (offset_all, sensor_all)) = outcome[0.0]
    (runs_kept, (offset_kept, sensor_kept)) = outcome[SCREEN_PROMISE]
    np.testing.assert_array_equal(offset_kept[0], offset_all[0])
    assert offset_kept[1] == offset_all[1] < 0.5
    assert sensor_all[1] >= 0.99  # tried, it would not have gone on
    assert (sensor_kept[1], runs_all - runs_kept) == (1.0, 2)
    np.testing.assert_array_equal(sensor_kept[0], hypotheses[1].start())


def test_a_refinement_stopped_on_a_ripple_goes_on_from_a_probe(whitebox_fmu, truth_fmu) -> None:
    """Entrained air lowers the bulk modulus, which tunes the ram's lightly damped mode: the
    low-passed misfit the refinement fits keeps ripples beside its valley. Here (a concealed
    ``compliance=0.15``, the diagnosis's refinement window) the screen's step put the bulk
    modulus at -22 %, in a dip where every local step costs more: refined from there, it
    stays. Probed one scale either way (:func:`~fmu_greybox.diagnosis.select.past_ripples`), it
    reaches the valley's floor at the true -15 %."""
    profile = FlightTestProfile(duration=20.0)
    request = SynthRequest({"compliance": 0.15}, seed=308, profile=profile)
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        recording = synthesise(truth, whitebox, request)
        train = int(0.8 * recording.n_samples)
        experiment, hypothesis = experiment_and_hypothesis(
            "hydraulic_actuator.toml", whitebox, recording, "parameter_mismatch@bulk_modulus", train
        )
        with Simulator(experiment, workers=2) as simulator:
            refine = Calibrator(simulator, 10148, 20.0)  # the refinement's view and window
            stuck, escaped = (Candidate([hypothesis], np.array([-0.2203])) for _ in range(2))
            refine.evaluate([stuck, escaped])
            refine.fit([stuck, escaped], max_iter=5)
            moves = past_ripples(refine, [escaped], max_iter=5)
    assert stuck.theta[0] == pytest.approx(-0.22, abs=0.01)
    assert moves >= 1
    assert escaped.theta[0] == pytest.approx(-0.15, abs=0.01)
    assert escaped.cost < 0.95 * stuck.cost
