"""The project file: which white-box FMU, which recordings, which stages, which GP settings.

A TOML file, validated on load; every error names the field and says how to mend it. The
project describes any white-box FMU, not only the reference actuator. See ``docs/config.md``
for the field-by-field reference and ``bench_configs/hydraulic_actuator.toml`` (on the command
line ``builtin:hydraulic_actuator``) for a full example.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from fmu_greybox.errors import ConfigError, UnitMismatchError
from fmu_greybox.resources import builtin_projects, project_path
from fmu_greybox.suggest import did_you_mean
from fmu_greybox.units import normalise_unit

FORMAT_VERSION = 1

#: Signal roles and the units each accepts (normalised spellings).
ROLE_UNITS: dict[str, tuple[str, ...]] = {
    "current": ("A", "mA", "uA"),
    "voltage": ("V", "mV"),
    "position": ("m", "mm", "um", "rad", "deg"),
    "velocity": ("m/s", "mm/s", "rad/s", "deg/s"),
    "pressure": ("Pa", "kPa", "MPa", "bar", "psi"),
    "force": ("N", "kN", "N.m"),
    "flow": ("m3/s", "l/min", "L/min", "cm3/s"),
    "temperature": ("K", "degC"),
    "command": ("1", ""),
    "other": (),
}

TARGET_MODES = ("residual", "increment", "output")
#: Target setting that lets training choose residual or increment per stage.
AUTO = "auto"
#: Where training takes the earlier stages' outputs in a stage's features from.
FEED_SOURCES = ("recorded", "free_run")
INDUCING_METHODS = ("equispaced", "kmeans", "greedy")
#: What a stage can ship, in the order of preference between equally good parts: fewer
#: additions first, physics before data (:mod:`fmu_greybox.workflow.parts`).
STAGE_PARTS = ("white-box", "terms", "terms+correctors", "correctors")
#: A stage's ``ship`` setting: the part the held-out comparison chooses, or one named.
BEST = "best"


def unit_suits_role(unit: str, role: str) -> bool:
    """Whether ``unit`` is one of the units :data:`ROLE_UNITS` accepts for ``role`` (any unit
    suits ``other``).

    Examples
    --------
    >>> unit_suits_role("bar", "pressure"), unit_suits_role("Pa", "force")
    (True, False)
    """
    accepted = ROLE_UNITS[role]
    return not accepted or normalise_unit(unit) in {normalise_unit(u) for u in accepted}


@dataclass(frozen=True)
class Signal:
    """A recorded signal and the FMU variable it corresponds to.

    Attributes
    ----------
    name : str
        Name used in the project (stage definitions refer to it).
    column : str
        Column name in the recordings.
    variable : str
        FMU variable name (input or output).
    role : str
        Physical role, one of :data:`ROLE_UNITS`.
    unit : str
        Unit of the recorded column; ``""`` where the project gives none (allowed only where
        the FMU declares none: then no unit is checked or converted).
    """

    name: str
    column: str
    variable: str
    role: str
    unit: str


@dataclass(frozen=True)
class StageConfig:
    """One stage of the autoregressive chain.

    Attributes
    ----------
    name : str
        Stage name (e.g. ``"EHV"``).
    target : str
        Signal recorded at this stage's output.
    whitebox_output : str
        FMU output predicting the same quantity.
    inputs : tuple of str
        Exogenous input signals.
    feeds_from : tuple of str
        Earlier stages whose outputs feed this one.
    lags : int
        Number of own previous outputs fed back (>= 1).
    target_mode : str or None
        What this stage's corrector learns (overrides ``[gp] target``); one of
        :data:`TARGET_MODES` or :data:`AUTO`.
    feed_rates : bool
        Also feed the rates of change of the feeding stages' outputs and of their residuals
        to the white-box (e.g. a pressure stage fed by a position stage sees the velocity
        and the velocity error).
    differences : int
        Also feed the last ``differences`` step changes of each of the stage's inputs, of its
        white-box output and of each feeding stage's output (0: none).
    ship : str
        What the stage ships: :data:`BEST` (training's comparison of the parts chooses) or one
        of :data:`STAGE_PARTS` (e.g. ``"terms"``: the named terms, no corrector).
    """

    name: str
    target: str
    whitebox_output: str
    inputs: tuple[str, ...]
    feeds_from: tuple[str, ...]
    lags: int = 1
    target_mode: str | None = None
    feed_rates: bool = False
    differences: int = 0
    ship: str = BEST


@dataclass(frozen=True)
class GPConfig:
    """Settings of the sparse-GP correctors.

    Attributes
    ----------
    inducing : int
        Number of inducing points per stage.
    inducing_method : str
        ``"equispaced"`` (paper), ``"kmeans"`` or ``"greedy"``.
    max_iter : int
        Cap on optimiser iterations.
    target : str
        ``"residual"`` (recorded minus white-box), ``"increment"`` (its step change),
        ``"output"`` (the recorded output) or ``"auto"`` (residual or increment per stage, by a
        free run on the tail of the training rows).
    feeds : str
        Where the earlier stages' outputs in a stage's training features come from:
        ``"recorded"`` (teacher forcing) or ``"free_run"`` (the earlier stages' own free run
        over the training rows, as the stage will see them when running).
    max_train_samples : int
        Training rows used per stage at most (evenly thinned beyond that); the calibration's
        halves use half as many at most.
    optimise_rows : int
        Rows the hyperparameters of a fit that only chooses (a stage's candidate targets, the
        comparison of the parts) are optimised on at most (evenly thinned beyond that; its
        posterior is then conditioned on every row: :class:`~fmu_greybox.gp.SparseGPR`'s
        ``optimise_rows``). The correctors that ship and the halves that calibrate their σ
        are optimised on every training row.
    seed : int
        Seed of every random choice in training.
    """

    inducing: int = 300
    inducing_method: str = "equispaced"
    max_iter: int = 200
    target: str = "residual"
    feeds: str = "recorded"
    max_train_samples: int = 30000
    optimise_rows: int = 5000
    seed: int = 0


@dataclass(frozen=True)
class Criteria:
    """Acceptance limits of one stage (``[acceptance]``; ``docs/config.md`` says why each
    default). ``None`` leaves a criterion unchecked (``false`` in the file).

    Attributes
    ----------
    max_nrmse : float or None
        Largest grey-box RMSE on the validation rows, divided by the standard deviation of the
        training target.
    band : tuple of float
        ``(low, high)`` [Hz]: the frequencies the frequency-domain criteria look at (only
        those where the recording's estimate can be trusted, see
        :mod:`fmu_greybox.evidence.spectra`).
    max_gain_error_db : float or None
        Largest RMS gain error against the recording in the band [dB].
    max_phase_error_deg : float or None
        Largest RMS phase error against the recording in the band [deg].
    min_coherence : float or None
        Smallest median coherence of the grey-box's output with the recorded output in the
        band.
    coverage95, coverage68 : tuple of float or None
        ``(low, high)`` shares of the validation rows that must lie inside ±1.96σ and ±1σ.
    input : str or None
        Signal the stage's frequency response is taken from (``None``: the first input of the
        first stage).
    """

    max_nrmse: float | None = 0.1
    band: tuple[float, float] = (0.0, 50.0)
    max_gain_error_db: float | None = 2.0
    max_phase_error_deg: float | None = 15.0
    min_coherence: float | None = 0.6
    coverage95: tuple[float, float] | None = (0.90, 0.99)
    coverage68: tuple[float, float] | None = None
    input: str | None = None


@dataclass(frozen=True)
class AcceptanceConfig:
    """The project's acceptance criteria: defaults, and per stage where a stage differs.

    Attributes
    ----------
    default : Criteria
        The ``[acceptance]`` table's own values (each field's default where not given).
    stages : dict[str, Criteria]
        Stage -> its criteria, for the stages with an ``[acceptance.NAME]`` table (the
        default's values where that table gives none).
    """

    default: Criteria = field(default_factory=Criteria)
    stages: dict[str, Criteria] = field(default_factory=dict)

    def for_stage(self, name: str) -> Criteria:
        """The criteria of stage ``name``."""
        return self.stages.get(name, self.default)


@dataclass(frozen=True)
class ProjectConfig:
    """A validated project file.

    Attributes
    ----------
    path : Path or None
        File it was read from (relative paths in it are relative to its folder).
    name : str
        Project name.
    fmu : str
        White-box FMU: a path or ``builtin:NAME``.
    step : float or None
        Communication step [s]; ``None`` means the recordings' sample time.
    parameters : dict[str, float]
        FMU parameter overrides.
    fixed_inputs : dict[str, float]
        FMU inputs held constant (not recorded).
    recording : Path or None
        Default recording.
    time_column : str
        Time column of the recordings.
    resample : float or None
        Resample recordings onto this step [s] (only when set).
    signals : dict[str, Signal]
        Signals by project name.
    stages : tuple of StageConfig
        Stages in autoregressive order.
    gp : GPConfig
        Corrector settings.
    train_fraction : float
        Leading share of a recording used for training; the rest is held out.
    acceptance : AcceptanceConfig
        What a validated grey-box must meet.

    The typed fields are the only source of truth: :meth:`to_dict` derives the TOML tables from
    them (stored in model folders, read back with :func:`parse_config`), and a changed project
    is made with :func:`dataclasses.replace`.
    """

    path: Path | None
    name: str
    fmu: str
    step: float | None
    parameters: dict[str, float]
    fixed_inputs: dict[str, float]
    recording: Path | None
    time_column: str
    resample: float | None
    signals: dict[str, Signal]
    stages: tuple[StageConfig, ...]
    gp: GPConfig = field(default_factory=GPConfig)
    train_fraction: float = 0.95
    acceptance: AcceptanceConfig = field(default_factory=AcceptanceConfig)

    def to_dict(self) -> dict[str, Any]:
        """The project as TOML tables, such that ``parse_config(c.to_dict(), c.path) == c``.

        Returns
        -------
        dict
            ``name``, ``whitebox``, ``recording``, ``signals``, ``stages``, ``gp``, ``split`` and
            ``acceptance`` tables (unset optional values left out, as TOML has no null; an
            unchecked criterion as ``false``).
        """
        whitebox = {"fmu": self.fmu, "step": self.step}
        whitebox |= {"parameters": dict(self.parameters), "fixed_inputs": dict(self.fixed_inputs)}
        recording = {
            "path": str(self.recording) if self.recording is not None else None,
            "time_column": self.time_column,
            "resample": self.resample,
        }
        return {
            "format_version": FORMAT_VERSION,
            "name": self.name,
            "whitebox": _without_none(whitebox),
            "recording": _without_none(recording),
            "signals": {
                n: _fields(s, skip=("name",) if s.unit else ("name", "unit"))
                for n, s in self.signals.items()
            },
            "stages": [_fields(s) for s in self.stages],
            "gp": _fields(self.gp),
            "split": {"train_fraction": self.train_fraction},
            "acceptance": _acceptance_table(self.acceptance),
        }

    def stage(self, name: str) -> StageConfig:
        """The stage called ``name``."""
        for stage in self.stages:
            if stage.name == name:
                return stage
        raise ConfigError(f"no stage {name!r}", field="stages", path=_p(self.path))

    def resolve_path(self, value: str | Path) -> Path:
        """A path from the file, made absolute relative to the file's folder."""
        p = Path(value)
        return p if p.is_absolute() or self.path is None else self.path.parent / p

    def check_against_fmu(self, archive: Any) -> None:
        """Check signals and stages against what the white-box FMU declares.

        Raises
        ------
        ConfigError
            A signal's variable or a stage's white-box output is not declared by the FMU, or a
            parameter / fixed input is unknown.
        UnitMismatchError
            A signal's unit differs from the FMU variable's unit.
        """
        known = archive.variables
        where = _p(self.path)
        for sig in self.signals.values():
            var = known.get(sig.variable)
            if var is None:
                raise ConfigError(
                    f"FMU {archive.path.name} has no variable {sig.variable!r}"
                    + did_you_mean(sig.variable, known),
                    field=f"signals.{sig.name}.variable",
                    path=where,
                )
            if var.unit and not sig.unit:
                raise ConfigError(
                    f"signal {sig.name!r} gives no unit but FMU variable {sig.variable!r} is in "
                    f"{var.unit!r}; add unit = {var.unit!r} (the unit of the recorded column)",
                    field=f"signals.{sig.name}.unit",
                    path=where,
                )
            if var.unit and sig.unit and normalise_unit(var.unit) != normalise_unit(sig.unit):
                raise UnitMismatchError(
                    f"signal {sig.name!r} is declared in {sig.unit!r} but FMU variable "
                    f"{sig.variable!r} is in {var.unit!r}; record it in {var.unit!r} or fix the "
                    "unit",
                    field=f"signals.{sig.name}.unit",
                    path=where,
                )
        for stage in self.stages:
            var = known.get(stage.whitebox_output)
            if var is None or var.causality != "output":
                raise ConfigError(
                    f"{stage.whitebox_output!r} is not an output of {archive.path.name}"
                    + did_you_mean(stage.whitebox_output, archive.outputs),
                    field=f"stages.{stage.name}.whitebox_output",
                    path=where,
                )
        for table, names in (
            ("whitebox.parameters", self.parameters),
            ("whitebox.fixed_inputs", self.fixed_inputs),
        ):
            for name in names:
                if name not in known:
                    raise ConfigError(
                        f"FMU {archive.path.name} has no variable {name!r}"
                        + did_you_mean(name, known),
                        field=f"{table}.{name}",
                        path=where,
                    )

    def input_mapping(self) -> dict[str, str]:
        """FMU input variable -> recorded column, for the signals that feed FMU inputs."""
        return {s.variable: s.column for s in self.signals.values() if s.variable != s.column}


# ---------------------------------------------------------------------------- loading
def load_config(path: str | Path) -> ProjectConfig:
    """Read and validate a project file.

    Parameters
    ----------
    path : str or Path
        The TOML file, or ``builtin:NAME`` for a project the package carries
        (:func:`fmu_greybox.resources.builtin_projects`, e.g. ``builtin:hydraulic_actuator``).

    Returns
    -------
    ProjectConfig

    Raises
    ------
    ConfigError
        For a missing file (the message lists the built-in projects), an unknown built-in
        name, an unreadable file, invalid TOML, or any invalid field (the message names it).
    """
    path = project_path(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise ConfigError(
            "no such project file; the built-in projects are " + ", ".join(builtin_projects()),
            path=str(path),
        ) from exc
    except OSError as exc:
        raise ConfigError(f"cannot read the project file: {exc.strerror}", path=str(path)) from exc
    except UnicodeDecodeError as exc:
        raise ConfigError("the project file is not UTF-8 text", path=str(path)) from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"invalid TOML: {exc}", path=str(path)) from exc
    return parse_config(raw, path)


def parse_config(raw: Mapping[str, Any], path: Path | None = None) -> ProjectConfig:
    """Validate a project already parsed from TOML (see :func:`load_config`)."""
    reader = _Reader(path)
    reader.keys(
        raw,
        "",
        {
            "format_version",
            "name",
            "whitebox",
            "recording",
            "signals",
            "stages",
            "gp",
            "split",
            "acceptance",
        },
    )
    version = reader.get(raw, "format_version", int, FORMAT_VERSION)
    if version != FORMAT_VERSION:
        reader.fail(
            "format_version",
            f"version {version} is not supported; this tool reads version {FORMAT_VERSION}",
        )
    whitebox = reader.table(raw, "whitebox", required=True)
    reader.keys(whitebox, "whitebox", {"fmu", "step", "parameters", "fixed_inputs"})
    recording = reader.table(raw, "recording")
    reader.keys(recording, "recording", {"path", "time_column", "resample"})
    signals = _signals(reader, reader.table(raw, "signals", required=True))
    stages = _stages(reader, raw.get("stages"), signals)
    split = reader.table(raw, "split")
    reader.keys(split, "split", {"train_fraction"})
    step = reader.get(whitebox, "step", float, None, "whitebox.")
    if step is not None:
        reader.positive("whitebox.step", step)
    resample = reader.get(recording, "resample", float, None, "recording.")
    if resample is not None:
        reader.positive("recording.resample", resample)
    rec_path = reader.get(recording, "path", str, None, "recording.")
    train_fraction = reader.get(split, "train_fraction", float, 0.95, "split.")
    if not 0.0 < train_fraction < 1.0:
        reader.fail(
            "split.train_fraction",
            f"{train_fraction} is not between 0 and 1 "
            "(exclusive); e.g. 0.95 holds out the last 5 %",
        )
    config = ProjectConfig(
        path=path,
        name=reader.get(raw, "name", str, path.stem if path else "project"),
        fmu=reader.get(whitebox, "fmu", str, None, "whitebox.", required=True),
        step=step,
        parameters=reader.numbers(whitebox, "parameters", "whitebox."),
        fixed_inputs=reader.numbers(whitebox, "fixed_inputs", "whitebox."),
        recording=None,
        time_column=reader.get(recording, "time_column", str, "time", "recording."),
        resample=resample,
        signals=signals,
        stages=stages,
        gp=_gp(reader, reader.table(raw, "gp")),
        train_fraction=train_fraction,
        acceptance=_acceptance(reader, reader.table(raw, "acceptance"), signals, stages),
    )
    sample_time = resample if resample is not None else step
    if sample_time is not None:
        check_bands(config.acceptance, sample_time, path)
    if rec_path is not None:
        object.__setattr__(config, "recording", config.resolve_path(rec_path))
    return config


def check_bands(acceptance: AcceptanceConfig, dt: float, path: Path | str | None) -> None:
    """Every acceptance band must start below the Nyquist frequency of the sample time ``dt``
    [s]: above it a recording holds no frequency to check.

    Raises
    ------
    ConfigError
        Naming ``acceptance.band`` (or ``acceptance.NAME.band``), the Nyquist frequency and
        the sample time.
    """
    nyquist = 0.5 / dt
    tables = {"acceptance": acceptance.default}
    tables |= {f"acceptance.{name}": c for name, c in acceptance.stages.items()}
    for where, criteria in tables.items():
        low, high = criteria.band
        if low >= nyquist:
            raise ConfigError(
                f"[{low:g}, {high:g}] Hz lies above {nyquist:g} Hz, the Nyquist frequency of "
                f"the sample time {dt:g} s: a recording holds no frequency there to check. "
                f"Give a band below {nyquist:g} Hz",
                field=f"{where}.band",
                path=str(path) if path else None,
            )


def _signals(reader: _Reader, table: Mapping[str, Any]) -> dict[str, Signal]:
    if not table:
        reader.fail(
            "signals",
            "no signals declared; add one [signals.NAME] table per recorded "
            "signal, with role and unit ('fmu-greybox init FMU' writes them all)",
        )
    signals: dict[str, Signal] = {}
    for name, entry in table.items():
        where = f"signals.{name}"
        if not isinstance(entry, Mapping):
            reader.fail(
                where,
                "must be a table with a role and (where the FMU declares one) a unit, e.g. "
                '{ role = "pressure", unit = "Pa" }',
            )
        reader.keys(entry, where, {"role", "unit", "column", "variable"})
        role = reader.get(entry, "role", str, None, where + ".", required=True)
        if role not in ROLE_UNITS:
            reader.fail(
                where + ".role",
                f"unknown role {role!r}"
                + did_you_mean(role, ROLE_UNITS)
                + f"; roles: {', '.join(ROLE_UNITS)}",
            )
        unit = reader.get(entry, "unit", str, "", where + ".")
        accepted = ROLE_UNITS[role]
        if unit and not unit_suits_role(unit, role):
            reader.fail(
                where + ".unit",
                f"{unit!r} is not a unit of a {role} "
                f"(accepted: {', '.join(repr(u) for u in accepted)})",
            )
        signals[name] = Signal(
            name=name,
            column=reader.get(entry, "column", str, name, where + "."),
            variable=reader.get(entry, "variable", str, name, where + "."),
            role=role,
            unit=unit,
        )
        for other in list(signals)[:-1]:
            if signals[other].column == signals[name].column:
                reader.fail(
                    where + ".column",
                    f"signals {other!r} and {name!r} both read column {signals[name].column!r}; "
                    'a column is one signal: give one of them its own column = "..." (or '
                    "remove one)",
                )
    return signals


def _stages(reader: _Reader, items: Any, signals: Mapping[str, Signal]) -> tuple[StageConfig, ...]:
    if not isinstance(items, list) or not items:
        reader.fail(
            "stages",
            "no stages; add [[stages]] tables in autoregressive order, each "
            "with name, target, inputs and feeds_from",
        )
    stages: list[StageConfig] = []
    for i, entry in enumerate(items):
        where = f"stages[{i}]"
        if not isinstance(entry, Mapping):
            reader.fail(where, "must be a table ([[stages]])")
        reader.keys(
            entry,
            where,
            {
                "name",
                "target",
                "whitebox_output",
                "inputs",
                "feeds_from",
                "lags",
                "target_mode",
                "feed_rates",
                "differences",
                "ship",
            },
        )
        name = reader.get(entry, "name", str, None, where + ".", required=True)
        target = reader.get(entry, "target", str, None, where + ".", required=True)
        if target not in signals:
            reader.fail(
                where + ".target",
                f"{target!r} is not a declared signal" + did_you_mean(target, signals),
            )
        inputs = tuple(reader.strings(entry, "inputs", where + "."))
        for inp in inputs:
            if inp not in signals:
                reader.fail(
                    where + ".inputs",
                    f"{inp!r} is not a declared signal" + did_you_mean(inp, signals),
                )
        lags = reader.get(entry, "lags", int, 1, where + ".")
        if not 1 <= lags <= 10:
            reader.fail(where + ".lags", f"{lags} is outside 1..10")
        mode = reader.get(entry, "target_mode", str, None, where + ".")
        if mode is not None and mode not in (*TARGET_MODES, AUTO):
            reader.fail(
                where + ".target_mode", f"{mode!r} is not one of {', '.join((*TARGET_MODES, AUTO))}"
            )
        differences = reader.get(entry, "differences", int, 0, where + ".")
        if not 0 <= differences <= 10:
            reader.fail(where + ".differences", f"{differences} is outside 0..10")
        ship = reader.get(entry, "ship", str, BEST, where + ".")
        if ship not in (BEST, *STAGE_PARTS):
            reader.fail(
                where + ".ship",
                f"{ship!r} is not one of {', '.join((BEST, *STAGE_PARTS))}"
                + did_you_mean(ship, (BEST, *STAGE_PARTS)),
            )
        stages.append(
            StageConfig(
                name=name,
                target=target,
                whitebox_output=reader.get(
                    entry, "whitebox_output", str, signals[target].variable, where + "."
                ),
                inputs=inputs,
                feeds_from=tuple(reader.strings(entry, "feeds_from", where + ".")),
                lags=lags,
                target_mode=mode,
                feed_rates=reader.get(entry, "feed_rates", bool, False, where + "."),
                differences=differences,
                ship=ship,
            )
        )
    _check_order(reader, stages)
    return tuple(stages)


def _check_order(reader: _Reader, stages: list[StageConfig]) -> None:
    """Unique names, known feeds, no cycle, and every feed listed before its consumer."""
    index: dict[str, int] = {}
    for i, stage in enumerate(stages):
        if stage.name in index:
            reader.fail(f"stages[{i}].name", f"stage name {stage.name!r} is used twice")
        index[stage.name] = i
    for i, stage in enumerate(stages):
        for feed in stage.feeds_from:
            if feed not in index:
                reader.fail(
                    f"stages[{i}].feeds_from", f"no stage {feed!r}" + did_you_mean(feed, index)
                )
            if feed == stage.name:
                reader.fail(
                    f"stages[{i}].feeds_from",
                    f"stage {feed!r} cannot feed itself; its "
                    "own previous outputs are fed back through 'lags'",
                )
    cycle = _find_cycle({s.name: s.feeds_from for s in stages})
    if cycle:
        reader.fail(
            "stages",
            "the stages feed each other in a cycle: "
            + " -> ".join(cycle)
            + "; an autoregressive chain needs an order (merge the stages in the cycle "
            "into one, as the paper does with RAM*)",
        )
    for i, stage in enumerate(stages):
        for feed in stage.feeds_from:
            if index[feed] > i:
                reader.fail(
                    f"stages[{i}].feeds_from",
                    f"stage {stage.name!r} feeds from "
                    f"{feed!r}, which is listed after it; list the stages in "
                    "autoregressive order",
                )


def _find_cycle(graph: Mapping[str, tuple[str, ...]]) -> list[str]:
    """A cycle in ``consumer -> feeds`` edges as a list of names (first repeated last)."""
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(node: str) -> list[str]:
        state[node] = 1
        path.append(node)
        for nxt in graph.get(node, ()):
            if state.get(nxt) == 1:
                return [*path[path.index(nxt) :], nxt]
            if nxt not in state:
                found = visit(nxt)
                if found:
                    return found
        state[node] = 2
        path.pop()
        return []

    for node in graph:
        if node not in state:
            found = visit(node)
            if found:
                return found
    return []


def _gp(reader: _Reader, table: Mapping[str, Any]) -> GPConfig:
    reader.keys(
        table,
        "gp",
        {
            "inducing",
            "inducing_method",
            "max_iter",
            "target",
            "feeds",
            "max_train_samples",
            "optimise_rows",
            "seed",
            "kernel",
        },
    )
    kernel = reader.get(table, "kernel", str, "se_ard", "gp.")
    if kernel != "se_ard":
        reader.fail(
            "gp.kernel",
            f'{kernel!r} is not available; use "se_ard" (squared '
            "exponential with one length-scale per input)",
        )
    gp = GPConfig(
        inducing=reader.get(table, "inducing", int, GPConfig.inducing, "gp."),
        inducing_method=reader.get(table, "inducing_method", str, GPConfig.inducing_method, "gp."),
        max_iter=reader.get(table, "max_iter", int, GPConfig.max_iter, "gp."),
        target=reader.get(table, "target", str, GPConfig.target, "gp."),
        feeds=reader.get(table, "feeds", str, GPConfig.feeds, "gp."),
        max_train_samples=reader.get(
            table, "max_train_samples", int, GPConfig.max_train_samples, "gp."
        ),
        optimise_rows=reader.get(table, "optimise_rows", int, GPConfig.optimise_rows, "gp."),
        seed=reader.get(table, "seed", int, GPConfig.seed, "gp."),
    )
    if gp.inducing < 1:
        reader.fail("gp.inducing", f"{gp.inducing} must be at least 1 (the paper uses < 400)")
    if gp.max_iter < 0:
        reader.fail("gp.max_iter", f"{gp.max_iter} must be >= 0")
    if gp.max_train_samples < 10:
        reader.fail("gp.max_train_samples", f"{gp.max_train_samples} must be at least 10")
    if gp.optimise_rows < gp.inducing:
        reader.fail(
            "gp.optimise_rows",
            f"{gp.optimise_rows} is fewer than gp.inducing = {gp.inducing}; the hyperparameters "
            "need at least as many rows as inducing points",
        )
    if gp.inducing_method not in INDUCING_METHODS:
        reader.fail(
            "gp.inducing_method",
            f"{gp.inducing_method!r} is not one of {', '.join(INDUCING_METHODS)}",
        )
    if gp.target not in (*TARGET_MODES, AUTO):
        reader.fail("gp.target", f"{gp.target!r} is not one of {', '.join((*TARGET_MODES, AUTO))}")
    if gp.feeds not in FEED_SOURCES:
        reader.fail("gp.feeds", f"{gp.feeds!r} is not one of {', '.join(FEED_SOURCES)}")
    return gp


def _acceptance(
    reader: _Reader,
    table: Mapping[str, Any],
    signals: Mapping[str, Signal],
    stages: tuple[StageConfig, ...],
) -> AcceptanceConfig:
    names = [s.name for s in stages]
    criteria = [f.name for f in fields(Criteria)]
    reader.keys(table, "acceptance", {*criteria, *names})
    default = _criteria(reader, table, "acceptance", Criteria(), signals)
    per_stage = {}
    for name in names:
        if name in table:
            where = f"acceptance.{name}"
            own = reader.table(table, name, prefix="acceptance.")
            reader.keys(own, where, set(criteria))
            per_stage[name] = _criteria(reader, own, where, default, signals)
    return AcceptanceConfig(default=default, stages=per_stage)


def _criteria(
    reader: _Reader,
    table: Mapping[str, Any],
    where: str,
    base: Criteria,
    signals: Mapping[str, Signal],
) -> Criteria:
    """The criteria of one ``[acceptance]`` table, ``base``'s where it gives none."""
    values: dict[str, Any] = {}
    if "input" in table:
        source = values["input"] = reader.get(table, "input", str, None, where + ".")
        if source not in signals:
            reader.fail(
                f"{where}.input",
                f"{source!r} is not a declared signal" + did_you_mean(source, signals),
            )
    for name in ("max_nrmse", "max_gain_error_db", "max_phase_error_deg", "min_coherence"):
        if name in table:
            value = (
                None if table[name] is False else reader.get(table, name, float, None, where + ".")
            )
            if value is not None:
                reader.positive(f"{where}.{name}", value)
            values[name] = value
    if values.get("min_coherence") is not None and values["min_coherence"] > 1.0:
        reader.fail(f"{where}.min_coherence", f"{values['min_coherence']} is above 1")
    if "band" in table:
        values["band"] = reader.interval(table, "band", where + ".", upper=None)
    for name in ("coverage95", "coverage68"):
        if name in table:
            values[name] = (
                None if table[name] is False else reader.interval(table, name, where + ".", 1.0)
            )
    return dataclasses.replace(base, **values)


def _acceptance_table(acceptance: AcceptanceConfig) -> dict[str, Any]:
    """The ``[acceptance]`` table of :meth:`ProjectConfig.to_dict` (unchecked as ``false``)."""

    def table(criteria: Criteria) -> dict[str, Any]:
        limits = {
            f.name: False if value is None else list(value) if isinstance(value, tuple) else value
            for f in fields(criteria)
            if f.name != "input"
            for value in [getattr(criteria, f.name)]
        }
        return _without_none(limits | {"input": criteria.input})

    return table(acceptance.default) | {n: table(c) for n, c in acceptance.stages.items()}


def _without_none(table: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in table.items() if v is not None}


def _fields(item: Any, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    """A frozen settings dataclass as a TOML table (tuples as lists, ``None`` left out)."""
    table = {f.name: getattr(item, f.name) for f in fields(item) if f.name not in skip}
    return _without_none({k: list(v) if isinstance(v, tuple) else v for k, v in table.items()})


def _p(path: Path | None) -> str | None:
    return str(path) if path is not None else None


class _Reader:
    """Typed access to raw TOML tables, failing with the dotted field name."""

    def __init__(self, path: Path | None) -> None:
        self.path = _p(path)

    def fail(self, field_name: str, message: str) -> None:
        raise ConfigError(message, field=field_name, path=self.path)

    def keys(self, table: Mapping[str, Any], where: str, allowed: set[str]) -> None:
        for key in table:
            if key not in allowed:
                name = f"{where}.{key}" if where else key
                self.fail(
                    name,
                    "unknown field"
                    + did_you_mean(key, allowed)
                    + f" (allowed here: {', '.join(sorted(allowed))})",
                )

    def table(
        self, raw: Mapping[str, Any], key: str, required: bool = False, prefix: str = ""
    ) -> Mapping[str, Any]:
        """``raw[key]``, checked to be a table (``prefix``: the dotted path of ``raw``)."""
        value = raw.get(key)
        field_name = prefix + key
        if value is None:
            if required:
                self.fail(field_name, f"missing; add a [{field_name}] table")
            return {}
        if not isinstance(value, Mapping):
            self.fail(field_name, f"must be a table ([{field_name}]), not {type(value).__name__}")
        return value

    def get(
        self,
        table: Mapping[str, Any],
        key: str,
        kind: type,
        default: Any,
        prefix: str = "",
        required: bool = False,
    ) -> Any:
        if key not in table:
            if required:
                self.fail(prefix + key, "missing; this field is required")
            return default
        value = table[key]
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            if abs(value) > _LARGEST_FLOAT:
                self.fail(prefix + key, f"must be a finite number, not {_shown(value)}")
            value = float(value)
        if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
            self.fail(prefix + key, f"must be {_kind_name(kind)}, not {_shown(value)}")
        if kind is float and not math.isfinite(value):
            self.fail(prefix + key, f"must be a finite number, not {value!r}")
        if kind is str and not value.strip():
            self.fail(prefix + key, "must not be empty")
        return value

    def strings(self, table: Mapping[str, Any], key: str, prefix: str) -> list[str]:
        value = table.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            self.fail(
                prefix + key, f'must be a list of names, e.g. ["a", "b"], not {_shown(value)}'
            )
        return list(value)

    def numbers(self, table: Mapping[str, Any], key: str, prefix: str) -> dict[str, float]:
        value = table.get(key, {})
        if not isinstance(value, Mapping):
            self.fail(prefix + key, "must be a table of NAME = number")
        return {name: self.get(value, name, float, None, f"{prefix}{key}.") for name in value}

    def positive(self, field_name: str, value: float) -> None:
        if value <= 0:
            self.fail(field_name, f"{value} must be positive")

    def interval(
        self, table: Mapping[str, Any], key: str, prefix: str, upper: float | None
    ) -> tuple[float, float]:
        """Two numbers ``[low, high]`` with ``0 <= low < high`` (``<= upper`` if given)."""
        value = table[key]
        limit = "" if upper is None else f" <= {upper:g}"
        if (
            not isinstance(value, list)
            or len(value) != 2
            or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
            or not all(math.isfinite(v) for v in value)
        ):
            self.fail(prefix + key, f"must be two numbers [low, high], not {_shown(value)}")
        low, high = float(value[0]), float(value[1])
        if not 0.0 <= low < high or (upper is not None and high > upper):
            self.fail(prefix + key, f"[{low:g}, {high:g}] is not 0 <= low < high{limit}")
        return low, high


#: Largest integer a float field accepts (TOML integers have no size limit in tomllib).
_LARGEST_FLOAT = int(sys.float_info.max)


def _shown(value: Any, limit: int = 60) -> str:
    """``repr(value)``, cut to ``limit`` characters for an error message."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _kind_name(kind: type) -> str:
    return {int: "an integer", float: "a number", str: "a string", bool: "true or false"}.get(
        kind, kind.__name__
    )
