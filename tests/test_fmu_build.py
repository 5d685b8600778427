"""The builder: archive layout, model descriptions, the variable table, errors, genericity."""

from __future__ import annotations

import shutil
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import INPUTS, OUTPUTS, unpacked
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Slave
from fmpy.model_description import read_build_description
from fmpy.validation import validate_fmu

from fmu_greybox.errors import FmuBuildError
from fmu_greybox.fmi import platforms, variables
from fmu_greybox.fmi.build import (
    REFERENCE_MODEL_DIR,
    build_fmu,
    load_variable_table,
)
from fmu_greybox.fmi.platforms import fmi2_platform

TRUTH_EFFECTS = (
    "gain_error",
    "offset",
    "deadband",
    "coulomb_friction",
    "stribeck_friction",
    "internal_leakage",
    "compliance",
    "supply_pressure_droop",
    "time_delay",
    "friction_asymmetry",
)


@pytest.mark.parametrize("identifier", ["HydraulicActuator", "HydraulicActuatorTruth"])
def test_archive_layout_and_validation(fmu_dir: Path, identifier: str) -> None:
    fmu = fmu_dir / f"{identifier}.fmu"
    folder, extension = fmi2_platform()
    with zipfile.ZipFile(fmu) as archive:
        names = set(archive.namelist())
    sources = {n for n in names if n.startswith("sources/")}
    assert names - sources == {
        "modelDescription.xml",
        f"binaries/{folder}/{identifier}{extension}",
        "documentation/README.md",
        "documentation/index.html",
    }
    assert {"sources/model.c", "sources/config.h", "sources/fmu_variables.h"} <= sources
    configuration = read_build_description(str(fmu))[0]  # checked against FMI's schema
    assert configuration.modelIdentifier == identifier
    listed = {f"sources/{n}" for s in configuration.sourceFileSets for n in s.sourceFiles}
    assert "sources/model.c" in listed and listed <= sources
    assert validate_fmu(str(fmu)) == []
    assert not list(fmu_dir.glob(".*"))  # no temporary left behind


@pytest.mark.parametrize("identifier", ["HydraulicActuator", "HydraulicActuatorTruth"])
def test_interface(fmu_dir: Path, identifier: str) -> None:
    description = read_model_description(str(fmu_dir / f"{identifier}.fmu"))
    cs = description.coSimulation
    assert cs.modelIdentifier == identifier
    assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate
    assert cs.canHandleVariableCommunicationStepSize
    units = {u.name for u in description.unitDefinitions}
    by_name = {v.name: v for v in description.modelVariables}
    assert [v.name for v in description.modelVariables if v.causality == "input"] == list(INPUTS)
    assert [v.name for v in description.modelVariables if v.causality == "output"] == list(OUTPUTS)
    for v in description.modelVariables:
        assert v.description, v.name
        assert v.unit in units, v.name
    for v in description.modelVariables:
        if v.causality == "parameter":
            fixed = {"solver_step", "initial_ram_position"}
            assert v.variability == ("fixed" if v.name in fixed else "tunable"), v.name
    effects = [name for name in TRUTH_EFFECTS if name in by_name]
    if identifier == "HydraulicActuatorTruth":
        assert effects == list(TRUTH_EFFECTS)
        assert all(float(by_name[name].start) == 0.0 for name in effects)
    else:
        assert effects == []
    assert {
        by_name[n].unit for n in ("valve_current", "supply_pressure", "load_force", "engage")
    } == {"mA", "Pa", "N", "1"}


def test_models_share_value_references_and_differ_in_guid(
    whitebox_fmu: Path, truth_fmu: Path
) -> None:
    white, _, white_refs = unpacked(whitebox_fmu)
    truth, _, truth_refs = unpacked(truth_fmu)
    assert white.guid != truth.guid
    assert all(truth_refs[name] == vr for name, vr in white_refs.items())
    assert set(truth_refs) - set(white_refs) == {
        *TRUTH_EFFECTS,
        "stribeck_velocity",
        "friction_smoothing_velocity",
    }


def test_model_structure_declares_direct_feedthrough(whitebox_fmu: Path) -> None:
    description, _, _ = unpacked(whitebox_fmu)
    feedthrough = {
        u.variable.name: sorted(d.name for d in u.dependencies) for u in description.outputs
    }
    assert feedthrough["load_flow"] == ["engage", "supply_pressure"]
    assert feedthrough["supply_flow"] == ["engage", "supply_pressure"]
    assert feedthrough["ram_position"] == []
    assert {u.variable.name for u in description.initialUnknowns} == set(OUTPUTS)


def test_build_is_deterministic_and_warning_free(tmp_path: Path, whitebox_fmu: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # compiler messages become warnings
        rebuilt = build_fmu(REFERENCE_MODEL_DIR, tmp_path)
    with zipfile.ZipFile(rebuilt) as a, zipfile.ZipFile(whitebox_fmu) as b:
        assert a.read("modelDescription.xml") == b.read("modelDescription.xml")


def test_readme_documents_every_parameter() -> None:
    table = load_variable_table(REFERENCE_MODEL_DIR / "variables.toml")
    readme = (REFERENCE_MODEL_DIR / "README.md").read_text(encoding="utf-8")
    for v in table.variables:
        assert f"`{v.name}`" in readme, v.name


def test_unit_parser() -> None:
    assert variables.parse_unit("m3/(s.Pa)") == ({"m": 4, "kg": -1, "s": 1}, 1.0, 0.0)
    assert variables.parse_unit("Pa.s/m3") == ({"kg": 1, "m": -4, "s": -1}, 1.0, 0.0)
    assert variables.parse_unit("m/mA") == ({"m": 1, "A": -1}, 1e3, 0.0)
    assert variables.parse_unit("1") == ({}, 1.0, 0.0)
    assert variables.parse_unit("degC") == ({"K": 1}, 1.0, 273.15)
    with pytest.raises(FmuBuildError, match="unknown unit symbol 'furlong'"):
        variables.parse_unit("furlong/s")


def _copy_model(tmp_path: Path) -> Path:
    model = tmp_path / "HydraulicActuator"
    shutil.copytree(REFERENCE_MODEL_DIR, model)
    return model


def test_compile_error_carries_compiler_output(tmp_path: Path) -> None:
    model = _copy_model(tmp_path)
    with (model / "model.c").open("a") as stream:
        stream.write("\nthis is not C;\n")
    with pytest.raises(FmuBuildError, match=r"(?s)compiling HydraulicActuator failed.*error"):
        build_fmu(model, tmp_path / "out")
    assert not (tmp_path / "out" / "HydraulicActuator.fmu").exists()


def test_table_errors_say_what_to_mend(tmp_path: Path) -> None:
    model = _copy_model(tmp_path)
    table = model / "variables.toml"
    text = table.read_text()
    table.write_text(text.replace('unit = "kg/m3"\n', "", 1))
    with pytest.raises(FmuBuildError, match=r"fluid_density.*unit is required"):
        build_fmu(model, tmp_path)
    table.write_text(text)
    with pytest.raises(FmuBuildError, match="no model 'Nope'"):
        build_fmu(model, tmp_path, "Nope")


def test_unsupported_platform(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(platforms.platform, "machine", lambda: "aarch64")
    monkeypatch.setattr(platforms.sys, "platform", "linux")
    with pytest.raises(FmuBuildError, match="no binary folder for linux on aarch64"):
        fmi2_platform()


# A second, unrelated model dropped in one folder: an undamped oscillator exercising every
# variable type and model memory, to show the framework and builder are generic.
OSCILLATOR_TOML = """
[fmu]
model_name = "Oscillator"
description = "Undamped mass-spring oscillator"
default_experiment = { stop_time = 1.0, step_size = 1e-2 }

[[model]]
identifier = "Oscillator"

[[variable]]
name = "force"
causality = "input"
variability = "continuous"
unit = "N"
start = 0.0
description = "External force"

[[variable]]
name = "enabled"
causality = "input"
variability = "discrete"
type = "Boolean"
start = true
description = "Whether the force acts"

[[variable]]
name = "position"
causality = "output"
variability = "continuous"
unit = "m"
description = "Position"
dependencies = []

[[variable]]
name = "steps"
causality = "output"
variability = "discrete"
type = "Integer"
description = "Internal steps taken"
dependencies = []

[[variable]]
name = "stiffness"
causality = "parameter"
variability = "tunable"
unit = "N/m"
start = 4.0
min = 0.0
description = "Spring stiffness"

[[variable]]
name = "label"
causality = "parameter"
variability = "fixed"
type = "String"
start = "spring"
description = "Free text"

[[variable]]
name = "solver_step"
causality = "parameter"
variability = "fixed"
unit = "s"
start = 1e-3
description = "Internal step"
"""

OSCILLATOR_CONFIG = """
enum { S_X, S_V, N_STATES };
#define MODEL_HAS_MEMORY
typedef struct { int steps; } ModelMemory;
"""

OSCILLATOR_MODEL = """
#include <stddef.h>
#include <stdio.h>
#include "fmu_framework.h"
const double model_state_nominal[N_STATES] = {1.0, 1.0};
int model_check(const SimData *d, char *message, size_t size) {
    (void)d, (void)message, (void)size;
    return 0;
}
void model_initialize(SimData *d) {
    d->x[S_X] = 1.0;
    d->x[S_V] = 0.0;
    d->memory.steps = 0;
}
void model_derivatives(const SimData *d, const double x[N_STATES], double dx[N_STATES]) {
    dx[S_X] = x[S_V];
    dx[S_V] = (BOOLEAN(d, enabled) ? REAL(d, force) : 0.0) - REAL(d, stiffness) * x[S_X];
}
void model_project(const SimData *d, double x[N_STATES]) { (void)d, (void)x; }
int model_check_memory(const SimData *d, char *message, size_t size) {
    if (d->memory.steps >= 0) return 0;
    snprintf(message, size, "steps = %d is negative", d->memory.steps);
    return -1;
}
int model_after_step(SimData *d, char *message, size_t size) {
    (void)message, (void)size;
    d->memory.steps++;
    return 0;
}
void model_outputs(SimData *d) {
    REAL(d, position) = d->x[S_X];
    INTEGER(d, steps) = d->memory.steps;
}
"""


def test_a_second_model_builds_from_one_folder(tmp_path: Path) -> None:
    folder = tmp_path / "Oscillator"
    folder.mkdir()
    (folder / "variables.toml").write_text(OSCILLATOR_TOML)
    (folder / "config.h").write_text(OSCILLATOR_CONFIG)
    (folder / "model.c").write_text(OSCILLATOR_MODEL)

    fmu = build_fmu(folder, tmp_path / "out")
    assert validate_fmu(str(fmu)) == []
    result = simulate_fmu(
        str(fmu), stop_time=1.0, output_interval=0.01, output=["position", "steps"]
    )
    np.testing.assert_allclose(result["position"], np.cos(2.0 * result["time"]), atol=1e-8)
    assert result["steps"][-1] == 1000

    description = read_model_description(str(fmu))
    refs = {v.name: v.valueReference for v in description.modelVariables}
    slave = FMU2Slave(
        guid=description.guid,
        unzipDirectory=extract(str(fmu), unzipdir=str(tmp_path / "unpacked")),
        modelIdentifier="Oscillator",
        instanceName="oscillator",
    )
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setString([refs["label"]], ["tuned spring"])
    slave.exitInitializationMode()
    assert slave.getString([refs["label"]]) == [b"tuned spring"]
    slave.setBoolean([refs["enabled"]], [False])
    slave.setReal([refs["force"]], [100.0])
    slave.doStep(0.0, 0.5)
    assert slave.getReal([refs["position"]])[0] == pytest.approx(np.cos(1.0), abs=1e-8)
    assert slave.getBoolean([refs["enabled"]]) == [False]
    assert slave.getInteger([refs["steps"]]) == [500]
    slave.terminate()
    slave.freeInstance()
