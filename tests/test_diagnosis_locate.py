"""Locating the mismatch: noise levels, roles, physics labels, origin stage on known cases."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from fmu_greybox.data.noise import noise_level
from fmu_greybox.diagnosis.hypotheses import physics_label
from fmu_greybox.diagnosis.locate import Locator, _inherited, regime_signals
from fmu_greybox.diagnosis.runner import Experiment
from fmu_greybox.diagnosis.signals import SignalMap
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.model.calibration import autocorrelation_time
from fmu_greybox.project.config import load_config
from fmu_greybox.project.roles import role_from_unit
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise

CONFIG = Path(__file__).resolve().parents[1] / "bench_configs" / "hydraulic_actuator.toml"


def test_noise_level_of_white_noise_on_a_smooth_signal() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(20000) * 1e-3
    x = 0.01 * np.sin(2 * np.pi * 0.5 * t) + 2e-5 * rng.standard_normal(t.size)
    assert noise_level(x) == pytest.approx(2e-5, rel=0.05)


def test_inherited_share_is_counted_out_of_sample() -> None:
    """A filtered copy of the upstream residual is inherited. A slow drift beside upstream
    noise is not: in-sample, the integral of the noise (a random walk) fits it (73 % here)."""
    rng = np.random.default_rng(0)
    dt, n = 1e-3, 30000
    noise = rng.standard_normal(n)
    drift = np.cumsum(np.cumsum(rng.standard_normal(n)))
    drift = (drift - drift.mean()) / drift.std() * 20 + rng.standard_normal(n)
    smooth = np.convolve(rng.standard_normal(n), np.ones(200) / 200, mode="same") * 10
    driven = lfilter([0.01], [1, -0.99], smooth) * 3 + 0.1 * rng.standard_normal(n)
    assert _inherited(np.column_stack([smooth, driven]), [0, 1], 1, dt) > 0.9
    assert _inherited(np.column_stack([noise, drift]), [0, 1], 1, dt) < 0.2


def test_autocorrelation_time_of_white_and_correlated_residuals() -> None:
    rng = np.random.default_rng(1)
    white = rng.standard_normal(50000)
    assert autocorrelation_time(white) == pytest.approx(1.0, abs=0.1)
    a = 0.9
    ar = np.empty_like(white)
    ar[0] = white[0]
    for k in range(1, ar.size):
        ar[k] = a * ar[k - 1] + white[k]
    assert autocorrelation_time(ar) == pytest.approx((1 + a) / (1 - a), rel=0.2)


@pytest.mark.parametrize(
    ("unit", "role"),
    [
        ("m/s", "velocity"),
        ("m3/s", "flow"),
        ("Pa", "pressure"),
        ("N", "force"),
        ("m", "position"),
        ("mA", "current"),
        ("V", "voltage"),
        ("1", "other"),
        ("", "other"),
        ("kg", "other"),
    ],
)
def test_roles_from_units(unit: str, role: str) -> None:
    assert role_from_unit(unit) == role


@pytest.mark.parametrize(
    ("name", "description", "label"),
    [
        ("bulk_modulus", "Effective bulk modulus beta", "compliance"),
        ("leakage_coefficient", "Cross-piston leakage coefficient", "internal_leakage"),
        ("valve_gain", "EHV static gain K", "gain_error"),
        ("viscous_damping", "Viscous damping coefficient b", "viscous_friction"),
        ("valve_damping", "EHV damping ratio zeta", "lag"),
        ("torque_constant", "Torque constant k_t", "gain_error"),
        ("ram_mass", "Moving mass", None),
    ],
)
def test_physics_labels_from_names_and_descriptions(name, description, label) -> None:
    assert physics_label(name, description) == label


@pytest.fixture(scope="module")
def project():
    return load_config(CONFIG)


def locate(project, whitebox_fmu, truth_fmu, effects: dict) -> Locator:
    profile = FlightTestProfile(duration=5.0)
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        recording = synthesise(truth, whitebox, SynthRequest(effects, seed=7, profile=profile))
        signals = SignalMap.from_project(project, whitebox, recording)
        experiment = Experiment.from_project(project, whitebox, recording, signals, 4000)
        wb = experiment.simulate([])
        signals.assign_stages(wb, experiment.dt)
        experiment.stages = signals.observed_stages
        columns = {c: recording[c] for c in recording.names}
        regimes = regime_signals(signals, columns, recording.dt)
        return Locator().fit(experiment, signals, wb, regimes)


@pytest.mark.parametrize(
    ("effects", "origin"),
    [
        ({}, None),
        ({"offset": 0.2}, 0),
        ({"coulomb_friction": 800.0}, 1),
        ({"deadband": 2e-5}, 1),
        ({"time_delay": 0.004}, 0),
    ],
)
def test_origin_stage_on_known_cases(project, whitebox_fmu, truth_fmu, effects, origin) -> None:
    locator = locate(project, whitebox_fmu, truth_fmu, effects)
    assert locator.origin_ == origin
    if origin is not None:
        assert all(not s.significant for s in locator.stages_[:origin])


def test_velocity_signal_is_attached_to_the_position_stage(
    project, whitebox_fmu, truth_fmu
) -> None:
    locator = locate(project, whitebox_fmu, truth_fmu, {"coulomb_friction": 800.0})
    ram = locator.stages_[1]
    assert [s.name for s in ram.signals] == ["ram_position", "ram_velocity"]
    kinds = {r.kind for r in ram.signals[0].regimes}
    assert {"direction", "load", "pressure", "command", "band", "window"} <= kinds
