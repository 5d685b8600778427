"""The commands of the bench: export the grey-box as an FMU (and an SSP bench), co-simulate a
bench."""

from __future__ import annotations

import time
from pathlib import Path

import click

from fmu_greybox.cli.options import fmi_option, info, out_option


@click.command()
@click.argument("model_dir", metavar="MODEL_DIR", type=click.Path(file_okay=False, path_type=Path))
@out_option(
    "greybox.fmu", "The grey-box FMU to write (its name is the model identifier)", False, "out"
)
@click.option(
    "--runtime",
    type=click.Choice(["native", "python"]),
    default="native",
    show_default=True,
    help="native: a C binary, no Python in the bench's process; python: a pythonfmu FMU.",
)
@fmi_option("FMI 2.0 or FMI 3.0 co-simulation (3: native runtime only; SSP benches take 2)")
@click.option("--author", default=None, help="Author in the model description (default: you).")
@click.option(
    "--fmu-version", default="1.0", show_default=True, help="Version in the model description."
)
@click.option(
    "--ood-threshold",
    type=click.FloatRange(0.0, 1.0, min_open=True, max_open=True),
    default=0.1,
    show_default=True,
    help="Default of the FMU's ood_threshold parameter (domain_score below it: out of domain).",
)
@click.option(
    "--ssp",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Also write an SSP bench: the recording played back into the grey-box FMU.",
)
@click.option(
    "--recording",
    "recording_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Recording the bench plays back (needed with --ssp).",
)
@click.option(
    "--greybox-only",
    is_flag=True,
    help="Leave the white-box FMU out of the bench (default: side by side).",
)
@click.pass_context
def export(
    ctx: click.Context,
    model_dir: Path,
    out: Path,
    runtime: str,
    fmi_version: str,
    author: str | None,
    fmu_version: str,
    ood_threshold: float,
    ssp: Path | None,
    recording_path: Path | None,
    greybox_only: bool,
) -> None:
    """Export a trained grey-box as an FMI 2.0 (or 3.0) co-simulation FMU (and an SSP bench).

    The FMU replaces the white-box on a bench: same inputs, corrected outputs, and per corrected
    output NAME_std and NAME_wb, plus domain_score, out_of_domain and the parameters
    correction_enabled and ood_threshold. See docs/bench.md.

    The FMU is native by default: a C binary compiled here with gcc, which runs in any FMI
    2.0 master (no Python needed in the bench's process); --fmi 3 makes it an FMI 3.0 FMU
    with the same variables and numbers; --runtime python writes a pythonfmu FMU instead.

    \b
    Examples:
      fmu-greybox export model/ --out greybox.fmu
      fmu-greybox export model/ --out greybox.fmu --ssp bench.ssp --recording rec.csv
      fmu-greybox export model/ --out greybox.fmu --fmi 3
      fmu-greybox export model/ --out greybox.fmu --runtime python
    """
    from fmu_greybox.atomic import prepare_output
    from fmu_greybox.export.fmu import export_greybox
    from fmu_greybox.export.ssp import make_bench, require_bench_fmi
    from fmu_greybox.model.store import load_model
    from fmu_greybox.project.data import load_project_recording

    if ssp is not None and recording_path is None:
        raise click.UsageError("--ssp needs --recording (the recording the bench plays back)")
    if ssp is not None:
        require_bench_fmi(fmi_version, "--ssp with --fmi 3")
    prepare_output(out, "--out")
    if ssp is not None:
        prepare_output(ssp, "--ssp")
    result = export_greybox(
        model_dir,
        out,
        runtime=runtime,
        fmi_version=fmi_version,
        author=author,
        version=fmu_version,
        ood_threshold=ood_threshold,
    )
    ports = result.interface.ports
    counts = {k: sum(p.causality == k for p in ports) for k in ("input", "output", "parameter")}
    info(
        ctx,
        f"wrote {out} ({runtime} FMU, FMI {fmi_version}.0, {counts['input']} inputs, "
        f"{counts['output']} outputs, {counts['parameter']} parameters; "
        f"model {result.model_sha256[:12]}, GUID {result.guid})",
    )
    if ssp is not None:
        recording = load_project_recording(load_model(model_dir).config, recording_path)
        make_bench(out, recording, ssp, side_by_side=not greybox_only)
        info(ctx, f"wrote {ssp} (run it: fmu-greybox cosim {ssp} --out results.csv)")


@click.command()
@click.argument("ssp", metavar="BENCH", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--engine",
    type=click.Choice(["fmpy", "libcosim"]),
    default="fmpy",
    show_default=True,
    help="Co-simulation master.",
)
@click.option("--stop-time", type=float, default=None, help="Stop time [s] (default: the SSD's).")
@click.option(
    "--step", type=float, default=None, help="Communication step [s] (default: the SSD's)."
)
@out_option("results.csv", "Every FMU output, one row per step (.csv or .parquet)", False, "out")
@click.pass_context
def cosim(
    ctx: click.Context,
    ssp: Path,
    engine: str,
    stop_time: float | None,
    step: float | None,
    out: Path,
) -> None:
    """Co-simulate an SSP bench in fmpy or libcosim; write every FMU output.

    Columns are COMPONENT.OUTPUT (Booleans as 0/1), one row per communication step.

    \b
    Examples:
      fmu-greybox cosim bench.ssp --out results.csv
      fmu-greybox cosim bench.ssp --engine libcosim --stop-time 2 --out results.parquet
    """
    from fmu_greybox.data.recording import save_recording
    from fmu_greybox.export.ssp import run_bench

    started = time.perf_counter()
    result = run_bench(ssp, engine=engine, stop_time=stop_time, step=step)
    save_recording(result, out)
    info(
        ctx,
        f"wrote {out} ({result.n_samples} steps of {len(result.names)} outputs in {engine}, "
        f"{time.perf_counter() - started:.2f} s)",
    )
