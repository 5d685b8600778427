"""The native grey-box FMU: every term kind in C, a bare C master, libcosim, the rebuild from
``sources/``, its integrity checks and its state.

Uses the session's model and FMUs of ``test_export``. "Equal to 1e-9" as there: per signal,
``max |a - b| <= 1e-9 * max(ptp(b), max |b|)``. Tests taking ``native_face`` run for the FMI
2.0 FMU and the FMI 3.0 one (the same core behind ``native/fmi3_shell.c``); the bare C master,
libcosim and the sanitizer build run the FMI 2.0 functions.
"""

from __future__ import annotations

import hashlib
import re
import shutil
import struct
import subprocess
import zipfile
from pathlib import Path

import c_master as master
import numpy as np
import pytest
import state_flips
from fmi_versions import call_name, fmi_prefix
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.model_description import read_build_description
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimManipulator import CosimManipulator
from libcosimpy.CosimObserver import CosimObserver
from libcosimpy.CosimSlave import CosimLocalSlave
from test_export import (
    INPUTS,
    STAGE_OUTPUTS,
    Slave,
    assert_close,
    assert_matches_master,
    input_rows,
    master_run,
    simulate_over,
    tampered,
    trained,
)
from tools import SANITIZE, sanitizer_environment

from fmu_greybox.errors import ExportError, FmuError
from fmu_greybox.export.fmu import RUNTIMES, export_greybox
from fmu_greybox.export.native import BUILD_DESCRIPTION, NATIVE_DIR
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.instance import fmu_instance
from fmu_greybox.model import terms as term_kinds
from fmu_greybox.model.native_terms import NATIVE_KINDS, kind_defines
from fmu_greybox.model.store import load_model, save_model

ROOT = Path(__file__).resolve().parents[1]
NAMES = [f"{o}{s}" for o in STAGE_OUTPUTS for s in ("", "_std", "_wb")]

#: One term of every kind, on the reference actuator, entering at the stages given: each runs
#: with its own numbers in the native FMU and in Python (a kind missing here fails
#: test_every_term_kind_has_a_native_implementation: add an example and its C function).
EXAMPLES: dict[str, term_kinds.Term] = {
    "ParameterChange": term_kinds.ParameterChange(name="bulk_modulus", value=1.1e9),
    "InputGain": term_kinds.InputGain(input="valve_current", gain=0.04),
    "InputOffset": term_kinds.InputOffset(input="valve_current", offset=0.05),
    "ForceOffset": term_kinds.ForceOffset(input="load_force", offset=150.0, entry=1),
    "InputSaturation": term_kinds.InputSaturation(input="valve_current", lower=-6.0, upper=6.5),
    "InputHysteresis": term_kinds.InputHysteresis(input="valve_current", width=0.08),
    "InputLag": term_kinds.InputLag(input="valve_current", tau=0.0023),
    "InputDeadband": term_kinds.InputDeadband(input="valve_current", width=0.03),
    "InputDelay": term_kinds.InputDelay(input="valve_current", delay=0.0017),
    "CoulombForce": term_kinds.CoulombForce(
        input="load_force", source="ram_velocity", force=300.0, asymmetry=40.0
    ),
    "ViscousForce": term_kinds.ViscousForce(
        input="load_force", source="ram_position", coefficient=2e3, rate=True, entry=1
    ),
    "StribeckForce": term_kinds.StribeckForce(
        input="load_force", source="ram_velocity", force=200.0, velocity=0.01
    ),
    "SpringForce": term_kinds.SpringForce(
        input="load_force", source="ram_position", coefficient=5e4, rest=0.001, entry=2
    ),
    "FlowDroop": term_kinds.FlowDroop(
        input="supply_pressure", source="supply_flow", resistance=1e9
    ),
    "SensorDelay": term_kinds.SensorDelay(outputs=("ram_position", "itfv_pressure"), delay=0.0025),
    "SensorGain": term_kinds.SensorGain(output="spool_position", gain=0.02),
    "SensorOffset": term_kinds.SensorOffset(output="itfv_pressure", offset=2e4, entry=2),
    "SensorChannelDelay": term_kinds.SensorChannelDelay(output="spool_position", delay=0.0012),
}


@pytest.fixture(scope="session")
def model_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return trained(tmp_path_factory)["model_dir"]


@pytest.fixture(scope="session")
def native_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return trained(tmp_path_factory)["fmus"]["native"]


@pytest.fixture(scope="session", params=["native", "native-fmi3"])
def native_face(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The native FMU's FMI 2.0 and FMI 3.0 exports in turn."""
    return trained(tmp_path_factory)["fmus"][request.param]


@pytest.fixture(scope="session")
def validation(tmp_path_factory: pytest.TempPathFactory):
    return trained(tmp_path_factory)["validation"]


@pytest.fixture(scope="session")
def terms_model(model_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The session's model carrying one term of every kind (its correctors were trained
    without them: what matters here is that every runtime computes the same)."""
    model = load_model(model_dir)
    model.terms = list(EXAMPLES.values())
    return save_model(model, tmp_path_factory.mktemp("terms") / "model")


@pytest.fixture(scope="session")
def terms_fmus(terms_model: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("terms_fmus")
    return {
        runtime: export_greybox(terms_model, folder / f"{runtime}.fmu", runtime=runtime).path
        for runtime in RUNTIMES
    }


def simulate(fmu: Path, recording, **kwargs) -> dict[str, np.ndarray]:
    """fmpy's simulate_fmu over a recording; the rows after the first (the master's)."""
    return simulate_over(fmu, recording, NAMES, **kwargs)


# ---------------------------------------------------------------------------- term kinds
def test_every_term_kind_has_a_native_implementation() -> None:
    source = (NATIVE_DIR / "terms.c").read_text(encoding="utf-8")
    for kind, cls in term_kinds.TERM_KINDS.items():
        assert kind in NATIVE_KINDS, f"{kind}: no native declaration (terms.py, Native)"
        function = cls.native.function
        if function is not None:
            assert f"static void {function}(Term *t, double *x)" in source, (
                f"{kind}: no function {function} in native/terms.c"
            )
        assert kind in EXAMPLES, f"{kind}: no example in this test"


def test_terms_of_every_kind_give_the_masters_outputs_in_both_runtimes(
    model_dir: Path, terms_model: Path, terms_fmus: dict[str, Path], validation
) -> None:
    short = validation.slice_time(0.0, 0.6)
    run = master_run(terms_model, short)
    plain = master_run(model_dir, short)
    assert np.max(np.abs(run.whitebox - plain.whitebox)) > 0  # the terms act
    for fmu in terms_fmus.values():
        assert_matches_master(simulate(fmu, short), run)


def test_a_kind_without_native_code_is_refused_at_export(
    model_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = load_model(model_dir)
    model.terms = [EXAMPLES["InputGain"]]
    save_model(model, tmp_path / "model")
    monkeypatch.delitem(NATIVE_KINDS, "InputGain")
    with pytest.raises(ExportError, match="--runtime python"):
        export_greybox(tmp_path / "model", tmp_path / "x.fmu")
    assert not (tmp_path / "x.fmu").exists()


def test_the_kind_table_follows_the_codes_whatever_the_mapping_order(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The C kind table is positional: a kind taken out of the mapping and put back (as the
    test above does through monkeypatch) moves to its end, and the table must not follow:
    exported FMUs built after it stepped the wrong kind's function."""
    before = kind_defines()
    code = NATIVE_KINDS["InputGain"]
    monkeypatch.delitem(NATIVE_KINDS, "InputGain")
    monkeypatch.setitem(NATIVE_KINDS, "InputGain", code)
    assert list(NATIVE_KINDS)[-1] == "InputGain" and code < max(NATIVE_KINDS.values())
    assert kind_defines() == before


def test_state_with_terms_memory_continues_identically(
    terms_fmus: dict[str, Path], validation
) -> None:
    u = input_rows(validation)[:300]
    first = Slave(terms_fmus["native"], "first", u)
    first.run(u[:150])
    state = first.slave.getFMUstate()
    saved = first.slave.serializeFMUstate(state)
    reference = first.run(u[150:])
    first.slave.setFMUstate(state)
    first.k = 150
    np.testing.assert_array_equal(first.run(u[150:]), reference)
    first.slave.freeFMUstate(state)
    first.close()
    second = Slave(terms_fmus["native"], "second", u)
    restored = second.slave.deSerializeFMUstate(saved)
    second.slave.setFMUstate(restored)
    second.slave.freeFMUstate(restored)
    second.k = 150
    np.testing.assert_array_equal(second.run(u[150:]), reference)
    second.close()


def test_single_bit_flips_of_a_saved_state_are_refused_never_crash(
    native_face: Path, validation, tmp_path: Path
) -> None:
    """Every bit of the first 200 bytes (header, white-box state sizes, time, phase and flags,
    the first interface values) and 600 bits drawn from the rest (the white-box's own state
    bytes included), flipped one at a time, in a process of its own: none crashes it, none is
    accepted (the state's SHA-256 trailer no longer matches)."""
    rows = input_rows(validation)[:40]
    counts = state_flips.sweep(native_face, list(INPUTS), rows, tmp_path, header=200, sample=600)
    assert counts["tried"] == 200 * 8 + 600
    assert counts["refused"] == counts["tried"], counts


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -0.1, 1.5])
def test_an_ood_threshold_that_is_no_score_is_refused_at_fmi2_set_real(
    native_face: Path, validation, value: float
) -> None:
    """Issue 42, item 10: ``ood_threshold = NaN`` was taken, and switched the domain flag off
    (``score < NaN`` is never true). Now fmi2SetReal answers fmi2Error and sets nothing: the
    run goes on with the threshold it had."""
    rows = input_rows(validation)[:20]
    run = state_flips.Run(str(native_face), list(INPUTS), rows)
    reference = state_flips.Run(str(native_face), list(INPUTS), rows)
    threshold = next(
        v.valueReference
        for v in read_model_description(str(native_face)).modelVariables
        if v.name == "ood_threshold"
    )
    with pytest.raises(FMICallException, match=call_name(native_face, "fmi2SetReal")):
        run.slave.setReal([threshold], [value])
    assert run.slave.getReal([threshold]) == reference.slave.getReal([threshold])
    np.testing.assert_array_equal(run.steps(0, 20), reference.steps(0, 20))
    run.slave.setReal([threshold], [0.5])  # a score is still taken
    assert run.slave.getReal([threshold]) == [0.5]


def forged(state: bytes, index: int, value: float) -> bytes:
    """The serialised grey-box state with value ``index`` of its doubles replaced and its
    SHA-256 trailer recomputed, as a forger would (layout: greybox_fmu.c, StateHeader)."""
    n_parts = struct.unpack_from("<I", state, 12)[0]
    body = bytearray(state[:-64])
    struct.pack_into("<d", body, 72 + 8 * n_parts + 8 * index, value)
    return bytes(body) + hashlib.sha256(body).hexdigest().encode()


@pytest.mark.parametrize(
    ("index", "value", "named"),
    [
        (1, 7.0, "phase"),
        (1, 1e9, "phase"),
        (1, -1.0, "phase"),
        (1, 2.5, "phase"),
        (0, float("nan"), "time"),
        (0, float("inf"), "time"),
        (2, 2.0, "running"),
        (4, 0.5, "correction_enabled"),
        (-1, float("nan"), "white-box"),
    ],
)
def test_forged_state_with_a_valid_checksum_is_refused_field_by_field(
    native_face: Path, validation, index: int, value: float, named: str
) -> None:
    u, dt = input_rows(validation)[:60], float(validation.dt)
    refused_at = call_name(native_face, "fmi2DeSerializeFMUstate")
    with open_fmu(native_face) as archive:
        start = dict(zip(INPUTS, u[0], strict=True))
        instance = fmu_instance(archive, INPUTS, STAGE_OUTPUTS, start_values=start)
        try:
            for row in u[:30]:
                instance.step(row, dt)
            saved, at = instance.serialize_state(), instance.time
            reference = np.array([instance.step(row, dt).copy() for row in u[30:]])
            n_values = struct.unpack_from("<Q", saved, 64)[0]
            with pytest.raises(FmuError, match=refused_at) as caught:
                instance.deserialize_state(forged(saved, index % n_values, value), at)
            assert named in str(caught.value)
            instance.deserialize_state(saved, at)  # the undamaged state still restores
            again = np.array([instance.step(row, dt).copy() for row in u[30:]])
            np.testing.assert_array_equal(again, reference)
        finally:
            instance.close()


# ---------------------------------------------------------------------------- masters
@pytest.fixture(scope="session")
def c_master(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """benchmarks/c_master.c compiled: a master with no Python in its process."""
    return master.build(tmp_path_factory.mktemp("c_master"))


def run_c_master(program: Path, fmu: Path, rows: np.ndarray, folder: Path) -> np.ndarray:
    """Run the native FMU over input rows in the C master; its outputs per step (NAMES)."""
    done = master.run(program, fmu, list(INPUTS), NAMES, rows, folder)
    assert not done.python_in_process
    return done.outputs


def test_bare_c_master_gives_the_masters_outputs_with_no_python(
    c_master: Path, native_fmu: Path, model_dir: Path, validation, tmp_path: Path
) -> None:
    run = master_run(model_dir, validation)
    rows = input_rows(validation)[:-1]  # row k acts over the step to row k + 1
    outputs = run_c_master(c_master, native_fmu, rows, tmp_path)
    assert outputs.shape == (run.rows.size, len(NAMES))
    assert_matches_master({n: outputs[:, i] for i, n in enumerate(NAMES)}, run)


def test_bare_c_master_runs_every_term_kind(
    c_master: Path, terms_model: Path, terms_fmus: dict[str, Path], validation, tmp_path: Path
) -> None:
    short = validation.slice_time(0.0, 0.4)
    run = master_run(terms_model, short)
    outputs = run_c_master(c_master, terms_fmus["native"], input_rows(short)[:-1], tmp_path)
    assert_matches_master({n: outputs[:, i] for i, n in enumerate(NAMES)}, run)


def test_two_native_instances_in_libcosim_give_the_masters_outputs(
    native_fmu: Path, model_dir: Path, validation
) -> None:
    short = validation.slice_time(0.0, 0.3)
    run = master_run(model_dir, short)
    refs = {
        v.name: v.valueReference for v in read_model_description(str(native_fmu)).modelVariables
    }
    log_output_level(CosimLogLevel.ERROR)
    execution = CosimExecution.from_step_size(step_size=1_000_000)
    indices = [
        execution.add_local_slave(CosimLocalSlave(fmu_path=str(native_fmu), instance_name=name))
        for name in ("a", "b")
    ]
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    override = CosimManipulator.create_override()
    execution.add_manipulator(override)
    u = input_rows(short)
    inputs = [refs[n] for n in INPUTS]
    for index in indices:
        for ref, value in zip(inputs, u[0], strict=True):
            assert execution.real_initial_value(index, ref, float(value))
    rows = {index: [] for index in indices}
    for k in range(run.rows.size):
        for index in indices:
            assert override.slave_real_values(index, inputs, [float(v) for v in u[k]])
        assert execution.step()
        for index in indices:
            rows[index].append(observer.last_real_values(index, [refs[n] for n in NAMES]))
    execution.stop()
    for index in indices:
        got = np.array(rows[index])
        assert_matches_master({n: got[:, i] for i, n in enumerate(NAMES)}, run)


# ---------------------------------------------------------------------------- sources, checks
def rebuilt(native_fmu: Path, folder: Path, extra: tuple[str, ...] = ()) -> tuple[Path, Path]:
    """The native FMU unpacked into ``folder``, its binary rebuilt from its sources as its
    buildDescription.xml says (with gcc), with ``extra`` compiler options after its own.

    Returns
    -------
    (unpacked folder, binary)
    """
    unpacked = Path(extract(str(native_fmu), str(folder)))
    configuration = read_build_description(str(unpacked))[0]  # checked against FMI's schema
    identifier = configuration.modelIdentifier
    description = (unpacked / "sources" / BUILD_DESCRIPTION).read_text(encoding="utf-8")
    options = re.search(r'compilerOptions="([^"]*)"', description).group(1).split()
    libraries = re.findall(r'<Library name="([^"]+)"', description)
    sources = unpacked / "sources"
    sources_c = [str(sources / f) for s in configuration.sourceFileSets for f in s.sourceFiles]
    folder = {"fmi2": "linux64", "fmi3": "x86_64-linux"}[fmi_prefix(native_fmu)]
    binary = unpacked / "binaries" / folder / f"{identifier}.so"
    binary.unlink()
    command = ["gcc", *options, *extra, "-shared", f"-I{sources}", *sources_c, "-o", str(binary)]
    subprocess.run([*command, *(f"-l{lib}" for lib in libraries)], check=True)
    return unpacked, binary


def test_state_flips_and_steps_under_address_and_undefined_behaviour_sanitizers(
    native_fmu: Path, validation, tmp_path: Path
) -> None:
    """The native FMU built with -fsanitize=address,undefined: it steps, saves, and refuses
    every one of 200 * 8 + 300 single-bit flips of its state (each through
    fmi2DeSerializeFMUstate, fmi2SetFMUstate and, where accepted, fmi2DoStep), in a process
    that any out-of-bounds access, use after free or undefined behaviour would end."""
    unpacked, binary = rebuilt(native_fmu, tmp_path / "fmu", SANITIZE)
    symbols = subprocess.run(["nm", "-D", str(binary)], capture_output=True, text=True).stdout
    assert "__asan_report_load8" in symbols and "__ubsan_handle" in symbols  # instrumented
    fmu = Path(shutil.make_archive(str(tmp_path / "sanitized"), "zip", unpacked))
    fmu = fmu.rename(fmu.with_suffix(".fmu"))
    rows = input_rows(validation)[:40]
    counts = state_flips.sweep(
        fmu, list(INPUTS), rows, tmp_path, header=200, sample=300, env=sanitizer_environment()
    )
    assert counts["tried"] == 200 * 8 + 300
    assert counts["refused"] == counts["tried"], counts


def test_rebuild_from_the_shipped_sources_runs_identically(
    native_face: Path, validation, tmp_path: Path
) -> None:
    """A bench rebuilds the binary as buildDescription.xml says, with nothing but gcc."""
    unpacked, _ = rebuilt(native_face, tmp_path / "fmu")
    short = validation.slice_time(0.0, 0.3)
    again = simulate(unpacked, short)
    shipped = simulate(native_face, short)
    for name in NAMES:
        np.testing.assert_array_equal(again[name], shipped[name], err_msg=name)


@pytest.mark.parametrize(
    ("member", "named"),
    [
        ("resources/greybox.dat", "greybox.dat"),
        ("resources/whitebox/binaries/linux64/HydraulicActuator.so", "HydraulicActuator.so"),
    ],
)
def test_modified_resources_refuse_instantiation(
    native_face: Path, tmp_path: Path, member: str, named: str
) -> None:
    def flip(data: bytes) -> bytes:
        return data[:100] + bytes([data[100] ^ 1]) + data[101:]

    flipped = tampered(native_face, member, flip, tmp_path)
    refused_at = call_name(native_face, "fmi2Instantiate")
    with open_fmu(flipped) as archive, pytest.raises(FmuError, match=refused_at) as caught:
        fmu_instance(archive)
    assert named in str(caught.value) and "SHA-256" in str(caught.value)
    assert "Export the FMU again" in str(caught.value)


def test_native_fmu_declares_no_python(native_face: Path) -> None:
    description = read_model_description(str(native_face))
    assert not description.coSimulation.needsExecutionTool
    with zipfile.ZipFile(native_face) as archive:
        names = archive.namelist()
    assert not any("pythonfmu" in n or n.endswith(".py") for n in names)
    assert {"sources/buildDescription.xml", "resources/greybox.dat"} <= set(names)


# ---------------------------------------------------------------------------- FMI 3.0
def test_the_fmi3_export_equals_the_fmi2_export_in_fmpy(
    tmp_path_factory: pytest.TempPathFactory, validation
) -> None:
    """Issue 43, item 3: ``export --fmi 3`` run in fmpy gives what the FMI 2.0 export gives,
    to 1e-9 of each signal's range (in fact bit for bit: one core behind both faces)."""
    fmus = trained(tmp_path_factory)["fmus"]
    names = [*NAMES, "domain_score"]
    fmi3 = simulate_over(fmus["native-fmi3"], validation, names)
    fmi2 = simulate_over(fmus["native"], validation, names)
    for name in names:
        assert_close(fmi3[name], fmi2[name], name)
        np.testing.assert_array_equal(fmi3[name], fmi2[name], err_msg=name)


def test_the_fmi3_export_carries_the_fmi2_exports_variables(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    """The same names, value references, causalities, variabilities, units, descriptions and
    start values (the inputs', ood_threshold's, correction_enabled's); FMI 3.0 adds the
    independent variable time past them, and the binary sits in its platform tuple's folder."""
    fmus = trained(tmp_path_factory)["fmus"]
    fmi2 = read_model_description(str(fmus["native"]))
    fmi3 = read_model_description(str(fmus["native-fmi3"]))
    assert (fmi2.fmiVersion, fmi3.fmiVersion) == ("2.0", "3.0")

    declared = ("name", "valueReference", "causality", "variability", "initial", "unit")
    declared += ("description", "start")

    def table(description) -> list[tuple]:
        variables = [v for v in description.modelVariables if v.causality != "independent"]
        return [tuple(getattr(v, name) for name in declared) for v in variables]

    assert table(fmi3) == table(fmi2)
    time = [(v.name, v.valueReference) for v in fmi3.modelVariables if v.causality == "independent"]
    assert time == [("time", len(fmi2.modelVariables))]
    assert [v.variable.name for v in fmi3.outputs] == [v.variable.name for v in fmi2.outputs]
    with zipfile.ZipFile(fmus["native-fmi3"]) as archive:
        assert "binaries/x86_64-linux/" + fmi3.coSimulation.modelIdentifier + ".so" in (
            archive.namelist()
        )
