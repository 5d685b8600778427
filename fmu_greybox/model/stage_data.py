"""A recording prepared for the chain: checked against the project, the white-box FMU run
open-loop over its inputs, arranged as the stages' targets, exogenous inputs and white-box
predictions (:class:`~fmu_greybox.project.data.ProjectData`).

Training, validation and diagnosis all start from the same arrays; this module makes them once.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from fmu_greybox.data.recording import Recording
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.fmi.binding import check_unit
from fmu_greybox.model.chain import GreyBoxChain
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
    y_wb = simulate_with_terms(
        archive,
        binding.inputs,
        binding.matrix(recording),
        recording.dt,
        chain.whitebox_outputs,
        terms,
        config.parameters,
        stages=range(len(chain.stages)),
        start_time=float(recording.time[0]),
        substeps=substeps,
        progress=progress,
    )
    exo = np.column_stack([recording[signals[n].column] for n in chain.exo_names])
    outputs = np.column_stack([recording[signals[n].column] for n in chain.target_signals])
    return ProjectData(recording=recording, binding=binding, exo=exo, outputs=outputs, y_wb=y_wb)
