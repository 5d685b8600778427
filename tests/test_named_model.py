"""The white-box with named terms: stepping, state, reset, and a grey-box that carries terms."""

from __future__ import annotations

import dataclasses
import json
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from fmpy import simulate_fmu
from fmpy.validation import validate_fmu
from lxml import etree
from test_export import (
    INPUTS,
    STAGE_OUTPUTS,
    Slave,
    assert_close,
    input_rows,
    input_signal,
    master_run,
    synth_recording,
)

from fmu_greybox.cli import main
from fmu_greybox.data.recording import save_recording
from fmu_greybox.errors import ConfigError
from fmu_greybox.export.fmu import export_greybox
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.gp import SparseGPR
from fmu_greybox.model.simulate import simulate_with_terms
from fmu_greybox.model.stage_data import estimate_noise, prepare
from fmu_greybox.model.store import load_model, save_model
from fmu_greybox.model.terms import CoulombForce, InputDelay, InputGain, SensorDelay
from fmu_greybox.model.whitebox import NamedModel, check_terms, read_terms
from fmu_greybox.project.config import load_config, parse_config
from fmu_greybox.project.data import split_row
from fmu_greybox.workflow.parts import (
    BLOCKS,
    EQUAL_MARGIN,
    PART_WORDS,
    STAGE_PARTS,
    TRAINING_PARTS,
    block_rmse,
    choose_stage_part,
    compare_parts,
    has_corrector,
    parts_text,
    passed_through_reason,
    passed_through_text,
)
from fmu_greybox.workflow.train import (
    stage_correctors,
    terms_per_stage,
    train_model,
    with_inducing,
)

ROOT = Path(__file__).resolve().parents[1]
OUTPUTS = ["spool_position", "ram_position", "itfv_pressure"]
DT = 1e-3


def terms() -> list:
    """A delayed command, a fed-back friction force, and a sensor delay from stage 1 on."""
    return [
        InputDelay(input="valve_current", delay=0.0025),
        CoulombForce(input="load_force", source="ram_velocity", force=400.0, smoothing=2e-3),
        SensorDelay(outputs=("ram_position", "itfv_pressure"), delay=0.002, entry=1),
    ]


def stepped(model: NamedModel, u: np.ndarray) -> np.ndarray:
    return np.array([model.step(row).copy() for row in u])


def named(archive, u: np.ndarray) -> NamedModel:
    return NamedModel(
        archive,
        INPUTS,
        OUTPUTS,
        DT,
        terms(),
        [0, 1, 2],
        start_values=dict(zip(INPUTS, u[0], strict=True)),
    )


def test_stepping_equals_the_batch_run_and_differs_from_plain(
    whitebox_archive, actuator_inputs
) -> None:
    archive, u = whitebox_archive, actuator_inputs
    with named(archive, u) as model:
        y = np.vstack([model.outputs().copy(), stepped(model, u[:-1])])
    batch = simulate_with_terms(archive, INPUTS, u, DT, OUTPUTS, terms(), stages=[0, 1, 2])
    np.testing.assert_array_equal(y, batch)
    plain = simulate_with_terms(archive, INPUTS, u, DT, OUTPUTS)
    assert np.max(np.abs(y[:, 1] - plain[:, 1])) > 1e-4  # the terms act (ram position, m)
    # the sensor delay enters at stage 1: the spool position only sees the stage-0 terms
    stage0 = simulate_with_terms(archive, INPUTS, u, DT, OUTPUTS, terms()[:2])
    np.testing.assert_array_equal(y[:, 0], stage0[:, 0])


def test_restored_state_continues_identically_in_another_instance(
    whitebox_archive, actuator_inputs
) -> None:
    archive, u = whitebox_archive, actuator_inputs
    with named(archive, u) as first, named(archive, u) as second:
        stepped(first, u[:250])
        saved = json.loads(json.dumps(first.state()))  # plain data
        after = stepped(first, u[250:400])
        second.restore(saved)
        np.testing.assert_array_equal(stepped(second, u[250:400]), after)
        first.restore(saved)
        np.testing.assert_array_equal(stepped(first, u[250:400]), after)


def test_reset_starts_over_with_the_terms_memory_cleared(whitebox_archive, actuator_inputs) -> None:
    archive, u = whitebox_archive, actuator_inputs
    with named(archive, u) as model:
        before = stepped(model, u[:200])
        model.reset(dict(zip(INPUTS, u[0], strict=True)), 0.0)
        np.testing.assert_array_equal(stepped(model, u[:200]), before)


def test_terms_acting_on_missing_variables_are_refused(whitebox_archive) -> None:
    archive = whitebox_archive
    check_terms(terms(), archive, 3)
    with pytest.raises(ConfigError, match=r"input 'valve_cmd'.*does not have"):
        check_terms([InputGain(input="valve_cmd", gain=0.1)], archive, 3)
    with pytest.raises(ConfigError, match=r"variable 'ram_speed'"):
        check_terms([CoulombForce(input="load_force", source="ram_speed")], archive, 3)
    with pytest.raises(ConfigError, match="enters at stage 3; the project has 3 stages"):
        check_terms([InputGain(input="valve_current", entry=3)], archive, 3)


def test_diagnosis_files_that_are_no_diagnosis_are_refused(tmp_path: Path) -> None:
    bad = tmp_path / "diagnosis.json"
    bad.write_text("{not json")
    with pytest.raises(ConfigError, match=r"diagnosis\.json: unreadable"):
        read_terms(bad)
    bad.write_text(json.dumps({"verdict": "x"}))
    with pytest.raises(ConfigError, match="findings: no list of findings"):
        read_terms(bad)
    bad.write_text(json.dumps({"findings": [{"effect": "offset", "terms": [{"kind": "Eval"}]}]}))
    with pytest.raises(ConfigError, match="unknown term kind 'Eval'"):
        read_terms(bad)
    good = {
        "findings": [
            {
                "effect": "gain_error",
                "terms": [InputGain(input="valve_current", gain=0.05).to_dict()],
            },
            {"effect": "unexplained", "terms": []},
        ]
    }
    bad.write_text(json.dumps(good))
    assert read_terms(bad) == [InputGain(input="valve_current", gain=0.05)]


@pytest.fixture(scope="module")
def termed(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A small grey-box trained on white-box + terms, saved, exported; and a validation run."""
    folder = tmp_path_factory.mktemp("termed")
    config = with_inducing(load_config(ROOT / "bench_configs" / "hydraulic_actuator.toml"), 30)
    config = dataclasses.replace(config, gp=dataclasses.replace(config.gp, max_iter=15))
    recording = synth_recording(3.0, seed=21)
    model = train_model(config, recording, terms=terms(), ship="terms+correctors")
    save_model(model, folder / "model")
    fmu = export_greybox(folder / "model", folder / "greybox.fmu", author="tests").path
    return {
        "model_dir": folder / "model",
        "fmu": fmu,
        "validation": synth_recording(1.0, 22),
        "recording": recording,
        "folder": folder,
        "config": config,
        "model": model,
    }


@pytest.mark.parametrize(
    ("factor", "equal"), [(1.0 + 0.8 * EQUAL_MARGIN, True), (1.0 + 1.2 * EQUAL_MARGIN, False)]
)
def test_parts_within_the_margin_are_equally_good(factor: float, equal: bool) -> None:
    """A part whose score is within ``EQUAL_MARGIN`` of the best's is listed as equally good
    and the printed line says so; one beyond it is not; the best still ships."""
    rng = np.random.default_rng(3)
    recorded = rng.normal(size=(400, 2))
    error = rng.normal(size=(400, 2))
    predictions = {
        "terms": recorded + error,
        "terms+correctors": recorded + factor * error,
        "correctors": recorded + 3.0 * error,
    }
    scale = {"A": 1.0, "B": 1.0}
    parts = compare_parts(["A", "B"], recorded, predictions, scale, first_row=100)
    assert parts.best == "terms" and parts.shipped == {"A": "terms", "B": "terms"}
    assert parts.score["terms+correctors"] == pytest.approx(factor * parts.score["terms"])
    payload = parts.to_dict()
    assert payload["equally_good"] == (["terms+correctors"] if equal else [])
    assert payload["equal_margin"] == EQUAL_MARGIN
    line = parts_text(payload)  # train's console line and the reports' sentence
    assert line.startswith("error score (nRMSE, lower is better): ")
    assert (f"as good within {100 * EQUAL_MARGIN:.0f} %: named terms + correctors" in line) is equal
    assert line.endswith("; shipped: A named terms alone, B named terms alone")
    # the terminal and the report say why the correctors are off: here the terms won
    assert "chose no corrector" in passed_through_reason(payload)
    lost = passed_through_reason({**payload, "shipped": "terms+correctors"})
    assert lost == passed_through_reason({}) and "free-run check" in lost
    # stage by stage: a part without a corrector, or a corrector that lost
    mixed = {**payload, "shipped": {"A": "terms", "B": "terms+correctors"}}
    assert passed_through_text(mixed, ["A", "B"]) == (
        "A (the held-out comparison of the parts chose no corrector); "
        f"B ({passed_through_reason({})})"
    )


def _stage_errors(scales: dict[str, list[float]], rows: int = 400) -> tuple[dict, dict]:
    """RMSE in total and per block of parts whose error has the given scale in each of four
    consecutive blocks (white noise, the same draw for every part)."""
    noise = np.random.default_rng(4).normal(size=rows)
    recorded = np.zeros(rows)
    total, blocks = {}, {}
    for part, per_block in scales.items():
        predicted = noise * np.repeat(per_block, rows // len(per_block))
        total[part] = float(np.sqrt(np.mean(predicted**2)))
        blocks[part] = block_rmse(predicted, recorded)
    return total, blocks


#: Error scales of the white-box and the terms in each of four blocks, shared by the cases.
PLAIN = {"white-box": [3.0] * 4, "terms": [1.0] * 4}


@pytest.mark.parametrize(
    ("scales", "chosen"),
    [
        # both better than the terms, by less than the margin
        ({**PLAIN, "terms+correctors": [0.97] * 4}, "terms"),
        # both better by more than the margin overall, but in only two blocks of four
        ({**PLAIN, "terms+correctors": [0.05, 0.9, 1.05, 1.05]}, "terms"),
        # both better by more than the margin in every block
        ({**PLAIN, "terms+correctors": [0.5] * 4}, "terms+correctors"),
        # physics and data equally good: the physics
        ({**PLAIN, "correctors": [0.99] * 4}, "terms"),
        # nothing beats the white-box clearly: the white-box alone
        ({"white-box": [1.0] * 4, "terms": [0.97] * 4, "correctors": [1.2] * 4}, "white-box"),
    ],
)
def test_a_stage_ships_the_simplest_part_the_best_does_not_beat_clearly(scales, chosen) -> None:
    total, blocks = _stage_errors(scales)
    assert choose_stage_part(total, blocks) == chosen


def _round_trips_without_correctors(model, validation, folder: Path) -> None:
    """A model whose every stage is passed through, without correctors: saved, loaded and
    exported, the FMU gives the master's outputs (the white-box with its terms)."""
    save_model(model, folder / "model")
    assert not list((folder / "model").glob("stage_*"))
    assert load_model(folder / "model").chain.correctors_ == [None, None, None]
    fmu = export_greybox(folder / "model", folder / "terms.fmu", author="tests").path
    result = simulate_fmu(
        str(fmu),
        stop_time=validation.time[-1],
        step_size=DT,
        output_interval=DT,
        input=input_signal(validation),
    )
    run = master_run(folder / "model", validation)
    for q, name in enumerate(STAGE_OUTPUTS):
        assert_close(result[name][1:], run.mean[:, q], name)
        assert_close(result[name + "_wb"][1:], run.whitebox[:, q], name + "_wb")


def test_train_with_terms_compares_its_parts_forward_in_time(termed, tmp_path) -> None:
    """Correctors trained on the first half of the training rows, terms alone and both are
    free-run over every later row; the comparison is kept, ``best`` is the lowest score, the
    shipped model is trained on all the training rows, and ``--ship terms`` writes the named
    white-box with every corrector passed through."""
    model, recording = termed["model"], termed["recording"]
    parts = model.training.parts
    assert set(parts["shipped"].values()) == {"terms+correctors"}  # --ship on every stage
    assert parts["best"] == min(parts["score"], key=parts["score"].__getitem__)
    assert set(parts["score"]) == set(STAGE_PARTS)
    n = recording.n_samples
    split = split_row(model.config, n)
    config = model.config
    half = split_row(dataclasses.replace(config, train_fraction=config.train_fraction / 2), n)
    assert model.training.train_rows == split + 1
    assert parts["trained_rows"] == [0, half]
    first = parts["held_out_rows"][0]
    assert parts["held_out_rows"] == [half + 1, n - 1] and first == half + 1
    with open_fmu(model.whitebox_fmu) as archive:
        named_run = simulate_with_terms(
            archive, INPUTS, input_rows(recording), DT, STAGE_OUTPUTS, terms(), stages=[0, 1, 2]
        )
        data = prepare(config, model.chain, archive, recording, terms=terms())
        noise = estimate_noise(config, model.chain, archive, data, terms())
    # the parts are judged in noise units, whitened against the drift of the inputs' noise
    judged = noise.judge()(data.outputs[first:] - named_run[first:])
    for q, stage in enumerate(model.chain.stage_names):
        column = model.config.signals[model.chain.target_signals[q]].column
        error = np.sqrt(np.mean((named_run[first:, q] - recording[column][first:]) ** 2))
        row = parts["stages"][stage]
        assert row["terms_rmse"] == pytest.approx(error, rel=1e-9)
        judged_rms = np.sqrt(np.mean(judged[:, q] ** 2))
        assert row["judged"]["terms"] == pytest.approx(judged_rms, rel=1e-6)
        assert row["best"] == min(STAGE_PARTS, key=lambda part: row[f"{part}_rmse"])
        assert len(row["blocks"]["terms"]) == len(row["judged_blocks"]["terms"]) == BLOCKS
    alone = train_model(termed["config"], recording, terms=terms(), ship="terms")
    assert not alone.chain.active_.any() and alone.terms == terms()
    # no corrector is fitted for what never runs; the folder and the exported FMU do without
    assert alone.chain.correctors_ == [None, None, None]
    _round_trips_without_correctors(alone, termed["validation"], tmp_path)
    assert alone.training.parts["score"] == pytest.approx(parts["score"], rel=1e-9)
    # its σ describes what it ships, the terms alone (calibrated with every stage passed
    # through: σ = sqrt(b), 95 % of the training rows' white-box + terms residual inside
    # ±1.96σ), not the correctors it no longer uses
    trained = slice(alone.chain.history, split + 1)
    for q, stage in enumerate(alone.chain.stage_names):
        column = config.signals[alone.chain.target_signals[q]].column
        residual = recording[column][trained] - named_run[trained, q]
        sigma = np.sqrt(alone.chain.calibration_[q].residual_variance)
        inside = np.mean(np.abs(residual) <= 1.959963984540054 * sigma)
        assert inside == pytest.approx(0.95, abs=2e-3), stage
        assert alone.training.calibration_check[stage]["rmse"] == pytest.approx(
            np.sqrt(np.mean(residual**2)), rel=1e-9
        )
    # calibrated on a recording instead: the same, over that recording's named run
    other = termed["validation"]
    on_other = train_model(
        termed["config"], recording, terms=terms(), ship="terms", calibration_recordings=[other]
    )
    with open_fmu(model.whitebox_fmu) as archive:
        other_run = simulate_with_terms(
            archive, INPUTS, input_rows(other), DT, STAGE_OUTPUTS, terms(), stages=[0, 1, 2]
        )
    for q, stage in enumerate(on_other.chain.stage_names):
        column = config.signals[on_other.chain.target_signals[q]].column
        residual = other[column][on_other.chain.history :] - other_run[on_other.chain.history :, q]
        sigma = np.sqrt(on_other.chain.calibration_[q].residual_variance)
        inside = np.mean(np.abs(residual) <= 1.959963984540054 * sigma)
        assert inside == pytest.approx(0.95, abs=2e-3), stage
        assert on_other.training.calibration_check[stage]["source"] == "recordings"
    plain = train_model(termed["config"], recording, terms=terms(), ship="correctors")
    assert plain.terms == []
    assert set(plain.training.parts["shipped"].values()) == {"correctors"}
    with pytest.raises(ConfigError, match="'all' is not a part to ship"):
        train_model(termed["config"], recording, terms=terms(), ship="all")


def test_a_model_carries_its_terms_through_save_load_and_into_the_master(termed) -> None:
    model = load_model(termed["model_dir"])
    assert model.terms == terms()
    validation = termed["validation"]
    run = master_run(termed["model_dir"], validation)
    with open_fmu(model.whitebox_fmu) as archive:
        expected = simulate_with_terms(
            archive, INPUTS, input_rows(validation), DT, OUTPUTS, terms(), stages=[0, 1, 2]
        )
    np.testing.assert_array_equal(run.whitebox, expected[1:])


def test_exported_fmu_with_terms_gives_the_masters_outputs(termed) -> None:
    fmu, validation = termed["fmu"], termed["validation"]
    assert validate_fmu(str(fmu)) == []
    result = simulate_fmu(
        str(fmu),
        stop_time=validation.time[-1],
        step_size=DT,
        output_interval=DT,
        input=input_signal(validation),
    )
    run = master_run(termed["model_dir"], validation)
    for q, name in enumerate(STAGE_OUTPUTS):
        assert_close(result[name][1:], run.mean[:, q], name)
        assert_close(result[name + "_std"][1:], run.std[:, q], name + "_std")
        assert_close(result[name + "_wb"][1:], run.whitebox[:, q], name + "_wb")
    with zipfile.ZipFile(fmu) as archive:
        xml = archive.read("modelDescription.xml")
    annotated = etree.fromstring(xml).findall(".//GreyBox/NamedTerm")
    assert [(t.get("effect"), t.get("stage")) for t in annotated] == [
        ("time_delay", "EHV"),
        ("coulomb_friction", "EHV"),
        ("time_delay", "RAM"),
    ]


def test_exported_fmu_state_with_terms_restores_identically(termed) -> None:
    rows = input_rows(termed["validation"])
    slave = Slave(termed["fmu"], "termed", rows)
    try:
        slave.run(rows[:300])
        state = slave.slave.getFMUstate()
        after = slave.run(rows[300:500])
        slave.slave.setFMUstate(state)
        slave.k = 300
        np.testing.assert_array_equal(slave.run(rows[300:500]), after)
        slave.slave.freeFMUstate(state)
    finally:
        slave.close()


def test_train_command_folds_a_diagnosis_terms(termed, tmp_path: Path) -> None:
    diagnosis = tmp_path / "diagnosis.json"
    diagnosis.write_text(
        json.dumps(
            {
                "findings": [
                    {"effect": "coulomb_friction", "terms": [terms()[1].to_dict()]},
                    {"effect": "none", "terms": []},
                ]
            }
        )
    )
    recording = save_recording(termed["recording"], tmp_path / "rec.csv")
    result = CliRunner().invoke(
        main,
        [
            "train",
            str(ROOT / "bench_configs" / "hydraulic_actuator.toml"),
            "--recording",
            str(recording),
            "--inducing",
            "10",
            "--terms",
            str(diagnosis),
            "--out",
            str(tmp_path / "model"),
        ],
    )
    assert result.exit_code == 0, result.output
    model = load_model(tmp_path / "model")
    parts = model.training.parts
    line = f"{TRAINING_PARTS}: {parts_text(parts)}."  # the demo's wording, one function
    assert line in result.output.splitlines()
    assert f"best: {PART_WORDS[parts['best']]}" in line
    assert all(f"{stage} {PART_WORDS[part]}" in line for stage, part in parts["shipped"].items())
    assert ("as good within" in line) == bool(parts["equally_good"])
    chosen = [parts["shipped"][stage] for stage in model.chain.stage_names]
    assert model.terms == terms_per_stage([terms()[1]], chosen)
    assert model.chain.active_.tolist() == [
        has_corrector(part) and model.training.free_run_check[stage]["active"]
        for stage, part in zip(model.chain.stage_names, chosen, strict=True)
    ]
    assert ("named terms: coulomb_friction" in result.output) == bool(model.terms)


def test_train_with_terms_optimises_each_choice_once(termed, monkeypatch) -> None:
    """The optimisations ``train --terms`` runs: per comparison chain and stage, one per
    candidate target (residual, increment) and one on all its rows; per stage of the model
    that ships one (its target is the comparison chain's: no candidates again), and per
    active stage one for the calibration's second half (its first half is the comparison
    chain's rows: that fit is shared, ``model/fit_cache.py``)."""
    calls: list[int] = []
    fit = SparseGPR.fit

    def counted(self, X, y, progress=None, start=None):
        calls.append(self.max_iter)
        return fit(self, X, y, progress=progress, start=start)

    monkeypatch.setattr(SparseGPR, "fit", counted)
    recording = termed["recording"]
    model = train_model(termed["config"], recording, terms=terms(), ship="terms+correctors")
    stages = len(model.chain.stages)
    active = int(model.chain.active_.sum())
    assert all(max_iter > 0 for max_iter in calls)
    assert len(calls) == 2 * stages * 3 + stages + active
    selection = model.training.target_selection
    assert set(selection) == {s.name for s in model.chain.stages}  # the comparison's choice


def test_a_stage_ship_setting_overrides_the_comparison_and_is_checked() -> None:
    """``[[stages]] ship`` names a stage's part: the comparison keeps it for that stage (and
    still chooses the others); without named terms a stage shipping ``white-box`` has its
    corrector off, and one shipping ``terms`` is refused with the field to change."""
    config = load_config(ROOT / "bench_configs" / "hydraulic_actuator.toml")
    names = [s.name for s in config.stages]
    rng = np.random.default_rng(5)
    recorded = rng.normal(size=(400, 3))
    error = rng.normal(size=(400, 3))
    predictions = {
        "white-box": recorded + 3.0 * error,
        "terms": recorded + error,
        "correctors": recorded + 2.0 * error,
        "terms+correctors": recorded + 0.5 * error,
    }
    scale = dict.fromkeys(names, 1.0)
    forced = {names[1]: "terms"}
    parts = compare_parts(names, recorded, predictions, scale, 100, stage_ship=forced)
    assert parts.shipped == {
        names[0]: "terms+correctors",
        names[1]: "terms",
        names[2]: "terms+correctors",
    }
    # --ship overrides the stage settings on every stage
    everywhere = compare_parts(names, recorded, predictions, scale, 100, "terms", forced)
    assert set(everywhere.shipped.values()) == {"terms"}
    stages = list(config.stages)
    stages[0] = dataclasses.replace(stages[0], ship="white-box")
    assert stage_correctors(dataclasses.replace(config, stages=tuple(stages))) == [
        False,
        True,
        True,
    ]
    stages[2] = dataclasses.replace(stages[2], ship="terms")
    with pytest.raises(ConfigError, match=r"ships 'terms', but no named terms") as caught:
        stage_correctors(dataclasses.replace(config, stages=tuple(stages)))
    assert caught.value.field == "stages[2].ship"
    raw = tomllib.loads((ROOT / "bench_configs" / "hydraulic_actuator.toml").read_text())
    raw["stages"][0]["ship"] = "corrector"
    with pytest.raises(ConfigError, match=r"'corrector' is not one of .*did you mean 'correctors'"):
        parse_config(raw)
