"""The named correction terms as the native grey-box FMU reads them (``native/terms.c``).

Everything here is made from the kinds' declarations (:class:`~fmu_greybox.model.terms.Native`
in :mod:`fmu_greybox.model.terms`): every kind with one has a code (its place in
:data:`~fmu_greybox.model.terms.TERM_KINDS`, from 1), and the FMU's generated
``greybox_config.h`` carries the table ``terms.c`` dispatches on (:func:`kind_defines`: per
code, the kind's C function, where it acts, whether it keeps a delay line). A term is stored as
:data:`TERM_INTS` integers (kind, positions, flags) and :data:`TERM_REALS` reals (its numbers,
in the order its declaration names them), both taken from a copy of the Python term after its
own ``bind()``: the lag coefficient, the delay in whole and fractional steps and the sub-step of
a rate are the numbers the Python runtime computes, not recomputed in C.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import numpy as np

from fmu_greybox.errors import ExportError
from fmu_greybox.model.terms import TERM_KINDS, Term

#: Integers and reals per term (``TERM_INTS``, ``TERM_REALS`` in terms.h).
TERM_INTS = 6
TERM_REALS = 6

#: Kind code of every term kind the native FMU implements (its row of the C kind table).
NATIVE_KINDS: dict[str, int] = {
    name: code
    for code, name in enumerate(
        (name for name, kind in TERM_KINDS.items() if kind.native is not None), start=1
    )
}


def _reals(term: Term) -> list[float]:
    """A bound term's reals, as its declaration names them; a feedback term's sub-step (the
    rate's divisor) goes last."""
    values = term.native.numbers(term)
    if term.feedback:
        values += [0.0] * (TERM_REALS - 1 - len(values)) + [term._h]
    return values


def _place(kind: type[Term]) -> str:
    """Where a kind acts, as the C enum of terms.h names it."""
    if kind.feedback:
        return "TERM_FEEDBACK"
    if kind.acts_on_inputs:
        return "TERM_INPUT"
    if kind.acts_on_outputs:
        return "TERM_CHANNELS" if kind.native.channels else "TERM_OUTPUT"
    return "TERM_PARAMETER"


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
    reals = _reals(bound)
    return ints, reals + [0.0] * (TERM_REALS - len(reals)), channels


def kind_defines() -> str:
    """The kind table of ``greybox_config.h``: ``TERM_KIND_TABLE(X)`` calls
    ``X(function, place, line)`` once per kind, in the order of the codes (from 1)."""
    rows = []
    for name, code in sorted(NATIVE_KINDS.items(), key=lambda item: item[1]):  # by code
        kind = TERM_KINDS[name]
        function = kind.native.function or "NULL"
        rows.append(
            f"    X({function}, {_place(kind)}, {int(kind.native.line)}) /* {code} {name} */"
        )
    return "#define TERM_KIND_TABLE(X) \\\n" + " \\\n".join(rows) + "\n"
