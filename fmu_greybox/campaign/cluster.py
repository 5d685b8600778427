"""The Dask cluster: connecting to it, and what reaches its workers once.

A campaign and ``diagnose --scheduler`` run on an existing Dask cluster (``tcp://host:port``
of a ``dask scheduler``) or on a local one started here (``LocalCluster``, one thread per worker
process). Nothing here schedules, queues or transfers by itself: Dask does.

What each worker receives once, not per task, is carried by a Dask worker plugin (the
scheduler hands it to every worker, including workers that join later, and calls its
``teardown`` when it is unregistered):

* :class:`FmuOnWorkers`: the white-box FMU's bytes, written into the worker's local directory
  as ``fmu-greybox/SHA256.fmu`` unless already there (a campaign's tasks open it from there);
* :class:`ExperimentOnWorkers`: one diagnosis' experiment (the FMU's bytes and the recorded
  arrays), opened on the worker and kept under a key for the simulation tasks of that
  diagnosis (:class:`DaskSimulations`, the :class:`~fmu_greybox.diagnosis.runner.SimulationCluster`
  of ``diagnose --scheduler``); a task then carries only its terms and row count.

:func:`worker_stats` counts, per worker process, what arrived and what ran, so that the
benchmark can show the once-per-worker movement.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import os
import resource
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import dask
import numpy as np
from dask.utils import parse_timedelta
from distributed import Client, LocalCluster
from distributed.diagnostics.plugin import WorkerPlugin

from fmu_greybox.atomic import atomic_write
from fmu_greybox.diagnosis.runner import Experiment, SimulationTask
from fmu_greybox.errors import ClusterError
from fmu_greybox.fmi.archive import open_fmu

#: Per worker process: FMU files by SHA-256, experiments by key, counters.
_FMU_FILES: dict[str, Path] = {}
_EXPERIMENTS: dict[str, Experiment] = {}
_STATS = {"fmu_files_written": 0, "experiments_placed": 0, "simulations": 0}


@contextmanager
def connect(scheduler: str | None = None, workers: int = 2) -> Iterator[Client]:
    """A client of an existing Dask cluster, or of a local one with ``workers`` processes.

    Parameters
    ----------
    scheduler : str or None
        Address of a running ``dask scheduler`` (``tcp://host:port``); ``None`` starts a
        local cluster for the time of the block.
    workers : int
        Worker processes of the local cluster (one thread each).

    Raises
    ------
    ClusterError
        If the scheduler does not answer, or has no worker, within Dask's connect time-out
        (``distributed.comm.timeouts.connect`` in the Dask configuration, 30 s by default).
    """
    if scheduler is None:
        with (
            LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                silence_logs=logging.CRITICAL,
            ) as cluster,
            Client(cluster) as client,
        ):
            yield client
        return
    timeout = parse_timedelta(dask.config.get("distributed.comm.timeouts.connect"))
    try:
        client = Client(scheduler, timeout=timeout)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ClusterError(
            f"cannot reach a Dask scheduler at {scheduler!r} ({exc}); start one with "
            "'dask scheduler' and give the address it prints, or leave out --scheduler to "
            "run on a local cluster"
        ) from None
    with client:
        try:
            client.wait_for_workers(1, timeout=timeout)
        except TimeoutError:
            raise ClusterError(
                f"the Dask scheduler at {scheduler} has no worker after {timeout:g} s; "
                f"start some with 'dask worker {scheduler}'"
            ) from None
        yield client


@dataclass(frozen=True)
class FmuBlob:
    """An FMU's bytes, named by their SHA-256.

    Attributes
    ----------
    sha256 : str
    data : bytes
    """

    sha256: str
    data: bytes

    @classmethod
    def read(cls, path: str | Path) -> FmuBlob:
        """The bytes of an FMU file."""
        data = Path(path).read_bytes()
        return cls(hashlib.sha256(data).hexdigest(), data)

    def on_worker(self, directory: str | Path) -> Path:
        """This FMU as a file in a worker's local ``directory``, written on first use (the
        file is named by its content, so campaigns and diagnoses that follow reuse it)."""
        path = Path(directory) / "fmu-greybox" / f"{self.sha256}.fmu"
        if not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_write(path, "wb") as f:
                f.write(self.data)
            _STATS["fmu_files_written"] += 1
        _FMU_FILES[self.sha256] = path
        return path


def fmu_file(sha256: str) -> Path:
    """The file of an FMU that :class:`FmuOnWorkers` put on this worker.

    Raises
    ------
    ClusterError
        If no such FMU was registered (the task ran outside a campaign).
    """
    try:
        return _FMU_FILES[sha256]
    except KeyError:
        raise ClusterError(
            f"FMU {sha256[:12]} is not on this worker; register FmuOnWorkers first"
        ) from None


class FmuOnWorkers(WorkerPlugin):
    """Writes an FMU into every worker's local directory, once per worker.

    Parameters
    ----------
    blob : FmuBlob
    """

    def __init__(self, blob: FmuBlob) -> None:
        self.blob = blob
        self.name = f"fmu-greybox-fmu-{blob.sha256[:16]}"

    def setup(self, worker) -> None:
        self.blob.on_worker(worker.local_directory)


class ExperimentOnWorkers(WorkerPlugin):
    """Opens one diagnosis' experiment on every worker, once per worker, under a key.

    Parameters
    ----------
    key : str
        Unique name of the placement (several diagnoses may share a cluster).
    blob : FmuBlob
        The white-box FMU.
    fields : dict
        Every field of the :class:`~fmu_greybox.diagnosis.runner.Experiment` but its archive
        and its cache (arrays, names, noise levels, parameters).
    """

    def __init__(self, key: str, blob: FmuBlob, fields: dict) -> None:
        self.name = key
        self.blob = blob
        self.fields = fields

    def setup(self, worker) -> None:
        archive = open_fmu(self.blob.on_worker(worker.local_directory))
        _EXPERIMENTS[self.name] = Experiment(archive=archive, **self.fields)
        _STATS["experiments_placed"] += 1

    def teardown(self, worker) -> None:
        experiment = _EXPERIMENTS.pop(self.name, None)
        if experiment is not None:
            experiment.archive.close()

    @classmethod
    def of(cls, experiment: Experiment, key: str) -> ExperimentOnWorkers:
        """The placement of an experiment opened here: its FMU file's bytes, its fields."""
        fields = {
            f.name: getattr(experiment, f.name)
            for f in dataclasses.fields(experiment)
            if f.name not in ("archive", "_cache")
        }
        return cls(key, FmuBlob.read(experiment.archive.path), fields)


def _simulate_placed(key: str, terms: list, rows: int) -> np.ndarray | None:
    """A simulation task on a worker: the experiment placed under ``key``."""
    _STATS["simulations"] += 1
    return _EXPERIMENTS[key].simulate(terms, rows)


class PlacedOnDask:
    """An experiment placed on a Dask cluster's workers (see :class:`DaskSimulations`)."""

    def __init__(self, client: Client, experiment: Experiment) -> None:
        self.client = client
        self.key = f"fmu-greybox-experiment-{uuid.uuid4().hex}"
        client.register_plugin(ExperimentOnWorkers.of(experiment, self.key))

    def run(self, tasks: list[SimulationTask]) -> list[np.ndarray | None]:
        """Simulate every task on the cluster (results in the order of ``tasks``)."""
        keys = [self.key] * len(tasks)
        terms = [t for t, _ in tasks]
        rows = [r for _, r in tasks]
        futures = self.client.map(_simulate_placed, keys, terms, rows, pure=False)
        return self.client.gather(futures)

    def close(self) -> None:
        """Unregister the placement: every worker closes its copy."""
        self.client.unregister_worker_plugin(self.key)


class DaskSimulations:
    """A Dask cluster as the diagnosis' :class:`~fmu_greybox.diagnosis.runner.SimulationCluster`.

    Parameters
    ----------
    client : distributed.Client
    """

    def __init__(self, client: Client) -> None:
        self.client = client

    def place(self, experiment: Experiment) -> PlacedOnDask:
        """Send the experiment to every worker once."""
        return PlacedOnDask(self.client, experiment)


def worker_stats() -> dict[str, int]:
    """What this worker process received and ran, and its peak resident memory [bytes].

    Run it on every worker with ``client.run(worker_stats)``.
    """
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    return {**_STATS, "peak_rss": int(peak), "pid": os.getpid()}
