"""Fuzz targets (libFuzzer, with AddressSanitizer and UndefinedBehaviorSanitizer): a short run
with a fixed seed over the committed corpus, which holds every input a longer run found a fault
with (``fuzz/corpus/``; docs/robustness.md says how long runs went)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from fmpy import extract, read_model_description
from test_export import trained
from tools import installed_tool

ROOT = Path(__file__).resolve().parents[1]
NATIVE = ROOT / "fmu_greybox" / "native"
#: The fuzzer started by a small process that forks it: Linux carries the peak resident memory
#: of the process that starts a program over into the program's own (``ru_maxrss``, which
#: libFuzzer's ``-rss_limit_mb`` reads), so a fuzzer started by a test worker that once held
#: 1.1 GB failed at its first input with "out-of-memory (used: 1069Mb; limit: 1024Mb)".
FRESH_PEAK = (
    sys.executable,
    "-c",
    "import subprocess, sys; sys.exit(subprocess.run(sys.argv[1:]).returncode)",
)


def build(
    target: str, sources: Path, files: list[str], folder: Path, flags: tuple[str, ...] = ()
) -> Path:
    """``fuzz/<target>.c`` with ``files`` of the folder ``sources`` as a libFuzzer binary."""
    binary = folder / target
    clang = installed_tool(("clang",), "clang")
    command = [clang, "-g", "-O1", "-fsanitize=fuzzer,address,undefined", *flags]
    command += ["-fno-sanitize-recover=all", f"-I{sources}", str(ROOT / "fuzz" / f"{target}.c")]
    command += [str(sources / f) for f in files]
    subprocess.run([*command, "-lm", "-ldl", "-o", str(binary)], check=True)
    return binary


def fuzz(binary: Path, corpus: str, runs: int, folder: Path, env: dict | None = None) -> str:
    """A run of ``runs`` inputs with seed 1 over a copy of ``fuzz/corpus/<corpus>``; its log.
    Any crash, leak, out-of-memory or sanitizer finding fails it."""
    copy = folder / corpus
    shutil.copytree(ROOT / "fuzz" / "corpus" / corpus, copy)
    done = subprocess.run(
        [*FRESH_PEAK, str(binary), "-seed=1", f"-runs={runs}", "-rss_limit_mb=1024", str(copy)],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=folder,
        env=env,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"Done {runs} runs" in done.stderr
    return done.stderr


def test_the_data_file_reader_survives_a_short_fuzz_run(tmp_path: Path) -> None:
    """greybox.dat's reader, fed mutations of valid files (and the file of 36 bytes declaring
    50 million sections, which allocated 2.4 GB until the count was checked against the file's
    size): no crash, leak, out-of-memory or undefined behaviour in 20 000 runs. Started after
    this test's worker held 1.2 GB, as a worker of the whole suite may have (``FRESH_PEAK``)."""
    binary = build("fuzz_greybox_data", NATIVE, ["greybox_data.c", "sha256.c"], tmp_path)
    ballast = b"\1" * (1200 * 2**20)  # written, so resident (zeroed pages would not be)
    del ballast
    fuzz(binary, "greybox_data", 20000, tmp_path)


def native_fuzzer(
    target: str, tmp_path_factory: pytest.TempPathFactory, folder: Path, *flags: str
) -> tuple[Path, dict]:
    """``fuzz/<target>.c`` linked with the shipped sources of the session's native FMU, and the
    environment of ``fuzz/fmu_harness.h`` (the unpacked FMU, its step)."""
    fmu = trained(tmp_path_factory)["fmus"]["native"]
    unpacked = Path(extract(str(fmu), str(folder / "fmu")))
    step = read_model_description(str(fmu)).defaultExperiment.stepSize
    sources = unpacked / "sources"
    files = sorted(p.name for p in sources.glob("*.c"))
    binary = build(target, sources, files, folder, flags)
    return binary, {**os.environ, "FUZZ_FMU_DIR": str(unpacked), "FUZZ_DT": str(step)}


def test_restored_states_survive_a_short_fuzz_run(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path
) -> None:
    """fmi2DeSerializeFMUstate, fmi2SetFMUstate and fmi2DoStep of the session's native FMU
    (built from its shipped sources), fed mutations of a state it saved and of the committed
    corpus, each with its SHA-256 trailer recomputed (so that the check of every field behind
    the hash is reached): no crash or sanitizer finding in 20 000 runs."""
    binary, env = native_fuzzer("fuzz_fmu_state", tmp_path_factory, tmp_path)
    seed = tmp_path / "fmu_state" / "own.bin"
    fuzz(binary, "fmu_state", 20000, tmp_path, {**env, "FUZZ_WRITE_SEED": str(seed)})
    assert seed.stat().st_size > 1000  # the FMU's own state after 5 steps was in the corpus


def test_set_real_and_do_step_sequences_survive_a_short_fuzz_run(
    tmp_path_factory: pytest.TempPathFactory, tmp_path: Path
) -> None:
    """Sequences of fmi2SetReal (inputs, ood_threshold, references that are no settable Real),
    fmi2SetBoolean (correction_enabled) and fmi2DoStep (any time and step) on the session's
    native FMU, with NaN, infinities, huge and subnormal values: no crash or sanitizer finding,
    and no breach of the FMU's rules that the target checks (a refused call changes nothing, an
    instance in its error phase steps no more) in 5 000 runs (each up to 32 calls, so about
    20 s; the chain step's loops are left out of the coverage instrumentation)."""
    ignore = f"-fsanitize-coverage-ignorelist={ROOT / 'fuzz' / 'coverage_ignore.txt'}"
    binary, env = native_fuzzer("fuzz_fmu_inputs", tmp_path_factory, tmp_path, ignore)
    fuzz(binary, "fmu_inputs", 5000, tmp_path, env)
