"""fmu-greybox: grey-box enhancement of white-box FMUs with sparse-GP correctors.

The public Python API, one name per step of the data flow (docs/api.md)::

    from fmu_greybox import load_config, load_recording, Diagnosis, train_model

Names are imported on first use, so ``import fmu_greybox`` stays cheap (the exported FMU's
runtime and the command line import the package before they know what they need).

Importing the package sets ``OPENBLAS_THREAD_TIMEOUT=1`` unless it is set already. numpy and
scipy each bundle an OpenBLAS with its own thread pool, whose idle threads spin for a while
after every call; the sparse-GP fit alternates numpy products and scipy factorisations, so on
a machine with few cores each call waits for the other pool's spinning threads. With idle
threads asleep at once, a fit of 4 000 samples and 60 inducing points took 0.20 s instead of
0.75 s on two cores (25 000 and 400: 14.0 s instead of 19.0 s; docs/sgpr.md). OpenBLAS reads
the variable when it loads, so it applies where this package is imported before numpy: the
command line, the test suite (``-p fmu_greybox`` in ``pyproject.toml``) and the processes they
start; a program that imports numpy first sets the variable itself (as
``benchmarks/bench_sgpr.py`` does) or in its environment.
"""

from __future__ import annotations

import importlib
import os
from typing import Any

os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "1")

__version__ = "0.1.0"

#: Public name -> module defining it.
_API = {
    # recordings
    "Recording": "fmu_greybox.data.recording",
    "load_recording": "fmu_greybox.data.recording",
    "save_recording": "fmu_greybox.data.recording",
    # the white-box FMU
    "open_fmu": "fmu_greybox.fmi.archive",
    "reference_fmus": "fmu_greybox.fmi.builtin",
    "simulate_recording": "fmu_greybox.model.simulate",
    # synthetic recordings of the reference actuator
    "SynthRequest": "fmu_greybox.synth.actuator",
    "FlightTestProfile": "fmu_greybox.synth.actuator",
    "synthesise": "fmu_greybox.synth.actuator",
    # the project
    "ProjectConfig": "fmu_greybox.project.config",
    "load_config": "fmu_greybox.project.config",
    "parse_config": "fmu_greybox.project.config",
    # the grey-box
    "GreyBoxChain": "fmu_greybox.model.chain",
    "GreyBoxModel": "fmu_greybox.model.store",
    "load_model": "fmu_greybox.model.store",
    "save_model": "fmu_greybox.model.store",
    "SparseGPR": "fmu_greybox.gp",
    # the workflow
    "train_model": "fmu_greybox.workflow.train",
    "validate_model": "fmu_greybox.workflow.validate",
    "validate_recordings": "fmu_greybox.workflow.validate",
    "run_master": "fmu_greybox.workflow.master",
    # diagnosis
    "Diagnosis": "fmu_greybox.diagnosis",
    # campaigns on a Dask cluster
    "run_campaign": "fmu_greybox.campaign.run",
    "DaskSimulations": "fmu_greybox.campaign.cluster",
    # export and the bench
    "export_greybox": "fmu_greybox.export.fmu",
    "make_bench": "fmu_greybox.export.ssp",
    "run_bench": "fmu_greybox.export.ssp",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str) -> Any:
    """Import a public name from its module on first use (PEP 562)."""
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'fmu_greybox' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
