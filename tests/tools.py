"""System tools the tests run (Chromium, clang, ...): found, or the test says what to install."""

from __future__ import annotations

import os
import shutil

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
