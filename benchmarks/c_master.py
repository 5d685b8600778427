"""Build and run the bare C master (``c_master.c``): an FMU stepped by a process without Python.

Used by ``tests/test_native_fmu.py`` (equivalence; no Python in the process) and by
``bench_export.py`` (cost per step of the native grey-box and of the white-box alone).
"""

from __future__ import annotations

import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description

from fmu_greybox.fmi.build import c_compiler, fmi2_headers

SOURCE = Path(__file__).resolve().parent / "c_master.c"


def build(folder: Path) -> Path:
    """Compile the master into ``folder``; returns the program."""
    program = folder / "c_master"
    command = [c_compiler(), "-O2", "-std=c11", f"-I{fmi2_headers()}", str(SOURCE)]
    subprocess.run([*command, "-o", str(program), "-ldl"], check=True, capture_output=True)
    return program


@dataclass(frozen=True)
class MasterRun:
    """What the C master reported.

    Attributes
    ----------
    outputs : ndarray, shape (steps, n_outputs)
        The outputs after each step.
    cpu_us : float
        CPU time per step [us] of the stepping loop (set inputs, fmi2DoStep, get outputs), the
        least over the repeats.
    python_in_process : bool
        Whether ``/proc/self/maps`` of the master named anything Python.
    """

    outputs: np.ndarray
    cpu_us: float
    python_in_process: bool


def run(
    program: Path,
    fmu: Path,
    inputs: list[str],
    outputs: list[str],
    rows: np.ndarray,
    folder: Path,
    repeats: int = 1,
) -> MasterRun:
    """Step an FMU over input rows (row k acts over step k) in the C master.

    Raises
    ------
    RuntimeError
        The master failed (its stderr, with the FMU's messages, is quoted).
    """
    description = read_model_description(str(fmu))
    refs = {v.name: v.valueReference for v in description.modelVariables}
    unpacked = extract(str(fmu), str(folder / "fmu"))
    np.savetxt(folder / "inputs.txt", rows, fmt="%.17g")
    done = subprocess.run(
        [
            str(program),
            unpacked,
            description.coSimulation.modelIdentifier,
            description.guid,
            repr(float(description.defaultExperiment.stepSize)),
            ",".join(str(refs[n]) for n in inputs),
            ",".join(str(refs[n]) for n in outputs),
            str(folder / "inputs.txt"),
            str(folder / "outputs.txt"),
            str(repeats),
        ],
        capture_output=True,
        text=True,
        check=False,
        env={"PATH": "/usr/bin:/bin"},  # nothing of this Python's environment
    )
    if done.returncode != 0:
        raise RuntimeError(f"the C master failed on {fmu.name}: {done.stderr}")
    report = dict(line.split(" ", 1) for line in done.stdout.splitlines())
    return MasterRun(
        outputs=np.loadtxt(folder / "outputs.txt", ndmin=2),
        cpu_us=float(report["cpu_us_per_step"]),
        python_in_process=report["python_in_process"] == "yes",
    )
