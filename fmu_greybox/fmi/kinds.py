"""The kinds of FMU fmu-greybox accepts as a white-box, and where each keeps its binary.

The one place that knows FMI versions, interfaces and binary folders: the archive check
(:func:`fmu_greybox.fmi.archive.open_fmu`) asks :func:`fmu_kind` whether an FMU is accepted,
the running instance (:func:`fmu_greybox.fmi.instance.fmu_instance`) picks its FMI calls by
kind, and the C paths (the native simulation runner and the native grey-box export, which
``dlopen`` an FMI 2.0 co-simulation binary) ask :attr:`FmuKind.native`.

Accepted today (``docs/config.md``, "White-box FMUs accepted"): FMI 2.0 co-simulation
(``binaries/linux64``; stepped by fmpy or the C runner), FMI 3.0 co-simulation
(``binaries/x86_64-linux``; stepped by fmpy, refused by the C paths), and FMI 2.0 and FMI 3.0
model exchange (stepped by an integrator in Python, :mod:`fmu_greybox.fmi.integrator`; refused
by the C paths). An FMU offering both interfaces is run as co-simulation.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from fmpy import platform as fmi2_folder
from fmpy import platform_tuple as fmi3_folder
from fmpy import sharedLibraryExtension

from fmu_greybox.errors import FmuArchiveError

if TYPE_CHECKING:
    from fmu_greybox.fmi.platforms import BinaryPlatform

#: The FMI 3.0 platform tuple of a win64 binary.
WINDOWS_TUPLE = "x86_64-windows"
CO_SIMULATION = "co-simulation"
MODEL_EXCHANGE = "model exchange"


@dataclass(frozen=True)
class FmuKind:
    """An FMI version and interface.

    Attributes
    ----------
    fmi_version : str
        ``"2.0"`` or ``"3.0"``.
    interface : str
        :data:`CO_SIMULATION` or :data:`MODEL_EXCHANGE`.
    remote : str
        The platform of a binary run through fmpy's remoting (``"win64"``: over Wine,
        :mod:`fmu_greybox.fmi.wine`), or ``""`` for a binary of this machine.
    """

    fmi_version: str
    interface: str
    remote: str = ""

    @property
    def label(self) -> str:
        """E.g. ``"FMI 3.0 co-simulation"``, ``"FMI 2.0 co-simulation (win64 through Wine)"``."""
        through = f" ({self.remote} through Wine)" if self.remote else ""
        return f"FMI {self.fmi_version} {self.interface}{through}"

    @property
    def binary_folder(self) -> str:
        """Folder under ``binaries/`` holding this machine's library, e.g. ``"linux64"``."""
        return fmi2_folder if self.fmi_version == "2.0" else fmi3_folder

    def folder_of(self, target: BinaryPlatform) -> str:
        """Folder under ``binaries/`` of a binary built for ``target``: its FMI 2.0 folder
        (``"win64"``), or for FMI 3.0 its platform tuple (``"x86_64-windows"``)."""
        if self.fmi_version == "2.0":
            return target.folder
        return WINDOWS_TUPLE if target.windows else fmi3_folder

    @property
    def native(self) -> bool:
        """Whether the C paths (the native simulation runner, the native grey-box export) can
        load it: they call the FMI 2.0 co-simulation functions."""
        return self == FMI2_CS


FMI2_CS = FmuKind("2.0", CO_SIMULATION)
FMI3_CS = FmuKind("3.0", CO_SIMULATION)
FMI2_ME = FmuKind("2.0", MODEL_EXCHANGE)
FMI3_ME = FmuKind("3.0", MODEL_EXCHANGE)
#: The kinds :func:`fmu_kind` accepts.
ACCEPTED = (FMI2_CS, FMI3_CS, FMI2_ME, FMI3_ME)


def fmu_kind(path: Path, description: object) -> FmuKind:
    """The kind of an FMU from its parsed model description, when accepted.

    Parameters
    ----------
    path : Path
        The ``.fmu`` file (for messages).
    description : fmpy.model_description.ModelDescription

    Raises
    ------
    FmuArchiveError
        For an FMI version or interface fmu-greybox does not run; the message says what is
        accepted.
    """
    version = "3.0" if str(description.fmiVersion).startswith("3.") else description.fmiVersion
    labels = [k.label for k in ACCEPTED]
    accepted = ", ".join(labels[:-1]) + " or " + labels[-1]
    if version not in {k.fmi_version for k in ACCEPTED}:
        raise FmuArchiveError(
            f"{path}: FMI version {description.fmiVersion}; fmu-greybox runs {accepted} FMUs. "
            "Export the model as one of these"
        )
    if description.coSimulation is not None:  # preferred: the FMU's own solver
        return FmuKind(version, CO_SIMULATION)
    if description.modelExchange is not None:
        indicators = int(description.numberOfEventIndicators or 0)
        if indicators:
            raise FmuArchiveError(
                f"{path}: an FMI {version} model-exchange FMU with {indicators} event "
                "indicators (state events), which fmu-greybox's integrator does not locate yet; "
                "re-export the model as co-simulation (with its own solver)"
            )
        return FmuKind(version, MODEL_EXCHANGE)
    raise FmuArchiveError(
        f"{path}: an FMI {version} FMU with neither a co-simulation nor a model-exchange "
        f"interface; fmu-greybox runs {accepted} FMUs. Re-export the model with one of them"
    )


def interface(description: object, kind: FmuKind) -> object:
    """The model description's element of ``kind``'s interface (fmpy's ``CoSimulation`` or
    ``ModelExchange``): its model identifier and capability flags."""
    if kind.interface == CO_SIMULATION:
        return description.coSimulation
    return description.modelExchange


def one_instance_per_process(description: object, kind: FmuKind) -> bool:
    """Whether the FMU says it can be instantiated only once per process (then no two of its
    runs may overlap in one process's threads)."""
    flags = interface(description, kind)
    return bool(getattr(flags, "canBeInstantiatedOnlyOncePerProcess", False))


def binary_path(unzip_dir: Path, kind: FmuKind, identifier: str) -> Path:
    """Where an extracted FMU of ``kind`` keeps its shared library for this machine."""
    return unzip_dir / "binaries" / kind.binary_folder / f"{identifier}{sharedLibraryExtension}"


def require_native(
    kind: FmuKind, path: Path, what: str, mend: str, error: type[Exception] = FmuArchiveError
) -> None:
    """Refuse a white-box the C paths cannot load.

    Parameters
    ----------
    kind : FmuKind
    path : Path
        The white-box FMU (for the message).
    what : str
        What needs it, e.g. ``"the native grey-box export"``.
    mend : str
        How to go on without it, e.g. ``"export with --runtime python"``.
    error : type of Exception
        What to raise.

    Raises
    ------
    error
        If ``kind`` is not :data:`FMI2_CS`.
    """
    if not kind.native:
        raise error(
            f"{path}: {what} loads FMI 2.0 co-simulation white-boxes only, and this one is "
            f"{kind.label}; {mend}"
        )
