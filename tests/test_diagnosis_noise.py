"""The noise model of the diagnosis: sensor noise of fast signals, input noise of closed-loop
commands, the drift input noise drives, and structure concentrated in one band."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from third_party import INPUTS as SERVO_INPUTS
from third_party import SENSOR_NOISE as SERVO_NOISE
from third_party import record

from fmu_greybox.data.noise import (
    DriftWhitening,
    InputSmoother,
    estimate_noise_model,
    input_noise_levels,
    noise_level,
    residual_bands,
    sensor_noise_level,
    significance,
)
from fmu_greybox.diagnosis.runner import Experiment
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.model.native_run import runs_side_by_side
from fmu_greybox.model.simulate import simulate_with_terms
from fmu_greybox.synth.actuator import (
    INPUTS,
    SENSOR_NOISE,
    FlightTestProfile,
    SynthRequest,
    coloured_noise,
)
from fmu_greybox.synth.actuator import synthesise as record_actuator


def test_closed_loop_command_noise_is_told_from_its_genuine_fast_content(
    whitebox_fmu, truth_fmu
) -> None:
    """The logged valve current is the controller's reaction to the position sensor's noise
    (genuine, the valve follows it) plus its own sensor's noise (0.02 mA): the second
    differences alone see both, the other recorded signals explain the first."""
    profile = FlightTestProfile(duration=8.0)
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        recording = record_actuator(truth, whitebox, SynthRequest({}, seed=5, profile=profile))
    u = np.column_stack([recording[name] for name in INPUTS])
    outputs = np.column_stack(
        [recording[name] for name in ("spool_position", "ram_position", "ram_velocity")]
    )
    levels = input_noise_levels(u, outputs)
    assert noise_level(recording["valve_current"]) > 1.8 * SENSOR_NOISE["valve_current"]
    assert levels[0] == pytest.approx(SENSOR_NOISE["valve_current"], rel=0.1)
    assert levels[1] == pytest.approx(SENSOR_NOISE["supply_pressure"], rel=0.1)


def test_fast_signal_noise_is_taken_from_its_residual(dc_servo_fmus) -> None:
    """The servo's armature current (1.7 ms time constant) moves a lot between samples: its
    recording's second differences overstate its sensor noise twofold; its residual against
    the white-box does not."""
    with open_fmu(dc_servo_fmus["DCServoTruth"]) as truth:
        recording = record(truth, {}, seed=6, duration=6.0)
    with open_fmu(dc_servo_fmus["DCServo"]) as whitebox:
        u = np.column_stack([recording[name] for name in SERVO_INPUTS])
        current = simulate_with_terms(whitebox, SERVO_INPUTS, u, recording.dt, ["ia"])[:, 0]
    true = SERVO_NOISE["ia"]
    assert noise_level(recording["ia"]) > 1.8 * true
    assert sensor_noise_level(recording["ia"], current) == pytest.approx(true, rel=0.3)


def test_smoothing_removes_input_noise_and_keeps_the_command() -> None:
    """A slow command (0.5 and 3 Hz) logged with white noise of 0.02: smoothed, its error is a
    fifth of the noise away from the ends, no lag, and the remaining error's draws have the
    Wiener error's power (the noise's power times the mean gain)."""
    dt, n, sigma = 1e-3, 20_000, 0.02
    t = np.arange(n) * dt
    command = np.sin(2 * np.pi * 0.5 * t) + 0.3 * np.sin(2 * np.pi * 3.0 * t)
    rng = np.random.default_rng(4)
    logged = (command + sigma * rng.standard_normal(n))[:, None]
    smoother = InputSmoother(logged, np.array([sigma]))
    error = smoother(logged)[:, 0] - command
    assert np.sqrt(np.mean(error[200:-200] ** 2)) < 0.2 * sigma
    # the mirror image puts a kink where the command has a slope at an end: a few rows there
    assert np.sum(np.abs(error) > sigma) < 50
    lag = np.argmax(np.correlate(smoother(logged)[:, 0], command, "full")) - (n - 1)
    assert lag == 0
    draws = np.array([smoother.noise(rng, np.array([sigma]))[:, 0] for _ in range(4)])
    assert np.mean(draws**2) == pytest.approx(np.mean(smoother.gain) * sigma**2, rel=0.2)
    quiet = InputSmoother(command[:, None], np.array([0.0]))
    np.testing.assert_allclose(quiet(command[:, None])[:, 0], command, atol=1e-12)


def test_whitening_makes_input_noise_drift_white_at_the_sensor_level() -> None:
    """An integrator of a noisy input: the residual is the sensor noise plus a random walk of
    ten noise levels; whitened against the drift re-noised runs show, it is white at about
    one noise level, with no band structured beyond chance."""
    rng = np.random.default_rng(7)
    n, dt, sigma = 20000, 1e-3, 1.0

    def walk() -> np.ndarray:
        return np.cumsum(rng.standard_normal(n)) * 0.12

    residual = (rng.standard_normal(n) * sigma + walk())[:, None]
    assert np.sqrt(np.mean(residual**2)) > 5.0
    whitening = DriftWhitening(np.array([walk()[:, None] for _ in range(4)]), np.ones(1), dt)
    whitened = whitening(residual)
    ratio, significant = significance(whitened, residual_bands(residual, whitening, dt))
    assert 0.7 < ratio[0] < 1.2
    assert not significant[0]


def test_an_offset_of_two_noise_levels_under_drift_is_significant_in_its_band() -> None:
    """Input noise makes the residual wander slowly by about a noise level (as the load
    torque's noise moves a servo's current): far more power at low frequencies than the
    sensor noise has there, so an offset of two noise levels lifts the whitened RMS little;
    in its band (the mean) it stands out."""
    rng = np.random.default_rng(8)
    n, dt = 20000, 1e-3

    def wander() -> np.ndarray:
        return coloured_noise(n, dt, 1.0, 0.5, rng)[:, None]

    whitening = DriftWhitening(np.array([wander() for _ in range(4)]), np.ones(1), dt)
    noise = rng.standard_normal((n, 1)) + wander()
    for offset, expected in ((0.0, False), (2.0, True)):
        residual = noise + offset
        bands = residual_bands(residual, whitening, dt)
        ratio, significant = significance(whitening(residual), bands)
        assert significant[0] == expected, offset
    assert ratio[0] < 1.3  # the RMS alone would not see it
    assert bands.significant[0, 0]  # the mean's band


def test_inputs_without_noise_are_not_renoised() -> None:
    """Where the noise model found no input noise, a re-drawn copy keeps the inputs as they are
    (the polish's input-noise variance is then zero, not the inputs' second-difference level)."""
    u = np.column_stack([np.sin(np.linspace(0.0, 6.0, 400)), np.zeros(400)])
    experiment = Experiment(
        archive=None,
        inputs=["a", "b"],
        u=u,
        dt=1e-3,
        start_time=0.0,
        outputs=[],
        stages=[],
        recorded=np.zeros((400, 0)),
        sigma=np.zeros(0),
        parameters={},
        train_rows=300,
        input_sigma=np.zeros(2),
    )
    np.testing.assert_array_equal(experiment.renoised(np.random.default_rng(0)).u, u)


def test_the_noise_model_is_the_same_with_its_runs_side_by_side_or_in_turn(
    whitebox_fmu, truth_fmu, two_cores
) -> None:
    """The re-drawn runs that measure the drift go in two threads when the white-box allows
    it; the noise model is the same to the bit (the draws are made first, in turn)."""
    profile = FlightTestProfile(duration=3.0)
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        recording = record_actuator(truth, whitebox, SynthRequest({}, seed=3, profile=profile))
        u = np.column_stack([recording[name] for name in INPUTS])
        names = ["spool_position", "ram_position", "itfv_pressure"]
        outputs = np.column_stack([recording[name] for name in names])
        threads: set[int] = set()

        def simulate(inputs: np.ndarray) -> np.ndarray:
            threads.add(threading.get_ident())
            return simulate_with_terms(whitebox, INPUTS, inputs, recording.dt, names)

        assert runs_side_by_side([], whitebox)
        in_turn = estimate_noise_model(u, outputs, simulate, recording.dt)
        assert threads == {threading.get_ident()}
        side_by_side = estimate_noise_model(u, outputs, simulate, recording.dt, side_by_side=True)
    assert len(threads) >= 3  # this thread's first run, and two threads for the re-drawn runs
    assert in_turn is not None and side_by_side is not None
    assert in_turn.whitening is not None and side_by_side.whitening is not None
    np.testing.assert_array_equal(side_by_side.sigma, in_turn.sigma)
    np.testing.assert_array_equal(side_by_side.whitening.ratio, in_turn.whitening.ratio)
    np.testing.assert_array_equal(side_by_side.whitening.drift, in_turn.whitening.drift)


def test_a_white_box_instantiated_once_per_process_runs_in_turn(
    whitebox_fmu, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An FMU that says it can be instantiated only once per process never runs in two
    threads at once."""
    with open_fmu(whitebox_fmu) as whitebox:
        assert runs_side_by_side([], whitebox)
        flags = whitebox.model_description.coSimulation
        monkeypatch.setattr(flags, "canBeInstantiatedOnlyOncePerProcess", True)
        assert not runs_side_by_side([], whitebox)
