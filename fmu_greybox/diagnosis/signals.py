"""What each FMU input and output is, physically, and which recorded signals observe the FMU.

Roles come from the project's signals first (``role`` in the config) and, for FMU variables the
project does not mention, from the units the FMU declares (``m/s`` is a velocity, ``m3/s`` a flow,
``Pa`` a pressure, ...). Nothing here knows any particular model's variable names.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fmu_greybox.data.recording import Recording, normalise_unit
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.project.config import ROLE_UNITS, ProjectConfig

#: Roles that a declared unit alone identifies (dimensionless units identify nothing).
_UNIT_ROLES: dict[str, str] = {
    normalise_unit(unit): role
    for role, units in ROLE_UNITS.items()
    if role not in ("command", "other")
    for unit in units
}


def role_from_unit(unit: str) -> str:
    """The physical role a unit implies (``"other"`` when it implies none).

    Examples
    --------
    >>> role_from_unit("m3/s"), role_from_unit("N"), role_from_unit("1")
    ('flow', 'force', 'other')
    """
    return _UNIT_ROLES.get(normalise_unit(unit), "other") if unit else "other"


def noise_level(x: np.ndarray) -> float:
    """Standard deviation of a signal's white sensor noise, from its high-frequency content.

    Robust and model-free: the median absolute deviation of the second differences divided by
    ``sqrt(6)`` (a second difference of white noise of variance s^2 has variance 6 s^2), scaled
    to a standard deviation. Smooth signal content barely contributes at usual sample rates.

    Parameters
    ----------
    x : ndarray, shape (n,)

    Returns
    -------
    float
        Estimated noise standard deviation (0 for fewer than 4 samples or a constant signal).
    """
    if x.size < 4:
        return 0.0
    d2 = np.diff(np.asarray(x, dtype=np.float64), 2)
    mad = np.median(np.abs(d2 - np.median(d2)))
    return float(1.4826 * mad / np.sqrt(6.0))


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
        FMU variable -> unit (the FMU's declaration).
    input_columns : dict[str, str]
        FMU input -> recorded column, for recorded inputs.
    input_stage : dict[str, int]
        FMU input -> index of the first stage that lists it among its inputs (inputs no stage
        lists are absent).
    observed : list of ObservedSignal
        Stage targets in chain order, then the other recorded signals mapped to FMU outputs.
    stage_names : list of str
        Stage names in chain order.
    """

    input_roles: dict[str, str]
    output_roles: dict[str, str]
    units: dict[str, str]
    input_columns: dict[str, str]
    input_stage: dict[str, int]
    observed: list[ObservedSignal]
    stage_names: list[str]

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

        def role(name: str) -> str:
            sig = by_variable.get(name)
            return sig.role if sig is not None else role_from_unit(variables[name].unit)

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
            input_roles={name: role(name) for name in inputs},
            output_roles={name: role(name) for name in outputs},
            units={v.name: v.unit for v in reals},
            input_columns={k: v for k, v in columns.items() if v in recording.signals},
            input_stage=input_stage,
            observed=observed,
            stage_names=[s.name for s in config.stages],
        )

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


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = float(np.sqrt(np.dot(a, a) * np.dot(b, b)))
    return float(np.dot(a, b) / den) if den > 0 else 0.0
