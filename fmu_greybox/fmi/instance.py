"""A running white-box instance, stepped the way a bench steps it.

:class:`FmuInstance` wraps fmpy's ``FMU2Slave`` (FMI 2.0), :class:`Fmu3Instance` its
``FMU3Slave`` (FMI 3.0); :class:`FmuMeInstance` and :class:`Fmu3MeInstance` wrap a
model-exchange FMU (``FMU2Model``, ``FMU3Model``) with an integrator
(:mod:`fmu_greybox.fmi.integrator`) behind the same interface; :func:`fmu_instance` picks the
one for an FMU's kind (:mod:`fmu_greybox.fmi.kinds`). The per-step path (set inputs,
``DoStep``, get outputs) calls the FMU's C functions directly with preallocated ``ctypes``
buffers, so a step costs a few microseconds of Python. Every failing FMI call raises
:class:`~fmu_greybox.errors.FmuError` carrying the call, its status, the simulation time and
the last messages the FMU logged.
"""

from __future__ import annotations

import ctypes
import itertools
import os
import threading
import weakref
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import ClassVar

import numpy as np
from fmpy import calloc as fmpy_calloc
from fmpy import free as fmpy_free
from fmpy.fmi2 import (
    FMU2Model,
    FMU2Slave,
    fmi2Boolean,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2EventInfo,
    printLogMessage,
)
from fmpy.fmi3 import FMU3Model, FMU3Slave, fmi3Boolean, fmi3Float64

from fmu_greybox.errors import FmuArchiveError, FmuError
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.fmi.integrator import (
    DEFAULT_INTEGRATOR,
    NATIVE_CALLS,
    CVodeStepper,
    Integrator,
    IntegratorError,
)
from fmu_greybox.fmi.kinds import FMI2_CS, FMI2_ME, FMI3_CS, FMI3_ME
from fmu_greybox.fmi.wine import (
    FMI2_WINE,
    RemoteSlot,
    keep_server_alive,
    remove_lock_folder,
    server_pid,
    stop_server,
)

_STATUS = ("OK", "Warning", "Discard", "Error", "Fatal", "Pending")
_WARNING = 1


def status_label(status: int, prefix: str = "fmi2") -> str:
    """Name of an ``fmi2Status`` code (of an ``fmi3Status`` code with ``prefix="fmi3"``)."""
    return prefix + _STATUS[status] if 0 <= status < len(_STATUS) else f"illegal status {status}"


class _LogBuffer:
    """Keeps the FMU's last log messages so an error can quote them."""

    def __init__(self, size: int = 20, prefix: str = "fmi2") -> None:
        self.messages: deque[str] = deque(maxlen=size)
        self.prefix = prefix

    def __call__(self, env, instance, status, category, message) -> None:
        text = message.decode("utf-8", "replace") if message else ""
        self.messages.append(f"[{status_label(status, self.prefix)}] {text}")

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


def _load_slave(archive: FmuArchive, instance_name: str, slave_class: type) -> object:
    """fmpy's slave of ``archive`` (an instance of ``slave_class``), its library loaded.

    Raises
    ------
    FmuArchiveError
        If the binary cannot be loaded (not a shared library for this platform, a missing
        dependency) or lacks functions of its FMI version.
    """
    kind = archive.kind
    with _LOADING:  # the working folder is the process's: one load at a time
        cwd = os.getcwd()
        try:
            return slave_class(
                guid=archive.guid,
                modelIdentifier=archive.model_identifier,
                unzipDirectory=str(archive.unzip_dir),
                instanceName=instance_name,
            )
        except Exception as exc:  # fmpy raises bare Exceptions; ctypes AttributeError for symbols
            raise FmuArchiveError(
                f"{archive.path}: its binary for {kind.binary_folder} cannot be loaded ({exc}); "
                f"rebuild or re-export the FMU for {kind.binary_folder} with the {kind.label} "
                "functions"
            ) from exc
        finally:
            os.chdir(cwd)  # fmpy enters the binary's folder to load it, and stays there on failure


class FmuInstance:
    """One instance of an FMI 2.0 co-simulation FMU, initialised and ready to step.

    Make one with :func:`fmu_instance`, which picks the class for the FMU's kind.

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
        self._log = _LogBuffer(prefix=self.PREFIX)
        self._slave = _load_slave(archive, instance_name, self.SLAVE)
        self._bind_calls(self._slave._functions)
        self._instantiate()
        try:
            self._initialise(start_time, {**(parameters or {}), **(start_values or {})})
            self.bind(inputs, outputs)
        except BaseException:
            self.close()
            raise

    #: fmpy's class of the slave.
    SLAVE: type = FMU2Slave
    #: Prefix of the FMI names of calls and statuses.
    PREFIX = "fmi2"
    #: The FMI function behind each operation, named in errors.
    CALLS: ClassVar[dict[str, str]] = {
        "instantiate": "fmi2Instantiate",
        "enter": "fmi2EnterInitializationMode",
        "exit": "fmi2ExitInitializationMode",
        "set": "fmi2SetReal",
        "get": "fmi2GetReal",
        "step": "fmi2DoStep",
        "get_state": "fmi2GetFMUstate",
        "set_state": "fmi2SetFMUstate",
        "free_state": "fmi2FreeFMUstate",
        "serialize": "fmi2SerializeFMUstate",
        "deserialize": "fmi2DeSerializeFMUstate",
        "reset": "fmi2Reset",
    }
    #: fmpy's slave method behind each FMU-state operation.
    STATE_METHODS: ClassVar[dict[str, str]] = {
        "get_state": "getFMUstate",
        "set_state": "setFMUstate",
        "free_state": "freeFMUstate",
        "serialize": "serializeFMUstate",
        "deserialize": "deSerializeFMUstate",
    }

    # ------------------------------------------------------------------ set-up
    def _bind_calls(self, functions: Mapping[str, object]) -> None:
        """Keep the C functions of the per-step path: those of :meth:`_bind_values` and
        ``_do_step(component, time, h, no_set_prior)``."""
        self._bind_values(functions)
        self._do_step = functions["fmi2DoStep"]

    def _bind_values(self, functions: Mapping[str, object]) -> None:
        """Keep ``_set_real(component, refs, n, values)`` and ``_get_real`` alike."""
        self._set_real = functions[self.CALLS["set"]]
        self._get_real = functions[self.CALLS["get"]]

    def _instantiate(self) -> None:
        self._callbacks = _callbacks(self._log)
        try:
            self._slave.instantiate(callbacks=self._callbacks, loggingOn=False)
        except Exception as exc:
            raise FmuError(self.CALLS["instantiate"], "NULL", self.time, self._log.last()) from exc
        self._component = self._slave.component

    def _setup(self, start_time: float) -> None:
        """What comes before the start values: FMI 2.0 sets up the experiment."""
        self._guarded("fmi2SetupExperiment", self._slave.setupExperiment, startTime=start_time)

    def _enter(self, start_time: float) -> None:
        """Enter initialisation mode (FMI 2.0 took the start time in :meth:`_setup`)."""
        self._guarded(self.CALLS["enter"], self._slave.enterInitializationMode)

    def _initialise(self, start_time: float, values: Mapping[str, float]) -> None:
        self._setup(start_time)
        if values:
            self.set_real(list(values), list(values.values()))
        self._enter(start_time)
        self._guarded(self.CALLS["exit"], self._slave.exitInitializationMode)
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
            raise FmuError(call, status_label(status, self.PREFIX), self.time, self._log.last())

    def _guarded(self, call: str, fn, *args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except FmuError:
            raise
        except Exception as exc:
            status = getattr(exc, "status", None)
            known = isinstance(status, int)
            label = status_label(status, self.PREFIX) if known else type(exc).__name__
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
                self.CALLS["set"],
                self._set_real(self._component, self._in_vr, n_in, self._in_buf),
            )
        self._check(self.CALLS["step"], self._do_step(self._component, self.time, h, 1))
        self.time += h
        return self.read_outputs()

    def read_outputs(self) -> np.ndarray:
        """Read the bound outputs at the current time (shape (n_outputs,), reused buffer)."""
        n_out = len(self._out_buf)
        if n_out:
            self._check(
                self.CALLS["get"],
                self._get_real(self._component, self._out_vr, n_out, self._out_buf),
            )
        return self._out_view

    def set_real(self, names: Sequence[str], values: Sequence[float]) -> None:
        """Set Real variables by name (parameters, inputs)."""
        refs = self._references(names)
        buf = (ctypes.c_double * len(names))(*map(float, values))
        self._check(self.CALLS["set"], self._set_real(self._component, refs, len(names), buf))

    def get_real(self, names: Sequence[str]) -> np.ndarray:
        """Read Real variables by name; returns shape (len(names),)."""
        refs = self._references(names)
        buf = (ctypes.c_double * len(names))()
        self._check(self.CALLS["get"], self._get_real(self._component, refs, len(names), buf))
        return np.array(buf[:], dtype=np.float64)

    # ------------------------------------------------------------------ state
    def _state_call(self, operation: str, *args: object) -> object:
        """Call fmpy's FMU-state method for ``operation`` (see :attr:`STATE_METHODS`)."""
        method = getattr(self._slave, self.STATE_METHODS[operation])
        return self._guarded(self.CALLS[operation], method, *args)

    def get_state(self) -> tuple[object, float]:
        """Capture the FMU state and the master's time; free it with :meth:`free_state`."""
        return self._state_call("get_state"), self.time

    def set_state(self, snapshot: tuple[object, float]) -> None:
        """Restore a state captured by :meth:`get_state`."""
        state, time = snapshot
        self._state_call("set_state", state)
        self.time = time

    def free_state(self, snapshot: tuple[object, float]) -> None:
        """Release a captured state."""
        self._state_call("free_state", snapshot[0])

    def serialize_state(self) -> bytes:
        """The FMU state as bytes followed by nothing else (the time is kept by the caller)."""
        state, _ = self.get_state()
        try:
            return bytes(self._state_call("serialize", state))
        finally:
            self.free_state((state, self.time))

    def deserialize_state(self, data: bytes, time: float) -> None:
        """Restore a state produced by :meth:`serialize_state` at master time ``time``."""
        state = self._state_call("deserialize", bytes(data))
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
        self._guarded(self.CALLS["reset"], self._slave.reset)
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


class Fmu3Instance(FmuInstance):
    """One instance of an FMI 3.0 co-simulation FMU: :class:`FmuInstance` with the FMI 3.0
    calls (``Float64`` for Real, the start time given on entering initialisation, a logger
    that is not variadic)."""

    SLAVE = FMU3Slave
    PREFIX = "fmi3"
    CALLS: ClassVar[dict[str, str]] = {
        "instantiate": "fmi3InstantiateCoSimulation",
        "enter": "fmi3EnterInitializationMode",
        "exit": "fmi3ExitInitializationMode",
        "set": "fmi3SetFloat64",
        "get": "fmi3GetFloat64",
        "step": "fmi3DoStep",
        "get_state": "fmi3GetFMUState",
        "set_state": "fmi3SetFMUState",
        "free_state": "fmi3FreeFMUState",
        "serialize": "fmi3SerializeFMUState",
        "deserialize": "fmi3DeserializeFMUState",
        "reset": "fmi3Reset",
    }
    STATE_METHODS: ClassVar[dict[str, str]] = {
        "get_state": "getFMUState",
        "set_state": "setFMUState",
        "free_state": "freeFMUState",
        "serialize": "serializeFMUState",
        "deserialize": "deserializeFMUState",
    }

    def _bind_calls(self, functions: Mapping[str, object]) -> None:
        """The FMI 3.0 functions behind the FMI 2.0 signatures of the per-step path (FMI 3.0
        adds the step's event, termination and early-return outputs, which this co-simulation
        master does not use)."""
        self._bind_values(functions)
        do_step = functions["fmi3DoStep"]
        flags = [fmi3Boolean() for _ in range(3)]
        last = fmi3Float64()
        outputs = (*(ctypes.byref(f) for f in flags), ctypes.byref(last))
        self._do_step = lambda c, t, h, no_prior: do_step(c, t, h, bool(no_prior), *outputs)

    def _bind_values(self, functions: Mapping[str, object]) -> None:
        """``fmi3SetFloat64`` / ``fmi3GetFloat64`` with the FMI 2.0 signatures (FMI 3.0 adds
        the number of values)."""
        set_float, get_float = functions[self.CALLS["set"]], functions[self.CALLS["get"]]
        self._set_real = lambda c, refs, n, values: set_float(c, refs, n, values, n)
        self._get_real = lambda c, refs, n, values: get_float(c, refs, n, values, n)

    def _instantiate(self) -> None:
        log = self._log

        def message(env, status, category, text) -> None:
            log(env, None, status, category, text)

        try:
            self._slave.instantiate(loggingOn=False, logMessage=message)
        except Exception as exc:
            raise FmuError(self.CALLS["instantiate"], "NULL", self.time, log.last()) from exc
        self._component = self._slave.component

    def _setup(self, start_time: float) -> None:
        """Nothing: FMI 3.0 takes the start time on entering initialisation mode."""

    def _enter(self, start_time: float) -> None:
        self._guarded(
            self.CALLS["enter"], self._slave.enterInitializationMode, startTime=start_time
        )


#: ``_discrete(component) -> (status, needed, terminate, values changed, next event time
#: defined)`` of a model-exchange instance.
DiscreteCall = Callable[[object], tuple[int, bool, bool, bool, bool]]


class FmuMeInstance(FmuInstance):
    """One instance of an FMI 2.0 model-exchange FMU, stepped by an integrator: the interface
    of :class:`FmuInstance`.

    :meth:`step` sets the inputs, then integrates the FMU's states over the step with
    ``integrator`` (:class:`~fmu_greybox.fmi.integrator.CVodeStepper`: CVode restarted from
    the FMU's state at every step, stopped exactly at its end), calling
    ``fmi2CompletedIntegratorStep`` after each internal step and handling the events it asks
    for (``fmi2NewDiscreteStates`` until no update is needed; CVode restarts from the states
    the event set). The FMU's time and states are the integrator's at the step's end, so the
    FMU state (:meth:`get_state`, :meth:`serialize_state`) holds everything a step starts
    from.

    Parameters
    ----------
    archive, inputs, outputs, parameters, start_values, instance_name, start_time
        As :class:`FmuInstance`.
    integrator : Integrator, optional
        Default :data:`~fmu_greybox.fmi.integrator.DEFAULT_INTEGRATOR`.
    """

    SLAVE = FMU2Model
    #: ctypes type of the flags ``fmi2CompletedIntegratorStep`` returns.
    BOOLEAN: ClassVar[type] = fmi2Boolean
    CALLS: ClassVar[dict[str, str]] = {
        **FmuInstance.CALLS,
        "instantiate": "fmi2Instantiate",
        "step": "CVode",
        "set_time": "fmi2SetTime",
        "set_states": "fmi2SetContinuousStates",
        "get_states": "fmi2GetContinuousStates",
        "derivatives": "fmi2GetDerivatives",
        "nominals": "fmi2GetNominalsOfContinuousStates",
        "completed": "fmi2CompletedIntegratorStep",
        "event_mode": "fmi2EnterEventMode",
        "discrete": "fmi2NewDiscreteStates",
        "continuous_mode": "fmi2EnterContinuousTimeMode",
    }

    def __init__(
        self,
        archive: FmuArchive,
        inputs: Sequence[str] = (),
        outputs: Sequence[str] = (),
        parameters: Mapping[str, float] | None = None,
        start_values: Mapping[str, float] | None = None,
        instance_name: str = "instance",
        start_time: float = 0.0,
        integrator: Integrator | None = None,
    ) -> None:
        self.integrator = integrator or DEFAULT_INTEGRATOR
        self.n_states = len(archive.model_description.derivatives)
        self._stepper: CVodeStepper | None = None
        self._component = None
        super().__init__(
            archive, inputs, outputs, parameters, start_values, instance_name, start_time
        )

    # ------------------------------------------------------------------ set-up
    def _bind_calls(self, functions: Mapping[str, object]) -> None:
        """The per-step C functions, as ``_set_real``/``_get_real`` of :class:`FmuInstance` and
        the model-exchange ones with FMI 2.0 signatures: ``_set_time(c, t)``,
        ``_set_states(c, x, n)``, ``_get_states``, ``_derivatives``, ``_nominals`` alike,
        ``_completed(c, no_prior, enter, terminate)``, ``_event_mode(c)``,
        ``_discrete(c) -> (status, needed, terminate, values changed)`` and
        ``_continuous_mode(c)``; each found under its FMI name in :attr:`CALLS` (one table
        per FMI version)."""

        def call(key: str):
            return functions[self.CALLS[key]]

        self._bind_values(functions)
        self._raw = {key: call(key) for key in NATIVE_CALLS[:8]}
        self._set_time = call("set_time")
        self._set_states = call("set_states")
        self._get_states = call("get_states")
        self._derivatives = call("derivatives")
        self._nominals = call("nominals")
        self._completed = call("completed")
        self._event_mode = call("event_mode")
        self._continuous_mode = call("continuous_mode")
        self._discrete = self._discrete_call(call("discrete"))
        self._flags = (self.BOOLEAN(), self.BOOLEAN())

    def _discrete_call(self, new_discrete) -> DiscreteCall:
        """``fmi2NewDiscreteStates`` as ``_discrete(c) -> (status, needed, terminate, values
        changed, next event time defined)``."""
        info = fmi2EventInfo()

        def discrete(c) -> tuple[int, bool, bool, bool, bool]:
            status = new_discrete(c, ctypes.byref(info))
            return (
                status,
                bool(info.newDiscreteStatesNeeded),
                bool(info.terminateSimulation),
                bool(info.valuesOfContinuousStatesChanged),
                bool(info.nextEventTimeDefined),
            )

        return discrete

    def _initialise(self, start_time: float, values: Mapping[str, float]) -> None:
        """Initialise as :class:`FmuInstance`, settle the initial event, enter continuous-time
        mode and make the integrator (once)."""
        super()._initialise(start_time, values)
        self._settle_event()
        self._check(self.CALLS["continuous_mode"], self._continuous_mode(self._component))
        if self._stepper is None:
            n = self.n_states
            self._x_buf = (ctypes.c_double * n)()
            self._check(self.CALLS["nominals"], self._nominals(self._component, self._x_buf, n))
            nominals = np.array(self._x_buf[:], dtype=np.float64)
            fmu = {"component": self._component, "fmi3": self.PREFIX == "fmi3"}
            fmu |= {name: self._raw[name] for name in NATIVE_CALLS[:8]}
            self._stepper = CVodeStepper(n, self._rhs, nominals, self.integrator, fmu)

    def _settle_event(self) -> bool:
        """In event mode: ``NewDiscreteStates`` until no update is needed; whether the
        continuous states changed."""
        changed = False
        for _ in range(1000):
            status, needed, terminate, values, timed = self._discrete(self._component)
            self._check(self.CALLS["discrete"], status)
            if terminate:
                raise FmuError(
                    self.CALLS["discrete"], "terminateSimulation", self.time, self._log.last()
                )
            if timed:
                raise self._time_event()
            changed = changed or values
            if not needed:
                return changed
        raise FmuError(
            self.CALLS["discrete"], "newDiscreteStatesNeeded after 1000 iterations", self.time
        )

    # ------------------------------------------------------------------ stepping
    def _rhs(self, t: float, x, dx) -> int:
        """CVode's right-hand side: the FMU's derivatives at time ``t`` and states ``x``."""
        c, n = self._component, self.n_states
        for call, status in (
            ("set_time", self._set_time(c, t)),
            ("set_states", self._set_states(c, x, n)),
            ("derivatives", self._derivatives(c, dx, n)),
        ):
            if status > _WARNING:
                self.time = t
                self._check(self.CALLS[call], status)  # raises; CVodeStepper re-raises it
        return 0

    def _after_step(self, t: float, x) -> np.ndarray | None:
        """After an accepted internal step: the FMU takes its time and states, then
        ``CompletedIntegratorStep``; an event it asks for is handled, returning the states
        it set."""
        c, n = self._component, self.n_states
        self._check(self.CALLS["set_time"], self._set_time(c, t))
        self._check(self.CALLS["set_states"], self._set_states(c, x, n))
        enter, terminate = self._flags
        self._check(
            self.CALLS["completed"],
            self._completed(c, 1, ctypes.byref(enter), ctypes.byref(terminate)),
        )
        if terminate.value:
            raise FmuError(self.CALLS["completed"], "terminateSimulation", t, self._log.last())
        if not enter.value:
            return None
        self._check(self.CALLS["event_mode"], self._event_mode(c))
        changed = self._settle_event()
        self._check(self.CALLS["continuous_mode"], self._continuous_mode(c))
        if not changed:
            return None
        self._check(self.CALLS["get_states"], self._get_states(c, self._x_buf, n))
        return np.array(self._x_buf[:], dtype=np.float64)

    def step(self, u: Sequence[float] | np.ndarray, h: float) -> np.ndarray:
        """Set the bound inputs, integrate one communication step, read the bound outputs
        (as :meth:`FmuInstance.step`).

        Raises
        ------
        FmuError
            An FMI call failed (its name and status), or the integrator did (call
            ``"CVode"``, with what CVode said).
        """
        n_in = len(self._in_buf)
        if n_in:
            self._in_buf[:] = u
            self._check(
                self.CALLS["set"],
                self._set_real(self._component, self._in_vr, n_in, self._in_buf),
            )
        if not (h > 0.0 and np.isfinite(h)):
            raise FmuError(
                self.CALLS["step"],
                "refused",
                self.time,
                f"communicationStepSize = {h:g} s must be positive",
            )
        stepper, c, n = self._stepper, self._component, self.n_states
        self._check(self.CALLS["get_states"], self._get_states(c, self._x_buf, n))
        stepper.x[:] = self._x_buf
        start, stop = self.time, self.time + h
        try:
            stepper.advance(start, stop, self._after_step)
        except IntegratorError as exc:
            raise self._integrator_error(exc) from exc
        self.time = stop
        return self.read_outputs()

    def _time_event(self) -> FmuError:
        return FmuError(
            self.CALLS["discrete"],
            "nextEventTimeDefined",
            self.time,
            "the FMU asks for a time event, which fmu-greybox's integrator does not schedule "
            "yet; export the model as co-simulation",
        )

    def _integrator_error(self, exc: IntegratorError) -> FmuError:
        """The :class:`FmuError` of a failed step: CVode's flag and words, or the FMU call
        that failed in the C loop with its status and the FMU's log."""
        if exc.call == "CVode":
            detail = f"{exc.detail} ({self.integrator.summary()})"
            return FmuError(self.CALLS["step"], f"flag {exc.flag}", self.time, detail)
        if exc.call == "time_event":
            return self._time_event()
        if exc.call == "terminate":
            call = self.CALLS[NATIVE_CALLS[exc.flag]]
            return FmuError(call, "terminateSimulation", self.time, self._log.last())
        status = status_label(exc.flag, self.PREFIX)
        return FmuError(self.CALLS[exc.call], status, self.time, self._log.last())

    def close(self) -> None:
        """Terminate and free the instance and the integrator (idempotent, never raises)."""
        if self._stepper is not None:
            self._stepper.close()
            self._stepper = None
        if self._component is not None:
            super().close()


class Fmu3MeInstance(FmuMeInstance):
    """One instance of an FMI 3.0 model-exchange FMU: :class:`FmuMeInstance` with the FMI 3.0
    calls (as :class:`Fmu3Instance` is :class:`FmuInstance` with them)."""

    SLAVE = FMU3Model
    PREFIX = "fmi3"
    CALLS: ClassVar[dict[str, str]] = {
        **Fmu3Instance.CALLS,
        "instantiate": "fmi3InstantiateModelExchange",
        "step": "CVode",
        "set_time": "fmi3SetTime",
        "set_states": "fmi3SetContinuousStates",
        "get_states": "fmi3GetContinuousStates",
        "derivatives": "fmi3GetContinuousStateDerivatives",
        "nominals": "fmi3GetNominalsOfContinuousStates",
        "completed": "fmi3CompletedIntegratorStep",
        "event_mode": "fmi3EnterEventMode",
        "discrete": "fmi3UpdateDiscreteStates",
        "continuous_mode": "fmi3EnterContinuousTimeMode",
    }
    STATE_METHODS = Fmu3Instance.STATE_METHODS
    _instantiate = Fmu3Instance._instantiate
    _setup = Fmu3Instance._setup
    _enter = Fmu3Instance._enter

    _bind_values = Fmu3Instance._bind_values
    BOOLEAN = fmi3Boolean

    def _discrete_call(self, update) -> DiscreteCall:
        """``fmi3UpdateDiscreteStates`` as the ``_discrete`` of :class:`FmuMeInstance`."""
        flags = [fmi3Boolean() for _ in range(5)]
        next_time = fmi3Float64()
        pointers = (*(ctypes.byref(f) for f in flags), ctypes.byref(next_time))

        def discrete(c) -> tuple[int, bool, bool, bool, bool]:
            status = update(c, *pointers)
            needed, terminate, _, values, timed = (bool(f.value) for f in flags)
            return status, needed, terminate, values, timed

        return discrete


class WineInstance(FmuInstance):
    """An instance of an FMI 2.0 co-simulation FMU whose win64 binary runs through fmpy's
    remoting over Wine (:mod:`fmu_greybox.fmi.wine`): :class:`FmuInstance`, holding the one
    place the remoting has for a running instance (:class:`~fmu_greybox.fmi.wine.RemoteSlot`)
    from its creation to :meth:`close`.

    Raises
    ------
    FmuArchiveError
        If another such instance runs in this process.
    """

    def __init__(self, archive: FmuArchive, *args: object, **kwargs: object) -> None:
        self._slot = RemoteSlot(archive.path)
        self._lock_folder: Path | None = None
        self._server: int | None = None
        self._component = None
        try:
            super().__init__(archive, *args, **kwargs)
        except BaseException:
            self.close()
            raise

    def _instantiate(self) -> None:
        """Instantiate, keeping the Wine server alive (:func:`~fmu_greybox.fmi.wine.
        keep_server_alive`) when the client names its lock file in the log, and noting the
        server's process when the client names it.

        ``fmi2Instantiate`` is called holding the GIL: the client forks the server's process
        and logs from the child, whose logger (Python) would wait forever for a GIL another
        thread held at the fork.
        """
        self._log = _WineLog(self._log, self)
        raw = self._slave.dll.fmi2Instantiate
        address = ctypes.cast(raw, ctypes.c_void_p).value
        self._slave.fmi2Instantiate = ctypes.PYFUNCTYPE(raw.restype, *raw.argtypes)(address)
        super()._instantiate()

    def heard(self, message: str) -> None:
        """Act on a message of the remoting client (see :meth:`_instantiate`)."""
        folder = keep_server_alive(message)
        self._lock_folder = folder or self._lock_folder
        pid = server_pid(message)
        self._server = pid if pid is not None else self._server

    def close(self) -> None:
        """Terminate the instance, stop its Wine server (:func:`~fmu_greybox.fmi.wine.
        stop_server`, in place of the client's ``fmi2FreeInstance``, so the client library
        stays loaded: its RPC threads outlive the instance) and free its place (idempotent,
        never raises)."""
        if self._component is not None:
            try:
                self._slave.terminate()
            except Exception:
                pass
            self._component = None
        stop_server(self._server)
        self._server = None
        remove_lock_folder(self._lock_folder)
        self._lock_folder = None
        self._slot.release()


class _WineLog(_LogBuffer):
    """The log of a :class:`WineInstance`: keeps its messages as :class:`_LogBuffer` does and
    hands each to :meth:`WineInstance.heard`."""

    def __init__(self, log: _LogBuffer, instance: WineInstance) -> None:
        super().__init__(log.messages.maxlen, log.prefix)
        self.instance = instance

    def __call__(self, env, instance, status, category, message) -> None:
        super().__call__(env, instance, status, category, message)
        self.instance.heard(message.decode("utf-8", "replace") if message else "")


#: The instance class of each accepted kind.
INSTANCE_CLASSES: dict = {
    FMI2_CS: FmuInstance,
    FMI3_CS: Fmu3Instance,
    FMI2_ME: FmuMeInstance,
    FMI3_ME: Fmu3MeInstance,
    FMI2_WINE: WineInstance,
}


def fmu_instance(
    archive: FmuArchive, *args: object, integrator: Integrator | None = None, **kwargs: object
) -> FmuInstance:
    """An instance of ``archive`` of the class for its kind; arguments as
    :class:`FmuInstance`, and the ``integrator`` of a model-exchange FMU (default
    :data:`~fmu_greybox.fmi.integrator.DEFAULT_INTEGRATOR`; a co-simulation FMU has its own).

    Raises
    ------
    FmuArchiveError
        For a kind no instance class steps (:func:`~fmu_greybox.fmi.archive.open_fmu` refuses
        those before).
    """
    try:
        instance_class = INSTANCE_CLASSES[archive.kind]
    except KeyError:
        raise FmuArchiveError(
            f"{archive.path}: {archive.kind.label} FMUs cannot be stepped here"
        ) from None
    if issubclass(instance_class, FmuMeInstance):
        kwargs["integrator"] = integrator
    return instance_class(archive, *args, **kwargs)
