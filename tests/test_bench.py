"""SSP benches: playback FMU, the generated SSD, and co-simulation in fmpy and libcosim.

Uses the session's model and grey-box FMUs (native and Python) from ``test_export`` (trained
once); tests taking ``bench`` run for a bench of each. Bench runs stop after about 1 s of the
1.5 s validation recording to stay quick.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import threading
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from fmpy import simulate_fmu
from fmpy.ssp.ssd import read_ssd
from fmpy.validation import validate_fmu
from test_export import (
    INPUTS,
    STAGE_OUTPUTS,
    assert_close,
    assert_matches_master,
    master_run,
    trained,
)

from fmu_greybox.cli import main
from fmu_greybox.data.recording import Recording, load_recording, save_recording
from fmu_greybox.errors import BenchError, RecordingError
from fmu_greybox.export import libcosim_run
from fmu_greybox.export.fmu import RUNTIMES
from fmu_greybox.export.libcosim_run import libcosim_columns
from fmu_greybox.export.slave import GreyBoxSlave
from fmu_greybox.export.ssp import (
    SSD_FILE,
    build_playback_fmu,
    make_bench,
    read_layout,
    run_bench,
    run_benches,
)
from fmu_greybox.model.store import load_model

#: 1024 steps: the recording's mean step (the master's) is then exactly libcosim's 1 ms, which
#: it counts in integer nanoseconds
STOP = 1.024


@pytest.fixture(scope="session")
def model_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return trained(tmp_path_factory)["model_dir"]


@pytest.fixture(scope="session")
def greybox_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The default (native) grey-box FMU."""
    return trained(tmp_path_factory)["fmus"][RUNTIMES[0]]


@pytest.fixture(scope="session")
def validation(tmp_path_factory: pytest.TempPathFactory) -> Recording:
    return trained(tmp_path_factory)["validation"]


def bench_of(runtime: str, validation: Recording, tmp_path_factory) -> Path:
    fmu = trained(tmp_path_factory)["fmus"][runtime]
    return make_bench(fmu, validation, tmp_path_factory.mktemp(f"bench_{runtime}") / "bench.ssp")


@pytest.fixture(scope="session", params=RUNTIMES)
def bench(request: pytest.FixtureRequest, validation: Recording, tmp_path_factory) -> Path:
    """A bench of each runtime's grey-box in turn."""
    return bench_of(request.param, validation, tmp_path_factory)


@pytest.fixture(scope="session")
def python_bench(validation: Recording, tmp_path_factory) -> Path:
    return bench_of("python", validation, tmp_path_factory)


def first_rows(recording: Recording, stop: float, zero_inputs: bool = False) -> Recording:
    """The recording up to ``stop``; with ``zero_inputs``, the inputs of row 0 set to 0."""
    part = recording.slice_time(recording.time[0], stop)
    signals = {name: np.array(values) for name, values in part.signals.items()}
    if zero_inputs:
        for name in INPUTS:
            signals[name][0] = 0.0
    return Recording(time=part.time, signals=signals, units=part.units, source=part.source)


def test_playback_fmu_plays_the_recording(validation: Recording, tmp_path: Path) -> None:
    fmu = build_playback_fmu(validation, tmp_path / "playback.fmu")
    assert validate_fmu(str(fmu)) == []
    result = simulate_fmu(
        str(fmu),
        stop_time=validation.time[-1],
        step_size=validation.dt,
        output_interval=validation.dt,
        output=list(validation.names),
    )
    for name in validation.names:
        np.testing.assert_array_equal(result[name], validation[name], err_msg=name)


def test_bench_is_a_valid_ssp_wiring_the_playback(bench: Path, validation: Recording) -> None:
    ssd = read_ssd(str(bench))  # validates against the SSP 1.0 schema
    assert [c.name for c in ssd.system.elements] == ["playback", "greybox", "whitebox"]
    links = {(c.endElement, c.endConnector, c.startConnector) for c in ssd.system.connections}
    for component in ("greybox", "whitebox"):
        for name in INPUTS:
            assert (component, name, name) in links
    layout = read_layout(bench)
    assert layout.step == pytest.approx(validation.dt)
    assert layout.stop == pytest.approx(validation.time[-1])
    assert {"out_of_domain", "ram_position_std"} <= set(layout.outputs["greybox"])
    with zipfile.ZipFile(bench) as archive:
        assert {
            SSD_FILE,
            "resources/greybox.fmu",
            "resources/whitebox.fmu",
            "resources/playback.fmu",
        } <= set(archive.namelist())


def test_libcosim_gives_the_masters_outputs(
    bench: Path, model_dir: Path, validation: Recording
) -> None:
    result = run_bench(bench, "libcosim", stop_time=STOP)
    run = master_run(model_dir, first_rows(validation, STOP))
    assert result.n_samples == run.rows.size
    np.testing.assert_allclose(result.time, run.time)
    assert_matches_master(result.signals, run, prefix="greybox.")
    for q, name in enumerate(STAGE_OUTPUTS):
        assert_close(result[f"whitebox.{name}"], run.whitebox[:, q], f"whitebox.{name}")


def test_libcosim_worker_threads_keep_their_python_state(python_bench: Path, monkeypatch) -> None:
    """pythonfmu wraps each FMI call in PyGILState_Ensure/Release; on libcosim's worker
    threads the FMU keeps the thread's Python state between calls (fmu_entry.keep_thread_state)
    instead of getting a new one per call (thread-local data would not survive a step)."""
    local, new_states = threading.local(), []
    stepping = GreyBoxSlave.do_step

    def counting(self, current_time: float, step_size: float) -> bool:
        if not hasattr(local, "seen"):
            local.seen = True
            new_states.append(current_time)
        return stepping(self, current_time, step_size)

    monkeypatch.setattr(GreyBoxSlave, "do_step", counting)
    # in this process (run_bench runs libcosim in a child, out of the monkeypatch's reach)
    layout = read_layout(python_bench)
    result = libcosim_columns(python_bench, layout.outputs, layout.start, 1e-3, 100)
    assert all(values.size == 100 for values in result.values())
    assert 1 <= len(new_states) <= 4, new_states  # one per worker thread, not one per step


def test_fmpy_ssp_gives_the_masters_outputs(
    bench: Path, model_dir: Path, validation: Recording
) -> None:
    # fmpy's simulate_ssp feeds 0 to every connected input during the first step (run_bench
    # initialises them at 0 too); the master gets the same inputs
    result = run_bench(bench, "fmpy", stop_time=STOP)
    run = master_run(model_dir, first_rows(validation, STOP, zero_inputs=True))
    assert result.n_samples == run.rows.size
    assert_matches_master(result.signals, run, prefix="greybox.")
    for q, name in enumerate(STAGE_OUTPUTS):
        assert_close(result[f"whitebox.{name}"], run.whitebox[:, q], f"whitebox.{name}")
    np.testing.assert_array_equal(
        result["playback.valve_current"], validation["valve_current"][1 : run.rows.size + 1]
    )


def test_cosim_command_writes_every_output(bench: Path, tmp_path: Path) -> None:
    out = tmp_path / "results.csv"
    result = CliRunner().invoke(
        main, ["cosim", str(bench), "--engine", "libcosim", "--stop-time", "0.2", "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    results = load_recording(out)
    assert results.n_samples == 200
    assert {
        "greybox.ram_position",
        "greybox.ram_position_std",
        "greybox.out_of_domain",
        "whitebox.ram_position",
        "playback.load_force",
    } <= set(results.names)
    assert results.units["greybox.ram_position"] == "m"


def test_export_command_writes_a_bench(
    model_dir: Path, validation: Recording, tmp_path: Path
) -> None:
    recording = save_recording(validation, tmp_path / "rec.csv")
    result = CliRunner().invoke(
        main,
        [
            "export",
            str(model_dir),
            "--out",
            str(tmp_path / "gb.fmu"),
            "--ssp",
            str(tmp_path / "bench.ssp"),
            "--recording",
            str(recording),
            "--greybox-only",
        ],
    )
    assert result.exit_code == 0, result.output
    assert set(read_layout(tmp_path / "bench.ssp").components) == {"playback", "greybox"}


def test_bench_needs_every_input_recorded(
    greybox_fmu: Path, validation: Recording, tmp_path: Path
) -> None:
    missing = validation.select([n for n in validation.names if n != "load_force"])
    with pytest.raises(BenchError, match="load_force"):
        make_bench(greybox_fmu, missing, tmp_path / "b.ssp")
    assert not (tmp_path / "b.ssp").exists()


def test_bench_refuses_another_sample_time(
    greybox_fmu: Path, validation: Recording, tmp_path: Path
) -> None:
    coarse = Recording(
        time=validation.time[::2],
        signals={n: v[::2] for n, v in validation.signals.items()},
        units=validation.units,
    )
    with pytest.raises(RecordingError, match=r"but the grey-box FMU .* runs at 0.001 s; resample"):
        make_bench(greybox_fmu, coarse, tmp_path / "b.ssp")


def test_a_failing_fmu_stops_libcosim_cleanly(bench: Path) -> None:
    with pytest.raises(BenchError, match="failed in libcosim"):
        run_bench(bench, "libcosim", stop_time=0.01, step=0.002)  # not the trained step


def test_an_input_refused_at_the_start_stops_libcosim_with_the_fmus_message(
    greybox_fmu: Path, model_dir: Path, validation: Recording, tmp_path: Path
) -> None:
    """Issue 42, item 2: a recording whose first row lies outside the grey-box's input domain
    made the native grey-box refuse it during libcosim's initialisation, and libcosim aborted
    the whole process (std::terminate on a cosim::error, exit 134). Now ``cosim`` exits 1
    with the grey-box's refusal, which names the input, its value, the time and the domain."""
    low, high = load_model(model_dir).training.input_ranges["valve_current"]
    outside = high + 3.0 * max(high - low, abs(low), abs(high))  # the domain is 1 scale wider
    part = first_rows(validation, 0.05)
    current = part["valve_current"].copy()
    current[0] = outside
    ssp = make_bench(greybox_fmu, part.with_signals({"valve_current": current}), tmp_path / "b.ssp")
    command = [sys.executable, "-c", "from fmu_greybox.cli import main; main()", "cosim"]
    args = [str(ssp), "--engine", "libcosim", "--out", str(tmp_path / "r.csv")]
    done = subprocess.run([*command, *args], capture_output=True, text=True, timeout=300)
    assert done.returncode == 1, done.stderr
    error = done.stderr.splitlines()[-1]
    assert error.startswith("error: b.ssp failed in libcosim: "), done.stderr
    assert f"input valve_current = {outside:.9g} at t = 0 s lies outside" in error
    assert "input domain [" in error and "retrain with recordings that cover it" in error
    assert "terminate called" not in done.stderr
    assert not (tmp_path / "r.csv").exists()


def test_a_failing_fmpy_bench_leaves_no_unpacked_fmus(
    greybox_fmu: Path, validation: Recording, tmp_path: Path, monkeypatch
) -> None:
    """Before: fmpy removed the unpacked SSP and FMUs (about 5 MB) only after a run that
    succeeded. Here the white-box fails at row 100 (an absurd valve current)."""
    temp = tmp_path / "temp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))  # a temporary folder to look into
    current = validation["valve_current"].copy()
    current[100:] = 1e300
    absurd = first_rows(validation, 0.3).with_signals({"valve_current": current[:301]})
    ssp = make_bench(greybox_fmu, absurd, tmp_path / "absurd.ssp")
    before = sorted(temp.iterdir())
    with pytest.raises(BenchError, match="failed in fmpy"):
        run_bench(ssp, "fmpy")
    assert sorted(temp.iterdir()) == before


def test_both_engines_side_by_side_give_what_each_gives_alone(
    greybox_fmu: Path, validation: Recording, tmp_path: Path, monkeypatch, two_cores
) -> None:
    """fmpy (here) and libcosim (in its child) run at once; fmpy points the temporary folder
    at a private one while it runs, and libcosim's request and answer stay out of it."""
    temp = tmp_path / "temp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    ssp = make_bench(greybox_fmu, first_rows(validation, 0.5), tmp_path / "b.ssp")
    alone = [run_bench(ssp, engine) for engine in ("libcosim", "fmpy")]
    scratches, real = [], libcosim_run.run_libcosim

    def spy(*args, **kwargs):
        scratches.append(args[5])
        return real(*args, **kwargs)

    monkeypatch.setattr(libcosim_run, "run_libcosim", spy)
    together = run_benches(ssp, ("libcosim", "fmpy"))
    assert scratches == [str(temp)]
    for (result, seconds), single in zip(together, alone, strict=True):
        assert seconds > 0 and result.names == single.names
        for name in single.names:
            np.testing.assert_array_equal(result[name], single[name], err_msg=name)
    assert list(temp.iterdir()) == []


def test_run_bench_errors_are_clear(bench: Path, tmp_path: Path) -> None:
    with pytest.raises(BenchError, match="engine"):
        run_bench(bench, "openmodelica")
    not_ssp = tmp_path / "x.ssp"
    not_ssp.write_text("no")
    with pytest.raises(BenchError, match="not an SSP archive"):
        run_bench(not_ssp)
