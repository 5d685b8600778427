"""The main job end to end (``fmu-greybox demo``), its report, and the report in Chromium.

One small demo runs per session (10 s training recording, 20 inducing points): every later test
reads its outputs. The Chromium test needs ``/usr/bin/chromium`` (the test command installs it
from the distribution's packages); outside CI it is skipped when Chromium is missing, in CI it
fails.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from fmpy.validation import validate_fmu
from PIL import Image

from fmu_greybox.cli import main
from fmu_greybox.report.spectra import frequency_response
from fmu_greybox.synth.actuator import TYPICAL_MAGNITUDES
from fmu_greybox.workflow.demo import choose_effect

#: A clear fault, so the test can require the diagnosis to name it.
EFFECT = "coulomb_friction=900"
SMALL = ("--duration", "10", "--validation-duration", "4.2", "--inducing", "20", "--max-iter", "15")


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("demo") / "out"
    result = CliRunner().invoke(
        main, ["demo", "--out", str(out), "--effect", EFFECT, "--seed", "3", *SMALL, "--json"]
    )
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert len(lines) == 1, result.stdout
    return out, json.loads(lines[0])


def test_demo_writes_every_output(demo: tuple[Path, dict]) -> None:
    out = demo[0]
    for name in (
        "report.html",
        "diagnosis.json",
        "summary.json",
        "metrics.json",
        "greybox.fmu",
        "bench.ssp",
        "recording.csv",
        "validation.csv",
        "model/model.json",
    ):
        assert (out / name).is_file(), name
    assert json.loads((out / "summary.json").read_text())["concealed_effects"] == {
        "coulomb_friction": 900.0
    }
    assert validate_fmu(str(out / "greybox.fmu")) == []
    diagnosis = json.loads((out / "diagnosis.json").read_text())
    assert diagnosis["schema_version"] >= 1 and diagnosis["findings"]


def test_demo_finds_the_concealed_effect(demo: tuple[Path, dict]) -> None:
    _, summary = demo
    assert summary["origin_stage"] == "RAM"
    assert summary["top_finding_correct"], summary["top_finding"]
    assert set(summary["validation"]) == {"EHV", "RAM", "ITFV"}
    for row in summary["validation"].values():
        assert row["wb_rmse"] > 0 and row["gb_rmse"] > 0


def test_demo_model_carries_the_named_terms_and_improves_the_ram(demo: tuple[Path, dict]) -> None:
    """The diagnosis' terms are folded into the trained model (and so into its FMU); on the
    independent recording the corrected model beats the white-box on the stage the friction
    acts on."""
    out, summary = demo
    diagnosis = json.loads((out / "diagnosis.json").read_text())
    manifest = json.loads((out / "model" / "model.json").read_text())
    found = [t for f in diagnosis["findings"] for t in f.get("terms", [])]
    assert manifest["named_terms"]["terms"] == found and found
    metrics = json.loads((out / "metrics.json").read_text())["stages"]
    assert metrics["RAM"]["named_rmse"] < 0.5 * metrics["RAM"]["wb_rmse"]
    assert summary["validation"]["RAM"]["improvement"] < -0.5


def test_demo_bench_runs_match_the_master(demo: tuple[Path, dict]) -> None:
    _, summary = demo
    assert set(summary["bench"]) == {"fmpy", "libcosim"}
    for engine, row in summary["bench"].items():
        assert row["steps"] == 4096, engine
        assert row["max_rel_diff"] <= 1e-9, engine


def test_report_is_self_contained(demo: tuple[Path, dict]) -> None:
    text = (Path(demo[0]) / "report.html").read_text(encoding="utf-8")
    assert text.index("Verdict") < text.index("Findings")
    sources = re.findall(r"src='([^']*)'", text)
    assert len(sources) >= 5  # residual, regime, before/after, traces, frequency response
    assert all(s.startswith("data:image/png;base64,") for s in sources)
    assert "http://" not in text and "https://" not in text and "<script" not in text
    for block in ("Traceability", "sha256 greybox.fmu", "±2σ", "Frequency response", "libcosim"):
        assert block in text, block


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def run_chromium(page: Path, tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    browser = chromium()
    if browser is None:
        if os.environ.get("CI"):
            pytest.fail("Chromium is missing: the test command installs Debian's 'chromium'")
        pytest.skip("Chromium not installed (apt-get install chromium)")
    flags = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={tmp_path / 'profile'}",
        "--hide-scrollbars",
    ]
    return subprocess.run(
        [browser, *flags, *args, page.as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def test_report_renders_in_headless_chromium(demo: tuple[Path, dict], tmp_path: Path) -> None:
    report = Path(demo[0]) / "report.html"
    shot = tmp_path / "report.png"
    done = run_chromium(report, tmp_path, "--window-size=1200,2400", f"--screenshot={shot}")
    assert shot.is_file(), done.stderr[-2000:]
    pixels = np.asarray(Image.open(shot).convert("L"), dtype=float)
    assert pixels.shape == (2400, 1200)
    assert (pixels < 200).mean() > 0.03  # text, tables and plots, not a blank page
    assert pixels.std() > 20
    # the same page with a probe that counts images that failed to decode
    probe = tmp_path / "probe.html"
    probe.write_text(
        report.read_text(encoding="utf-8").replace(
            "</body>",
            "<script>window.addEventListener('load',()=>{const bad=[...document.images]"
            ".filter(i=>!i.complete||i.naturalWidth===0).length;document.body.setAttribute("
            "'data-images',document.images.length+'/'+bad);});</script></body>",
        ),
        encoding="utf-8",
    )
    dom = run_chromium(probe, tmp_path, "--virtual-time-budget=10000", "--dump-dom").stdout
    found = re.search(r'data-images="(\d+)/(\d+)"', dom)
    assert found, dom[-500:]
    total, broken = map(int, found.groups())
    assert total >= 5 and broken == 0


def test_a_failed_demo_writes_no_report(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import fmu_greybox.workflow.demo as demo_module
    from fmu_greybox.errors import BenchError

    def broken_bench(*_args, **_kwargs):
        raise BenchError("bench.ssp failed in fmpy: simulated failure")

    monkeypatch.setattr(demo_module, "run_bench", broken_bench)
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["-q", "demo", "--out", str(out), "--effect", EFFECT, *SMALL])
    assert result.exit_code == 1
    assert "simulated failure" in result.stderr and "Traceback" not in result.output
    assert (out / "diagnosis.json").is_file()  # steps done before the failure are kept
    assert not (out / "report.html").exists() and not (out / "summary.json").exists()


def test_choose_effect_is_deterministic_and_typical() -> None:
    drawn = [choose_effect(seed) for seed in range(40)]
    assert drawn == [choose_effect(seed) for seed in range(40)]
    assert len({next(iter(d)) for d in drawn}) >= 5
    for d in drawn:
        ((name, value),) = d.items()
        low, high = TYPICAL_MAGNITUDES[name][0], TYPICAL_MAGNITUDES[name][-1]
        assert low <= value <= high * 1.01


def test_frequency_response_of_a_known_filter() -> None:
    # y[k] = a y[k-1] + (1 - a) u[k-1]: H(z) = (1 - a) z^-1 / (1 - a z^-1)
    rng = np.random.default_rng(0)
    dt, a = 1e-3, 0.9
    u = rng.standard_normal(2**15)
    y = np.zeros_like(u)
    for k in range(1, u.size):
        y[k] = a * y[k - 1] + (1 - a) * u[k - 1]
    r = frequency_response(u, {"recording": y, "grey-box": y, "white-box": 2 * y}, dt)
    z = np.exp(-2j * np.pi * r.freq * dt)
    exact = (1 - a) * z / (1 - a * z)
    np.testing.assert_allclose(np.abs(r.response["recording"]), np.abs(exact), rtol=0.02)
    np.testing.assert_allclose(
        np.angle(r.response["recording"][1:50]), np.angle(exact[1:50]), atol=0.02
    )
    assert r.coherence["recording"].min() > 0.99
    assert r.band_error_db("grey-box") == pytest.approx(0.0, abs=1e-9)
    assert r.band_error_db("white-box") == pytest.approx(20 * np.log10(2), rel=1e-6)
    assert r.match["white-box"].min() > 0.99  # a scaled copy is fully coherent
