"""A recording played back as an FMU: one Real output per recorded signal.

:class:`PlaybackSlave` is the pythonfmu slave of the playback FMU that
:func:`fmu_greybox.export.ssp.build_playback_fmu` writes, to drive a grey-box (and its white-box)
on an
SSP bench from a recording. Its resources hold ``recording.csv`` (time and signals, 17
significant digits) and ``fmu_runtime.json`` (names, units, the CSV's SHA-256).

Timing follows :mod:`fmu_greybox.model.simulate`: row ``k`` holds the input that acts over
``[t_k, t_k+1)``, so the outputs at time ``t`` are those of the last row with ``t_k <= t``
(sample and hold; the first row before the recording, the last one after it). After
``fmi2DoStep(t, h)`` the outputs are those at ``t + h``, which a master passes on to the inputs
of the next step.
"""

from __future__ import annotations

import functools
import math
from operator import getitem
from pathlib import Path
from typing import Any

import numpy as np
from pythonfmu import DefaultExperiment, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability
from pythonfmu import Real as RealVariable

from fmu_greybox.errors import ModelFormatError
from fmu_greybox.export.runtime import attach_logger, guarded, refuse_step, report
from fmu_greybox.export.slave import check_python, read_settings
from fmu_greybox.model.store import file_sha256

#: The recording in the FMU's resources.
RECORDING_FILE = "recording.csv"
#: Fraction of the sample time by which a communication point may miss a sample instant.
TIME_TOLERANCE = 1e-6


class PlaybackSlave(Fmi2Slave):
    """pythonfmu slave of a recording-playback FMU (see the module docstring).

    Raises
    ------
    ModelFormatError
        ``recording.csv`` is missing, unreadable or differs from the hash recorded at build.
    """

    #: Why the instance stopped working (see :func:`fmu_greybox.export.runtime.guarded`).
    failure = ""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        attach_logger(self, kwargs)
        try:
            self._instantiate(Path(kwargs["resources"]))
        except Exception as exc:
            report(self, "fmi2Instantiate", f"{type(exc).__name__}: {exc}")
            raise

    def _instantiate(self, resources: Path) -> None:
        settings = read_settings(resources)
        check_python(settings)
        path = resources / RECORDING_FILE
        if not path.is_file() or file_sha256(path) != settings["recording_sha256"]:
            raise ModelFormatError(
                f"{path} is missing or differs from the recording the FMU was built with; "
                "build the playback FMU again"
            )
        table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
        self.modelName = settings["model_identifier"]
        self.description = settings["description"]
        self.author = settings["author"]
        self.version = settings["version"]
        self._times = table[:, 0]
        self._rows = table[:, 1:].tolist()
        dt = float((self._times[-1] - self._times[0]) / (len(self._times) - 1))
        self._tolerance = TIME_TOLERANCE * dt
        self.default_experiment = DefaultExperiment(
            start_time=float(self._times[0]), stop_time=float(self._times[-1]), step_size=dt
        )
        self._reals: list[float] = list(self._rows[0])
        self._time = float(self._times[0])
        for i, (name, unit) in enumerate(zip(settings["signals"], settings["units"], strict=True)):
            text = f"Recorded {name}" + (f" [{unit}]" if unit else "") + " (sample and hold)"
            self.register_variable(
                RealVariable(
                    name,
                    causality=Fmi2Causality.output,
                    variability=Fmi2Variability.continuous,
                    initial=Fmi2Initial.calculated,
                    description=text,
                    getter=functools.partial(getitem, self._reals, i),
                ),
                nested=False,
            )

    def _show(self, time: float) -> None:
        """Publish the row acting at ``time``."""
        k = int(np.searchsorted(self._times, time + self._tolerance, side="right")) - 1
        self._reals[:] = self._rows[min(max(k, 0), len(self._rows) - 1)]
        self._time = time

    def setup_experiment(
        self, start_time: float, stop_time: float | None = None, tolerance: float | None = None
    ) -> None:
        self._show(float(start_time))

    @guarded("fmi2DoStep", False)
    def do_step(self, current_time: float, step_size: float) -> bool:
        if self.failure:
            return refuse_step(self, current_time)
        self._show(current_time + step_size)
        return True

    @guarded("fmi2GetReal", lambda vrs: [math.nan] * len(vrs))
    def get_real(self, vrs: list[int]) -> list[float]:
        reals = self._reals
        return [reals[vr] for vr in vrs]

    @guarded("fmi2SetReal")
    def set_real(self, vrs: list[int], values: list[float]) -> None:
        raise ValueError("a playback FMU has no Real inputs or parameters to set")

    def _get_fmu_state(self) -> dict[str, Any]:
        return {"time": self._time}

    @guarded("fmi2SetFMUstate")
    def _set_fmu_state(self, saved: dict[str, Any]) -> None:
        self._show(float(saved["time"]))
