"""The platforms a binary is compiled for: this machine, or win64 cross-compiled with mingw-w64.

One place knows the FMI 2.0 binary folder, the shared-library extension, the compiler and the
flags of each; every build compiles for one of them through
:func:`fmu_greybox.fmi.compiler.compile_library`.
"""

from __future__ import annotations

import os
import platform
import shutil
import sys
from dataclasses import dataclass

from fmu_greybox.errors import FmuBuildError


@dataclass(frozen=True)
class BinaryPlatform:
    """Where and how a shared library for one FMI 2.0 platform is built.

    Attributes
    ----------
    folder : str
        The FMI 2.0 folder under ``binaries/``, e.g. ``"win64"``.
    extension : str
        The shared library's extension, e.g. ``".dll"``.
    compiler : str
        The C compiler's command, e.g. ``"x86_64-w64-mingw32-gcc"``; empty for this machine's
        (``$CC`` or gcc, :func:`c_compiler`).
    flags : tuple of str
        Options beyond the sources' own: position-independent code on Unix; on Windows the
        compiler's runtime linked in, so that the DLL needs none of mingw-w64's DLLs.
    package : str
        The Debian package that installs the compiler (for the message when it is missing).
    """

    folder: str
    extension: str
    compiler: str
    flags: tuple[str, ...]
    package: str = ""

    @property
    def windows(self) -> bool:
        """Whether the binary is a Windows DLL."""
        return self.folder.startswith("win")


#: Windows on x86-64, cross-compiled with Debian's mingw-w64.
WIN64 = BinaryPlatform(
    "win64", ".dll", "x86_64-w64-mingw32-gcc", ("-static-libgcc",), "gcc-mingw-w64-x86-64"
)


def host_platform() -> BinaryPlatform:
    """This machine's platform (its FMI 2.0 folder and extension, ``$CC`` or gcc).

    Raises
    ------
    FmuBuildError
        On a platform FMI 2.0 has no binary folder for.
    """
    folder, extension = fmi2_platform()
    return BinaryPlatform(folder, extension, "", () if folder.startswith("win") else ("-fPIC",))


def platform_named(name: str) -> BinaryPlatform:
    """``"host"`` (this machine) or ``"win64"``.

    Raises
    ------
    FmuBuildError
        For another name.
    """
    if name == "host":
        return host_platform()
    if name == WIN64.folder:
        return WIN64
    raise FmuBuildError(f"no build platform {name!r}; choose host or {WIN64.folder}")


def compiler_of(platform: BinaryPlatform) -> str:
    """The full path of the platform's C compiler.

    Raises
    ------
    FmuBuildError
        If it is not installed; the message names the Debian package.
    """
    if not platform.compiler:
        return c_compiler()
    found = shutil.which(platform.compiler)
    if not found:
        raise FmuBuildError(
            f"the {platform.folder} cross-compiler {platform.compiler} is not installed: "
            f"apt-get install {platform.package}"
        )
    return found


def fmi2_platform() -> tuple[str, str]:
    """FMI 2.0 platform folder and shared-library extension of this machine.

    Returns
    -------
    tuple of str
        E.g. ``("linux64", ".so")``.

    Raises
    ------
    FmuBuildError
        On a platform FMI 2.0 has no binary folder for (e.g. Linux on ARM).
    """
    machine = platform.machine().lower()
    bits = 64 if sys.maxsize > 2**32 else 32
    intel = machine in {"x86_64", "amd64", "i386", "i686", "x86"}
    if sys.platform.startswith("linux") and intel:
        return f"linux{bits}", ".so"
    if sys.platform == "darwin":
        return "darwin64", ".dylib"
    if sys.platform.startswith("win") and intel:
        return f"win{bits}", ".dll"
    raise FmuBuildError(
        f"FMI 2.0 defines no binary folder for {sys.platform} on {machine}; "
        "build on linux64, win64 or darwin64."
    )


def c_compiler() -> str:
    """The C compiler: ``$CC`` or gcc.

    Raises
    ------
    FmuBuildError
        If it is not found.
    """
    compiler = os.environ.get("CC", "gcc")
    found = shutil.which(compiler)
    if not found:
        raise FmuBuildError(f"C compiler {compiler!r} not found: install gcc or set CC.")
    return found
