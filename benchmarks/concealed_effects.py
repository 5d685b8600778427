"""Concealed effects: does the diagnosis find what the truth model hid from the white-box?

For every truth effect of the reference actuator at several magnitudes and noise levels, for
pairs of effects and for no-effect controls, a recording is made with the truth FMU in closed
loop (:func:`fmu_greybox.synth.actuator.synthesise`). The diagnosis gets only the white-box FMU, the
project file ``bench_configs/hydraulic_actuator.toml`` and the recording.

Scoring (this file knows the truth; the diagnosis does not):

* expected origin: the first stage with a recorded signal (its target, or the ram velocity for
  the RAM) that the effect moves by more than 0.83 times its sensor noise (RMS: the structure
  that lifts a residual to 1.3 times the noise, the diagnosis' significance level), found by
  running the truth FMU open-loop over the recorded inputs with and without the effect;
  ``None`` for controls;
* effect correct: the top finding's effect is (one of) the true effect(s), or it is a
  ``parameter_mismatch`` whose physics label is; ``none`` for controls;
* estimated vs true magnitude, converted to the truth model's parameter units;
* held-out improvement: the relative change of the held-out RMSE, white-box + named terms
  against white-box, averaged over the stages the effect moves.

Usage::

    .venv/bin/python benchmarks/concealed_effects.py [--quick] [--json] [--workers N]
        [--case EFFECT=VALUE[+EFFECT=VALUE] ...]

``--case`` replaces the suite by the cases given (noise scale 1, seeds 301, 302, ...), e.g.
magnitudes outside the suite's.

``--coverage`` also checks the calibrated uncertainty on each case, as the demo does: the
named terms folded into the white-box, the grey-box trained on the recording (``--inducing``,
``--max-iter``; the demo's 150 and 100 by default) and free-run on an independent 8 s
recording of the same truth model (seed + 1 000 003); per stage the share of its rows inside
±1σ and ±1.96σ, and over all stages of all cases the share whose ±1.96σ coverage lies in the
target 0.90 .. 0.99.

With ``--json`` the last line is one JSON object: ``origin_accuracy``, ``effect_accuracy``,
``control_false_findings``, ``median_improvement`` (with ``--coverage`` also
``coverage95_in_target`` and ``coverage95_median``) and the cases.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from fmu_greybox.diagnosis import Diagnosis
from fmu_greybox.diagnosis.findings import named_physics
from fmu_greybox.diagnosis.locate import SIGNIFICANT_STRUCTURE
from fmu_greybox.fmi.archive import FmuArchive, open_fmu
from fmu_greybox.fmi.builtin import reference_fmus
from fmu_greybox.model.simulate import simulate_with_terms
from fmu_greybox.model.whitebox import terms_from_findings
from fmu_greybox.project.config import load_config
from fmu_greybox.synth.actuator import (
    INPUTS,
    SENSOR_NOISE,
    TYPICAL_MAGNITUDES,
    FlightTestProfile,
    SynthRequest,
    synthesise,
)
from fmu_greybox.workflow.train import train_model, with_inducing
from fmu_greybox.workflow.validate import validate_model

CONFIG = Path(__file__).resolve().parent.parent / "bench_configs" / "hydraulic_actuator.toml"
#: The recorded signals of each stage of the reference actuator (benchmark knowledge).
STAGE_SIGNALS = {
    "EHV": ("spool_position",),
    "RAM": ("ram_position", "ram_velocity"),
    "ITFV": ("itfv_pressure",),
}


@dataclass(frozen=True)
class Case:
    """One recording to diagnose."""

    effects: dict[str, float] = field(default_factory=dict)
    noise: float = 1.0
    seed: int = 0

    @property
    def label(self) -> str:
        if not self.effects:
            return "control"
        return " + ".join(f"{k}={v:g}" for k, v in self.effects.items())


MAGNITUDES = TYPICAL_MAGNITUDES
PAIRS = (
    {"coulomb_friction": 600.0, "offset": 0.2},
    {"gain_error": 0.05, "time_delay": 0.003},
    {"internal_leakage": 5e-13, "compliance": 0.3},
)


def cases(quick: bool) -> list[Case]:
    """The suite (``quick``: one magnitude per effect, one pair, two controls)."""
    found: list[Case] = []
    seed = 100
    for effect, values in MAGNITUDES.items():
        for value in values[-1:] if quick else values:
            seed += 1
            found.append(Case({effect: value}, 1.0, seed))
    if not quick:
        for effect in ("gain_error", "coulomb_friction", "compliance", "supply_pressure_droop"):
            seed += 1
            found.append(Case({effect: MAGNITUDES[effect][-1]}, 3.0, seed))
    for pair in PAIRS[:1] if quick else PAIRS:
        seed += 1
        found.append(Case(dict(pair), 1.0, seed))
    controls = ((1.0, 1), (1.0, 2)) if quick else ((1.0, 1), (1.0, 2), (1.0, 3), (3.0, 4))
    found += [Case({}, noise, s) for noise, s in controls]
    return found


def given_case(text: str, seed: int) -> Case:
    """A case from ``EFFECT=VALUE[+EFFECT=VALUE]`` (the effects of the truth model)."""
    effects = {}
    for part in text.split("+"):
        name, sep, value = part.partition("=")
        if not sep or name.strip() not in MAGNITUDES:
            raise SystemExit(
                f"--case {text!r}: write EFFECT=VALUE with EFFECT one of {', '.join(MAGNITUDES)}"
            )
        effects[name.strip()] = float(value)
    return Case(effects, 1.0, seed)


def expected_origin(truth: FmuArchive, recording, case: Case, config) -> tuple[str | None, list]:
    """First stage with a recorded signal the effect moves by more than 0.83 noise levels;
    every stage it moves."""
    if not case.effects:
        return None, []
    u = np.column_stack([recording[name] for name in INPUTS])
    signals = [name for stage in config.stages for name in STAGE_SIGNALS[stage.name]]
    runs = []
    for effects in ({}, case.effects):
        run = simulate_with_terms(truth, INPUTS, u, recording.dt, signals, parameters=effects)
        runs.append(run)
    change = np.sqrt(np.mean((runs[1] - runs[0]) ** 2, axis=0))
    sigma = np.array([SENSOR_NOISE[name] for name in signals]) * max(case.noise, 1e-3)
    moved = [
        stage.name
        for stage in config.stages
        if any(
            change[signals.index(name)] > SIGNIFICANT_STRUCTURE * sigma[signals.index(name)]
            for name in STAGE_SIGNALS[stage.name]
        )
    ]
    return (moved[0] if moved else None), moved


def in_truth_units(finding: dict, effect: str, whitebox: FmuArchive) -> float | None:
    """A finding's magnitude in the truth model's units for ``effect``."""
    value = finding["magnitude"]["value"]
    if finding["effect"] == "parameter_mismatch":
        nominal, estimate = finding["nominal"], finding["estimate"]
        return {
            "gain_error": estimate / nominal - 1.0,
            "internal_leakage": estimate - nominal,
            "compliance": 1.0 - estimate / nominal,
        }.get(effect)
    if effect == "deadband":  # half-width in mA of valve current -> m of spool travel
        return value * whitebox.variable("valve_gain").start
    return value


def run_case(
    case: Case,
    paths: dict,
    config,
    workers: int,
    duration: float,
    coverage: tuple[int, int] | None = None,
) -> dict:
    """Record, diagnose and score one case; with ``coverage`` (inducing points, iterations)
    also train and validate the grey-box (see the module docstring)."""
    profile = FlightTestProfile(duration=duration)
    request = SynthRequest(effects=case.effects, seed=case.seed, noise=case.noise, profile=profile)
    with (
        open_fmu(paths["HydraulicActuatorTruth"]) as truth,
        open_fmu(paths["HydraulicActuator"]) as whitebox,
    ):
        recording = synthesise(truth, whitebox, request)
        origin, moved = expected_origin(truth, recording, case, config)
        started = time.perf_counter()
        diagnosis = Diagnosis(config, workers=workers, greybox=None).fit(recording)
        seconds = time.perf_counter() - started
        findings = [f.to_dict() for f in diagnosis.findings_]
        top = findings[0]
        truth_effects = list(case.effects) or ["none"]
        named = named_physics(top)
        correct = named in truth_effects
        estimate = in_truth_units(top, named, whitebox) if correct and case.effects else None
    if coverage is not None:
        checked = uncertainty_coverage(case, paths, config, findings, recording, coverage)
    true_value = case.effects.get(named) if correct else None
    affected = [diagnosis.fit_[s] for s in moved if s in diagnosis.fit_]
    improvement = (
        float(np.mean([row["named_improvement"] for row in affected])) if affected else None
    )
    return {
        "case": case.label,
        "noise": case.noise,
        "seed": case.seed,
        "control": not case.effects,
        "expected_origin": origin,
        "origin": diagnosis.origin_stage_,
        "origin_correct": diagnosis.origin_stage_ == origin,
        "top_finding": top["effect"]
        if top["effect"] != "parameter_mismatch"
        else f"parameter_mismatch:{top.get('parameter')}",
        "top_physics": named,
        "effect_correct": correct,
        "findings": [named_physics(f) for f in findings],
        "estimate": estimate,
        "true": true_value,
        "improvement": improvement,
        "seconds": round(seconds, 1),
        **({"coverage": checked} if coverage is not None else {}),
    }


#: The independent validation recording of a case: its seed offset and length [s] (the demo's).
VALIDATION_SEED, VALIDATION_DURATION = 1_000_003, 8.0


def uncertainty_coverage(
    case: Case, paths: dict, config, findings: list, recording, sizes: tuple[int, int]
) -> dict[str, dict[str, float]]:
    """Train the grey-box on the case's recording (named terms first), free-run it on an
    independent recording; per stage ``coverage68``, ``coverage95``, RMSE and median σ."""
    profile = FlightTestProfile(duration=VALIDATION_DURATION)
    request = SynthRequest(
        effects=case.effects,
        seed=case.seed + VALIDATION_SEED,
        noise=case.noise,
        profile=profile,
    )
    with (
        open_fmu(paths["HydraulicActuatorTruth"]) as truth,
        open_fmu(paths["HydraulicActuator"]) as whitebox,
    ):
        independent = synthesise(truth, whitebox, request)
    model = train_model(
        with_inducing(config, *sizes), recording, terms=terms_from_findings(findings)
    )
    table = validate_model(model, independent).table
    keys = ("coverage68", "coverage95", "gb_rmse", "median_std")
    return {stage: {k: row[k] for k in keys} for stage, row in table.items()}


def print_coverage(row: dict) -> None:
    """The case's coverage, one line under its row."""
    parts = [
        f"{stage} {100 * c['coverage68']:.1f} / {100 * c['coverage95']:.1f} %"
        for stage, c in row["coverage"].items()
    ]
    print(f"{'':4s}inside ±1σ / ±1.96σ on an independent recording: {', '.join(parts)}")


def print_row(row: dict) -> None:
    est = "-" if row["estimate"] is None else f"{row['estimate']:.3g}"
    true = "-" if row["true"] is None else f"{row['true']:.3g}"
    imp = "-" if row["improvement"] is None else f"{100 * row['improvement']:+.0f} %"
    print(
        f"{row['case']:48s} {row['noise']:5.1f} {row['expected_origin']!s:6s} "
        f"{row['origin']!s:6s} {row['top_finding'][:34]:34s} "
        f"{'yes' if row['effect_correct'] else 'NO':4s} {est:>10s} {true:>10s} {imp:>7s} "
        f"{row['seconds']:6.1f}",
        flush=True,
    )


def summary(rows: list[dict]) -> dict:
    effect_rows = [r for r in rows if not r["control"]]
    controls = [r for r in rows if r["control"]]
    improvements = [r["improvement"] for r in effect_rows if r["improvement"] is not None]
    covered = [c["coverage95"] for r in rows for c in r.get("coverage", {}).values()]
    coverage = (
        {
            "coverage95_in_target": float(np.mean([0.90 <= c <= 0.99 for c in covered])),
            "coverage95_median": statistics.median(covered),
            "coverage95_range": [min(covered), max(covered)],
        }
        if covered
        else {}
    )
    return {
        **coverage,
        "origin_accuracy": float(np.mean([r["origin_correct"] for r in rows])),
        "effect_accuracy": float(np.mean([r["effect_correct"] for r in effect_rows])),
        "control_false_findings": sum(
            sum(1 for f in r["findings"] if f != "none") for r in controls
        ),
        "median_improvement": statistics.median(improvements) if improvements else None,
        "n_cases": len(rows),
        "n_controls": len(controls),
        "median_seconds": statistics.median(r["seconds"] for r in rows),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="A shorter suite.")
    parser.add_argument("--json", action="store_true", help="End with one JSON line.")
    parser.add_argument("--workers", type=int, default=2, help="Simulation workers.")
    parser.add_argument(
        "--duration", type=float, default=None, help="Recording length [s] (default 20, quick 12)."
    )
    parser.add_argument(
        "--coverage",
        action="store_true",
        help="Also train and validate the grey-box and report its uncertainty's coverage.",
    )
    parser.add_argument("--inducing", type=int, default=150, help="With --coverage (150).")
    parser.add_argument("--max-iter", type=int, default=100, help="With --coverage (100).")
    parser.add_argument(
        "--case",
        action="append",
        default=[],
        metavar="EFFECT=VALUE[+EFFECT=VALUE]",
        help="Run these cases instead of the suite (repeatable).",
    )
    args = parser.parse_args()
    duration = args.duration or (12.0 if args.quick else 20.0)
    config = load_config(CONFIG)
    paths = reference_fmus()
    print(
        f"{'true effect':48s} {'noise':>5s} {'exp.':6s} {'origin':6s} {'top finding':34s} "
        f"{'ok':4s} {'estimate':>10s} {'true':>10s} {'impr.':>7s} {'time':>6s}"
    )
    rows = []
    chosen = [given_case(text, 301 + i) for i, text in enumerate(args.case)] or cases(args.quick)
    for case in chosen:
        sizes = (args.inducing, args.max_iter) if args.coverage else None
        row = run_case(case, paths, config, args.workers, duration, sizes)
        rows.append(row)
        print_row(row)
        if args.coverage:
            print_coverage(row)
    result = summary(rows)
    print(
        f"origin accuracy {100 * result['origin_accuracy']:.0f} %, effect accuracy "
        f"{100 * result['effect_accuracy']:.0f} %, false findings on controls "
        f"{result['control_false_findings']}, median held-out improvement "
        f"{100 * (result['median_improvement'] or 0):+.0f} %"
    )
    if "coverage95_in_target" in result:
        low, high = result["coverage95_range"]
        print(
            f"coverage of ±1.96σ on independent recordings: in 0.90..0.99 for "
            f"{100 * result['coverage95_in_target']:.0f} % of the stages, median "
            f"{result['coverage95_median']:.3f} (range {low:.3f}-{high:.3f})"
        )
    if args.json:
        print(json.dumps({**result, "duration": duration, "cases": rows}))


if __name__ == "__main__":
    main()
