"""The ``fmu-greybox`` group: its own options (``--debug``, ``--quiet``, ``--verbose``), the
errors of every command turned into a message and an exit code, and the commands."""

from __future__ import annotations

import gc
import logging

import click

from fmu_greybox import __version__
from fmu_greybox.cli.bench import cosim, export
from fmu_greybox.cli.demo import demo
from fmu_greybox.cli.diagnose import campaign, diagnose
from fmu_greybox.cli.greybox import train, validate
from fmu_greybox.cli.options import EXIT_INTERRUPTED, EXIT_USER_ERROR
from fmu_greybox.cli.whitebox import fmu, init, simulate, synth
from fmu_greybox.errors import FmuGreyboxError


class Group(click.Group):
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


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"]})
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


#: The commands (``--help`` lists them by name).
COMMANDS = (fmu, init, synth, simulate, train, validate, demo, export, cosim, diagnose, campaign)
for command in COMMANDS:
    main.add_command(command)


def run() -> None:
    """The ``fmu-greybox`` console script: :func:`main`, after which every object left is
    frozen (:func:`gc.freeze`), so that the interpreter's last collections on the way out do
    not look at them all again (0.72 s after a demo, 0.26 s frozen; ``docs/speed.md``)."""
    try:
        main()
    finally:
        gc.freeze()
