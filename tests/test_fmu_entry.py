"""The entry module of fmu-greybox's Python FMUs under pythonfmu 0.7's loader.

pythonfmu's binary releases one reference to the entry module's namespace per instantiation that
it never took; :func:`fmu_greybox.export.runtime.hold_namespace` takes it back. If the namespace's
reference count ever falls below what the objects referring to it hold, the interpreter frees it
while clearing modules at exit: a segmentation fault after everything succeeded (the CI run that
"passed" with exit code 139). The check runs in a fresh interpreter, as a bench's would.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

from fmu_greybox.data.recording import Recording
from fmu_greybox.export.ssp import build_playback_fmu

PROBE = textwrap.dedent(
    """
    import gc, json, sys
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    fmu = sys.argv[1]
    md = read_model_description(fmu)
    folder = extract(fmu)
    for i in range(6):
        slave = FMU2Slave(guid=md.guid, unzipDirectory=folder, instanceName=f"i{i}",
                          modelIdentifier=md.coSimulation.modelIdentifier)
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        slave.doStep(0.0, 1e-3)
        slave.terminate()
        slave.freeInstance()
    gc.collect()
    namespace = vars(sys.modules["playback_fmu"])
    count = sys.getrefcount(namespace) - 2  # the call's argument and the name 'namespace'
    frame = sys._getframe()
    held = sum(
        sum(item is namespace for item in holder) if isinstance(holder, list) else 1
        for holder in gc.get_referrers(namespace) if holder is not frame
    )
    print(json.dumps({"count": count, "held": held}))
    """
)


def test_entry_namespace_outlives_its_holders(tmp_path: Path) -> None:
    t = np.arange(50) * 1e-3
    fmu = build_playback_fmu(
        Recording(time=t, signals={"valve_current": np.sin(t)}, units={"valve_current": "mA"}),
        tmp_path / "playback.fmu",
    )
    done = subprocess.run(
        [sys.executable, "-c", PROBE, str(fmu)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    facts = json.loads(done.stdout.strip().splitlines()[-1])
    assert facts["count"] >= facts["held"], facts
