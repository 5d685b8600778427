"""Entry module of the Python FMUs that fmu-greybox writes (grey-box and recording playback).

The exporter copies this file into an FMU's ``resources/`` as ``<kind>_fmu.py`` and appends one
line binding the slave class, e.g. ``GreyBoxSlave = load_slave("fmu_greybox.export.slave",
"GreyBoxSlave")``. pythonfmu's binary imports that module in the simulation process and
instantiates the class.

The slave classes live in the installed ``fmu_greybox`` package, so the simulation process must
be able to import it (with numpy, scipy and fmpy). This module uses only the standard library and
pythonfmu (which every pythonfmu FMU carries in its resources), so when that import fails the FMU
still loads and refuses instantiation with a message saying what is missing and how to install
it, instead of crashing the simulator: ``fmi2Instantiate`` returns NULL and the message is
reported (see :func:`report`). Once instantiated, the slaves' FMI methods never raise either
(see :func:`guarded`).

Mind pythonfmu's loader (0.7): for every instantiation it executes this module's code a second
time, with the module's namespace as globals and fresh local names, so nothing here may rely on
module-level state other than imports; and it then releases one reference to the module's
namespace that it never took, which frees the namespace after a few instantiations and crashes
the simulator. :func:`hold_namespace`, called at the end of the module, takes that reference
each time.
"""

from __future__ import annotations

import ctypes
import functools
import importlib
import json
import logging
import sys
import threading
from pathlib import Path

from pythonfmu import Fmi2Slave

#: File in an FMU's resources describing what the FMU needs from the Python that runs it.
RUNTIME_FILE = "fmu_runtime.json"
#: Python logger of the FMUs' errors.
LOGGER = "fmu_greybox.fmu"
#: Threads whose Python thread state :func:`keep_thread_state` keeps.
_KEPT = threading.local()


class FmiLogger:
    """The master's FMI logger of one pythonfmu instance, reached at any logging level.

    pythonfmu (0.7) hands a slave the address of its C++ logger object (the ``logger`` keyword)
    but passes the slave's messages to the master only while the master has switched debug
    logging on. That object holds the instance name (a ``std::string`` at byte
    :attr:`NAME_AT`) and, at byte :attr:`CALLBACKS_AT`, the ``fmi2CallbackFunctions`` the master
    gave ``fmi2Instantiate``, whose first member is the master's logger: an error is sent
    through it directly, so that it reaches the master whatever the logging level, as the
    native runtime's errors do. The layout is trusted only if the name found there is the
    instance's; otherwise (another pythonfmu, a slave made in-process) :meth:`error` does
    nothing and the Python logger alone has the message.
    """

    NAME_AT = 16
    CALLBACKS_AT = 72
    ENVIRONMENT_AT = 32  # componentEnvironment within fmi2CallbackFunctions
    _PROTOTYPE = ctypes.CFUNCTYPE(
        None, ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_char_p
    )

    def __init__(self, address: object, instance_name: str) -> None:
        self._send = None
        self._name = instance_name.encode("utf-8")
        if not isinstance(address, int) or address <= 0:
            return
        pointer, size = (ctypes.c_size_t * 2).from_address(address + self.NAME_AT)
        if size != len(self._name) or ctypes.string_at(pointer, size) != self._name:
            return
        callbacks = ctypes.c_void_p.from_address(address + self.CALLBACKS_AT).value
        logger = ctypes.c_void_p.from_address(callbacks).value if callbacks else None
        if logger:
            self._send = self._PROTOTYPE(logger)
            self._environment = ctypes.c_void_p.from_address(callbacks + self.ENVIRONMENT_AT)

    def error(self, message: str) -> None:
        """Send an error message (status fmi2Error, category logStatusError)."""
        if self._send is not None:
            text = message.replace("%", "%%").encode("utf-8")  # the logger reads a format
            self._send(self._environment.value, self._name, 3, b"logStatusError", text)


def attach_logger(slave, kwargs: dict) -> None:
    """Give a slave its :class:`FmiLogger` (``slave.fmi_logger``) from pythonfmu's keywords."""
    slave.fmi_logger = FmiLogger(kwargs.get("logger"), slave.instance_name)


def report(slave, call: str, message: str) -> None:
    """Report why an FMI call of a Python FMU fails, to the master and in Python.

    The master's FMI logger gets it at any logging level (:class:`FmiLogger`); it also goes to
    the Python logger ``fmu_greybox.fmu``, which prints it on stderr unless the host configured
    logging.
    """
    text = f"{call} failed: {message}"
    logging.getLogger(LOGGER).error("FMU instance %r: %s", slave.instance_name, text)
    logger = getattr(slave, "fmi_logger", None)
    if logger is not None:
        logger.error(text)


def guarded(call: str, fallback=None):
    """Decorate an FMI method of a slave so that it never raises.

    When pythonfmu (0.7) sees a Python exception in an FMI call of an instance, it releases the
    instance's Python objects and returns fmi2Fatal; any later call on that instance (even the
    ``fmi2Terminate`` some masters send before ``fmi2FreeInstance``) then crashes the process. So
    the exception is reported (:func:`report`), recorded in the slave's ``failure``, and the
    method returns ``fallback`` (called with the method's arguments if callable). The slave's
    ``fmi2DoStep`` refuses to step while ``failure`` is set, returning fmi2Discard (pythonfmu
    0.7 has no way for a Python slave to answer fmi2Error).
    """

    def decorate(method):
        @functools.wraps(method)
        def run(self, *args):
            keep_thread_state()
            try:
                return method(self, *args)
            except Exception as exc:
                message = f"{type(exc).__name__}: {exc}"
                report(self, call, message)
                self.failure = self.failure or f"{call} failed: {message}"
                return fallback(*args) if callable(fallback) else fallback

        return run

    return decorate


def keep_thread_state() -> None:
    """Keep the calling thread's Python thread state from one FMI call to the next.

    pythonfmu (0.7) brackets every FMI call with ``PyGILState_Ensure``/``PyGILState_Release``.
    On a thread Python did not create (libcosim steps its slaves on its own worker threads),
    each pair makes a new Python thread state and deletes it again: in libcosim that was half
    the cost of a grey-box step (measured with M = 50: 44 µs per step, 22 µs with the state
    kept). One more ``PyGILState_Ensure``, never released, keeps the thread's state for the
    thread's life; it costs one thread state (about a kilobyte) per worker thread that ever
    calls the FMU, freed when the interpreter exits.
    """
    if not getattr(_KEPT, "held", False):
        ctypes.pythonapi.PyGILState_Ensure()
        _KEPT.held = True


def refuse_step(slave, current_time: float, reason: str | None = None) -> bool:
    """``fmi2DoStep`` refused: report why (``reason``, or the slave's first failure again)
    and return ``False``, which pythonfmu answers with fmi2Discard."""
    report(slave, "fmi2DoStep", reason or f"at t = {current_time:g} s: {slave.failure}")
    return False


def load_slave(module: str, name: str) -> type:
    """The slave class ``module.name``, or a stand-in that refuses to instantiate.

    Parameters
    ----------
    module, name : str
        Where the slave class lives, e.g. ``"fmu_greybox.export.slave"``, ``"GreyBoxSlave"``.

    Returns
    -------
    type
        A subclass of ``Fmi2Slave`` named ``name``.
    """
    try:
        return getattr(importlib.import_module(module), name)
    except Exception as exc:
        return refusing_slave(name, f"{type(exc).__name__}: {exc}")


def refusing_slave(name: str, reason: str) -> type:
    """A slave class whose instantiation fails with :func:`runtime_message`."""

    class Refusing(Fmi2Slave):
        def __init__(self, **kwargs) -> None:
            super().__init__(**kwargs)
            attach_logger(self, kwargs)
            message = runtime_message(kwargs.get("resources"), reason)
            report(self, "fmi2Instantiate", message)
            raise RuntimeError(message)

        def do_step(self, current_time: float, step_size: float) -> bool:
            return False

    Refusing.__name__ = Refusing.__qualname__ = name
    return Refusing


def read_requirements(resources: str | None) -> dict:
    """The FMU's ``fmu_runtime.json`` (empty if unreadable)."""
    if not resources:
        return {}
    try:
        return json.loads((Path(resources) / RUNTIME_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def runtime_message(resources: str | None, reason: str) -> str:
    """Why the FMU cannot run in this Python, and how to mend it."""
    needs = read_requirements(resources)
    wanted = needs.get("requires_python", [3, 11])
    package = needs.get("install", "fmu-greybox")
    python = sys.executable or "the Python embedded in the simulator"
    version = ".".join(map(str, sys.version_info[:3]))
    problems = [reason]
    if tuple(sys.version_info[:2]) < tuple(wanted):
        problems.insert(
            0, f"Python {version} is older than the {'.'.join(map(str, wanted))} this FMU needs"
        )
    return (
        f"this Python FMU cannot start in Python {version} ({python}): {'; '.join(problems)}. "
        f"It runs in the Python of the simulation process and needs Python >= "
        f"{'.'.join(map(str, wanted))} with {package} and its dependencies (numpy, scipy, fmpy) "
        f"importable there; install them with: {python} -m pip install '{package}' "
        "(see docs/bench.md, 'Runtime requirements')"
    )


def hold_namespace() -> None:
    """Take one more reference to this module's namespace (see the module docstring).

    The reference is taken at the C level and never given back. Held by a Python object (a list
    in the namespace, say), all of them would be released at once when the interpreter clears
    this module at exit, freeing the namespace while it is being cleared: a segmentation fault
    after the simulation had finished. Never giving them back leaks one namespace per FMU module,
    once per process.
    """
    ctypes.pythonapi.Py_IncRef(ctypes.py_object(globals()))


hold_namespace()
