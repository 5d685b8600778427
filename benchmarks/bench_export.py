"""Cost per 1 kHz communication step of the exported grey-box FMU, against the bare white-box.

The three-stage hydraulic actuator (EHV -> RAM -> ITFV) is trained on a synthetic 6 s recording
with M inducing points per stage (a few optimiser iterations: the cost of a step depends on M
and the number of features, not on how well the hyperparameters fit), exported for both
runtimes (native and Python), and stepped; the bare white-box FMU is stepped the same way in the
same run (``x white-box`` is the ratio to it in the same engine):

- ``C master``: ``c_master.c``, a bare FMI master in C with no Python in its process (native
  grey-box and white-box only): per step set the four inputs, ``fmi2DoStep``, get every Real
  output -- what a native bench does;
- ``fmpy``: fmpy's ``FMU2Slave``; per step set the four inputs (from the recording),
  ``fmi2DoStep``, get every Real output (and ``out_of_domain`` for the grey-box) -- what a
  Python master does;
- ``libcosim``: the FMU alone in libcosim (libcosimpy), inputs held at their first recorded
  values, a last-value observer attached, all steps in one ``step(n)`` call -- libcosim's loop
  with no Python between steps (a Python FMU's own Python runs inside ``fmi2DoStep``);
- ``libcosim 1 core``: the same with the process held on one CPU core while libcosim starts its
  worker threads (they inherit it). libcosim hands each step to whichever worker is free, so on a
  multi-core machine consecutive steps of the FMU run on different cores, and each core's cache
  must fetch the correctors' factors again (about 1.9 MB at M = 400 and three stages); a
  real-time bench pins its threads (``taskset -c N``) and gets this figure;
- ``in-process``: the Python grey-box's slave class called directly from Python (set, step,
  get), i.e. without pythonfmu's C++ wrapper -- the difference to ``fmpy`` is that wrapper's
  cost; its breakdown shows where a step's time goes (white-box FMU step, the chain of
  correctors with their out-of-domain score, the rest of the slave);
- ``chain step``: the compiled chain step alone (``native/chain_core.c``, the code both
  runtimes run) over the recording's white-box outputs, called from a Python loop (about a
  microsecond of each call is Python's).

Figures are CPU time of the process per step (wall time in brackets where measured: it also
counts time the process waited for a shared CPU), after :data:`SETTLE` s and :data:`WARMUP`
untimed steps (the C master: its first run): the median of ``--repeat`` runs, with their range,
the date and the load average (``benchmarks/spread.py``).

With ``--equivalence`` it also runs the grey-box FMUs of the first M on a separate 2.048 s
validation recording -- the native one in the C master, in fmpy's ``simulate_fmu``, in fmpy's
SSP simulation and in libcosim (the SSP bench of :func:`fmu_greybox.export.ssp.make_bench`), the
Python one in the last three -- and prints the largest difference to the in-process master
(:func:`fmu_greybox.workflow.master.run_master`, memory from the white-box), relative to each
signal's range, over the corrected outputs, their standard deviations and the white-box outputs.

Usage: ``.venv/bin/python benchmarks/bench_export.py [--inducing 50,100,200,400] [--steps N]
[--repeat R] [--equivalence] [--json]``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import c_master
from spread import conditions, conditions_line, median_range

from fmu_greybox.export.fmu import RUNTIMES, export_greybox
from fmu_greybox.export.slave import GreyBoxSlave
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.builtin import reference_fmus
from fmu_greybox.model.store import save_model
from fmu_greybox.project.config import load_config
from fmu_greybox.synth import actuator as synth
from fmu_greybox.workflow.train import train_model, with_inducing

ROOT = Path(__file__).resolve().parent.parent
INPUTS = ("valve_current", "supply_pressure", "load_force", "engage")
#: Steps run before the clock starts (caches, branch predictors).
WARMUP = 500
#: Seconds to wait before them: loading a model factorises its posteriors with multi-threaded
#: BLAS, whose idle workers spin for about 0.1 s afterwards and would be counted.
SETTLE = 0.5


def recording(duration: float = 6.0, seed: int = 3):
    """The truth actuator in closed loop (Coulomb friction)."""
    paths = reference_fmus()
    request = synth.SynthRequest(
        effects={"coulomb_friction": 600.0},
        seed=seed,
        profile=synth.FlightTestProfile(duration=duration),
    )
    with (
        open_fmu(paths["HydraulicActuatorTruth"]) as truth,
        open_fmu(paths["HydraulicActuator"]) as whitebox,
    ):
        return synth.synthesise(truth, whitebox, request)


def export(rec, inducing: int, folder: Path) -> dict[str, Path]:
    """Train with ``inducing`` points per stage (5 iterations) and export for each runtime."""
    project = load_config(ROOT / "bench_configs" / "hydraulic_actuator.toml")
    config = with_inducing(project, inducing)
    config = dataclasses.replace(
        config,
        gp=dataclasses.replace(config.gp, max_iter=5),
    )
    model = save_model(train_model(config, rec), folder / f"model{inducing}")
    return {
        runtime: export_greybox(model, folder / f"{runtime}{inducing}.fmu", runtime=runtime).path
        for runtime in RUNTIMES
    }


class Clock:
    """Wall and CPU time of a block [s] (CPU time of the whole process, all threads)."""

    def __enter__(self) -> Clock:
        self.wall, self.cpu = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc: object) -> None:
        self.wall = time.perf_counter() - self.wall
        self.cpu = time.process_time() - self.cpu


def fmpy_loop(fmu: Path, u: np.ndarray) -> Clock:
    """Time the FMU2Slave loop over the input rows ``u``."""
    description = read_model_description(str(fmu))
    refs = {v.name: v.valueReference for v in description.modelVariables}
    reals = [
        v.valueReference
        for v in description.modelVariables
        if v.causality == "output" and v.type == "Real"
    ]
    bools = [
        v.valueReference
        for v in description.modelVariables
        if v.causality == "output" and v.type == "Boolean"
    ]
    with tempfile.TemporaryDirectory() as folder:
        slave = FMU2Slave(
            guid=description.guid,
            unzipDirectory=extract(str(fmu), folder),
            modelIdentifier=description.coSimulation.modelIdentifier,
            instanceName="bench",
        )
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        inputs = [refs[n] for n in INPUTS]
        slave.setReal(inputs, list(u[0]))
        slave.exitInitializationMode()
        rows = u.tolist()
        time.sleep(SETTLE)
        for k, row in enumerate(rows[:WARMUP]):
            slave.setReal(inputs, row)
            slave.doStep(k * 1e-3, 1e-3)
        with Clock() as clock:
            for k, row in enumerate(rows, start=WARMUP):
                slave.setReal(inputs, row)
                slave.doStep(k * 1e-3, 1e-3)
                slave.getReal(reals)
                if bools:
                    slave.getBoolean(bools)
        slave.terminate()
        slave.freeInstance()
    return clock


@contextlib.contextmanager
def one_core():
    """Hold the calling thread, and the threads it starts, on one core (the lowest allowed)."""
    cores = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(cores)})
    try:
        yield
    finally:
        os.sched_setaffinity(0, cores)


def libcosim_run(fmu: Path, u: np.ndarray) -> Clock:
    """Time libcosim stepping the FMU alone ``len(u)`` times."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.ERROR)
    refs = {v.name: v.valueReference for v in read_model_description(str(fmu)).modelVariables}
    execution = CosimExecution.from_step_size(step_size=1_000_000)
    index = execution.add_local_slave(CosimLocalSlave(fmu_path=str(fmu), instance_name="bench"))
    execution.add_observer(CosimObserver.create_last_value())
    for name, value in zip(INPUTS, u[0], strict=True):
        execution.real_initial_value(index, refs[name], float(value))
    execution.step(WARMUP)  # initialisation happens in the first
    time.sleep(SETTLE)
    with Clock() as clock:
        execution.step(len(u))
    execution.stop()
    return clock


class Parts:
    """CPU time spent in a few callables, accumulated [s]."""

    def __init__(self) -> None:
        self.cpu: dict[str, float] = {}

    def wrap(self, name: str, fn):
        self.cpu[name] = 0.0

        def timed(*args):
            start = time.process_time()
            try:
                return fn(*args)
            finally:
                self.cpu[name] += time.process_time() - start

        return timed


def in_process(fmu: Path, u: np.ndarray, parts: Parts | None = None) -> Clock:
    """Time the grey-box slave class called directly; ``parts`` times its pieces."""
    with tempfile.TemporaryDirectory() as folder:
        resources = Path(extract(str(fmu), folder)) / "resources"
        slave = GreyBoxSlave(instance_name="bench", resources=str(resources))
        n_in = len(INPUTS)
        inputs = list(range(n_in))
        reals = list(range(n_in, len(slave.interface.reals) - 1))
        flag = [len(slave.interface.reals)]
        slave.setup_experiment(0.0)
        slave.enter_initialization_mode()
        slave.set_real(inputs, list(u[0]))
        slave.exit_initialization_mode()
        if parts is not None:
            whitebox, plan = slave._run.whitebox, slave._plan
            whitebox.step = parts.wrap("white-box step", whitebox.step)
            plan.step = parts.wrap("chain step", plan.step)
        rows = u.tolist()
        time.sleep(SETTLE)
        for k, row in enumerate(rows[:WARMUP]):
            slave.set_real(inputs, row)
            slave.do_step(k * 1e-3, 1e-3)
        if parts is not None:
            parts.cpu = dict.fromkeys(parts.cpu, 0.0)
        with Clock() as clock:
            for k, row in enumerate(rows, start=WARMUP):
                slave.set_real(inputs, row)
                slave.do_step(k * 1e-3, 1e-3)
                slave.get_real(reals)
                slave.get_boolean(flag)
        slave.terminate()
    return clock


def equivalence(
    model_dir: Path, fmus: dict[str, Path], program: Path, folder: Path
) -> dict[str, float]:
    """Largest relative difference to the master per runtime and engine (see the module
    docstring)."""
    from fmpy import simulate_fmu

    from fmu_greybox.data.recording import Recording
    from fmu_greybox.export.ssp import make_bench, run_bench
    from fmu_greybox.model.stage_data import prepare
    from fmu_greybox.model.store import load_model
    from fmu_greybox.workflow.master import run_master

    rec = recording(duration=2.048, seed=8)  # 2048 steps: its mean step is exactly 1 ms
    model = load_model(model_dir)
    names = [n + s for n in model.chain.whitebox_outputs for s in ("", "_std", "_wb")]

    def master(r: Recording):
        with open_fmu(model.whitebox_fmu) as archive:
            data = prepare(model.config, model.chain, archive, r)
        return run_master(model, data, 0, memory_from="whitebox")

    def worst(columns: dict[str, np.ndarray], run) -> float:
        largest = 0.0
        for q, name in enumerate(model.chain.whitebox_outputs):
            for suffix, ref in (("", run.mean), ("_std", run.std), ("_wb", run.whitebox)):
                ref = ref[:, q]
                scale = max(np.ptp(ref), np.max(np.abs(ref)))
                largest = max(largest, float(np.max(np.abs(columns[name + suffix] - ref)) / scale))
        return largest

    reference = master(rec)
    # fmpy's SSP simulation feeds 0 to connected inputs in its first step: so does the master
    signals = {n: np.array(v) for n, v in rec.signals.items()}
    for name in INPUTS:
        signals[name][0] = 0.0
    zeroed = master(Recording(time=rec.time, signals=signals, units=rec.units))
    signal = np.zeros(rec.n_samples, dtype=[("time", float)] + [(n, float) for n in INPUTS])
    signal["time"] = rec.time
    for name in INPUTS:
        signal[name] = rec[name]
    figures = {}
    for runtime, fmu in fmus.items():
        if runtime == "native":
            rows = np.column_stack([rec[n] for n in INPUTS])[:-1]
            done = c_master.run(program, fmu, list(INPUTS), names, rows, folder / "eq_c")
            columns = {n: done.outputs[:, i] for i, n in enumerate(names)}
            figures["native, C master"] = worst(columns, reference)
        result = simulate_fmu(
            str(fmu),
            stop_time=rec.time[-1],
            step_size=rec.dt,
            output_interval=rec.dt,
            input=signal,
            output=names,
        )
        columns = {n: result[n][1:] for n in names}
        figures[f"{runtime}, fmpy simulate_fmu"] = worst(columns, reference)
        bench = make_bench(fmu, rec, folder / f"bench_{runtime}.ssp")
        cosim = run_bench(bench, "libcosim")
        columns = {n: cosim[f"greybox.{n}"] for n in names}
        figures[f"{runtime}, libcosim (SSP)"] = worst(columns, reference)
        ssp = run_bench(bench, "fmpy")
        figures[f"{runtime}, fmpy SSP"] = worst({n: ssp[f"greybox.{n}"] for n in names}, zeroed)
    return figures


def c_master_run(program: Path, fmu: Path, u: np.ndarray, repeat: int) -> dict[str, Any]:
    """CPU time per step [us] in the C master (every Real output read): the median of
    ``repeat`` runs of the master (each after its own untimed first run), with their range."""
    description = read_model_description(str(fmu))
    reals = [
        v.name for v in description.modelVariables if v.causality == "output" and v.type == "Real"
    ]
    cpu = []
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as folder:
            cpu_us = c_master.run(program, fmu, list(INPUTS), reals, u, Path(folder)).cpu_us
            cpu.append(cpu_us * 1e-6)  # the master reports us per step: seconds of one step
    return per_step(cpu, None, 1)  # the C master measures CPU time only


def chain_step(model_dir: Path, rec, steps: int, repeat: int) -> dict[str, Any]:
    """CPU time per call [us] of the compiled chain step over the recording's white-box
    outputs, called from a Python loop; the median of ``repeat`` runs, with their range."""
    from fmu_greybox.model.stage_data import prepare
    from fmu_greybox.model.store import load_model

    model = load_model(model_dir)
    chain = model.chain
    with open_fmu(model.whitebox_fmu) as archive:
        data = prepare(model.config, chain, archive, rec)
    exo = np.ascontiguousarray(data.exo[: steps + 1])
    y_wb = np.ascontiguousarray(data.y_wb[: steps + 1])
    plan = chain.plan()
    time.sleep(SETTLE)
    clocks = []
    for _ in range(repeat):
        state = plan.start(y_wb[0], exo[0])
        with Clock() as clock:
            for j in range(1, exo.shape[0]):
                plan.step(state, exo[j - 1], y_wb[j])
        clocks.append(clock)
    return per_step([c.cpu for c in clocks], [c.wall for c in clocks], exo.shape[0] - 1)


def libcosim_one_core(fmu: Path, u: np.ndarray) -> Clock:
    """:func:`libcosim_run` with libcosim's worker threads on one core."""
    with one_core():
        return libcosim_run(fmu, u)


def timed(run, fmu: Path, u: np.ndarray, repeat: int) -> dict[str, Any]:
    """CPU and wall time per step [us] of ``repeat`` runs (see :func:`per_step`)."""
    clocks = [run(fmu, u) for _ in range(repeat)]
    return per_step([c.cpu for c in clocks], [c.wall for c in clocks], len(u))


def per_step(cpu: list[float], wall: list[float] | None, steps: int) -> dict[str, Any]:
    """The median CPU time per step [us] of runs of ``steps`` steps (``cpu``, ``wall``: each
    run's seconds; ``wall`` None where not measured), its range, and the median wall time."""
    spread = median_range([c / steps * 1e6 for c in cpu])
    walls = None if wall is None else median_range([w / steps * 1e6 for w in wall])["median"]
    return {
        "cpu_us": spread["median"],
        "cpu_us_range": [spread["min"], spread["max"]],
        "wall_us": walls,
    }


def breakdown(fmu: Path, u: np.ndarray) -> dict[str, float]:
    """CPU time per step [us] of the slave's pieces, called in-process."""
    parts = Parts()
    clock = in_process(fmu, u, parts)
    pieces = {name: cpu / len(u) * 1e6 for name, cpu in parts.cpu.items()}
    pieces["rest of the slave"] = clock.cpu / len(u) * 1e6 - sum(pieces.values())
    return pieces


#: Engines measured per kind of FMU (the white-box alone is measured in all that apply).
ENGINES = {
    "native": ("C master", "fmpy", "libcosim", "libcosim 1 core"),
    "python": ("fmpy", "libcosim", "libcosim 1 core", "in-process"),
}


def main() -> None:
    """Run the benchmark and print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--inducing", default="50,100,200,400", help="inducing points per stage, comma separated"
    )
    parser.add_argument("--steps", type=int, default=3000, help="communication steps per run")
    parser.add_argument("--repeat", type=int, default=3, help="runs per figure (median kept)")
    parser.add_argument(
        "--equivalence",
        action="store_true",
        help="also compare the C master, fmpy, fmpy SSP and libcosim with the master",
    )
    parser.add_argument("--json", action="store_true", help="print a final JSON line")
    args = parser.parse_args()
    sizes = [int(m) for m in args.inducing.split(",")]

    load_before = os.getloadavg()[0]
    rec = recording()
    u = np.column_stack([rec[n] for n in INPUTS])[: args.steps]
    rows = []
    figures = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        program = c_master.build(tmp)
        runs = {
            "C master": lambda fmu, u_, r: c_master_run(program, fmu, u_, r),
            "fmpy": lambda fmu, u_, r: timed(fmpy_loop, fmu, u_, r),
            "libcosim": lambda fmu, u_, r: timed(libcosim_run, fmu, u_, r),
            "libcosim 1 core": lambda fmu, u_, r: timed(libcosim_one_core, fmu, u_, r),
            "in-process": lambda fmu, u_, r: timed(in_process, fmu, u_, r),
        }
        whitebox = reference_fmus()["HydraulicActuator"]
        bare = {e: runs[e](whitebox, u, args.repeat) for e in ENGINES["native"]}
        for m in sizes:
            fmus = export(rec, m, tmp)
            row = {"inducing": m}
            for runtime, engines in ENGINES.items():
                row[runtime] = {e: runs[e](fmus[runtime], u, args.repeat) for e in engines}
            row["breakdown"] = breakdown(fmus["python"], u)
            row["chain step"] = chain_step(tmp / f"model{m}", rec, args.steps, args.repeat)
            rows.append(row)
            if args.equivalence and not figures:
                figures = equivalence(tmp / f"model{m}", fmus, program, tmp)
    report(args, rows, bare, figures, sizes[0], len(u), conditions(load_before))


def wall(figure: dict[str, float | None]) -> float:
    """Wall time per step [us], NaN where not measured (the C master)."""
    return math.nan if figure["wall_us"] is None else figure["wall_us"]


def report(
    args, rows: list[dict], bare: dict, figures: dict, first: int, steps: int, facts: dict
) -> None:
    """Print the table (and the JSON line); ``facts``: :func:`spread.conditions`."""
    print(
        f"grey-box FMU of the three-stage actuator, {steps} steps of 1 ms, CPU time per step "
        f"(wall in brackets), {conditions_line(facts, args.repeat)}"
    )
    print(
        "white-box FMU alone: "
        + ", ".join(f"{e} {v['cpu_us']:.1f} us ({wall(v):.1f})" for e, v in bare.items())
    )
    print(
        f"{'M/stage':>8} {'runtime':>8} {'engine':>15} {'us/step':>9} {'(range)':>15} "
        f"{'(wall)':>9} {'x white-box':>12}"
    )
    for row in rows:
        for runtime in ENGINES:
            for engine, v in row[runtime].items():
                ratio = f"{v['cpu_us'] / bare[engine]['cpu_us']:12.2f}" if engine in bare else ""
                low, high = v["cpu_us_range"]
                print(
                    f"{row['inducing']:8d} {runtime:>8} {engine:>15} {v['cpu_us']:9.1f} "
                    f"{f'({low:.1f}-{high:.1f})':>15} {wall(v):9.1f} {ratio:>12}"
                )
        pieces = ", ".join(f"{name} {us:.1f}" for name, us in row["breakdown"].items())
        print(f"{'':8} {'python':>8} in-process breakdown [us]: {pieces}")
        step = row["chain step"]
        print(
            f"{'':8} {'both':>8} compiled chain step alone: {step['cpu_us']:.1f} us "
            f"({step['wall_us']:.1f})"
        )
    for engine, difference in figures.items():
        print(
            f"equivalence, M = {first}: {engine:30} max |FMU - master| / range = {difference:.2e}"
        )
    if args.json:
        print(
            json.dumps(
                {
                    "steps": steps,
                    "repeat": args.repeat,
                    **facts,
                    "whitebox_us_per_step": bare,
                    "greybox_us_per_step": rows,
                    "equivalence": figures,
                }
            )
        )


if __name__ == "__main__":
    main()
