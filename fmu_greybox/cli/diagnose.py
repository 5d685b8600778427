"""The commands that diagnose: one recording, or many on a Dask cluster with the trend of
each named effect."""

from __future__ import annotations

import json
from pathlib import Path

import click

from fmu_greybox.cli.options import info, out_option, recording_option
from fmu_greybox.errors import FmuGreyboxError


@click.command()
@click.argument("config_path", metavar="CONFIG", type=click.Path(dir_okay=False, path_type=Path))
@recording_option("diagnose")
@out_option("diagnosis", "Folder for diagnosis.json and report.html", folder=True)
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    default=2,
    show_default=True,
    help="Simulation worker processes.",
)
@click.option(
    "--scheduler",
    metavar="ADDRESS",
    default=None,
    help="Run the hypothesis simulations on this Dask cluster (tcp://host:port) instead of "
    "--workers local processes.",
)
@click.option(
    "--no-greybox", is_flag=True, help="Skip training the grey-box on top of the named terms."
)
@click.option("--json", "as_json", is_flag=True, help="Print diagnosis.json's verdict as JSON.")
@click.pass_context
def diagnose(
    ctx: click.Context,
    config_path: Path,
    recording_path: Path | None,
    out_dir: Path,
    workers: int,
    scheduler: str | None,
    no_greybox: bool,
    as_json: bool,
) -> None:
    """Locate where the white-box departs from a recording, name the physics it left out,
    model it and show the fit improve.

    \b
    Examples:
      fmu-greybox synth --effect coulomb_friction=600 --duration 25 --out rec.csv
      fmu-greybox diagnose builtin:hydraulic_actuator --recording rec.csv --out diag/
      fmu-greybox diagnose builtin:hydraulic_actuator --recording rec.csv \\
          --scheduler tcp://127.0.0.1:8786 --out diag/
    """
    from contextlib import nullcontext

    from fmu_greybox.diagnosis import Diagnosis, GreyBoxSettings, write_outputs
    from fmu_greybox.project.config import load_config
    from fmu_greybox.project.data import load_project_recording

    quiet = ctx.obj["quiet"] or as_json
    config = load_config(config_path)
    recording = load_project_recording(config, recording_path)
    if scheduler is not None:
        from fmu_greybox.campaign.cluster import DaskSimulations, connect

        connection = connect(scheduler)
    else:
        connection = nullcontext()
    with connection as client:
        diagnosis = Diagnosis(
            config,
            workers=workers,
            greybox=None if no_greybox else GreyBoxSettings(),
            progress=None if quiet else (lambda message: click.echo(f"... {message}", err=True)),
            cluster=None if client is None else DaskSimulations(client),
        ).fit(recording)
    payload = write_outputs(diagnosis, recording, out_dir)
    if as_json:
        keys = ("origin_stage", "findings", "fit", "verdict")
        click.echo(json.dumps({k: payload[k] for k in keys}, default=float))
        return
    for line in payload["verdict"]:
        click.echo(line)
    info(
        ctx,
        f"wrote {out_dir / 'diagnosis.json'} and {out_dir / 'report.html'} "
        f"({payload['timings']['total']} s)",
    )


@click.command()
@click.argument("config_path", metavar="CONFIG", type=click.Path(dir_okay=False, path_type=Path))
@click.argument(
    "recordings", metavar="RECORDING...", nargs=-1, required=True, type=click.Path(path_type=Path)
)
@out_option(
    "campaign",
    "Campaign folder: campaign.json, campaign.html and recordings/*/ (reused on a rerun)",
    folder=True,
)
@click.option(
    "--scheduler",
    metavar="ADDRESS",
    default=None,
    help="Address of a running Dask scheduler (tcp://host:port).",
)
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    default=None,
    help="Worker processes of a local Dask cluster (default: one per core; not with --scheduler).",
)
@click.option("--no-greybox", is_flag=True, help="Skip training the grey-box in each diagnosis.")
@click.pass_context
def campaign(
    ctx: click.Context,
    config_path: Path,
    recordings: tuple[Path, ...],
    out_dir: Path,
    scheduler: str | None,
    workers: int | None,
    no_greybox: bool,
) -> None:
    """Diagnose many recordings of one project on a Dask cluster; trend each named effect.

    Each recording is diagnosed as a task (on the cluster at --scheduler, else on a local one
    with --workers processes); a line is printed as each one finishes. A rerun skips the
    recordings already diagnosed (same content, tool version and project). A recording that
    fails is reported and the others go on; the exit code is then 1. See docs/campaign.md.

    \b
    Examples:
      fmu-greybox campaign builtin:hydraulic_actuator flights/*.csv --out camp/
      fmu-greybox campaign builtin:hydraulic_actuator flights/*.parquet \\
          --scheduler tcp://10.0.0.5:8786 --out camp/
    """
    import os

    from fmu_greybox.campaign.cluster import connect
    from fmu_greybox.campaign.page import summary_lines
    from fmu_greybox.campaign.run import run_campaign
    from fmu_greybox.project.config import load_config

    if scheduler is not None and workers is not None:
        raise click.UsageError("give either --scheduler or --workers, not both")
    config = load_config(config_path)
    with connect(scheduler, workers or os.cpu_count() or 1) as client:
        payload = run_campaign(
            config,
            recordings,
            out_dir,
            client,
            greybox=not no_greybox,
            progress=_campaign_progress(ctx.obj["quiet"]),
        )
    for line in summary_lines(payload):
        click.echo(line)
    info(
        ctx,
        f"wrote {out_dir / 'campaign.json'} and {out_dir / 'campaign.html'} "
        f"({payload['summary']['wall_seconds']} s)",
    )
    failed = payload["summary"]["failed"]
    if failed:
        raise FmuGreyboxError(
            f"{failed} of {len(recordings)} recordings failed; their errors are in "
            f"{out_dir / 'campaign.json'} (rerun to retry only those)"
        )


def _campaign_progress(quiet: bool):
    """A line per finished recording (above a progress bar when on a terminal)."""
    import sys

    from tqdm import tqdm

    bar = tqdm(total=0, unit="recording", disable=quiet or not sys.stderr.isatty(), leave=False)

    def report(outcome, done: int, total: int) -> None:
        line = f"[{done}/{total}] {outcome.line()}"
        if bar.disable:
            if not quiet or outcome.status == "failed":
                click.echo(line, err=outcome.status == "failed")
            return
        bar.total = total
        bar.update(1)
        bar.write(line, file=sys.stderr)
        if done == total:
            bar.close()

    return report
