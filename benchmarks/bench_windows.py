"""The native grey-box FMU on a Windows bench: its win64 binary, stepped under Wine by the bare C
master compiled for Windows, against its linux64 binary stepped by the same master for Linux.

The reference actuator's white-box is built for linux64 and for win64 (mingw-w64) and packed as
one FMU carrying both binaries, as a supplier's may; a grey-box is trained on a synthetic
recording with concealed Coulomb friction (:data:`EFFECTS`) and exported with the native
runtime, which then carries ``binaries/linux64`` and ``binaries/win64``. Both masters
(``c_master.c``) step it over the same input rows and report the outputs, the CPU time per step
(informational: Wine is no timing reference) and the status of three steps a bench must see
refused (twice the trained step, a jump in time, every input 1e30).

Printed: per output, the largest difference between the two runs relative to the signal's range
over the linux64 run; the worst of these; both step times; both sets of refusal statuses; and
the cost of a white-box with a win64 binary only, stepped through fmpy's remoting over Wine,
beside its linux64 build (start-up and wall time per step).

With ``--diagnosis``, printed instead: the wall time of the diagnosis of a 2 s recording with
concealed Coulomb friction through the reference white-box's linux64 build and through its
win64 build (its simulations in the C runner's win64 program under Wine), and what each named.

Usage: ``.venv/bin/python benchmarks/bench_windows.py [--rows N | --diagnosis]`` (needs
``wine64`` and ``gcc-mingw-w64-x86-64``).
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
import zipfile
from pathlib import Path

import c_master
import numpy as np
from fmpy import read_model_description

from fmu_greybox.diagnosis import Diagnosis
from fmu_greybox.export.fmu import export_greybox
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.builtin import model_fmus, reference_project
from fmu_greybox.fmi.instance import fmu_instance
from fmu_greybox.fmi.platforms import WIN64
from fmu_greybox.model.native_run import native_runner, wine_runner_program
from fmu_greybox.model.store import save_model
from fmu_greybox.project.config import load_config
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise
from fmu_greybox.workflow.train import train_model, with_inducing

INPUTS = ("valve_current", "supply_pressure", "load_force", "engage")
#: The concealed effect of the training recording.
EFFECTS = {"coulomb_friction": 600.0}


def dual_platform_whitebox(folder: Path) -> Path:
    """The reference white-box FMU with its linux64 and its win64 binary (one FMU)."""
    linux = model_fmus("HydraulicActuator")["HydraulicActuator"]
    windows = model_fmus("HydraulicActuator", target=WIN64)["HydraulicActuator"]
    both = folder / "HydraulicActuator.fmu"
    with zipfile.ZipFile(both, "w", zipfile.ZIP_DEFLATED) as target:
        for source in (linux, windows):
            with zipfile.ZipFile(source) as fmu:
                for name in fmu.namelist():
                    if name not in target.namelist():
                        target.writestr(fmu.getinfo(name), fmu.read(name))
    return both


def bench_recording(whitebox: Path, effects: dict[str, float], seed: int, duration: float):
    """A synthetic recording of the truth model with ``effects``, on ``whitebox``'s signals."""
    truth = model_fmus("HydraulicActuator")["HydraulicActuatorTruth"]
    request = SynthRequest(effects, seed=seed, profile=FlightTestProfile(duration=duration))
    with open_fmu(truth) as truth_archive, open_fmu(whitebox) as whitebox_archive:
        return synthesise(truth_archive, whitebox_archive, request)


def native_greybox(folder: Path, whitebox: Path, duration: float = 2.0) -> tuple[Path, object]:
    """Train a small grey-box on ``whitebox`` and export it natively; returns the FMU and the
    recording it was trained on."""
    recording = bench_recording(whitebox, EFFECTS, 11, duration)
    config = with_inducing(load_config(reference_project()), 20, max_iter=15)
    model = train_model(dataclasses.replace(config, fmu=str(whitebox)), recording)
    save_model(model, folder / "model")
    return export_greybox(folder / "model", folder / "greybox.fmu", runtime="native").path, (
        recording
    )


def real_outputs(fmu: Path) -> list[str]:
    """The grey-box's Real outputs, in declaration order."""
    description = read_model_description(str(fmu))
    return [
        v.name for v in description.modelVariables if v.causality == "output" and v.type == "Real"
    ]


def both_masters(fmu: Path, rows: np.ndarray, folder: Path) -> dict[str, c_master.MasterRun]:
    """The FMU stepped over ``rows`` by the C master for linux64 and, under Wine, for win64."""
    names = real_outputs(fmu)
    runs = {}
    for label, target in (("linux64", None), ("win64", WIN64)):
        work = folder / label
        work.mkdir()
        program = c_master.build(work, target)
        runs[label] = c_master.run(program, fmu, list(INPUTS), names, rows, work)
    return runs


def relative_differences(runs: dict[str, c_master.MasterRun], names: list[str]) -> dict:
    """Per output: max |win64 - linux64| / range of the linux64 run (``nan`` for a constant)."""
    linux, windows = runs["linux64"].outputs, runs["win64"].outputs
    result = {}
    for j, name in enumerate(names):
        span = float(np.ptp(linux[:, j]))
        worst = float(np.max(np.abs(windows[:, j] - linux[:, j])))
        result[name] = worst / span if span > 0 else (0.0 if worst == 0 else np.inf)
    return result


def whitebox_step_times(rows: np.ndarray) -> dict[str, tuple[float, float]]:
    """Wall time to start an instance [s] and per step [us] of the reference white-box, its
    linux64 build stepped by fmpy and its win64 build through fmpy's remoting over Wine."""
    builds = {
        "linux64": model_fmus("HydraulicActuator")["HydraulicActuator"],
        "win64 through Wine": model_fmus("HydraulicActuator", target=WIN64)["HydraulicActuator"],
    }
    outputs = ["spool_position", "ram_position", "itfv_pressure"]
    times = {}
    for label, fmu in builds.items():
        with open_fmu(fmu) as archive:
            started = time.perf_counter()
            with fmu_instance(archive, INPUTS, outputs) as instance:
                ready = time.perf_counter()
                for u in rows:
                    instance.step(u, 1e-3)
                done = time.perf_counter()
        times[label] = (ready - started, 1e6 * (done - ready) / len(rows))
    return times


def diagnosis_times(duration: float = 2.0) -> dict[str, tuple[float, list]]:
    """Wall time [s] and findings of the diagnosis of one recording with concealed Coulomb
    friction (700 N), through the linux64 white-box (its simulations in the C runner here) and
    the win64 one (in the C runner's win64 program under Wine), as ``tests/test_windows.py``;
    the runners are built (or found in the cache) before the clock starts."""
    builds = {
        "linux64": model_fmus("HydraulicActuator")["HydraulicActuator"],
        "win64 under Wine": model_fmus("HydraulicActuator", target=WIN64)["HydraulicActuator"],
    }
    recording = bench_recording(builds["linux64"], {"coulomb_friction": 700.0}, 23, duration)
    project = load_config(reference_project())
    native_runner(), wine_runner_program()  # built once and cached, not timed
    result = {}
    for label, fmu in builds.items():
        started = time.perf_counter()
        diagnosis = Diagnosis(dataclasses.replace(project, fmu=str(fmu)), greybox=None)
        findings = diagnosis.fit(recording).findings_
        result[label] = (time.perf_counter() - started, findings)
    return result


def print_diagnosis_times() -> None:
    """Print :func:`diagnosis_times`: per white-box, the time and each finding's magnitude."""
    for label, (seconds, findings) in diagnosis_times().items():
        named = "; ".join(
            f"{f.effect} at {f.stage}: {f.magnitude['value']:.8f} {f.magnitude['unit']}"
            for f in findings
        )
        print(f"diagnosis through {label}: {seconds:.1f} s; {named}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=2000, help="steps of 1 ms")
    parser.add_argument(
        "--diagnosis",
        action="store_true",
        help="only time the diagnosis of a 2 s recording through linux64 and win64 under Wine",
    )
    args = parser.parse_args()
    if args.diagnosis:
        print_diagnosis_times()
        return
    with tempfile.TemporaryDirectory(prefix="bench_windows_") as tmp:
        folder = Path(tmp)
        fmu, recording = native_greybox(folder, dual_platform_whitebox(folder))
        with zipfile.ZipFile(fmu) as archive:
            binaries = sorted(n for n in archive.namelist() if n.startswith("binaries/"))
        rows = np.column_stack([recording[n] for n in INPUTS])[: args.rows]
        runs = both_masters(fmu, rows, folder)
        names = real_outputs(fmu)
        differences = relative_differences(runs, names)
    print(f"grey-box binaries: {', '.join(binaries)}")
    print(f"{len(rows)} steps; max |win64 - linux64| / range of the signal:")
    for name, value in differences.items():
        print(f"  {name:28s} {value:.3g}")
    print(f"worst: {max(differences.values()):.3g}")
    for label, run in runs.items():
        refusals = ", ".join(f"{k} {v}" for k, v in run.refusals.items())
        print(f"{label}: {run.cpu_us:.1f} us CPU per step; refusal statuses: {refusals}")
    print("the white-box alone, stepped from Python (wall time):")
    for label, (start, step) in whitebox_step_times(rows).items():
        print(f"  {label}: {start:.2f} s to start, {step:.0f} us per step")


if __name__ == "__main__":
    main()
