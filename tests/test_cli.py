"""The ``fmu-greybox`` command line: build, synth, simulate; exit codes and messages."""

from __future__ import annotations

import gc
import importlib.metadata
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result

from fmu_greybox.cli import EXIT_INTERRUPTED, EXIT_NOT_ACCEPTED, main, run
from fmu_greybox.data.recording import load_recording
from fmu_greybox.fmi.builtin import sources_digest
from fmu_greybox.synth.actuator import SENSOR_NOISE

SCRIPT = Path(sys.executable).with_name("fmu-greybox")


@pytest.fixture(scope="module")
def env(fmu_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """Environment whose built-in FMU cache already holds this session's FMUs."""
    base = tmp_path_factory.mktemp("cache")
    folder = base / "fmus" / sources_digest()[:16]
    folder.mkdir(parents=True)
    for fmu in fmu_dir.glob("*.fmu"):
        shutil.copy2(fmu, folder / fmu.name)
    return {"FMU_GREYBOX_CACHE": str(base)}


def cli(env: dict[str, str], *args: object) -> Result:
    return CliRunner().invoke(main, [str(a) for a in args], env=env)


def run_script(env: dict[str, str], *args: object) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(SCRIPT), *map(str, args)],
        capture_output=True,
        text=True,
        env={**os.environ, **env},
        timeout=120,
        check=False,
    )


def assert_user_error(result: Result, *parts: str) -> None:
    assert result.exit_code == 1, result.output
    assert result.stderr.startswith("error: ")
    assert "Traceback" not in result.output
    for part in parts:
        assert part in result.stderr


def test_fmu_build_writes_both_fmus(tmp_path: Path) -> None:
    result = run_script({}, "fmu", "build", "--out", tmp_path / "fmus")
    assert result.returncode == 0, result.stderr
    for name in ("HydraulicActuator", "HydraulicActuatorTruth"):
        path = tmp_path / "fmus" / f"{name}.fmu"
        assert f"built {name}: {path}" in result.stdout
        with zipfile.ZipFile(path) as zf:
            assert "modelDescription.xml" in zf.namelist()


def test_synth_list_effects(env: dict[str, str]) -> None:
    result = cli(env, "synth", "--list-effects")
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    names = [line.split()[0] for line in lines]
    assert names[:2] == ["gain_error", "offset"] and "coulomb_friction" in names
    assert {"time_delay", "friction_asymmetry"} <= set(names) and len(names) == 12
    coulomb = next(line for line in lines if line.startswith("coulomb_friction"))
    assert "[N]" in coulomb


@pytest.mark.parametrize(("recorded", "simulated"), [(".csv", ".parquet"), (".parquet", ".csv")])
def test_synth_then_simulate(
    env: dict[str, str], tmp_path: Path, recorded: str, simulated: str
) -> None:
    record = tmp_path / f"x{recorded}"
    result = cli(
        env,
        "-q",
        "synth",
        "--effect",
        "coulomb_friction=800",
        "--seed",
        3,
        "--duration",
        2,
        "--out",
        record,
    )
    assert result.exit_code == 0, result.output
    assert result.stdout == ""  # --quiet
    recording = load_recording(record)
    assert recording.n_samples == 2001 and recording.names[0] == "valve_current"
    assert set(recording.names) >= set(SENSOR_NOISE)
    assert recording.units["supply_pressure"] == "Pa" and recording.units["engage"] == "1"
    if recorded == ".parquet":  # Parquet keeps the provenance too
        assert json.loads(recording.metadata["effects"]) == {"coulomb_friction": 800.0}
    out = tmp_path / f"y{simulated}"
    result = cli(env, "simulate", "builtin:HydraulicActuator", record, "--out", out)
    assert result.exit_code == 0, result.output
    assert f"wrote {out} (2001 samples of 10 outputs)" in result.stdout
    whitebox = load_recording(out)
    assert np.array_equal(whitebox.time, recording.time)
    assert whitebox.units["ram_position"] == "m"
    residual = recording["ram_position"] - whitebox["ram_position"]
    assert 0 < np.sqrt(np.mean(residual**2)) < 0.05  # friction makes the white-box drift


def test_simulate_with_map_fix_and_param(env: dict[str, str], tmp_path: Path) -> None:
    record = tmp_path / "x.csv"
    assert cli(env, "synth", "--duration", 2, "--noise", 0, "--out", record).exit_code == 0
    plain = tmp_path / "plain.csv"
    assert cli(env, "simulate", "builtin:HydraulicActuator", record, "--out", plain).exit_code == 0
    frame = record.read_text().replace("valve_current", "i_cmd", 1)
    edited = tmp_path / "edited.csv"
    edited.write_text(frame)
    result = cli(env, "simulate", "builtin:HydraulicActuator", edited, "--out", tmp_path / "m.csv")
    assert_user_error(result, "'valve_current' needs column 'valve_current'", "--map", "--fix")
    result = cli(
        env,
        "simulate",
        "builtin:HydraulicActuator",
        edited,
        "--out",
        tmp_path / "m.csv",
        "--map",
        "valve_current=i_cmd",
        "--fix",
        "engage=1",
    )
    assert result.exit_code == 0, result.output
    assert load_recording(tmp_path / "m.csv") == load_recording(plain)
    result = cli(
        env,
        "simulate",
        "builtin:HydraulicActuator",
        record,
        "--out",
        tmp_path / "p.csv",
        "--param",
        "viscous_damping=5000",
    )
    assert result.exit_code == 0, result.output
    assert load_recording(tmp_path / "p.csv") != load_recording(plain)


@pytest.mark.parametrize(
    ("args", "parts"),
    [
        (
            ("synth", "--effect", "coulomb_frictoin=800", "--out", "x.csv"),
            ("unknown effect 'coulomb_frictoin'", "did you mean 'coulomb_friction'"),
        ),
        (
            ("synth", "--effect", "compliance=2", "--out", "x.csv"),
            ("fmi2ExitInitializationMode", "compliance = 2 is outside its range [0, 0.9]"),
        ),
        (
            ("simulate", "builtin:HydraulicActuator", "missing.csv", "--out", "y.csv"),
            ("missing.csv", "cannot read the file"),
        ),
    ],
)
def test_user_error_exits_1_with_a_message(
    env: dict[str, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, args: tuple, parts: tuple
) -> None:
    monkeypatch.chdir(tmp_path)
    assert_user_error(cli(env, *args), *parts)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_simulate_errors(env: dict[str, str], tmp_path: Path) -> None:
    record = tmp_path / "x.csv"
    assert cli(env, "synth", "--duration", 0.5, "--out", record).exit_code == 0
    result = cli(
        env,
        "simulate",
        "builtin:HydraulicActuator",
        record,
        "--out",
        tmp_path / "y.csv",
        "--map",
        "novalue",
    )
    assert result.exit_code == 2 and "'novalue' is not NAME=VALUE" in result.stderr
    assert_user_error(
        cli(env, "simulate", tmp_path / "absent.fmu", record, "--out", tmp_path / "y.csv"),
        "absent.fmu: no such FMU file",
    )
    assert_user_error(
        cli(env, "simulate", "builtin:NoSuchModel", record, "--out", tmp_path / "y.csv"),
        "unknown built-in FMU 'builtin:NoSuchModel'",
    )


@pytest.mark.parametrize(
    "args",
    [
        ("synth", "--duration", "abc", "--out", "x.csv"),
        ("synth", "--no-such-option"),
        ("simulate", "builtin:HydraulicActuator"),
    ],
)
def test_usage_error_exits_2(env: dict[str, str], args: tuple) -> None:
    result = cli(env, *args)
    assert result.exit_code == 2, result.output
    assert "Usage:" in result.stderr and "Traceback" not in result.output


def test_subprocess_user_error_and_debug_traceback(env: dict[str, str], tmp_path: Path) -> None:
    args = ("synth", "--effect", "nope=1", "--out", tmp_path / "x.csv")
    plain = run_script(env, *args)
    assert plain.returncode == 1
    assert plain.stderr.startswith("error: ") and "Traceback" not in plain.stderr
    debug = run_script(env, "--debug", *args)
    assert debug.returncode == 1
    assert "Traceback (most recent call last)" in debug.stderr
    assert "fmu_greybox.errors.ConfigError" in debug.stderr
    assert not (tmp_path / "x.csv").exists()


def test_ctrl_c_exits_130(env: dict[str, str], tmp_path: Path) -> None:
    """Issue 42, item 10: Ctrl-C (SIGINT) ended a command with exit code 1, as click's
    'Aborted!' does, where shells and schedulers expect 128 + 2."""
    code = (
        "import signal; signal.signal(signal.SIGINT, signal.default_int_handler)\n"  # even if
        "from fmu_greybox.cli import main; print('ready', flush=True); main()"  # run in background
    )
    args = ["synth", "--duration", "3000", "--out", str(tmp_path / "long.csv")]
    process = subprocess.Popen(
        [sys.executable, "-c", code, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, **env},
    )
    try:
        assert process.stdout.readline() == "ready\n"
        time.sleep(3.0)  # into the synthesis, which runs for minutes
        assert process.poll() is None
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == EXIT_INTERRUPTED == 130, stderr
    assert stderr.strip().endswith("interrupted (Ctrl-C)") and "Traceback" not in stderr
    assert not (tmp_path / "long.csv").exists()


COMMANDS = [
    ["init"],
    ["fmu", "build"],
    ["synth"],
    ["simulate"],
    ["train"],
    ["validate"],
    ["demo"],
    ["export"],
    ["cosim"],
    ["diagnose"],
    ["campaign"],
]


def test_every_command_has_examples_and_usage_errors_exit_2() -> None:
    runner = CliRunner()
    for command in COMMANDS:
        help_text = runner.invoke(main, [*command, "--help"])
        assert help_text.exit_code == 0, command
        assert "Example" in help_text.output, command
        bad = runner.invoke(main, [*command, "--no-such-option"])
        assert bad.exit_code == 2, command
        assert "Traceback" not in bad.output


@pytest.mark.parametrize("command", COMMANDS, ids=" ".join)
def test_out_has_a_default_stated_in_the_help(command: list[str]) -> None:
    text = " ".join(CliRunner().invoke(main, [*command, "--help"]).output.split())
    option = text[text.index("--out ") :]
    assert "[default: " in option[: option.index("  --") if "  --" in option else None]
    assert re.search(r"--out (FILE|DIRECTORY) [A-Z]", text), text


def test_synth_without_out_writes_the_default_file(
    env: dict[str, str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    result = cli(env, "-q", "synth", "--duration", 0.2)
    assert result.exit_code == 0, result.output
    assert load_recording(tmp_path / "recording.csv").n_samples == 201


def test_shared_options_have_one_range_and_one_help() -> None:
    runner = CliRunner()
    for option in ("--inducing", "--max-iter"):
        helps = []
        for command in ("train", "demo"):
            text = " ".join(runner.invoke(main, [command, "--help"]).output.split())
            start = text.index(option + " INTEGER RANGE")
            helps.append(text[start:].split(".")[0].split(" (default")[0])
        assert helps[0] == helps[1], helps  # the same words up to the default
    for command in (["train", "x.toml"], ["demo"]):
        refused = runner.invoke(main, [*command, "--inducing", "0"])
        assert refused.exit_code == 2 and "x>=1" in refused.stderr, refused.output
        refused = runner.invoke(main, [*command, "--max-iter", "-1"])
        assert refused.exit_code == 2 and "x>=0" in refused.stderr, refused.output


def test_top_level_help_lists_each_command_with_its_whole_sentence() -> None:
    text = " ".join(CliRunner().invoke(main, ["--help"]).output.split())
    assert "..." not in text[text.index("Commands:") :]  # nothing cut short
    for sentence in (
        "Locate where the white-box departs from a recording, name the physics it left out, "
        "model it and show the fit improve.",
        "Co-simulate an SSP bench in fmpy or libcosim; write every FMU output.",
        "Export a trained grey-box as an FMI 2.0 (or 3.0) co-simulation FMU (and an SSP bench).",
    ):
        assert sentence in text
    # every exit code a command can end with is listed, the acceptance one included
    assert f"{EXIT_NOT_ACCEPTED} acceptance criteria not met (validate --strict)" in text


def test_without_a_terminal_each_step_prints_one_line(env: dict[str, str], tmp_path: Path) -> None:
    """CliRunner's stderr is not a terminal: no bars, no carriage returns, one line per step."""
    record = tmp_path / "x.csv"
    result = cli(env, "synth", "--duration", 1, "--out", record)
    assert result.exit_code == 0, result.output
    result = cli(env, "simulate", "builtin:HydraulicActuator", record, "--out", tmp_path / "y.csv")
    assert result.exit_code == 0, result.output
    assert "\r" not in result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1, lines
    assert re.fullmatch(
        r"Stepping the white-box over the recording: done, 1000 steps in \d+\.\d s", lines[0]
    )


def test_the_command_line_in_a_report_names_no_local_folder(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from fmu_greybox.report.provenance import command_line

    argv = ["x", "validate", "cfg.toml", "--recording", "/data/flight 7.csv", "--out=/tmp/val"]
    monkeypatch.setattr("sys.argv", argv)
    assert command_line() == ("fmu-greybox validate cfg.toml --recording 'flight 7.csv' --out=val")


def test_the_console_script_freezes_what_is_left_once_the_command_ended(monkeypatch) -> None:
    """``fmu-greybox`` is :func:`run`: the command, then :func:`gc.freeze` (whatever the exit),
    so that the way out does not collect every object again."""
    (script,) = [
        e
        for e in importlib.metadata.entry_points(group="console_scripts")
        if e.name == "fmu-greybox"
    ]
    assert script.value == "fmu_greybox.cli:run"
    frozen = []
    monkeypatch.setattr(gc, "freeze", lambda: frozen.append(True))
    for argv in (["fmu-greybox", "--version"], ["fmu-greybox", "simulate", "nowhere.toml"]):
        monkeypatch.setattr(sys, "argv", argv)
        with pytest.raises(SystemExit):
            run()
    assert frozen == [True, True]
