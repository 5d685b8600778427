"""What each FMU input and output is, physically, and which recorded signals observe the FMU.

Roles come from the project's signals first (``role`` in the config) and, for FMU variables the
project does not mention, from the FMU's own declarations (:mod:`.roles`: the unit, else the
name and description). Nothing here knows any particular model's variable names.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fmu_greybox.data.recording import Recording
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.project.config import ProjectConfig, Signal
from fmu_greybox.project.roles import VariableRole, infer_role


@dataclass(frozen=True)
class ObservedSignal:
    """A recorded signal that an FMU output predicts.

    Attributes
    ----------
    name : str
        Project signal name.
    column : str
        Recorded column.
    variable : str
        FMU output predicting it (a stage's ``whitebox_output`` for its target).
    role : str
        Physical role.
    unit : str
        Unit.
    stage : int
        Index of the stage it belongs to: the stage whose target it is, else the stage whose
        target it tracks most closely (see :meth:`SignalMap.assign_stages`).
    is_target : bool
        Whether it is a stage target.
    """

    name: str
    column: str
    variable: str
    role: str
    unit: str
    stage: int
    is_target: bool


@dataclass
class SignalMap:
    """Roles of an FMU's inputs and outputs within a project, and the observed signals.

    Attributes
    ----------
    input_roles : dict[str, str]
        FMU input -> role.
    output_roles : dict[str, str]
        FMU Real output -> role.
    units : dict[str, str]
        FMU variable -> unit (the FMU's declaration, else the project's).
    input_columns : dict[str, str]
        FMU input -> recorded column, for recorded inputs.
    input_stage : dict[str, int]
        FMU input -> index of the first stage that lists it among its inputs (inputs no stage
        lists are absent).
    observed : list of ObservedSignal
        Stage targets in chain order, then the other recorded signals mapped to FMU outputs.
    stage_names : list of str
        Stage names in chain order.
    roles : list of VariableRole
        Every Real input and output with its role and where the role came from.
    """

    input_roles: dict[str, str]
    output_roles: dict[str, str]
    units: dict[str, str]
    input_columns: dict[str, str]
    input_stage: dict[str, int]
    observed: list[ObservedSignal]
    stage_names: list[str]
    roles: list[VariableRole]

    @classmethod
    def from_project(
        cls, config: ProjectConfig, archive: FmuArchive, recording: Recording
    ) -> SignalMap:
        """Collect roles and observed signals of a project over a recording.

        Parameters
        ----------
        config : ProjectConfig
        archive : FmuArchive
            The white-box FMU.
        recording : Recording
            Decides which signals are actually recorded.
        """
        by_variable = {s.variable: s for s in config.signals.values()}
        variables = archive.variables
        reals = [v for v in variables.values() if v.type == "Real"]
        inputs = [v.name for v in reals if v.causality == "input"]
        outputs = [v.name for v in reals if v.causality == "output"]

        def role(name: str) -> VariableRole:
            sig = by_variable.get(name)
            if sig is not None:
                return VariableRole(name, variables[name].causality, sig.role, "project", "")
            return infer_role(variables[name])

        roles = [role(name) for name in (*inputs, *outputs)]
        role_of = {r.variable: r.role for r in roles}

        stage_of_signal: dict[str, int] = {}
        predicted_by: dict[str, str] = {}
        input_stage: dict[str, int] = {}
        for q, stage in enumerate(config.stages):
            stage_of_signal.setdefault(stage.target, q)
            predicted_by.setdefault(stage.target, stage.whitebox_output)
            for name in stage.inputs:
                input_stage.setdefault(config.signals[name].variable, q)
        observed = []
        last = len(config.stages) - 1
        for sig in config.signals.values():
            variable = predicted_by.get(sig.name, sig.variable)
            var = variables.get(variable)
            if var is None or var.causality != "output" or sig.column not in recording.signals:
                continue
            observed.append(
                ObservedSignal(
                    name=sig.name,
                    column=sig.column,
                    variable=variable,
                    role=sig.role,
                    unit=sig.unit or var.unit,
                    stage=stage_of_signal.get(sig.name, last),
                    is_target=sig.name in stage_of_signal,
                )
            )
        observed.sort(key=lambda s: (not s.is_target, s.stage))
        columns = {
            name: by_variable[name].column if name in by_variable else name for name in inputs
        }
        return cls(
            input_roles={name: role_of[name] for name in inputs},
            output_roles={name: role_of[name] for name in outputs},
            units={v.name: v.unit or _declared_unit(by_variable.get(v.name)) for v in reals},
            input_columns={k: v for k, v in columns.items() if v in recording.signals},
            input_stage=input_stage,
            observed=observed,
            stage_names=[s.name for s in config.stages],
            roles=roles,
        )

    @property
    def inferred_roles(self) -> list[VariableRole]:
        """Roles the project did not declare and the FMU's declarations gave (none ``other``)."""
        return [r for r in self.roles if r.source != "project" and r.role != "other"]

    @property
    def observed_variables(self) -> list[str]:
        """FMU outputs of the observed signals, in order."""
        return [s.variable for s in self.observed]

    @property
    def observed_stages(self) -> list[int]:
        """Stage index of every observed signal."""
        return [s.stage for s in self.observed]

    def inputs_with_role(self, *roles: str) -> list[str]:
        """FMU inputs of the given roles, in declaration order."""
        return [name for name, r in self.input_roles.items() if r in roles]

    def outputs_with_role(self, *roles: str) -> list[str]:
        """FMU outputs of the given roles, in declaration order."""
        return [name for name, r in self.output_roles.items() if r in roles]

    def assign_stages(self, y_wb: np.ndarray, dt: float) -> None:
        """Attach each observed signal that is no stage target to the stage it tracks.

        The stage is the one whose target's white-box prediction, or its rate of change, or
        its running integral, correlates best with the signal's white-box prediction (a
        velocity tracks the position stage it is the rate of). Generic: it uses only the
        simulated signals.

        Parameters
        ----------
        y_wb : ndarray, shape (n, n_observed)
            White-box predictions of the observed signals, columns as :attr:`observed`.
        dt : float
            Sample time [s].
        """
        targets = [j for j, s in enumerate(self.observed) if s.is_target]
        for j, sig in enumerate(self.observed):
            if sig.is_target:
                continue
            best, stage = -1.0, sig.stage
            for t in targets:
                y = y_wb[:, t]
                for candidate in (y, np.gradient(y, dt), np.cumsum(y) * dt):
                    score = abs(_correlation(y_wb[:, j], candidate))
                    if score > best:
                        best, stage = score, self.observed[t].stage
            self.observed[j] = ObservedSignal(**{**sig.__dict__, "stage": stage})


def _declared_unit(signal: Signal | None) -> str:
    """The unit a project declares for a signal (empty when it declares none)."""
    return signal.unit if signal is not None else ""


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = float(np.sqrt(np.dot(a, a) * np.dot(b, b)))
    return float(np.dot(a, b) / den) if den > 0 else 0.0
