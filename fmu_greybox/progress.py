"""Progress of long steps: a bar on a terminal, one line per finished step anywhere else.

Bars redraw themselves with carriage returns; written to a file or a CI log they leave every
redraw behind (about 100 KB for one demo). So a :class:`Progress` draws a bar (tqdm) only when
standard error is a terminal, and otherwise prints one line when its step finishes, e.g.
``Fitting the EHV corrector: done, 100 iterations in 5.2 s``. Labels are the start of a
sentence saying what is being done.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import Any, TextIO, TypeVar

from tqdm import tqdm

T = TypeVar("T")


class Progress:
    """One step's progress (use as a context manager, or call :meth:`close`).

    Parameters
    ----------
    label : str
        What is being done, e.g. ``"Simulating the white-box"``.
    total : int or None
        Expected count (for the bar).
    enabled : bool
        ``False`` shows nothing at all.
    unit : str
        What is counted (singular), e.g. ``"step"``, ``"iteration"``.
    stream : file, optional
        Where to write (default: standard error).
    """

    def __init__(
        self,
        label: str,
        total: int | None = None,
        enabled: bool = True,
        unit: str = "step",
        stream: TextIO | None = None,
    ) -> None:
        self.label = label
        self.unit = unit
        self.count = 0
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self._started = time.perf_counter()
        self._closed = False
        interactive = enabled and _is_terminal(self.stream)
        self._bar = (
            tqdm(total=total, desc=label, unit=unit, leave=False, file=self.stream)
            if interactive
            else None
        )

    def update(self, n: int = 1, **postfix: Any) -> None:
        """Count ``n`` more; ``postfix`` values are shown beside a bar."""
        self.count += n
        if self._bar is not None:
            self._bar.update(n)
            if postfix:
                self._bar.set_postfix(postfix)

    def close(self) -> None:
        """Finish: remove the bar, or print the one line (once)."""
        if self._closed:
            return
        self._closed = True
        if self._bar is not None:
            self._bar.close()
        elif self.enabled:
            plural = "" if self.count == 1 else "s"
            seconds = time.perf_counter() - self._started
            self.stream.write(
                f"{self.label}: done, {self.count} {self.unit}{plural} in {seconds:.1f} s\n"
            )
            self.stream.flush()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def announce(message: str, enabled: bool = True, stream: TextIO | None = None) -> None:
    """One line saying what starts now (nothing when not ``enabled``), on standard error by
    default, as the :class:`Progress` lines are."""
    if enabled:
        out = stream if stream is not None else sys.stderr
        out.write(message + "\n")
        out.flush()


def track(
    items: Iterable[T], label: str, total: int | None, enabled: bool, unit: str = "step"
) -> Iterator[T]:
    """Iterate over ``items`` with a :class:`Progress` (closed when the loop ends)."""
    with Progress(label, total, enabled, unit) as progress:
        for item in items:
            yield item
            progress.update()


def _is_terminal(stream: TextIO) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False
