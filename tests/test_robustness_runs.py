"""Interrupted and failing runs (issue 7, section 4).

A run killed with SIGKILL in the middle of training or of writing the model folder leaves the
earlier model intact and nothing that looks like a complete model; a write failing midway leaves
the earlier recording intact; an FMU failing mid-run is reported with the FMI call and the time,
and the command's earlier output survives.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow.csv as pa_csv
import pytest
from click.testing import CliRunner

from fmu_greybox.cli import main
from fmu_greybox.data.recording import Recording, load_recording, save_recording
from fmu_greybox.errors import FmuError, ModelFormatError, RecordingError
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.instance import FmuInstance
from fmu_greybox.model.store import MANIFEST, load_model
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise

REFERENCE = Path(__file__).resolve().parents[1] / "bench_configs" / "hydraulic_actuator.toml"

#: Run ``fmu-greybox ARGS`` with one function slowed: after its N-th call it touches MARKER and
#: sleeps, so the test can kill the process at a known point.
STALLED_RUN = """
import importlib, pathlib, sys, time
module_name, owner_name, function_name, calls, marker, *args = sys.argv[1:]
module = importlib.import_module(module_name)
owner = getattr(module, owner_name) if owner_name else module
original = getattr(owner, function_name)
count = []
def stalled(*a, **k):
    result = original(*a, **k)
    count.append(1)
    if len(count) == int(calls):
        pathlib.Path(marker).touch()
        time.sleep(600)
    return result
setattr(owner, function_name, stalled)
from fmu_greybox.cli import main
main(args)
"""


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file below ``folder`` by relative path, with its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def workspace(
    whitebox_fmu: Path, truth_fmu: Path, tmp_path_factory: pytest.TempPathFactory
) -> Path:
    """A project file (small GP), a recording, and a model trained from them in ``model/``."""
    folder = tmp_path_factory.mktemp("runs")
    text = REFERENCE.read_text(encoding="utf-8")
    text = text.replace('fmu = "builtin:HydraulicActuator"', f"fmu = {str(whitebox_fmu)!r}")
    text = text.replace("inducing = 300", "inducing = 10").replace("max_iter = 200", "max_iter = 5")
    (folder / "project.toml").write_text(text, encoding="utf-8")
    request = SynthRequest(
        effects={"gain_error": 0.1}, seed=7, noise=0.0, profile=FlightTestProfile(duration=0.5)
    )
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        save_recording(synthesise(truth, whitebox, request), folder / "rec.csv")
    result = train(folder, folder / "model")
    assert result.exit_code == 0, result.output
    return folder


def train(folder: Path, out: Path):
    return CliRunner().invoke(
        main,
        [
            "-q",
            "train",
            str(folder / "project.toml"),
            "--recording",
            str(folder / "rec.csv"),
            "--out",
            str(out),
        ],
    )


@pytest.fixture()
def earlier(workspace: Path, tmp_path: Path) -> Iterator[Path]:
    """A private copy of the workspace; its ``model/`` is the earlier output to protect."""
    for name in ("project.toml", "rec.csv", "rec.csv.units.json"):
        (tmp_path / name).write_bytes((workspace / name).read_bytes())
    (tmp_path / "model").mkdir()
    for name, content in snapshot(workspace / "model").items():
        (tmp_path / "model" / name).write_bytes(content)
    yield tmp_path


@pytest.mark.parametrize(
    ("target", "calls"),
    [
        (("fmu_greybox.gp.sgpr", "SparseGPR", "fit"), 2),  # 2 of 3 stages fitted
        (("fmu_greybox.gp.storage", "", "save"), 2),  # 2 of 3 stages' files written
    ],
    ids=["mid-training", "mid-write"],
)
def test_sigkill_leaves_the_earlier_model_intact(
    earlier: Path, target: tuple[str, str, str], calls: int
) -> None:
    before = snapshot(earlier / "model")
    marker = earlier / "stalled"
    args = [
        "-q",
        "train",
        str(earlier / "project.toml"),
        "--recording",
        str(earlier / "rec.csv"),
        "--out",
        str(earlier / "model"),
    ]
    process = subprocess.Popen(
        [sys.executable, "-c", STALLED_RUN, *target, str(calls), str(marker), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 180
        while not marker.exists():
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, "the run never reached the stall point"
            time.sleep(0.05)
        process.send_signal(signal.SIGKILL)
    finally:
        process.kill()
        process.communicate()
    assert process.returncode == -signal.SIGKILL
    assert snapshot(earlier / "model") == before  # byte for byte
    load_model(earlier / "model")
    leftovers = sorted(
        p
        for p in earlier.iterdir()
        if p.name
        not in {"project.toml", "rec.csv", "rec.csv.units.json", "model", "stalled", ".model.lock"}
    )
    # the killed run's lock file stays, naming it, but nobody holds it any more
    assert "process" in (earlier / ".model.lock").read_text()
    for path in leftovers:  # at most a hidden temporary that cannot pass for a model
        assert path.name.startswith(".model.") and path.name.endswith(".tmp"), path
        assert not (path / MANIFEST).exists()
        with pytest.raises(ModelFormatError, match="not a model folder"):
            load_model(path)
    if target[1] == "":  # killed while writing: the temporary holds the first stage only
        assert [sorted(q.name for q in p.iterdir()) for p in leftovers] == [
            [
                "stage_EHV.json",
                "stage_EHV.npz",
                "stage_RAM.json",
                "stage_RAM.npz",
                "training_rows.npz",
                "whitebox.fmu",
            ]
        ]
    # the next run takes over the stale lock and removes the killed run's temporary
    for path in leftovers:
        os.utime(path, (time.time() - 60, time.time() - 60))
    result = train(earlier, earlier / "model")
    assert result.exit_code == 0, result.output
    load_model(earlier / "model")
    assert sorted(p.name for p in earlier.iterdir() if p.name.startswith(".")) == []


def test_failed_train_keeps_the_earlier_model(earlier: Path) -> None:
    """A training that fails with an error (here: the recording vanished) changes nothing."""
    before = snapshot(earlier / "model")
    (earlier / "rec.csv").unlink()
    result = train(earlier, earlier / "model")
    assert result.exit_code == 1 and "rec.csv: cannot read the file" in result.stderr
    assert snapshot(earlier / "model") == before


def test_write_failing_midway_keeps_the_earlier_recording(tmp_path: Path, monkeypatch) -> None:
    old = Recording(np.arange(5) * 0.1, {"x": np.arange(5.0)}, {"x": "m"})
    path = save_recording(old, tmp_path / "rec.csv")
    before = snapshot(tmp_path)
    write = pa_csv.write_csv

    def disk_full(table, handle, *args, **kwargs) -> None:
        write(table.slice(0, table.num_rows // 2), handle, *args, **kwargs)  # half reach the disk
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(pa_csv, "write_csv", disk_full)
    new = Recording(np.arange(50) * 0.1, {"x": np.ones(50)}, {"x": "mm"})
    with pytest.raises(RecordingError, match=r"rec\.csv: cannot write the file: No space left"):
        save_recording(new, path)
    assert snapshot(tmp_path) == before  # old file and units file intact, no temporaries
    assert load_recording(path) == old


# ------------------------------------------------------------------ an FMU failing mid-run


def test_parameter_made_invalid_mid_run_names_the_call_and_time(truth_fmu: Path) -> None:
    with open_fmu(truth_fmu) as archive, FmuInstance(archive, [], ["ram_position"]) as fmu:
        for _ in range(5):
            fmu.step([], 1e-3)
        fmu.set_real(["time_delay"], [0.06])  # tunable, so accepted until the next step
        with pytest.raises(FmuError) as info:
            fmu.step([], 1e-3)
    error = info.value
    assert (error.call, error.status) == ("fmi2DoStep", "fmi2Error")
    assert error.time == pytest.approx(0.005)
    assert str(error) == (
        "fmi2DoStep returned fmi2Error at t = 0.005 s: [fmi2Error] fmi2DoStep failed: "
        "time_delay = 0.06 is outside its range [0, 0.05]; fmi2Reset or an earlier FMU state "
        "continues"
    )


def test_simulate_failing_mid_run_keeps_the_earlier_output(
    workspace: Path, whitebox_fmu: Path, tmp_path: Path
) -> None:
    recording = load_recording(workspace / "rec.csv")
    current = np.where(np.arange(recording.n_samples) >= 100, 1e300, recording["valve_current"])
    save_recording(recording.with_signals({"valve_current": current}), tmp_path / "absurd.csv")
    out = tmp_path / "wb.csv"
    args = ["-q", "simulate", str(whitebox_fmu), str(workspace / "rec.csv"), "--out", str(out)]
    assert CliRunner().invoke(main, args).exit_code == 0
    before = snapshot(tmp_path)
    args[3] = str(tmp_path / "absurd.csv")
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 1, result.output
    assert result.stderr.startswith("error: fmi2DoStep returned fmi2Error at t = 0.1 s: ")
    assert "Traceback" not in result.output
    assert snapshot(tmp_path) == before  # wb.csv from the earlier run untouched, no debris
    assert not any(name.startswith(".") for name in os.listdir(tmp_path))
