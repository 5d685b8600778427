"""Speed of the white-box actuator FMU: 25 000 communication steps of 1 ms (25 s simulated).

Three ways, in one run on one machine:

- ``FMU2Slave loop``: fmpy's ``FMU2Slave``, per step set the valve current, ``doStep``, get the
  ten outputs (what a Python master such as the grey-box co-simulation does);
- ``simulate_fmu``: fmpy's ``simulate_fmu`` with the same input signal and output interval;
- ``C only``: one ``doStep`` over the whole 25 s with a constant input: the integrator's own
  cost, without Python and FMI call overhead.

Usage: ``.venv/bin/python benchmarks/bench_whitebox.py [--fmu PATH] [--steps N] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Slave

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from fmu_greybox.fmi.build import REFERENCE_MODEL_DIR, build_fmu

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
STEP = 1e-3  # s


def current(t: np.ndarray) -> np.ndarray:
    """Valve current [mA]: multi-sine around null."""
    return 3.0 * np.sin(2 * np.pi * 0.5 * t) + 1.0 * np.sin(2 * np.pi * 7.0 * t)


def _slave(fmu: Path, folder: str, name: str) -> tuple[FMU2Slave, dict[str, int]]:
    description = read_model_description(str(fmu))
    refs = {v.name: v.valueReference for v in description.modelVariables}
    slave = FMU2Slave(
        guid=description.guid,
        unzipDirectory=folder,
        modelIdentifier=description.coSimulation.modelIdentifier,
        instanceName=name,
    )
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    return slave, refs


def bench_loop(fmu: Path, folder: str, steps: int) -> float:
    """Wall time [s] of the FMU2Slave step loop."""
    slave, refs = _slave(fmu, folder, "loop")
    u = current(np.arange(steps) * STEP).tolist()
    vr_in, vr_out = [refs["valve_current"]], [refs[name] for name in OUTPUTS]
    start = time.perf_counter()
    for k in range(steps):
        slave.setReal(vr_in, [u[k]])
        slave.doStep(k * STEP, STEP)
        slave.getReal(vr_out)
    wall = time.perf_counter() - start
    slave.terminate()
    slave.freeInstance()
    return wall


def bench_simulate_fmu(fmu: Path, steps: int) -> float:
    """Wall time [s] of fmpy's simulate_fmu (includes loading and unpacking the FMU)."""
    t = np.arange(steps + 1) * STEP
    signal = np.zeros(
        t.size,
        dtype=[
            (name, float)
            for name in ("time", "valve_current", "supply_pressure", "load_force", "engage")
        ],
    )
    signal["time"], signal["valve_current"] = t, current(t)
    signal["supply_pressure"], signal["engage"] = 20.7e6, 1.0
    start = time.perf_counter()
    simulate_fmu(
        str(fmu), stop_time=steps * STEP, output_interval=STEP, input=signal, output=list(OUTPUTS)
    )
    return time.perf_counter() - start


def bench_c_only(fmu: Path, folder: str, steps: int) -> float:
    """Wall time [s] of one doStep over the whole horizon."""
    slave, refs = _slave(fmu, folder, "c-only")
    slave.setReal([refs["valve_current"]], [1.0])
    start = time.perf_counter()
    slave.doStep(0.0, steps * STEP)
    wall = time.perf_counter() - start
    slave.terminate()
    slave.freeInstance()
    return wall


def main() -> None:
    """Run the benchmark and print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fmu", type=Path, help="FMU to time (default: build the white-box)")
    parser.add_argument("--steps", type=int, default=25_000, help="communication steps")
    parser.add_argument("--json", action="store_true", help="print a final JSON line")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        fmu = args.fmu or build_fmu(REFERENCE_MODEL_DIR, Path(tmp), "HydraulicActuator")
        folder = extract(str(fmu), unzipdir=str(Path(tmp) / "unpacked"))
        walls = {
            "FMU2Slave loop": bench_loop(fmu, folder, args.steps),
            "simulate_fmu": bench_simulate_fmu(fmu, args.steps),
            "C only": bench_c_only(fmu, folder, args.steps),
        }
    simulated = args.steps * STEP
    print(
        f"{fmu.name}: {args.steps} samples, communication step {STEP * 1e3:g} ms "
        f"({simulated:g} s simulated)"
    )
    print(f"{'':16} {'wall [s]':>9} {'us/step':>9} {'real-time factor':>17} {'x C only':>9}")
    for name, wall in walls.items():
        print(
            f"{name:16} {wall:9.3f} {wall / args.steps * 1e6:9.2f} {simulated / wall:17.1f} "
            f"{wall / walls['C only']:9.2f}"
        )
    if args.json:
        print(
            json.dumps(
                {
                    "fmu": fmu.name,
                    "samples": args.steps,
                    "step_size": STEP,
                    "results": {
                        name: {
                            "wall_s": wall,
                            "us_per_step": wall / args.steps * 1e6,
                            "real_time_factor": simulated / wall,
                        }
                        for name, wall in walls.items()
                    },
                }
            )
        )


if __name__ == "__main__":
    main()
