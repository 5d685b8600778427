"""The recording as the diagnosis sees it, and the simulations it runs, in parallel.

:class:`Experiment` holds the recorded inputs, the observed outputs and the noise model of
:mod:`.noise` (sensor noise, input noise, the drift input noise drives); its
:meth:`~Experiment.residual` is the residual every step judges and fits.
:class:`Simulator` runs the white-box with sets of correction terms over a prefix of the
recording, in worker processes (each worker receives the extracted FMU and the arrays once).
Workers are forked where the platform allows it (no re-import of the caller's main module);
elsewhere they are spawned. Given a :class:`SimulationCluster` (a Dask cluster:
:class:`fmu_greybox.campaign.cluster.DaskSimulations`), the batches run on its workers instead.
A simulation whose FMU fails returns ``None``: the hypothesis that drove it there is rejected,
not the diagnosis.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from fmu_greybox.data.noise import (
    Bands,
    DriftWhitening,
    InputSmoother,
    estimate_noise_model,
    floored_levels,
    noise_level,
    residual_bands,
)
from fmu_greybox.data.recording import Recording
from fmu_greybox.diagnosis.memo import Memo
from fmu_greybox.diagnosis.signals import SignalMap
from fmu_greybox.errors import FmuError
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.model.native_run import runs_side_by_side
from fmu_greybox.model.simulate import simulate_with_terms
from fmu_greybox.model.terms import Term
from fmu_greybox.project.config import ProjectConfig
from fmu_greybox.project.data import bind_project_inputs


@dataclass
class Experiment:
    """A recording arranged for simulation and comparison.

    Attributes
    ----------
    archive : FmuArchive
        The white-box FMU (already extracted).
    inputs : list of str
        FMU inputs, one per column of ``u``.
    u : ndarray, shape (n, n_inputs)
        Recorded (or fixed) inputs; after :meth:`estimate_noise`, smoothed against their
        noise (:attr:`smoother`).
    dt : float
        Sample time [s].
    start_time : float
        Time of row 0 [s].
    outputs : list of str
        FMU outputs observed by recorded signals.
    stages : list of int
        Stage index of every observed output.
    recorded : ndarray, shape (n, n_outputs)
        The recorded signals.
    sigma : ndarray, shape (n_outputs,)
        Their sensor-noise standard deviations (residuals are divided by these).
    parameters : dict[str, float]
        Project parameter values.
    train_rows : int
        Rows ``0 .. train_rows - 1`` train; the rest is held out.
    input_sigma : ndarray, shape (n_inputs,)
        Sensor-noise standard deviations of the recorded inputs (after
        :meth:`estimate_noise`; zeros before).
    whitening : DriftWhitening or None
        Whitening against the drift input noise drives (after :meth:`estimate_noise`, when an
        input is noisy).
    smoother : InputSmoother or None
        The smoothing of the noisy recorded inputs (after :meth:`estimate_noise`, when an
        input is noisy).
    """

    archive: FmuArchive
    inputs: list[str]
    u: np.ndarray
    dt: float
    start_time: float
    outputs: list[str]
    stages: list[int]
    recorded: np.ndarray
    sigma: np.ndarray
    parameters: dict[str, float]
    train_rows: int
    input_sigma: np.ndarray | None = None
    whitening: DriftWhitening | None = None
    smoother: InputSmoother | None = None
    _cache: dict = field(default_factory=dict, repr=False)

    @classmethod
    def from_project(
        cls,
        config: ProjectConfig,
        archive: FmuArchive,
        recording: Recording,
        signals: SignalMap,
        train_rows: int,
    ) -> Experiment:
        """Arrange a recording of a project: inputs bound as the project says, every observed
        signal with the noise level of its recording (floored at 1e-6 of its RMS, for
        noise-free recordings) until :meth:`estimate_noise` refines it.
        """
        binding = bind_project_inputs(config, archive, recording)
        recorded = np.column_stack([recording[s.column] for s in signals.observed])
        sigma = floored_levels([noise_level(x) for x in recorded.T], recorded)
        return cls(
            archive=archive,
            inputs=binding.inputs,
            u=binding.matrix(recording),
            dt=recording.dt,
            start_time=float(recording.time[0]),
            outputs=signals.observed_variables,
            stages=signals.observed_stages,
            recorded=recorded,
            sigma=sigma,
            parameters=dict(config.parameters),
            train_rows=train_rows,
        )

    @property
    def n_samples(self) -> int:
        """Number of rows."""
        return self.u.shape[0]

    def estimate_noise(self, runs: int = 4, seed: int = 0) -> np.ndarray | None:
        """Set the noise model (:func:`~fmu_greybox.data.noise.estimate_noise_model`, with its
        ``runs`` and ``seed``; the inputs are smoothed where noisy) and return the white-box
        over the inputs kept, shape (n, n_outputs); None if the FMU fails on them."""
        caches: list[dict] = []  # the first run is over the inputs kept: its cache is kept

        def simulate_over(u: np.ndarray) -> np.ndarray | None:
            cache: dict = {}
            caches.append(cache)
            return dataclasses.replace(self, u=u, _cache=cache).simulate([])

        noise = estimate_noise_model(
            self.u,
            self.recorded,
            simulate_over,
            self.dt,
            runs,
            seed,
            side_by_side=runs_side_by_side([], self.archive),
        )
        self._cache = caches[0]
        if noise is None:
            return None
        self.input_sigma, self.smoother = noise.input_sigma, noise.smoother
        self.u, self.sigma, self.whitening = noise.u, noise.sigma, noise.whitening
        return noise.simulated

    def renoised(self, rng: np.random.Generator) -> Experiment:
        """A copy whose inputs carry a fresh draw of their error: the smoothed inputs'
        remaining error (:meth:`~fmu_greybox.data.noise.InputSmoother.noise`) after
        :meth:`estimate_noise` (none where it found no input noise), else white noise at each
        input's second-difference noise level."""
        if self.input_sigma is None:
            sigma = np.array([noise_level(x) for x in self.u.T])
            u = self.u + rng.standard_normal(self.u.shape) * sigma
        elif self.smoother is not None:
            u = self.u + self.smoother.noise(rng, self.input_sigma)
        else:
            u = self.u.copy()
        return dataclasses.replace(self, u=u, _cache={})

    def simulate(self, terms: Sequence[Term], rows: int | None = None) -> np.ndarray | None:
        """Observed outputs over the first ``rows`` rows with ``terms`` applied.

        Returns
        -------
        ndarray, shape (rows, n_outputs), or None if the FMU failed.
        """
        rows = self.n_samples if rows is None else rows
        try:
            return simulate_with_terms(
                self.archive,
                self.inputs,
                self.u[:rows],
                self.dt,
                self.outputs,
                terms,
                self.parameters,
                self.stages,
                self.start_time,
                cache=self._cache,
            )
        except FmuError:
            return None

    def residual(self, simulated: np.ndarray, start: int = 0) -> np.ndarray:
        """Noise-normalised residual ``(recorded - simulated) / sigma``, whitened against the
        drift input noise drives (:attr:`whitening`) over the rows given: white at unit level
        where the white-box is right.

        Parameters
        ----------
        simulated : ndarray, shape (rows, n_outputs)
            Simulated rows ``start .. start + rows - 1``.
        start : int
            Row of the recording the first simulated row corresponds to.

        Returns
        -------
        ndarray, shape (rows, n_outputs)
        """
        normalised = self.normalised(simulated, start)
        return normalised if self.whitening is None else self.whitening(normalised)

    def normalised(self, simulated: np.ndarray, start: int = 0) -> np.ndarray:
        """``(recorded - simulated) / sigma`` (not whitened); arguments as :meth:`residual`."""
        rows = simulated.shape[0]
        return (self.recorded[start : start + rows] - simulated) / self.sigma

    def bands(self, simulated: np.ndarray, start: int = 0) -> Bands:
        """Band powers of the residual against sensor noise and input-noise drift
        (:func:`~fmu_greybox.data.noise.residual_bands`); arguments as :meth:`residual`."""
        return residual_bands(self.normalised(simulated, start), self.whitening, self.dt)


_WORKER: dict[str, Experiment] = {}

#: Memory the :class:`Simulator` keeps its latest results in (their workers' residuals, no larger,
#: beside them).
MEMO_BYTES = 64 * 2**20


def _init_worker(experiment: Experiment) -> None:
    _WORKER["experiment"] = experiment


def _simulate_task(
    task: tuple[list[Term], int, bool],
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A worker's simulation, with the residual of its training rows when ``scored``."""
    terms, rows, scored = task
    experiment = _WORKER["experiment"]
    simulated = experiment.simulate(terms, rows)
    if not scored or simulated is None:
        return simulated, None
    return simulated, experiment.residual(simulated[: experiment.train_rows])


#: One simulation of a batch: the terms, and the rows to simulate.
SimulationTask = tuple[list[Term], int]


class PlacedExperiment(Protocol):
    """An experiment already sent to the workers of a cluster."""

    def run(self, tasks: list[SimulationTask]) -> list[np.ndarray | None]:
        """Simulate every task on the cluster; results in the order of ``tasks``."""
        ...

    def close(self) -> None:
        """Release the experiment on the workers."""
        ...


class SimulationCluster(Protocol):
    """Workers elsewhere that run the simulations instead of local processes."""

    def place(self, experiment: Experiment) -> PlacedExperiment:
        """Send ``experiment`` (FMU and arrays) to every worker once."""
        ...


class Simulator:
    """Runs batches of simulations of one experiment, in parallel when ``workers > 1``.

    Parameters
    ----------
    experiment : Experiment
    workers : int
        Worker processes (1 runs in this process). Use as a context manager, or call
        :meth:`close`.
    cluster : SimulationCluster, optional
        Run the batches on this cluster's workers instead of local processes (``workers`` is
        then not used); a batch of one simulation still runs in this process.

    Attributes
    ----------
    runs : int
        Simulations run so far (a set of terms asked for again over the same rows, while its
        result is among the last :data:`MEMO_BYTES` kept, is not run again: the screening's
        two views of the residual score the same simulations).
    rows_simulated : int
        Total rows simulated so far.

    Notes
    -----
    Worker processes also compute the residual of a scored batch's training rows
    (:meth:`training_residual`), beside the simulations, rather than this process after them.
    """

    def __init__(
        self, experiment: Experiment, workers: int = 2, cluster: SimulationCluster | None = None
    ) -> None:
        self.experiment = experiment
        self.workers = max(1, min(int(workers), os.cpu_count() or 1))
        self.runs = 0
        self.rows_simulated = 0
        self._residuals: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._memo: Memo[tuple[str, int], np.ndarray | None] = Memo(
            MEMO_BYTES,
            lambda result: 0 if result is None else result.nbytes,
            lambda old: None if old is None else self._residuals.pop(id(old), None),
        )
        self._pool = None
        self._placed = None if cluster is None else cluster.place(experiment)
        if self.workers > 1 and cluster is None:
            methods = multiprocessing.get_all_start_methods()
            context = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
            self._pool = context.Pool(
                self.workers, initializer=_init_worker, initargs=(experiment,)
            )

    def run(
        self, term_sets: Sequence[Sequence[Term]], rows: int | None = None, scored: bool = False
    ) -> list:
        """Simulate every set of terms over the first ``rows`` rows.

        With ``scored``, the worker processes also compute each simulation's
        :meth:`training_residual`.

        Returns
        -------
        list of (ndarray of shape (rows, n_outputs) or None)
            In the order of ``term_sets``; ``None`` where the FMU failed.
        """
        rows = self.experiment.n_samples if rows is None else rows
        keys = [(repr([t.to_dict() for t in terms]), rows) for terms in term_sets]
        missing = {key: terms for key, terms in zip(keys, term_sets, strict=True)}
        missing = {key: terms for key, terms in missing.items() if key not in self._memo}
        tasks = [(list(terms), rows) for terms in missing.values()]
        self.runs += len(tasks)
        self.rows_simulated += rows * len(tasks)
        residuals: list[np.ndarray | None] = [None] * len(tasks)
        if self._placed is not None and len(tasks) > 1:
            results = self._placed.run(tasks)
        elif self._pool is None or len(tasks) == 1:
            results = [self.experiment.simulate(terms, rows) for terms, rows in tasks]
        else:
            answers = self._pool.map(
                _simulate_task, [(*task, scored) for task in tasks], chunksize=1
            )
            results = [simulated for simulated, _ in answers]
            residuals = [residual for _, residual in answers]
        found = {key: self._memo[key] for key in keys if key in self._memo}
        found.update(zip(missing, results, strict=True))
        for key, result, residual in zip(missing, results, residuals, strict=True):
            self._remember(key, result, residual)
        return [found[key] for key in keys]

    def training_residual(self, simulated: np.ndarray, rows: int) -> np.ndarray:
        """The residual (:meth:`Experiment.residual`) of the first ``rows`` rows of a
        simulation this simulator returned: the one its worker computed when ``rows`` are its
        training rows and the batch was scored (read-only), else computed here.

        Returns
        -------
        ndarray, shape (rows, n_outputs)
        """
        kept = self._residuals.get(id(simulated))
        train = min(simulated.shape[0], self.experiment.train_rows)
        if kept is not None and kept[0] is simulated and rows == train:
            return kept[1]
        return self.experiment.residual(simulated[:rows])

    def _remember(
        self, key: tuple[str, int], result: np.ndarray | None, residual: np.ndarray | None
    ) -> None:
        """Keep a result (read-only) and its worker's residual, forgetting the oldest beyond
        :data:`MEMO_BYTES` of results (a residual goes with its result)."""
        if result is not None:
            result.setflags(write=False)
            if residual is not None:
                residual.setflags(write=False)
                self._residuals[id(result)] = (result, residual)
        self._memo.keep(key, result)

    def close(self) -> None:
        """Stop the worker processes, release the experiment on a cluster (idempotent)."""
        if self._placed is not None:
            self._placed.close()
            self._placed = None
        if self._pool is not None:
            self._pool.close()
            self._pool.join()
            self._pool = None

    def __enter__(self) -> Simulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
