"""System tools the tests run (Chromium, clang, ...): found, or the test says what to install."""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest


def installed_tool(names: tuple[str, ...], package: str) -> str:
    """The path of the first of ``names`` on the PATH. Where none is: in CI (``CI`` set) the
    test fails, since the test command installs ``package`` (``scripts/test.sh``); elsewhere
    it is skipped, saying what to install."""
    for name in names:
        found = shutil.which(name)
        if found:
            return found
    if os.environ.get("CI"):
        pytest.fail(f"{names[0]} is missing: the test command installs Debian's {package!r}")
    pytest.skip(f"{names[0]} is not installed (apt-get install {package})")


#: AddressSanitizer and UndefinedBehaviorSanitizer, every finding fatal.
SANITIZE = (
    "-O1",
    "-g",
    "-fno-omit-frame-pointer",
    "-fsanitize=address,undefined",
    "-fno-sanitize-recover=all",
)


def sanitizer_environment() -> dict[str, str]:
    """This process's environment with gcc's ASan and UBSan runtimes preloaded (a Python that
    was not built with them loads an instrumented FMU only so), any finding ending the
    process."""
    runtimes = [
        subprocess.run(
            ["gcc", f"-print-file-name={name}"], capture_output=True, text=True, check=True
        ).stdout.strip()
        for name in ("libasan.so", "libubsan.so")
    ]
    return {
        **os.environ,
        "LD_PRELOAD": ":".join(runtimes),
        "ASAN_OPTIONS": "detect_leaks=0:abort_on_error=1",
        "UBSAN_OPTIONS": "halt_on_error=1:print_stacktrace=1",
    }
