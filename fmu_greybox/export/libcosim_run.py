"""Running an SSP bench in libcosim, in a process of its own.

libcosim runs its FMUs in worker threads. An FMU error during the first ``execution.step()``
(the initialisation: for instance the grey-box refusing a recorded input at t = 0 that lies
outside its input domain) is thrown as a C++ ``cosim::error`` where nothing catches it:
``std::terminate`` ends the process ("terminate called after throwing an instance of
'cosim::error'", SIGABRT, exit 134), and no Python code can stop it. Later errors come back as
an ordinary failed step.

So :func:`run_libcosim` runs :func:`libcosim_columns` in a child Python process (``python -m
fmu_greybox.export.libcosim_run REQUEST``) and turns whatever ends it into a
:class:`~fmu_greybox.errors.BenchError`: a failed step with libcosim's message, an aborted
process with the message of the error that aborted it (libcosim's ``what()``, which carries the
FMU's own message: the input, its value, the time and the domain). This module imports only
numpy and libcosimpy, so the child starts in under a second.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from fmu_greybox.errors import BenchError

#: What libcosim's C++ runtime prints when an uncaught exception ends the process.
TERMINATED = "terminate called after throwing"
#: The line of that report holding the exception's message.
WHAT = "what():"
#: Exit status of a child that failed cleanly (its message is in the request's error file).
FAILED = 1


def libcosim_columns(
    ssp: str | Path,
    outputs: Mapping[str, Sequence[str]],
    start: float,
    step: float,
    n_steps: int,
) -> dict[str, np.ndarray]:
    """Co-simulate an SSP in libcosim, in this process, and collect outputs.

    Only for a bench known to initialise (or in a process that may die):
    :func:`run_libcosim` is the safe way.

    Parameters
    ----------
    ssp : str or Path
        The ``.ssp`` archive.
    outputs : mapping of str to sequence of str
        Component name -> output connectors to collect.
    start : float
        Start time [s] (the SSD's DefaultExperiment).
    step : float
        Communication step [s].
    n_steps : int
        Steps to run.

    Returns
    -------
    dict of str to ndarray
        ``<component>.<output>`` -> values at the end of each step (Booleans as 0/1).

    Raises
    ------
    BenchError
        libcosim cannot load the SSP, or a step failed (the FMU's message is logged).
    """
    from libcosimpy._internal import get_last_error_message
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    ssp = Path(ssp)
    log_output_level(CosimLogLevel.ERROR)
    try:
        execution = CosimExecution.from_ssp_file(str(ssp), step_size=round(step * 1e9))
    except AssertionError as exc:
        raise BenchError(f"libcosim could not load {ssp}: {get_last_error_message()}") from exc
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    reads = []  # (slave index, Real refs, Real names, Boolean refs, Boolean names)
    for name, outs in outputs.items():
        index = execution.slave_index_from_instance_name(name)
        described = {v.name.decode(): v for v in execution.slave_variables(index)}
        reals = [n for n in outs if described[n].type == CosimVariableType.REAL.value]
        bools = [n for n in outs if described[n].type == CosimVariableType.BOOLEAN.value]
        reads.append(
            (
                index,
                [described[n].reference for n in reals],
                [f"{name}.{n}" for n in reals],
                [described[n].reference for n in bools],
                [f"{name}.{n}" for n in bools],
            )
        )
    columns = {n: np.empty(n_steps) for *_, reals, _, bools in reads for n in (*reals, *bools)}
    for k in range(n_steps):
        if not execution.step():
            raise BenchError(
                f"{ssp.name} failed in libcosim at t = {start + k * step:g} s: "
                f"{get_last_error_message()} (the FMU's own message is logged above)"
            )
        for index, real_refs, real_names, bool_refs, bool_names in reads:
            if real_refs:
                values = observer.last_real_values(index, real_refs)
                for n, v in zip(real_names, values, strict=True):
                    columns[n][k] = v
            if bool_refs:
                values = observer.last_boolean_values(index, bool_refs)
                for n, v in zip(bool_names, values, strict=True):
                    columns[n][k] = float(v)
    return columns


def run_libcosim(
    ssp: str | Path,
    outputs: Mapping[str, Sequence[str]],
    start: float,
    step: float,
    n_steps: int,
    scratch: str | Path | None = None,
) -> dict[str, np.ndarray]:
    """:func:`libcosim_columns` in a child process: an abort inside libcosim ends the child only.

    The child's log (libcosim's and the FMUs' messages) is passed on to this process's standard
    error when it ends.

    Parameters
    ----------
    ssp, outputs, start, step, n_steps
        As for :func:`libcosim_columns`.
    scratch : str or Path, optional
        The folder in which the request and the child's answer are kept while it runs (removed
        after); default: the temporary folder.

    Returns
    -------
    dict of str to ndarray
        As for :func:`libcosim_columns`.

    Raises
    ------
    BenchError
        A step failed, or libcosim ended the process (the message is the error it ended on).
    """
    ssp = Path(ssp)
    with tempfile.TemporaryDirectory(prefix="fmu_greybox_libcosim_", dir=scratch) as private:
        folder = Path(private)
        request = {
            "ssp": str(ssp.resolve()),
            "outputs": {name: list(outs) for name, outs in outputs.items()},
            "start": start,
            "step": step,
            "n_steps": n_steps,
            "columns": str(folder / "columns.npz"),
            "error": str(folder / "error.txt"),
        }
        (folder / "request.json").write_text(json.dumps(request), encoding="utf-8")
        with open(folder / "log.txt", "w+b") as log:
            done = subprocess.run(
                [sys.executable, "-m", __name__, str(folder / "request.json")],
                stdin=subprocess.DEVNULL,
                stderr=log,
                check=False,
            )
            log.seek(0)
            messages = log.read().decode("utf-8", errors="replace")
        if done.returncode == 0:
            with np.load(request["columns"], allow_pickle=False) as stored:
                return {name: stored[name] for name in stored.files}
        if done.returncode == FAILED and Path(request["error"]).is_file():
            sys.stderr.write(messages)
            raise BenchError(Path(request["error"]).read_text(encoding="utf-8"))
    log, reason = _abort_reason(messages)
    sys.stderr.write(log)
    raise BenchError(
        f"{ssp.name} failed in libcosim: {reason} (the libcosim process ended on this error, "
        f"{_ending(done.returncode)}; the FMUs' own messages are logged above)"
    )


def _abort_reason(messages: str) -> tuple[str, str]:
    """(the log without the C++ runtime's report, the message the process ended on).

    That message is the uncaught exception's ``what()``, or else the log's last line.
    """
    log, _, report = messages.partition(TERMINATED)
    _, found, what = report.partition(WHAT)
    if found:
        return log, " ".join(what.split())
    lines = [line.strip() for line in messages.splitlines() if line.strip()]
    return messages, lines[-1] if lines else "no message"


def _ending(returncode: int) -> str:
    """How a child process ended, in words (``killed by SIGABRT``, ``exit 3``)."""
    if returncode < 0:
        try:
            return f"killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"killed by signal {-returncode}"
    return f"exit {returncode}"


def _child(request_path: str) -> int:
    """The child's work: read the request, run libcosim, store the columns or the error."""
    request = json.loads(Path(request_path).read_text(encoding="utf-8"))
    try:
        columns = libcosim_columns(
            request["ssp"],
            request["outputs"],
            request["start"],
            request["step"],
            request["n_steps"],
        )
    except BenchError as exc:
        Path(request["error"]).write_text(str(exc), encoding="utf-8")
        return FAILED
    np.savez(request["columns"], **columns)
    return 0


if __name__ == "__main__":
    status = _child(sys.argv[1])
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)  # no interpreter teardown: it would unload the FMUs' binaries under libcosim
