"""The integrator that steps a model-exchange white-box at the project's step.

A model-exchange FMU has no solver of its own: it gives the derivatives of its continuous
states, and the master integrates them. :class:`Integrator` says how (and is what the model
folder and the exported FMU record); :class:`CVodeStepper` does it with SUNDIALS' CVode as fmpy
ships it (``fmpy.sundials``): variable-order, variable-step BDF with Newton iterations on a
dense finite-difference Jacobian, the method for stiff systems such as hydraulics, where the
pressure dynamics are orders of magnitude faster than the ram's.

Each communication step is an initial-value problem of its own: from the FMU's state at the
step's start, with the inputs held over the step (as a co-simulation FMU holds them), CVode is
restarted (order 1, its first step estimated afresh) and stopped exactly at the step's end
(``CVodeSetStopTime``, so that no internal step runs past it with the old inputs). A step is
then a function of the FMU's state and the inputs alone: an FMU state restored, or a
simulation restarted, continues exactly as before, and the inputs' jumps at the communication
points never enter CVode's error estimates.

Accuracy: CVode keeps each internal step's local error below ``rtol * |x_i| + atol_i`` for
every state ``x_i``, with ``atol_i = atol * nominal_i`` (the state's nominal value, from
``fmi2GetNominalsOfContinuousStates``). The global error over a simulation is a small multiple
of that (``tests/test_fmu_model_exchange.py`` measures it against the co-simulation build).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from fmu_greybox.fmi.compiler import NATIVE_DIR, CBuild, core_flags, load_cached_library

CVODE = "cvode"
#: The integrators a model-exchange white-box can be stepped by.
METHODS = (CVODE,)


@dataclass(frozen=True)
class Integrator:
    """How a model-exchange white-box is integrated over each communication step.

    Attributes
    ----------
    method : str
        ``"cvode"``: SUNDIALS CVode (BDF, Newton, dense LU), as fmpy ships it.
    rtol : float
        Relative tolerance of each internal step's local error.
    atol : float
        Absolute tolerance, as a fraction of each state's nominal value.
    max_steps : int
        Most internal steps in one communication step before the step fails (CVode's own
        limit, ``CVodeSetMaxNumSteps``, counts per call, and each call here is one step).
    """

    method: str = CVODE
    rtol: float = 1e-8
    atol: float = 1e-8
    max_steps: int = 20_000

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"integrator {self.method!r} is not one of {', '.join(METHODS)}")
        for name in ("rtol", "atol"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 < value < 1.0):
                raise ValueError(f"integrator {name} = {value} must lie in (0, 1)")
        if self.max_steps < 1:
            raise ValueError(f"integrator max_steps = {self.max_steps} must be positive")

    def to_dict(self) -> dict[str, Any]:
        """The settings as plain data (``model.json``), with the method's words."""
        return {**asdict(self), "summary": self.summary()}

    def summary(self) -> str:
        """One sentence for people: what integrates, with which tolerances, how often restarted."""
        return (
            f"SUNDIALS CVode (BDF, Newton, dense LU; fmpy {_fmpy_version()}) with rtol "
            f"{self.rtol:g} and atol {self.atol:g} times each state's nominal value, restarted "
            "at every communication step with the inputs held over the step"
        )


#: The integrator model-exchange white-boxes are stepped by unless one is given.
DEFAULT_INTEGRATOR = Integrator()


def whitebox_facts(kind: Any, integrator: Integrator | None = None) -> dict[str, Any]:
    """What the model folder records of how its white-box was stepped (``model.json``,
    ``training["whitebox"]``): the FMU's kind, and for model exchange the integrator.

    Parameters
    ----------
    kind : FmuKind
    integrator : Integrator, optional
        Default :data:`DEFAULT_INTEGRATOR` (for a model-exchange kind).
    """
    facts: dict[str, Any] = {"kind": kind.label}
    if kind.interface == "model exchange":
        facts["integrator"] = (integrator or DEFAULT_INTEGRATOR).to_dict()
    else:
        facts["stepped_by"] = "the FMU's own solver (co-simulation)"
    return facts


def recorded_integrator(facts: Mapping[str, Any]) -> Integrator | None:
    """The integrator a model folder's white-box facts record (:func:`whitebox_facts`), or
    ``None`` (a co-simulation white-box, or a folder written before it was recorded)."""
    data = facts.get("integrator")
    if not isinstance(data, dict):
        return None
    return Integrator(**{k: data[k] for k in ("method", "rtol", "atol", "max_steps")})


def _fmpy_version() -> str:
    import fmpy

    return str(fmpy.__version__)


class IntegratorError(RuntimeError):
    """CVode or the FMU failed during a step: ``call`` is what failed (an FMI call's key in
    the instance's ``CALLS``, or ``"CVode"``), ``flag`` its status or CVode's return code,
    ``detail`` what CVode said."""

    def __init__(self, flag: int, detail: str, call: str = "CVode") -> None:
        self.flag = flag
        self.detail = detail
        self.call = call
        super().__init__(f"{call} returned {flag}: {detail}")


#: CVode's ``itask`` and return values missing from fmpy's bindings (``cvode.h``).
CV_ONE_STEP = 2
CV_TSTOP_RETURN = 1
NATIVE_SOURCE = NATIVE_DIR / "me_step.c"
#: The FMU calls of the C loop, in the order of its ``enum`` (``native/me_step.c``); the last
#: three name CVode, a termination and a time event the FMU asked for.
NATIVE_CALLS = (
    "set_time",
    "set_states",
    "get_states",
    "derivatives",
    "completed",
    "event_mode",
    "discrete",
    "continuous_mode",
    "CVode",
    "terminate",
    "time_event",
)


class _FgbMe(ctypes.Structure):
    """``FgbMe`` of ``native/me_step.c``."""

    _fields_ = [
        ("component", ctypes.c_void_p),
        ("fmi3", ctypes.c_int),
        ("n", ctypes.c_size_t),
        ("cvode", ctypes.c_void_p),
        ("max_steps", ctypes.c_long),
        ("x", ctypes.c_void_p),
        # the FMU's functions (the first eight calls), then CVode's
        *(
            (name, ctypes.c_void_p)
            for name in (*NATIVE_CALLS[:8], "cv_step", "cv_reinit", "cv_stop_time", "array")
        ),
        ("failed_call", ctypes.c_int),
        ("failed_status", ctypes.c_int),
        ("steps", ctypes.c_long),
        ("evaluations", ctypes.c_long),
    ]


@functools.lru_cache(maxsize=1)
def me_library() -> ctypes.CDLL | None:
    """The C integration loop (``native/me_step.c``), compiled on first use and cached beside
    the built-in FMUs; ``None`` where :data:`~fmu_greybox.fmi.compiler.DISABLE_VARIABLE` is
    ``0`` or it cannot be built (then with a warning saying why, once per process: the loop
    runs in Python; both by :func:`~fmu_greybox.fmi.compiler.load_cached_library`)."""
    from fmu_greybox.fmi.builtin import cache_dir

    build = CBuild(what=NATIVE_SOURCE.name, sources=(NATIVE_SOURCE,), flags=core_flags())
    digest = hashlib.sha256(" ".join(build.flags).encode() + NATIVE_SOURCE.read_bytes())
    library = cache_dir().parent / "me-step" / digest.hexdigest()[:16] / "libfgbmestep.so"
    loaded = load_cached_library(
        build, library, "model-exchange white-boxes integrate in a Python loop (slower)"
    )
    if loaded is None:
        return None
    loaded.fgb_me_step.argtypes = [ctypes.POINTER(_FgbMe), ctypes.c_double, ctypes.c_double]
    loaded.fgb_me_step.restype = ctypes.c_int
    return loaded


def _address(function: object) -> int:
    return ctypes.cast(function, ctypes.c_void_p).value


class CVodeStepper:
    """CVode over the states of one FMU instance, restarted at each communication step.

    Where the C loop is available (:func:`me_library`) and ``fmu`` is given, CVode's
    right-hand side and the loop over internal steps run in C (``native/me_step.c``) and
    :meth:`advance` calls the FMU's functions from there; otherwise the callables given run in
    Python. Both make the same calls in the same order, so the same numbers.

    Parameters
    ----------
    n : int
        Number of continuous states.
    rhs : callable
        ``rhs(t, x, dx)``: set the time and the states ``x`` (a ``POINTER(c_double)``), write
        the derivatives into ``dx``; returns 0 (or raises).
    nominals : ndarray, shape (n,)
        The states' nominal values (absolute tolerances are ``atol`` times these).
    settings : Integrator
    fmu : dict, optional
        For the C loop: ``component``, ``fmi3`` (bool) and the FMU's C functions by the names
        of :data:`NATIVE_CALLS` (the first eight).
    """

    def __init__(
        self,
        n: int,
        rhs: Callable[[float, Any, Any], int],
        nominals: np.ndarray,
        settings: Integrator,
        fmu: dict[str, Any] | None = None,
    ) -> None:
        from fmpy.sundials import (
            CV_BDF,
            NV_DATA_S,
            CVodeCreate,
            CVodeInit,
            CVodeSetLinearSolver,
            CVodeSetMaxNumSteps,
            CVodeSVtolerances,
            CVRhsFn,
            N_VNew_Serial,
            SUNContext,
            SUNContext_Create,
            SUNDenseMatrix,
            SUNLinSol_Dense,
        )
        from fmpy.sundials.libraries import sundials_core, sundials_cvode
        from fmpy.sundials.sundials_types import SUN_COMM_NULL

        self.n = n
        self.settings = settings
        self._rhs = rhs
        self._nv_data = NV_DATA_S
        self._error: BaseException | None = None
        self.messages: list[str] = []
        self._steps = 0
        self._evaluations = 0
        self._context = SUNContext()
        _ok(SUNContext_Create(SUN_COMM_NULL, ctypes.byref(self._context)), "SUNContext_Create")
        self._quiet(sundials_core)
        self._x = N_VNew_Serial(n, self._context)
        self._abstol = N_VNew_Serial(n, self._context)
        self.x = np.ctypeslib.as_array(NV_DATA_S(self._x), (n,))
        np.ctypeslib.as_array(NV_DATA_S(self._abstol), (n,))[:] = settings.atol * np.abs(
            np.where(np.asarray(nominals) > 0.0, nominals, 1.0)
        )
        self._memory = CVodeCreate(CV_BDF, self._context)
        # private function objects: fmpy's own (shared) bindings keep their argtypes
        self._cvode = sundials_cvode["CVode"]
        self._reinit = sundials_cvode["CVodeReInit"]
        self._stop_time = sundials_cvode["CVodeSetStopTime"]
        self._cvode.argtypes = [
            ctypes.c_void_p,
            ctypes.c_double,
            ctypes.c_void_p,
            ctypes.POINTER(ctypes.c_double),
            ctypes.c_int,
        ]
        self._reinit.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_void_p]
        self._stop_time.argtypes = [ctypes.c_void_p, ctypes.c_double]
        for function in (self._cvode, self._reinit, self._stop_time):
            function.restype = ctypes.c_int
        self.native = me_library() if fmu is not None else None
        if self.native is not None:
            self._f = CVRhsFn(_address(self.native.fgb_me_rhs))
            self._me = _FgbMe(
                component=fmu["component"],
                fmi3=int(bool(fmu["fmi3"])),
                n=n,
                cvode=self._memory,
                max_steps=settings.max_steps,
                x=ctypes.cast(self._x, ctypes.c_void_p).value,
                cv_step=_address(self._cvode),
                cv_reinit=_address(self._reinit),
                cv_stop_time=_address(self._stop_time),
                array=_address(sundials_core["N_VGetArrayPointer"]),
                **{name: _address(fmu[name]) for name in NATIVE_CALLS[:8]},
            )
            user_data = sundials_cvode["CVodeSetUserData"]
            user_data.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
            user_data.restype = ctypes.c_int
        else:
            self._f = CVRhsFn(self._evaluate)  # kept: CVode holds the pointer
        _ok(CVodeInit(self._memory, self._f, 0.0, self._x), "CVodeInit")
        if self.native is not None:
            _ok(user_data(self._memory, ctypes.addressof(self._me)), "CVodeSetUserData")
        _ok(CVodeSVtolerances(self._memory, settings.rtol, self._abstol), "CVodeSVtolerances")
        self._matrix = SUNDenseMatrix(n, n, self._context)
        self._solver = SUNLinSol_Dense(self._x, self._matrix, self._context)
        _ok(CVodeSetLinearSolver(self._memory, self._solver, self._matrix), "linear solver")
        _ok(CVodeSetMaxNumSteps(self._memory, settings.max_steps), "CVodeSetMaxNumSteps")
        self._reached = ctypes.c_double()

    @property
    def steps(self) -> int:
        """CVode's internal steps so far (over every communication step)."""
        return self._me.steps if self.native is not None else self._steps

    @property
    def evaluations(self) -> int:
        """Right-hand-side evaluations so far."""
        return self._me.evaluations if self.native is not None else self._evaluations

    def _quiet(self, core: ctypes.CDLL) -> None:
        """Keep CVode's messages for the error raised instead of printing them."""
        from fmpy.sundials.sundials_types import SUNErrHandlerFn

        def keep(line, function, file, message, code, user_data, context) -> None:
            text = message.decode("utf-8", "replace") if message else ""
            self.messages.append(f"{function.decode() if function else '?'}: {text}")
            del self.messages[:-10]

        self._handler = SUNErrHandlerFn(keep)
        clear, push = core["SUNContext_ClearErrHandlers"], core["SUNContext_PushErrHandler"]
        clear.argtypes = [ctypes.c_void_p]
        push.argtypes = [ctypes.c_void_p, SUNErrHandlerFn, ctypes.c_void_p]
        clear(self._context)
        push(self._context, self._handler, None)

    def _evaluate(self, t: float, x: Any, dx: Any, user_data: Any) -> int:
        self._evaluations += 1
        try:
            return self._rhs(t, self._nv_data(x), self._nv_data(dx))
        except BaseException as exc:  # an exception cannot cross CVode: keep it, stop CVode
            self._error = exc
            return -1

    def advance(
        self,
        start: float,
        stop: float,
        completed: Callable[[float, Any], np.ndarray | None],
    ) -> None:
        """Integrate the FMU from ``start`` to ``stop``, from the states :attr:`x` holds.

        Parameters
        ----------
        start, stop : float
            The communication step's ends [s].
        completed : callable
            ``completed(t, x)`` after each internal step, with the accepted states ``x`` (a
            ``POINTER(c_double)``) at time ``t``: returns ``None``, or the states after an
            event (CVode restarts from them). Not called by the C loop, which does the same.

        Raises
        ------
        IntegratorError
            CVode failed (too much work, repeated error-test or convergence failures), with
            what it said, or (C loop) an FMU call failed.
        BaseException
            What the right-hand side or ``completed`` raised (Python loop).
        """
        self.messages.clear()
        if self.native is not None:
            if self.native.fgb_me_step(ctypes.byref(self._me), start, stop) != 0:
                call = NATIVE_CALLS[self._me.failed_call]
                said = " | ".join(self.messages[-3:]) if call == "CVode" else ""
                if call == "CVode" and self._me.steps and not said:
                    said = self._too_much_work(start)
                raise IntegratorError(self._me.failed_status, said or "no message", call)
            return
        self._restart(start, stop)
        taken = 0
        while True:
            reached = ctypes.byref(self._reached)
            flag = self._cvode(self._memory, stop, self._x, reached, CV_ONE_STEP)
            if self._error is not None:
                error, self._error = self._error, None
                raise error
            if flag < 0:
                raise IntegratorError(flag, " | ".join(self.messages[-3:]) or "no message")
            self._steps += 1
            taken += 1
            if taken > self.settings.max_steps:
                raise IntegratorError(-1, self._too_much_work(start))
            t = self._reached.value
            done = flag == CV_TSTOP_RETURN or t >= stop
            after_event = completed(stop if done else t, self._nv_data(self._x))
            if done:
                return
            if after_event is not None:
                self.x[:] = after_event
                self._restart(t, stop)

    def _too_much_work(self, start: float) -> str:
        return (
            f"more than max_steps = {self.settings.max_steps} internal steps (mxstep) in the "
            f"communication step from t = {start:.9g} s; the model may be stiffer there than "
            "expected, or failing: check its parameters and inputs"
        )

    def _restart(self, start: float, stop: float) -> None:
        _ok(self._reinit(self._memory, start, self._x), "CVodeReInit")
        _ok(self._stop_time(self._memory, stop), "CVodeSetStopTime")

    def close(self) -> None:
        """Free CVode's memory (idempotent)."""
        if self._memory is None:
            return
        from fmpy.sundials import CVodeFree

        CVodeFree(ctypes.byref(ctypes.c_void_p(self._memory)))
        self._memory = None


def _ok(flag: int, call: str) -> None:
    if flag != 0:
        raise IntegratorError(flag, f"{call} failed")
