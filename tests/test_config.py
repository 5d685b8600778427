"""Project-file validation: every error names its field and says how to mend it."""

from __future__ import annotations

import copy
import dataclasses
import tomllib
from pathlib import Path

import pytest

from fmu_greybox.errors import ConfigError, UnitMismatchError
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.project.config import load_config, parse_config

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "bench_configs" / "hydraulic_actuator.toml"


@pytest.fixture()
def raw() -> dict:
    return tomllib.loads(REFERENCE.read_text())


def _error(raw: dict) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        parse_config(raw, REFERENCE)
    return info.value


def test_reference_project_loads_in_paper_order() -> None:
    config = load_config(REFERENCE)
    assert [s.name for s in config.stages] == ["EHV", "RAM", "ITFV"]
    assert config.stage("RAM").feeds_from == ("EHV",)
    assert config.fmu == "builtin:HydraulicActuator"
    assert config.signals["valve_current"].role == "current"


def test_positioner_project_loads() -> None:
    config = load_config(ROOT / "bench_configs" / "positioner.toml")
    assert len(config.stages) >= 2


def test_reference_project_matches_its_fmu(whitebox_fmu: Path) -> None:
    with open_fmu(whitebox_fmu) as archive:
        load_config(REFERENCE).check_against_fmu(archive)


@pytest.mark.parametrize(
    ("mutate", "field", "words"),
    [
        (lambda r: r.update(stagse=[]), "stagse", "did you mean 'stages'"),
        (lambda r: r.pop("whitebox"), "whitebox", "missing"),
        (lambda r: r["whitebox"].pop("fmu"), "whitebox.fmu", "required"),
        (lambda r: r["whitebox"].update(step=-1.0), "whitebox.step", "positive"),
        (lambda r: r["whitebox"].update(step="fast"), "whitebox.step", "a number"),
        (lambda r: r.update(format_version=7), "format_version", "not supported"),
        (
            lambda r: r["signals"]["load_force"].update(role="forse"),
            "signals.load_force.role",
            "did you mean 'force'",
        ),
        (
            lambda r: r["signals"]["load_force"].update(unit="Pa"),
            "signals.load_force.unit",
            "not a unit of a force",
        ),
        (lambda r: r["signals"].update(extra=3), "signals.extra", "must be a table"),
        (lambda r: r.update(signals={}), "signals", "no signals"),
        (lambda r: r.update(stages=[]), "stages", "no stages"),
        (
            lambda r: r["stages"][1].update(target="ram_positon"),
            "stages[1].target",
            "did you mean 'ram_position'",
        ),
        (
            lambda r: r["stages"][1].update(inputs=["load"]),
            "stages[1].inputs",
            "not a declared signal",
        ),
        (lambda r: r["stages"][1].update(inputs="load_force"), "stages[1].inputs", "list of names"),
        (
            lambda r: r["stages"][1].update(feeds_from=["EHW"]),
            "stages[1].feeds_from",
            "did you mean 'EHV'",
        ),
        (
            lambda r: r["stages"][1].update(feeds_from=["RAM"]),
            "stages[1].feeds_from",
            "cannot feed itself",
        ),
        (
            lambda r: (
                r["stages"][1].update(feeds_from=[]),
                r["stages"][0].update(feeds_from=["RAM"]),
            ),
            "stages[0].feeds_from",
            "listed after it",
        ),
        (lambda r: r["stages"][2].update(name="EHV"), "stages[2].name", "used twice"),
        (lambda r: r["stages"][0].update(lags=0), "stages[0].lags", "outside 1..10"),
        (
            lambda r: r["stages"][0].update(target_mode="delta"),
            "stages[0].target_mode",
            "not one of",
        ),
        (
            lambda r: r["stages"][0].update(feed_rates="yes"),
            "stages[0].feed_rates",
            "true or false",
        ),
        (lambda r: r["gp"].update(inducing=0), "gp.inducing", "at least 1"),
        (lambda r: r["gp"].update(kernel="matern"), "gp.kernel", "not available"),
        (lambda r: r["gp"].update(inducing_method="random"), "gp.inducing_method", "not one of"),
        (lambda r: r["gp"].update(target="delta"), "gp.target", "not one of"),
        (lambda r: r["gp"].update(feeds="predicted"), "gp.feeds", "not one of recorded, free_run"),
        (lambda r: r["stages"][1].update(differences=11), "stages[1].differences", "outside 0..10"),
        (lambda r: r["stages"][1].update(differences=1.5), "stages[1].differences", "integer"),
        (lambda r: r["split"].update(train_fraction=1.5), "split.train_fraction", "between 0"),
        (lambda r: r["recording"].update(resample=0.0), "recording.resample", "positive"),
        (
            lambda r: r["whitebox"].update(parameters={"bulk_modulus": "high"}),
            "whitebox.parameters.bulk_modulus",
            "a number",
        ),
    ],
)
def test_every_error_names_its_field(raw: dict, mutate, field: str, words: str) -> None:
    mutate(raw)
    error = _error(raw)
    assert error.field == field
    assert words in str(error)
    assert str(REFERENCE) in str(error)


def test_cycle_is_reported_as_a_cycle(raw: dict) -> None:
    raw["stages"][0]["feeds_from"] = ["ITFV"]
    error = _error(raw)
    assert "cycle" in str(error)
    assert "EHV -> ITFV -> EHV" in str(error) or "ITFV -> EHV -> ITFV" in str(error)


def test_invalid_toml_and_unreadable_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[whitebox\nfmu = 1")
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_config(bad)
    with pytest.raises(ConfigError, match="no such project file; the built-in projects are"):
        load_config(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="cannot read the project file: Is a directory"):
        load_config(tmp_path)


def test_a_unit_may_be_left_out_only_where_the_fmu_declares_none(
    raw: dict, whitebox_fmu: Path
) -> None:
    raw["signals"]["load_force"].pop("unit")
    config = parse_config(raw, REFERENCE)
    assert config.signals["load_force"].unit == ""
    assert parse_config(config.to_dict(), REFERENCE) == config
    with open_fmu(whitebox_fmu) as archive, pytest.raises(ConfigError) as info:
        config.check_against_fmu(archive)
    assert info.value.field == "signals.load_force.unit"
    assert "add unit = 'N'" in str(info.value)


def test_units_are_checked_against_the_fmu(raw: dict, whitebox_fmu: Path) -> None:
    raw["signals"]["supply_pressure"]["unit"] = "bar"
    config = parse_config(raw, REFERENCE)
    with open_fmu(whitebox_fmu) as archive, pytest.raises(UnitMismatchError) as info:
        config.check_against_fmu(archive)
    assert info.value.field == "signals.supply_pressure.unit"
    assert "'bar'" in str(info.value) and "'Pa'" in str(info.value)


def test_unknown_fmu_variables_are_named(raw: dict, whitebox_fmu: Path) -> None:
    broken = copy.deepcopy(raw)
    broken["signals"]["valve_current"]["variable"] = "valve_curent"
    with open_fmu(whitebox_fmu) as archive:
        with pytest.raises(ConfigError, match="did you mean 'valve_current'"):
            parse_config(broken, REFERENCE).check_against_fmu(archive)
        broken = copy.deepcopy(raw)
        broken["stages"][0]["whitebox_output"] = "valve_current"
        with pytest.raises(ConfigError, match="not an output"):
            parse_config(broken, REFERENCE).check_against_fmu(archive)
        broken = copy.deepcopy(raw)
        broken["whitebox"]["parameters"] = {"bulk_modulu": 1e9}
        with pytest.raises(ConfigError, match=r"whitebox\.parameters\.bulk_modulu"):
            parse_config(broken, REFERENCE).check_against_fmu(archive)


@pytest.mark.parametrize("name", ["hydraulic_actuator.toml", "positioner.toml"])
def test_project_tables_are_derived_from_the_typed_fields(name):
    """One source of truth: the stored tables round-trip, and a replaced setting is stored."""
    config = load_config(ROOT / "bench_configs" / name)
    assert parse_config(config.to_dict(), config.path) == config
    changed = dataclasses.replace(config, gp=dataclasses.replace(config.gp, inducing=7))
    assert changed.to_dict()["gp"]["inducing"] == 7
    assert parse_config(changed.to_dict(), config.path).gp.inducing == 7
