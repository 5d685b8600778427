"""Wall time of ``fmu-greybox campaign`` with 1 and 2 Dask workers, and what moves where.

A campaign of N recordings of the truth actuator (Coulomb friction growing from 300 N by 200 N
per recording, seed per recording) is run three ways in the same run on the same machine:

* the peer: the same diagnoses one after the other in this process, no Dask;
* the campaign on a local Dask cluster of 1 worker process, then of 2 (a fresh output folder
  each time, so nothing is reused).

The client's own work per recording (read and hash) is timed alone. Then one
``diagnose --scheduler`` on the 2-worker cluster against the local two-process pool
(``--workers 2``), on the first recording. Data movement is measured, not estimated: the pickled
size of what each task and each worker receive, of what each task returns, and the counters
each worker keeps (:func:`fmu_greybox.campaign.cluster.worker_stats`: FMU files written,
experiments placed, simulations run, peak resident memory).

Usage: ``.venv/bin/python benchmarks/bench_campaign.py [--recordings N] [--duration S]
[--json]``.
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from fmu_greybox.campaign.cluster import (
    DaskSimulations,
    ExperimentOnWorkers,
    FmuBlob,
    connect,
    worker_stats,
)
from fmu_greybox.campaign.run import run_campaign
from fmu_greybox.data.recording import save_recording
from fmu_greybox.diagnosis import Diagnosis
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.builtin import reference_fmus
from fmu_greybox.project.config import load_config
from fmu_greybox.project.data import load_project_recording, whitebox_path
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise

CONFIG = Path(__file__).resolve().parent.parent / "bench_configs" / "hydraulic_actuator.toml"


def recordings(folder: Path, count: int, duration: float) -> list[Path]:
    """``count`` recordings with a growing Coulomb friction, as CSV files in ``folder``."""
    paths = reference_fmus()
    files = []
    with (
        open_fmu(paths["HydraulicActuatorTruth"]) as truth,
        open_fmu(paths["HydraulicActuator"]) as whitebox,
    ):
        for i in range(count):
            force = 300.0 + 200.0 * i
            request = SynthRequest(
                {"coulomb_friction": force},
                seed=10 + i,
                profile=FlightTestProfile(duration=duration),
            )
            files.append(folder / f"flight_{i:02d}.csv")
            save_recording(synthesise(truth, whitebox, request), files[-1])
    return files


def serial(files: list[Path]) -> float:
    """The peer: every diagnosis in this process, one after the other [s]."""
    config = load_config(CONFIG)
    started = time.perf_counter()
    for path in files:
        Diagnosis(config, workers=1, greybox=None).fit(load_project_recording(config, path))
    return time.perf_counter() - started


def client_reading(files: list[Path]) -> float:
    """What the client does per recording before submitting it: read and hash [s]."""
    config = load_config(CONFIG)
    started = time.perf_counter()
    for path in files:
        load_project_recording(config, path).sha256()
    return (time.perf_counter() - started) / len(files)


def campaign(files: list[Path], folder: Path, workers: int) -> tuple[float, dict, dict]:
    """The campaign on a local cluster: wall time [s], campaign.json, worker counters."""
    config = load_config(CONFIG)
    with connect(None, workers) as client:
        started = time.perf_counter()
        payload = run_campaign(config, files, folder, client, greybox=False)
        seconds = time.perf_counter() - started
        stats = client.run(worker_stats)
    return seconds, payload, stats


def one_diagnosis(path: Path) -> dict:
    """``diagnose`` of one recording: on the 2-worker cluster, and with the local 2-process
    pool; wall times, worker counters and the placement's size."""
    config = load_config(CONFIG)
    recording = load_project_recording(config, path)
    started = time.perf_counter()
    local = Diagnosis(config, workers=2, greybox=None).fit(recording)
    pool_seconds = time.perf_counter() - started
    with connect(None, 2) as client:
        started = time.perf_counter()
        remote = Diagnosis(config, greybox=None, cluster=DaskSimulations(client)).fit(recording)
        cluster_seconds = time.perf_counter() - started
        stats = client.run(worker_stats)
    experiment = remote.experiment_
    plugin = ExperimentOnWorkers.of(experiment, "key")
    terms = remote.findings_[0].details["terms"]
    return {
        "pool_seconds": round(pool_seconds, 1),
        "cluster_seconds": round(cluster_seconds, 1),
        "same_findings": [f.to_dict()["summary"] for f in local.findings_]
        == [f.to_dict()["summary"] for f in remote.findings_],
        "simulations": remote.simulations_,
        "simulations_on_workers": sum(s["simulations"] for s in stats.values()),
        "experiments_placed_per_worker": [s["experiments_placed"] for s in stats.values()],
        "placement_bytes_per_worker": len(pickle.dumps(plugin)),
        "task_bytes": len(pickle.dumps(("key", terms, experiment.n_samples))),
        "result_bytes": experiment.n_samples * len(experiment.outputs) * 8,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=int, default=4, help="Recordings in the campaign.")
    parser.add_argument("--duration", type=float, default=4.0, help="Length of each [s].")
    parser.add_argument("--json", action="store_true", help="Print one JSON line.")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        files = recordings(folder, args.recordings, args.duration)
        peer = serial(files)
        one, _, _ = campaign(files, folder / "one", 1)
        two, payload, stats2 = campaign(files, folder / "two", 2)
        diagnosis = one_diagnosis(files[0])
        config = load_config(CONFIG)
        recording = load_project_recording(config, files[0])
        result = json.loads((folder / "two" / payload["recordings"][0]["diagnosis"]).read_text())
        html = (folder / "two" / payload["recordings"][0]["report"]).read_bytes()
        figures = {
            "recordings": args.recordings,
            "samples_per_recording": recording.n_samples,
            "serial_seconds": round(peer, 1),
            "campaign_1_worker_seconds": round(one, 1),
            "campaign_2_workers_seconds": round(two, 1),
            "speedup_2_over_1": round(one / two, 2),
            "overhead_1_worker_over_serial": round(one / peer, 2),
            "fmu_bytes_per_worker": len(FmuBlob.read(whitebox_path(config)).data),
            "fmu_files_written_per_worker": [s["fmu_files_written"] for s in stats2.values()],
            "client_read_seconds_per_recording": round(client_reading(files), 3),
            "recording_bytes_per_task": len(pickle.dumps(recording)),
            "result_bytes_per_task": len(json.dumps(result)) + len(html),
            "worker_peak_rss_mb": round(max(s["peak_rss"] for s in stats2.values()) / 2**20),
            "trend": [round(v, 1) for v in payload["trends"][0]["values"]],
            "drift": payload["trends"][0]["drift"],
            "diagnose_scheduler": diagnosis,
        }
    if args.json:
        print(json.dumps(figures))
        return
    for key, value in figures.items():
        print(f"{key:32s} {value}")


if __name__ == "__main__":
    main()
