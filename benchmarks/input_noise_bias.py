"""The compliance calibration with and without sensor noise on the recorded inputs.

Records the truth actuator with a bulk modulus 30 % low (seed 11, 6 s) twice, with
``input_noise`` off and on, and calibrates the ``parameter_mismatch@bulk_modulus`` hypothesis
on each with the hypothesis tests' own helper. The truth is -0.3.

Usage::

    .venv/bin/python benchmarks/input_noise_bias.py
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
from test_diagnosis_hypotheses import calibrate  # noqa: E402

from fmu_greybox.fmi.archive import open_fmu  # noqa: E402
from fmu_greybox.fmi.builtin import reference_fmus  # noqa: E402
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise  # noqa: E402


def main() -> None:
    paths = reference_fmus()
    profile = FlightTestProfile(duration=6.0)
    for input_noise in (False, True):
        request = SynthRequest({"compliance": 0.3}, 11, profile=profile, input_noise=input_noise)
        with (
            open_fmu(paths["HydraulicActuatorTruth"]) as truth,
            open_fmu(paths["HydraulicActuator"]) as whitebox,
        ):
            recording = synthesise(truth, whitebox, request)
            fitted = calibrate(
                "hydraulic_actuator.toml", whitebox, recording, "parameter_mismatch@bulk_modulus"
            )
        low, high = fitted.ci95[0]
        print(f"input_noise={input_noise}: {fitted.theta[0]:+.3f} [{low:+.3f}, {high:+.3f}]")


if __name__ == "__main__":
    main()
