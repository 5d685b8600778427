"""One test body for both faces of the native grey-box (FMI 2.0 and FMI 3.0).

fmpy's FMI 3.0 slave is given the FMI 2.0 names the tests call (:class:`FMU3AsFMU2`), and the
FMI calls a test expects in a message are named for the FMU's version (:func:`call_name`).
"""

from __future__ import annotations

from pathlib import Path

from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave

#: FMI 2.0 calls and their FMI 3.0 counterparts, as the tests name them.
FMI3_CALLS = {
    "fmi2Instantiate": "fmi3InstantiateCoSimulation",
    "fmi2SetReal": "fmi3SetFloat64",
    "fmi2ExitInitializationMode": "fmi3ExitInitializationMode",
    "fmi2DoStep": "fmi3DoStep",
    "fmi2DeSerializeFMUstate": "fmi3DeserializeFMUState",
    "fmi2SetFMUstate": "fmi3SetFMUState",
}


class FMU3AsFMU2(FMU3Slave):
    """fmpy's FMU3Slave answering the FMI 2.0 calls the tests make (start time given to
    ``setupExperiment``, taken on entering initialisation mode as FMI 3.0 wants)."""

    start_time = 0.0

    def setupExperiment(self, startTime: float = 0.0) -> None:  # noqa: N802
        self.start_time = startTime

    def enterInitializationMode(self, **kwargs) -> None:  # noqa: N802
        super().enterInitializationMode(startTime=self.start_time, **kwargs)

    def getReal(self, vr):  # noqa: N802
        return self.getFloat64(vr)

    def setReal(self, vr, values) -> None:  # noqa: N802
        self.setFloat64(vr, values)

    def getFMUstate(self):  # noqa: N802
        return self.getFMUState()

    def setFMUstate(self, state) -> None:  # noqa: N802
        self.setFMUState(state)

    def freeFMUstate(self, state) -> None:  # noqa: N802
        self.freeFMUState(state)

    def serializeFMUstate(self, state) -> bytes:  # noqa: N802
        return self.serializeFMUState(state)

    def deSerializeFMUstate(self, serialized: bytes):  # noqa: N802
        return self.deserializeFMUState(serialized)


def fmi_prefix(fmu: Path | str) -> str:
    """``"fmi2"`` or ``"fmi3"``: the prefix of the FMU's calls and statuses."""
    return "fmi3" if read_model_description(str(fmu)).fmiVersion.startswith("3") else "fmi2"


def slave_class(fmu: Path | str) -> type:
    """fmpy's co-simulation slave for the FMU's version, under the FMI 2.0 names."""
    return FMU3AsFMU2 if fmi_prefix(fmu) == "fmi3" else FMU2Slave


def call_name(fmu: Path | str, fmi2_call: str) -> str:
    """The FMU's name for an FMI 2.0 call (itself for an FMI 2.0 FMU)."""
    return FMI3_CALLS[fmi2_call] if fmi_prefix(fmu) == "fmi3" else fmi2_call
