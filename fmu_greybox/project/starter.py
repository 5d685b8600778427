"""A starter project for one's own white-box FMU, written from its model description (``init``).

The project file it writes declares:

- ``[whitebox] fmu``: the FMU, by a path relative to the project file (or its ``builtin:`` name);
- a ``[signals.NAME]`` per FMU input and per Real output, named as the variable, its role read
  the way the diagnosis reads the roles of undeclared variables
  (:func:`~fmu_greybox.project.roles.infer_role`: from the unit, else the description, else
  the name) and its unit the FMU's (left out where the FMU declares none); a role whose accepted
  units do not hold the FMU's unit becomes ``other``;
- a ``[[stages]]`` per output that holds a level, of a role in :data:`STAGE_ROLES` (a velocity or
  a flow is the rate of such a level: the diagnosis reads it as a signal, no stage needed),
  fed by every input, in the FMU's order, feeding from none; an FMU with no such output gets a
  stage per Real output;
- the defaults of ``[gp]``, ``[split]`` and ``[acceptance]``, as comments.

The user then checks the roles and units, orders and connects the stages (``feeds_from``) and
names the recording. The file is checked before it is written: it loads with
:func:`~fmu_greybox.project.config.load_config` and passes
:meth:`~fmu_greybox.project.config.ProjectConfig.check_against_fmu`.
"""

from __future__ import annotations

import json
import os
import re
import textwrap
import tomllib
from dataclasses import fields
from pathlib import Path
from typing import Any

from fmu_greybox.atomic import atomic_write, prepare_output
from fmu_greybox.errors import ConfigError, OutputError
from fmu_greybox.fmi.archive import FmuArchive, FmuVariable, open_fmu, real_outputs
from fmu_greybox.fmi.builtin import PREFIX, resolve_fmu
from fmu_greybox.project.config import (
    Criteria,
    GPConfig,
    ProjectConfig,
    parse_config,
    unit_suits_role,
)
from fmu_greybox.project.roles import VariableRole, infer_role

#: The project file's name in the folder ``init`` writes.
PROJECT_FILE = "project.toml"
#: Roles of the outputs that get a stage: levels, not rates of levels.
STAGE_ROLES = ("position", "pressure", "current", "voltage", "force", "temperature")
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def write_starter(fmu: str | Path, out_dir: str | Path, force: bool = False) -> ProjectConfig:
    """Write ``out_dir/project.toml``, a starter project for ``fmu``.

    Parameters
    ----------
    fmu : str or Path
        The white-box FMU: a path or ``builtin:NAME``.
    out_dir : str or Path
        Folder receiving the project file (made if needed).
    force : bool
        Write over an existing project file.

    Returns
    -------
    ProjectConfig
        The project as written (its ``path`` is the file).

    Raises
    ------
    OutputError
        If the project file exists and ``force`` is false, or its folder cannot be made.
    FmuArchiveError
        If the FMU cannot be found or opened.
    """
    target = Path(out_dir) / PROJECT_FILE
    if target.exists() and not force:
        raise OutputError(
            f"--out {target} exists; edit it, choose another --out, or pass --force to write a "
            "new starter project over it"
        )
    path = resolve_fmu(fmu)
    spec = str(fmu) if str(fmu).startswith(PREFIX) else _relative(path, target.parent)
    with open_fmu(path) as archive:
        text = starter_text(archive, spec)
        config = parse_config(tomllib.loads(text), target.resolve())
        config.check_against_fmu(archive)
    prepare_output(target, "--out")
    with atomic_write(target) as handle:
        handle.write(text)
    return config


def starter_text(archive: FmuArchive, fmu: str) -> str:
    """The starter project file of an FMU (see the module docstring).

    Parameters
    ----------
    archive : FmuArchive
        The opened FMU.
    fmu : str
        What ``[whitebox] fmu`` says: a path relative to the project file, or ``builtin:NAME``.

    Returns
    -------
    str
        TOML text.

    Raises
    ------
    ConfigError
        If the FMU has no Real output (nothing for a stage to correct).
    """
    inputs = [archive.variables[name] for name in archive.inputs]
    outputs = [archive.variables[name] for name in real_outputs(archive)]
    if not outputs:
        raise ConfigError(
            f"FMU {archive.path.name} declares no Real output, so there is nothing to correct; "
            "choose the white-box FMU whose outputs were recorded"
        )
    roles = {v.name: _role(v) for v in (*inputs, *outputs)}
    staged = [v for v in outputs if roles[v.name].role in STAGE_ROLES] or outputs
    lines = [
        *_comment(
            f"fmu-greybox project for {archive.model_name}, written by `fmu-greybox init` from "
            "the FMU's model description. Check every role and unit, put the stages in "
            "autoregressive order and connect them (feeds_from), and name the recording."
        ),
        "# Field reference: docs/config.md",
        "format_version = 1",
        f"name = {_value(archive.model_name)}",
        "",
        "[whitebox]",
        f"fmu = {_value(fmu)}" + ("" if fmu.startswith(PREFIX) else "  # relative to this file"),
        "# step = 0.001  # communication step [s]; default: the recording's sample time",
        "# parameters = { NAME = 1.0 }  # FMU parameter overrides",
        "# fixed_inputs = { NAME = 1.0 }  # FMU inputs that were not recorded",
        "",
        "[recording]",
        '# path = "recording.csv"  # default recording; `--recording FILE` overrides',
        'time_column = "time"',
        "",
        *_comment(
            "One table per FMU input and output: its role (read from the FMU's unit, description "
            "or name) and the unit of the recorded column (the FMU's; none where the FMU declares "
            'none). A column named otherwise than the variable: column = "...".'
        ),
    ]
    for variable in (*inputs, *outputs):
        lines += ["", f"[signals.{_key(variable.name)}]  # {variable.causality}"]
        lines += _signal_lines(variable, roles[variable.name])
    lines += [
        "",
        *_comment(
            f"A stage per output that holds a level ({', '.join(STAGE_ROLES)}), fed by every "
            "input. List them in autoregressive order and connect them: a stage fed by another "
            "names it in feeds_from."
        ),
    ]
    names = [_value(v.name) for v in inputs]
    for variable in staged:
        lines += [
            "",
            "[[stages]]",
            f"name = {_value(variable.name)}",
            f"target = {_value(variable.name)}",
            f"inputs = [{', '.join(names)}]",
            "feeds_from = []",
        ]
    lines += ["", "# The defaults, written out: uncomment a line to change it."]
    lines += _commented_defaults()
    return "\n".join(lines) + "\n"


def _role(variable: FmuVariable) -> VariableRole:
    """The variable's role, ``other`` where its unit is not one of the role's units."""
    found = infer_role(variable)
    if variable.unit and not unit_suits_role(variable.unit, found.role):
        return VariableRole(variable.name, variable.causality, "other", "unit", variable.unit)
    return found


def _signal_lines(variable: FmuVariable, role: VariableRole) -> list[str]:
    """``role`` and ``unit`` lines of one signal, saying where the role was read."""
    if role.role == "other":
        why = "no role found in its unit, description or name: set one if it has one"
    elif role.source == "unit":
        why = f"from its unit {role.evidence!r}"
    else:
        why = f"from the word {role.evidence!r} of its {role.source}"
    lines = [f"role = {_value(role.role)}  # {why}"]
    if variable.unit:
        lines.append(f"unit = {_value(variable.unit)}")
    else:
        lines.append('# unit = "..."  # the FMU declares none; give the recorded unit if known')
    return _comment(variable.description) + lines
    return lines


def _commented_defaults() -> list[str]:
    """``[gp]``, ``[split]`` and ``[acceptance]`` with their default values, commented out."""
    gp = GPConfig()
    train_fraction = next(f.default for f in fields(ProjectConfig) if f.name == "train_fraction")
    criteria = Criteria()
    lines = ["# [gp]"]
    lines += [f"# {f.name} = {_value(getattr(gp, f.name))}" for f in fields(gp)]
    lines += ["", "# [split]", f"# train_fraction = {_value(train_fraction)}"]
    lines += ["", "# [acceptance]  # what `validate` checks; false leaves a criterion unchecked"]
    lines += [
        f"# {f.name} = {_value(getattr(criteria, f.name))}"
        for f in fields(criteria)
        if f.name != "input"
    ]
    return lines


def _comment(text: str) -> list[str]:
    """``text`` as comment lines of at most 100 characters (none for blank text)."""
    return ["# " + line for line in textwrap.wrap(" ".join(text.split()), width=98)]


def _relative(path: Path, folder: Path) -> str:
    """``path`` relative to ``folder`` (both made absolute), as the project file writes it."""
    return Path(os.path.relpath(path.resolve(), folder.resolve())).as_posix()


def _key(name: str) -> str:
    """A TOML key: bare where it can be, else quoted."""
    return name if _BARE_KEY.fullmatch(name) else _value(name)


def _value(value: Any) -> str:
    """A TOML value of a string, number, Boolean, tuple or ``None`` (``false``: unchecked)."""
    if value is None or isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, tuple | list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    return repr(value)
