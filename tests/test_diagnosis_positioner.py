"""The diagnosis on the electromechanical positioner (a second built-in white-box): a missing
friction named as a term, mis-set parameters calibrated through the FMU."""

from __future__ import annotations

from pathlib import Path

import pytest

from fmu_greybox.diagnosis import Diagnosis
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.builtin import model_fmus
from fmu_greybox.project.config import load_config
from fmu_greybox.synth.positioner import synthesise_positioner

PROJECT = Path(__file__).resolve().parents[1] / "bench_configs" / "positioner.toml"


def diagnose_positioner(effects: dict, seed: int) -> Diagnosis:
    """Diagnose an 8 s recording of the truth positioner with ``effects`` (noise scale 1)."""
    paths = model_fmus("ElectroMechanicalPositioner")
    with (
        open_fmu(paths["ElectroMechanicalPositionerTruth"]) as truth,
        open_fmu(paths["ElectroMechanicalPositioner"]) as whitebox,
    ):
        recording = synthesise_positioner(
            truth, whitebox, effects, seed=seed, duration=8.0, noise=1.0
        )
    return Diagnosis(load_config(PROJECT), greybox=None).fit(recording)


def test_missing_friction_is_found_on_the_positioner() -> None:
    diagnosis = diagnose_positioner({"coulomb_friction": 100.0}, seed=3)
    top = diagnosis.findings_[0]
    assert top.effect == "coulomb_friction"
    assert top.stage == diagnosis.origin_stage_
    assert top.magnitude["value"] == pytest.approx(100.0, rel=0.1)
    assert diagnosis.fit_["DRIVE"]["named_rmse"] < 0.5 * diagnosis.fit_["DRIVE"]["wb_rmse"]


@pytest.mark.parametrize(
    ("effects", "seed", "parameter", "relative_change"),
    [
        ({"gain_error": -0.1}, 7, "torque_constant", -0.1),  # torque (1 + g) k_t i
        ({"viscous_friction_extra": 250.0}, 3, "viscous_friction", 250.0 / 500.0),  # of 500
    ],
)
def test_mis_set_parameter_is_calibrated_through_the_positioner(
    effects: dict, seed: int, parameter: str, relative_change: float
) -> None:
    diagnosis = diagnose_positioner(effects, seed)
    top = diagnosis.findings_[0].to_dict()
    assert (top["effect"], top["parameter"]) == ("parameter_mismatch", parameter)
    assert top["magnitude"]["value"] == pytest.approx(relative_change, rel=0.1)
    assert diagnosis.fit_["DRIVE"]["named_rmse"] < 0.5 * diagnosis.fit_["DRIVE"]["wb_rmse"]
