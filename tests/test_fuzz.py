"""Fuzz targets (libFuzzer, with AddressSanitizer and UndefinedBehaviorSanitizer): a short run
with a fixed seed over the committed corpus, which holds every input a longer run found a fault
with (``fuzz/corpus/``; docs/robustness.md says how long runs went)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NATIVE = ROOT / "fmu_greybox" / "native"
CLANG = shutil.which("clang")


def build(target: str, sources: list[str], folder: Path) -> Path:
    """``fuzz/<target>.c`` with ``sources`` (of fmu_greybox/native) as a libFuzzer binary."""
    binary = folder / target
    command = [CLANG, "-g", "-O1", "-fsanitize=fuzzer,address,undefined"]
    command += ["-fno-sanitize-recover=all", f"-I{NATIVE}", str(ROOT / "fuzz" / f"{target}.c")]
    command += [str(NATIVE / s) for s in sources]
    subprocess.run([*command, "-o", str(binary)], check=True)
    return binary


@pytest.mark.skipif(CLANG is None, reason="clang is not installed (scripts/test.sh installs it)")
def test_the_data_file_reader_survives_a_short_fuzz_run(tmp_path: Path) -> None:
    """greybox.dat's reader, fed mutations of valid files (and the file of 36 bytes declaring
    50 million sections, which allocated 2.4 GB until the count was checked against the file's
    size): no crash, leak, out-of-memory or undefined behaviour in 20 000 runs."""
    binary = build("fuzz_greybox_data", ["greybox_data.c", "sha256.c"], tmp_path)
    corpus = tmp_path / "corpus"
    shutil.copytree(ROOT / "fuzz" / "corpus" / "greybox_data", corpus)
    done = subprocess.run(
        [str(binary), "-seed=1", "-runs=20000", "-rss_limit_mb=512", str(corpus)],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Done 20000 runs" in done.stderr
