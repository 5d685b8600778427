"""White-boxes of every accepted kind (``fmu_greybox/fmi/kinds.py``).

The reference actuator built as an FMI 3.0 co-simulation FMU (the framework's FMI 3.0 shell,
``fmu_sources/framework/fmi3``) is opened, stepped, diagnosed, trained on and exported as the
FMI 2.0 co-simulation build is. Both builds run the same C code, so "equal" here means equal
to the last bit where the same arithmetic runs (white-box outputs, trained parameters), and
to 1e-12 of each signal's scale where the numbers pass through an optimiser
(:func:`assert_close`).
"""

from __future__ import annotations

import dataclasses
import re
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from fmpy import simulate_fmu
from fmpy.validation import validate_fmu

from fmu_greybox.cli import main
from fmu_greybox.diagnosis import Diagnosis
from fmu_greybox.errors import ExportError, FmuArchiveError, FmuError
from fmu_greybox.export.fmu import export_greybox
from fmu_greybox.fmi.archive import open_fmu, real_outputs
from fmu_greybox.fmi.builtin import model_fmus, reference_project
from fmu_greybox.fmi.instance import Fmu3Instance, fmu_instance
from fmu_greybox.fmi.kinds import FMI2_CS, FMI3_CS
from fmu_greybox.model.native_run import run_native
from fmu_greybox.model.simulate import simulate_with_terms
from fmu_greybox.model.store import save_model
from fmu_greybox.model.terms import ParameterChange
from fmu_greybox.project.config import load_config, parse_config
from fmu_greybox.project.starter import starter_text
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise
from fmu_greybox.workflow.train import train_model, with_inducing

INPUTS = ("valve_current", "supply_pressure", "load_force", "engage")
OUTPUTS = ("spool_position", "ram_position", "itfv_pressure", "pressure_a")
DT = 1e-3
#: Largest difference allowed between the FMI 2.0 and FMI 3.0 paths where an optimiser runs,
#: relative to each signal's scale (the same arithmetic: in practice 0).
RTOL = 1e-12


@pytest.fixture(scope="module")
def fmi3_fmus() -> dict[str, Path]:
    """The reference actuator (white-box, truth) built as FMI 3.0 co-simulation FMUs."""
    return model_fmus("HydraulicActuator", FMI3_CS)


@pytest.fixture(scope="module")
def fmi3_whitebox(fmi3_fmus) -> Path:
    return fmi3_fmus["HydraulicActuator"]


def recording(whitebox_fmu: Path, truth_fmu: Path, effects: dict, seed: int, duration: float):
    profile = FlightTestProfile(duration=duration)
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        return synthesise(truth, whitebox, SynthRequest(effects, seed=seed, profile=profile))


def input_rows(n: int) -> np.ndarray:
    """A current chirp at the rated supply, shape (n, 4)."""
    t = np.arange(n) * DT
    current = 6.0 * np.sin(2 * np.pi * (1.0 + 4.0 * t) * t)
    return np.column_stack([current, np.full(n, 2.1e7), 1500.0 * np.ones(n), np.ones(n)])


def stepped(fmu: Path, rows: np.ndarray) -> np.ndarray:
    """The outputs after each row, stepped through :func:`fmu_instance`, shape (n, 4)."""
    with open_fmu(fmu) as archive, fmu_instance(archive, INPUTS, OUTPUTS) as instance:
        return np.array([instance.step(u, DT).copy() for u in rows])


def assert_close(got: np.ndarray, ref: np.ndarray, what: str, rtol: float = RTOL) -> None:
    scale = max(float(np.ptp(ref)), float(np.max(np.abs(ref))), 1e-300)
    worst = float(np.max(np.abs(np.asarray(got) - ref)))
    assert worst <= rtol * scale, f"{what}: max difference {worst:.3g}, scale {scale:.3g}"


# ------------------------------------------------------------------------ the FMU and its steps
def test_the_fmi3_build_passes_fmpy_validation_and_opens_as_fmi3(fmi3_fmus) -> None:
    for path in fmi3_fmus.values():
        assert validate_fmu(str(path)) == [], path
    with open_fmu(fmi3_fmus["HydraulicActuator"]) as archive:
        assert archive.kind == FMI3_CS
        assert (archive.unzip_dir / "binaries" / FMI3_CS.binary_folder).is_dir()
        position = archive.variable("ram_position")
        assert (position.type, position.unit, position.causality) == ("Real", "m", "output")
        assert archive.variable("time").causality == "independent"
        assert archive.inputs == list(INPUTS)


def test_the_fmu_build_command_builds_fmi3(tmp_path) -> None:
    done = CliRunner().invoke(main, ["fmu", "build", "--fmi", "3", "--out", str(tmp_path)])
    assert done.exit_code == 0, done.output
    path = tmp_path / "HydraulicActuator.fmu"
    assert f"built HydraulicActuator: {path} (FMI 3.0 co-simulation)" in done.output
    for name in ("HydraulicActuator", "HydraulicActuatorTruth"):
        with open_fmu(tmp_path / f"{name}.fmu") as archive:
            assert archive.kind == FMI3_CS


def test_an_fmi3_array_variable_is_not_taken_for_a_real(fmi3_whitebox, tmp_path) -> None:
    """Arrays (FMI 3.0 ``Dimension``) are exchanged with other calls than scalars: the archive
    names their type so that no role, binding or term reads one as a Real."""
    with zipfile.ZipFile(fmi3_whitebox) as source:
        xml = source.read("modelDescription.xml").decode()
        members = {name: source.read(name) for name in source.namelist()}
    tag = re.search(r'<Float64 name="pressure_b"[^>]*?(/>)', xml)
    xml = xml[: tag.start(1)] + '><Dimension start="2"/></Float64>' + xml[tag.end(1) :]
    members["modelDescription.xml"] = xml.encode()
    arrays = tmp_path / "arrays.fmu"
    with zipfile.ZipFile(arrays, "w", zipfile.ZIP_DEFLATED) as target:
        for name, data in members.items():
            target.writestr(name, data)
    with open_fmu(arrays) as archive:
        assert archive.variable("pressure_b").type == "Float64 array"
        assert "pressure_b" not in real_outputs(archive)
        assert "pressure_a" in real_outputs(archive)


def test_fmi3_steps_bit_for_bit_as_fmi2(whitebox_fmu, fmi3_whitebox) -> None:
    rows = input_rows(400)
    fmi2, fmi3 = stepped(whitebox_fmu, rows), stepped(fmi3_whitebox, rows)
    assert np.ptp(fmi2[:, 1]) > 1e-3  # the ram moved
    np.testing.assert_array_equal(fmi3, fmi2)


def test_an_fmi3_state_restores_and_serialises(fmi3_whitebox) -> None:
    rows = input_rows(300)
    with open_fmu(fmi3_whitebox) as archive, fmu_instance(archive, INPUTS, OUTPUTS) as inst:
        assert isinstance(inst, Fmu3Instance)
        for u in rows[:100]:
            inst.step(u, DT)
        snapshot, data, at = inst.get_state(), inst.serialize_state(), inst.time
        first = np.array([inst.step(u, DT).copy() for u in rows[100:]])
        inst.set_state(snapshot)
        inst.free_state(snapshot)
        again = np.array([inst.step(u, DT).copy() for u in rows[100:]])
        inst.deserialize_state(data, at)
        restored = np.array([inst.step(u, DT).copy() for u in rows[100:]])
    np.testing.assert_array_equal(again, first)
    np.testing.assert_array_equal(restored, first)


def test_fmi3_refusals_name_the_fmi3_call_and_the_reason(fmi3_whitebox) -> None:
    with open_fmu(fmi3_whitebox) as archive:
        with pytest.raises(FmuError, match=r"bulk_modulus = -1e\+09 must be positive") as info:
            fmu_instance(archive, INPUTS, OUTPUTS, parameters={"bulk_modulus": -1e9})
        assert (info.value.call, info.value.status) == ("fmi3ExitInitializationMode", "fmi3Error")
        assert "[fmi3Error] bulk_modulus" in str(info.value)  # the FMU's log, as FMI 3.0 words it
        with fmu_instance(archive, INPUTS, OUTPUTS) as inst:
            negative = r"communicationStepSize = -0\.001 s must be positive"
            with pytest.raises(FmuError, match=negative) as info:
                inst.step(input_rows(1)[0], -DT)
        assert (info.value.call, info.value.status) == ("fmi3DoStep", "fmi3Error")


def test_fmi3_runs_in_python_where_the_c_runner_cannot_load_it(whitebox_fmu, fmi3_whitebox):
    """Simulations with named terms step an FMI 3.0 white-box with fmpy (the C runner loads FMI
    2.0 only, and says so when asked): the numbers of the FMI 2.0 white-box in C."""
    rows = input_rows(300)
    terms = [ParameterChange(name="bulk_modulus", value=9e8)]
    runs = {}
    for kind, path in ((FMI2_CS, whitebox_fmu), (FMI3_CS, fmi3_whitebox)):
        with open_fmu(path) as archive:
            assert archive.kind == kind
            runs[kind] = simulate_with_terms(archive, INPUTS, rows, DT, OUTPUTS, terms)
            if kind == FMI3_CS:
                with pytest.raises(FmuArchiveError, match="the native simulation runner loads "):
                    run_native(archive, INPUTS, rows, DT, OUTPUTS, terms, [0] * 4, None, 0.0, 4)
    np.testing.assert_array_equal(runs[FMI3_CS], runs[FMI2_CS])


# ------------------------------------------------------------------------ diagnosis and training
def test_the_diagnosis_names_concealed_friction_through_fmi3_as_through_fmi2(
    whitebox_fmu, truth_fmu, fmi3_whitebox
) -> None:
    """Through FMI 3.0 the hypotheses step in Python, through FMI 2.0 in C: the same numbers
    (``tests/test_native_run.py``), so the same findings, magnitudes and explained fractions."""
    bench = recording(whitebox_fmu, truth_fmu, {"coulomb_friction": 700.0}, seed=23, duration=2)
    project = load_config(reference_project())
    found = {}
    for kind, path in ((FMI2_CS, whitebox_fmu), (FMI3_CS, fmi3_whitebox)):
        config = dataclasses.replace(project, fmu=str(path))
        found[kind] = Diagnosis(config, greybox=None).fit(bench).findings_
    assert [(f.effect, f.stage) for f in found[FMI3_CS]] == [("coulomb_friction", "RAM")]
    for fmi3, fmi2 in zip(found[FMI3_CS], found[FMI2_CS], strict=True):
        assert (fmi3.effect, fmi3.summary, fmi3.magnitude) == (
            fmi2.effect,
            fmi2.summary,
            fmi2.magnitude,
        )
        assert fmi3.explained_fraction == pytest.approx(fmi2.explained_fraction, rel=RTOL)


def test_a_greybox_trained_through_fmi3_equals_the_fmi2_one_and_runs_exported_in_python(
    whitebox_fmu, truth_fmu, fmi3_whitebox, tmp_path
) -> None:
    bench = recording(whitebox_fmu, truth_fmu, {"coulomb_friction": 600.0}, seed=11, duration=2)
    config = with_inducing(load_config(reference_project()), 20, max_iter=15)
    models = {
        kind: train_model(dataclasses.replace(config, fmu=str(path)), bench)
        for kind, path in ((FMI2_CS, whitebox_fmu), (FMI3_CS, fmi3_whitebox))
    }
    plans = {kind: model.chain.plan().arrays for kind, model in models.items()}
    for (plan2, params2), (plan3, params3) in [(plans[FMI2_CS], plans[FMI3_CS])]:
        np.testing.assert_array_equal(plan3, plan2)
        assert_close(params3, params2, "trained parameters")
    exported = {}
    for kind, model in models.items():
        folder = tmp_path / f"model_fmi{kind.fmi_version}"
        save_model(model, folder)
        exported[kind] = export_greybox(folder, folder.with_suffix(".fmu"), runtime="python").path
    refused = r"FMI 3\.0 co-simulation; export with --runtime python"
    with pytest.raises(ExportError, match=refused):
        export_greybox(tmp_path / "model_fmi3.0", tmp_path / "native.fmu", runtime="native")
    assert validate_fmu(str(exported[FMI3_CS])) == []
    names = ["ram_position", "ram_position_std", "ram_position_wb", "itfv_pressure"]
    runs = {kind: run_exported(path, bench, names, 300) for kind, path in exported.items()}
    assert np.ptp(runs[FMI2_CS]["ram_position_wb"]) > 1e-4  # the white-box inside moved
    for name in names:
        assert_close(runs[FMI3_CS][name], runs[FMI2_CS][name], name)


def run_exported(fmu: Path, bench, names: list[str], rows: int) -> dict[str, np.ndarray]:
    """fmpy's ``simulate_fmu`` of an exported grey-box over the first ``rows`` of ``bench``."""
    signal = np.zeros(rows, dtype=[("time", float)] + [(n, float) for n in INPUTS])
    signal["time"] = bench.time[:rows] - bench.time[0]
    for name in INPUTS:
        signal[name] = bench[name][:rows]
    result = simulate_fmu(
        str(fmu),
        stop_time=signal["time"][-1],
        step_size=bench.dt,
        output_interval=bench.dt,
        input=signal,
        output=names,
    )
    return {name: result[name] for name in names}


def test_the_starter_project_reads_the_same_roles_and_units_from_fmi3(
    whitebox_fmu, fmi3_whitebox
) -> None:
    with open_fmu(whitebox_fmu) as fmi2, open_fmu(fmi3_whitebox) as fmi3:
        text = starter_text(fmi3, "actuator.fmu")
        assert text == starter_text(fmi2, "actuator.fmu")
        config = parse_config(tomllib.loads(text), Path("project.toml"))
        config.check_against_fmu(fmi3)
    assert config.signals["ram_position"].unit == "m"
