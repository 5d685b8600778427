"""The white-box with its named correction terms, stepped one communication step at a time.

:class:`NamedModel` is what the diagnosis names folded into the white-box FMU: per distinct entry
stage of the terms one FMU instance, stepped with the terms that act from that stage on (see
:mod:`fmu_greybox.model.terms`), each observed output read from the instance of its stage. Without
terms it is the plain white-box, one instance, at the cost of one function call more.

The diagnosis simulates hypotheses with it
(:func:`~fmu_greybox.model.simulate.simulate_with_terms`), training computes the correctors'
white-box predictions with it, and the co-simulation master and the exported FMU step it, so a
model trained on white-box + named terms runs on the same numbers everywhere.
"""

from __future__ import annotations

import base64
import copy
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fmu_greybox.errors import ConfigError
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.fmi.instance import fmu_instance
from fmu_greybox.fmi.integrator import Integrator
from fmu_greybox.model.terms import Term, term_from_dict

#: FMU steps per communication step while a feedback term is active.
DEFAULT_SUBSTEPS = 4
#: Effects that are verdicts, not terms (docs/diagnosis.md).
VERDICTS = ("none", "unexplained")


@dataclass
class PartLayout:
    """One FMU instance of a :class:`NamedModel`: what it observes and which terms it runs.

    Both runtimes of an exported grey-box lay out the white-box this way (the native FMU
    stores it, :mod:`fmu_greybox.export.native`).

    Attributes
    ----------
    level : int
        Lowest stage the instance serves (the terms acting there act on it).
    columns : list of int
        Positions of the outputs it observes among the model's outputs.
    outputs : list of str
        Those outputs.
    bound : list of str
        The outputs it reads after every (sub-)step: ``outputs``, then those the terms need.
    terms : list of Term
        Its terms, in model order (copies: each instance binds and remembers its own).
    parameters : dict of str to float
        FMU parameter values set before initialisation (the terms' override the project's).
    substeps : int
        FMU steps per communication step: the model's while a feedback term acts, else 1.
    """

    level: int
    columns: list[int]
    outputs: list[str]
    bound: list[str]
    terms: list[Term]
    parameters: dict[str, float]
    substeps: int

    def every(self, term: Term, dt: float) -> float:
        """Time between two calls of ``term`` [s]: the sub-step for feedback terms, else
        the communication step ``dt``."""
        return dt / self.substeps if term.feedback else dt


def term_groups(
    terms: Sequence[Term], stages: Sequence[int]
) -> list[tuple[int, list[int], list[Term]]]:
    """The outputs grouped by the terms that act on them: one group per distinct set of terms
    acting on an output's stage (:meth:`~fmu_greybox.model.terms.Term.acts_at`).

    Parameters
    ----------
    terms : sequence of Term
    stages : sequence of int
        Stage of every output.

    Returns
    -------
    list of (int, list of int, list of Term)
        Per group, in order of its lowest stage: that stage, the positions of its outputs, and
        the terms acting on them (in model order).
    """
    groups: dict[tuple[int, ...], tuple[int, list[int]]] = {}
    for j, stage in enumerate(stages):
        key = tuple(i for i, t in enumerate(terms) if t.acts_at(stage))
        level, columns = groups.setdefault(key, (stage, []))
        groups[key] = (min(level, stage), [*columns, j])
    ordered = sorted(groups.items(), key=lambda item: item[1][0])
    return [(level, columns, [terms[i] for i in key]) for key, (level, columns) in ordered]


def part_layouts(
    outputs: Sequence[str],
    terms: Sequence[Term],
    stages: Sequence[int],
    parameters: Mapping[str, float] | None,
    substeps: int,
) -> list[PartLayout]:
    """The FMU instances of a named model: one per distinct set of terms acting on an observed
    output's stage (:func:`term_groups`).

    Parameters
    ----------
    outputs : sequence of str
        The model's outputs.
    terms : sequence of Term
    stages : sequence of int
        Stage of every output.
    parameters : mapping, optional
        Project parameter values.
    substeps : int
        FMU steps per communication step while a feedback term is active.

    Returns
    -------
    list of PartLayout
    """
    layouts = []
    for level, columns, acting in term_groups(terms, stages):
        active = [copy.deepcopy(t) for t in acting]
        observed = [outputs[j] for j in columns]
        bound = list(observed)
        for term in active:
            bound += [name for name in term.needs() if name not in bound]
        values = dict(parameters or {})
        for term in active:
            values.update(term.parameters())
        fed = any(t.acts_on_inputs and t.feedback for t in active)
        layouts.append(
            PartLayout(
                level=level,
                columns=columns,
                outputs=observed,
                bound=bound,
                terms=active,
                parameters=values,
                substeps=max(1, int(substeps)) if fed else 1,
            )
        )
    return layouts


class _Part:
    """One FMU instance with the terms active at its entry stage, and the outputs it serves."""

    def __init__(
        self,
        archive: FmuArchive,
        inputs: Sequence[str],
        layout: PartLayout,
        start_values: Mapping[str, float] | None,
        start_time: float,
        dt: float,
        instance_name: str,
        integrator: Integrator | None = None,
    ) -> None:
        terms = layout.terms
        self.layout = layout
        self.parameters = layout.parameters
        self.columns = layout.columns
        self.terms = terms
        self.once = [t for t in terms if t.acts_on_inputs and not t.feedback]
        self.fed = [t for t in terms if t.acts_on_inputs and t.feedback]
        self.after = [t for t in terms if t.acts_on_outputs]
        self.plain = not (self.once or self.fed or self.after)
        self.substeps = layout.substeps
        self.dt = dt
        self.n_out = len(layout.outputs)
        self.instance = fmu_instance(
            archive,
            inputs=inputs,
            outputs=layout.bound,
            parameters=self.parameters,
            start_values=start_values,
            instance_name=instance_name,
            start_time=start_time,
            integrator=integrator,
        )
        self._held = np.empty(len(inputs))
        self._row = np.empty(len(inputs))
        self._sensed = np.empty(len(layout.bound))
        self._start()

    def _start(self) -> None:
        for term in self.terms:
            every = self.layout.every(term, self.dt)
            term.bind(self.instance.input_names, self.instance.output_names, every)
        self.current = self.instance.read_outputs().copy()
        self._sensed[:] = self.current
        for term in self.after:
            term.on_output(self._sensed)

    def outputs(self) -> np.ndarray:
        """The observed outputs of the last step (or the initial ones), shape (n_out,)."""
        return self._sensed[: self.n_out]

    def step(self, u: np.ndarray) -> np.ndarray:
        """Apply the terms to the inputs ``u``, advance one communication step, observe."""
        if self.plain:
            self._sensed[:] = self.instance.step(u, self.dt)
            return self._sensed[: self.n_out]
        held = self._held
        held[:] = u
        for term in self.once:
            term.on_input(held, self.current)
        h = self.dt / self.substeps
        for _ in range(self.substeps):
            self._row[:] = held
            for term in self.fed:
                term.on_input(self._row, self.current)
            self.current = self.instance.step(self._row, h)
        self._sensed[:] = self.current
        for term in self.after:
            term.on_output(self._sensed)
        return self._sensed[: self.n_out]

    def reset(self, start_values: Mapping[str, float], start_time: float) -> None:
        self.instance.reset({**self.parameters, **start_values}, start_time)
        self._start()

    def state(self) -> dict[str, Any]:
        return {
            "fmu": base64.b64encode(self.instance.serialize_state()).decode("ascii"),
            "time": self.instance.time,
            "current": self.current.tolist(),
            "sensed": self._sensed.tolist(),
            "terms": [t.memory().tolist() for t in self.terms],
        }

    def restore(self, saved: Mapping[str, Any]) -> None:
        self.instance.deserialize_state(base64.b64decode(saved["fmu"]), saved["time"])
        self.current = np.array(saved["current"], dtype=np.float64)
        self._sensed[:] = saved["sensed"]
        for term, memory in zip(self.terms, saved["terms"], strict=True):
            term.restore(np.asarray(memory, dtype=np.float64))


class NamedModel:
    """The white-box FMU with named correction terms, one communication step at a time.

    Timing as :func:`fmu_greybox.model.simulate.run_open_loop`: :meth:`outputs` after
    construction is row 0; :meth:`step` applies the (corrected) inputs of row ``k`` and returns
    row ``k + 1``. A feedback term computes its correction from the outputs at the start of each
    sub-step.

    Parameters
    ----------
    archive : FmuArchive
        The white-box FMU.
    inputs : sequence of str
        FMU inputs, in the order :meth:`step` receives them.
    outputs : sequence of str
        FMU outputs, in the order :meth:`step` returns them.
    dt : float
        Communication step [s].
    terms : sequence of Term
        Corrections (copied: each instance binds and remembers its own).
    stages : sequence of int, optional
        Stage index of every output (default 0): an output of stage ``s`` sees the terms with
        ``entry <= s`` only.
    parameters : mapping, optional
        Project parameter values (terms' parameter values override them).
    start_values : mapping, optional
        Initial input values.
    start_time : float
        Time of row 0 [s].
    substeps : int
        FMU steps per communication step while a feedback term is active.
    instance_name : str
        FMI instance name (instances beyond the first get ``@stage`` appended).
    integrator : Integrator, optional
        How a model-exchange white-box is integrated (default
        :data:`~fmu_greybox.fmi.integrator.DEFAULT_INTEGRATOR`; unused for co-simulation).

    Raises
    ------
    FmuError
        If the FMU fails to instantiate or initialise.
    """

    def __init__(
        self,
        archive: FmuArchive,
        inputs: Sequence[str],
        outputs: Sequence[str],
        dt: float,
        terms: Sequence[Term] = (),
        stages: Sequence[int] | None = None,
        parameters: Mapping[str, float] | None = None,
        start_values: Mapping[str, float] | None = None,
        start_time: float = 0.0,
        substeps: int = DEFAULT_SUBSTEPS,
        instance_name: str = "whitebox",
        integrator: Integrator | None = None,
    ) -> None:
        stages = list(stages) if stages is not None else [0] * len(outputs)
        self.output_names = list(outputs)
        self.parts: list[_Part] = []
        try:
            for layout in part_layouts(outputs, terms, stages, parameters, substeps):
                name = instance_name if not self.parts else f"{instance_name}@{layout.level}"
                self.parts.append(
                    _Part(archive, inputs, layout, start_values, start_time, dt, name, integrator)
                )
        except BaseException:
            self.close()
            raise
        self._y = np.empty(len(outputs))
        self._single = len(self.parts) == 1

    @property
    def time(self) -> float:
        """Simulation time of the instances [s]."""
        return self.parts[0].instance.time

    def outputs(self) -> np.ndarray:
        """The observed outputs now, shape (n_outputs,) (a reused buffer)."""
        for part in self.parts:
            self._y[part.columns] = part.outputs()
        return self._y

    def step(self, u: np.ndarray) -> np.ndarray:
        """Advance one communication step with inputs ``u`` (n_inputs,); returns the observed
        outputs at its end, shape (n_outputs,) (a reused buffer: copy it to keep it)."""
        if self._single:
            self._y[:] = self.parts[0].step(u)
            return self._y
        for part in self.parts:
            self._y[part.columns] = part.step(u)
        return self._y

    def reset(self, start_values: Mapping[str, float], start_time: float) -> None:
        """Start over (``fmi2Reset``, initialisation, the terms' memory cleared)."""
        for part in self.parts:
            part.reset(start_values, start_time)

    def state(self) -> list[dict[str, Any]]:
        """Everything needed to continue identically later, as plain JSON-able data (each FMU's
        serialised state in base64)."""
        return [part.state() for part in self.parts]

    def restore(self, saved: Sequence[Mapping[str, Any]]) -> None:
        """Continue from what :meth:`state` returned."""
        for part, kept in zip(self.parts, saved, strict=True):
            part.restore(kept)

    def close(self) -> None:
        """Free the FMU instances (idempotent)."""
        for part in self.parts:
            part.instance.close()

    def __enter__(self) -> NamedModel:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def terms_from_findings(findings: Sequence[Mapping[str, Any]]) -> list[Term]:
    """The terms of a diagnosis' findings (``diagnosis.json``'s ``findings``), in order.

    Raises
    ------
    ValueError
        A finding's term cannot be rebuilt (unknown kind or field).
    """
    return [
        term_from_dict(data)
        for finding in findings
        if finding.get("effect") not in VERDICTS
        for data in finding.get("terms", [])
    ]


def read_terms(path: str | Path) -> list[Term]:
    """The named terms of a diagnosis, from the ``diagnosis.json`` it wrote.

    Raises
    ------
    ConfigError
        The file is unreadable, not a diagnosis, or a finding's term cannot be rebuilt.
    """
    path = Path(path)
    mend = "pass the diagnosis.json that 'fmu-greybox diagnose' wrote"
    try:
        payload = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"unreadable ({exc}); {mend}", path=str(path)) from exc
    findings = payload.get("findings") if isinstance(payload, dict) else None
    if not isinstance(findings, list) or not all(isinstance(f, dict) for f in findings):
        raise ConfigError(f"no list of findings; {mend}", field="findings", path=str(path))
    try:
        return terms_from_findings(findings)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{exc}; {mend}", field="findings", path=str(path)) from exc


def check_terms(terms: Sequence[Term], archive: FmuArchive, n_stages: int) -> None:
    """Every variable a term acts on exists in the white-box, with the causality it needs.

    Raises
    ------
    ConfigError
        Naming the term, the variable and the FMU.
    """
    inputs, outputs = set(archive.inputs), set(archive.variables)
    for term in terms:
        label = f"term {type(term).__name__} ({term.effect})"
        wanted = [("input", name, inputs) for name in [getattr(term, "input", None)] if name]
        wanted += [("variable", name, outputs) for name in [*term.needs(), *term.parameters()]]
        wanted += [("variable", name, outputs) for name in getattr(term, "outputs", ())]
        for kind, name, available in wanted:
            if name not in available:
                raise ConfigError(
                    f"{label} acts on {kind} {name!r}, which {archive.path.name} does not have; "
                    "the diagnosis was made with another white-box FMU. Diagnose again with "
                    "this project's FMU",
                    field="terms",
                )
        if not 0 <= term.entry < n_stages:
            raise ConfigError(
                f"{label} enters at stage {term.entry}; the project has {n_stages} stages. "
                "Diagnose again with this project",
                field="terms",
            )
