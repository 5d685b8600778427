"""The data the package carries: the C sources of the built-in FMUs and the bench configuration.

Both live at the top of the repository (``fmu_sources/``, ``bench_configs/``), are reached from
the package through ``fmu_greybox/_data/`` (links in a checkout, so an editable install sees the
working tree) and are copied into the wheel as package data, so an installed package never
reaches outside itself. Wherever a path is taken, ``builtin:NAME`` names a packaged item: an FMU
(:mod:`fmu_greybox.fmi.builtin`) or a project file of ``bench_configs/`` by its stem
(:func:`builtin_projects`, e.g. ``builtin:hydraulic_actuator``).
"""

from __future__ import annotations

import os
from pathlib import Path

from fmu_greybox.errors import ConfigError, FmuBuildError

#: Folder of the package data inside the package.
DATA_DIR = Path(__file__).resolve().parent / "_data"
#: What starts the name of a packaged FMU or project where a path is taken.
PREFIX = "builtin:"


def data_path(*parts: str, env: str | None = None) -> Path:
    """A path inside the package data, or the one an environment variable names.

    Parameters
    ----------
    *parts : str
        Path components below ``_data/`` (``"fmu_sources"``, ``"bench_configs", "x.toml"``).
    env : str, optional
        Environment variable that, when set, overrides the packaged path.

    Returns
    -------
    Path
        The path (not checked for existence).
    """
    if env and os.environ.get(env):
        return Path(os.environ[env])
    return DATA_DIR.joinpath(*parts)


def sources_root() -> Path:
    """The packaged ``fmu_sources/`` folder.

    Raises
    ------
    FmuBuildError
        If the folder holds no ``framework/`` (a package built without its data).
    """
    root = data_path("fmu_sources")
    if not (root / "framework").is_dir():
        raise FmuBuildError(
            f"C sources of the built-in FMUs not found at {root}; reinstall fmu-greybox (its "
            "wheel carries them as package data)"
        )
    return root


def bench_config(name: str) -> Path:
    """A file of the packaged ``bench_configs/`` folder.

    Parameters
    ----------
    name : str
        File name, e.g. ``"hydraulic_actuator.toml"``.

    Raises
    ------
    ConfigError
        If the package carries no such file.
    """
    path = data_path("bench_configs", name)
    if not path.is_file():
        raise ConfigError(
            "bench configuration file not found in the package data; reinstall fmu-greybox",
            path=str(path),
        )
    return path


def builtin_projects() -> dict[str, Path]:
    """The project files the package carries, by the name that addresses them.

    Returns
    -------
    dict[str, Path]
        ``builtin:STEM`` -> file, for every ``.toml`` file of the packaged ``bench_configs/``
        (``builtin:hydraulic_actuator``, ``builtin:positioner``), sorted by name.
    """
    folder = data_path("bench_configs")
    return {PREFIX + path.stem: path for path in sorted(folder.glob("*.toml"))}


def project_path(spec: str | Path) -> Path:
    """The project file ``spec`` names: a packaged one for ``builtin:NAME``, else the path.

    Parameters
    ----------
    spec : str or Path
        ``builtin:NAME`` (see :func:`builtin_projects`) or a path (not checked for existence).

    Raises
    ------
    ConfigError
        For a ``builtin:`` name the package does not carry; the message lists those it does.
    """
    text = str(spec)
    if not text.startswith(PREFIX):
        return Path(spec)
    projects = builtin_projects()
    if text not in projects:
        raise ConfigError(
            f"no built-in project {text!r}; the built-in projects are {', '.join(projects)}",
            path=text,
        )
    return projects[text]
