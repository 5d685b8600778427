"""The data the package carries: the C sources of the built-in FMUs and the bench configuration.

Both live at the top of the repository (``fmu_sources/``, ``bench_configs/``), are reached from
the package through ``fmu_greybox/_data/`` (links in a checkout, so an editable install sees the
working tree) and are copied into the wheel as package data, so an installed package never
reaches outside itself.
"""

from __future__ import annotations

import os
from pathlib import Path

from fmu_greybox.errors import ConfigError, FmuBuildError

#: Folder of the package data inside the package.
DATA_DIR = Path(__file__).resolve().parent / "_data"


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
