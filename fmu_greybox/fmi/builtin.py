"""The built-in FMUs, built from ``fmu_sources/`` on first use and cached.

``builtin:HydraulicActuator``, ``builtin:HydraulicActuatorTruth``,
``builtin:ElectroMechanicalPositioner`` and ``builtin:ElectroMechanicalPositionerTruth`` name
them wherever an FMU path is accepted. The cache folder is keyed by a hash of the C sources and
the builder, so an edit of either rebuilds; set ``FMU_GREYBOX_CACHE`` to move it.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from fmu_greybox.errors import FmuArchiveError
from fmu_greybox.fmi.kinds import FMI2_CS, MODEL_EXCHANGE, FmuKind
from fmu_greybox.fmi.platforms import BinaryPlatform
from fmu_greybox.resources import PREFIX, bench_config, sources_root

#: The reference actuator's models (white-box, truth).
REFERENCE_MODELS = ("HydraulicActuator", "HydraulicActuatorTruth")

#: Every built-in model -> its folder under ``fmu_sources/`` (one folder builds a white-box and
#: its truth model).
BUILTIN_MODELS: dict[str, str] = {
    "HydraulicActuator": "HydraulicActuator",
    "HydraulicActuatorTruth": "HydraulicActuator",
    "ElectroMechanicalPositioner": "ElectroMechanicalPositioner",
    "ElectroMechanicalPositionerTruth": "ElectroMechanicalPositioner",
}


def reference_project() -> Path:
    """The reference actuator's project file, ``bench_configs/hydraulic_actuator.toml``."""
    return bench_config("hydraulic_actuator.toml")


def cache_dir() -> Path:
    """Folder holding the built FMUs for the current sources."""
    base = Path(os.environ.get("FMU_GREYBOX_CACHE", Path.home() / ".cache" / "fmu-greybox"))
    return base / "fmus" / sources_digest()[:16]


def sources_digest() -> str:
    """SHA-256 over the C sources (the shell shared with the native folder too), variable
    tables and the builder."""
    from fmu_greybox.fmi import build as fmu_build

    digest = hashlib.sha256()
    root = sources_root()
    files = sorted(p for p in root.rglob("*") if p.is_file() and p.suffix != ".csv")
    builder = Path(fmu_build.__file__)
    builders = [
        *fmu_build.GENERATORS,
        *(builder.with_name(n) for n in ("platforms.py", "compiler.py")),
    ]
    for path in [*files, *fmu_build.SHARED_SOURCES, fmu_build.FMI3_SHELL, *builders]:
        digest.update(str(path.relative_to(path.parents[1])).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def reference_fmus() -> dict[str, Path]:
    """Paths of the reference actuator FMUs, building them once if needed.

    Returns
    -------
    dict[str, Path]
        Model identifier -> ``.fmu`` path.
    """
    return model_fmus(BUILTIN_MODELS[REFERENCE_MODELS[0]])


def model_fmus(
    model_folder: str, kind: FmuKind = FMI2_CS, target: BinaryPlatform | None = None
) -> dict[str, Path]:
    """Paths of the built-in FMUs of one model folder, building them once if needed.

    Parameters
    ----------
    model_folder : str
        A folder named in :data:`BUILTIN_MODELS`, e.g. ``"ElectroMechanicalPositioner"``.
    kind : FmuKind
        Their kind; other kinds than FMI 2.0 co-simulation (the built-in names) are cached
        in a sub-folder named after the FMI version, e.g. ``fmi3.0/``, and the interface
        when model exchange, e.g. ``fmi2.0-me/``.
    target : BinaryPlatform or None
        The platform of their binaries, this machine's when ``None``; another is cached in a
        sub-folder named after it, e.g. ``win64/``.

    Returns
    -------
    dict[str, Path]
        Model identifier -> ``.fmu`` path, for the white-box and its truth model.
    """
    from fmu_greybox.fmi.build import build_model_pair

    me = "-me" if kind.interface == MODEL_EXCHANGE else ""
    folder = cache_dir() if kind == FMI2_CS else cache_dir() / f"fmi{kind.fmi_version}{me}"
    folder = folder / target.folder if target is not None else folder
    names = [name for name, source in BUILTIN_MODELS.items() if source == model_folder]
    paths = {name: folder / f"{name}.fmu" for name in names}
    if not all(p.is_file() for p in paths.values()):
        folder.mkdir(parents=True, exist_ok=True)
        paths = build_model_pair(sources_root() / model_folder, folder, kind, target)
    return paths


def resolve_fmu(spec: str | Path) -> Path:
    """Turn ``builtin:NAME`` or a path into the path of an existing ``.fmu`` file.

    Raises
    ------
    FmuArchiveError
        For an unknown built-in name or a missing file.
    """
    text = str(spec)
    if text.startswith(PREFIX):
        name = text[len(PREFIX) :]
        if name not in BUILTIN_MODELS:
            raise FmuArchiveError(
                f"unknown built-in FMU {text!r}; choose one of "
                + ", ".join(PREFIX + n for n in BUILTIN_MODELS)
            )
        return model_fmus(BUILTIN_MODELS[name])[name]
    path = Path(text)
    if not path.is_file():
        raise FmuArchiveError(
            f"{path}: no such FMU file; give a path or one of "
            + ", ".join(PREFIX + n for n in BUILTIN_MODELS)
        )
    return path
