"""What a screened step promises against what it gives: the evidence for ``SCREEN_PROMISE``.

On the time-domain views, the screen (:mod:`fmu_greybox.diagnosis.select`) tries a hypothesis'
Gauss-Newton step only when its linear model predicts that the window's cost falls by at least
``SCREEN_PROMISE`` (0.1 %), a tenth of the 1 % a hypothesis must explain to go on. This script
diagnoses recordings of the reference actuator with the rule off (every step tried) and prints,
per recording and view kind, how many screened steps promised less than the threshold and the
most any of them gained when tried: the rule changes nothing while that stays under 1 % on the
views it applies to. The spectrum's steps, always tried, are shown for comparison.

Usage: ``.venv/bin/python benchmarks/screen_promise.py [--effect NAME=VALUE ...] [--seed N]
[--duration S]`` (default: six effects of the vocabulary, seed 3, 25 s).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import NamedTuple
from unittest import mock

from fmu_greybox.diagnosis import Diagnosis, calibrate, select
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.builtin import reference_fmus
from fmu_greybox.project.config import load_config
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, parse_effects, synthesise

CONFIG = Path(__file__).resolve().parent.parent / "bench_configs" / "hydraulic_actuator.toml"
EFFECTS = (
    "coulomb_friction=600",
    "deadband=2e-05",
    "time_delay=0.004",
    "compliance=0.3",
    "offset=0.2",
    "internal_leakage=1e-12",
)


class Step(NamedTuple):
    """One screened step: the relative fall of the window's cost its linear model promised and
    the one it gave, the hypothesis and view in words, and whether the view is the spectrum."""

    promised: float
    gained: float
    what: str
    spectral: bool


def screened_steps(effect: str, seed: int, duration: float) -> list[Step]:
    """Diagnose one recording with every screened step tried; each step, as tried."""
    steps: list[Step] = []
    direction, line_search = calibrate.Calibrator._direction, calibrate.Calibrator._line_search

    def predicted(self, c, jac):
        step, cost = direction(self, c, jac)
        c.promised = min(getattr(c, "promised", math.inf), cost)
        return step, cost

    def tried(self, directions, tol, tries):
        before = [(c, c.cost, c.promised) for c, _ in directions]
        line_search(self, directions, tol, tries)
        if tries == 1:  # the screen's single try
            spectral = self.spectrum is not None
            view = "spectrum" if spectral else "time-domain"
            view = f"{'low-passed ' if self.smoothing > 0 else ''}{view} view"
            steps.extend(
                Step(
                    1 - promised / cost,
                    1 - c.cost / cost,
                    f"{c.hypotheses[-1].key}, {view}",
                    spectral,
                )
                for c, cost, promised in before
            )
        for c, _ in directions:
            c.promised = math.inf

    paths = reference_fmus()
    with (
        open_fmu(paths["HydraulicActuatorTruth"]) as truth,
        open_fmu(paths["HydraulicActuator"]) as whitebox,
    ):
        request = SynthRequest(
            effects=parse_effects([effect]), seed=seed, profile=FlightTestProfile(duration)
        )
        recording = synthesise(truth, whitebox, request)
    with (
        mock.patch.object(calibrate.Calibrator, "_direction", predicted),
        mock.patch.object(calibrate.Calibrator, "_line_search", tried),
        mock.patch.object(select, "SCREEN_PROMISE", 0.0),
    ):
        Diagnosis(load_config(CONFIG), greybox=None).fit(recording)
    return steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--effect", action="append", default=None, metavar="NAME=VALUE")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--duration", type=float, default=25.0)
    args = parser.parse_args()
    threshold = select.SCREEN_PROMISE
    worst = 0.0
    total = skipped = 0
    for effect in args.effect or EFFECTS:
        steps = screened_steps(effect, args.seed, args.duration)
        for spectral in (False, True):
            view = [s for s in steps if s.spectral == spectral]
            untried = [s for s in view if s.promised < threshold]
            most = max(untried, key=lambda s: s.gained, default=Step(0.0, 0.0, "-", spectral))
            if not spectral:
                worst, skipped = max(worst, most.gained), skipped + len(untried)
                total += len(view)
            print(
                f"{effect:24s} {'spectrum' if spectral else 'time domain':11s} "
                f"{len(view):4d} screened steps, {len(untried):4d} "
                f"promised less than {100 * threshold:g} %; the most one of those gained when "
                f"tried: {100 * most.gained:.3f} % ({most.what}; promised "
                f"{100 * most.promised:.3f} %)",
                flush=True,
            )
    print(
        f"time domain, all: {total} screened steps, {skipped} not tried under the rule; the most "
        f"one of them would have gained: {100 * worst:.3f} % (a hypothesis goes on from 1 %)"
    )


if __name__ == "__main__":
    main()
