"""The ``fmu-greybox`` command line.

Exit codes: 0 success, 1 user error (a message says what to mend), 2 usage error, 3 acceptance
criteria not met (``validate --strict``), 130 interrupted (Ctrl-C: 128 + SIGINT, as shells
report it). Tracebacks are shown only with ``--debug``.

Conventions every command follows (through the option factories of
:mod:`~fmu_greybox.cli.options`, so that a new command or option gets them too): ``--out``
always has a default, named in the help; an option that two commands share has one help text
and one range (the project file's); long steps print a bar on a terminal and one line per
finished step anywhere else (:mod:`fmu_greybox.progress`).

The commands, grouped by what they do: :mod:`~fmu_greybox.cli.whitebox` (the reference FMUs, a
starter project, synthetic recordings, open-loop simulation), :mod:`~fmu_greybox.cli.greybox`
(train, validate), :mod:`~fmu_greybox.cli.diagnose` (diagnose, campaign),
:mod:`~fmu_greybox.cli.bench` (export, cosim) and :mod:`~fmu_greybox.cli.demo`; the group that
gathers them, and turns their errors into exit codes, is :mod:`~fmu_greybox.cli.group`.
"""

from fmu_greybox.cli.group import main, run
from fmu_greybox.cli.options import EXIT_INTERRUPTED, EXIT_NOT_ACCEPTED, EXIT_USER_ERROR

__all__ = ["EXIT_INTERRUPTED", "EXIT_NOT_ACCEPTED", "EXIT_USER_ERROR", "main", "run"]
