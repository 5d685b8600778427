"""Open-loop simulation of the white-box (with or without named terms) over recorded inputs.

:func:`run_open_loop` is the one stepping loop of the white-box: the diagnosis's hypotheses,
training's white-box predictions, the ``simulate`` command and the co-simulation master all
step a :class:`~fmu_greybox.model.whitebox.NamedModel` through it.

Timing convention, shared by the synthetic recorder and the co-simulation master: row ``k`` of
a recording holds the input ``u_k`` applied over ``[t_k, t_k+1)`` and the output ``y_k``
observed at ``t_k`` *before* ``u_k`` acts. So ``y_0`` is the FMU's initial output and
``y_k+1`` is read after the step that applied ``u_k``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Protocol

import numpy as np

from fmu_greybox.data.recording import Recording
from fmu_greybox.fmi.archive import FmuArchive, open_fmu, real_outputs
from fmu_greybox.fmi.binding import InputBinding, bind_inputs, input_units
from fmu_greybox.model.native_run import run_native, runs_natively
from fmu_greybox.model.terms import Term
from fmu_greybox.model.whitebox import DEFAULT_SUBSTEPS, NamedModel, term_groups
from fmu_greybox.progress import Progress, track

#: Largest number of runs :func:`simulate_with_terms` keeps in a cache.
CACHE_SIZE = 8
#: What a run's progress says.
STEPPING = "Stepping the white-box over the recording"


class Stepper(Protocol):
    """A model stepped one communication step at a time (a
    :class:`~fmu_greybox.model.whitebox.NamedModel`)."""

    def outputs(self) -> np.ndarray:
        """The outputs now, shape (n_outputs,)."""

    def step(self, u: np.ndarray) -> np.ndarray:
        """Apply inputs ``u`` over one step; the outputs at its end, shape (n_outputs,)."""


def run_open_loop(model: Stepper, u: np.ndarray, progress: bool = False) -> np.ndarray:
    """Step a model through an input sequence.

    Parameters
    ----------
    model : Stepper
        Initialised, taking the inputs in the column order of ``u``.
    u : ndarray, shape (n_samples, n_inputs)
        Input rows; row ``k`` acts over ``[t_k, t_k + dt)``.
    progress : bool
        Show a progress bar.

    Returns
    -------
    ndarray, shape (n_samples, n_outputs)
        Row 0 is the initial output, row ``k + 1`` the output after applying ``u[k]``.
    """
    n = u.shape[0]
    first = model.outputs()
    y = np.empty((n, first.size))
    y[0] = first
    for k in track(range(n - 1), STEPPING, n - 1, progress):
        y[k + 1] = model.step(u[k])
    return y


def simulate_with_terms(
    archive: FmuArchive,
    inputs: Sequence[str],
    u: np.ndarray,
    dt: float,
    outputs: Sequence[str],
    terms: Sequence[Term] = (),
    parameters: Mapping[str, float] | None = None,
    stages: Sequence[int] | None = None,
    start_time: float = 0.0,
    substeps: int = DEFAULT_SUBSTEPS,
    cache: dict | None = None,
    progress: bool = False,
) -> np.ndarray:
    """Run the white-box open-loop over recorded inputs with correction terms applied.

    The run is stepped in C (:mod:`~fmu_greybox.model.native_run`, the same numbers without
    Python between the steps; its progress is shown when it is done) unless the runner cannot be
    built or the white-box is of a kind it does not load (FMI 3.0: stepped by fmpy in Python).

    Parameters
    ----------
    archive, inputs, dt, outputs, terms, parameters, stages, start_time, substeps
        As :class:`NamedModel`.
    u : ndarray, shape (n, len(inputs))
        Recorded inputs.
    cache : dict, optional
        Results of earlier runs by (terms, outputs, rows, stages): a run whose active terms,
        outputs and length match one in it is not repeated (the stages before a late-entering
        term usually match the plain run). Bounded to :data:`CACHE_SIZE` entries.
    progress : bool
        Show a progress bar.

    Returns
    -------
    ndarray, shape (n, len(outputs))
        Row 0 the initial outputs, row ``k + 1`` those after applying ``u[k]``.

    Raises
    ------
    FmuError
        If the FMU fails (e.g. a correction drives it out of its valid range).
    """
    stages = list(stages) if stages is not None else [0] * len(outputs)
    y = np.empty((u.shape[0], len(outputs)))
    for level, columns, active in term_groups(terms, stages):
        names = [outputs[j] for j in columns]
        key = (repr([t.to_dict() for t in active]), tuple(names), u.shape[0])
        if cache is not None and key in cache:
            y[:, columns] = cache[key]
            continue
        levels_of = [level] * len(names)
        if runs_natively(active, archive.kind):
            with Progress(STEPPING, u.shape[0] - 1, progress) as bar:
                y[:, columns] = run_native(
                    archive,
                    inputs,
                    u,
                    dt,
                    names,
                    active,
                    levels_of,
                    parameters,
                    start_time,
                    substeps,
                )
                bar.update(u.shape[0] - 1)
        else:
            start = dict(zip(inputs, u[0], strict=True))
            with NamedModel(
                archive,
                inputs,
                names,
                dt,
                active,
                levels_of,
                parameters,
                start,
                start_time,
                substeps,
            ) as model:
                y[:, columns] = run_open_loop(model, u, progress)
        if cache is not None:
            while len(cache) >= CACHE_SIZE:
                cache.pop(next(iter(cache)))
            cache[key] = y[:, columns].copy()
    return y


def simulate_recording(
    fmu: str | Path | FmuArchive,
    recording: Recording,
    *,
    mapping: Mapping[str, str] | None = None,
    fixed: Mapping[str, float] | None = None,
    parameters: Mapping[str, float] | None = None,
    outputs: Sequence[str] | None = None,
    progress: bool = False,
) -> Recording:
    """Run an FMU open-loop over the inputs of a recording.

    Parameters
    ----------
    fmu : str, Path or FmuArchive
        The co-simulation FMU (opened and closed here when given as a path).
    recording : Recording
        Supplies the inputs (by name, or through ``mapping``) and the time grid; its time step
        is the communication step. A column in another unit than the FMU input it feeds
        (``mm`` for ``m``) is converted first, with a note in the log.
    mapping, fixed : mapping, optional
        See :func:`fmu_greybox.fmi.binding.bind_inputs`.
    parameters : mapping of str to float, optional
        FMU parameter values.
    outputs : sequence of str, optional
        Variables to record; default every Real output of the FMU.
    progress : bool
        Show a progress bar.

    Returns
    -------
    Recording
        The simulated outputs on the recording's time grid, with the FMU's units.
    """
    archive = fmu if isinstance(fmu, FmuArchive) else open_fmu(fmu)
    try:
        recording = recording.converted(input_units(archive, mapping))
        binding = bind_inputs(archive, recording, mapping, fixed)
        names = list(outputs) if outputs is not None else real_outputs(archive)
        y = simulate_binding(archive, binding, recording, names, parameters, progress)
    finally:
        if archive is not fmu:
            archive.close()
    return Recording(
        time=recording.time.copy(),
        signals={name: y[:, j].copy() for j, name in enumerate(names)},
        units={name: archive.variable(name).unit for name in names},
        source=f"{archive.path.name} over {recording.source}",
        metadata={"fmu": archive.path.name, "recording": recording.source},
    )


def simulate_binding(
    archive: FmuArchive,
    binding: InputBinding,
    recording: Recording,
    outputs: Sequence[str],
    parameters: Mapping[str, float] | None = None,
    progress: bool = False,
) -> np.ndarray:
    """Simulate with an already resolved input binding.

    Returns
    -------
    ndarray, shape (n_samples, len(outputs))
    """
    u = binding.matrix(recording)
    return simulate_with_terms(
        archive,
        binding.inputs,
        u,
        recording.dt,
        outputs,
        parameters=parameters,
        start_time=float(recording.time[0]),
        progress=progress,
    )
