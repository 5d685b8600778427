"""Open-loop runs of the white-box with named terms in C, without Python between the steps.

:func:`run_native` gives the numbers :func:`~fmu_greybox.model.simulate.run_open_loop` gives
over a :class:`~fmu_greybox.model.whitebox.NamedModel`, call for call and bit for bit: the
white-box and its terms are laid out as the native grey-box FMU lays them out (the same
:func:`~fmu_greybox.model.whitebox.part_layouts` and data file,
:mod:`fmu_greybox.export.native`) and stepped by the same C code (``native/whitebox.c``,
``native/terms.c``). What the C loop saves is the Python of every step: the diagnosis runs
hundreds of such simulations, and a step of the reference actuator costs about half as much
without it (``benchmarks/bench_diagnosis.py``).

The runner, ``native/simulate.c``, is compiled on first use with the C compiler the install
needs (as the built-in FMUs are) and cached under the built-in FMUs' cache folder, keyed by a
hash of its sources. Where it cannot be built, :func:`native_runner` says why and the caller
steps the model in Python.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import hashlib
import multiprocessing.util
import os
import struct
import subprocess
import tempfile
import threading
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fmu_greybox.errors import FmuBuildError, FmuError
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.fmi.build import fmi2_headers
from fmu_greybox.fmi.builtin import cache_dir
from fmu_greybox.fmi.compiler import (
    DISABLE_VARIABLE,
    NATIVE_DIR,
    CBuild,
    compile_cached,
    core_flags,
    load_cached_library,
)
from fmu_greybox.fmi.instance import status_label
from fmu_greybox.fmi.kinds import FmuKind, one_instance_per_process, require_native
from fmu_greybox.fmi.platforms import WIN64
from fmu_greybox.fmi.wine import FMI2_WINE, wine_program
from fmu_greybox.model.native_data import data_file_bytes
from fmu_greybox.model.native_terms import NATIVE_KINDS, kind_defines
from fmu_greybox.model.native_whitebox import whitebox_sections
from fmu_greybox.model.terms import Term
from fmu_greybox.model.whitebox import part_layouts

#: The runner's sources (``native/``), in compile order, and the headers they include.
SOURCES = ("simulate.c", "whitebox.c", "terms.c", "greybox_data.c", "sha256.c")
HEADERS = ("whitebox.h", "dynlib.h", "terms.h", "greybox_data.h", "sha256.h")
#: The main of the runner as a program (the win64 one under Wine).
PROGRAM_SOURCE = "simulate_main.c"
#: Bytes kept for the runner's error message.
MESSAGE_SIZE = 2048
#: Characters of Wine's standard error quoted when the win64 runner ends during a run.
STDERR_KEPT = 600


def _digest() -> str:
    digest = hashlib.sha256(" ".join(core_flags()).encode() + kind_defines().encode())
    for name in (*SOURCES, *HEADERS, PROGRAM_SOURCE):
        digest.update(name.encode() + (NATIVE_DIR / name).read_bytes())
    return digest.hexdigest()[:16]


@functools.lru_cache(maxsize=1)
def native_runner() -> ctypes.CDLL | None:
    """The compiled runner (built on first use), or ``None`` where
    :data:`~fmu_greybox.fmi.compiler.DISABLE_VARIABLE` is ``0`` or it cannot be built (then with
    a warning that says why, once per process; both by
    :func:`~fmu_greybox.fmi.compiler.load_cached_library`)."""
    build = CBuild(
        what="the native simulation runner",
        sources=tuple(NATIVE_DIR / s for s in SOURCES),
        flags=core_flags(),
        include_dirs=(NATIVE_DIR, fmi2_headers()),
        libraries=("m", "dl"),
    )
    library = cache_dir().parent / "native-run" / _digest() / "libfgbsimulate.so"
    runner = load_cached_library(
        build,
        library,
        "simulations step in Python (slower): the native runner is unavailable",
        _config_header(),
    )
    if runner is None:
        return None
    runner.fgb_simulate.restype = ctypes.c_int
    runner.fgb_simulate.argtypes = [
        ctypes.c_char_p,
        ctypes.c_char_p,
        ctypes.c_char_p,
        ctypes.c_double,
        ctypes.c_double,
        ctypes.c_void_p,
        ctypes.c_ssize_t,
        ctypes.c_void_p,
        ctypes.c_char_p,
        ctypes.c_size_t,
        ctypes.c_char_p,
        ctypes.c_size_t,
        ctypes.POINTER(ctypes.c_int),
        ctypes.POINTER(ctypes.c_double),
        ctypes.c_char_p,
        ctypes.c_size_t,
    ]
    return runner


def runs_natively(terms: Sequence[Term], kind: FmuKind) -> bool:
    """Whether :func:`run_native` can run these terms (every kind has a C implementation) on a
    white-box of ``kind``, and its runner is built: the shared library for a white-box the C
    paths load (:attr:`~fmu_greybox.fmi.kinds.FmuKind.native`), the win64 program under Wine
    for one with Windows binaries only (:data:`~fmu_greybox.fmi.wine.FMI2_WINE`)."""
    if not all(type(t).__name__ in NATIVE_KINDS for t in terms):
        return False
    if kind == FMI2_WINE:
        return wine_runner_program() is not None
    return kind.native and native_runner() is not None


def runs_side_by_side(terms: Sequence[Term], archive: FmuArchive) -> bool:
    """Whether runs of the white-box with ``terms`` may go side by side in threads of this
    process: each runs in C here (:func:`runs_natively`; not under Wine, where each thread
    starts a runner of its own), and the FMU does not say it can be instantiated only once
    per process."""
    if archive.kind == FMI2_WINE or not runs_natively(terms, archive.kind):
        return False
    return not one_instance_per_process(archive.model_description, archive.kind)


def _config_header() -> dict[str, str]:
    """The generated header both runners are compiled with: the kind table of the terms."""
    return {
        "greybox_config.h": (
            "/* Generated by fmu-greybox: the kind table of the term kinds (native_terms.py). */\n"
            f"#ifndef GREYBOX_CONFIG_H\n#define GREYBOX_CONFIG_H\n{kind_defines()}#endif\n"
        )
    }


@functools.lru_cache(maxsize=1)
def wine_runner_program() -> Path | None:
    """The runner as a win64 program (``native/simulate_main.c`` around ``simulate.c``),
    cross-compiled with mingw-w64 on first use and cached beside the Linux runner; ``None``,
    with a warning that says why, where it cannot be built (the white-box then steps through
    fmpy's remoting, one remote call per FMI function)."""
    if os.environ.get(DISABLE_VARIABLE) == "0":
        return None
    build = CBuild(
        what="the native simulation runner for win64",
        sources=tuple(NATIVE_DIR / s for s in (PROGRAM_SOURCE, *SOURCES)),
        flags=core_flags(),
        include_dirs=(NATIVE_DIR, fmi2_headers()),
        libraries=("m",),
        shared=False,
    )
    program = cache_dir().parent / "native-run" / _digest() / "fgbsimulate.exe"
    try:
        if not program.is_file():
            compile_cached(build, program, _config_header(), target=WIN64)
    except FmuBuildError as exc:
        warnings.warn(
            f"a white-box with Windows binaries only steps through fmpy's remoting, one call at "
            f"a time (slow): the win64 simulation runner is unavailable: {exc}",
            stacklevel=2,
        )
        return None
    return program


@dataclass(frozen=True)
class RunAnswer:
    """What one ``fgb_simulate`` call gave: its status, the outputs when it is 0, else its
    message and, when the white-box refused a call, that call, its status, time and log."""

    status: int
    y: np.ndarray
    message: str
    failure: str
    fmi_status: int
    at: float
    log: str


class WineRunner:
    """The win64 runner program under Wine, serving one thread's runs one job at a time over
    its standard input and output (``native/simulate_main.c`` gives the protocol). One per
    thread of a process: a diagnosis's forked workers each start their own, and so do the
    threads of a Dask worker, whose jobs would otherwise cross on one pipe."""

    def __init__(self, program: Path) -> None:
        self.program = program
        self.stderr = tempfile.TemporaryFile()  # Wine's own messages, quoted if it ends
        self.process = subprocess.Popen(
            [wine_program(), str(program)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.stderr,
        )
        # Closed at the exit of the process that started it, a diagnosis worker included: a
        # worker ends through multiprocessing, which runs these finalizers, not atexit's.
        self.finalizer = multiprocessing.util.Finalize(self, self.close, exitpriority=0)

    @classmethod
    def of_this_thread(cls, program: Path) -> WineRunner:
        """The runner of the calling thread, started on first use (or again if it died)."""
        key = (os.getpid(), threading.get_ident())
        runner = _RUNNERS.get(key)
        if runner is None or runner.process.poll() is not None:
            if runner is not None:
                runner.close()
            runner = _RUNNERS[key] = cls(program)
        return runner

    @classmethod
    def close_all(cls) -> None:
        """Stop this process's runners (each one's input closed, then waited for)."""
        for key in [k for k in _RUNNERS if k[0] == os.getpid()]:
            _RUNNERS.pop(key).close()

    def close(self) -> None:
        """Close the program's input and wait for it to end (killed after 10 s); again, or
        after it died, does nothing more."""
        self.finalizer.cancel()
        if self.process.stdin is not None:
            with contextlib.suppress(OSError):  # a job left unsent by a dead program
                self.process.stdin.close()
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        if self.process.stdout is not None:
            self.process.stdout.close()
        self.stderr.close()

    def call(
        self,
        data: Path,
        sha256: str,
        folder: str,
        dt: float,
        start: float,
        u: np.ndarray,
        n_outputs: int,
    ) -> RunAnswer:
        """One run, as ``fgb_simulate`` with the paths as Wine sees them (drive Z:)."""
        texts = [windows_path(data).encode(), sha256.encode(), windows_path(Path(folder)).encode()]
        header = struct.pack("<4s6q2d", b"FGB1", *map(len, texts), *u.shape, n_outputs, dt, start)
        try:
            assert self.process.stdin is not None and self.process.stdout is not None
            self.process.stdin.write(header + b"".join(texts) + u.astype("<f8").tobytes())
            self.process.stdin.flush()
            status, fmi_status, at, *lengths = struct.unpack("<2qd3q", self._read(48))
            message, failure, log = (self._read(n).decode(errors="replace") for n in lengths)
            y = (
                np.frombuffer(self._read(8 * u.shape[0] * n_outputs), "<f8")
                if status == 0
                else None
            )
        except (OSError, EOFError) as exc:
            raise FmuError("fgb_simulate", "an error", detail=self._ended(exc)) from exc
        except BaseException:  # interrupted mid-job: the next job would read this one's answer
            self.process.kill()
            self.process.wait()  # ended before the next run asks whether it lives (poll)
            raise
        shape = (u.shape[0], n_outputs)
        y = np.empty(shape) if y is None else y.reshape(shape).copy()
        return RunAnswer(int(status), y, message, failure, int(fmi_status), at, log)

    def _ended(self, exc: Exception) -> str:
        """Why a run got no answer: the program's exit status and Wine's last words."""
        try:
            code = self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            code = self.process.wait()
        self.stderr.seek(0)
        said = self.stderr.read().decode(errors="replace").strip()[-STDERR_KEPT:]
        return (
            f"the win64 simulation runner under Wine ({self.program}) ended with exit status "
            f"{code} during a run ({exc}){f'; Wine said: {said}' if said else ''}. Where Wine "
            f"does not say why, the white-box's DLL may have crashed: set {DISABLE_VARIABLE}=0 "
            "to step the white-box through fmpy's remoting, which names the FMI call that fails"
        )

    def _read(self, n: int) -> bytes:
        assert self.process.stdout is not None
        chunk = self.process.stdout.read(n)
        if len(chunk) != n:
            raise EOFError(f"{len(chunk)} of {n} bytes")
        return chunk


#: The win64 runner of each thread that started one, by process and thread id.
_RUNNERS: dict[tuple[int, int], WineRunner] = {}


def _forget_parent_runners() -> None:
    """In a forked child: close its copies of the parent's runner pipes (flushed after every
    job, so nothing is written), so that the parent's runner sees the end of its input when
    the parent closes it, whatever the child is still doing."""
    for runner in _RUNNERS.values():
        runner.finalizer.cancel()
        for stream in (runner.process.stdin, runner.process.stdout, runner.stderr):
            if stream is not None:
                stream.close()
    _RUNNERS.clear()


os.register_at_fork(after_in_child=_forget_parent_runners)


def windows_path(path: Path) -> str:
    """A Linux path as a Windows program under Wine opens it (the root is drive Z:)."""
    return "Z:" + str(Path(path).resolve()).replace("/", "\\")


def run_native(
    archive: FmuArchive,
    inputs: Sequence[str],
    u: np.ndarray,
    dt: float,
    outputs: Sequence[str],
    terms: Sequence[Term],
    stages: Sequence[int],
    parameters: Mapping[str, float] | None,
    start_time: float,
    substeps: int,
) -> np.ndarray:
    """Run the white-box with ``terms`` over the input rows in C: in this process, or, for a
    white-box with Windows binaries only, in this thread's win64 runner under Wine.

    Arguments as :class:`~fmu_greybox.model.whitebox.NamedModel` (the start values are the
    first row of ``u``) and :func:`~fmu_greybox.model.simulate.run_open_loop`.

    Returns
    -------
    ndarray, shape (n, len(outputs))
        Row 0 the initial outputs, row ``k + 1`` those after applying ``u[k]``.

    Raises
    ------
    FmuError
        The white-box refused a call (the call, its status, the time and the white-box's last
        messages, as the Python loop raises it), its data could not be loaded, or the runner
        is not built (:func:`runs_natively` says so beforehand) or ended.
    FmuArchiveError
        The white-box is of a kind the runner does not load (:func:`runs_natively` says so
        beforehand).
    """
    if archive.kind != FMI2_WINE:
        require_native(
            archive.kind,
            archive.path,
            "the native simulation runner",
            "step it in Python (simulate_with_terms does so by itself for such a white-box)",
        )
    layouts = part_layouts(outputs, terms, stages, parameters, substeps)
    data = data_file_bytes(whitebox_sections(archive, inputs, layouts, dt, len(outputs)))
    rows = np.ascontiguousarray(u, dtype=np.float64)
    with tempfile.TemporaryDirectory(prefix="fmu_greybox_run_") as tmp:
        (Path(tmp) / "whitebox").symlink_to(archive.unzip_dir, target_is_directory=True)
        path = Path(tmp) / "whitebox.dat"
        path.write_bytes(data)
        sha256 = hashlib.sha256(data).hexdigest()
        if archive.kind == FMI2_WINE:
            program = wine_runner_program()
            if program is None:
                raise FmuError("fgb_simulate", "nothing", detail="the win64 runner is not built")
            runner = WineRunner.of_this_thread(program)
            answer = runner.call(path, sha256, tmp, dt, start_time, rows, len(outputs))
        else:
            answer = _call_here(path, sha256, tmp, dt, start_time, rows, len(outputs))
    if answer.status == 0:
        return answer.y
    if answer.failure:  # the white-box refused a call: the error the Python loop raises
        raise FmuError(answer.failure, status_label(answer.fmi_status), answer.at, answer.log)
    detail = f"{archive.path.name}: {answer.message}"
    raise FmuError("fgb_simulate", "an error", detail=f"{detail} {answer.log}".strip())


def _call_here(
    data: Path, sha256: str, folder: str, dt: float, start: float, u: np.ndarray, n_outputs: int
) -> RunAnswer:
    """One ``fgb_simulate`` call in this process's shared library."""
    runner = native_runner()
    if runner is None:
        raise FmuError("fgb_simulate", "nothing", detail="the native runner is not built")
    y = np.empty((u.shape[0], n_outputs))
    message, log = (ctypes.create_string_buffer(MESSAGE_SIZE) for _ in range(2))
    failure = ctypes.create_string_buffer(64)
    fmi_status, at = ctypes.c_int(0), ctypes.c_double(0.0)
    status = runner.fgb_simulate(
        str(data).encode(),
        sha256.encode(),
        folder.encode(),
        dt,
        start,
        u.ctypes.data,
        u.shape[0],
        y.ctypes.data,
        message,
        MESSAGE_SIZE,
        failure,
        len(failure),
        ctypes.byref(fmi_status),
        ctypes.byref(at),
        log,
        MESSAGE_SIZE,
    )
    return RunAnswer(
        status,
        y,
        message.value.decode(errors="replace"),
        failure.value.decode(),
        fmi_status.value,
        at.value,
        log.value.decode(errors="replace"),
    )
