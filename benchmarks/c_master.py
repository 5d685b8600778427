"""Build and run the bare C master (``c_master.c``): an FMU stepped by a process without Python.

Used by ``tests/test_native_fmu.py`` (equivalence; no Python in the process) and by
``bench_export.py`` (cost per step of the native grey-box and of the white-box alone).
"""

from __future__ import annotations

import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description

from fmu_greybox.fmi.build import fmi2_headers
from fmu_greybox.fmi.compiler import NATIVE_DIR, CBuild, compile_library, core_flags
from fmu_greybox.fmi.platforms import BinaryPlatform, host_platform
from fmu_greybox.fmi.wine import wine_program

SOURCE = Path(__file__).resolve().parent / "c_master.c"
#: The statuses of the refused steps the master reports (see ``c_master.c``).
REFUSALS = ("refused_step_size", "refused_time_jump", "refused_input")


def build(folder: Path, target: BinaryPlatform | None = None) -> Path:
    """Compile the master into ``folder`` for ``target`` (this machine when ``None``; win64:
    a static ``c_master.exe``, run under Wine by :func:`run`); returns the program."""
    target = target or host_platform()
    program = folder / ("c_master.exe" if target.windows else "c_master")
    build = CBuild(
        what="the bare C master",
        sources=(SOURCE,),
        flags=core_flags(),
        include_dirs=(fmi2_headers(), NATIVE_DIR),
        libraries=("dl",),
        shared=False,
    )
    compile_library(build, program, target)
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
    refusals : dict of str to int
        The fmi2Status of each refused step of :data:`REFUSALS`.
    """

    outputs: np.ndarray
    cpu_us: float
    python_in_process: bool
    refusals: dict[str, int]


def run(
    program: Path,
    fmu: Path,
    inputs: list[str],
    outputs: list[str],
    rows: np.ndarray,
    folder: Path,
    repeats: int = 1,
) -> MasterRun:
    """Step an FMU over input rows (row k acts over step k) in the C master (a Windows master,
    ``c_master.exe``, under Wine).

    Raises
    ------
    RuntimeError
        The master failed (its stderr, with the FMU's messages, is quoted).
    """
    description = read_model_description(str(fmu))
    refs = {v.name: v.valueReference for v in description.modelVariables}
    unpacked = extract(str(fmu), str(folder / "fmu"))
    np.savetxt(folder / "inputs.txt", rows, fmt="%.17g")
    windows = program.suffix == ".exe"
    env = {"PATH": "/usr/bin:/bin"}  # nothing of this Python's environment
    if windows:  # Wine finds its prefix from HOME (or WINEPREFIX)
        env.update({k: v for k, v in os.environ.items() if k in ("HOME", "WINEPREFIX")})
        env["WINEDEBUG"] = "-all"
    done = subprocess.run(
        [
            *([wine_program()] if windows else []),
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
        env=env,
    )
    if done.returncode != 0:
        raise RuntimeError(f"the C master failed on {fmu.name}: {done.stderr}")
    report = dict(line.split(" ", 1) for line in done.stdout.splitlines())
    return MasterRun(
        outputs=np.loadtxt(folder / "outputs.txt", ndmin=2),
        cpu_us=float(report["cpu_us_per_step"]),
        python_in_process=report["python_in_process"] == "yes",
        refusals={name: int(report[name]) for name in REFUSALS},
    )
