"""Validate a trained grey-box on held-out data (the ``validate`` command)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fmu_greybox.atomic import atomic_write
from fmu_greybox.data.recording import Recording
from fmu_greybox.errors import ConfigError, ModelFormatError, RecordingError
from fmu_greybox.evidence.plots import calibration_figure, frequency_figure, save_png, trace_figure
from fmu_greybox.evidence.spectra import FrequencyResponse, frequency_response
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.model.domain import beyond_training
from fmu_greybox.model.stage_data import prepare
from fmu_greybox.model.store import TRAINING_ROWS, GreyBoxModel
from fmu_greybox.project.config import AcceptanceConfig, ProjectConfig, check_bands
from fmu_greybox.project.data import ProjectData, check_sample_time, split_row
from fmu_greybox.project.fingerprint import (
    copy_message,
    data_rows,
    find_copy,
    recorded_rows,
    trained_mask,
)
from fmu_greybox.workflow.acceptance import Acceptance, across_recordings, evaluate
from fmu_greybox.workflow.master import MasterRun, run_master
from fmu_greybox.workflow.metrics import pooled_row, stage_table, uncertainty_table

#: Fewest rows ``validate`` scores: an error measure over fewer says little.
MIN_SCORED_ROWS = 50
#: Project tables that decide what is validated (how the recording is read and fed, the
#: stages); [gp] and [split] only steer training (``train --inducing`` overrides [gp]).
_COMPARED_TABLES = ("whitebox", "recording", "signals", "stages")
#: Fields of those tables that may differ: the recording's file, the white-box's location.
_FREE_FIELDS = (("recording", "path"), ("whitebox", "fmu"))


@dataclass
class Validation:
    """A free run on held-out data and its error table.

    Attributes
    ----------
    run : MasterRun
        The master's output over the rows after its start.
    data : ProjectData
        The recording arranged for the chain.
    table : dict
        Stage -> ``wb_rmse``, ``gb_rmse``, ``wb_nrmse``, ``gb_nrmse``, ``improvement`` (the
        grey-box against the plain white-box), and for a model with named terms
        ``named_rmse``, ``named_nrmse`` (white-box + terms, without the correctors); the
        coverage of its uncertainty (:func:`~fmu_greybox.workflow.metrics.uncertainty_table`);
        all over the scored rows; and ``calibration_rmse``, the grey-box's RMSE on the
        training rows its uncertainty was calibrated on (held-out free runs), and
        ``calibration_independent_rows``, what those rows are worth for the band
        (:func:`~fmu_greybox.model.calibration.calibration_rows`), when the model stores
        them.
    held_out : str
        Which rows were scored, in words.
    scored : ndarray of int, shape (m,)
        The rows scored: those of the run that the model was not trained on.
    responses : list of FrequencyResponse
        Per stage, from the acceptance's input (:func:`validation_responses`) over the longest
        run of consecutive scored rows.
    criteria : AcceptanceConfig
        The acceptance criteria.
    acceptance : Acceptance or None
        Those criteria checked (:mod:`fmu_greybox.workflow.acceptance`).
    """

    run: MasterRun
    data: ProjectData
    table: dict[str, dict[str, float]]
    held_out: str
    scored: np.ndarray
    responses: list[FrequencyResponse] = field(default_factory=list)
    criteria: AcceptanceConfig = field(default_factory=AcceptanceConfig)
    acceptance: Acceptance | None = None

    @property
    def whitebox(self) -> np.ndarray:
        """The plain white-box's stage outputs over the master's rows, shape (m, Q)."""
        return self.data.y_wb[self.run.rows]

    @property
    def rows_out_of_domain(self) -> int | None:
        """Scored rows on which the correctors were outside their domain (``None``: the
        master that made the run does not say)."""
        return rows_outside(self.run, self.scored)


def rows_outside(run: MasterRun, scored: np.ndarray) -> int | None:
    """How many of the ``scored`` rows (recording rows, shape (k,)) the run was outside its
    correctors' domain on; ``None`` when the run does not say."""
    return None if run.outside is None else int(run.outside[scored - run.rows[0]].sum())


def check_project(config: ProjectConfig, model: GreyBoxModel, model_dir: str | Path) -> None:
    """The project given to ``validate`` must read and feed recordings as the project the model
    was trained with did.

    Compared: the [whitebox], [recording], [signals] and [stages] tables, but for the
    recording's path and the white-box's location (the model carries its white-box FMU).

    Raises
    ------
    ConfigError
        Naming the first field that differs, with both values.
    """
    given, trained = _comparable(config), _comparable(model.config)
    difference = _first_difference(given, trained, "")
    if difference is not None:
        field, here, there = difference
        raise ConfigError(
            f"{_shown(here)} here but {_shown(there)} in the project {model_dir} was trained "
            f"with; validate with the project the model was trained with (it is stored in "
            f"{Path(model_dir) / 'model.json'}, under 'project') or retrain",
            field=field,
            path=str(config.path) if config.path else None,
        )


def validate_model(
    model: GreyBoxModel,
    recording: Recording,
    progress: bool = False,
    acceptance: AcceptanceConfig | None = None,
) -> Validation:
    """Free-run the grey-box over a recording, score the rows it was not trained on and check
    the acceptance criteria (``acceptance``, by default those stored with the model's project).

    Training rows are recognised by their values (:mod:`fmu_greybox.project.fingerprint`), in
    any file. The chain's memory starts from the recorded outputs at the end of a leading run
    of training rows (the training recording's split), else at the first row; training rows
    later in the recording are run through but not scored. ``data.y_wb`` is the plain
    white-box; ``run.whitebox`` what the correctors start from (the same, or white-box + the
    model's named terms).

    Raises
    ------
    RecordingError
        A sample time other than the model's step, or fewer than :data:`MIN_SCORED_ROWS`
        rows that were not used in training.

    Returns
    -------
    Validation
    """
    check_sample_time(recording, model.dt, "the model (the step it was trained at)")
    criteria = acceptance if acceptance is not None else model.config.acceptance
    check_bands(criteria, model.dt, model.config.path)
    with open_fmu(model.whitebox_fmu) as archive:
        data = prepare(model.config, model.chain, archive, recording, progress)
    trained, older = _trained(model, data)
    leading = int(np.argmin(trained)) if not trained.all() else trained.size
    start = max(0, leading - 1)
    unseen = int((~trained[start + 1 :]).sum())
    if unseen < MIN_SCORED_ROWS:
        raise RecordingError(
            f"only {unseen} of its {data.n_samples} rows were not used in training or in "
            "calibrating σ (such rows are recognised by their values); validation needs at "
            f"least {MIN_SCORED_ROWS}."
            " Validate on held-out data: the tail of the training recording after its "
            "train_fraction, or another recording",
            path=recording.source,
        )
    run = run_master(model, data, start, progress)
    keep = ~trained[run.rows]
    table = stage_table(
        model.chain.stage_names,
        data.outputs[run.rows][keep],
        data.y_wb[run.rows][keep],  # the plain white-box (prepare folds no terms)
        run.mean[keep],
        model.target_std,
        named=run.whitebox[keep] if model.terms else None,
    )
    scored = run.rows[keep]
    skipped = int(trained[run.rows].sum())
    held_out = f"{scored.size} rows not used in training ({_ranges_text(scored)})"
    outside = rows_outside(run, scored)
    beyond = beyond_training(
        model.training.input_ranges,
        data.binding.inputs,
        data.binding.matrix(data.recording)[scored],
    )
    if outside:
        held_out += (
            f"; on {outside} of them the correctors were outside their domain (where the "
            "exported FMU sets out_of_domain at its default threshold, and the correctors fade "
            "out)"
        )
    if beyond:
        held_out += f"; inputs beyond the training recording's: {beyond}"
    if skipped:
        held_out += f"; {skipped} training rows in the run not scored"
    held_out += older
    names, recorded = model.chain.stage_names, data.outputs[run.rows][keep]
    uncertainty = uncertainty_table(
        names, recorded, run.mean[keep], run.std[keep], run.latent_std[keep]
    )
    for name, row in uncertainty.items():
        table[name].update(row)
    # the error the band was calibrated on (models trained before it was stored say nothing)
    for name, check in model.training.calibration_check.items():
        table[name]["calibration_rmse"] = check["rmse"]
        if "independent_rows" in check:  # kept since 2026-11-27
            table[name]["calibration_independent_rows"] = check["independent_rows"]
        if "source" in check:  # kept since 2026-11-27 (train --calibrate-on)
            recordings = check["free_runs"] if check["source"] == "recordings" else 0
            table[name]["calibration_recordings"] = recordings
        shares = [s for s in check.get("free_run_shares", []) if s == s]  # kept since 2026-11-27
        if shares:
            table[name]["calibration_share_low"] = min(shares)
            table[name]["calibration_share_high"] = max(shares)
    responses = validation_responses(model, data, run, scored, criteria)
    return Validation(
        run=run,
        data=data,
        table=table,
        held_out=held_out,
        scored=scored,
        responses=responses,
        criteria=criteria,
        acceptance=evaluate(criteria, table, responses, (outside or 0) / scored.size, beyond),
    )


@dataclass
class PooledValidation:
    """Several held-out recordings validated together (``validate`` given more than one).

    Attributes
    ----------
    validations : dict
        Recording name -> its :class:`Validation`, in the order given.
    pooled : dict
        Stage -> its shares inside ±1σ and ±1.96σ pooled over the recordings by what their rows
        are worth (:func:`~fmu_greybox.workflow.metrics.pooled_row`).
    acceptance : Acceptance
        The criteria over all of them (:func:`~fmu_greybox.workflow.acceptance.across_recordings`:
        coverage on the pooled shares, every other criterion on each recording).
    """

    validations: dict[str, Validation]
    pooled: dict[str, dict[str, float]]
    acceptance: Acceptance


def validate_recordings(
    model: GreyBoxModel,
    recordings: Mapping[str, Recording],
    progress: bool = False,
    acceptance: AcceptanceConfig | None = None,
) -> PooledValidation:
    """:func:`validate_model` on each recording, and the acceptance over all of them.

    Parameters
    ----------
    model : GreyBoxModel
    recordings : mapping
        Name (as the outputs will show it) -> recording; at least one.
    progress : bool
    acceptance : AcceptanceConfig, optional
        By default those stored with the model's project.

    Raises
    ------
    RecordingError
        A recording given twice, or a copy of another (also rounded, or with other time
        stamps: :func:`~fmu_greybox.project.fingerprint.find_copy`), naming both.

    Returns
    -------
    PooledValidation
    """
    found = find_copy(recorded_rows(list(recordings.values())))
    if found is not None:
        raise RecordingError(
            f"{copy_message(*found)}: validating on it again would narrow the coverage "
            "interval with no new evidence. Give each recording once"
        )
    criteria = acceptance if acceptance is not None else model.config.acceptance
    validations = {
        name: validate_model(model, recording, progress, criteria)
        for name, recording in recordings.items()
    }
    stages = model.chain.stage_names
    counts = [v.scored.size for v in validations.values()]
    pooled = {s: pooled_row([v.table[s] for v in validations.values()], counts) for s in stages}
    scored = sum(counts)
    outside = sum(v.rows_out_of_domain or 0 for v in validations.values()) / scored
    checked = {name: v.acceptance for name, v in validations.items() if v.acceptance}
    return PooledValidation(
        validations, pooled, across_recordings(criteria, checked, pooled, outside)
    )


def write_pooled_metrics(result: PooledValidation, path: Path) -> dict:
    """Write the ``metrics.json`` of several recordings atomically: per recording its file, its
    name (the folder of its own ``metrics.json`` beside this one), held-out rows and verdict;
    the pooled shares; the acceptance over all. Returns its content."""
    recordings = [
        {
            "recording": v.data.recording.source,
            "folder": name,
            "held_out": v.held_out,
            "n_rows": int(v.scored.size),
            "rows_out_of_domain": v.rows_out_of_domain,
            "verdict": v.acceptance.verdict if v.acceptance else None,
        }
        for name, v in result.validations.items()
    ]
    payload = {
        "recordings": recordings,
        "pooled": result.pooled,
        "acceptance": result.acceptance.to_dict(),
    }
    with atomic_write(path, "w") as f:
        json.dump(payload, f, indent=2)
    return payload


def validation_responses(
    model: GreyBoxModel,
    data: ProjectData,
    run: MasterRun,
    scored: np.ndarray,
    criteria: AcceptanceConfig,
) -> list[FrequencyResponse]:
    """Per stage, the frequency responses of recording, white-box and grey-box over the
    longest run of consecutive scored rows (a spectrum needs evenly spaced samples), from the
    stage's acceptance ``input`` (by default the first input of the first stage; no response
    for a stage without one)."""
    config, chain = model.config, model.chain
    units = model.training.target_unit
    default = next(iter(config.stages[0].inputs), None)
    first, last = max(_ranges(scored), key=lambda r: r[1] - r[0])
    rows = np.arange(first, last + 1)
    in_run = rows - run.rows[0]
    responses = []
    for q, (stage, output) in enumerate(zip(chain.stage_names, chain.target_signals, strict=True)):
        source = criteria.for_stage(stage).input or default
        if source is None:
            continue
        signal = config.signals[source]
        responses.append(
            frequency_response(
                data.recording[signal.column][rows],
                {
                    "recording": data.outputs[rows, q],
                    "white-box": data.y_wb[rows, q],
                    "grey-box": run.mean[in_run, q],
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
    """Write ``metrics.json`` atomically (``scored_rows``: the scored rows as ``[first, last]``
    ranges, both included; ``model``: what the model is and computes on each stage, in words;
    ``parts``: for a model trained with named terms, the comparison of its parts made at
    training, :mod:`fmu_greybox.workflow.parts`); returns its content."""
    payload = {
        "model": {"kind": model.kind, "stages": model.contents()},
        "held_out": validation.held_out,
        "n_rows": int(validation.scored.size),
        "rows_out_of_domain": validation.rows_out_of_domain,
        "scored_rows": _ranges(validation.scored),
        "units": model.training.target_unit,
        "stages": validation.table,
        "frequency": frequency_table(validation),
        "acceptance": validation.acceptance.to_dict() if validation.acceptance else None,
    }
    if model.training.parts is not None:  # train --terms: its comparison on the held-out rows
        payload["parts"] = model.training.parts
    with atomic_write(path, "w") as f:
        json.dump(payload, f, indent=2)
    return payload


def write_plots(validation: Validation, model: GreyBoxModel, out_dir: Path) -> list[str]:
    """Write the residual, calibration and frequency-response plots (PNG, atomically) into
    ``out_dir``; returns their file names."""
    run, names = validation.run, model.chain.stage_names
    units = [model.training.target_unit.get(n, "") for n in names]
    recorded = validation.data.outputs[run.rows]
    keep = validation.scored - run.rows[0]
    figures = {
        "traces.png": trace_figure(
            run.time,
            recorded,
            validation.whitebox,
            run.mean,
            run.std,
            names,
            units,
            outside=run.outside,
            model_label=model.kind,
        ),
        "calibration.png": calibration_figure(
            recorded[keep], run.mean[keep], run.std[keep], run.latent_std[keep], names
        ),
    }
    if validation.responses:
        bands = [validation.criteria.for_stage(r.stage).band for r in validation.responses]
        figures["frequency.png"] = frequency_figure(validation.responses, bands, model.kind)
    for name, fig in figures.items():
        save_png(fig, out_dir / name)
    return list(figures)


#: Relative difference under which a recording's leading rows have the training rows' spread.
_SAME_SPREAD = 1e-6


def _trained(model: GreyBoxModel, data: ProjectData) -> tuple[np.ndarray, str]:
    """Which rows the model was trained on, shape (n,), and a note for the held-out line.

    A model folder of format version 5 or later recognises training rows at the recording's
    resolution anywhere. An older one recognises them bit for bit (versions 3 and 4) or not
    at all (1 and 2), and besides takes the leading training rows of a recording for its
    training rows when they have the training's spread in every stage
    (:func:`_has_training_spread`: the training recording, or a rounded copy of it); the note
    says so.
    """
    values = data_rows(data)
    fingerprint = model.trained_rows
    trained = np.zeros(data.n_samples, dtype=bool)
    if fingerprint is not None:
        if fingerprint.scale is not None and fingerprint.scale.size != values.shape[1]:
            raise ModelFormatError(
                f"{model.whitebox_fmu.parent / TRAINING_ROWS}: its scale has "
                f"{fingerprint.scale.size} columns, the project's rows {values.shape[1]}; "
                "retrain the model"
            )
        trained = trained_mask(values, fingerprint)
    if fingerprint is not None and fingerprint.scale is not None:
        return trained, ""
    train_rows = model.training.train_rows
    if train_rows is None:
        train_rows = split_row(model.config, data.n_samples) + 1
    train_rows = int(train_rows)
    if data.recording.sha256() == model.training.recording_sha256 or _has_training_spread(
        model, data, train_rows
    ):
        trained[:train_rows] = True
    how = "bit for bit" if fingerprint is not None else "in its training recording only"
    return trained, (
        f"; this model folder is of an older format: it recognises training rows {how}, and "
        "a recording whose first rows have its training rows' spread as its training "
        "recording (a copy elsewhere in a file, or rounded and reordered, is scored); retrain "
        "it to recognise training rows at the recording's resolution"
    )


def _has_training_spread(model: GreyBoxModel, data: ProjectData, train_rows: int) -> bool:
    """Whether the first ``train_rows`` rows have the training targets' standard deviation in
    every stage (within :data:`_SAME_SPREAD`), as the training recording and its copies do."""
    spread = model.training.target_std
    if data.n_samples < train_rows or not spread:
        return False
    return all(
        abs(float(np.std(data.outputs[:train_rows, q])) - spread[name])
        <= _SAME_SPREAD * max(abs(spread[name]), np.finfo(float).tiny)
        for q, name in enumerate(model.chain.stage_names)
    )


def _ranges(rows: np.ndarray) -> list[list[int]]:
    """Sorted row indices as ``[first, last]`` runs of consecutive rows."""
    if rows.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(rows) != 1)
    firsts = np.concatenate([[rows[0]], rows[breaks + 1]])
    lasts = np.concatenate([rows[breaks], [rows[-1]]])
    return [[int(a), int(b)] for a, b in zip(firsts, lasts, strict=True)]


def _ranges_text(rows: np.ndarray, limit: int = 4) -> str:
    runs = [f"{a}..{b}" if a != b else f"{a}" for a, b in _ranges(rows)]
    more = f" and {len(runs) - limit} more runs" if len(runs) > limit else ""
    return "rows " + ", ".join(runs[:limit]) + more


def _comparable(config: ProjectConfig) -> dict[str, Any]:
    """The project's tables that must match, without the fields that may differ."""
    tables = {k: v for k, v in config.to_dict().items() if k in _COMPARED_TABLES}
    for table, key in _FREE_FIELDS:
        tables.get(table, {}).pop(key, None)
    return tables


def _first_difference(a: Any, b: Any, where: str) -> tuple[str, Any, Any] | None:
    """The dotted field where two TOML-like values first differ, with both values."""
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        for key in [*a, *(k for k in b if k not in a)]:
            found = _first_difference(a.get(key), b.get(key), f"{where}.{key}" if where else key)
            if found is not None:
                return found
        return None
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            found = _first_difference(x, y, f"{where}[{i}]")
            if found is not None:
                return found
        return None
    return None if a == b else (where, a, b)


def _shown(value: Any) -> str:
    return "(not set)" if value is None else repr(value)
