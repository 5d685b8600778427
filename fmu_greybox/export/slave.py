"""The grey-box FMU at run time: the white-box FMU and the stage correctors behind one FMI slave.

:class:`GreyBoxSlave` is the pythonfmu slave of an FMU written by :mod:`fmu_greybox.export.fmu`. Its
resources hold a copy of the model folder (``greybox_model/``: white-box FMU, corrector arrays,
``model.json`` with the SHA-256 of every file) and ``fmu_runtime.json`` (export settings). At
instantiation the model is loaded and every hash checked; the white-box runs with the model's
named terms, if it carries any (:meth:`~fmu_greybox.model.store.GreyBoxModel.whitebox`).

Each ``fmi2DoStep(t, h)`` does what :func:`fmu_greybox.workflow.master.run_master` does for one
row: step
the white-box with the current inputs, then the stage correctors in autoregressive order; the
chain's memory starts from the white-box outputs at initialisation (zero residual), since a bench
has no recording. The correctors were trained at one communication step ``dt``: ``h`` must equal
it to a relative 1e-6, and the white-box is then advanced by exactly ``dt``, so that the outputs
do not depend on how a master rounds its time (libcosim counts nanoseconds and hands out steps
that differ from 1 ms in the last bit).

Variables (value references in this order, see :func:`greybox_interface`):

* the white-box's Real inputs, same names, units and start values;
* the white-box's Real outputs, same names; a stage's output carries the corrected value;
* per stage output ``<name>_std`` (predictive standard deviation) and ``<name>_wb`` (the
  white-box with the named terms acting on the stage, if any, before the corrector);
* ``domain_score`` (0..1, see :mod:`fmu_greybox.model.chain_step`) and the Boolean
``out_of_domain``: some
  stage's features left their (widened) training range, where the chain clips them, or
  ``domain_score`` fell below ``ood_threshold``;
* the tunable parameters ``ood_threshold`` and ``correction_enabled`` (Boolean).
"""

from __future__ import annotations

import base64
import functools
import json
import math
import sys
import weakref
from dataclasses import dataclass, field
from operator import getitem
from pathlib import Path
from typing import Any

import numpy as np
from pythonfmu import (
    Boolean,
    DefaultExperiment,
    Fmi2Causality,
    Fmi2Initial,
    Fmi2Slave,
    Fmi2Variability,
    Real,
)
from pythonfmu.enums import Fmi2Status

from fmu_greybox import __version__, _chainstep
from fmu_greybox.errors import ExportError, ModelFormatError
from fmu_greybox.export.runtime import RUNTIME_FILE, attach_logger, guarded, refuse_step, report
from fmu_greybox.fmi.archive import FmuArchive, open_fmu
from fmu_greybox.model.chain_step import DEFAULT_OOD_THRESHOLD, ChainState, out_of_domain
from fmu_greybox.model.domain import InputDomain
from fmu_greybox.model.store import MANIFEST, GreyBoxModel, file_sha256, load_model
from fmu_greybox.model.whitebox import NamedModel

#: Folder in the FMU's resources holding the copy of the model folder.
MODEL_FOLDER = "greybox_model"
#: Version of the serialised FMU state.
STATE_VERSION = 3
#: Relative tolerance on the communication step against the training step.
STEP_RTOL = 1e-6

ENABLED = "correction_enabled"
THRESHOLD = "ood_threshold"
SCORE = "domain_score"
FLAG = "out_of_domain"


# ---------------------------------------------------------------------------- the interface
@dataclass(frozen=True)
class Port:
    """One variable of the exported FMU.

    Attributes
    ----------
    name : str
    type : str
        ``"Real"`` or ``"Boolean"``.
    causality : str
        ``"input"``, ``"output"`` or ``"parameter"``.
    variability : str
        ``"continuous"``, ``"discrete"`` or ``"tunable"``.
    unit : str
        ``""`` when dimensionless or unknown.
    description : str
    start : float or bool or None
        Start value (inputs and parameters).
    """

    name: str
    type: str
    causality: str
    variability: str
    unit: str = ""
    description: str = ""
    start: float | bool | None = None

    @property
    def initial(self) -> str | None:
        """FMI ``initial``: calculated for outputs, exact for parameters, none for inputs."""
        return {"output": "calculated", "parameter": "exact"}.get(self.causality)


@dataclass(frozen=True)
class GreyBoxInterface:
    """The variables of a grey-box FMU and where the chain's signals sit among them.

    Attributes
    ----------
    reals : list of Port
        Real variables; their value reference is their position.
    booleans : list of Port
        Boolean variables; value references follow the Reals.
    n_inputs : int
        The first ``n_inputs`` Reals are the white-box inputs, in white-box order.
    wb_outputs : list of str
        White-box Real outputs passed through (Reals ``n_inputs ..``), in white-box order.
    stage_output : ndarray of int, shape (Q,)
        Position of each stage's output within ``wb_outputs``.
    exo_index : ndarray of int, shape (n_exo,)
        Position within the inputs of each of the chain's exogenous signals.
    """

    reals: list[Port]
    booleans: list[Port]
    n_inputs: int
    wb_outputs: list[str]
    stage_output: np.ndarray
    exo_index: np.ndarray

    @property
    def ports(self) -> list[Port]:
        """All variables in value-reference order."""
        return [*self.reals, *self.booleans]

    @property
    def input_names(self) -> list[str]:
        """The white-box inputs."""
        return [p.name for p in self.reals[: self.n_inputs]]

    def reference(self, name: str) -> int:
        """Value reference of a variable."""
        return next(i for i, p in enumerate(self.ports) if p.name == name)


def greybox_interface(
    model: GreyBoxModel, archive: FmuArchive, ood_threshold: float = DEFAULT_OOD_THRESHOLD
) -> GreyBoxInterface:
    """Derive the grey-box FMU's variables from the model and its white-box FMU.

    Raises
    ------
    ExportError
        A white-box input or output is not Real, a chain input is not a white-box input, or a
        generated name clashes with a white-box variable.
    """
    variables = archive.variables
    odd = [v.name for v in variables.values() if v.causality in ("input", "output")]
    odd = [n for n in odd if variables[n].type != "Real"]
    if odd:
        raise ExportError(
            f"{archive.path.name}: {', '.join(odd)} are not Real; the exported grey-box passes "
            "Real inputs and outputs only. Wrap the white-box so its interface is Real"
        )
    inputs = [variables[n] for n in archive.inputs]
    outputs = [variables[n] for n in archive.outputs]
    chain = model.chain
    input_names = [v.name for v in inputs]
    exo_index = []
    for signal_name in chain.exo_names:
        variable = model.config.signals[signal_name].variable
        if variable not in input_names:
            raise ExportError(
                f"stage input {signal_name!r} (FMU variable {variable!r}) is not an input of "
                f"{archive.path.name}; an exported grey-box sees only the white-box inputs "
                f"({', '.join(input_names)}), so retrain with stage inputs among them"
            )
        exo_index.append(input_names.index(variable))
    out_names = [v.name for v in outputs]
    stage_of = {s.config.whitebox_output: s for s in chain.stages}
    reals = [
        Port(
            v.name,
            "Real",
            "input",
            "continuous",
            v.unit,
            v.description,
            v.start if v.start is not None else 0.0,
        )
        for v in inputs
    ]
    contents = model.contents()
    for v in outputs:
        text = v.description or v.name
        stage = stage_of.get(v.name)
        if stage is not None:
            text = f"{text}; {contents[stage.name]} (stage {stage.name})"
        reals.append(Port(v.name, "Real", "output", "continuous", v.unit, text))
    for kind in ("std", "wb"):
        for stage in chain.stages:
            name = stage.config.whitebox_output
            reals.append(
                Port(
                    f"{name}_{kind}",
                    "Real",
                    "output",
                    "continuous",
                    variables[name].unit,
                    _stage_output_text(model, stage.stage_index, kind),
                )
            )
    reals.append(
        Port(
            SCORE,
            "Real",
            "output",
            "continuous",
            "1",
            "Smallest over stages of the kernel correlation between the corrector's "
            "features and its nearest inducing point (1 on the training data, towards "
            "0 far from it); 1 while correction is off",
        )
    )
    reals.append(
        Port(
            THRESHOLD,
            "Real",
            "parameter",
            "tunable",
            "1",
            f"{FLAG} is also set while {SCORE} < {THRESHOLD}",
            float(ood_threshold),
        )
    )
    booleans = [
        Port(
            FLAG,
            "Boolean",
            "output",
            "discrete",
            "",
            "The bench drives the grey-box outside its training data: a corrector feature "
            "left its training range (widened by 5 %; the chain clips it there) or "
            f"{SCORE} < {THRESHOLD}; false while correction is off",
        ),
        Port(
            ENABLED,
            "Boolean",
            "parameter",
            "tunable",
            "",
            "Apply the stage correctors (false: outputs are the white-box's, for A/B runs)",
            True,
        ),
    ]
    names = [p.name for p in [*reals, *booleans]]
    clash = sorted({n for n in names if names.count(n) > 1})
    if clash:
        raise ExportError(
            f"{archive.path.name} already declares {', '.join(clash)}, which the grey-box FMU "
            "adds; rename the white-box variables"
        )
    return GreyBoxInterface(
        reals=reals,
        booleans=booleans,
        n_inputs=len(inputs),
        wb_outputs=out_names,
        stage_output=np.array([out_names.index(o) for o in chain.whitebox_outputs], dtype=int),
        exo_index=np.array(exo_index, dtype=int),
    )


def _stage_output_text(model: GreyBoxModel, q: int, kind: str) -> str:
    """The description of stage ``q``'s ``_std`` or ``_wb`` output."""
    stage = model.chain.stages[q]
    name = stage.config.whitebox_output
    if kind == "std":
        return (
            f"Calibrated predictive standard deviation of {name} (stage {stage.name}; the "
            "correctors' variance propagated through the chain, scaled, plus the stage's "
            "residual variance)"
        )
    acting = model.stage_terms(q)
    if acting:
        effects = ", ".join(dict.fromkeys(t.effect for t in acting))
        return f"White-box {name} with the named terms ({effects}), before the corrector"
    return f"Plain white-box {name} (no named term acts on stage {stage.name})"


@dataclass
class _Run:
    """What exists once the FMU is initialised."""

    whitebox: NamedModel
    state: ChainState
    started_with: list[float] = field(default_factory=list)


class GreyBoxSlave(Fmi2Slave):
    """pythonfmu slave of an exported grey-box FMU (see the module docstring).

    Parameters
    ----------
    **kwargs
        From pythonfmu: ``instance_name``, ``resources`` (the FMU's resources folder), ...

    Raises
    ------
    RuntimeError
        This Python is too old for the FMU.
    ModelFormatError
        A model file in the resources is missing or does not match its recorded hash.
    """

    #: Why the instance stopped working (see :func:`fmu_greybox.export.runtime.guarded`).
    failure = ""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        weakref.finalize(self, _release, self.__dict__)
        attach_logger(self, kwargs)
        try:
            self._instantiate(Path(kwargs["resources"]))
        except Exception as exc:
            report(self, "fmi2Instantiate", f"{type(exc).__name__}: {exc}")
            raise

    def _instantiate(self, resources: Path) -> None:
        settings = read_settings(resources)
        check_python(settings)
        model_dir = resources / MODEL_FOLDER
        recorded = settings["model_sha256"]
        if file_sha256(model_dir / MANIFEST) != recorded:
            raise ModelFormatError(
                f"{model_dir / MANIFEST} does not match the hash recorded at export "
                f"({recorded[:12]}...); the FMU was modified. Export it again"
            )
        self.model = load_model(model_dir)
        self.archive = open_fmu(self.model.whitebox_fmu)
        self.interface = greybox_interface(self.model, self.archive, settings["ood_threshold"])
        self.domain = InputDomain.of(
            self.archive, self.interface.input_names, self.model.training.input_ranges
        )
        self.modelName = settings["model_identifier"]
        self.description = settings["description"]
        self.author = settings["author"]
        self.version = settings["version"]
        self.default_experiment = DefaultExperiment(step_size=self.model.dt)
        self._reals: list[float] = [0.0] * len(self.interface.reals)
        self._bools: list[bool] = [False] * len(self.interface.booleans)
        self._register()
        self._run: _Run | None = None
        self._time = 0.0
        self._initialising = False
        self._plan = self.model.chain.plan()
        self._layout()
        exported = settings.get("exported_with", "")
        if exported and exported != __version__:
            self.log(
                f"exported with fmu-greybox {exported}, running with {__version__}; the model "
                "files passed their checks",
                Fmi2Status.warning,
            )

    # ------------------------------------------------------------------ set-up
    def _register(self) -> None:
        # explicit getters and setters: pythonfmu would otherwise make closures over the slave,
        # a reference cycle that delays releasing the white-box until garbage collection
        kinds = {"Real": Real, "Boolean": Boolean}
        for store, ports in (
            (self._reals, self.interface.reals),
            (self._bools, self.interface.booleans),
        ):
            for i, port in enumerate(ports):
                if port.start is not None:
                    store[i] = port.start
                self.register_variable(
                    kinds[port.type](
                        port.name,
                        causality=Fmi2Causality[port.causality],
                        variability=Fmi2Variability[port.variability],
                        initial=Fmi2Initial[port.initial] if port.initial else None,
                        description=port.description,
                        getter=functools.partial(getitem, store, i),
                        setter=functools.partial(store.__setitem__, i),
                    ),
                    nested=False,
                )

    def _layout(self) -> None:
        """Positions used on the hot path."""
        iface = self.interface
        n_in, n_wb = iface.n_inputs, len(iface.wb_outputs)
        q = len(self.model.chain.stages)
        self._n_in = n_in
        self._out_slice = slice(n_in, n_in + n_wb + 2 * q + 1)
        self._stage_output = iface.stage_output
        self._stage_positions = tuple(int(i) for i in iface.stage_output)
        self._exo_index = tuple(int(i) for i in iface.exo_index)
        self._exo = np.empty(iface.exo_index.size)
        self._threshold_vr = iface.reference(THRESHOLD)
        self._settable_reals = frozenset([*range(n_in), self._threshold_vr])
        self._bool_vr = {len(iface.reals) + i: i for i in range(len(iface.booleans))}
        self._enabled_vr = iface.reference(ENABLED)
        self._enabled = self._bool_vr[self._enabled_vr]
        self._flag = self._bool_vr[iface.reference(FLAG)]

    # ------------------------------------------------------------------ FMI calls
    def setup_experiment(
        self, start_time: float, stop_time: float | None = None, tolerance: float | None = None
    ) -> None:
        self._time = float(start_time)

    def enter_initialization_mode(self) -> None:
        self._initialising = True

    @guarded("fmi2ExitInitializationMode")
    def exit_initialization_mode(self) -> None:
        self._prepare()
        self._initialising = False

    @guarded("fmi2DoStep", False)
    def do_step(self, current_time: float, step_size: float) -> bool:
        if self.failure:
            return refuse_step(self, current_time)
        run = self._run
        if run is None:
            raise RuntimeError("fmi2DoStep before initialisation; call fmi2ExitInitializationMode")
        refusal = self._refusal(current_time, step_size)
        if refusal:
            return refuse_step(self, current_time, refusal)
        reals = self._reals
        u = reals[: self._n_in]
        wb = run.whitebox.step(u)  # by exactly the trained step, see the module docstring
        y_wb = wb[self._stage_output]
        exo = self._exo
        exo[:] = [u[i] for i in self._exo_index]
        enabled = self._bools[self._enabled]
        state = run.state
        score = self._plan.step(state, exo, y_wb, enabled)
        flag = out_of_domain(score, state, self._reals[self._threshold_vr])
        self._publish(wb, y_wb, state, score, flag)
        self._time = current_time + step_size
        return True

    def _refusal(self, current_time: float, step_size: float) -> str | None:
        """Why a step is refused: a jump in time, another step than the trained one, inputs
        outside the input domain (:mod:`fmu_greybox.model.domain`); checked in this order and
        worded by the native runtime's own code (``native/rules.c``, through
        :mod:`fmu_greybox._chainstep`), so both runtimes refuse alike."""
        dt, time = self.model.dt, self._time
        return _chainstep.step_refusal(
            current_time, step_size, time, dt, STEP_RTOL * dt
        ) or self.domain.refusal(self._reals[: self._n_in], time)

    @guarded("fmi2Terminate")
    def terminate(self) -> None:
        if self._run is not None:
            self._run.whitebox.close()
            self._run = None

    @guarded("fmi2GetReal", lambda vrs: [math.nan] * len(vrs))
    def get_real(self, vrs: list[int]) -> list[float]:
        if self._initialising:
            self._prepare()
        return list(map(self._reals.__getitem__, vrs))

    @guarded("fmi2SetReal")
    def set_real(self, vrs: list[int], values: list[float]) -> None:
        if not self._settable_reals.issuperset(vrs):
            vr = next(vr for vr in vrs if vr not in self._settable_reals)
            raise ValueError(f"value reference {vr} is not a Real input or tunable parameter")
        for vr, value in zip(vrs, values, strict=True):
            if vr == self._threshold_vr and not 0.0 <= value <= 1.0:  # NaN included
                raise ValueError(
                    f"{THRESHOLD} = {value} must lie between 0 and 1 (a {SCORE}); nothing was set"
                )
        reals = self._reals
        for vr, value in zip(vrs, values, strict=True):
            reals[vr] = value

    @guarded("fmi2GetBoolean", lambda vrs: [False] * len(vrs))
    def get_boolean(self, vrs: list[int]) -> list[bool]:
        if self._initialising:
            self._prepare()
        return [self._bools[self._boolean_index(vr)] for vr in vrs]

    @guarded("fmi2SetBoolean")
    def set_boolean(self, vrs: list[int], values: list[bool]) -> None:
        for vr, value in zip(vrs, values, strict=True):
            if vr != self._enabled_vr:
                raise ValueError(f"value reference {vr} is not a Boolean tunable parameter")
            self._bools[self._boolean_index(vr)] = bool(value)

    def _boolean_index(self, vr: int) -> int:
        try:
            return self._bool_vr[vr]
        except KeyError:
            raise ValueError(f"value reference {vr} is not a Boolean variable") from None

    # ------------------------------------------------------------------ stepping
    def _prepare(self) -> _Run:
        """The white-box initialised with the current inputs, and the chain's first memory.

        In initialisation mode the inputs may still change: the white-box is initialised again
        whenever they differ from those it was initialised with.
        """
        inputs = self._reals[: self._n_in]
        run = self._run
        if run is not None and run.started_with == inputs:
            return run
        refusal = self.domain.refusal(inputs, self._time)
        if refusal:
            raise ValueError(refusal)
        start = dict(zip(self.interface.input_names, inputs, strict=True))
        if run is None:
            whitebox = self.model.whitebox(
                self.archive,
                self.interface.input_names,
                self.interface.wb_outputs,
                start,
                self._time,
                instance_name=f"{self.instance_name}.whitebox",
            )
        else:
            whitebox = run.whitebox
            whitebox.reset(start, self._time)
        wb = whitebox.outputs()
        y_wb = wb[self._stage_output]
        exo = np.array([inputs[i] for i in self._exo_index])
        state = self._plan.start(np.ascontiguousarray(y_wb), exo)
        self._run = _Run(whitebox=whitebox, state=state, started_with=inputs)
        self._publish(wb, y_wb, state, 1.0, False)
        return self._run

    def _publish(
        self, wb: np.ndarray, y_wb: np.ndarray, state: ChainState, score: float, flag: bool
    ) -> None:
        # white-box outputs with the stage outputs corrected, standard deviations, raw
        # white-box stage outputs, score: built as Python floats, the form _reals holds
        values = wb.tolist()
        for position, value in zip(self._stage_positions, state.out_mean.tolist(), strict=True):
            values[position] = value
        values += np.sqrt(state.out_var).tolist()
        values += y_wb.tolist()
        values.append(score)
        self._reals[self._out_slice] = values
        self._bools[self._flag] = flag

    # ------------------------------------------------------------------ state
    @guarded("fmi2GetFMUstate")
    def _get_fmu_state(self) -> dict[str, Any]:
        run = self._run
        saved: dict[str, Any] = {
            "version": STATE_VERSION,
            "time": self._time,
            "reals": list(self._reals),
            "bools": list(self._bools),
            "run": None,
        }
        if run is not None:
            saved["run"] = {
                "whitebox": run.whitebox.state(),
                "chain": run.state.to_array().tolist(),
                "started_with": list(run.started_with),
            }
        return saved

    @guarded("fmi2SetFMUstate")
    def _set_fmu_state(self, saved: dict[str, Any]) -> None:
        self._check_state(saved)
        self._time = float(saved["time"])
        self._reals[:] = saved["reals"]
        self._bools[:] = saved["bools"]
        kept = saved["run"]
        if kept is None:
            self.terminate()
            return
        if self._run is None:
            self._reals[: self._n_in] = kept["started_with"]
            self._prepare()
        run = self._run
        run.started_with = list(kept["started_with"])
        run.whitebox.restore(kept["whitebox"])
        run.state.load_array(np.asarray(kept["chain"], dtype=np.float64))
        self._reals[:] = saved["reals"]
        self._bools[:] = saved["bools"]

    def _check_state(self, saved: Any) -> None:
        """Every field of a restored state, before any is used: one this FMU could have saved.

        Raises
        ------
        ValueError
            Naming the field and what it holds (pythonfmu reports it at fmi2SetFMUstate, and
            the next fmi2DoStep is refused).
        """

        def refuse(field: str, why: str) -> ValueError:
            return ValueError(f"damaged FMU state: {field} {why}; save the state again")

        def numbers(value: Any, field: str, size: int | None, finite: int | None = None) -> None:
            """A list of ``size`` numbers, the first ``finite`` of them (all if None) finite."""
            if not isinstance(value, list) or (size is not None and len(value) != size):
                raise refuse(field, f"is not a list of {size or 'some'} numbers")
            if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
                raise refuse(field, "holds a value that is not a number")
            if not all(math.isfinite(v) for v in value[:finite]):
                raise refuse(field, "holds a value that is not finite")

        if not isinstance(saved, dict) or saved.get("version") != STATE_VERSION:
            version = saved.get("version") if isinstance(saved, dict) else None
            raise ValueError(
                f"FMU state of version {version!r}; this FMU reads version "
                f"{STATE_VERSION}. Save the state again with this FMU"
            )
        if set(saved) != {"version", "time", "reals", "bools", "run"}:
            raise refuse("its keys", f"are {sorted(saved)}")
        numbers([saved["time"]], "time", 1)
        numbers(saved["reals"], "reals", len(self._reals), finite=self._n_in)
        if not 0.0 <= saved["reals"][self._threshold_vr] <= 1.0:  # NaN included
            raise refuse(THRESHOLD, "lies outside 0 to 1")
        bools = saved["bools"]
        if not (
            isinstance(bools, list)
            and len(bools) == len(self._bools)
            and all(isinstance(b, bool | np.bool_) for b in bools)
        ):
            raise refuse("bools", f"is not a list of {len(self._bools)} Booleans")
        kept = saved["run"]
        if kept is None:
            return
        if not isinstance(kept, dict) or set(kept) != {"whitebox", "chain", "started_with"}:
            raise refuse("run", "is not a table of whitebox, chain and started_with")
        numbers(kept["started_with"], "run.started_with", self._n_in)
        size = self._run.state.values.size if self._run is not None else None
        numbers(kept["chain"], "run.chain", size)
        parts = kept["whitebox"]
        if not isinstance(parts, list) or not all(isinstance(p, dict) for p in parts):
            raise refuse("run.whitebox", "is not a list of the white-box instances' states")
        for i, part in enumerate(parts):
            try:
                base64.b64decode(part["fmu"], validate=True)
            except (KeyError, TypeError, ValueError) as exc:
                raise refuse(f"run.whitebox[{i}].fmu", f"is not base64 ({exc})") from exc


def _release(attributes: dict[str, Any]) -> None:
    """Close the white-box instance and remove its extraction folder (at garbage collection)."""
    run = attributes.get("_run")
    if run is not None:
        run.whitebox.close()
    archive = attributes.get("archive")
    if archive is not None:
        archive.close()


def read_settings(resources: Path) -> dict[str, Any]:
    """The export settings in an FMU's resources.

    Raises
    ------
    ModelFormatError
        If the file is missing or unreadable.
    """
    path = resources / RUNTIME_FILE
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ModelFormatError(f"{path}: unreadable ({exc}); export the FMU again") from exc


def check_python(settings: dict[str, Any]) -> None:
    """Refuse a Python older than the FMU needs.

    Raises
    ------
    RuntimeError
        With the running and the required version.
    """
    wanted = tuple(settings.get("requires_python", (3, 11)))
    if tuple(sys.version_info[:2]) < wanted:
        raise RuntimeError(
            f"this FMU needs Python >= {'.'.join(map(str, wanted))}; the simulation process runs "
            f"Python {'.'.join(map(str, sys.version_info[:3]))} ({sys.executable}). Run the bench "
            "with a newer Python (see docs/bench.md, 'Runtime requirements')"
        )
