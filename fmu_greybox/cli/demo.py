"""The demo command: the main job on the built-in default, reference actuator and synthetic
recording."""

from __future__ import annotations

import json
import time
from pathlib import Path

import click

from fmu_greybox.cli.options import (
    inducing_option,
    info,
    max_iter_option,
    out_option,
    truth_options,
)


@click.command()
@out_option("out", "Folder for everything produced (report.html first)", folder=True)
@truth_options("Concealed truth effect (repeatable; default: one drawn by --seed).")
@click.option(
    "--duration",
    type=click.FloatRange(min=5.0),
    default=30.0,
    show_default=True,
    help="Length of the training recording [s].",
)
@click.option(
    "--validation-duration",
    type=click.FloatRange(min=4.2),
    default=8.0,
    show_default=True,
    help="Length of the independent validation recording [s].",
)
@inducing_option(150)
@max_iter_option(100)
@click.option("--json", "as_json", is_flag=True, help="Print the summary as one JSON line.")
@click.pass_context
def demo(
    ctx: click.Context,
    out_dir: Path,
    effects: tuple[str, ...],
    seed: int,
    duration: float,
    validation_duration: float,
    inducing: int,
    max_iter: int,
    as_json: bool,
) -> None:
    """The main job on the built-in default: reference actuator, synthetic recording.

    Builds the reference FMUs, records the truth actuator with a concealed effect, diagnoses
    the recording, trains and validates the grey-box, exports it as an FMU, runs it on an SSP
    bench in fmpy and libcosim, and writes OUT/report.html, OUT/diagnosis.json, OUT/summary.json
    and OUT/greybox.fmu.

    \b
    Examples:
      fmu-greybox demo
      fmu-greybox demo --effect internal_leakage=1e-12 --seed 4 --out leak/
    """
    from fmu_greybox.report.demo import DemoSettings, run_demo
    from fmu_greybox.report.main import verdict_lines, write_report
    from fmu_greybox.synth import actuator as synth_mod

    quiet = ctx.obj["quiet"] or as_json
    settings = DemoSettings(
        out_dir=out_dir,
        effects=synth_mod.parse_effects(effects) if effects else None,
        seed=seed,
        duration=duration,
        validation_duration=validation_duration,
        inducing=inducing,
        max_iter=max_iter,
    )
    started = time.perf_counter()
    result = run_demo(
        settings,
        log=None if quiet else (lambda message: click.echo(message, err=True)),
        progress=not quiet,
    )
    outcome = write_report(result)
    outcome["seconds"] = round(time.perf_counter() - started, 1)
    if as_json:
        click.echo(json.dumps(outcome, default=float))
        return
    click.echo("")
    for line in verdict_lines(result):
        click.echo(line)
    info(ctx, f"report: {out_dir / 'report.html'} ({outcome['seconds']} s)")
