"""The co-simulation master: the white-box FMU and the stage correctors, stepped together.

Each communication step does what a bench does: set the FMU's inputs, ``fmi2DoStep``, read the
white-box outputs (with the model's named terms, if any: :meth:`GreyBoxModel.whitebox`), then
run the stage correctors in autoregressive order, each fed its own and the earlier stages'
corrected outputs (free run). The FMU advances by the model's communication step, as the
exported FMU does. The white-box does not see the corrected outputs, so the master steps it
through the white-box's one loop (:func:`~fmu_greybox.model.simulate.run_open_loop`) and then
the chain through its own (:meth:`~fmu_greybox.model.chain.GreyBoxChain.free_run`): the numbers
are those of stepping both together, row by row. Rows up to ``start`` only advance the FMU and
provide the chain's initial memory: from the recording by default, or from the white-box
outputs (``memory_from="whitebox"``), which is what an exported grey-box FMU does since it has
no recording.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.model.simulate import run_open_loop
from fmu_greybox.model.store import GreyBoxModel
from fmu_greybox.project.data import ProjectData

#: Where :func:`run_master` can take the chain's initial memory from.
MEMORY_SOURCES = ("recorded", "whitebox")


@dataclass
class MasterRun:
    """What the master produced over the rows it predicted.

    Attributes
    ----------
    rows : ndarray of int, shape (m,)
        Recording rows predicted (``start + 1 .. n - 1``).
    time : ndarray, shape (m,)
        Their times [s].
    whitebox : ndarray, shape (m, Q)
        White-box stage outputs (with the model's named terms, if any): what the correctors
        start from.
    mean, std : ndarray, shape (m, Q)
        Grey-box stage outputs and their calibrated standard deviations (those of the
        exported FMU's ``_std`` outputs).
    latent_std : ndarray, shape (m, Q)
        The standard deviations propagated through the chain before calibration.
    in_domain : ndarray of bool, shape (m,), or None
        The rows where the correctors stayed inside their domain (the exported FMU's
        ``out_of_domain`` false at its default threshold); ``None`` when the master that made
        the run does not say.
    """

    rows: np.ndarray
    time: np.ndarray
    whitebox: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    latent_std: np.ndarray
    in_domain: np.ndarray | None = None

    @property
    def outside(self) -> np.ndarray | None:
        """The rows where the correctors were outside their domain, shape (m,), or ``None``."""
        return None if self.in_domain is None else ~self.in_domain


def run_master(
    model: GreyBoxModel,
    data: ProjectData,
    start: int,
    progress: bool = False,
    memory_from: str = "recorded",
) -> MasterRun:
    """Step the white-box FMU and the chain over a recording, one communication step at a time.

    Parameters
    ----------
    model : GreyBoxModel
        The trained grey-box.
    data : ProjectData
        The recording arranged for the chain (its ``y_wb`` is not used: the FMU is stepped
        here).
    start : int
        Last row whose recorded outputs initialise the chain's memory.
    progress : bool
        Show a progress bar.
    memory_from : {"recorded", "whitebox"}
        Initial memory from the recorded outputs of rows ``..start`` or from the white-box
        outputs of those rows (zero residual memory: what an exported grey-box FMU does).

    Returns
    -------
    MasterRun
    """
    if memory_from not in MEMORY_SOURCES:
        raise ValueError(f"memory_from={memory_from!r} is not one of {', '.join(MEMORY_SOURCES)}")
    chain = model.chain
    u = data.binding.matrix(data.recording)
    n = u.shape[0]
    with (
        open_fmu(model.whitebox_fmu) as archive,
        model.whitebox(
            archive,
            data.binding.inputs,
            chain.whitebox_outputs,
            dict(zip(data.binding.inputs, u[0], strict=True)),
            float(data.recording.time[0]),
            instance_name="greybox_master",
        ) as fmu,
    ):
        wb = run_open_loop(fmu, u, progress)
    known = data.outputs if memory_from == "recorded" else wb
    run = chain.free_run_variances(data.exo, wb, known, start)
    rows = np.arange(start + 1, n)
    return MasterRun(
        rows=rows,
        time=data.recording.time[rows],
        whitebox=wb[rows],
        mean=run.mean,
        std=np.sqrt(run.var),
        latent_std=np.sqrt(run.latent_var),
        in_domain=run.in_domain,
    )
