"""Diagnosis: locate the mismatch between a white-box FMU and a recording, name the physics it
left out, model it, and show the fit improve.

The estimator is :class:`~.diagnose.Diagnosis`; ``diagnosis.json`` and the HTML report are
written by :func:`~.report.write_outputs`. See ``docs/diagnosis.md``.
"""

from fmu_greybox.diagnosis.diagnose import Diagnosis, GreyBoxSettings
from fmu_greybox.diagnosis.report import SCHEMA_VERSION, write_outputs

__all__ = ["SCHEMA_VERSION", "Diagnosis", "GreyBoxSettings", "write_outputs"]
