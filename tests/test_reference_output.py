"""Regression: the white-box reproduces fmu_sources/HydraulicActuator/reference_output.csv.

The input sequence is documented in fmu_sources/HydraulicActuator/README.md (section 7) and
defined by :func:`reference_inputs`. After a deliberate physics change, regenerate with

    .venv/bin/python -m tests.test_reference_output --write     (from the repository root)
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from fmu_greybox.fmi.build import REFERENCE_MODEL_DIR, build_fmu

sys.path.insert(0, str(Path(__file__).resolve().parent))  # conftest, when run with -m
from conftest import INPUTS, OUTPUTS, simulate_fmu_loop

REFERENCE_CSV = REFERENCE_MODEL_DIR / "reference_output.csv"
STOP_TIME = 2.0  # s
STEP_SIZE = 1e-3  # s
TOLERANCE = 1e-9  # of each output's range


def reference_inputs(time: np.ndarray) -> dict[str, np.ndarray]:
    """The documented input sequence: current step, then multi-sine; constant supply; load step."""
    tau = time - 0.5
    multisine = (
        3.0 * np.sin(2 * np.pi * 1.5 * tau)
        + 1.5 * np.sin(2 * np.pi * 6.0 * tau)
        + 0.8 * np.sin(2 * np.pi * 17.0 * tau)
    )
    current = np.where(time < 0.1, 0.0, np.where(time < 0.5, 2.0, multisine))
    return {
        "valve_current": current,
        "supply_pressure": np.full(time.shape, 20.7e6),
        "load_force": np.where(time >= 1.2, 5000.0, 0.0),
        "engage": np.ones(time.shape),
    }


def run_reference(fmu: Path) -> dict[str, np.ndarray]:
    """Simulate the white-box over the reference inputs."""
    time = np.array([k * STEP_SIZE for k in range(round(STOP_TIME / STEP_SIZE) + 1)])
    signals = reference_inputs(time)
    inputs = {name: (lambda t, v=values: v) for name, values in signals.items()}
    return simulate_fmu_loop(fmu, STOP_TIME, STEP_SIZE, inputs=inputs)


def read_reference() -> dict[str, np.ndarray]:
    """The committed reference as {column: values}."""
    table = np.genfromtxt(REFERENCE_CSV, delimiter=",", names=True)
    return {name: table[name] for name in table.dtype.names}


def write_reference() -> None:
    """Build the white-box, simulate the reference inputs and write the CSV."""
    with tempfile.TemporaryDirectory() as folder:
        run = run_reference(build_fmu(REFERENCE_MODEL_DIR, Path(folder), "HydraulicActuator"))
    columns = ["time", *INPUTS, *OUTPUTS]
    data = np.column_stack([run[name] for name in columns])
    np.savetxt(
        REFERENCE_CSV, data, delimiter=",", header=",".join(columns), comments="", fmt="%.12g"
    )


def test_reference_inputs_are_the_documented_ones() -> None:
    reference = read_reference()
    for name, values in reference_inputs(reference["time"]).items():
        np.testing.assert_allclose(reference[name], values, rtol=1e-11, atol=1e-11)


def test_whitebox_reproduces_reference_output(whitebox_fmu: Path) -> None:
    reference = read_reference()
    run = run_reference(whitebox_fmu)
    np.testing.assert_allclose(run["time"], reference["time"], rtol=0, atol=1e-12)
    for name in OUTPUTS:
        spread = np.ptp(reference[name])
        assert np.max(np.abs(run[name] - reference[name])) <= TOLERANCE * spread, name


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="rewrite reference_output.csv")
    if parser.parse_args().write:
        write_reference()
        print(f"wrote {REFERENCE_CSV}")
