"""The built-in reference FMUs, built from ``fmu_sources/`` on first use and cached.

``builtin:HydraulicActuator`` and ``builtin:HydraulicActuatorTruth`` name them wherever an FMU
path is accepted. The cache folder is keyed by a hash of the C sources and the builder, so an
edit of either rebuilds; set ``FMU_GREYBOX_CACHE`` to move it.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from .errors import FmuArchiveError, FmuBuildError

PREFIX = "builtin:"
REFERENCE_MODELS = ("HydraulicActuator", "HydraulicActuatorTruth")


def sources_root() -> Path:
    """The ``fmu_sources/`` folder of this checkout.

    Raises
    ------
    FmuBuildError
        If the package was installed without its C sources.
    """
    root = Path(
        os.environ.get("FMU_GREYBOX_SOURCES", Path(__file__).resolve().parents[1] / "fmu_sources")
    )
    if not (root / "framework").is_dir():
        raise FmuBuildError(
            f"C sources of the built-in FMUs not found at {root}; install fmu-greybox from its "
            "repository with 'pip install -e .' or set FMU_GREYBOX_SOURCES to the fmu_sources "
            "folder"
        )
    return root


def cache_dir() -> Path:
    """Folder holding the built FMUs for the current sources."""
    base = Path(os.environ.get("FMU_GREYBOX_CACHE", Path.home() / ".cache" / "fmu-greybox"))
    return base / "fmus" / sources_digest()[:16]


def sources_digest() -> str:
    """SHA-256 over the C sources, variable tables and the builder."""
    from . import fmu_build

    digest = hashlib.sha256()
    root = sources_root()
    files = sorted(p for p in root.rglob("*") if p.is_file() and p.suffix != ".csv")
    for path in [*files, Path(fmu_build.__file__)]:
        digest.update(str(path.relative_to(path.parents[1])).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def reference_fmus() -> dict[str, Path]:
    """Paths of the built-in FMUs, building them once if needed.

    Returns
    -------
    dict[str, Path]
        Model identifier -> ``.fmu`` path.
    """
    from .fmu_build import build_reference_fmus

    folder = cache_dir()
    paths = {name: folder / f"{name}.fmu" for name in REFERENCE_MODELS}
    if not all(p.is_file() for p in paths.values()):
        folder.mkdir(parents=True, exist_ok=True)
        paths = build_reference_fmus(folder)
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
        if name not in REFERENCE_MODELS:
            raise FmuArchiveError(
                f"unknown built-in FMU {text!r}; choose one of "
                + ", ".join(PREFIX + n for n in REFERENCE_MODELS)
            )
        return reference_fmus()[name]
    path = Path(text)
    if not path.is_file():
        raise FmuArchiveError(
            f"{path}: no such FMU file; give a path or one of "
            + ", ".join(PREFIX + n for n in REFERENCE_MODELS)
        )
    return path
