"""The named correction terms as the native grey-box FMU reads them (``native/terms.c``).

Every kind of :data:`~fmu_greybox.model.terms.TERM_KINDS` has a code here and a ``case`` in
``terms.c``; the codes reach the C code through the FMU's generated ``greybox_config.h``
(``TERM_<Kind>``). A term is stored as :data:`TERM_INTS` integers (kind, positions, flags) and
:data:`TERM_REALS` reals (its numbers), both taken from a copy of the Python term after its own
``bind()``: the lag coefficient, the delay in whole and fractional steps and the sub-step of a
rate are the numbers the Python runtime computes, not recomputed in C.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence

import numpy as np

from fmu_greybox.errors import ExportError
from fmu_greybox.model.terms import Term

#: Integers and reals per term (``TERM_INTS``, ``TERM_REALS`` in terms.h).
TERM_INTS = 6
TERM_REALS = 6


def _line(term: Term) -> list[float]:
    """A delay line's length in whole steps and the fraction of a step beyond them."""
    line = term._line
    return [float(line.whole), line.frac]


def _feedback(*names: str) -> Callable[[Term], list[float]]:
    """A feedback term's numbers; its sub-step goes last (the rate's divisor)."""

    def numbers(term: Term) -> list[float]:
        values = [float(getattr(term, name)) for name in names]
        return values + [0.0] * (TERM_REALS - 1 - len(values)) + [term._h]

    return numbers


#: Per kind: its reals, from the bound copy of the term (terms.c reads them in this order).
_REALS: dict[str, Callable[[Term], list[float]]] = {
    "ParameterChange": lambda t: [],  # its value is set as an FMU parameter
    "InputGain": lambda t: [t.gain],
    "InputOffset": lambda t: [t.offset],
    "ForceOffset": lambda t: [t.offset],
    "InputSaturation": lambda t: [t.lower, t.upper],
    "InputHysteresis": lambda t: [t.width],
    "InputLag": lambda t: [t._alpha],
    "InputDeadband": lambda t: [t.width],
    "InputDelay": _line,
    "CoulombForce": _feedback("force", "smoothing", "asymmetry"),
    "ViscousForce": _feedback("coefficient"),
    "StribeckForce": _feedback("force", "velocity", "smoothing"),
    "SpringForce": _feedback("coefficient", "rest"),
    "FlowDroop": _feedback("resistance"),
    "SensorDelay": _line,
    "SensorGain": lambda t: [t.gain],
    "SensorOffset": lambda t: [t.offset],
    "SensorChannelDelay": _line,
}
#: Kind code of every term kind the native FMU implements (``TERM_<Kind>`` in C).
NATIVE_KINDS: dict[str, int] = {name: code for code, name in enumerate(_REALS, start=1)}


def kind_code(term: Term) -> int:
    """The native code of a term's kind.

    Raises
    ------
    ExportError
        The kind has no native implementation.
    """
    kind = type(term).__name__
    if kind not in NATIVE_KINDS:
        raise ExportError(
            f"the model carries a {kind} term ({term.effect}), which the native FMU does not "
            "implement yet; export with --runtime python"
        )
    return NATIVE_KINDS[kind]


def encode_term(
    term: Term, inputs: Sequence[str], outputs: Sequence[str], every: float
) -> tuple[list[int], list[float], list[int]]:
    """One term as the data file stores it.

    Parameters
    ----------
    term : Term
        Not changed (a copy is bound).
    inputs : sequence of str
        The white-box inputs, in the order the FMU sets them.
    outputs : sequence of str
        The outputs its instance reads after each (sub-)step.
    every : float
        Time between two calls of the term [s] (:meth:`PartLayout.every`).

    Returns
    -------
    ints : list of int, length TERM_INTS
        Kind, input position, source position, sensor channel position (-1 where none),
        rate flag, number of sensor-delay channels.
    reals : list of float, length TERM_REALS
    channels : list of int
        Positions of a sensor delay's outputs (empty for other kinds).

    Raises
    ------
    ExportError
        The kind has no native implementation.
    """
    code = kind_code(term)
    bound = copy.deepcopy(term)
    bound.bind(inputs, outputs, every)
    channel = getattr(bound, "_j", -1)
    if isinstance(channel, np.ndarray):  # a sensor delay: the outputs it delays
        channels, output = [int(j) for j in channel], -1
    else:  # one sensor channel, -1 when this instance does not read it
        channels, output = [], int(channel)
    ints = [
        code,
        int(getattr(bound, "_i", -1)),
        int(getattr(bound, "_o", -1)),
        output,
        int(bool(getattr(term, "rate", False))),
        len(channels),
    ]
    reals = [float(v) for v in _REALS[type(term).__name__](bound)]
    return ints, reals + [0.0] * (TERM_REALS - len(reals)), channels


def kind_defines() -> str:
    """The ``#define TERM_<Kind> <code>`` lines of ``greybox_config.h``."""
    return "".join(f"#define TERM_{name} {code}\n" for name, code in NATIVE_KINDS.items())
