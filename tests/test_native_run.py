"""The white-box's open-loop runs in C (``model/native_run.py``, ``native/simulate.c``): bit for
bit the Python stepping loop, for every term kind, several instances at once, and failures that
name their cause."""

from __future__ import annotations

import ctypes
import dataclasses
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest
from test_export import INPUTS, STAGE_OUTPUTS, input_rows, synth_recording
from test_native_fmu import EXAMPLES

from fmu_greybox.errors import FmuError
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.builtin import reference_fmus
from fmu_greybox.fmi.compiler import DISABLE_VARIABLE, CBuild, core_flags, load_cached_library
from fmu_greybox.fmi.kinds import FMI2_CS
from fmu_greybox.model import simulate as simulate_module
from fmu_greybox.model import terms as term_kinds
from fmu_greybox.model.native_run import run_native, runs_natively
from fmu_greybox.model.simulate import STEPPING, run_open_loop, simulate_with_terms
from fmu_greybox.model.whitebox import DEFAULT_SUBSTEPS, NamedModel

DT = 1e-3
#: Stage of every observed output: terms entering at a later stage run in their own instance.
OUTPUTS = (*STAGE_OUTPUTS, "ram_velocity", "supply_flow")
STAGES = (0, 1, 2, 1, 1)
#: test_native_fmu's example of every kind, with limits this recording's current reaches.
KINDS = {
    **EXAMPLES,
    "InputSaturation": term_kinds.InputSaturation(input="valve_current", lower=-0.1, upper=0.12),
}


@pytest.fixture(scope="module")
def whitebox():
    with open_fmu(reference_fmus()["HydraulicActuator"]) as archive:
        yield archive


@pytest.fixture(scope="module")
def rows() -> np.ndarray:
    return input_rows(synth_recording(1.5, seed=5))


def in_python(archive, u: np.ndarray, terms, stages=STAGES, parameters=None) -> np.ndarray:
    start = dict(zip(INPUTS, u[0], strict=True))
    with NamedModel(
        archive, INPUTS, OUTPUTS, DT, terms, stages, parameters, start, 0.0, DEFAULT_SUBSTEPS
    ) as model:
        return run_open_loop(model, u)


def in_c(archive, u: np.ndarray, terms, stages=STAGES, parameters=None) -> np.ndarray:
    return run_native(
        archive, INPUTS, u, DT, OUTPUTS, terms, stages, parameters, 0.0, DEFAULT_SUBSTEPS
    )


def test_the_runner_is_built_here() -> None:
    assert runs_natively(list(EXAMPLES.values()), FMI2_CS)


@pytest.mark.parametrize("kind", sorted(KINDS))
def test_every_term_kind_runs_in_c_bit_for_bit_as_in_python(whitebox, rows, kind) -> None:
    term = KINDS[kind]
    python, native = in_python(whitebox, rows, [term]), in_c(whitebox, rows, [term])
    assert np.isfinite(native).all()
    np.testing.assert_array_equal(native, python)
    plain = in_c(whitebox, rows, [])
    assert not np.array_equal(native, plain), f"{kind} changed nothing: the example is too weak"


def test_several_terms_and_instances_with_project_parameters(whitebox, rows) -> None:
    """Terms entering at stages 0, 1 and 2 (three FMU instances), a parameter of the project
    and a term's own parameter: the same numbers in C and in Python."""
    terms = [
        EXAMPLES["InputDelay"],
        EXAMPLES["CoulombForce"],
        EXAMPLES["SpringForce"],
        EXAMPLES["SensorOffset"],
        term_kinds.ParameterChange(name="bulk_modulus", value=1.3e9),
    ]
    parameters = {"bulk_modulus": 1.2e9}
    python = in_python(whitebox, rows, terms, parameters=parameters)
    native = in_c(whitebox, rows, terms, parameters=parameters)
    np.testing.assert_array_equal(native, python)


def test_simulate_with_terms_uses_the_runner_and_matches_the_python_loop(whitebox, rows) -> None:
    """``simulate_with_terms`` (the diagnosis' and training's simulation) gives the Python
    loop's numbers, per stage level, as a program with the runner switched off computes them."""
    terms = [EXAMPLES["StribeckForce"], EXAMPLES["SensorGain"]]
    got = simulate_with_terms(whitebox, INPUTS, rows, DT, OUTPUTS, terms, stages=STAGES)
    expected = np.empty_like(got)
    for level in (0, 1, 2):
        columns = [j for j, s in enumerate(STAGES) if s == level]
        active = [t for t in terms if t.entry <= level]
        expected[:, columns] = in_python(whitebox, rows, active, stages=[level] * len(OUTPUTS))[
            :, columns
        ]
    np.testing.assert_array_equal(got, expected)


def test_a_run_that_shows_its_progress_is_stepped_in_c(whitebox, rows, capsys, monkeypatch) -> None:
    """Training and ``simulate`` show their progress: that does not send the white-box to the
    Python loop (the demo's 30 000 rows with a named term took 2.8 s there). The C runner steps
    it, with the same numbers, and its progress line comes when it is done."""
    terms = [EXAMPLES["CoulombForce"]]
    quiet = simulate_with_terms(whitebox, INPUTS, rows, DT, OUTPUTS, terms, stages=STAGES)
    capsys.readouterr()

    def python_loop(*args, **kwargs):
        raise AssertionError("stepped in Python")

    monkeypatch.setattr(simulate_module, "run_open_loop", python_loop)
    shown = simulate_with_terms(
        whitebox, INPUTS, rows, DT, OUTPUTS, terms, stages=STAGES, progress=True
    )
    np.testing.assert_array_equal(shown, quiet)
    lines = capsys.readouterr().err.splitlines()
    steps = rows.shape[0] - 1
    assert lines and all(line.startswith(f"{STEPPING}: done, {steps} steps in ") for line in lines)


def test_the_runner_can_be_switched_off() -> None:
    code = (
        "from fmu_greybox.fmi.kinds import FMI2_CS;"
        "from fmu_greybox.model.native_run import native_runner, runs_natively;"
        "print(native_runner() is None, runs_natively([], FMI2_CS))"
    )
    env = {**os.environ, DISABLE_VARIABLE: "0"}
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert done.stdout.split() == ["True", "False"]


def test_a_failing_white_box_raises_with_its_own_reason(whitebox, rows) -> None:
    """A hypothesis the white-box refuses (a negative bulk modulus): the runner stops and
    raises the FmuError the Python loop raises: the same call, status and time, and the
    white-box's own reason (the diagnosis drops such a candidate)."""
    refused = term_kinds.ParameterChange(name="bulk_modulus", value=-1e9)
    reason = r"bulk_modulus = -1e\+09 must be positive"
    with pytest.raises(FmuError, match=reason) as python:
        in_python(whitebox, rows, [refused])
    with pytest.raises(FmuError, match=reason) as native:
        in_c(whitebox, rows, [refused])
    got, expected = native.value, python.value
    assert (got.call, got.status, got.time) == (expected.call, expected.status, expected.time)
    assert got.call == "fmi2ExitInitializationMode" and got.status == "fmi2Error"


def test_without_a_compiler_simulations_step_in_python_and_say_so(tmp_path) -> None:
    """A fresh cache and no C compiler: the runner cannot be built, a warning says why, and
    ``runs_natively`` is false (the caller steps the model in Python)."""
    code = (
        "import warnings; warnings.simplefilter('always');"
        "from fmu_greybox.fmi.kinds import FMI2_CS;"
        "from fmu_greybox.model.native_run import runs_natively; print(runs_natively([], FMI2_CS))"
    )
    env = {**os.environ, "CC": "no-such-compiler", "FMU_GREYBOX_CACHE": str(tmp_path)}
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert done.stdout.split() == ["False"]
    assert "native runner is unavailable" in done.stderr
    assert "C compiler 'no-such-compiler' not found" in done.stderr


def test_one_loader_builds_caches_and_falls_back_saying_why(tmp_path, monkeypatch) -> None:
    """``load_cached_library`` (the runner's and the model-exchange loop's): a library is
    compiled once and loaded from the cache after; C that does not compile gives ``None`` and
    a warning naming what runs instead and the compiler's error; the switch gives ``None``
    without a word."""
    source = tmp_path / "twice.c"
    source.write_text("double twice(double x) { return 2.0 * x; }\n")
    build = CBuild(what="twice.c", sources=(source,), flags=core_flags())
    library = tmp_path / "cache" / "libtwice.so"

    def twice(loaded: ctypes.CDLL, x: float) -> float:
        loaded.twice.restype, loaded.twice.argtypes = ctypes.c_double, [ctypes.c_double]
        return loaded.twice(x)

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert twice(load_cached_library(build, library, "doubling in Python"), 1.25) == 2.5
    source.write_text("this is not C;\n")  # the cached library is loaded as it is
    assert twice(load_cached_library(build, library, "doubling in Python"), 1.25) == 2.5
    with pytest.warns(UserWarning, match=r"(?s)^doubling in Python: compiling twice\.c failed.*"):
        assert (
            load_cached_library(build, tmp_path / "other" / "lib.so", "doubling in Python") is None
        )
    monkeypatch.setenv(DISABLE_VARIABLE, "0")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_cached_library(build, library, "doubling in Python") is None


def test_a_stage_that_takes_the_terms_off_sees_the_plain_white_box(whitebox, rows) -> None:
    """A term with ``stages_off`` (chosen per stage at training) leaves that stage's outputs
    those of the plain white-box, bit for bit, in C, in Python and in ``simulate_with_terms``;
    the other stages keep the term's effect."""
    term = dataclasses.replace(EXAMPLES["CoulombForce"], stages_off=(1,))
    term = term_kinds.term_from_dict(term.to_dict())  # the field survives the model folder
    assert term.stages_off == (1,) and not term.acts_at(1) and term.acts_at(2)
    plain = in_c(whitebox, rows, [])
    python, native = in_python(whitebox, rows, [term]), in_c(whitebox, rows, [term])
    np.testing.assert_array_equal(native, python)
    simulated = simulate_with_terms(whitebox, INPUTS, rows, DT, OUTPUTS, [term], stages=STAGES)
    np.testing.assert_array_equal(simulated, native)
    off = [j for j, s in enumerate(STAGES) if s == 1]
    on = [j for j, s in enumerate(STAGES) if s != 1]
    np.testing.assert_array_equal(native[:, off], plain[:, off])
    assert not np.array_equal(native[:, on], plain[:, on])
