"""What ran: the tool's identity for a report's traceability block.

A version number alone does not say which code ran (a checkout between releases, a patched
install). So beside it: the git commit of the checkout the package was imported from, when it
was (marked when tracked files differ from that commit), and the SHA-256 of the package's own
source files as they are on disk, which an installed wheel has as much as a checkout.
"""

from __future__ import annotations

import hashlib
import platform
import shlex
import subprocess
import sys
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path

import fmu_greybox
from fmu_greybox import __version__
from fmu_greybox.model.store import file_sha256

#: Where the package lives (its package data, ``_data/``, is hashed by what it holds: the
#: white-box sources and the project files have their own hashes).
PACKAGE = Path(fmu_greybox.__file__).resolve().parent
#: Source files hashed by :func:`package_sha256`.
SOURCE_SUFFIXES = (".py", ".c", ".h")


def package_sha256(root: Path = PACKAGE) -> str:
    """SHA-256 over the package's source files (relative path and bytes, sorted by path),
    leaving out ``_data/`` and caches."""
    digest = hashlib.sha256()
    files = sorted(
        p
        for p in root.rglob("*")
        if p.suffix in SOURCE_SUFFIXES
        and p.is_file()
        and "__pycache__" not in p.parts
        and "_data" not in p.relative_to(root).parts
    )
    for path in files:
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()


def git_commit(root: Path = PACKAGE) -> str | None:
    """The commit of the git checkout holding ``root``, with ``+ local changes`` when tracked
    files differ from it; ``None`` outside a checkout or without git."""
    try:
        head = _git(root, "rev-parse", "HEAD")
        changed = _git(root, "status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return None
    return f"{head} + local changes" if changed else head


def _git(root: Path, *args: str) -> str:
    done = subprocess.run(
        ["git", "-C", str(root), *args], capture_output=True, text=True, timeout=10, check=True
    )
    return done.stdout.strip()


def tool_rows() -> list[tuple[str, str, str]]:
    """Traceability rows ``(item, what it covers, value)`` of the tool itself."""
    rows = [("fmu-greybox", "the tool's version", __version__)]
    commit = git_commit()
    if commit is not None:
        rows.append(("commit", "the git checkout the tool ran from", commit))
    rows.append(
        (
            "package sources",
            "SHA-256 of the package's Python and C files as they ran (checkout or wheel)",
            package_sha256(),
        )
    )
    return rows


#: Packages whose versions decide what a run computed.
RUNTIME_PACKAGES = ("fmpy", "pythonfmu", "libcosimpy", "numpy", "scipy")


def environment_rows(command: str) -> list[tuple[str, str, str]]:
    """Traceability rows of where and how a run ran: the versions of
    :data:`RUNTIME_PACKAGES`, Python's, the platform, the command line and the finishing time."""
    rows = []
    for package in RUNTIME_PACKAGES:
        try:
            version = metadata.version(package)
        except metadata.PackageNotFoundError:
            version = "not installed"
        rows.append((package, "version", version))
    return [
        *rows,
        ("python", "version", platform.python_version()),
        ("platform", "operating system and machine", platform.platform()),
        ("command", "the command line", command),
        ("finished", "UTC", datetime.now(UTC).strftime("%Y-%m-%d %H:%M:%S")),
    ]


def command_line() -> str:
    """The command line that runs, as ``fmu-greybox ...``, each absolute path cut to its name,
    also as an option's ``--name=value`` (a report names no local folder)."""
    return shlex.join(["fmu-greybox", *map(_without_folder, sys.argv[1:])])


def _without_folder(arg: str) -> str:
    """An argument with an absolute path in it cut to the path's name."""
    option, sep, value = arg.partition("=") if arg.startswith("-") else ("", "", arg)
    return option + sep + (Path(value).name if Path(value).is_absolute() else value)


def project_row(path: Path) -> tuple[str, str, str]:
    """The traceability row of a project file: its name and SHA-256."""
    return (
        "project file",
        f"SHA-256 of {path.name} (stages, signals, GP settings, acceptance criteria)",
        file_sha256(path),
    )
