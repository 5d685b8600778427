"""The one place that compiles C: the options of each body of C code, the platform's compiler
and options, the shared library's name.

Every C build of the package goes through :func:`compile_library`: the reference FMUs
(:mod:`fmu_greybox.fmi.build`), the native grey-box FMU and its rebuild from ``sources/``
(:mod:`fmu_greybox.export.native`), the native simulation runner
(:mod:`fmu_greybox.model.native_run`) and the model-exchange integration loop
(:mod:`fmu_greybox.fmi.integrator`), the last two cached on first use and loaded by
:func:`load_cached_library`; setup.py compiles the Python extension with the same
core options (``native/cflags.txt``). The platforms themselves (folders, extensions,
compilers) are :mod:`fmu_greybox.fmi.platforms`.
"""

from __future__ import annotations

import ctypes
import dataclasses
import os
import subprocess
import tempfile
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from fmu_greybox.errors import FmuBuildError
from fmu_greybox.fmi.platforms import BinaryPlatform, compiler_of, host_platform

#: The package's C sources.
NATIVE_DIR = Path(__file__).resolve().parents[1] / "native"

#: Options of the reference FMUs' framework: IEEE arithmetic (no ``-ffast-math``, no
#: floating-point contraction), so that a model steps the same numbers on every build.
FRAMEWORK_FLAGS = (
    "-std=c99",
    "-O2",
    "-funroll-loops",
    "-fvisibility=hidden",
    "-ffp-contract=off",
    "-Wall",
    "-Wextra",
)
#: Options of the grey-box's C beyond the core's (``native/cflags.txt``): only the FMI
#: functions are exported, and every warning is shown.
NATIVE_EXTRA_FLAGS = ("-fvisibility=hidden", "-Wall", "-Wextra")
#: The header a build generates for the FMI 3.0 face (:func:`shell_config`).
SHELL_CONFIG = "fmi_shell_config.h"
#: Libraries a Windows DLL does without (``native/dynlib.h`` loads with kernel32 there).
POSIX_LIBRARIES = ("dl",)
#: Set to ``0`` to load no cached library (:func:`load_cached_library`): the diagnosis's
#: simulations and the model-exchange integration loop then run in Python, the reference the C
#: is tested against.
DISABLE_VARIABLE = "FMU_GREYBOX_NATIVE_RUN"


def core_flags() -> tuple[str, ...]:
    """The chain core's options (``native/cflags.txt``, which setup.py reads for the Python
    extension: both runtimes step the chain with the same machine code)."""
    return tuple((NATIVE_DIR / "cflags.txt").read_text(encoding="ascii").split())


def native_flags() -> tuple[str, ...]:
    """The options of every binary made of ``native/`` sources (grey-box FMU, runners)."""
    return (*core_flags(), *NATIVE_EXTRA_FLAGS)


@dataclass(frozen=True)
class CBuild:
    """What one shared library is compiled from.

    Attributes
    ----------
    what : str
        Its name in messages, e.g. ``"the native grey-box"``.
    sources : tuple of Path
        The C files, in order.
    flags : tuple of str
        The sources' options (:data:`FRAMEWORK_FLAGS` or :func:`native_flags`); the
        platform adds its own (``-fPIC``; ``-static-libgcc`` on win64) and ``-shared``.
    include_dirs : tuple of Path
    defines : tuple of str
        ``NAME`` or ``NAME=VALUE``.
    libraries : tuple of str
        Linked as ``-l<name>``; :data:`POSIX_LIBRARIES` are left out on Windows.
    shared : bool
        A shared library (else a program: on Windows linked statically, so that it needs
        none of mingw-w64's DLLs).
    """

    what: str
    sources: tuple[Path, ...]
    flags: tuple[str, ...]
    include_dirs: tuple[Path, ...] = ()
    defines: tuple[str, ...] = ()
    libraries: tuple[str, ...] = field(default=("m",))
    shared: bool = True

    def command(self, library: Path, target: BinaryPlatform | None = None) -> list[str]:
        """The compiler's command line for ``target`` (this machine's when ``None``), writing
        ``library`` (or the program).

        Raises
        ------
        FmuBuildError
            The target's compiler is not installed (the message names its package).
        """
        target = target or host_platform()
        libraries = [x for x in self.libraries if not (target.windows and x in POSIX_LIBRARIES)]
        if self.shared:
            linking = ["-shared", *target.flags]
        else:
            linking = ["-static"] if target.windows else []
        command = [compiler_of(target), *self.flags, *linking]
        command += [f"-I{folder}" for folder in self.include_dirs]
        command += [f"-D{define}" for define in self.defines]
        command += [str(source) for source in self.sources]
        return [*command, "-o", str(library), *(f"-l{x}" for x in libraries)]


def library_name(identifier: str, target: BinaryPlatform | None = None) -> str:
    """The shared library's file name, e.g. ``"HydraulicActuator.so"``."""
    return identifier + (target or host_platform()).extension


def compile_library(build: CBuild, library: Path, target: BinaryPlatform | None = None) -> None:
    """Compile ``build`` into the shared library (or program) ``library``, its folder made if
    missing.

    Compiler messages of a successful build are passed on as a warning.

    Raises
    ------
    FmuBuildError
        The compiler is missing or fails; the message holds its command and output.
    """
    command = build.command(library, target)
    library.parent.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    output = (done.stdout + done.stderr).strip()
    if done.returncode != 0:
        raise FmuBuildError(
            f"compiling {build.what} failed (exit {done.returncode}):\n"
            f"{' '.join(command)}\n{output}"
        )
    if output:
        warnings.warn(f"compiler messages for {build.what}:\n{output}", stacklevel=3)


def compile_cached(
    build: CBuild,
    library: Path,
    generated: dict[str, str] | None = None,
    target: BinaryPlatform | None = None,
) -> None:
    """Compile ``build`` into ``library`` of a cache, atomically (concurrent builders do not
    clash): in a temporary folder beside it, renamed into place once complete.

    Parameters
    ----------
    build : CBuild
    library : Path
    generated : dict of str to str, optional
        Headers written into the temporary folder first (name to text), which is searched
        for includes before ``build.include_dirs``.
    target : BinaryPlatform, optional
        As for :func:`compile_library`.

    Raises
    ------
    FmuBuildError
        As :func:`compile_library`.
    """
    library.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=library.parent) as tmp:
        for name, text in (generated or {}).items():
            (Path(tmp) / name).write_text(text, encoding="ascii")
        built = Path(tmp) / library.name
        folders = (Path(tmp), *build.include_dirs)
        compile_library(dataclasses.replace(build, include_dirs=folders), built, target)
        os.replace(built, library)


def load_cached_library(
    build: CBuild, library: Path, instead: str, generated: dict[str, str] | None = None
) -> ctypes.CDLL | None:
    """The shared library ``library`` of a cache, compiled from ``build`` on first use
    (:func:`compile_cached`), loaded.

    Parameters
    ----------
    build : CBuild
    library : Path
        In a folder keyed by a digest of what it is compiled from: an existing file is loaded
        as it is.
    instead : str
        What the caller does without the library, the warning's first words, e.g.
        ``"simulations step in Python (slower)"``.
    generated : dict of str to str, optional
        Headers written for the build (:func:`compile_cached`).

    Returns
    -------
    ctypes.CDLL or None
        ``None`` where :data:`DISABLE_VARIABLE` is ``0``, or where the library cannot be built
        or loaded: then with a warning, ``"<instead>: <why>"``, to the caller's caller.
    """
    if os.environ.get(DISABLE_VARIABLE, "1") == "0":
        return None
    try:
        if not library.exists():
            compile_cached(build, library, generated)
        return ctypes.CDLL(str(library))
    except (FmuBuildError, OSError) as exc:
        warnings.warn(f"{instead}: {exc}", stacklevel=3)
        return None


def shell_config(identifier: str, time_reference: int) -> str:
    """``fmi_shell_config.h``: what the FMI 3.0 face (``native/fmi3_shell.c``) needs of the
    core it wraps, its identifier and the value reference of ``time``."""
    return (
        "/* Generated by fmu-greybox: the identity of the core behind the FMI 3.0 face. */\n"
        "#ifndef FMI_SHELL_CONFIG_H\n#define FMI_SHELL_CONFIG_H\n"
        f'#define FMI_SHELL_IDENTIFIER "{identifier}"\n'
        f"#define FMI_SHELL_TIME_VR {time_reference}\n#endif\n"
    )
