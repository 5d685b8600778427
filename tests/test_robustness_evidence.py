"""Recordings that are not the evidence they look like (issue 42, items 5, 6, 7 and 9).

Each test fails on the code before its fix: a copy of the training CSV re-saved with 15 or 12
significant digits was scored as unseen data (item 5); ``train --calibrate-on`` took the
training recording, or a copy, as calibration data (item 6); the same recording given twice to
``validate`` counted twice (item 7); a model folder of an older format scored every row of a
copy of its training recording, silently (item 9).
"""

from __future__ import annotations

import json
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_robustness_workflow import project, write_project

from fmu_greybox.data.recording import Recording, save_recording
from fmu_greybox.errors import ConfigError, RecordingError
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.model.store import (
    MANIFEST,
    MANIFEST_HASH,
    TRAINING_ROWS,
    file_sha256,
    load_model,
    manifest_digest,
    save_model,
)
from fmu_greybox.project.config import ProjectConfig, parse_config
from fmu_greybox.project.data import load_project_recording, split_row
from fmu_greybox.project.fingerprint import (
    data_rows,
    find_copy,
    fingerprint,
    recorded_rows,
    row_digests,
    trained_mask,
)
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise
from fmu_greybox.workflow.train import train_model
from fmu_greybox.workflow.validate import validate_model, validate_recordings


def rounded_csv(source: Path, target: Path, digits: int) -> Path:
    """``source`` re-saved with ``digits`` significant digits, as a spreadsheet tool would:
    every number of the CSV rounded, no units sidecar kept."""
    header, *lines = source.read_text(encoding="utf-8").splitlines()
    rows = [",".join(f"{float(v):.{digits}g}" for v in line.split(",")) for line in lines]
    target.write_text("\n".join([header, *rows]) + "\n", encoding="utf-8")
    return target


@pytest.fixture(scope="module")
def workspace(whitebox_fmu: Path, truth_fmu: Path, tmp_path_factory) -> Path:
    """project.toml, rec.csv (0.5 s at 1 kHz, with noise), other.csv (another flight) and
    model/ trained on the first 80 % of rec.csv."""
    folder = tmp_path_factory.mktemp("evidence")
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        for name, seed in (("rec", 11), ("other", 12)):
            request = SynthRequest(
                effects={"gain_error": 0.1}, seed=seed, profile=FlightTestProfile(duration=0.5)
            )
            save_recording(synthesise(truth, whitebox, request), folder / f"{name}.csv")
    path = write_project(project(whitebox_fmu), folder / "project.toml")
    config = parse_config(tomllib.loads(path.read_text(encoding="utf-8")), path)
    save_model(
        train_model(config, load_project_recording(config, folder / "rec.csv")), folder / "model"
    )
    return folder


@pytest.fixture(scope="module")
def config(workspace: Path) -> ProjectConfig:
    path = workspace / "project.toml"
    return parse_config(tomllib.loads(path.read_text(encoding="utf-8")), path)


@pytest.fixture(scope="module")
def reference(workspace: Path, config: ProjectConfig):
    """Validation on the training recording itself: its held-out tail."""
    model = load_model(workspace / "model")
    return validate_model(model, load_project_recording(config, workspace / "rec.csv"))


# -- item 5: a rounded copy of the training CSV is the training recording ----------------------


@pytest.mark.parametrize("digits", [15, 12])
def test_a_rounded_copy_of_the_training_csv_scores_only_its_held_out_rows(
    workspace: Path, config: ProjectConfig, reference, tmp_path: Path, digits: int
) -> None:
    """Before: every row of the copy differed in its last bits and was scored as unseen."""
    copy = rounded_csv(workspace / "rec.csv", tmp_path / "copy.csv", digits)
    recording = load_project_recording(config, copy)
    assert not np.array_equal(recording["ram_position"], reference.data.recording["ram_position"])
    result = validate_model(load_model(workspace / "model"), recording)
    np.testing.assert_array_equal(result.scored, reference.scored)
    assert "training rows in the run not scored" not in result.held_out
    for stage, row in reference.table.items():
        for key, value in row.items():
            assert result.table[stage][key] == pytest.approx(value, rel=1e-6, abs=1e-12), key


def test_another_flight_shares_no_rows_with_the_training_one(
    workspace: Path, config: ProjectConfig
) -> None:
    """The tolerance is far below the data's own noise: every row of another flight (but the
    first, the chain's initial memory) is scored."""
    result = validate_model(
        load_model(workspace / "model"), load_project_recording(config, workspace / "other.csv")
    )
    np.testing.assert_array_equal(result.scored, np.arange(1, result.data.n_samples))


# -- item 6: calibration recordings are not the training one -----------------------------------


@pytest.mark.parametrize("copy", ["itself", "byte copy", "rounded copy"])
def test_calibrating_on_the_training_recording_is_refused(
    workspace: Path, config: ProjectConfig, tmp_path: Path, copy: str
) -> None:
    """Before: σ was calibrated on the training rows themselves (RAM's variance fell 11 times,
    and 1.2 % of an independent recording's rows then fell inside ±1.96σ)."""
    path = {
        "itself": workspace / "rec.csv",
        "byte copy": tmp_path / "same.csv",
        "rounded copy": tmp_path / "rounded.csv",
    }[copy]
    if copy == "byte copy":
        shutil.copyfile(workspace / "rec.csv", path)
    if copy == "rounded copy":
        rounded_csv(workspace / "rec.csv", path, 12)
    training = load_project_recording(config, workspace / "rec.csv")
    others = [load_project_recording(config, workspace / "other.csv")]
    others.append(load_project_recording(config, path))
    with pytest.raises(ConfigError) as info:
        train_model(config, training, calibration_recordings=others)
    text = str(info.value)
    assert info.value.field == "--calibrate-on"
    assert f"calibration recording {path}: 100.0% of its rows are rows of " in text
    assert f"rows of {workspace / 'rec.csv'}" in text
    assert "Calibrate on recordings made apart from the training one" in text


def test_the_same_calibration_recording_twice_is_refused(
    workspace: Path, config: ProjectConfig, tmp_path: Path
) -> None:
    rounded = rounded_csv(workspace / "other.csv", tmp_path / "other_again.csv", 15)
    training = load_project_recording(config, workspace / "rec.csv")
    others = [load_project_recording(config, p) for p in (workspace / "other.csv", rounded)]
    with pytest.raises(ConfigError, match=f"{rounded}: 100.0% of its rows are rows of "):
        train_model(config, training, calibration_recordings=others)


# -- item 7: one recording given twice to validate counts once ---------------------------------


def test_the_same_recording_twice_to_validate_is_refused(
    workspace: Path, config: ProjectConfig, tmp_path: Path
) -> None:
    """Before: the copy counted as independent evidence; the coverage interval narrowed and
    the verdict flipped from UNDECIDED to FAIL. A copy with its time stamps moved is one too."""
    other = load_project_recording(config, workspace / "other.csv")
    moved = Recording(other.time + 100.0, other.signals, other.units, str(tmp_path / "moved.csv"))
    model = load_model(workspace / "model")
    with pytest.raises(RecordingError) as info:
        validate_recordings(model, {"1-other": other, "2-moved": moved})
    text = str(info.value)
    assert text.startswith(f"{tmp_path / 'moved.csv'}: 100.0% of its rows are rows of ")
    assert "Give each recording once" in text


# -- item 9: a model folder of an older format -------------------------------------------------


def _rewrite(folder: Path, version: int, digests: np.ndarray | None) -> None:
    """The folder as an older version wrote it: exact-value digests (3, 4) or none (1, 2)."""
    manifest = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
    manifest["format_version"] = version
    if digests is None:
        (folder / TRAINING_ROWS).unlink()
        del manifest["files"][TRAINING_ROWS]
    else:
        np.savez(folder / TRAINING_ROWS, digests=np.unique(digests))
        manifest["files"][TRAINING_ROWS] = file_sha256(folder / TRAINING_ROWS)
    manifest[MANIFEST_HASH] = manifest_digest(manifest)
    (folder / MANIFEST).write_text(json.dumps(manifest), encoding="utf-8")


@pytest.mark.parametrize("version", [4, 2])
def test_an_older_model_folder_recognises_a_rounded_copy_by_its_spread_and_says_so(
    workspace: Path, config: ProjectConfig, reference, tmp_path: Path, version: int
) -> None:
    """Before: all rows of the copy were scored, with no word of it."""
    folder = tmp_path / "old"
    shutil.copytree(workspace / "model", folder)
    split = split_row(config, reference.data.n_samples)
    exact = row_digests(data_rows(reference.data)[: split + 1])
    _rewrite(folder, version, exact if version == 4 else None)
    old = load_model(folder)
    assert (old.trained_rows is None) == (version == 2)
    copy = load_project_recording(
        config, rounded_csv(workspace / "rec.csv", tmp_path / "c.csv", 12)
    )
    result = validate_model(old, copy)
    np.testing.assert_array_equal(result.scored, reference.scored)
    assert "this model folder is of an older format" in result.held_out
    assert "retrain it to recognise training rows at the recording's resolution" in result.held_out
    independent = validate_model(old, load_project_recording(config, workspace / "other.csv"))
    assert independent.scored.size == independent.data.n_samples - 1


# -- the property across recordings: rounding, time, column order, duplication -----------------


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    digits=st.integers(12, 17),
    time_scale=st.floats(0.001, 1000.0),
    n_columns=st.integers(1, 6),
)
def test_a_rounded_retimed_reordered_copy_is_found_and_another_recording_is_not(
    seed: int, digits: int, time_scale: float, n_columns: int
) -> None:
    """A recording rounded row-wise to 12-17 significant digits, with its time scaled and its
    columns in another order, is found as a copy of the original; an independent one with the
    same statistics is not, and neither shares a row with the other."""
    rng = np.random.default_rng(seed)
    n = 300
    scales = 10.0 ** rng.uniform(-6, 6, n_columns)
    names = [f"s{i}" for i in range(n_columns)]

    def recording(values: np.ndarray, time: np.ndarray, order: list[int], source: str):
        signals = {names[i]: values[:, i] for i in order}
        return Recording(time, signals, {k: "1" for k in signals}, source)

    values = rng.standard_normal((n, n_columns)).cumsum(axis=0) * scales
    time = np.arange(n) * 1e-3
    rounded = np.vectorize(lambda v: float(f"{v:.{digits}g}"))(values)
    original = recording(values, time, list(range(n_columns)), "a.csv")
    copy = recording(rounded, time * time_scale, list(rng.permutation(n_columns)), "b.csv")
    other = recording(
        rng.standard_normal((n, n_columns)).cumsum(axis=0) * scales, time, [0], "c.csv"
    )
    assert find_copy(recorded_rows([original, other])) is None
    assert find_copy(recorded_rows([original, other, copy])) == ("b.csv", "a.csv", 1.0)
    rows = dict(recorded_rows([original, copy, other]))
    assert trained_mask(rows["b.csv"], fingerprint(rows["a.csv"])).all()
    assert not trained_mask(rows["c.csv"], fingerprint(rows["a.csv"])).any()


def test_rows_moved_across_a_cell_edge_by_less_than_the_tolerance_are_found() -> None:
    """Values placed just inside a cell's edge and moved across it by a tenth of the tolerance
    are training rows, in any combination of columns; moved by a hundred times the tolerance
    they are not."""
    from fmu_greybox.project.fingerprint import RESOLUTION, TOLERANCE, full_scale

    rng = np.random.default_rng(3)
    scale = full_scale(rng.standard_normal((1, 4)) * 10.0)
    cell = scale * RESOLUTION
    centres = rng.integers(-(10**6), 10**6, (2000, 4)).astype(float)
    sides = rng.choice([-1.0, 0.0, 1.0], (2000, 4))
    edge = centres + sides * (0.5 - 0.05 * TOLERANCE / RESOLUTION)
    trained = fingerprint(np.vstack([edge * cell, scale[None, :]]))
    across = (edge + sides * 0.1 * TOLERANCE / RESOLUTION) * cell
    away = (edge + sides * 100.0 * TOLERANCE / RESOLUTION) * cell
    assert trained.scale is not None and np.allclose(trained.scale, scale)
    assert trained_mask(across, trained).all()
    moved = sides.any(axis=1)
    assert not trained_mask(away, trained)[moved].any()
