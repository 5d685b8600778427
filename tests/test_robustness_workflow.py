"""Misuse of train, validate, diagnose and export that must get a clear answer (issue 15).

Each test is one item of the issue; each fails on the code before its fix: validate scored a
byte copy of the training CSV as held out (item 1), ran a recording at another sample time
(item 2) or with another project (item 3); a project's constant silently overrode a recorded
input (item 4); too little data gave a model or a verdict (item 5); export --ssp into a missing
folder failed after writing the FMU (item 6); two trains into one folder both "wrote" (item 7);
the messages of item 10 named options or nothing.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fmu_greybox.atomic import output_lock
from fmu_greybox.cli import main
from fmu_greybox.data.recording import Recording, load_recording, save_recording
from fmu_greybox.diagnosis import Diagnosis
from fmu_greybox.errors import ConfigError, RecordingError, UnitMismatchError
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.model.store import GreyBoxModel, load_model, save_model
from fmu_greybox.project.config import ProjectConfig, parse_config
from fmu_greybox.project.data import load_project_recording, split_row
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise
from fmu_greybox.workflow.train import MIN_TRAIN_ROWS, train_model
from fmu_greybox.workflow.validate import (
    MIN_SCORED_ROWS,
    check_project,
    validate_model,
    write_metrics,
)

REFERENCE = Path(__file__).resolve().parents[1] / "bench_configs" / "hydraulic_actuator.toml"


def project(whitebox_fmu: Path, **changes: dict) -> dict:
    """The reference project's tables: this white-box, a small fast GP, 80 % training."""
    raw = tomllib.loads(REFERENCE.read_text(encoding="utf-8"))
    raw["whitebox"]["fmu"] = str(whitebox_fmu)
    raw["gp"].update(inducing=8, max_iter=3)
    raw["split"] = {"train_fraction": 0.8}
    for table, values in changes.items():
        raw[table] = {**raw.get(table, {}), **values}
    return raw


def write_project(raw: dict, path: Path) -> Path:
    """The tables as a TOML file (only the kinds of values the reference project holds)."""

    def value(v: object) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    lines = [f"{k} = {value(v)}" for k, v in raw.items() if not isinstance(v, dict | list)]
    for name, table in raw.items():
        if name == "signals":
            for signal, entry in table.items():
                lines.append(f"[signals.{signal}]")
                lines += [f"{k} = {value(v)}" for k, v in entry.items()]
        elif name == "stages":
            for stage in table:
                lines.append("[[stages]]")
                lines += [f"{k} = {value(v)}" for k, v in stage.items()]
        elif isinstance(table, dict):
            lines.append(f"[{name}]")
            for k, v in table.items():
                if isinstance(v, dict):
                    lines.append(
                        f"{k} = {{ {', '.join(f'{a} = {value(b)}' for a, b in v.items())} }}"
                    )
                else:
                    lines.append(f"{k} = {value(v)}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def workspace(whitebox_fmu: Path, truth_fmu: Path, tmp_path_factory) -> Path:
    """project.toml, rec.csv (0.5 s at 1 kHz) and model/ trained on its first 80 %."""
    folder = tmp_path_factory.mktemp("workflow")
    request = SynthRequest(
        effects={"gain_error": 0.1}, seed=11, noise=0.0, profile=FlightTestProfile(duration=0.5)
    )
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        save_recording(synthesise(truth, whitebox, request), folder / "rec.csv")
    path = write_project(project(whitebox_fmu), folder / "project.toml")
    config = parse_config(tomllib.loads(path.read_text(encoding="utf-8")), path)
    model = train_model(config, load_project_recording(config, folder / "rec.csv"))
    save_model(model, folder / "model")
    return folder


@pytest.fixture(scope="module")
def config(workspace: Path) -> ProjectConfig:
    path = workspace / "project.toml"
    return parse_config(tomllib.loads(path.read_text(encoding="utf-8")), path)


@pytest.fixture(scope="module")
def model(workspace: Path) -> GreyBoxModel:
    return load_model(workspace / "model")


@pytest.fixture(scope="module")
def reference(workspace: Path, config: ProjectConfig, model: GreyBoxModel):
    """Validation on the training recording itself: its held-out tail."""
    return validate_model(model, load_project_recording(config, workspace / "rec.csv"))


def shifted(recording: Recording, rows: np.ndarray, source: str) -> Recording:
    """The given rows of a recording, on a fresh time grid of the same step."""
    time = recording.time[0] + recording.dt * np.arange(rows.size)
    signals = {n: v[rows] for n, v in recording.signals.items()}
    return Recording(time, signals, recording.units, source)


# -- item 1: training rows are recognised by their values --------------------------------------


def test_byte_copy_without_units_scores_only_the_held_out_rows(
    workspace: Path, config: ProjectConfig, model: GreyBoxModel, reference, tmp_path: Path
) -> None:
    """Before: the copy (no .units.json) hashed differently and every row was scored."""
    copy = tmp_path / "copy.csv"
    shutil.copyfile(workspace / "rec.csv", copy)
    result = validate_model(model, load_project_recording(config, copy))
    split = split_row(config, result.data.n_samples)
    np.testing.assert_array_equal(result.scored, np.arange(split + 1, result.data.n_samples))
    np.testing.assert_array_equal(result.scored, reference.scored)
    assert result.table == reference.table
    write_metrics(result, model, tmp_path / "metrics.json")
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["scored_rows"] == [[split + 1, result.data.n_samples - 1]]
    assert metrics["n_rows"] == result.data.n_samples - split - 1


def test_training_rows_anywhere_are_run_but_not_scored(
    workspace: Path, config: ProjectConfig, model: GreyBoxModel
) -> None:
    """Held-out rows first, then the training rows, time stamps made new: only the first part
    (but its first row, the chain's initial memory) is scored."""
    recording = load_project_recording(config, workspace / "rec.csv")
    split = split_row(config, recording.n_samples)
    order = np.r_[split + 1 : recording.n_samples, 0 : split + 1]
    result = validate_model(model, shifted(recording, order, "reordered.csv"))
    held = recording.n_samples - split - 1
    np.testing.assert_array_equal(result.scored, np.arange(1, held))
    assert f"{split + 1} training rows in the run not scored" in result.held_out


def test_only_training_rows_is_refused(
    workspace: Path, config: ProjectConfig, model: GreyBoxModel
) -> None:
    recording = load_project_recording(config, workspace / "rec.csv")
    head = recording.select(recording.names).slice_time(0.0, 0.3)
    with pytest.raises(RecordingError) as info:
        validate_model(model, head)
    text = str(info.value)
    assert "only 0 of its 301 rows were not used in training" in text
    assert f"at least {MIN_SCORED_ROWS}" in text


# -- item 2: the sample time must be the model's step ------------------------------------------


def test_another_sample_time_is_refused(
    workspace: Path, config: ProjectConfig, model: GreyBoxModel
) -> None:
    """Before: a 2 kHz recording for a 1 kHz model exited 0, the RAM stage 1907 % worse."""
    recording = load_project_recording(config, workspace / "rec.csv")
    fine = np.arange(2 * recording.n_samples - 1) * recording.dt / 2
    twice = Recording(
        fine,
        {n: np.interp(fine, recording.time, v) for n, v in recording.signals.items()},
        recording.units,
        "2kHz.csv",
    )
    with pytest.raises(RecordingError) as info:
        validate_model(model, twice)
    text = str(info.value)
    assert "2kHz.csv: sampled every 0.0005 s but the model (the step it was trained at)" in text
    assert "runs at 0.001 s" in text and "resample = 0.001" in text


def test_time_in_milliseconds_without_a_unit_is_pointed_out(
    workspace: Path, config: ProjectConfig, model: GreyBoxModel, tmp_path: Path
) -> None:
    """Before: a fake -100 % improvement."""
    recording = load_recording(workspace / "rec.csv")
    frame = recording.to_frame()
    frame["time"] = frame["time"] * 1000.0
    frame.to_csv(tmp_path / "ms.csv", index=False)
    with pytest.raises(RecordingError) as info:
        validate_model(model, load_project_recording(config, tmp_path / "ms.csv"))
    text = str(info.value)
    assert "sampled every 1 s" in text and "is its time column in milliseconds?" in text
    # with its unit, the same file is converted and validates like the original
    frame.rename(columns={"time": "time [ms]"}).to_csv(tmp_path / "ms_unit.csv", index=False)
    result = validate_model(model, load_project_recording(config, tmp_path / "ms_unit.csv"))
    assert result.scored.size > 0


# -- item 3: validate uses the training project or refuses ------------------------------------


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (lambda raw: raw["signals"]["load_force"].update(column="F_load"), "signals.load_force"),
        (lambda raw: raw["stages"][1].update(lags=3), "stages[1].lags"),
        (lambda raw: raw["signals"]["supply_pressure"].update(unit="bar"), "supply_pressure.unit"),
        (lambda raw: raw["whitebox"].update(fixed_inputs={"engage": 1.0}), "whitebox.fixed"),
    ],
    ids=["column", "lags", "unit", "fixed_inputs"],
)
def test_a_project_other_than_the_training_one_is_refused(
    whitebox_fmu: Path, workspace: Path, model: GreyBoxModel, tmp_path: Path, edit, field
) -> None:
    """Before: validate used the model's stored project and ignored the one it was given."""
    raw = project(whitebox_fmu)
    edit(raw)
    path = write_project(raw, tmp_path / "other.toml")
    with pytest.raises(ConfigError) as info:
        check_project(parse_config(tomllib.loads(path.read_text()), path), model, "model/")
    text = str(info.value)
    assert str(path) in text and field in text
    assert "in the project model/ was trained with" in text


def test_validate_command_refuses_the_other_project_before_running(
    whitebox_fmu: Path, workspace: Path, tmp_path: Path
) -> None:
    raw = project(whitebox_fmu)
    raw["signals"]["load_force"]["column"] = "F_load"
    path = write_project(raw, tmp_path / "other.toml")
    result = CliRunner().invoke(
        main,
        [
            "validate",
            str(path),
            "--model",
            str(workspace / "model"),
            "--recording",
            str(workspace / "rec.csv"),
            "--out",
            str(tmp_path / "val"),
        ],
    )
    assert result.exit_code == 1
    assert "signals.load_force.column: 'F_load' here but 'load_force'" in result.output
    assert "load_flow" not in result.output and not (tmp_path / "val").exists()


def test_validate_on_several_recordings_writes_nothing_unless_all_can_be_scored(
    workspace: Path, tmp_path: Path
) -> None:
    """A second recording holding only training rows stops the run with its own name before
    any output is written (the first one, the held-out tail, alone would have validated)."""
    recording = load_recording(workspace / "rec.csv")
    head = save_recording(recording.slice_time(0.0, 0.3), tmp_path / "head.csv")
    tail = save_recording(recording.slice_time(0.4, 0.5), tmp_path / "tail.csv")
    args = ["validate", str(workspace / "project.toml"), "--model", str(workspace / "model")]
    args += ["--recording", str(tail), "--recording", str(head)]
    result = CliRunner().invoke(main, [*args, "--out", str(tmp_path / "val")])
    assert result.exit_code == 1
    assert "head.csv" in result.output and "were not used in training" in result.output
    assert not (tmp_path / "val").exists()


def test_same_project_with_other_gp_settings_validates(
    workspace: Path, config: ProjectConfig, model: GreyBoxModel
) -> None:
    """[gp] only steers training (train --inducing overrides it): not compared."""
    other = dataclasses.replace(config, gp=dataclasses.replace(config.gp, inducing=99))
    check_project(other, model, workspace / "model")


# -- item 4: a recorded input held constant -----------------------------------------------------


def test_recorded_input_in_fixed_inputs_is_refused(
    whitebox_fmu: Path, workspace: Path, tmp_path: Path
) -> None:
    """Before: the constant silently replaced the recorded supply pressure (ITFV RMSE x40)."""
    raw = project(whitebox_fmu, whitebox={"fixed_inputs": {"supply_pressure": 2.0e7}})
    path = write_project(raw, tmp_path / "fixed.toml")
    config = parse_config(tomllib.loads(path.read_text()), path)
    with pytest.raises(ConfigError) as info:
        train_model(config, load_project_recording(config, workspace / "rec.csv"))
    text = str(info.value)
    assert f"{path}: whitebox.fixed_inputs.supply_pressure: FMU input 'supply_pressure'" in text
    assert "records it (column 'supply_pressure')" in text


# -- item 5: minimum data ----------------------------------------------------------------------


def test_too_few_training_rows_are_refused(
    whitebox_fmu: Path, workspace: Path, tmp_path: Path
) -> None:
    """Before: train_fraction = 0.001 wrote a model trained on 6 rows."""
    path = write_project(project(whitebox_fmu, split={"train_fraction": 0.01}), tmp_path / "a.toml")
    config = parse_config(tomllib.loads(path.read_text()), path)
    with pytest.raises(ConfigError) as info:
        train_model(config, load_project_recording(config, workspace / "rec.csv"))
    assert "split.train_fraction" in str(info.value)
    assert f"leaves 5 training rows; a model needs at least {MIN_TRAIN_ROWS}" in str(info.value)


def test_more_inducing_points_than_rows_are_refused(
    whitebox_fmu: Path, workspace: Path, tmp_path: Path
) -> None:
    """Before: clamped silently to an exact GP, which then looked like a hang."""
    path = write_project(project(whitebox_fmu, gp={"inducing": 1000}), tmp_path / "b.toml")
    config = parse_config(tomllib.loads(path.read_text()), path)
    with pytest.raises(ConfigError) as info:
        train_model(config, load_project_recording(config, workspace / "rec.csv"))
    text = str(info.value)
    assert "gp.inducing: 1000 inducing points per stage, but a stage is trained on" in text
    assert "set gp.inducing (or --inducing) to at most" in text


@pytest.mark.parametrize("rows", [2, 10, 999])
def test_diagnosis_on_too_few_rows_is_refused(
    workspace: Path, config: ProjectConfig, rows: int
) -> None:
    """Before: 2 rows ended in a scipy ValueError traceback, 10 rows in a confident verdict."""
    recording = load_project_recording(config, workspace / "rec.csv")
    longer = shifted(recording, np.arange(rows) % recording.n_samples, "short.csv")
    with pytest.raises(RecordingError, match=rf"short.csv: holds {rows} rows; .* at least 1000"):
        Diagnosis(config, greybox=None).fit(longer)


# -- item 6: export into folders that do not exist ---------------------------------------------


def test_export_ssp_under_a_file_is_refused_before_anything_is_written(
    workspace: Path, tmp_path: Path
) -> None:
    """Before: the FMU was written, then --ssp ended in a FileNotFoundError traceback."""
    (tmp_path / "blocker").write_text("a file, not a folder")
    out = tmp_path / "new" / "deeper" / "greybox.fmu"
    result = CliRunner().invoke(
        main,
        [
            "export",
            str(workspace / "model"),
            "--out",
            str(out),
            "--ssp",
            str(tmp_path / "blocker" / "bench.ssp"),
            "--recording",
            str(workspace / "rec.csv"),
        ],
    )
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert f"--ssp {tmp_path / 'blocker' / 'bench.ssp'}: cannot make its folder" in result.output
    assert not out.exists()


# -- item 7: one run per output folder ---------------------------------------------------------


def test_second_train_into_a_busy_folder_is_refused(workspace: Path, tmp_path: Path) -> None:
    """Before: both runs printed "wrote" and the last one silently replaced the other."""
    out = tmp_path / "model"
    with output_lock(out, "--out"):
        result = CliRunner().invoke(
            main,
            [
                "train",
                str(workspace / "project.toml"),
                "--recording",
                str(workspace / "rec.csv"),
                "--out",
                str(out),
            ],
        )
    assert result.exit_code == 1
    assert f"--out {out} is being written by process" in result.output
    assert not out.exists() and not (tmp_path / ".model.lock").exists()


# -- units converted on load, project files ----------------------------------------------------


def test_project_recording_in_other_units_is_converted(
    workspace: Path, config: ProjectConfig, model: GreyBoxModel, reference, tmp_path: Path, caplog
) -> None:
    """Ram position in mm, supply pressure in bar: converted to the project's m and Pa."""
    recording = load_recording(workspace / "rec.csv")
    frame = recording.to_frame()
    frame["ram_position"] *= 1e3
    frame["supply_pressure"] /= 1e5
    frame = frame.rename(columns={"ram_position": "ram_position [mm]"})
    frame = frame.rename(columns={"supply_pressure": "supply_pressure [bar]"})
    frame.to_csv(tmp_path / "mm.csv", index=False)
    with caplog.at_level("WARNING", logger="fmu_greybox"):
        converted = load_project_recording(config, tmp_path / "mm.csv")
    assert "'ram_position' converted from 'mm' to 'm'" in caplog.text
    np.testing.assert_allclose(converted["ram_position"], recording["ram_position"], rtol=1e-12)
    assert converted.units["supply_pressure"] == "Pa"
    frame.rename(columns={"ram_position [mm]": "ram_position [N]"}).to_csv(
        tmp_path / "force.csv", index=False
    )
    with pytest.raises(UnitMismatchError, match="'ram_position' is recorded in 'N'"):
        load_project_recording(config, tmp_path / "force.csv")


def test_unfed_input_names_the_project_fields_not_command_line_options(
    whitebox_fmu: Path, workspace: Path, model: GreyBoxModel, tmp_path: Path
) -> None:
    """Before: validate (and train, diagnose) suggested --map and --fix, which only simulate
    has."""
    raw = project(whitebox_fmu)
    del raw["signals"]["engage"]
    path = write_project(raw, tmp_path / "noengage.toml")
    config = parse_config(tomllib.loads(path.read_text()), path)
    full = load_recording(workspace / "rec.csv")
    recording = full.select([n for n in full.names if n != "engage"])
    longer = shifted(recording, np.arange(1000) % recording.n_samples, "long.csv")
    for run in (lambda: train_model(config, recording), lambda: Diagnosis(config).fit(longer)):
        with pytest.raises(RecordingError) as info:
            run()
        text = str(info.value)
        assert "'engage' needs column 'engage'" in text
        assert f"in {path}, give each a [signals.NAME] table" in text and "fixed_inputs" in text
        assert "--map" not in text and "--fix" not in text


def test_two_signals_reading_one_column_are_refused(whitebox_fmu: Path) -> None:
    raw = project(whitebox_fmu)
    raw["signals"]["load_force"]["column"] = "supply_pressure"
    with pytest.raises(ConfigError) as info:
        parse_config(raw, Path("p.toml"))
    assert "p.toml: signals.load_force.column: signals 'supply_pressure' and 'load_force'" in str(
        info.value
    )
