"""Correctors alone, named terms alone and both, on a recording of another excitation.

``--case servo`` (the default): the third-party-style DC servo (``tests/third_party.py``) is
recorded with a Coulomb friction its white-box lacks, once to train (12 s, reference amplitude
2 rad) and once with another excitation (6 s, amplitude 0.7 rad, another seed).
``--case stiffness``: the reference actuator with a concealed spring of 30 000 N/m on its load
(the concealed suite's case ``stiffness@load_force(ram_position)=30000``), its 20 s recording and
the suite's independent 8 s recording of another seed; the grey-box with the suite's
``--coverage`` settings (150 inducing points, 100 iterations). ``--case LABEL``: the same for any
case of the actuator suite, by its label as ``concealed_effects.py`` prints it (e.g.
``deadband=2e-05``; the first case of that label).

The diagnosis names terms on the first recording; the correctors are trained on the plain
white-box and on the white-box with those terms (``train_model(..., ship=...)``), and both models
are validated on the second recording. Printed: the comparison ``train --terms`` makes on the
training recording (the part it would ship is its ``best``), then each part's RMSE on the other
excitation, per stage.

``--range-margin X`` widens the range the correctors' features are clipped to by X times their
training span on each side (``fmu_greybox.model.chain.RANGE_MARGIN``, 0.05), to test whether
the clipping is what holds terms + correctors back on the other excitation (``1e6``: no
clipping in practice).

Usage: ``.venv/bin/python benchmarks/parts_other_excitation.py [--case servo|stiffness|LABEL]
[--range-margin X]``
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
import concealed_effects  # noqa: E402
import third_party  # noqa: E402

from fmu_greybox.diagnosis import Diagnosis  # noqa: E402
from fmu_greybox.fmi.archive import open_fmu  # noqa: E402
from fmu_greybox.model import chain  # noqa: E402
from fmu_greybox.model.terms import term_from_dict  # noqa: E402
from fmu_greybox.report.demo import VALIDATION_SEED_OFFSET  # noqa: E402
from fmu_greybox.workflow.train import train_model, with_inducing  # noqa: E402
from fmu_greybox.workflow.validate import validate_model  # noqa: E402

#: The concealed suite's case of ``--case stiffness``.
STIFFNESS_CASE = "stiffness@load_force(ram_position)=30000"


def servo(folder: Path) -> tuple:
    """The servo's project, training recording and recording of another excitation."""
    fmus = third_party.build_fmus(folder)
    with open_fmu(fmus["DCServoTruth"]) as truth:
        training = third_party.record(truth, {"fc": 0.02}, seed=13, duration=12.0)
        other = third_party.record(truth, {"fc": 0.02}, seed=99, duration=6.0, amplitude=0.7)
    config = third_party.project(fmus["DCServo"])
    return config, config, training, other


def suite_case(label: str, folder: Path) -> tuple:
    """The actuator's project (and its grey-box settings), the suite case's training recording
    and its independent recording, as ``concealed_effects.py --coverage`` makes them."""
    ce = concealed_effects
    chosen = [c for c in ce.cases(False, ("actuator",)) if c.label == label]
    if not chosen:
        labels = ", ".join(c.label for c in ce.cases(False, ("actuator",)))
        raise SystemExit(f"--case {label!r} is not a case of the actuator suite; one of: {labels}")
    case = chosen[0]
    paths = ce.fmu_paths(folder)
    config, truth_path, _, _ = ce.case_setting(case, paths)
    with open_fmu(truth_path) as truth, open_fmu(paths[case.whitebox]) as whitebox:
        training = ce.record(case, truth, whitebox, case.seed, 20.0)
        other = ce.record(
            case, truth, whitebox, case.seed + VALIDATION_SEED_OFFSET, ce.VALIDATION_DURATION
        )
    return config, with_inducing(config, 150, 100), training, other


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--case",
        default="servo",
        help="servo (default), stiffness, or the label of a case of the actuator suite.",
    )
    parser.add_argument(
        "--range-margin",
        type=float,
        default=chain.RANGE_MARGIN,
        help=f"Feature clipping margin, a share of the training span ({chain.RANGE_MARGIN}).",
    )
    args = parser.parse_args()
    chain.RANGE_MARGIN = args.range_margin
    with tempfile.TemporaryDirectory(prefix="parts-") as folder:
        if args.case == "servo":
            config, greybox, training, other = servo(Path(folder))
        else:
            label = STIFFNESS_CASE if args.case == "stiffness" else args.case
            config, greybox, training, other = suite_case(label, Path(folder))
        diagnosis = Diagnosis(config, greybox=None).fit(training)
        findings = [f.to_dict() for f in diagnosis.findings_]
        terms = [term_from_dict(t) for f in findings for t in f.get("terms", [])]
        print("named:", ", ".join(f"{f['effect']} {f['magnitude']['value']:.4g}" for f in findings))
        tables = {}
        for ship in ("correctors", "terms+correctors"):
            model = train_model(greybox, training, terms=terms, ship=ship)
            tables[ship] = validate_model(model, other).table
        print("comparison on the training recording:", json.dumps(model.training.parts))
        for stage, row in tables["terms+correctors"].items():
            print(
                f"other excitation {stage}: white-box {row['wb_rmse']:.4g}, correctors "
                f"{tables['correctors'][stage]['gb_rmse']:.4g}, terms {row['named_rmse']:.4g}, "
                f"terms+correctors {row['gb_rmse']:.4g}"
            )


if __name__ == "__main__":
    main()
