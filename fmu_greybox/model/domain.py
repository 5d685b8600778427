"""The input domain of an exported grey-box: the inputs it accepts at ``fmi2DoStep``.

A grey-box is the white-box corrected by what it learned from its training recording; far
beyond that recording the corrections mean nothing and the white-box alone may fail (an input
of 1e30 drove the white-box's pressures to 1e57 Pa). So both runtimes (native and Python)
refuse a step, with a message naming the input, its value and the domain, when an input is

* not a finite number, or
* outside its domain: the intersection of the range the white-box FMU declares for it
  (``min``/``max`` in its model description, where declared) and its training range widened by
  :data:`INPUT_MARGIN` times its *scale* on each side, the scale being the larger of the
  range's width and its largest magnitude. A margin of 1 accepts, for an input recorded over
  [-3, 3] mA, anything in [-9, 9] mA; for one held at 20.7 MPa, [0, 41.4] MPa; zero is
  always inside. An input that training never saw away from zero, and every input of a
  model folder older than the record of training ranges, is bounded by its declaration only.

Within the domain but beyond the training range the grey-box runs and says so: its
``out_of_domain`` flag is set (the correctors' features are clipped to their training range).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from fmu_greybox import _chainstep
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.model.chain import RANGE_MARGIN

#: Multiples of an input's training scale the domain extends beyond its training range.
INPUT_MARGIN = 1.0


def training_ranges(names: Sequence[str], rows: np.ndarray) -> dict[str, list[float]]:
    """The range of each input over the training rows (recorded in the model's training facts).

    Parameters
    ----------
    names : sequence of str
        FMU inputs, in the columns' order.
    rows : ndarray, shape (n, len(names))

    Returns
    -------
    dict of str to [low, high]
    """
    return {
        name: [float(np.min(rows[:, i])), float(np.max(rows[:, i]))] for i, name in enumerate(names)
    }


def beyond_training(
    ranges: Mapping[str, Sequence[float]], names: Sequence[str], rows: np.ndarray
) -> str:
    """The inputs whose range over ``rows`` reaches beyond their training range widened as the
    correctors' features are (:data:`~fmu_greybox.model.chain.RANGE_MARGIN` of its span), in
    words: what a training recording would have to cover for the rows to lie inside the
    correctors' domain.

    Parameters
    ----------
    ranges : mapping of str to [low, high]
        Per input its training range (:func:`training_ranges`); inputs not in it are skipped.
    names : sequence of str
        The inputs, in the columns' order.
    rows : ndarray, shape (n, len(names))

    Returns
    -------
    str
        E.g. ``"valve_current -3.2 to 2.1 (trained on -1.64 to 0.81)"``, ``"; "``-joined;
        ``""`` when every input stayed within its range or there are no rows.
    """
    if not rows.size:
        return ""
    texts = []
    for i, name in enumerate(names):
        if name not in ranges:
            continue
        low, high = ranges[name]
        margin = RANGE_MARGIN * (high - low)
        seen_low, seen_high = float(np.min(rows[:, i])), float(np.max(rows[:, i]))
        if seen_low < low - margin or seen_high > high + margin:
            texts.append(
                f"{name} {seen_low:.3g} to {seen_high:.3g} (trained on {low:.3g} to {high:.3g})"
            )
    return "; ".join(texts)


@dataclass(frozen=True)
class InputDomain:
    """Per input the interval it must lie in.

    Attributes
    ----------
    names : list of str
        The grey-box's inputs, in value-reference order.
    low, high : ndarray, shape (n_inputs,)
        Bounds (-inf/inf where unbounded).
    """

    names: list[str]
    low: np.ndarray
    high: np.ndarray

    @classmethod
    def of(
        cls, archive: FmuArchive, names: Sequence[str], ranges: Mapping[str, Sequence[float]]
    ) -> InputDomain:
        """The domain of a grey-box's inputs.

        Parameters
        ----------
        archive : FmuArchive
            The white-box (its declared ranges).
        names : sequence of str
            The inputs.
        ranges : mapping of str to (low, high)
            Training ranges (``model.training.input_ranges``; empty for old model folders).

        Returns
        -------
        InputDomain
        """
        low, high = np.full(len(names), -math.inf), np.full(len(names), math.inf)
        for i, name in enumerate(names):
            variable = archive.variable(name)
            if variable.minimum is not None:
                low[i] = variable.minimum
            if variable.maximum is not None:
                high[i] = variable.maximum
            if name in ranges:
                lowest, highest = (float(v) for v in ranges[name])
                scale = max(highest - lowest, abs(lowest), abs(highest))
                if scale > 0.0:
                    low[i] = max(low[i], lowest - INPUT_MARGIN * scale)
                    high[i] = min(high[i], highest + INPUT_MARGIN * scale)
        return cls(list(names), low, high)

    def refusal(self, u: Sequence[float], time: float) -> str | None:
        """Why the inputs ``u`` are refused at ``time``, or ``None`` if they are accepted.

        The first input that is not finite or lies outside its interval is named, by the
        native runtime's own code (``native/rules.c``, through :mod:`fmu_greybox._chainstep`):
        both runtimes refuse the same inputs in the same words.

        Parameters
        ----------
        u : sequence of float, shape (n_inputs,)
            The inputs, in the order of :attr:`names`.
        time : float
            The grey-box's time [s], quoted in the message.

        Returns
        -------
        str or None
        """
        return _chainstep.input_refusal(self.names, u, self.low, self.high, time)
