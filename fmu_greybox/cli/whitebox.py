"""The commands on the white-box and its recordings: build the reference FMUs, write a starter
project for an FMU, synthesise a recording of the truth actuator, simulate an FMU over a
recording."""

from __future__ import annotations

import time
from pathlib import Path

import click

from fmu_greybox.cli.options import fmi_option, info, out_option, pairs, truth_options


@click.group()
def fmu() -> None:
    """Build and inspect the reference FMUs."""


@fmu.command("build")
@out_option("fmus", "Folder receiving the reference FMUs", folder=True)
@fmi_option("FMI version of the FMUs (3: the framework with its FMI 3.0 face)")
@click.option(
    "--interface",
    type=click.Choice(["cs", "me"]),
    default="cs",
    show_default=True,
    help="cs: co-simulation (the FMU integrates itself with its Rosenbrock method); me: model "
    "exchange (the FMU gives its states' derivatives; fmu-greybox integrates them with CVode "
    "at the project's step).",
)
@click.option(
    "--platform",
    "platform_name",
    type=click.Choice(["host", "win64"]),
    default="host",
    show_default=True,
    help="Platform of the binaries (win64: cross-compiled with mingw-w64, FMI 2.0 only).",
)
@click.pass_context
def fmu_build_cmd(
    ctx: click.Context, out_dir: Path, fmi_version: str, interface: str, platform_name: str
) -> None:
    """Compile the reference actuator FMUs from fmu_sources/.

    \b
    Examples:
      fmu-greybox fmu build --out fmus/
      fmu-greybox fmu build --fmi 3 --out fmus3/
      fmu-greybox fmu build --interface me --out fmus_me/
      fmu-greybox fmu build --fmi 3 --interface me --out fmus3_me/
      fmu-greybox fmu build --platform win64 --out fmus_win64/
    """
    from fmu_greybox.fmi.build import build_reference_fmus
    from fmu_greybox.fmi.kinds import CO_SIMULATION, MODEL_EXCHANGE, FmuKind
    from fmu_greybox.fmi.platforms import platform_named

    out_dir.mkdir(parents=True, exist_ok=True)
    kind = FmuKind(f"{fmi_version}.0", MODEL_EXCHANGE if interface == "me" else CO_SIMULATION)
    target = platform_named(platform_name)
    label = kind.label if platform_name == "host" else f"{kind.label}, {target.folder}"
    for name, path in build_reference_fmus(out_dir, kind, target).items():
        info(ctx, f"built {name}: {path} ({label})")


@click.command()
@click.argument("fmu_spec", metavar="FMU")
@out_option("project", "Folder receiving project.toml", folder=True)
@click.option("--force", is_flag=True, help="Write over an existing project.toml.")
@click.pass_context
def init(ctx: click.Context, fmu_spec: str, out_dir: Path, force: bool) -> None:
    """Write a starter project for your own white-box FMU, to check and edit.

    FMU is a .fmu path or builtin:NAME. OUT/project.toml declares each FMU input and output as
    a signal (its role read from the FMU's unit, description or name, as the diagnosis reads
    it; its unit the FMU's), a stage per output that holds a level (a position, pressure,
    current, voltage, force or temperature) fed by every input, and the defaults of [gp],
    [split] and [acceptance] as comments. Check the roles and units, order and connect the
    stages (feeds_from), then diagnose a recording. docs/config.md describes every field.

    \b
    Examples:
      fmu-greybox init path/to/model.fmu --out myproject/
      fmu-greybox diagnose myproject/project.toml --recording rec.csv --out diag/
      fmu-greybox init builtin:HydraulicActuator --out actuator/ --force
    """
    from fmu_greybox.project.starter import write_starter

    config = write_starter(fmu_spec, out_dir, force=force)
    stages = ", ".join(stage.name for stage in config.stages)
    info(
        ctx,
        f"wrote {out_dir / 'project.toml'} ({len(config.signals)} signals; stages {stages}); "
        "check its roles, units and stage order, then: fmu-greybox diagnose "
        f"{out_dir / 'project.toml'} --recording REC",
    )


@click.command()
@truth_options("Switch on a concealed truth effect (repeatable).")
@click.option(
    "--duration",
    type=click.FloatRange(min=0.01),
    default=30.0,
    show_default=True,
    help="Length of the recording [s].",
)
@click.option(
    "--noise",
    type=click.FloatRange(min=0.0),
    default=1.0,
    show_default=True,
    help="Sensor-noise scale (0 = noise-free).",
)
@out_option("recording.csv", "Recording to write (.csv or .parquet)", folder=False, name="out")
@click.option("--list-effects", is_flag=True, help="List the truth model's effects and exit.")
@click.pass_context
def synth(
    ctx: click.Context,
    effects: tuple[str, ...],
    seed: int,
    duration: float,
    noise: float,
    out: Path,
    list_effects: bool,
) -> None:
    """Record the truth actuator in closed loop, as a flight test would.

    \b
    Examples:
      fmu-greybox synth --list-effects
      fmu-greybox synth --effect gain_error=0.1 --noise 0 --out exp1.csv
      fmu-greybox synth --effect coulomb_friction=800 --effect time_delay=0.004 --out rec.parquet
    """
    from fmu_greybox.data.recording import save_recording
    from fmu_greybox.fmi.archive import open_fmu
    from fmu_greybox.fmi.builtin import reference_fmus
    from fmu_greybox.synth import actuator as synth_mod

    paths = reference_fmus()
    with (
        open_fmu(paths["HydraulicActuatorTruth"]) as truth,
        open_fmu(paths["HydraulicActuator"]) as whitebox,
    ):
        if list_effects:
            offered = synth_mod.list_effects(truth, whitebox)
            rows = [
                (v.name, f"[{v.unit or '-'}]", synth_mod.typical_range(v), v.description)
                for v in offered
            ]
            widths = [max(len(row[i]) for row in rows) for i in range(3)]
            for row in rows:
                cells = [f"{cell:{width}}" for cell, width in zip(row[:3], widths, strict=True)]
                click.echo("  ".join([*cells, row[3]]))
            return
        request = synth_mod.SynthRequest(
            effects=synth_mod.parse_effects(effects),
            seed=seed,
            noise=noise,
            profile=synth_mod.FlightTestProfile(duration=duration),
        )
        started = time.perf_counter()
        recording = synth_mod.synthesise(truth, whitebox, request, progress=not ctx.obj["quiet"])
    save_recording(recording, out)
    info(
        ctx,
        f"wrote {out} ({recording.n_samples} samples, {len(recording.names)} signals, "
        f"{time.perf_counter() - started:.2f} s)",
    )


@click.command()
@click.argument("fmu_spec", metavar="FMU")
@click.argument("recording_path", metavar="RECORDING", type=click.Path(path_type=Path))
@out_option(
    "simulated.csv", "The FMU's outputs, one row per recorded row (.csv or .parquet)", False, "out"
)
@click.option(
    "--map",
    "mapping",
    multiple=True,
    metavar="INPUT=COLUMN",
    help="Feed an FMU input from a differently named column (repeatable).",
)
@click.option(
    "--fix",
    "fixed",
    multiple=True,
    metavar="INPUT=VALUE",
    help="Hold an unrecorded FMU input constant (repeatable).",
)
@click.option(
    "--param",
    "params",
    multiple=True,
    metavar="NAME=VALUE",
    help="Set an FMU parameter (repeatable).",
)
@click.option(
    "--resample",
    type=float,
    default=None,
    metavar="DT",
    help="Resample an uneven recording onto a uniform grid of step DT [s].",
)
@click.pass_context
def simulate(
    ctx: click.Context,
    fmu_spec: str,
    recording_path: Path,
    out: Path,
    mapping: tuple[str, ...],
    fixed: tuple[str, ...],
    params: tuple[str, ...],
    resample: float | None,
) -> None:
    """Run a co-simulation FMU open-loop over a recording's inputs.

    FMU is a .fmu path or builtin:HydraulicActuator. Inputs are taken from the columns of the
    same name unless mapped.

    \b
    Example:
      fmu-greybox simulate builtin:HydraulicActuator rec.csv --out wb.csv
      fmu-greybox simulate my.fmu bench.mat --map valve_current=i_cmd --fix engage=1 --out wb.csv
    """
    from fmu_greybox.data.recording import load_recording, save_recording
    from fmu_greybox.fmi.builtin import resolve_fmu
    from fmu_greybox.model.simulate import simulate_recording

    options = {
        "mapping": pairs(mapping, "--map", numeric=False),
        "fixed": pairs(fixed, "--fix", numeric=True),
        "parameters": pairs(params, "--param", numeric=True),
    }
    recording = load_recording(recording_path, resample=resample)
    result = simulate_recording(
        resolve_fmu(fmu_spec), recording, progress=not ctx.obj["quiet"], **options
    )
    save_recording(result, out)
    info(ctx, f"wrote {out} ({result.n_samples} samples of {len(result.names)} outputs)")
