"""The stretch of a long recording a diagnosis runs on.

A diagnosis simulates the white-box hundreds of times over the rows it is given, so its cost
grows with the recording; a ten-minute flight test at 1 kHz is 600 000 rows. Beyond
:data:`MAX_ROWS` rows it runs on one contiguous stretch of that many rows (contiguous, because
every simulation starts from the recording's state at its first row and runs through): the
stretch in which the recorded inputs vary most. What a hypothesis can be told from depends on
how the inputs excite the model, so the stretch with the largest excitation carries the most
information per row. Each input counts by its variance about its mean over the recording and
by the variance of its step changes (a steady input and a slow ramp excite little; steps,
sweeps and turbulence much), both relative to the whole recording's, so inputs of any unit
weigh alike.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: Most rows a diagnosis runs on (60 s at 1 kHz).
MAX_ROWS = 60_000
#: Candidate stretches start every this share of the stretch's length.
STRIDE = 0.05


@dataclass(frozen=True)
class Window:
    """The rows of a recording a diagnosis ran on.

    Attributes
    ----------
    first, last : int
        First and last row (0-based, inclusive).
    of_rows : int
        Rows of the whole recording.
    share_of_excitation : float
        The stretch's share of the recording's input excitation (its rows' share would be
        ``rows / of_rows`` for an evenly excited recording).
    """

    first: int
    last: int
    of_rows: int
    share_of_excitation: float

    @property
    def rows(self) -> int:
        """Rows of the stretch."""
        return self.last - self.first + 1

    def to_dict(self) -> dict[str, float | int | str]:
        """Plain data for ``diagnosis.json``."""
        return {
            "first_row": self.first,
            "last_row": self.last,
            "rows": self.rows,
            "of_rows": self.of_rows,
            "share_of_excitation": self.share_of_excitation,
            "how": (
                f"the {self.rows} consecutive rows whose inputs vary most (variance about "
                "the mean and of the step changes, each relative to the whole recording's); "
                f"a diagnosis runs on at most {MAX_ROWS} rows"
            ),
        }


def excitation(inputs: Sequence[np.ndarray]) -> np.ndarray:
    """Each row's input excitation: per input, its squared departure from the mean and its
    squared step change, each divided by its mean over the recording, summed over the inputs.

    Parameters
    ----------
    inputs : sequence of ndarray, each shape (n,)

    Returns
    -------
    ndarray, shape (n,)
    """
    n = len(inputs[0])
    score = np.zeros(n)
    for x in inputs:
        x = np.asarray(x, dtype=np.float64)
        step = np.zeros(n)
        step[1:] = np.diff(x) ** 2
        for part in ((x - x.mean()) ** 2, step):
            total = part.mean()
            if total > 0.0:
                score += part / total
    return score


def most_excited(inputs: Sequence[np.ndarray], rows: int = MAX_ROWS) -> Window | None:
    """The stretch of ``rows`` consecutive rows with the largest input excitation, among
    those starting every :data:`STRIDE` of ``rows`` (and the one ending at the last row);
    ``None`` when the recording is no longer than ``rows``.

    Parameters
    ----------
    inputs : sequence of ndarray, each shape (n,)
        The recorded inputs.
    rows : int

    Returns
    -------
    Window or None
    """
    n = len(inputs[0])
    if n <= rows:
        return None
    score = excitation(inputs)
    running = np.concatenate([[0.0], np.cumsum(score)])
    stride = max(1, int(STRIDE * rows))
    starts = np.unique(np.append(np.arange(0, n - rows + 1, stride), n - rows))
    sums = running[starts + rows] - running[starts]
    best = int(starts[int(np.argmax(sums))])
    total = float(running[-1])
    share = float(sums.max() / total) if total > 0 else rows / n
    return Window(first=best, last=best + rows - 1, of_rows=n, share_of_excitation=share)
