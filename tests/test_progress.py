"""Progress output: a bar on a terminal, one line per finished step in a log, nothing when off."""

from __future__ import annotations

import io
import re

from fmu_greybox.progress import Progress, track


class Terminal(io.StringIO):
    """A stream that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def test_a_log_gets_one_line_when_the_step_finishes() -> None:
    log = io.StringIO()
    with Progress("Fitting the EHV corrector", 40, True, "iteration", log) as progress:
        for _ in range(40):
            progress.update(bound="-1.2e4")
        assert log.getvalue() == ""  # nothing while it runs
    assert re.fullmatch(
        r"Fitting the EHV corrector: done, 40 iterations in \d+\.\d s\n", log.getvalue()
    )
    progress.close()  # closing twice writes nothing more
    assert log.getvalue().count("\n") == 1


def test_a_terminal_gets_a_bar_that_leaves_no_line() -> None:
    terminal = Terminal()
    with Progress("Stepping the white-box", 100, True, "step", terminal) as progress:
        for _ in range(100):
            progress.update()
    assert "Stepping the white-box" in terminal.getvalue() and "\r" in terminal.getvalue()
    assert "done" not in terminal.getvalue()


def test_switched_off_shows_nothing_and_track_yields_every_item(capsys) -> None:
    silent = io.StringIO()
    with Progress("Recording", 5, False, "step", silent) as progress:
        progress.update(5)
    assert silent.getvalue() == "" and progress.count == 5
    assert list(track(range(7), "Counting", 7, enabled=False)) == list(range(7))
    assert capsys.readouterr().err == ""
