"""The first hour: the built-in projects on the command line, a starter project for one's own
FMU, and the small things a newcomer meets first (demo's effect check, synth's effect list,
the fmpy snippet of docs/bench.md)."""

from __future__ import annotations

import contextlib
import json
import re
import subprocess
import sys
from pathlib import Path

import click
import pytest
from click.testing import CliRunner, Result

from fmu_greybox.cli import main
from fmu_greybox.errors import ConfigError
from fmu_greybox.fmi.archive import real_outputs
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
        assert "bench_configs" not in text, command
        used |= set(re.findall(r"builtin:\w+", text))
    assert used - {"builtin:NAME"} <= known
    assert "builtin:hydraulic_actuator" in used
    for command in ("diagnose", "train", "validate", "campaign"):
        assert "builtin:hydraulic_actuator" in texts[command], command


@pytest.fixture(scope="module")
def first_hour(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder away from the checkout where the CLI wrote ``rec.csv`` (2.5 s) and ``model/``,
    trained on the built-in project (10 inducing points, 3 iterations)."""
    folder = tmp_path_factory.mktemp("first_hour")
    with contextlib.chdir(folder):
        assert cli("-q", "synth", "--duration", 2.5, "--out", "rec.csv").exit_code == 0
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
    return folder


def test_train_runs_on_the_built_in_project_away_from_the_checkout(first_hour: Path) -> None:
    model = load_model(first_hour / "model")
    assert model.config.name == "hydraulic_actuator"
    assert [s.name for s in model.config.stages] == ["EHV", "RAM", "ITFV"]


def test_init_writes_a_starter_project_for_the_built_in_white_box(tmp_path: Path) -> None:
    from fmu_greybox.fmi.archive import open_fmu
    from fmu_greybox.fmi.builtin import resolve_fmu

    result = cli("init", "builtin:HydraulicActuator", "--out", tmp_path / "actuator")
    assert result.exit_code == 0, result.output
    config = load_config(tmp_path / "actuator" / "project.toml")
    with open_fmu(resolve_fmu(config.fmu)) as archive:
        config.check_against_fmu(archive)
        assert list(config.signals) == [*archive.inputs, *real_outputs(archive)]
    assert config.fmu == "builtin:HydraulicActuator"
    levels = ["spool_position", "ram_position", "itfv_pressure", "pressure_a", "pressure_b"]
    assert [s.target for s in config.stages] == levels  # not the velocities and flows
    assert all(s.inputs == tuple(archive.inputs) for s in config.stages)
    reference = load_config("builtin:hydraulic_actuator")
    for name, signal in reference.signals.items():  # the roles and units its authors gave
        if signal.role != "command":
            assert (config.signals[name].role, config.signals[name].unit) == (
                signal.role,
                signal.unit,
            ), name
    assert config.gp == reference.gp.__class__()  # the defaults, as comments
    text = (tmp_path / "actuator" / "project.toml").read_text()
    assert "# inducing = 300" in text and "# coverage95 = [0.9, 0.99]" in text


def test_init_refuses_to_overwrite_a_project_unless_forced(tmp_path: Path) -> None:
    target = tmp_path / "project.toml"
    target.write_text("# mine\n")
    result = cli("init", "builtin:HydraulicActuator", "--out", tmp_path)
    assert result.exit_code == 1
    assert f"--out {target} exists" in result.stderr and "--force" in result.stderr
    assert target.read_text() == "# mine\n"
    assert cli("init", "builtin:HydraulicActuator", "--out", tmp_path, "--force").exit_code == 0
    assert load_config(target).fmu == "builtin:HydraulicActuator"
    assert [p.name for p in tmp_path.iterdir()] == ["project.toml"]  # no temporary left


def test_a_starter_project_for_a_third_party_fmu_without_units_diagnoses_as_written(
    dc_servo_fmus: dict[str, Path], tmp_path: Path
) -> None:
    """The DC servo declares no units and terse names: the roles come from its descriptions,
    the units are left out, and ``diagnose`` names the bearing friction of the recording."""
    from third_party import record

    from fmu_greybox.data.recording import save_recording
    from fmu_greybox.fmi.archive import open_fmu

    result = cli("init", dc_servo_fmus["DCServo"], "--out", tmp_path / "servo")
    assert result.exit_code == 0, result.output
    config = load_config(tmp_path / "servo" / "project.toml")
    roles = {name: (s.role, s.unit) for name, s in config.signals.items()}
    assert roles == {
        "u": ("voltage", ""),
        "tl": ("force", ""),
        "th": ("position", ""),
        "w": ("velocity", ""),
        "ia": ("current", ""),
    }
    assert [(s.name, s.inputs, s.feeds_from) for s in config.stages] == [
        ("th", ("u", "tl"), ()),
        ("ia", ("u", "tl"), ()),
    ]
    with open_fmu(dc_servo_fmus["DCServoTruth"]) as truth:
        save_recording(record(truth, {"fc": 0.02}, seed=13, duration=8.0), tmp_path / "rec.csv")
    result = cli(
        "diagnose",
        tmp_path / "servo" / "project.toml",
        "--recording",
        tmp_path / "rec.csv",
        "--out",
        tmp_path / "diag",
        "--json",
    )
    assert result.exit_code == 0, result.output
    top = json.loads(result.stdout)["findings"][0]
    assert (top["effect"], top["stage"]) == ("coulomb_friction", "th")
    assert top["magnitude"]["value"] == pytest.approx(0.02, rel=0.1)


def test_demo_refuses_an_unknown_effect_before_it_says_or_writes_anything(tmp_path: Path) -> None:
    out = tmp_path / "out"
    result = cli("demo", "--effect", "foo=1", "--out", out)
    assert result.exit_code == 1
    assert result.stderr.startswith("error: --effect: unknown effect 'foo'; effects offered: ")
    assert "coulomb_friction" in result.stderr and "internal_leakage" in result.stderr
    assert "[1/6]" not in result.output
    assert not out.exists()


def test_synth_lists_each_effect_with_its_typical_magnitudes_and_unit() -> None:
    from fmu_greybox.synth.actuator import TYPICAL_MAGNITUDES

    result = cli("synth", "--list-effects")
    assert result.exit_code == 0, result.output
    lines = {line.split()[0]: " ".join(line.split()) for line in result.stdout.splitlines()}
    assert "[N] typical 300 to 900 N Coulomb seal friction" in lines["coulomb_friction"]
    assert "[s] typical 0.002 to 0.005 s Sensor delay" in lines["time_delay"]
    assert "[1] typical 0.03 to 0.1 Relative EHV gain error" in lines["gain_error"]
    for name, magnitudes in TYPICAL_MAGNITUDES.items():
        assert f"typical {magnitudes[0]:g} to {magnitudes[-1]:g}" in lines[name]
    assert "[m/s] - Stribeck velocity" in lines["stribeck_velocity"]  # a shape, not an effect


def test_the_fmpy_snippet_of_the_bench_page_runs_as_written(first_hour: Path) -> None:
    """Exported from the model the CLI trained, the FMU runs in plain fmpy by the page's code."""
    page = (ROOT / "docs" / "bench.md").read_text(encoding="utf-8")
    (snippet,) = [
        s for s in re.findall(r"```python\n(.*?)```", page, flags=re.S) if "ram_position" in s
    ]
    with contextlib.chdir(first_hour):
        assert cli("-q", "export", "model", "--out", "greybox.fmu").exit_code == 0
    (first_hour / "snippet.py").write_text(snippet, encoding="utf-8")
    run = subprocess.run(
        [sys.executable, "snippet.py"], cwd=first_hour, capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert re.fullmatch(r"ram_position at 2 s: \S+ m \+/- \S+ m\n", run.stdout), run.stdout
