"""The misfit of a parameter that sets a lightly damped mode, in the diagnosis' three views.

The truth actuator is recorded with entrained air (``compliance``: the effective bulk modulus
falls by that share; the hydraulic mode moves from 100 Hz to about 63 Hz at 0.6). The
white-box's ``bulk_modulus`` is then changed step by step and the misfit printed, relative to
the white-box's, in each view the diagnosis screens and fits with (the raw residual, the
low-passed one, the spectrum; :mod:`fmu_greybox.diagnosis.calibrate`), on the screening window.

Usage::

    .venv/bin/python benchmarks/narrow_valley.py [--compliance 0.6] [--seed 301]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from fmu_greybox.diagnosis.calibrate import Calibrator, Candidate
from fmu_greybox.diagnosis.runner import Experiment, Simulator
from fmu_greybox.diagnosis.signals import SignalMap
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.builtin import reference_fmus
from fmu_greybox.model.terms import ParameterChange
from fmu_greybox.project.config import load_config
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise

CONFIG = Path(__file__).resolve().parent.parent / "bench_configs" / "hydraulic_actuator.toml"
CHANGES = (0.0, -0.1, -0.2, -0.3, -0.4, -0.5, -0.55, -0.58, -0.6, -0.62, -0.65, -0.7, -0.75)
ROWS = 4000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--compliance", type=float, default=0.6, help="Truth entrained air.")
    parser.add_argument("--seed", type=int, default=301, help="Recording seed.")
    args = parser.parse_args()
    config = load_config(CONFIG)
    paths = reference_fmus()
    profile = FlightTestProfile(duration=20.0)
    request = SynthRequest({"compliance": args.compliance}, seed=args.seed, profile=profile)
    with (
        open_fmu(paths["HydraulicActuatorTruth"]) as truth,
        open_fmu(paths["HydraulicActuator"]) as whitebox,
    ):
        recording = synthesise(truth, whitebox, request)
        signals = SignalMap.from_project(config, whitebox, recording)
        train = int(0.8 * recording.n_samples)
        experiment = Experiment.from_project(config, whitebox, recording, signals, train)
        experiment.estimate_noise()
        nominal = whitebox.variable("bulk_modulus").start
        with Simulator(experiment, workers=2) as simulator:
            views = {
                "raw": Calibrator(simulator, ROWS),
                "low-passed": Calibrator(simulator, ROWS, smoothing=20.0),
                "spectrum": Calibrator(simulator, ROWS, spectrum=True),
            }
            costs = {}
            for name, view in views.items():
                candidates = [
                    Candidate([], np.zeros(0), fixed=[ParameterChange("bulk_modulus", v)])
                    for v in (nominal * (1.0 + c) for c in CHANGES)
                ]
                view.evaluate(candidates)
                costs[name] = [c.cost / candidates[0].cost for c in candidates]
    print(
        f"truth compliance {args.compliance:g} (bulk modulus x {1 - args.compliance:g}), seed "
        f"{args.seed}: misfit relative to the white-box's over the first {ROWS} rows"
    )
    print(f"{'bulk modulus change':>20s} " + " ".join(f"{name:>11s}" for name in views))
    for i, change in enumerate(CHANGES):
        row = " ".join(f"{costs[name][i]:11.3f}" for name in views)
        print(f"{100 * change:19.0f}% {row}")


if __name__ == "__main__":
    main()
