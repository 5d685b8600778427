"""The first hour: the built-in projects on the command line, a starter project for one's own
FMU, and the small things a newcomer meets first (demo's effect check, synth's effect list,
the fmpy snippet of docs/bench.md)."""

from __future__ import annotations

import re
from pathlib import Path

import click
import pytest
from click.testing import CliRunner, Result

from fmu_greybox.cli import main
from fmu_greybox.errors import ConfigError
from fmu_greybox.model.store import load_model
from fmu_greybox.project.config import load_config
from fmu_greybox.resources import DATA_DIR, builtin_projects

ROOT = Path(__file__).resolve().parents[1]


def cli(*args: object) -> Result:
    return CliRunner().invoke(main, [str(a) for a in args])


def help_texts(group: click.Group = main, prefix: tuple[str, ...] = ()) -> dict[str, str]:
    """``--help`` of every command and group, by its command line."""
    texts = {" ".join(prefix) or "fmu-greybox": cli(*prefix, "--help").output}
    for name, command in group.commands.items():
        if isinstance(command, click.Group):
            texts |= help_texts(command, (*prefix, name))
        else:
            texts[" ".join((*prefix, name))] = cli(*prefix, name, "--help").output
    return texts


def test_every_packaged_project_file_is_a_built_in_project() -> None:
    projects = builtin_projects()
    packaged = sorted((DATA_DIR / "bench_configs").glob("*.toml"))
    assert list(projects.values()) == packaged
    assert set(projects) >= {"builtin:hydraulic_actuator", "builtin:positioner"}
    for name, path in projects.items():
        assert load_config(name) == load_config(path)


def test_a_missing_or_unknown_project_names_the_built_ins(tmp_path: Path) -> None:
    names = ", ".join(builtin_projects())
    with pytest.raises(ConfigError) as missing:
        load_config(tmp_path / "nope.toml")
    assert str(missing.value) == (
        f"{tmp_path / 'nope.toml'}: no such project file; the built-in projects are {names}"
    )
    with pytest.raises(ConfigError, match=f"no built-in project 'builtin:hydraulic'; .* {names}$"):
        load_config("builtin:hydraulic")
    for command in ("diagnose", "train", "validate", "campaign"):
        extra = {"validate": ["--model", tmp_path], "campaign": ["rec.csv"]}.get(command, [])
        result = cli(command, "hydraulic_actuator.toml", *extra)
        assert result.exit_code == 1, (command, result.output)
        assert "hydraulic_actuator.toml: no such project file" in result.stderr
        assert names in result.stderr


def test_every_help_example_names_only_what_the_package_carries() -> None:
    """No example names a checkout path; every ``builtin:`` name in them resolves."""
    from fmu_greybox.fmi.builtin import BUILTIN_MODELS

    known = {*builtin_projects(), *(f"builtin:{m}" for m in BUILTIN_MODELS)}
    texts = help_texts()
    used = set()
    for command, text in texts.items():
        assert "bench_configs" not in text and ".toml" not in text, command
        used |= set(re.findall(r"builtin:\w+", text))
    assert used <= known
    assert "builtin:hydraulic_actuator" in used
    for command in ("diagnose", "train", "validate", "campaign"):
        assert "builtin:hydraulic_actuator" in texts[command], command


def test_train_runs_on_the_built_in_project_away_from_the_checkout(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert cli("-q", "synth", "--duration", 2, "--out", "rec.csv").exit_code == 0
    result = cli(
        "-q",
        "train",
        "builtin:hydraulic_actuator",
        "--recording",
        "rec.csv",
        "--inducing",
        10,
        "--max-iter",
        3,
        "--out",
        "model",
    )
    assert result.exit_code == 0, result.output
    model = load_model(tmp_path / "model")
    assert model.config.name == "hydraulic_actuator"
    assert [s.name for s in model.config.stages] == ["EHV", "RAM", "ITFV"]
