"""A recording prepared for the chain: checked against the project, the white-box FMU run
open-loop over its inputs, arranged as the stages' targets, exogenous inputs and white-box
predictions (:class:`~fmu_greybox.project.data.ProjectData`).

Training, validation and diagnosis all start from the same arrays; this module makes them once.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence

import numpy as np

from fmu_greybox.data.noise import NoiseModel, estimate_noise_model
from fmu_greybox.data.recording import Recording
from fmu_greybox.errors import FmuError
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.fmi.binding import check_unit
from fmu_greybox.model.chain import GreyBoxChain
from fmu_greybox.model.native_run import runs_side_by_side
from fmu_greybox.model.simulate import simulate_with_terms
from fmu_greybox.model.terms import Term
from fmu_greybox.model.whitebox import DEFAULT_SUBSTEPS
from fmu_greybox.project.config import ProjectConfig
from fmu_greybox.project.data import ProjectData, bind_project_inputs, check_step


def prepare(
    config: ProjectConfig,
    chain: GreyBoxChain,
    archive: FmuArchive,
    recording: Recording,
    progress: bool = False,
    terms: Sequence[Term] = (),
    substeps: int = DEFAULT_SUBSTEPS,
) -> ProjectData:
    """Check the recording against the project and simulate the white-box over it.

    Parameters
    ----------
    config : ProjectConfig
    chain : GreyBoxChain
        Defines the exogenous inputs and stage targets.
    archive : FmuArchive
        The white-box FMU.
    recording : Recording
    progress : bool
        Show a progress bar during the simulation.
    terms : sequence of Term
        Named correction terms folded into the white-box (see
        :class:`~fmu_greybox.model.whitebox.NamedModel`); ``y_wb`` is then white-box + terms.
    substeps : int
        FMU steps per communication step while a feedback term is active.

    Returns
    -------
    ProjectData
    """
    check_step(config, recording)
    signals = config.signals
    columns = [signals[n].column for n in chain.exo_names + chain.target_signals]
    recording.require(columns, context=f"project {config.name}")
    for sig in signals.values():
        if sig.column in recording.signals and sig.variable in archive.variables:
            check_unit(archive, sig.variable, recording, sig.column)
    binding = bind_project_inputs(config, archive, recording)
    run = whitebox_run(config, chain, archive, binding.inputs, recording, terms, substeps)
    y_wb = run(binding.matrix(recording), progress=progress)
    exo = np.column_stack([recording[signals[n].column] for n in chain.exo_names])
    outputs = np.column_stack([recording[signals[n].column] for n in chain.target_signals])
    return ProjectData(recording=recording, binding=binding, exo=exo, outputs=outputs, y_wb=y_wb)


def whitebox_run(
    config: ProjectConfig,
    chain: GreyBoxChain,
    archive: FmuArchive,
    inputs: Sequence[str],
    recording: Recording,
    terms: Sequence[Term] = (),
    substeps: int = DEFAULT_SUBSTEPS,
) -> Callable[..., np.ndarray]:
    """The white-box with ``terms`` run open-loop on ``recording``'s time grid over given input
    rows: ``run(u, progress=False)``, ``u`` of shape (n, len(inputs)), returns the stage
    targets' white-box outputs, shape (n, Q) (:func:`prepare`'s ``y_wb``)."""
    return functools.partial(
        simulate_with_terms,
        archive,
        inputs,
        dt=recording.dt,
        outputs=chain.whitebox_outputs,
        terms=terms,
        parameters=config.parameters,
        stages=range(len(chain.stages)),
        start_time=float(recording.time[0]),
        substeps=substeps,
    )


def estimate_noise(
    config: ProjectConfig,
    chain: GreyBoxChain,
    archive: FmuArchive,
    data: ProjectData,
    terms: Sequence[Term] = (),
    substeps: int = DEFAULT_SUBSTEPS,
) -> NoiseModel | None:
    """The noise of a prepared recording's stage targets against the white-box with ``terms``
    (:func:`~fmu_greybox.data.noise.estimate_noise_model`: sensor noise, and the drift the
    inputs' noise drives); None if the white-box fails on the smoothed inputs."""
    run = whitebox_run(config, chain, archive, data.binding.inputs, data.recording, terms, substeps)

    def simulate(u: np.ndarray) -> np.ndarray | None:
        try:
            return run(u)
        except FmuError:
            return None

    u = data.binding.matrix(data.recording)
    side_by_side = runs_side_by_side(terms, archive)
    return estimate_noise_model(
        u, data.outputs, simulate, data.recording.dt, side_by_side=side_by_side
    )
