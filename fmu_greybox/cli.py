"""The ``fmu-greybox`` command line.

Exit codes: 0 success, 1 user error (a message says what to mend), 2 usage error, 3 acceptance
criteria not met (``validate --strict``), 130 interrupted (Ctrl-C: 128 + SIGINT, as shells
report it). Tracebacks are shown only with ``--debug``.

Conventions every command follows (through the option factories below, so that a new command
or option gets them too): ``--out`` always has a default, named in the help; an option that two
commands share has one help text and one range (the project file's); long steps print a bar on
a terminal and one line per finished step anywhere else (:mod:`fmu_greybox.progress`).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from fmu_greybox import __version__
from fmu_greybox.errors import FmuGreyboxError

if TYPE_CHECKING:  # the commands import what they use when they run (a fast --help)
    from fmu_greybox.data.recording import Recording
    from fmu_greybox.model.store import GreyBoxModel
    from fmu_greybox.project.config import ProjectConfig
    from fmu_greybox.workflow.validate import Validation

#: ``train --ship`` (fmu_greybox.workflow.parts.SHIP_CHOICES, not imported: it needs numpy).
SHIP_CHOICES = ("best", "correctors", "terms", "terms+correctors")

EXIT_USER_ERROR = 1
EXIT_NOT_ACCEPTED = 3
#: Ctrl-C (SIGINT): 128 + the signal's number, what a shell reports for a process it ended.
EXIT_INTERRUPTED = 130
#: What an option factory returns: click's decorator of a command function.
Decorator = Callable[[Callable[..., Any]], Callable[..., Any]]


class _Group(click.Group):
    """A click group that turns fmu-greybox errors into a message and exit code 1 (Ctrl-C into
    exit code 130), and lists its commands with their whole first sentence (click cuts it to
    the terminal's width)."""

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = []
        for name in self.list_commands(ctx):
            command = self.get_command(ctx, name)
            if command is not None and not command.hidden:
                rows.append((name, command.get_short_help_str(limit=10_000)))
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except FmuGreyboxError as exc:
            if ctx.obj and ctx.obj.get("debug"):
                raise
            click.secho(f"error: {exc}", fg="red", err=True)
            ctx.exit(EXIT_USER_ERROR)
        except KeyboardInterrupt:
            if ctx.obj and ctx.obj.get("debug"):
                import traceback

                traceback.print_exc()
            click.secho("interrupted (Ctrl-C)", fg="red", err=True)
            ctx.exit(EXIT_INTERRUPTED)


def _pairs(items: tuple[str, ...], option: str, numeric: bool) -> dict:
    """Parse repeated ``NAME=VALUE`` options."""
    result: dict = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name or not value:
            raise click.BadParameter(f"{item!r} is not NAME=VALUE", param_hint=option)
        if numeric:
            try:
                result[name] = float(value)
            except ValueError:
                raise click.BadParameter(f"{value!r} is not a number", param_hint=option) from None
        else:
            result[name] = value
    return result


def out_option(default: str, what: str, folder: bool, name: str = "out_dir") -> Decorator:
    """The ``--out`` option: what the command writes there, with its default.

    Parameters
    ----------
    default : str
        File or folder written when ``--out`` is not given.
    what : str
        What is written, as the start of a sentence.
    folder : bool
        A folder (else a file).
    name : str
        The command function's parameter.
    """
    return click.option(
        "--out",
        name,
        type=click.Path(file_okay=not folder, dir_okay=folder, path_type=Path),
        default=Path(default),
        show_default=True,
        help=f"{what}.",
    )


def fmi_option(what: str) -> Decorator:
    """``--fmi 2|3`` (default 2), the FMI version of what the command writes."""
    return click.option(
        "--fmi",
        "fmi_version",
        type=click.Choice(["2", "3"]),
        default="2",
        show_default=True,
        help=f"{what}.",
    )


def inducing_option(default: int | None) -> Decorator:
    """``--inducing``, with the project file's range (``[gp] inducing``: at least 1)."""
    return click.option(
        "--inducing",
        type=click.IntRange(min=1),
        default=default,
        show_default=default is not None,
        help="Inducing points per stage"
        + (" (default: the project's [gp] inducing)." if default is None else "."),
    )


def max_iter_option(default: int | None) -> Decorator:
    """``--max-iter``, with the project file's range (``[gp] max_iter``: at least 0)."""
    return click.option(
        "--max-iter",
        type=click.IntRange(min=0),
        default=default,
        show_default=default is not None,
        help="Optimiser iterations per stage"
        + (" (default: the project's [gp] max_iter)." if default is None else "."),
    )


def recording_option(what: str, several: str = "") -> Decorator:
    """``--recording`` of a command that reads a project's recording (``several``: repeatable,
    with that sentence in its help, into ``recording_paths``)."""
    return click.option(
        "--recording",
        "recording_paths" if several else "recording_path",
        type=click.Path(dir_okay=False, path_type=Path),
        multiple=bool(several),
        help=f"Recording to {what} (default: the project's [recording] path).{several}",
    )


def _info(ctx: click.Context, message: str) -> None:
    if not ctx.obj.get("quiet"):
        click.echo(message)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="fmu-greybox")
@click.option("--debug", is_flag=True, help="Show tracebacks of errors.")
@click.option("-q", "--quiet", is_flag=True, help="Print only results and errors.")
@click.option(
    "-v", "--verbose", is_flag=True, help="Also print the FMUs' and the tool's log messages."
)
@click.pass_context
def main(ctx: click.Context, debug: bool, quiet: bool, verbose: bool) -> None:
    """Grey-box enhancement of white-box FMUs with sparse-GP correctors.

    Exit codes: 0 success, 1 an error in the input (the message says which file, column or
    variable and how to mend it), 2 a usage error, 3 acceptance criteria not met
    (validate --strict), 130 interrupted (Ctrl-C).

    CONFIG, the project of diagnose, train, validate and campaign, is a project file or a
    project the package carries: builtin:hydraulic_actuator (the reference actuator) or
    builtin:positioner.

    \b
    Examples:
      fmu-greybox demo                       # the main job on the built-in default
      fmu-greybox init my.fmu --out myproject/  # a starter project for your own FMU
      fmu-greybox fmu build --out fmus/
      fmu-greybox synth --effect coulomb_friction=800 --seed 3 --out rec.csv
      fmu-greybox diagnose builtin:hydraulic_actuator --recording rec.csv
      fmu-greybox train builtin:hydraulic_actuator --recording rec.csv --out model/
      fmu-greybox export model/ --out greybox.fmu --ssp bench.ssp --recording rec.csv
      fmu-greybox cosim bench.ssp --engine libcosim --out results.csv
    """
    ctx.ensure_object(dict)
    ctx.obj.update(debug=debug, quiet=quiet)
    if verbose or debug:
        logging.basicConfig(format="%(levelname)s %(name)s: %(message)s")
        logging.getLogger("fmu_greybox").setLevel(logging.DEBUG if debug else logging.INFO)


@main.group()
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
        _info(ctx, f"built {name}: {path} ({label})")


@main.command()
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
    _info(
        ctx,
        f"wrote {out_dir / 'project.toml'} ({len(config.signals)} signals; stages {stages}); "
        "check its roles, units and stage order, then: fmu-greybox diagnose "
        f"{out_dir / 'project.toml'} --recording REC",
    )


@main.command()
@click.option(
    "--effect",
    "effects",
    multiple=True,
    metavar="NAME=VALUE",
    help="Switch on a concealed truth effect (repeatable).",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
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
    _info(
        ctx,
        f"wrote {out} ({recording.n_samples} samples, {len(recording.names)} signals, "
        f"{time.perf_counter() - started:.2f} s)",
    )


@main.command()
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
        "mapping": _pairs(mapping, "--map", numeric=False),
        "fixed": _pairs(fixed, "--fix", numeric=True),
        "parameters": _pairs(params, "--param", numeric=True),
    }
    recording = load_recording(recording_path, resample=resample)
    result = simulate_recording(
        resolve_fmu(fmu_spec), recording, progress=not ctx.obj["quiet"], **options
    )
    save_recording(result, out)
    _info(ctx, f"wrote {out} ({result.n_samples} samples of {len(result.names)} outputs)")


@main.command()
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
        _info(ctx, f"{TRAINING_PARTS}: {parts_text(model.training.parts)}.")
    _info(
        ctx,
        f"wrote {out_dir} ({len(model.chain.stages)} stages, "
        f"{model.training.train_rows} training rows, {model.training.seconds} s{named})",
    )


@main.command()
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
        _info(ctx, f"wrote {', '.join(str(out_dir / name) for name in files)}")
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
    write_page(pooled_report_html(result, config, model_dir, command), out_dir / REPORT)
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
    _info(
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
    from fmu_greybox.report.validation import REPORT, validation_report_html
    from fmu_greybox.workflow.validate import write_metrics, write_plots

    folder.mkdir(parents=True, exist_ok=True)
    metrics = write_metrics(result, model, folder / "metrics.json")
    plots = write_plots(result, model, folder)
    write_page(validation_report_html(result, model, config, model_dir, command), folder / REPORT)
    return metrics, ["metrics.json", *plots, REPORT]


def _print_validation(ctx: click.Context, model: GreyBoxModel, result: Validation) -> None:
    """A validation's held-out rows, table, passed-through stages and acceptance, as text."""
    from fmu_greybox.workflow.metrics import format_table
    from fmu_greybox.workflow.parts import passed_through_text

    _info(ctx, f"held out: {result.held_out}")
    click.echo(format_table(result.table, model.training.target_unit, model.contents()))
    passed = model.chain.passed_through
    if passed:
        _info(ctx, f"passed through: {passed_through_text(model.training.parts or {}, passed)}")
    if result.acceptance is not None:
        click.echo(result.acceptance.summary())


@main.command()
@out_option("out", "Folder for everything produced (report.html first)", folder=True)
@click.option(
    "--effect",
    "effects",
    multiple=True,
    metavar="NAME=VALUE",
    help="Concealed truth effect (repeatable; default: one drawn by --seed).",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
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
    _info(ctx, f"report: {out_dir / 'report.html'} ({outcome['seconds']} s)")


@main.command()
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
    _info(
        ctx,
        f"wrote {out} ({runtime} FMU, FMI {fmi_version}.0, {counts['input']} inputs, "
        f"{counts['output']} outputs, {counts['parameter']} parameters; "
        f"model {result.model_sha256[:12]}, GUID {result.guid})",
    )
    if ssp is not None:
        recording = load_project_recording(load_model(model_dir).config, recording_path)
        make_bench(out, recording, ssp, side_by_side=not greybox_only)
        _info(ctx, f"wrote {ssp} (run it: fmu-greybox cosim {ssp} --out results.csv)")


@main.command()
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
    _info(
        ctx,
        f"wrote {out} ({result.n_samples} steps of {len(result.names)} outputs in {engine}, "
        f"{time.perf_counter() - started:.2f} s)",
    )


@main.command()
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
    _info(
        ctx,
        f"wrote {out_dir / 'diagnosis.json'} and {out_dir / 'report.html'} "
        f"({payload['timings']['total']} s)",
    )


@main.command()
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
    from fmu_greybox.errors import FmuGreyboxError
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
    _info(
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
