"""The reference FMUs in libcosim (Open Simulation Platform) through libcosimpy agree with fmpy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import OUTPUTS, unpacked
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimManipulator import CosimManipulator
from libcosimpy.CosimObserver import CosimObserver
from libcosimpy.CosimSlave import CosimLocalSlave

STEP_NS = 1_000_000  # 1 ms communication step
STEPS = 400
SWITCH = 150  # step at which the override manipulator changes the valve current


def _libcosim_run(fmu: Path, parameters: dict[str, float]) -> np.ndarray:
    _, _, refs = unpacked(fmu)
    log_output_level(CosimLogLevel.ERROR)
    execution = CosimExecution.from_step_size(step_size=STEP_NS)
    index = execution.add_local_slave(CosimLocalSlave(fmu_path=str(fmu), instance_name="ram"))
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    override = CosimManipulator.create_override()
    execution.add_manipulator(override)
    for name, value in {**parameters, "valve_current": 4.0, "load_force": 2000.0}.items():
        assert execution.real_initial_value(index, refs[name], value)
    output_refs = [refs[name] for name in OUTPUTS]
    rows = []
    for k in range(STEPS):
        if k == SWITCH:
            assert override.slave_real_values(index, [refs["valve_current"]], [-3.0])
        assert execution.step()
        rows.append(observer.last_real_values(index, output_refs))
    return np.array(rows)


def _fmpy_run(instantiate, fmu: Path, parameters: dict[str, float]) -> np.ndarray:
    """The same run with fmpy's FMU2Slave on libcosim's time grid (integer nanoseconds)."""
    slave, refs = instantiate(
        fmu, name="ram", parameters=parameters, inputs={"valve_current": 4.0, "load_force": 2000.0}
    )
    time = [k * STEP_NS / 1e9 for k in range(STEPS + 1)]
    output_refs = [refs[name] for name in OUTPUTS]
    rows = []
    for k in range(STEPS):
        if k == SWITCH:
            slave.setReal([refs["valve_current"]], [-3.0])
        slave.doStep(time[k], time[k + 1] - time[k])
        rows.append(slave.getReal(output_refs))
    slave.terminate()
    slave.freeInstance()
    return np.array(rows)


@pytest.mark.parametrize(
    ("model", "parameters"),
    [
        ("whitebox", {}),
        ("truth", {"coulomb_friction": 400.0, "time_delay": 0.003, "supply_pressure_droop": 1e10}),
    ],
)
def test_libcosim_matches_fmpy(
    instantiate, whitebox_fmu: Path, truth_fmu: Path, model: str, parameters: dict[str, float]
) -> None:
    fmu = whitebox_fmu if model == "whitebox" else truth_fmu
    cosim = _libcosim_run(fmu, parameters)
    reference = _fmpy_run(instantiate, fmu, parameters)
    assert np.ptp(reference[:, OUTPUTS.index("ram_position")]) > 0.005  # it moved both ways
    spread = np.ptp(reference, axis=0)
    assert np.all(np.abs(cosim - reference) <= 1e-12 * spread)
