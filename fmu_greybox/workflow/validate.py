"""Validate a trained grey-box on held-out data (the ``validate`` command)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fmu_greybox.atomic import atomic_write
from fmu_greybox.data.recording import Recording
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.model.store import GreyBoxModel
from fmu_greybox.project.data import ProjectData, prepare, split_row
from fmu_greybox.workflow.master import MasterRun, run_master
from fmu_greybox.workflow.metrics import stage_table


@dataclass
class Validation:
    """A free run on held-out data and its error table.

    Attributes
    ----------
    run : MasterRun
        The master's output over the held-out rows.
    data : ProjectData
        The recording arranged for the chain.
    table : dict
        Stage -> ``wb_rmse``, ``gb_rmse``, ``wb_nrmse``, ``gb_nrmse``, ``improvement`` (the
        grey-box against the plain white-box), and for a model with named terms
        ``named_rmse``, ``named_nrmse`` (white-box + terms, without the correctors).
    held_out : str
        Which rows were held out, in words.
    """

    run: MasterRun
    data: ProjectData
    table: dict[str, dict[str, float]]
    held_out: str

    @property
    def whitebox(self) -> np.ndarray:
        """The plain white-box's stage outputs over the master's rows, shape (m, Q)."""
        return self.data.y_wb[self.run.rows]


def validate_model(model: GreyBoxModel, recording: Recording, progress: bool = False) -> Validation:
    """Free-run the grey-box over held-out rows and compare with the white-box.

    ``data.y_wb`` is the plain white-box; ``run.whitebox`` what the correctors start from (the
    same, or white-box + the model's named terms).

    On the training recording the held-out rows are those after the training split; on any
    other recording, every row after the first.

    Returns
    -------
    Validation
    """
    with open_fmu(model.whitebox_fmu) as archive:
        data = prepare(model.config, model.chain, archive, recording, progress)
    if recording.sha256() == model.training.get("recording_sha256"):
        start = split_row(model.config, data.n_samples)
        held_out = f"rows {start + 1}..{data.n_samples - 1} of the training recording"
    else:
        start = 0
        held_out = f"all {data.n_samples - 1} rows of a recording not used in training"
    run = run_master(model, data, start, progress)
    table = stage_table(
        model.chain.stage_names,
        data.outputs[run.rows],
        data.y_wb[run.rows],  # the plain white-box (prepare folds no terms)
        run.mean,
        model.target_std,
        named=run.whitebox if model.terms else None,
    )
    return Validation(run=run, data=data, table=table, held_out=held_out)


def write_metrics(validation: Validation, model: GreyBoxModel, path: Path) -> None:
    """Write ``metrics.json`` atomically."""
    payload = {
        "held_out": validation.held_out,
        "n_rows": int(validation.run.rows.size),
        "units": model.training.get("target_unit", {}),
        "stages": validation.table,
    }
    with atomic_write(path, "w") as f:
        json.dump(payload, f, indent=2)
