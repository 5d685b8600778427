"""The domain score of an exported grey-box on its own training inputs, with and without sensor
noise on the recorded inputs.

Trains the export tests' model (5 s recording with Coulomb friction, seed 11, 40 inducing points,
30 iterations), exports the native FMU and steps it over the first 500 training rows; prints how
many steps set ``out_of_domain`` and the lowest and median ``domain_score``.

Usage::

    .venv/bin/python benchmarks/domain_noisy_inputs.py
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
import test_export  # noqa: E402

from fmu_greybox.synth import actuator as synth  # noqa: E402


class _Folders:
    """Stands in for pytest's ``tmp_path_factory``."""

    def mktemp(self, name: str) -> Path:
        return Path(tempfile.mkdtemp(prefix=name))


def scores(input_noise: bool, rows: int = 500) -> tuple[int, float, float]:
    """Flagged steps, lowest and median domain score over the first ``rows`` training rows."""
    plain = synth.SynthRequest
    synth.SynthRequest = lambda *a, **k: plain(*a, **{**k, "input_noise": input_noise})
    test_export._CACHE.clear()
    try:
        made = test_export.trained(_Folders())
    finally:
        synth.SynthRequest = plain
    u = test_export.input_rows(made["training"])[: rows + 100]
    slave = test_export.Slave(made["fmus"]["native"], "domain", u)
    flag, score = slave.refs["out_of_domain"], slave.refs["domain_score"]
    flags, values = [], []
    for k in range(rows):
        slave.run(u[k : k + 1])
        flags.append(slave.slave.getBoolean([flag])[0])
        values.append(slave.slave.getReal([score])[0])
    slave.close()
    return sum(flags), min(values), float(np.median(values))


def main() -> None:
    for input_noise in (False, True):
        flagged, low, median = scores(input_noise)
        print(
            f"input_noise={input_noise}: out_of_domain on {flagged} of 500 training rows; "
            f"domain_score lowest {low:.2g}, median {median:.2f}"
        )


if __name__ == "__main__":
    main()
