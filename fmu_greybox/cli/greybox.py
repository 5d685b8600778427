"""The commands on the grey-box: train its correctors, validate it on held-out recordings."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import click

from fmu_greybox.cli.options import (
    EXIT_NOT_ACCEPTED,
    inducing_option,
    info,
    max_iter_option,
    out_option,
    recording_option,
)

if TYPE_CHECKING:  # the commands import what they use when they run (a fast --help)
    from fmu_greybox.data.recording import Recording
    from fmu_greybox.model.store import GreyBoxModel
    from fmu_greybox.project.config import ProjectConfig
    from fmu_greybox.workflow.validate import Validation

#: ``train --ship`` (fmu_greybox.workflow.parts.SHIP_CHOICES, not imported: it needs numpy).
SHIP_CHOICES = ("best", "correctors", "terms", "terms+correctors")


@click.command()
@click.argument("config_path", metavar="CONFIG", type=click.Path(dir_okay=False, path_type=Path))
@recording_option("train on")
@inducing_option(None)
@max_iter_option(None)
@click.option(
    "--terms",
    "terms_path",
    type=click.Path(dir_okay=False, path_type=Path),
    help="diagnosis.json of 'diagnose': fold its named terms into the white-box first; the "
    "correctors learn what remains and the model (and its exported FMU) carries the terms.",
)
@click.option(
    "--ship",
    type=click.Choice(SHIP_CHOICES),
    default="best",
    show_default=True,
    help="With --terms: the model to write. Correctors on the plain white-box, the named terms "
    "alone and correctors on the terms are compared on the held-out rows; 'best' writes the "
    "best of them.",
)
@click.option(
    "--calibrate-on",
    "calibration_paths",
    type=click.Path(dir_okay=False, path_type=Path),
    multiple=True,
    help="Recording to calibrate the uncertainty (σ) on, free-run whole by the model that "
    "ships; repeatable. Default: the two halves of the training rows, each free-run by "
    "correctors trained on the other. Every recording is one more free run: a drifting "
    "stage's σ rests on a few independent rows per free run. Their rows are not scored by "
    "'validate'.",
)
@out_option("model", "Model folder to write", folder=True)
@click.pass_context
def train(
    ctx: click.Context,
    config_path: Path,
    recording_path: Path | None,
    inducing: int | None,
    max_iter: int | None,
    terms_path: Path | None,
    ship: str,
    calibration_paths: tuple[Path, ...],
    out_dir: Path,
) -> None:
    """Train the stage correctors of a project (teacher forcing).

    The --out folder is locked while training: a second run into it is refused.

    \b
    Examples:
      fmu-greybox train builtin:hydraulic_actuator --recording rec.csv --out model/
      fmu-greybox train builtin:hydraulic_actuator --recording rec.csv \\
          --terms diag/diagnosis.json --out model/
      fmu-greybox train builtin:hydraulic_actuator --recording rec.csv \\
          --calibrate-on run2.csv --calibrate-on run3.csv --out model/
    """
    from fmu_greybox.atomic import output_lock
    from fmu_greybox.model.store import save_model
    from fmu_greybox.model.whitebox import read_terms
    from fmu_greybox.project.config import load_config
    from fmu_greybox.project.data import load_project_recording
    from fmu_greybox.workflow.parts import TRAINING_PARTS, parts_text
    from fmu_greybox.workflow.train import train_model, with_inducing

    config = with_inducing(load_config(config_path), inducing, max_iter)
    with output_lock(out_dir, "--out"):
        recording = load_project_recording(config, recording_path)
        terms = read_terms(terms_path) if terms_path is not None else []
        calibration = [load_project_recording(config, path) for path in calibration_paths]
        model = train_model(
            config,
            recording,
            progress=not ctx.obj["quiet"],
            terms=terms,
            ship=ship,
            calibration_recordings=calibration,
        )
        save_model(model, out_dir)
    named = f", named terms: {', '.join(t.effect for t in model.terms)}" if model.terms else ""
    if model.training.parts is not None:
        info(ctx, f"{TRAINING_PARTS}: {parts_text(model.training.parts)}.")
    info(
        ctx,
        f"wrote {out_dir} ({len(model.chain.stages)} stages, "
        f"{model.training.train_rows} training rows, {model.training.seconds} s{named})",
    )


@click.command()
@click.argument("config_path", metavar="CONFIG", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--model",
    "model_dir",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Model folder written by 'train'.",
)
@recording_option(
    "validate on",
    " Repeatable: each recording's results go to a numbered subfolder, and the coverage "
    "criteria are checked on the shares pooled over all of them.",
)
@out_option("validation", "Folder for report.html, metrics.json and the plots", folder=True)
@click.option("--json", "as_json", is_flag=True, help="Print metrics as one JSON line.")
@click.option(
    "--strict",
    is_flag=True,
    help=f"Exit with code {EXIT_NOT_ACCEPTED} unless every acceptance criterion passes.",
)
@click.pass_context
def validate(
    ctx: click.Context,
    config_path: Path,
    model_dir: Path,
    recording_paths: tuple[Path, ...],
    out_dir: Path,
    as_json: bool,
    strict: bool,
) -> None:
    """Free-run the grey-box on held-out data, check the acceptance criteria; write
    report.html, metrics.json and plots.

    The criteria are the project file's [acceptance] table (docs/config.md); the result,
    PASS, FAIL or UNDECIDED per stage and criterion, is printed and stored in metrics.json.

    CONFIG must be the project the model was trained with. Rows the model was trained on are
    recognised by their values, in any recording, and are not scored; metrics.json lists the
    rows scored (scored_rows).

    Several --recording: a drifting stage's recording is worth few independent rows, too few
    to decide whether its band holds; the coverage criteria are checked on the shares of all
    the recordings pooled, every other criterion on each recording.

    \b
    Example:
      fmu-greybox validate builtin:hydraulic_actuator --model model/ \\
          --recording rec.csv --out validation/ --strict
    """
    from fmu_greybox.model.store import load_model
    from fmu_greybox.project.config import load_config
    from fmu_greybox.project.data import load_project_recording
    from fmu_greybox.workflow.validate import check_project

    config = load_config(config_path)
    model = load_model(model_dir)
    check_project(config, model, model_dir)
    recordings = [load_project_recording(config, p) for p in recording_paths or (None,)]
    progress = not (ctx.obj["quiet"] or as_json)
    where = (model_dir, out_dir)
    if len(recordings) == 1:
        verdict = _validate_one(ctx, model, config, recordings[0], where, as_json, progress)
    else:
        folders = [f"{i}-{Path(r.source or 'recording').stem}" for i, r in enumerate(recordings, 1)]
        named = dict(zip(folders, recordings, strict=True))
        verdict = _validate_several(ctx, model, config, named, where, as_json, progress)
    if strict and verdict != "PASS":
        ctx.exit(EXIT_NOT_ACCEPTED)


def _validate_one(
    ctx: click.Context,
    model: GreyBoxModel,
    config: ProjectConfig,
    recording: Recording,
    where: tuple[Path, Path],
    as_json: bool,
    progress: bool,
) -> str | None:
    """Validate on one recording, write its outputs into ``where``'s output folder (the model
    folder first); the verdict."""
    from fmu_greybox.report.provenance import command_line
    from fmu_greybox.workflow.validate import validate_model

    model_dir, out_dir = where
    result = validate_model(model, recording, progress=progress, acceptance=config.acceptance)
    metrics, files = _write_validation(result, model, config, model_dir, out_dir, command_line())
    if as_json:
        click.echo(json.dumps(metrics))
    else:
        _print_validation(ctx, model, result)
        info(ctx, f"wrote {', '.join(str(out_dir / name) for name in files)}")
    return result.acceptance.verdict if result.acceptance is not None else None


def _validate_several(
    ctx: click.Context,
    model: GreyBoxModel,
    config: ProjectConfig,
    recordings: dict[str, Recording],
    where: tuple[Path, Path],
    as_json: bool,
    progress: bool,
) -> str:
    """Validate on each recording (its outputs in ``<output folder>/<name>``), pool the
    coverage and write the output folder's ``metrics.json`` and ``report.html``; the verdict
    over all."""
    from fmu_greybox.evidence.html import write_page
    from fmu_greybox.evidence.render import rendering_aside
    from fmu_greybox.report.provenance import command_line
    from fmu_greybox.report.validation import REPORT, pooled_report_html
    from fmu_greybox.workflow.metrics import coverage_text, error_ratio
    from fmu_greybox.workflow.validate import validate_recordings, write_pooled_metrics

    model_dir, out_dir = where
    command = command_line()
    result = validate_recordings(model, recordings, progress, config.acceptance)
    for name, validation in result.validations.items():
        _write_validation(validation, model, config, model_dir, out_dir / name, command)
    metrics = write_pooled_metrics(result, out_dir / "metrics.json")
    with rendering_aside():
        text = pooled_report_html(result, config, model_dir, command)
    write_page(text, out_dir / REPORT)
    if as_json:
        click.echo(json.dumps(metrics))
        return result.acceptance.verdict
    for name, validation in result.validations.items():
        click.echo(f"{name} ({recordings[name].source}):")
        _print_validation(ctx, model, validation)
    click.echo(f"pooled over the {len(recordings)} recordings:")
    for stage, row in result.pooled.items():
        k = error_ratio(row)
        click.echo(
            f"  {stage} inside ±1σ / ±1.96σ: {coverage_text(row, 'coverage68')} / "
            f"{coverage_text(row, 'coverage95')} ({row['independent_rows']:.0f} independent rows"
            + (f"; RMSE {k:.3g} times the calibration's" if k is not None else "")
            + ")"
        )
    click.echo(result.acceptance.summary())
    info(
        ctx,
        f"wrote {out_dir / 'metrics.json'}, {out_dir / REPORT} and a folder per recording in "
        f"{out_dir}",
    )
    return result.acceptance.verdict


def _write_validation(
    result: Validation,
    model: GreyBoxModel,
    config: ProjectConfig,
    model_dir: Path,
    folder: Path,
    command: str,
) -> tuple[dict, list[str]]:
    """Write one recording's validation into ``folder``: ``metrics.json``, the plots and
    ``report.html``, each atomically, the page last. Returns the metrics and the files' names."""
    from fmu_greybox.evidence.html import write_page
    from fmu_greybox.evidence.render import rendering_aside
    from fmu_greybox.report.validation import REPORT, validation_report_html
    from fmu_greybox.workflow.validate import write_metrics, write_plots

    folder.mkdir(parents=True, exist_ok=True)
    metrics = write_metrics(result, model, folder / "metrics.json")
    plots = write_plots(result, model, folder)
    with rendering_aside():
        text = validation_report_html(result, model, config, model_dir, command)
    write_page(text, folder / REPORT)
    return metrics, ["metrics.json", *plots, REPORT]


def _print_validation(ctx: click.Context, model: GreyBoxModel, result: Validation) -> None:
    """A validation's held-out rows, table, passed-through stages and acceptance, as text."""
    from fmu_greybox.workflow.metrics import format_table
    from fmu_greybox.workflow.parts import passed_through_text

    info(ctx, f"held out: {result.held_out}")
    click.echo(format_table(result.table, model.training.target_unit, model.contents()))
    passed = model.chain.passed_through
    if passed:
        info(ctx, f"passed through: {passed_through_text(model.training.parts or {}, passed)}")
    if result.acceptance is not None:
        click.echo(result.acceptance.summary())
