"""What every command of the command line shares: the exit codes, the option factories (``--out``
with its default, ``--fmi``, ``--inducing``, ``--max-iter``, ``--recording``), ``NAME=VALUE``
options and the line a command prints unless ``--quiet``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

EXIT_USER_ERROR = 1
EXIT_NOT_ACCEPTED = 3
#: Ctrl-C (SIGINT): 128 + the signal's number, what a shell reports for a process it ended.
EXIT_INTERRUPTED = 130
#: What an option factory returns: click's decorator of a command function.
Decorator = Callable[[Callable[..., Any]], Callable[..., Any]]


def pairs(items: tuple[str, ...], option: str, numeric: bool) -> dict:
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


def truth_options(effects_help: str) -> Decorator:
    """``--effect NAME=VALUE`` (repeatable, into ``effects``) and ``--seed``, the concealed
    truth of a synthetic recording."""
    effect = click.option(
        "--effect", "effects", multiple=True, metavar="NAME=VALUE", help=effects_help
    )
    seed = click.option("--seed", type=int, default=0, show_default=True, help="Random seed.")
    return lambda command: effect(seed(command))


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


def info(ctx: click.Context, message: str) -> None:
    """Print ``message`` unless ``--quiet`` was given."""
    if not ctx.obj.get("quiet"):
        click.echo(message)
