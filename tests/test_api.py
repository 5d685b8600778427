"""The public API: every name resolves, and docs/api.md's example runs as written."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import fmu_greybox

ROOT = Path(__file__).resolve().parents[1]


def test_every_public_name_resolves_to_its_module() -> None:
    for name in fmu_greybox.__all__[1:]:
        value = getattr(fmu_greybox, name)
        assert value.__module__.startswith("fmu_greybox."), name


def test_importing_the_package_imports_no_workflow_module() -> None:
    """``import fmu_greybox`` stays cheap (the exported FMU's runtime imports it first)."""
    code = "import sys, fmu_greybox; print(sorted(m for m in sys.modules if 'fmu_greybox.' in m))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert loaded.stdout.strip() == "[]"


def test_the_api_page_example_runs(tmp_path: Path) -> None:
    page = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    (example,) = re.findall(r"```python\n(.*?)```", page, flags=re.S)
    script = tmp_path / "example.py"
    script.write_text(example, encoding="utf-8")
    run = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, cwd=tmp_path, timeout=900
    )
    assert run.returncode == 0, run.stderr[-3000:]
    lines = run.stdout.splitlines()
    rmse = {
        m.group(1): (float(m.group(2)), float(m.group(3)))
        for m in (re.match(r"(\w+): white-box RMSE (\S+), grey-box RMSE (\S+)", x) for x in lines)
        if m
    }
    assert set(rmse) == {"EHV", "RAM", "ITFV"}
    # a 5 % gain error is what the correctors learn: the valve stage improves
    assert rmse["EHV"][1] < 0.5 * rmse["EHV"][0]
    assert lines[-1] == "exported greybox.fmu"


def test_importing_the_package_lets_idle_blas_threads_sleep_unless_the_user_chose() -> None:
    code = "import os, fmu_greybox; print(os.environ['OPENBLAS_THREAD_TIMEOUT'])"
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_THREAD_TIMEOUT"}
    default = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    chosen = subprocess.run(
        [sys.executable, "-c", code],
        env={**env, "OPENBLAS_THREAD_TIMEOUT": "7"},
        capture_output=True,
        text=True,
    )
    assert (default.stdout.strip(), chosen.stdout.strip()) == ("1", "7")
