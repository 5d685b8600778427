"""Correctors alone, named terms alone and both, on a recording of another excitation.

The third-party-style DC servo (``tests/third_party.py``) is recorded with a Coulomb friction its
white-box lacks, once to train (12 s, reference amplitude 2 rad) and once with another
excitation (6 s, amplitude 0.7 rad, another seed). The diagnosis names terms on the first; the
correctors are trained on the plain white-box and on the white-box with those terms
(``train_model(..., ship=...)``), and both models are validated on the second recording. Printed:
the comparison ``train --terms`` makes on its own held-out rows, then each part's RMSE on the
other excitation, per stage.

Usage: ``.venv/bin/python benchmarks/parts_other_excitation.py``
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
import third_party  # noqa: E402

from fmu_greybox.diagnosis import Diagnosis  # noqa: E402
from fmu_greybox.fmi.archive import open_fmu  # noqa: E402
from fmu_greybox.model.terms import term_from_dict  # noqa: E402
from fmu_greybox.workflow.train import train_model  # noqa: E402
from fmu_greybox.workflow.validate import validate_model  # noqa: E402


def main() -> None:
    with tempfile.TemporaryDirectory(prefix="parts-") as folder:
        fmus = third_party.build_fmus(Path(folder))
        with open_fmu(fmus["DCServoTruth"]) as truth:
            training = third_party.record(truth, {"fc": 0.02}, seed=13, duration=12.0)
            other = third_party.record(truth, {"fc": 0.02}, seed=99, duration=6.0, amplitude=0.7)
        config = third_party.project(fmus["DCServo"])
        diagnosis = Diagnosis(config, greybox=None).fit(training)
        findings = [f.to_dict() for f in diagnosis.findings_]
        terms = [term_from_dict(t) for f in findings for t in f.get("terms", [])]
        print("named:", ", ".join(f"{f['effect']} {f['magnitude']['value']:.4g}" for f in findings))
        tables = {}
        for ship in ("correctors", "terms+correctors"):
            model = train_model(config, training, terms=terms, ship=ship)
            tables[ship] = validate_model(model, other).table
        print("held-out rows of the training recording:", json.dumps(model.training["parts"]))
        for stage, row in tables["terms+correctors"].items():
            print(
                f"other excitation {stage}: white-box {row['wb_rmse']:.4g}, correctors "
                f"{tables['correctors'][stage]['gb_rmse']:.4g}, terms {row['named_rmse']:.4g}, "
                f"terms+correctors {row['gb_rmse']:.4g}"
            )


if __name__ == "__main__":
    main()
