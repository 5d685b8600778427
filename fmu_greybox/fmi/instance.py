"""A running FMI 2.0 co-simulation instance, stepped the way a bench steps it.

:class:`FmuInstance` wraps fmpy's ``FMU2Slave``. The per-step path (set inputs, ``fmi2DoStep``,
get outputs) calls the FMU's C functions directly with preallocated ``ctypes`` buffers, so a
step costs a few microseconds of Python. Every failing FMI call raises
:class:`~fmu_greybox.errors.FmuError` carrying the call, its status, the simulation time and the
last messages the FMU logged.
"""

from __future__ import annotations

import ctypes
import itertools
import os
import threading
import weakref
from collections import deque
from collections.abc import Mapping, Sequence

import numpy as np
from fmpy import calloc as fmpy_calloc
from fmpy import free as fmpy_free
from fmpy import platform as fmpy_platform
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2FMUstate,
    printLogMessage,
)

from fmu_greybox.errors import FmuArchiveError, FmuError
from fmu_greybox.fmi.archive import FmuArchive

_STATUS = ("fmi2OK", "fmi2Warning", "fmi2Discard", "fmi2Error", "fmi2Fatal", "fmi2Pending")
_WARNING = 1


def status_label(status: int) -> str:
    """Name of an ``fmi2Status`` code."""
    return _STATUS[status] if 0 <= status < len(_STATUS) else f"illegal status {status}"


class _LogBuffer:
    """Keeps the FMU's last log messages so an error can quote them."""

    def __init__(self, size: int = 20) -> None:
        self.messages: deque[str] = deque(maxlen=size)

    def __call__(self, env, instance, status, category, message) -> None:
        text = message.decode("utf-8", "replace") if message else ""
        self.messages.append(f"[{status_label(status)}] {text}")

    def last(self, n: int = 3) -> str:
        return " | ".join(list(self.messages)[-n:])


#: Log buffers of the live instances, by the ``componentEnvironment`` their FMU passes back.
_BUFFERS: weakref.WeakValueDictionary[int, _LogBuffer] = weakref.WeakValueDictionary()
_KEYS = itertools.count(1)


def _route(env, instance, status, category, message) -> None:
    """Send a formatted message to its instance's buffer; print other FMUs' as fmpy does."""
    buffer = _BUFFERS.get(env) if env else None
    if buffer is not None:
        buffer(env, instance, status, category, message)
    else:
        printLogMessage(env, instance, status, category, message)


#: The one Python logger behind fmpy's C proxy. The proxy keeps a single process-wide pointer to
#: the last logger it wrapped (fmpy's default callbacks use it too), so that logger must live as
#: long as the process and route each message by its ``componentEnvironment``.
_LOGGER = fmi2CallbackLoggerTYPE(_route)


def _callbacks(log: _LogBuffer) -> fmi2CallbackFunctions:
    """FMI callbacks routing the FMU's (variadic) logger through fmpy's C proxy to ``log``."""
    from fmpy.logging import addLoggerProxy

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = _LOGGER
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy_calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy_free)
    key = next(_KEYS)
    _BUFFERS[key] = log
    callbacks.componentEnvironment = key
    addLoggerProxy(ctypes.byref(callbacks))
    return callbacks


#: Held while fmpy loads a binary: it changes the process's working folder to the binary's and
#: back, so two threads loading at once (fits run side by side) could leave the process in a
#: temporary folder that is then removed.
_LOADING = threading.Lock()


def _load_slave(archive: FmuArchive, instance_name: str) -> FMU2Slave:
    """fmpy's slave of ``archive``, its shared library loaded.

    Raises
    ------
    FmuArchiveError
        If the binary cannot be loaded (not a shared library for this platform, a missing
        dependency) or lacks FMI 2.0 functions.
    """
    with _LOADING:  # the working folder is the process's: one load at a time
        cwd = os.getcwd()
        try:
            return FMU2Slave(
                guid=archive.guid,
                modelIdentifier=archive.model_identifier,
                unzipDirectory=str(archive.unzip_dir),
                instanceName=instance_name,
            )
        except Exception as exc:  # fmpy raises bare Exceptions; ctypes AttributeError for symbols
            raise FmuArchiveError(
                f"{archive.path}: its binary for {fmpy_platform} cannot be loaded ({exc}); "
                f"rebuild or re-export the FMU for {fmpy_platform} with the FMI 2.0 "
                "co-simulation functions"
            ) from exc
        finally:
            os.chdir(cwd)  # fmpy enters the binary's folder to load it, and stays there on failure


class FmuInstance:
    """One instance of a co-simulation FMU, initialised and ready to step.

    Parameters
    ----------
    archive : FmuArchive
        The extracted FMU (see :func:`fmu_greybox.fmi.archive.open_fmu`).
    inputs : sequence of str
        Real inputs set before every step, in the order :meth:`step` receives them.
    outputs : sequence of str
        Real variables read after every step, in the order :meth:`step` returns them.
    parameters : mapping of str to float, optional
        Real parameter values set before initialisation.
    start_values : mapping of str to float, optional
        Initial values of the inputs (applied before initialisation).
    instance_name : str
        FMI instance name.
    start_time : float
        Simulation start time [s].
    """

    def __init__(
        self,
        archive: FmuArchive,
        inputs: Sequence[str] = (),
        outputs: Sequence[str] = (),
        parameters: Mapping[str, float] | None = None,
        start_values: Mapping[str, float] | None = None,
        instance_name: str = "instance",
        start_time: float = 0.0,
    ) -> None:
        self.archive = archive
        self.time = float(start_time)
        self._log = _LogBuffer()
        self._slave = _load_slave(archive, instance_name)
        fn = self._slave._functions
        self._set_real = fn["fmi2SetReal"]
        self._get_real = fn["fmi2GetReal"]
        self._do_step = fn["fmi2DoStep"]
        self._callbacks = _callbacks(self._log)
        self._instantiate()
        try:
            self._initialise(start_time, {**(parameters or {}), **(start_values or {})})
            self.bind(inputs, outputs)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ set-up
    def _instantiate(self) -> None:
        try:
            self._slave.instantiate(callbacks=self._callbacks, loggingOn=False)
        except Exception as exc:
            raise FmuError("fmi2Instantiate", "NULL", self.time, self._log.last()) from exc
        self._component = self._slave.component

    def _initialise(self, start_time: float, values: Mapping[str, float]) -> None:
        self._guarded("fmi2SetupExperiment", self._slave.setupExperiment, startTime=start_time)
        if values:
            self.set_real(list(values), list(values.values()))
        self._guarded("fmi2EnterInitializationMode", self._slave.enterInitializationMode)
        self._guarded("fmi2ExitInitializationMode", self._slave.exitInitializationMode)
        self.time = float(start_time)

    def bind(self, inputs: Sequence[str], outputs: Sequence[str]) -> None:
        """Choose the inputs and outputs exchanged by :meth:`step`.

        Parameters
        ----------
        inputs, outputs : sequence of str
            Real variable names.
        """
        self.input_names = list(inputs)
        self.output_names = list(outputs)
        self._in_vr = self._references(self.input_names)
        self._out_vr = self._references(self.output_names)
        self._in_buf = (ctypes.c_double * len(self.input_names))()
        self._out_buf = (ctypes.c_double * len(self.output_names))()
        self._out_view = np.frombuffer(self._out_buf, dtype=np.float64)

    def _references(self, names: Sequence[str]) -> ctypes.Array:
        refs = [self.archive.variable(n).value_reference for n in names]
        return (ctypes.c_uint * len(refs))(*refs)

    # ------------------------------------------------------------------ stepping
    def _check(self, call: str, status: int) -> None:
        if status > _WARNING:
            raise FmuError(call, status_label(status), self.time, self._log.last())

    def _guarded(self, call: str, fn, *args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except FmuError:
            raise
        except Exception as exc:
            status = getattr(exc, "status", None)
            label = status_label(status) if isinstance(status, int) else type(exc).__name__
            raise FmuError(call, label, self.time, self._log.last() or str(exc)) from exc

    def step(self, u: Sequence[float] | np.ndarray, h: float) -> np.ndarray:
        """Set the bound inputs, advance one communication step, read the bound outputs.

        Parameters
        ----------
        u : array_like, shape (n_inputs,)
            Input values in the order given to :meth:`bind`.
        h : float
            Communication step [s].

        Returns
        -------
        ndarray, shape (n_outputs,)
            Output values at the end of the step. The array is reused by the next call: copy it
            to keep it.
        """
        n_in = len(self._in_buf)
        if n_in:
            self._in_buf[:] = u
            self._check(
                "fmi2SetReal", self._set_real(self._component, self._in_vr, n_in, self._in_buf)
            )
        self._check("fmi2DoStep", self._do_step(self._component, self.time, h, 1))
        self.time += h
        return self.read_outputs()

    def read_outputs(self) -> np.ndarray:
        """Read the bound outputs at the current time (shape (n_outputs,), reused buffer)."""
        n_out = len(self._out_buf)
        if n_out:
            self._check(
                "fmi2GetReal", self._get_real(self._component, self._out_vr, n_out, self._out_buf)
            )
        return self._out_view

    def set_real(self, names: Sequence[str], values: Sequence[float]) -> None:
        """Set Real variables by name (parameters, inputs)."""
        refs = self._references(names)
        buf = (ctypes.c_double * len(names))(*map(float, values))
        self._check("fmi2SetReal", self._set_real(self._component, refs, len(names), buf))

    def get_real(self, names: Sequence[str]) -> np.ndarray:
        """Read Real variables by name; returns shape (len(names),)."""
        refs = self._references(names)
        buf = (ctypes.c_double * len(names))()
        self._check("fmi2GetReal", self._get_real(self._component, refs, len(names), buf))
        return np.array(buf[:], dtype=np.float64)

    # ------------------------------------------------------------------ state
    def get_state(self) -> tuple[fmi2FMUstate, float]:
        """Capture the FMU state and the master's time; free it with :meth:`free_state`."""
        state = self._guarded("fmi2GetFMUstate", self._slave.getFMUstate)
        return state, self.time

    def set_state(self, snapshot: tuple[fmi2FMUstate, float]) -> None:
        """Restore a state captured by :meth:`get_state`."""
        state, time = snapshot
        self._guarded("fmi2SetFMUstate", self._slave.setFMUstate, state)
        self.time = time

    def free_state(self, snapshot: tuple[fmi2FMUstate, float]) -> None:
        """Release a captured state."""
        self._guarded("fmi2FreeFMUstate", self._slave.freeFMUstate, snapshot[0])

    def serialize_state(self) -> bytes:
        """The FMU state as bytes followed by nothing else (the time is kept by the caller)."""
        state, _ = self.get_state()
        try:
            return bytes(
                self._guarded("fmi2SerializeFMUstate", self._slave.serializeFMUstate, state)
            )
        finally:
            self.free_state((state, self.time))

    def deserialize_state(self, data: bytes, time: float) -> None:
        """Restore a state produced by :meth:`serialize_state` at master time ``time``."""
        state = self._guarded(
            "fmi2DeSerializeFMUstate", self._slave.deSerializeFMUstate, bytes(data)
        )
        try:
            self.set_state((state, time))
        finally:
            self.free_state((state, time))

    def reset(
        self,
        parameters: Mapping[str, float] | None = None,
        start_time: float = 0.0,
    ) -> None:
        """``fmi2Reset`` then initialise again, optionally with new parameter values."""
        self._guarded("fmi2Reset", self._slave.reset)
        self._initialise(start_time, dict(parameters or {}))

    def close(self) -> None:
        """Terminate and free the instance (idempotent, never raises)."""
        if self._component is None:
            return
        for fn in (self._slave.terminate, self._slave.freeInstance):
            try:
                fn()
            except Exception:
                pass
        self._component = None

    def __enter__(self) -> FmuInstance:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
