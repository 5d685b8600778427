"""Shared fixtures: the reference FMUs, built once per session, and helpers to run them.

Fixtures
--------
fmu_dir
    Folder holding ``HydraulicActuator.fmu`` and ``HydraulicActuatorTruth.fmu``.
whitebox_fmu, truth_fmu
    The two FMU paths.
dc_servo_fmus
    The third-party-style DC servo's FMUs (``tests/third_party.py``), by model identifier.
instantiate
    ``instantiate(fmu, name=..., parameters=..., inputs=...) -> (FMU2Slave, {name: vr})``: an
    fmpy slave that has left initialisation mode at t = 0.
simulate
    ``simulate(fmu, stop_time, step_size=1e-3, inputs=..., parameters=...) -> {name: array}``:
    a communication-step loop with fmpy's ``FMU2Slave`` on the time grid ``simulate_fmu`` uses;
    inputs are constants or vectorised functions of time sampled at each step's start.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.model_description import ModelDescription

from fmu_greybox import side_by_side
from fmu_greybox.fmi.build import build_reference_fmus

OUTPUTS = (
    "spool_position",
    "ram_position",
    "itfv_pressure",
    "ram_velocity",
    "load_flow",
    "relief_flow",
    "pressure_a",
    "pressure_b",
    "spool_velocity",
    "supply_flow",
)
INPUTS = ("valve_current", "supply_pressure", "load_force", "engage")

Signal = float | Callable[[np.ndarray], np.ndarray]


@functools.cache
def unpacked(fmu: Path) -> tuple[ModelDescription, str, dict[str, int]]:
    """Model description, extracted folder and value references of an FMU (extracted once)."""
    description = read_model_description(str(fmu))
    folder = extract(str(fmu), unzipdir=str(fmu.with_suffix("")))
    refs = {v.name: v.valueReference for v in description.modelVariables}
    return description, folder, refs


def instantiate_fmu(
    fmu: Path,
    name: str = "actuator",
    parameters: Mapping[str, float] | None = None,
    inputs: Mapping[str, float] | None = None,
) -> tuple[FMU2Slave, dict[str, int]]:
    """An initialised fmpy slave of ``fmu`` at t = 0 and the value references by name."""
    description, folder, refs = unpacked(fmu)
    slave = FMU2Slave(
        guid=description.guid,
        unzipDirectory=folder,
        modelIdentifier=description.coSimulation.modelIdentifier,
        instanceName=name,
    )
    slave.instantiate()
    try:
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        values = {**(parameters or {}), **(inputs or {})}
        if values:
            slave.setReal([refs[k] for k in values], list(values.values()))
        slave.exitInitializationMode()
    except Exception:
        slave.freeInstance()
        raise
    return slave, refs


def simulate_fmu_loop(
    fmu: Path,
    stop_time: float,
    step_size: float = 1e-3,
    inputs: Mapping[str, Signal] | None = None,
    parameters: Mapping[str, float] | None = None,
    outputs: tuple[str, ...] = OUTPUTS,
    name: str = "actuator",
) -> dict[str, np.ndarray]:
    """Run ``fmu`` over [0, stop_time] and return time, the inputs and the outputs.

    Time points are ``k * step_size`` and each step is ``t[k+1] - t[k]``, as in fmpy's
    ``simulate_fmu``, so both give bitwise comparable runs.
    """
    n = round(stop_time / step_size)
    time = np.array([k * step_size for k in range(n + 1)])
    signals = {}
    for key, signal in (inputs or {}).items():
        values = signal(time) if callable(signal) else np.full(time.shape, float(signal))
        signals[key] = np.broadcast_to(np.asarray(values, dtype=float), time.shape)
    slave, refs = instantiate_fmu(fmu, name, parameters, {k: v[0] for k, v in signals.items()})
    input_refs = [refs[k] for k in signals]
    output_refs = [refs[k] for k in outputs]
    result = np.empty((n + 1, len(outputs)))
    result[0] = slave.getReal(output_refs)
    try:
        for k in range(n):
            if input_refs:
                slave.setReal(input_refs, [float(v[k]) for v in signals.values()])
            slave.doStep(
                currentCommunicationPoint=time[k], communicationStepSize=time[k + 1] - time[k]
            )
            result[k + 1] = slave.getReal(output_refs)
    finally:
        slave.terminate()
        slave.freeInstance()
    return {"time": time, **signals, **{k: result[:, i] for i, k in enumerate(outputs)}}


@pytest.fixture(scope="session")
def fmu_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Folder with both reference FMUs, built once per test session."""
    folder = tmp_path_factory.mktemp("fmus")
    build_reference_fmus(folder)
    return folder


@pytest.fixture(scope="session")
def whitebox_fmu(fmu_dir: Path) -> Path:
    """The white-box ``HydraulicActuator.fmu``."""
    return fmu_dir / "HydraulicActuator.fmu"


@pytest.fixture(scope="session")
def truth_fmu(fmu_dir: Path) -> Path:
    """The truth ``HydraulicActuatorTruth.fmu``."""
    return fmu_dir / "HydraulicActuatorTruth.fmu"


@pytest.fixture(scope="session")
def whitebox_archive(whitebox_fmu: Path):
    """The white-box FMU, opened once per session."""
    from fmu_greybox.fmi.archive import open_fmu

    with open_fmu(whitebox_fmu) as archive:
        yield archive


@pytest.fixture(scope="session")
def actuator_inputs() -> np.ndarray:
    """800 rows at 1 ms of the white-box's inputs (current, supply, load, engage): a biased
    sine current and a slower load sine at full supply, engaged."""
    t = np.arange(800) * 1e-3
    u = np.empty((t.size, 4))
    u[:, 0] = 2.0 * np.sin(2 * np.pi * 3 * t) + 0.5
    u[:, 1] = 20.7e6
    u[:, 2] = 2000.0 * np.sin(2 * np.pi * 1.3 * t)
    u[:, 3] = 1.0
    return u


@pytest.fixture(scope="session")
def instantiate() -> Callable[..., tuple[FMU2Slave, dict[str, int]]]:
    """:func:`instantiate_fmu`."""
    return instantiate_fmu


@pytest.fixture(scope="session")
def simulate() -> Callable[..., dict[str, np.ndarray]]:
    """:func:`simulate_fmu_loop`."""
    return simulate_fmu_loop


@pytest.fixture()
def two_cores(monkeypatch: pytest.MonkeyPatch) -> None:
    """The process may use two cores (one core runs two threads too, in turns)."""
    monkeypatch.setattr(side_by_side, "available_cores", lambda: 2)


@pytest.fixture(scope="session")
def dc_servo_fmus(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The third-party-style DC servo (``tests/data/dc_servo``): ``DCServo``, ``DCAxis`` (no
    speed output) and ``DCServoTruth``, built once per test session."""
    from third_party import build_fmus

    return build_fmus(tmp_path_factory.mktemp("dc_servo"))


#: Seconds each test file took in a full run (``tests/file_seconds.txt``), by file path.
FILE_SECONDS = {
    path: float(seconds)
    for seconds, path in (
        line.split()
        for line in (Path(__file__).parent / "file_seconds.txt").read_text().splitlines()
        if line.strip() and not line.startswith("#")
    )
}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Heaviest test files first (``tests/file_seconds.txt``), so that no long file starts
    last on one pytest worker while the other idles; the order inside a file is kept.
    ``scripts/test.sh`` keeps this order with ``--no-loadscope-reorder``."""
    items.sort(key=lambda item: -FILE_SECONDS.get(item.nodeid.split("::")[0], 0.0))
