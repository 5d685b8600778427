"""Correctors on top of named terms: does sensor noise in their training rows make them worse?

The demo's case (the reference actuator, a concealed supply-pressure droop of 1.5e10 Pa/(m3/s)):
its diagnosis names the droop, and the comparison of the parts at training (correctors trained
on the first half of the training rows) finds terms + correctors worse than the terms alone on
the RAM. Here the correctors are trained on top of the named terms on all 30 s, once on the
demo's recording (sensor noise on every signal) and once on the same recording without sensor
noise, with the demo's settings (150 inducing points, 100 iterations), and both models are
free-run on the demo's noisy independent 8 s recording. Printed per stage: the held-out RMSE
of the terms alone and of terms + correctors.

If the noise-free training helps and the noisy one harms, the harm is errors in variables (the
noisy recorded outputs in the correctors' features); if both help, it is not.

Usage: ``.venv/bin/python benchmarks/parts_noise.py [--diagnosis out/diagnosis.json]``; the
diagnosis is the demo's (``fmu-greybox demo --out out``), whose terms are used; the concealed
effect and the seed are read from the ``summary.json`` beside it.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.builtin import reference_fmus, reference_project
from fmu_greybox.model.store import load_model, save_model
from fmu_greybox.model.whitebox import read_terms
from fmu_greybox.project.config import load_config
from fmu_greybox.report.demo import VALIDATION_SEED_OFFSET, DemoSettings
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise
from fmu_greybox.workflow.train import fit_model, with_inducing
from fmu_greybox.workflow.validate import validate_model


def record(effects: dict[str, float], seed: int, duration: float, noise: float):
    """The truth actuator with the demo's concealed ``effects``, recorded in closed loop."""
    fmus = reference_fmus()
    request = SynthRequest(
        effects=effects, seed=seed, noise=noise, profile=FlightTestProfile(duration=duration)
    )
    with (
        open_fmu(fmus["HydraulicActuatorTruth"]) as truth,
        open_fmu(fmus["HydraulicActuator"]) as whitebox,
    ):
        return synthesise(truth, whitebox, request)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--diagnosis", type=Path, default=Path("out/diagnosis.json"))
    args = parser.parse_args()
    terms = read_terms(args.diagnosis)
    summary = json.loads((args.diagnosis.parent / "summary.json").read_text())
    effects, seed = summary["concealed_effects"], summary["seed"]
    settings = DemoSettings(out_dir=args.diagnosis.parent)
    config = with_inducing(load_config(reference_project()), settings.inducing, settings.max_iter)
    validation = record(effects, seed + VALIDATION_SEED_OFFSET, settings.validation_duration, 1.0)
    print(f"terms: {[t.to_dict() for t in terms]}")
    for noise in (1.0, 0.0):
        training = record(effects, seed, settings.duration, noise)
        model = fit_model(config, training, False, None, terms, calibrate=False).model
        with tempfile.TemporaryDirectory() as tmp:
            folder = save_model(model, Path(tmp) / "model")
            table = validate_model(load_model(folder), validation).table
        rows = ", ".join(
            f"{stage} terms {row['named_rmse']:.3g} -> terms+correctors {row['gb_rmse']:.3g}"
            for stage, row in table.items()
        )
        print(f"trained with sensor noise x{noise:g}: {rows}", flush=True)


if __name__ == "__main__":
    main()
