"""Campaigns on a real Dask cluster: a scheduler and two workers started here as separate
processes on 127.0.0.1, a campaign of three recordings whose friction grows (the truth actuator
with 300, 600 and 900 N), a broken recording beside them, the rerun, and one diagnosis whose
simulations run on the cluster. Also the drift test against known answers."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import dask
import numpy as np
import pytest
from click.testing import CliRunner
from distributed import Client

from fmu_greybox.campaign.cluster import worker_stats
from fmu_greybox.campaign.page import trend_figure
from fmu_greybox.campaign.run import RecordingOutcome, campaign_order
from fmu_greybox.campaign.trends import Z95, campaign_trends, drift_test
from fmu_greybox.cli import main
from fmu_greybox.data.recording import load_recording, save_recording
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise

ACTUATOR = Path(__file__).resolve().parents[1] / "bench_configs" / "hydraulic_actuator.toml"
DASK = Path(sys.executable).parent / "dask"
#: Friction of the truth actuator per flight, and the flight dates.
FRICTION = {
    "2026-01-10T09:00:00": 300.0,
    "2026-02-10T09:00:00": 600.0,
    "2026-03-10T09:00:00": 900.0,
}


def _start(command: list, log: Path) -> subprocess.Popen:
    with log.open("w") as out:
        return subprocess.Popen(
            [str(c) for c in command], stdout=out, stderr=subprocess.STDOUT, start_new_session=True
        )


def _stop(process: subprocess.Popen) -> None:
    """End a process started here and its children (its own session), politely first."""
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


@pytest.fixture(scope="module")
def dask_cluster(tmp_path_factory):
    """``dask scheduler`` and two ``dask worker`` processes on free ports of 127.0.0.1.

    Yields the scheduler's address and the two workers' addresses; every process is ended at
    the end of the module, also when a test fails.
    """
    folder = tmp_path_factory.mktemp("dask")
    scheduler_file = folder / "scheduler.json"
    started = []
    try:
        options = "--host 127.0.0.1 --no-dashboard".split()
        scheduler = ["scheduler", *options, "--port", "0", "--scheduler-file", scheduler_file]
        started.append(_start([DASK, *scheduler], folder / "scheduler.log"))
        deadline = time.monotonic() + 60
        while not scheduler_file.is_file() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(scheduler_file.read_text())["address"]
        for i in range(2):
            worker = ["worker", address, *options, "--nworkers", "1", "--nthreads", "1"]
            worker += ["--name", f"w{i}", "--local-directory", folder / f"w{i}"]
            started.append(_start([DASK, *worker], folder / f"worker{i}.log"))
        with Client(address, timeout=60) as client:
            client.wait_for_workers(2, timeout=120)
            workers = sorted(client.nthreads())
        yield address, workers
    finally:
        for process in reversed(started):
            _stop(process)


@pytest.fixture(scope="module")
def flights(tmp_path_factory, whitebox_fmu, truth_fmu) -> dict[str, Path]:
    """Three 4 s flights whose Coulomb friction grows, dated in their Parquet files, and a
    fourth whose valve current was not recorded."""
    folder = tmp_path_factory.mktemp("flights")
    paths = {}
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        for seed, (date, force) in enumerate(FRICTION.items(), start=5):
            request = SynthRequest(
                {"coulomb_friction": force}, seed=seed, profile=FlightTestProfile(duration=4.0)
            )
            recording = synthesise(truth, whitebox, request)
            dated = dataclasses.replace(recording, metadata={"time_origin": date})
            paths[date] = folder / f"flight_{int(force)}.parquet"
            save_recording(dated, paths[date])
    names = [n for n in recording.names if n != "valve_current"]
    broken = dataclasses.replace(
        recording.select(names), metadata={"time_origin": "2026-04-10T09:00:00"}
    )
    paths["broken"] = folder / "flight_no_current.parquet"
    save_recording(broken, paths["broken"])
    return paths


@pytest.fixture(scope="module")
def campaign_run(dask_cluster, flights, tmp_path_factory):
    """The campaign through the command line, flights given out of date order."""
    address, _ = dask_cluster
    out = tmp_path_factory.mktemp("campaign")
    given = [flights["2026-03-10T09:00:00"], flights["broken"], *list(flights.values())[:2]]
    args = ["campaign", str(ACTUATOR), *map(str, given), "--out", str(out)]
    result = CliRunner().invoke(main, [*args, "--scheduler", address, "--no-greybox"])
    return args, out, result


def test_campaign_names_the_growing_friction_and_its_drift(campaign_run, dask_cluster, flights):
    _, out, result = campaign_run
    assert result.exit_code == 1, result.output  # one recording failed, the others went on
    lines = [line for line in result.output.splitlines() if line.startswith("[")]
    assert len(lines) == 4  # one line per finished recording (not a terminal)
    assert "1 of 4 recordings failed" in result.output
    payload = json.loads((out / "campaign.json").read_text())
    assert payload["order"] == "start_time"
    records = payload["recordings"]
    assert [r["start_time"] for r in records] == [*FRICTION, "2026-04-10T09:00:00"]
    assert [r["status"] for r in records] == ["diagnosed"] * 3 + ["failed"]
    assert "valve_current" in records[3]["error"] and records[3]["findings"] is None
    # both workers of the cluster diagnosed
    assert {r["worker"] for r in records[:3]} == set(dask_cluster[1])
    for record in records[:3]:
        diagnosis = json.loads((out / record["diagnosis"]).read_text())
        assert record["sha256"] == diagnosis["recording"]["sha256"]
        assert record["findings"] == diagnosis["findings"]
        assert (out / record["report"]).is_file()
        assert record["findings"][0]["effect"] == "coulomb_friction"
    (trend,) = payload["trends"]
    assert (trend["effect"], trend["stage"], trend["parameter"], trend["unit"]) == (
        "coulomb_friction",
        "RAM",
        "force",
        "N",
    )
    assert trend["values"][3] is None and trend["ci95"][3] is None
    assert trend["values"][:3] == pytest.approx(list(FRICTION.values()), rel=0.05)
    assert trend["slope"] == pytest.approx(300.0, rel=0.1)  # N per recording
    assert trend["drift"] is True and trend["p_value"] < 1e-6
    page = (out / "campaign.html").read_text()
    assert page.count("data:image/png;base64,") == 1  # the one trend's plot
    for record in records[:3]:
        assert f"href='{record['report']}'" in page
    assert "DRIFTS" in page


def test_a_rerun_reuses_every_diagnosis(campaign_run, dask_cluster):
    args, out, _ = campaign_run
    written = {p: p.stat().st_mtime_ns for p in out.glob("recordings/*/diagnosis.json")}
    assert len(written) == 3
    result = CliRunner().invoke(main, [*args, "--scheduler", dask_cluster[0], "--no-greybox"])
    assert result.exit_code == 1, result.output  # the broken recording is tried again
    payload = json.loads((out / "campaign.json").read_text())
    assert payload["summary"] == {
        "recordings": 4,
        "diagnosed": 0,
        "reused": 3,
        "failed": 1,
        "wall_seconds": payload["summary"]["wall_seconds"],
    }
    assert {p: p.stat().st_mtime_ns for p in written} == written
    assert payload["trends"][0]["drift"] is True


def test_an_edited_diagnosis_is_not_reused(campaign_run, dask_cluster, tmp_path):
    """Issue 42, item 4: a diagnosis.json whose value was moved outside its own interval was
    reused unchecked (trended as 4795 N), then the trend plot died in matplotlib ('yerr' must
    not contain negative values). Now that recording fails, naming the file, the finding and
    the remedy, and the campaign goes on with the others."""
    args, out, _ = campaign_run
    copy = tmp_path / "campaign"
    shutil.copytree(out, copy)
    (edited,) = copy.glob("recordings/flight_600-*/diagnosis.json")
    diagnosis = json.loads(edited.read_text())
    force = diagnosis["findings"][0]["magnitudes"]["force"]
    assert force["ci95"][1] < 4795.0
    force["value"] = 4795.0
    edited.write_text(json.dumps(diagnosis))
    rerun = [*args[:-1], str(copy), "--scheduler", dask_cluster[0], "--no-greybox"]
    result = CliRunner().invoke(main, rerun)
    assert result.exit_code == 1, result.output  # the error of a recording, no traceback
    assert isinstance(result.exception, SystemExit), result.exception
    assert "2 of 4 recordings failed" in result.output
    payload = json.loads((copy / "campaign.json").read_text())
    assert [r["status"] for r in payload["recordings"]] == ["reused", "failed", "reused", "failed"]
    error = payload["recordings"][1]["error"]
    assert error.startswith(f"{edited}: finding 1 (coulomb_friction), magnitude 'force': ")
    assert "its value 4795.0 lies outside its own 95 % interval" in error
    assert "Delete it (or its folder) and run the campaign again" in error
    assert f"flight_600.parquet: FAILED: {edited}" in result.output
    (trend,) = payload["trends"]
    assert trend["values"][1] is None and 4795.0 not in trend["values"]
    assert (copy / "campaign.html").is_file()


def test_a_copy_of_a_flight_counts_once(campaign_run, dask_cluster, flights, tmp_path):
    """Issue 42, item 7: a flight given again (a byte copy, or re-saved as CSV with 12
    significant digits) gave the drift test more points from one flight. Now each copy is
    left out, naming the flight it copies, and the trend holds one point per flight."""
    args, out, _ = campaign_run
    copy = tmp_path / "campaign"
    shutil.copytree(out, copy)
    first = flights[next(iter(FRICTION))]
    same = tmp_path / "same.parquet"
    shutil.copyfile(first, same)
    recording = load_recording(first)
    signals = {
        n: np.array([float(f"{v:.12g}") for v in values]) for n, values in recording.signals.items()
    }
    rounded = tmp_path / "rounded.csv"
    save_recording(dataclasses.replace(recording, signals=signals), rounded)
    given = [*args[2:-2], str(same), str(rounded)]
    rerun = ["campaign", args[1], *given, "--out", str(copy)]
    result = CliRunner().invoke(main, [*rerun, "--scheduler", dask_cluster[0], "--no-greybox"])
    assert result.exit_code == 1, result.output
    assert "3 of 6 recordings failed" in result.output
    payload = json.loads((copy / "campaign.json").read_text())
    by_source = {Path(r["source"]).name: r for r in payload["recordings"]}
    for name in ("same.parquet", "rounded.csv"):
        record = by_source[name]
        assert record["status"] == "failed" and record["findings"] is None
        assert f"100.0% of its rows are rows of {first}" in record["error"]
        assert "count each recording once" in record["error"]
    (trend,) = payload["trends"]
    assert sum(v is not None for v in trend["values"]) == 3


def test_one_diagnosis_runs_its_simulations_on_the_cluster(
    campaign_run, dask_cluster, flights, tmp_path
):
    """The same answer as the diagnosis that ran in one worker process, with its simulations
    spread over both workers, each of which received the FMU and the arrays once."""
    address, workers = dask_cluster
    _, out, _ = campaign_run
    flight = flights["2026-01-10T09:00:00"]
    result = CliRunner().invoke(
        main,
        [
            "diagnose",
            str(ACTUATOR),
            "--recording",
            str(flight),
            "--out",
            str(tmp_path),
            "--scheduler",
            address,
            "--no-greybox",
        ],
    )
    assert result.exit_code == 0, result.output
    on_cluster = json.loads((tmp_path / "diagnosis.json").read_text())
    (campaign,) = [
        json.loads(p.read_text())
        for p in out.glob("recordings/*/diagnosis.json")
        if json.loads(p.read_text())["recording"]["sha256"] == on_cluster["recording"]["sha256"]
    ]
    assert [f["effect"] for f in on_cluster["findings"]] == ["coulomb_friction"]
    # not to the last digit: a Dask worker runs numpy with one BLAS thread, this process with
    # several, and the rounding of the linear algebra differs (checked: with
    # OMP_NUM_THREADS=1 a local diagnosis gives the worker's value exactly)
    assert on_cluster["findings"][0]["magnitude"]["value"] == pytest.approx(
        campaign["findings"][0]["magnitude"]["value"], rel=1e-6
    )
    with Client(address) as client:
        stats = client.run(worker_stats)
    assert sorted(stats) == workers
    assert [s["experiments_placed"] for s in stats.values()] == [1, 1]
    assert [s["fmu_files_written"] for s in stats.values()] == [1, 1]
    ran = [s["simulations"] for s in stats.values()]
    assert min(ran) > 0 and sum(ran) < on_cluster["simulations"]


def test_an_unreachable_scheduler_is_a_clear_error(tmp_path) -> None:
    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
        result = CliRunner().invoke(
            main,
            [
                "campaign",
                str(ACTUATOR),
                str(tmp_path / "x.csv"),
                "--out",
                str(tmp_path),
                "--scheduler",
                "tcp://127.0.0.1:9",
            ],
        )
    assert result.exit_code == 1
    assert "cannot reach a Dask scheduler at 'tcp://127.0.0.1:9'" in result.output
    assert "Traceback" not in result.output
    both = ["--scheduler", "tcp://127.0.0.1:9", "--workers", "2"]
    result = CliRunner().invoke(
        main, ["campaign", str(ACTUATOR), "x.csv", "--out", str(tmp_path), *both]
    )
    assert result.exit_code == 2 and "not both" in result.output


def test_drift_test_flags_change_and_keeps_its_false_alarm_rate() -> None:
    rng = np.random.default_rng(0)
    sigma = np.array([10.0, 20.0, 10.0, 15.0, 10.0])

    def intervals(y):
        return [[v - Z95 * s, v + Z95 * s] for v, s in zip(y, sigma, strict=True)]

    alarms = 0
    trials = 4000
    for _ in range(trials):
        y = 500.0 + sigma * rng.standard_normal(5)
        alarms += bool(drift_test(list(y), intervals(y)).drift)
    # a constant magnitude measured with the stated errors: 5 % false alarms (binomial sd 0.34 %)
    assert alarms / trials == pytest.approx(0.05, abs=0.012)
    y = 500.0 + 25.0 * np.arange(5) + sigma * rng.standard_normal(5)
    test = drift_test(list(y), intervals(y))
    assert test.drift is True
    assert test.slope_ci95[0] < 25.0 < test.slope_ci95[1]
    # the weighted slope of exact data on a line is the line's
    exact = drift_test([1.0, 3.0, 5.0], [[0.0, 2.0], [2.5, 3.5], [4.0, 6.0]])
    # chi-square about the weighted mean 3: (1 - 3)^2 / sigma^2 twice, sigma = 1 / Z95
    assert (exact.slope, exact.intercept, exact.chi2) == pytest.approx((2.0, 1.0, 8 * Z95**2))
    # too few recordings with an interval: the data cannot decide
    single = drift_test([1.0, None, 2.0], [[0.5, 1.5], None, None])
    assert single.drift is None and single.slope is None


def test_trends_follow_each_named_magnitude_and_leave_gaps() -> None:
    def finding(effect, hypothesis, magnitudes, **extra):
        return {
            "effect": effect,
            "stage": "RAM",
            "hypothesis": hypothesis,
            "magnitudes": magnitudes,
            **extra,
        }

    leak = finding(
        "parameter_mismatch",
        "parameter_mismatch@leakage_coefficient",
        {"relative_change": {"value": 0.5, "unit": "", "ci95": [0.4, 0.6]}},
        parameter="leakage_coefficient",
    )
    stribeck = finding(
        "stribeck_friction",
        "stribeck_friction@load_force(ram_velocity)",
        {
            "force": {"value": 500.0, "unit": "N", "ci95": [480.0, 520.0]},
            "stribeck_velocity": {"value": 0.01, "unit": "m/s", "ci95": None},
        },
    )
    none = {"effect": "none", "stage": None}
    trends = campaign_trends([[leak, stribeck], None, [none], [leak]])
    assert [(t.effect, t.parameter, t.unit) for t in trends] == [
        ("parameter_mismatch", "leakage_coefficient", ""),
        ("stribeck_friction", "force", "N"),
        ("stribeck_friction", "stribeck_velocity", "m/s"),
    ]
    assert trends[0].values == [0.5, None, None, 0.5]
    assert trends[0].test.drift is False and trends[0].named_in == 2
    assert trends[1].values == [500.0, None, None, None] and trends[1].test.drift is None


def test_the_trend_plot_draws_no_negative_error_bar() -> None:
    """Before: a value outside its interval made matplotlib raise ('yerr' must not contain
    negative values) and the campaign page was never written."""
    trend = {"parameter": "force", "unit": "N", "slope": None, "intercept": None}
    trend |= {"values": [300.0, 4795.0, None], "ci95": [[280.0, 320.0], [560.0, 640.0], None]}
    figure = trend_figure(trend, ["a", "b", "c"])
    (bars,) = figure.axes[0].collections  # the error bars: one segment per value
    lows, highs = (np.array([s[k][1] for s in bars.get_segments()]) for k in (0, 1))
    np.testing.assert_allclose(lows, [280.0, 560.0])
    np.testing.assert_allclose(highs, [320.0, 4795.0])  # the bar stops at the value


def test_recordings_are_ordered_by_start_time_only_when_all_carry_one() -> None:
    dated = [
        RecordingOutcome(0, "b", start_time="2026-05-01T00:00:00"),
        RecordingOutcome(1, "a", start_time="2026-04-30T23:59:59"),
    ]
    ordered, how = campaign_order(dated)
    assert [o.source for o in ordered] == ["a", "b"] and how == "start_time"
    ordered, how = campaign_order([*dated, RecordingOutcome(2, "c")])
    assert [o.source for o in ordered] == ["b", "a", "c"] and how == "given"
