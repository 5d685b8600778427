"""Concealed effects: does the diagnosis find what the truth hid from the white-box?

Two white-boxes are diagnosed:

* the reference actuator (``bench_configs/hydraulic_actuator.toml``): every truth effect of its
  truth FMU and every effect the recorder can put around it in its closed loop (a saturating
  amplifier, a play in the command path, a load offset, a spring, a position sensor reading
  high, a pressure sensor offset or late; :mod:`fmu_greybox.synth.loop`), each at a small and a
  large magnitude, four again at noise scale 3, pairs of effects, the pairs where aliases lurk
  (sensor gain against flow gain, force offset against current offset, saturation against
  droop, Coulomb against viscous friction on a test with few velocity levels, friction stronger
  in one direction), and no-effect controls;
* a DC servo in the style of a third party (``tests/data/dc_servo``: no units, terse names,
  descriptions only; recorded by ``tests/third_party.py`` in its own closed loop), with and
  without a speed output: a missing Coulomb friction, a current-sensor offset of two noise
  levels, friction stronger in one direction, and controls.

Every recording carries sensor noise on every recorded signal, the logged commands included.
The diagnosis gets only the white-box FMU, the project file and the recording.

Scoring (this file knows the truth; the diagnosis does not):

* expected origin: the first stage with a recorded signal that the effect moves by more than
  0.83 times its sensor noise (RMS: the structure that lifts a residual to 1.3 times the noise,
  the diagnosis' significance level), found by running the truth FMU open-loop over the
  recorded inputs with and without the effect; ``None`` for controls;
* effect correct: the top finding's effect is (one of) the true effect(s), or it is a
  ``parameter_mismatch`` whose physics label is; ``none`` for controls. *Named or equally
  consistent*: the same, or a true effect is among the top finding's alternatives;
* estimated vs true magnitude, converted to the truth's units;
* held-out improvement: the relative change of the held-out RMSE, white-box + named terms
  against white-box, averaged over the stages the effect moves;
* harm: a kept finding whose removal makes some observed signal's held-out fit better by more
  than 5 % (the diagnosis drops those; this counts any it kept).

Usage::

    .venv/bin/python benchmarks/concealed_effects.py [--quick] [--json] [--workers N]
        [--suite actuator|servo] [--case EFFECT=VALUE[+EFFECT=VALUE] ...] [--start N] [--stop N]

``--start N`` skips the suite's first N-1 cases and ``--stop N`` ends after its N-th (each
case's seed is its own, so a part runs exactly as in a whole run). ``--case`` replaces the
suite by the cases given (actuator, noise scale 1, seeds 301, 302, ...), e.g. magnitudes
outside the suite's.

``--coverage`` also checks the calibrated uncertainty on each case, as the demo does: the
named terms folded into the white-box, the grey-box trained on the recording (``--inducing``,
``--max-iter``; the demo's 150 and 100 by default) and free-run on an independent 8 s
recording of the same truth model (seed + 1 000 003); per stage the share of its rows inside
±1σ and ±1.96σ (with the 95 % interval of the ±1.96σ share), and over all stages of all cases
the share whose ±1.96σ coverage lies in the target 0.90 .. 0.99, and the share whose interval
reaches it (the recording cannot tell those from calibrated). Each case's ``--json`` line
also says which of the model's parts shipped (``shipped``: the terms, the correctors or both).
``--calibrate-on C`` calibrates σ on C more recordings of the same truth model, each as long
as the independent one (seeds + 2 000 001, + 2 000 002, ...), instead of the halves of the
training recording (``train --calibrate-on``): one free run of the bench test's length each.

Per stage name (EHV, RAM, ...) the shares are also pooled over the cases
(:func:`~fmu_greybox.model.calibration.pooled_coverage`: each weighted by its independent rows,
with the interval of their sum): a drifting position stage's recording is worth a handful of
independent rows, too few to decide alone whether its band is wide or narrow; the cases
together can. Bands decidedly too narrow are counted, with how many of them were scored on
a recording whose grey-box errors are larger than those of the free runs their σ was
calibrated on by enough to account for the miss (``validate`` notes those in its acceptance
table).

With ``--json`` each case is also printed as one JSON line when it is done, and the last line
is one JSON object: the summary figures (with ``--coverage`` also ``coverage95_in_target``,
``coverage95_consistent``, ``coverage95_median``, ``coverage95_range``,
``coverage95_pooled``, ``coverage95_narrow``, ``coverage95_by_size``,
``coverage95_by_worth`` and ``coverage95_by_free_runs``) and the cases.
``--summarise LOG [LOG ...]`` runs nothing: it reads the cases such runs printed (a suite run
in parts, or stopped part way) and prints their summary.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
import third_party  # noqa: E402

from fmu_greybox.data.noise import SIGNIFICANT_STRUCTURE  # noqa: E402
from fmu_greybox.diagnosis import Diagnosis  # noqa: E402
from fmu_greybox.diagnosis.findings import named_physics  # noqa: E402
from fmu_greybox.fmi.archive import FmuArchive, open_fmu  # noqa: E402
from fmu_greybox.fmi.builtin import reference_fmus  # noqa: E402
from fmu_greybox.model.calibration import Z95, calibration_spread, chance_within  # noqa: E402
from fmu_greybox.model.simulate import simulate_with_terms  # noqa: E402
from fmu_greybox.model.whitebox import terms_from_findings  # noqa: E402
from fmu_greybox.project.config import load_config  # noqa: E402
from fmu_greybox.report.demo import VALIDATION_SEED_OFFSET  # noqa: E402
from fmu_greybox.synth.actuator import (  # noqa: E402
    INPUTS,
    SENSOR_NOISE,
    TYPICAL_MAGNITUDES,
    FlightTestProfile,
    SynthRequest,
    synthesise,
)
from fmu_greybox.synth.loop import is_loop_effect, loop_terms, parse_loop_effects  # noqa: E402
from fmu_greybox.workflow.acceptance import share_at_error_ratio  # noqa: E402
from fmu_greybox.workflow.metrics import coverage_text, error_ratio, pooled_row  # noqa: E402
from fmu_greybox.workflow.train import train_model, with_inducing  # noqa: E402
from fmu_greybox.workflow.validate import validate_model  # noqa: E402

CONFIG = ROOT / "bench_configs" / "hydraulic_actuator.toml"
#: The recorded signals of each stage (benchmark knowledge).
STAGE_SIGNALS = {
    "EHV": ("spool_position",),
    "RAM": ("ram_position", "ram_velocity"),
    "ITFV": ("itfv_pressure",),
    "ELEC": ("ia",),
    "MECH": ("th", "w"),
}
#: The physics a truth effect is (the truth's name without the variable it acts on).
TRUTH_PHYSICS = {
    "friction_asymmetry": "coulomb_friction",
    "fa": "coulomb_friction",
    "fc": "coulomb_friction",
    "saturation_upper": "saturation",
    "saturation_lower": "saturation",
}

#: Effects around the actuator in its loop, at a small and a large magnitude.
LOOP_MAGNITUDES: dict[str, tuple[float, ...]] = {
    "sensor_gain@ram_position": (0.03, 0.08),
    "sensor_offset@itfv_pressure": (1e5, 3e5),
    "sensor_delay@itfv_pressure": (0.002, 0.006),
    "saturation@valve_current": (6.0, 4.0),
    "hysteresis@valve_current": (0.2, 0.6),
    "force_offset@load_force": (1500.0, 4000.0),
    "stiffness@load_force(ram_position)": (3e4, 1e5),
}
MAGNITUDES = {**TYPICAL_MAGNITUDES, **LOOP_MAGNITUDES}
PAIRS = (
    {"coulomb_friction": 600.0, "offset": 0.2},
    {"gain_error": 0.05, "time_delay": 0.003},
    {"internal_leakage": 5e-13, "compliance": 0.3},
)
#: One truth each, where another explanation lurks (the alias named in the comment).
ALIASES = (
    {"sensor_gain@ram_position": 0.05},  # against the valve's flow gain
    {"gain_error": 0.05},  # against the position sensor's gain
    {"force_offset@load_force": 2500.0},  # against a current offset
    {"offset": 0.2},  # against a force offset
    {"saturation@valve_current": 5.0},  # against a supply droop
    {"saturation_upper@valve_current": 5.0, "saturation_lower@valve_current": -8.0},
    {"coulomb_friction": 600.0, "friction_asymmetry": 250.0},  # friction stronger one way
    {"coulomb_friction": 300.0, "friction_asymmetry": 150.0},
)
#: Coulomb against viscous friction on a test that ramps at one rate only [m/s].
FEW_VELOCITIES = 0.02


@dataclass(frozen=True)
class Case:
    """One recording to diagnose."""

    effects: dict[str, float] = field(default_factory=dict)
    noise: float = 1.0
    seed: int = 0
    suite: str = "actuator"
    whitebox: str = "HydraulicActuator"
    ramp_rate: float | None = None

    @property
    def label(self) -> str:
        text = " + ".join(f"{k}={v:g}" for k, v in self.effects.items()) or "control"
        if self.suite == "servo":
            text = f"{self.whitebox}: {text}"
        return f"{text} (ramps)" if self.ramp_rate else text


def cases(quick: bool, suites: tuple[str, ...]) -> list[Case]:
    """The suite (``quick``: one magnitude per effect, one pair, two controls)."""
    found: list[Case] = []
    if "actuator" in suites:
        found += _actuator_cases(quick)
    if "servo" in suites:
        found += _servo_cases(quick)
    return found


def _actuator_cases(quick: bool) -> list[Case]:
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
    for alias in ALIASES[:2] if quick else ALIASES:
        seed += 1
        found.append(Case(dict(alias), 1.0, seed))
    seed += 1
    found.append(Case({"coulomb_friction": 600.0}, 1.0, seed, ramp_rate=FEW_VELOCITIES))
    controls = ((1.0, 1), (1.0, 2)) if quick else ((1.0, 1), (1.0, 2), (1.0, 3), (3.0, 4))
    found += [Case({}, noise, s) for noise, s in controls]
    return found


def _servo_cases(quick: bool) -> list[Case]:
    found = [
        Case({"fc": 0.02}, seed=501, suite="servo", whitebox="DCServo"),
        Case({"fc": 0.02}, seed=502, suite="servo", whitebox="DCAxis"),
        Case({"sensor_offset@ia": 0.008}, seed=503, suite="servo", whitebox="DCServo"),
        Case({}, seed=504, suite="servo", whitebox="DCServo"),
    ]
    if not quick:
        found += [
            Case({"fc": 0.006}, seed=505, suite="servo", whitebox="DCServo"),
            Case({"fc": 0.01, "fa": 0.004}, seed=506, suite="servo", whitebox="DCServo"),
            Case({"sensor_offset@ia": 0.02}, seed=507, suite="servo", whitebox="DCAxis"),
            Case({}, seed=508, suite="servo", whitebox="DCAxis"),
        ]
    return found


def given_case(text: str, seed: int) -> Case:
    """An actuator case from ``EFFECT=VALUE[+EFFECT=VALUE]``."""
    effects = {}
    for part in text.split("+"):
        name, sep, value = part.partition("=")
        known = name.strip() in MAGNITUDES or is_loop_effect(name) or name in TRUTH_PHYSICS
        if not sep or not known:
            raise SystemExit(
                f"--case {text!r}: write EFFECT=VALUE with EFFECT one of {', '.join(MAGNITUDES)}"
                " or another truth effect or loop effect"
            )
        effects[name.strip()] = float(value)
    return Case(effects, 1.0, seed)


def truth_physics(effect: str) -> str:
    """The vocabulary identifier of a truth effect."""
    name = effect.split("@")[0]
    return TRUTH_PHYSICS.get(name, name)


def expected_origin(
    truth: FmuArchive, recording, case: Case, config, inputs, noise: dict[str, float]
) -> tuple[str | None, list]:
    """First stage with a recorded signal the effect moves by more than 0.83 noise levels;
    every stage it moves."""
    if not case.effects:
        return None, []
    u = np.column_stack([recording[name] for name in inputs])
    outputs = list(truth.outputs)
    signals = [
        name for stage in config.stages for name in STAGE_SIGNALS[stage.name] if name in outputs
    ]
    runs = []
    for effects in ({}, case.effects):
        parameters = {k: v for k, v in effects.items() if not is_loop_effect(k)}
        terms = loop_terms(parse_loop_effects(effects, inputs, outputs))
        run = simulate_with_terms(
            truth, inputs, u, recording.dt, signals, terms, parameters=parameters
        )
        runs.append(run)
    change = np.sqrt(np.mean((runs[1] - runs[0]) ** 2, axis=0))
    sigma = np.array([noise[name] for name in signals]) * max(case.noise, 1e-3)
    moved = [
        stage.name
        for stage in config.stages
        if any(
            change[signals.index(name)] > SIGNIFICANT_STRUCTURE * sigma[signals.index(name)]
            for name in STAGE_SIGNALS[stage.name]
            if name in signals
        )
    ]
    return (moved[0] if moved else None), moved


def in_truth_units(finding: dict, effect: str, whitebox: FmuArchive) -> float | None:
    """A finding's magnitude in the truth's units for ``effect``."""
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


def true_magnitude(case: Case, physics: str) -> float | None:
    """The truth's magnitude of the effect of that physics (the first named, for pairs)."""
    for name, value in case.effects.items():
        if truth_physics(name) == physics:
            return abs(value) if physics == "saturation" else value
    return None


def case_setting(case: Case, paths: dict) -> tuple:
    """The case's project, truth FMU path, recorded inputs and sensor noise."""
    if case.suite == "servo":
        noise = dict(third_party.SENSOR_NOISE)
        return (
            third_party.project(paths[case.whitebox]),
            paths["DCServoTruth"],
            third_party.INPUTS,
            noise,
        )
    return load_config(CONFIG), paths["HydraulicActuatorTruth"], INPUTS, SENSOR_NOISE


def record(case: Case, truth: FmuArchive, whitebox: FmuArchive, seed: int, duration: float):
    """A recording of the case's truth model (its suite's recorder) with this seed."""
    if case.suite == "servo":
        return third_party.record(truth, case.effects, seed, duration)
    profile = FlightTestProfile(duration=duration, ramp_rate=case.ramp_rate)
    return synthesise(truth, whitebox, SynthRequest(case.effects, seed, case.noise, profile))


def run_case(
    case: Case,
    paths: dict,
    workers: int,
    duration: float,
    coverage: tuple[int, int] | None = None,
    calibrate_on: int = 0,
) -> dict:
    """Record, diagnose and score one case; with ``coverage`` (inducing points, iterations)
    also train and validate the grey-box, its σ calibrated on ``calibrate_on`` more
    recordings when not 0 (see the module docstring)."""
    config, truth_path, inputs, noise = case_setting(case, paths)
    with open_fmu(truth_path) as truth, open_fmu(paths[case.whitebox]) as whitebox:
        recording = record(case, truth, whitebox, case.seed, duration)
        origin, moved = expected_origin(truth, recording, case, config, inputs, noise)
        started = time.perf_counter()
        diagnosis = Diagnosis(config, workers=workers, greybox=None).fit(recording)
        seconds = time.perf_counter() - started
        findings = [f.to_dict() for f in diagnosis.findings_]
        top = findings[0]
        truth_effects = [truth_physics(name) for name in case.effects] or ["none"]
        named = named_physics(top)
        correct = named in truth_effects
        alternatives = [named_physics(a) for a in top.get("alternatives", [])]
        consistent = correct or any(a in truth_effects for a in alternatives)
        estimate = in_truth_units(top, named, whitebox) if correct and case.effects else None
        harmful = _harmful(diagnosis, whitebox)
        if coverage is not None:
            independent = record(
                case, truth, whitebox, case.seed + VALIDATION_SEED_OFFSET, VALIDATION_DURATION
            )
            calibration = [
                record(case, truth, whitebox, seed, VALIDATION_DURATION)
                for seed in calibration_seeds(case, calibrate_on)
            ]
    checked, shipped = (
        uncertainty_coverage(config, findings, recording, independent, coverage, calibration)
        if coverage is not None
        else (None, None)
    )
    true_value = true_magnitude(case, named) if correct else None
    affected = [diagnosis.fit_[s] for s in moved if s in diagnosis.fit_]
    improvement = (
        float(np.mean([row["named_improvement"] for row in affected])) if affected else None
    )
    return {
        "case": case.label,
        "suite": case.suite,
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
        "consistent": consistent,
        "alternatives": alternatives,
        "findings": [named_physics(f) for f in findings],
        "harmful_kept": harmful,
        "estimate": estimate,
        "true": true_value,
        "improvement": improvement,
        "seconds": round(seconds, 1),
        **({"coverage": checked, "shipped": shipped} if checked is not None else {}),
    }


#: The independent validation recording of a case: its length [s] (the demo's); its seed is the
#: case's plus the demo's VALIDATION_SEED_OFFSET.
VALIDATION_DURATION = 8.0
#: The seeds of a case's calibration recordings are its own plus this plus 1, 2, ...
CALIBRATION_SEED_OFFSET = 2_000_000


def calibration_seeds(case: Case, count: int) -> list[int]:
    """The seeds of the case's ``count`` calibration recordings (``--calibrate-on``)."""
    return [case.seed + CALIBRATION_SEED_OFFSET + c for c in range(1, count + 1)]


def uncertainty_coverage(
    config,
    findings: list,
    recording,
    independent,
    sizes: tuple[int, int],
    calibration: list = (),
) -> tuple[dict[str, dict[str, float]], str]:
    """Train the grey-box on the case's recording (named terms first; σ calibrated on the
    ``calibration`` recordings when given), free-run it on the independent recording; per
    stage ``coverage68``, ``coverage95`` with its interval, RMSE, median σ and the RMSE of the
    free runs σ was calibrated on, and which of the model's parts shipped (``terms``,
    ``correctors`` or ``terms+correctors``; ``correctors`` when nothing was named)."""
    model = train_model(
        with_inducing(config, *sizes),
        recording,
        terms=terms_from_findings(findings),
        calibration_recordings=calibration,
    )
    table = validate_model(model, independent).table
    keys = ("coverage68", "coverage95", "coverage95_low", "coverage95_high", "gb_rmse")
    keys += ("median_std", "independent_rows", "calibration_rmse", "calibration_independent_rows")
    keys += ("calibration_recordings", "calibration_share_low", "calibration_share_high")
    shipped = (model.training.parts or {}).get("shipped", "correctors")
    return {stage: {k: row[k] for k in keys if k in row} for stage, row in table.items()}, shipped


def print_coverage(row: dict) -> None:
    """The case's coverage, one line under its row."""
    parts = [
        f"{stage} {100 * c['coverage68']:.1f} / {coverage_text(c, 'coverage95')}"
        for stage, c in row["coverage"].items()
    ]
    print(f"{'':4s}inside ±1σ / ±1.96σ on an independent recording: {', '.join(parts)}")


def _harmful(diagnosis, whitebox: FmuArchive) -> int:
    """Kept findings without which some observed signal's held-out fit is better by more than
    5 % (the selection's own check, repeated here on the final model)."""
    selection = diagnosis.selection_
    if selection is None or not selection.selected_.hypotheses:
        return 0
    selected = selection.selected_
    pairs = list(zip(selected.hypotheses, selected.split(), strict=True))
    experiment = dataclasses.replace(diagnosis.experiment_, archive=whitebox, _cache={})
    rows = experiment.train_rows
    kept = experiment.residual(selected.simulated[rows:], rows)
    count = 0
    for left, _ in pairs:
        terms = [t for h, th in pairs if h is not left for t in h.terms(th)]
        run = experiment.simulate(terms)
        if run is None:
            continue
        without = experiment.residual(run[rows:], rows)
        rms_kept = np.sqrt(np.mean(kept**2, axis=0))
        rms_without = np.sqrt(np.mean(without**2, axis=0))
        count += bool(np.any(rms_kept > 1.05 * rms_without))
    return count


def print_row(row: dict) -> None:
    est = "-" if row["estimate"] is None else f"{row['estimate']:.3g}"
    true = "-" if row["true"] is None else f"{row['true']:.3g}"
    imp = "-" if row["improvement"] is None else f"{100 * row['improvement']:+.0f} %"
    ok = "yes" if row["effect_correct"] else ("alt" if row["consistent"] else "NO")
    print(
        f"{row['case'][:56]:56s} {row['noise']:5.1f} {row['expected_origin']!s:6s} "
        f"{row['origin']!s:6s} {row['top_finding'][:34]:34s} "
        f"{ok:4s} {est:>10s} {true:>10s} {imp:>7s} {row['harmful_kept']:5d} "
        f"{row['seconds']:6.1f}",
        flush=True,
    )


#: The target of a ±1.96σ share on an independent recording.
TARGET = (0.90, 0.99)


#: The target as the summary prints it.
TARGET_TEXT = f"{TARGET[0]:.2f}..{TARGET[1]:.2f}"


def _reaches_target(stage: dict) -> bool:
    """Whether a stage's ±1.96σ share's 95 % interval reaches the :data:`TARGET`."""
    return stage["coverage95_low"] <= TARGET[1] and stage["coverage95_high"] >= TARGET[0]


def _narrow(rows: list[dict]) -> dict:
    """The stages whose ±1.96σ share is decidedly below 0.90 (``decided``), and how many of them
    (``shifted``) were scored on a recording whose grey-box errors are so much larger than
    those of the training free runs their σ was calibrated on (``k`` times) that this alone
    puts the share expected of Gaussian errors below 0.90
    (:func:`~fmu_greybox.workflow.acceptance.share_at_error_ratio`), counted over the stages
    that report it (``told``); ``stages`` lists each with its case, share, ``k`` and the share
    ``k`` predicts."""
    listed = []
    for row in rows:
        for stage, c in row.get("coverage", {}).items():
            if c["coverage95_high"] >= TARGET[0]:
                continue
            item = {"case": row["case"], "stage": stage, "coverage95": c["coverage95"]}
            k = error_ratio(c)
            if k is not None:
                item |= {"k": k, "predicted": share_at_error_ratio(k, Z95)}
            listed.append(item)
    told = [item for item in listed if "k" in item]
    return {
        "decided": len(listed),
        "told": len(told),
        "shifted": sum(item["predicted"] < TARGET[0] for item in told),
        "stages": listed,
    }


def _in_target(share: float) -> bool:
    """Whether a ±1.96σ share lies in the :data:`TARGET`."""
    return TARGET[0] <= share <= TARGET[1]


def _by_size(stages: list[dict]) -> dict[str, float]:
    """How well the error ratio ``k`` alone predicts the ±1.96σ shares, over the stages that
    report it (``stages``): the median and the largest distance between a share and
    :func:`~fmu_greybox.workflow.acceptance.share_at_error_ratio` of its ``k``; and, split by
    whether that prediction lies in the target (``k`` about 0.76 .. 1.19), how many stages
    there are and how many of them lie in the target (``predicted_in``, ``in_of_predicted_in``;
    ``predicted_out``, ``in_of_predicted_out``)."""
    pairs = [
        (c["coverage95"], share_at_error_ratio(k, Z95))
        for c in stages
        if (k := error_ratio(c)) is not None
    ]
    if not pairs:
        return {"stages": 0}
    gaps = [abs(share - predicted) for share, predicted in pairs]
    inside = [_in_target(share) for share, predicted in pairs if _in_target(predicted)]
    outside = [_in_target(share) for share, predicted in pairs if not _in_target(predicted)]
    return {
        "stages": len(gaps),
        "median_gap": statistics.median(gaps),
        "max_gap": max(gaps),
        "predicted_in": len(inside),
        "in_of_predicted_in": sum(inside),
        "predicted_out": len(outside),
        "in_of_predicted_out": sum(outside),
    }


def _by_worth(stages: list[dict]) -> dict[str, float]:
    """Split the stages that say what their calibration rows were worth by whether those rows
    vouch for the target on recordings like them (their
    :func:`~fmu_greybox.model.calibration.calibration_spread` within 0.90 .. 0.99), and count
    how many of each lie in the target (``vouched``, ``in_of_vouched``; ``unvouched``,
    ``in_of_unvouched``) and how many the Beta law of their rows expects there
    (``expected_of_vouched``, ``expected_of_unvouched``: the sum of each stage's
    :func:`~fmu_greybox.model.calibration.chance_within`; for endless recordings, so an upper
    figure for 8 s ones)."""
    split: dict[bool, list[tuple[bool, float]]] = {True: [], False: []}
    for c in stages:
        if "calibration_independent_rows" in c:
            rows = c["calibration_independent_rows"]
            low, high = calibration_spread(rows)
            chance = chance_within(rows, TARGET)
            split[_in_target(low) and _in_target(high)].append(
                (_in_target(c["coverage95"]), chance)
            )
    counts: dict[str, float] = {}
    for vouched, name in ((True, "vouched"), (False, "unvouched")):
        counts[name] = len(split[vouched])
        counts[f"in_of_{name}"] = sum(inside for inside, _ in split[vouched])
        counts[f"expected_of_{name}"] = sum(chance for _, chance in split[vouched])
    return counts


def _by_free_runs(stages: list[dict]) -> dict[str, int]:
    """Of the stages whose model says what its calibration's free runs held, each scored with
    σ calibrated on the others (``calibration_share_low`` .. ``_high``), how many have their
    independent recording's ±1.96σ share in that range (``in_range`` of ``stages``), and how
    many of those missing the target do (``misses_in_range`` of ``misses``)."""
    told = [c for c in stages if "calibration_share_low" in c and "calibration_share_high" in c]
    in_range = [
        c["calibration_share_low"] <= c["coverage95"] <= c["calibration_share_high"] for c in told
    ]
    missed = [
        inside for c, inside in zip(told, in_range, strict=True) if not _in_target(c["coverage95"])
    ]
    return {
        "stages": len(told),
        "in_range": sum(in_range),
        "misses": len(missed),
        "misses_in_range": sum(missed),
    }


def pooled_by_stage(rows: list[dict]) -> dict[str, dict[str, float]]:
    """Per stage name, its ±1.96σ shares over the cases pooled by their independent rows."""
    by_stage: dict[str, list[dict]] = {}
    for row in rows:
        for stage, c in row.get("coverage", {}).items():
            by_stage.setdefault(stage, []).append(c)
    return {stage: pooled_row(found) for stage, found in by_stage.items()}


def summary(rows: list[dict]) -> dict:
    effect_rows = [r for r in rows if not r["control"]]
    controls = [r for r in rows if r["control"]]
    improvements = [r["improvement"] for r in effect_rows if r["improvement"] is not None]
    stages = [c for r in rows for c in r.get("coverage", {}).values()]
    covered = [c["coverage95"] for c in stages]
    coverage = (
        {
            "coverage95_in_target": float(np.mean([_in_target(c) for c in covered])),
            "coverage95_consistent": float(np.mean([_reaches_target(c) for c in stages])),
            "coverage95_median": statistics.median(covered),
            "coverage95_range": [min(covered), max(covered)],
            "coverage95_pooled": pooled_by_stage(rows),
            "coverage95_narrow": _narrow(rows),
            "coverage95_by_size": _by_size(stages),
            "coverage95_by_worth": _by_worth(stages),
            "coverage95_by_free_runs": _by_free_runs(stages),
        }
        if covered
        else {}
    )
    return {
        **coverage,
        "origin_accuracy": float(np.mean([r["origin_correct"] for r in rows])),
        "effect_accuracy": float(np.mean([r["effect_correct"] for r in effect_rows])),
        "consistent_accuracy": float(np.mean([r["consistent"] for r in effect_rows])),
        "control_false_findings": sum(
            sum(1 for f in r["findings"] if f != "none") for r in controls
        ),
        "harmful_findings_kept": sum(r["harmful_kept"] for r in rows),
        "median_improvement": statistics.median(improvements) if improvements else None,
        "n_cases": len(rows),
        "n_controls": len(controls),
        "median_seconds": statistics.median(r["seconds"] for r in rows),
        "cases": rows,
    }


def fmu_paths(folder: Path) -> dict[str, Path]:
    """Every FMU the suites use: the reference actuator's and the servo's (built here)."""
    return {**reference_fmus(), **third_party.build_fmus(folder)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="A shorter suite.")
    parser.add_argument("--json", action="store_true", help="End with one JSON line.")
    parser.add_argument("--workers", type=int, default=2, help="Simulation workers.")
    parser.add_argument(
        "--duration", type=float, default=None, help="Recording length [s] (default 20, quick 12)."
    )
    parser.add_argument(
        "--suite",
        action="append",
        choices=("actuator", "servo"),
        help="Run only this white-box's cases (repeatable; default both).",
    )
    parser.add_argument(
        "--coverage",
        action="store_true",
        help="Also train and validate the grey-box and report its uncertainty's coverage.",
    )
    parser.add_argument("--inducing", type=int, default=150, help="With --coverage (150).")
    parser.add_argument("--max-iter", type=int, default=100, help="With --coverage (100).")
    parser.add_argument(
        "--calibrate-on",
        type=int,
        default=0,
        metavar="C",
        help="With --coverage: calibrate σ on C more recordings of the independent one's length "
        "(default 0: the halves of the training recording).",
    )
    parser.add_argument(
        "--case",
        action="append",
        default=[],
        metavar="EFFECT=VALUE[+EFFECT=VALUE]",
        help="Run these actuator cases instead of the suite (repeatable).",
    )
    parser.add_argument(
        "--start",
        type=int,
        default=1,
        metavar="N",
        help="Begin at the suite's N-th case (1-based), to resume an interrupted run.",
    )
    parser.add_argument(
        "--stop",
        type=int,
        default=None,
        metavar="N",
        help="End after the suite's N-th case (1-based; default: its last), to run it in parts.",
    )
    parser.add_argument(
        "--summarise",
        nargs="+",
        metavar="LOG",
        help="Run nothing: summarise the cases earlier --json runs printed to these logs.",
    )
    args = parser.parse_args()
    if args.summarise:
        print_summary(summary(logged_cases(args.summarise)), args.json)
        return
    if args.start < 1:
        parser.error(f"--start {args.start}: cases are numbered from 1")
    if args.stop is not None and args.stop < args.start:
        parser.error(f"--stop {args.stop}: before --start {args.start}")
    duration = args.duration or (12.0 if args.quick else 20.0)
    print(
        f"{'true effect':56s} {'noise':>5s} {'exp.':6s} {'origin':6s} {'top finding':34s} "
        f"{'ok':4s} {'estimate':>10s} {'true':>10s} {'impr.':>7s} {'harm':>5s} {'time':>6s}"
    )
    rows = []
    suites = tuple(args.suite or ("actuator", "servo"))
    chosen = [given_case(text, 301 + i) for i, text in enumerate(args.case)]
    with tempfile.TemporaryDirectory(prefix="concealed-") as folder:
        paths = fmu_paths(Path(folder))
        for case in (chosen or cases(args.quick, suites))[args.start - 1 : args.stop]:
            sizes = (args.inducing, args.max_iter) if args.coverage else None
            row = run_case(case, paths, args.workers, duration, sizes, args.calibrate_on)
            rows.append(row)
            print_row(row)
            if args.coverage:
                print_coverage(row)
            if args.json:
                print(json.dumps(row), flush=True)
    print_summary({**summary(rows), "duration": duration}, args.json)


def logged_cases(paths: list[str]) -> list[dict]:
    """The cases ``--json`` runs printed to these logs, in order; a case printed twice (a
    resumed run, the final line repeating them) counts once, as printed last."""
    found: dict[tuple, dict] = {}
    for path in paths:
        try:
            lines = Path(path).read_text(encoding="utf-8").splitlines()
        except OSError as exc:
            raise SystemExit(f"--summarise {path}: unreadable ({exc})") from exc
        for line in lines:
            if not line.startswith("{"):
                continue
            payload = json.loads(line)
            for row in payload.get("cases", [payload] if "case" in payload else []):
                found[(row["suite"], row["case"], row["seed"])] = row
    if not found:
        raise SystemExit(f"--summarise: no case in {', '.join(paths)}; run with --json")
    return list(found.values())


def print_summary(result: dict, as_json: bool) -> None:
    """The summary lines (and with ``as_json`` the final JSON line)."""
    print(
        f"origin accuracy {100 * result['origin_accuracy']:.0f} %, effect accuracy "
        f"{100 * result['effect_accuracy']:.0f} % (named or equally consistent "
        f"{100 * result['consistent_accuracy']:.0f} %), false findings on controls "
        f"{result['control_false_findings']}, harmful findings kept "
        f"{result['harmful_findings_kept']}, median held-out improvement "
        f"{100 * (result['median_improvement'] or 0):+.0f} %"
    )
    if "coverage95_in_target" in result:
        low, high = result["coverage95_range"]
        print(
            f"coverage of ±1.96σ on independent recordings: in {TARGET_TEXT} for "
            f"{100 * result['coverage95_in_target']:.0f} % of the stages (its 95 % interval "
            f"reaches it for {100 * result['coverage95_consistent']:.0f} %), median "
            f"{result['coverage95_median']:.3f} (range {low:.3f}-{high:.3f})"
        )
        narrow = result.get("coverage95_narrow", {})
        if narrow.get("decided"):
            print(
                f"  decided too narrow: {narrow['decided']} stage(s); of the {narrow['told']} "
                f"that say, {narrow['shifted']} on a recording whose errors are larger than "
                "those their band was calibrated on by enough to account for it"
            )
        by_size = result.get("coverage95_by_size", {})
        if by_size.get("stages"):
            print(
                f"  share against the one its error ratio predicts, over {by_size['stages']} "
                f"stages: median gap {100 * by_size['median_gap']:.1f} points, largest "
                f"{100 * by_size['max_gap']:.1f}"
            )
            print(
                f"  in {TARGET_TEXT}: {by_size['in_of_predicted_in']} of the "
                f"{by_size['predicted_in']} stages whose error ratio predicts a share there, "
                f"{by_size['in_of_predicted_out']} of the {by_size['predicted_out']} whose "
                "ratio predicts one outside"
            )
        worth = result.get("coverage95_by_worth", {})
        if worth.get("vouched", 0) + worth.get("unvouched", 0):
            print(
                f"  in {TARGET_TEXT}: {worth['in_of_vouched']} of the {worth['vouched']} stages "
                "whose calibration rows vouch for it on recordings like them "
                f"({worth['expected_of_vouched']:.1f} expected from their rows), "
                f"{worth['in_of_unvouched']} of the {worth['unvouched']} whose rows are too few "
                f"({worth['expected_of_unvouched']:.1f} expected)"
            )
        runs = result.get("coverage95_by_free_runs", {})
        if runs.get("stages"):
            print(
                f"  in the range of shares the calibration's free runs held (each with σ from "
                f"the others): {runs['in_range']} of {runs['stages']} stages, "
                f"{runs['misses_in_range']} of the {runs['misses']} outside {TARGET_TEXT}"
            )
        for item in narrow.get("stages", []):
            ratio = (
                f": errors {item['k']:.3g} times the calibration's, which predict "
                f"{100 * item['predicted']:.1f} %"
                if "k" in item
                else ""
            )
            print(f"    {item['case']} {item['stage']} {100 * item['coverage95']:.1f} %{ratio}")
        for stage, c in result["coverage95_pooled"].items():
            print(
                f"  {stage} pooled over {c['recordings']} cases: {coverage_text(c, 'coverage95')} "
                f"of {c['independent_rows']:.0f} independent rows inside ±1.96σ"
            )
    if as_json:
        print(json.dumps(result))


if __name__ == "__main__":
    main()
