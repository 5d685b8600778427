"""Single-bit flips of a serialised FMU state, each restored into a running instance.

Run as a program in its own process (a segfault then ends this process, not pytest's)::

    python state_flips.py FMU INPUTS.npy HEADER_BYTES BODY_SAMPLE SEED NAME [NAME ...]

The FMU runs the first half of the rows of ``INPUTS.npy`` (columns: the inputs NAME ...), its
state is saved and serialised, and the second half is run as the reference. Then every bit of
the first HEADER_BYTES bytes, and BODY_SAMPLE bits drawn (seeded) from the rest, is flipped in
turn; each damaged copy goes through ``fmi2DeSerializeFMUstate`` and ``fmi2SetFMUstate`` (their
FMI 3.0 counterparts for an FMI 3.0 FMU, :mod:`fmi_versions`). A
refusal at either counts as refused; an accepted copy must then run the second half to the very
same outputs (an identical state), else it counts as ``accepted_different``. Prints one JSON
line: ``{"tried", "refused", "identical", "accepted_different", "examples"}``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from fmi_versions import slave_class
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException


class Run:
    """An fmpy slave of the FMU stepped through rows of its inputs."""

    def __init__(self, fmu: str, names: list[str], rows: np.ndarray) -> None:
        description = read_model_description(fmu)
        refs = {v.name: v.valueReference for v in description.modelVariables}
        self.inputs = [refs[n] for n in names]
        self.outputs = [
            v.valueReference
            for v in description.modelVariables
            if v.causality == "output" and v.type == "Real"
        ]
        self.dt = float(description.defaultExperiment.stepSize or 1e-3)
        self.rows = rows
        self.slave = slave_class(fmu)(
            guid=description.guid,
            unzipDirectory=extract(fmu),
            modelIdentifier=description.coSimulation.modelIdentifier,
            instanceName="flips",
        )
        self.slave.instantiate(loggingOn=False)
        self.slave.setupExperiment(startTime=0.0)
        self.slave.enterInitializationMode()
        self.slave.setReal(self.inputs, list(rows[0]))
        self.slave.exitInitializationMode()

    def steps(self, first: int, last: int) -> np.ndarray:
        """Step rows first..last-1 (row k from t = k dt); the outputs after each step."""
        out = []
        for k in range(first, last):
            self.slave.setReal(self.inputs, list(self.rows[k]))
            self.slave.doStep(k * self.dt, self.dt)
            out.append(self.slave.getReal(self.outputs))
        return np.array(out)


def restored(run: Run, state: bytes) -> bool:
    """Whether the FMU accepts the serialised state (deserialised and set)."""
    try:
        handle = run.slave.deSerializeFMUstate(state)
    except FMICallException:
        return False
    try:
        run.slave.setFMUstate(handle)
    except FMICallException:
        return False
    finally:
        run.slave.freeFMUstate(handle)
    return True


def sweep(
    fmu: Path,
    names: list[str],
    rows: np.ndarray,
    folder: Path,
    header: int,
    sample: int,
    env: dict[str, str] | None = None,
) -> dict[str, object]:
    """Run the sweep over ``fmu`` in a process of its own; its counts.

    Parameters
    ----------
    fmu : Path
        The FMU.
    names : list of str
        Its input variables, the columns of ``rows``.
    rows : ndarray, shape (n, len(names))
        Inputs: the state is saved after the first half, the second half is the reference.
    folder : Path
        Where the rows are written for the process.
    header, sample : int
        Bytes flipped bit by bit from the start; bits drawn from the rest (seed 42).
    env : dict, optional
        The process's environment (e.g. a sanitizer runtime preloaded); by default this one's.

    Returns
    -------
    dict
        ``tried``, ``refused``, ``identical``, ``accepted_different``, ``examples``.
    """
    rows_file = folder / "flip_rows.npy"
    np.save(rows_file, rows)
    command = [sys.executable, __file__, str(fmu), str(rows_file), str(header), str(sample), "42"]
    done = subprocess.run([*command, *names], capture_output=True, text=True, timeout=900, env=env)
    assert done.returncode == 0, (
        f"the sweep's process ended with exit code {done.returncode} (-11: a segfault):\n"
        f"{done.stderr[-3000:]}"
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str]) -> None:
    fmu, rows_file, header, sample, seed, *names = argv
    rows = np.load(rows_file)
    half = len(rows) // 2
    run = Run(fmu, names, rows)
    run.steps(0, half)
    good = bytes(run.slave.serializeFMUstate(run.slave.getFMUstate()))
    reference = run.steps(half, len(rows))
    n_bits = 8 * len(good)
    body = np.random.default_rng(int(seed)).choice(
        np.arange(8 * int(header), n_bits),
        size=min(int(sample), n_bits - 8 * int(header)),
        replace=False,
    )
    counts = {"tried": 0, "refused": 0, "identical": 0, "accepted_different": 0, "examples": []}
    for bit in [*range(8 * int(header)), *sorted(int(b) for b in body)]:
        damaged = bytearray(good)
        damaged[bit // 8] ^= 1 << (bit % 8)
        counts["tried"] += 1
        if not restored(run, bytes(damaged)):
            counts["refused"] += 1
            continue
        try:
            same = np.array_equal(run.steps(half, len(rows)), reference, equal_nan=True)
        except FMICallException:
            same = False
        if same:
            counts["identical"] += 1
        else:
            counts["accepted_different"] += 1
            if len(counts["examples"]) < 5:
                counts["examples"].append(bit)
        assert restored(run, good), "the undamaged state was refused"
    print(json.dumps(counts))


if __name__ == "__main__":
    main(sys.argv[1:])
