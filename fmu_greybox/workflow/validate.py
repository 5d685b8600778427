"""Validate a trained grey-box on held-out data (the ``validate`` command)."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from fmu_greybox.atomic import atomic_write
from fmu_greybox.data.recording import Recording
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.model.store import GreyBoxModel
from fmu_greybox.project.config import AcceptanceConfig
from fmu_greybox.project.data import ProjectData, prepare, split_row
from fmu_greybox.report.plots import calibration_figure, frequency_figure, save_png, trace_figure
from fmu_greybox.report.spectra import FrequencyResponse, frequency_response
from fmu_greybox.workflow.acceptance import Acceptance, evaluate
from fmu_greybox.workflow.master import MasterRun, run_master
from fmu_greybox.workflow.metrics import stage_table, uncertainty_table


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
        ``named_rmse``, ``named_nrmse`` (white-box + terms, without the correctors); the
        coverage of its uncertainty (:func:`~fmu_greybox.workflow.metrics.uncertainty_table`).
    held_out : str
        Which rows were held out, in words.
    responses : list of FrequencyResponse
        Per stage, from the acceptance's input (:func:`validation_responses`) over the same
        rows.
    criteria : AcceptanceConfig
        The acceptance criteria.
    acceptance : Acceptance or None
        Those criteria checked (:mod:`fmu_greybox.workflow.acceptance`).
    """

    run: MasterRun
    data: ProjectData
    table: dict[str, dict[str, float]]
    held_out: str
    responses: list[FrequencyResponse] = field(default_factory=list)
    criteria: AcceptanceConfig = field(default_factory=AcceptanceConfig)
    acceptance: Acceptance | None = None

    @property
    def whitebox(self) -> np.ndarray:
        """The plain white-box's stage outputs over the master's rows, shape (m, Q)."""
        return self.data.y_wb[self.run.rows]


def validate_model(
    model: GreyBoxModel,
    recording: Recording,
    progress: bool = False,
    acceptance: AcceptanceConfig | None = None,
) -> Validation:
    """Free-run the grey-box over held-out rows, compare with the white-box, and check the
    acceptance criteria (``acceptance``, by default those stored with the model's project).

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
    names, recorded = model.chain.stage_names, data.outputs[run.rows]
    for name, row in uncertainty_table(names, recorded, run.mean, run.std, run.latent_std).items():
        table[name].update(row)
    criteria = acceptance if acceptance is not None else model.config.acceptance
    responses = validation_responses(model, data, run, criteria)
    return Validation(
        run=run,
        data=data,
        table=table,
        held_out=held_out,
        responses=responses,
        criteria=criteria,
        acceptance=evaluate(criteria, table, responses),
    )


def validation_responses(
    model: GreyBoxModel, data: ProjectData, run: MasterRun, criteria: AcceptanceConfig
) -> list[FrequencyResponse]:
    """Per stage, the frequency responses of recording, white-box and grey-box over the
    master's rows, from the stage's acceptance ``input`` (by default the first input of the
    first stage; no response for a stage without one)."""
    config, chain = model.config, model.chain
    units = model.training.get("target_unit", {})
    default = next(iter(config.stages[0].inputs), None)
    responses = []
    for q, (stage, output) in enumerate(zip(chain.stage_names, chain.target_signals, strict=True)):
        source = criteria.for_stage(stage).input or default
        if source is None:
            continue
        signal = config.signals[source]
        responses.append(
            frequency_response(
                data.recording[signal.column][run.rows],
                {
                    "recording": data.outputs[run.rows, q],
                    "white-box": data.y_wb[run.rows, q],
                    "grey-box": run.mean[:, q],
                },
                model.dt,
                source,
                output,
                stage=stage,
                units=(signal.unit, units.get(stage, "")),
            )
        )
    return responses


def frequency_table(validation: Validation) -> dict[str, dict]:
    """Per stage, the frequency-domain statistics of white-box and grey-box in the stage's
    acceptance band (NaN as ``None``)."""
    table = {}
    for r in validation.responses:
        band = validation.criteria.for_stage(r.stage).band
        table[r.stage] = {
            "input": r.input_name,
            "gain_unit": r.gain_unit,
            **{
                source: {
                    k: (None if isinstance(v, float) and v != v else v)
                    for k, v in asdict(r.band_statistics(source, band)).items()
                }
                for source in ("white-box", "grey-box")
            },
        }
    return table


def write_metrics(validation: Validation, model: GreyBoxModel, path: Path) -> dict:
    """Write ``metrics.json`` atomically; returns its content."""
    payload = {
        "held_out": validation.held_out,
        "n_rows": int(validation.run.rows.size),
        "units": model.training.get("target_unit", {}),
        "stages": validation.table,
        "frequency": frequency_table(validation),
        "acceptance": validation.acceptance.to_dict() if validation.acceptance else None,
    }
    with atomic_write(path, "w") as f:
        json.dump(payload, f, indent=2)
    return payload


def write_plots(validation: Validation, model: GreyBoxModel, out_dir: Path) -> list[str]:
    """Write the residual, calibration and frequency-response plots (PNG, atomically) into
    ``out_dir``; returns their file names."""
    run, names = validation.run, model.chain.stage_names
    units = [model.training.get("target_unit", {}).get(n, "") for n in names]
    recorded = validation.data.outputs[run.rows]
    figures = {
        "traces.png": trace_figure(
            run.time, recorded, validation.whitebox, run.mean, run.std, names, units
        ),
        "calibration.png": calibration_figure(recorded, run.mean, run.std, run.latent_std, names),
    }
    if validation.responses:
        bands = [validation.criteria.for_stage(r.stage).band for r in validation.responses]
        figures["frequency.png"] = frequency_figure(validation.responses, bands)
    for name, fig in figures.items():
        save_png(fig, out_dir / name)
    return list(figures)
