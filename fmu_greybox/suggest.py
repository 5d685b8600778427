"""Suggestions ("did you mean ...?"): the one helper behind every error message.

A name the user typed (a column, a field, an FMU variable, an effect) is compared with the names
that exist: a match that differs only in case is the one suggestion; otherwise up to
:data:`MAX_SUGGESTIONS` names that look alike (:func:`difflib.get_close_matches` on lower case,
cutoff :data:`CUTOFF`), best first.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable

__all__ = ["CUTOFF", "MAX_SUGGESTIONS", "closest", "did_you_mean"]

#: Most names suggested at once.
MAX_SUGGESTIONS = 3
#: Similarity (0..1) below which a name is not suggested.
CUTOFF = 0.6


def closest(name: object, candidates: Iterable[object]) -> list[str]:
    """Candidates that look like ``name``, best first.

    Parameters
    ----------
    name : object
        What the user gave (shown with ``str``).
    candidates : iterable
        The names that exist (shown with ``str``; repeats ignored).

    Returns
    -------
    list of str
        The candidate equal to ``name`` but for case, alone; else up to
        :data:`MAX_SUGGESTIONS` close matches; else nothing.
    """
    wanted = str(name).lower()
    by_lower: dict[str, str] = {}
    for candidate in candidates:
        by_lower.setdefault(str(candidate).lower(), str(candidate))
    if wanted in by_lower:
        return [by_lower[wanted]]
    hits = difflib.get_close_matches(wanted, list(by_lower), n=MAX_SUGGESTIONS, cutoff=CUTOFF)
    return [by_lower[hit] for hit in hits]


def did_you_mean(name: object, candidates: Iterable[object], fallback: Iterable[str] = ()) -> str:
    """``"; did you mean 'a' or 'b'?"``, or ``""`` when nothing looks like ``name``.

    Parameters
    ----------
    name : object
        What the user gave.
    candidates : iterable
        The names that exist.
    fallback : iterable of str
        Suggested when no candidate looks like ``name`` (e.g. columns commonly holding time).

    Returns
    -------
    str
        A clause to append to a sentence about ``name``.
    """
    hits = closest(name, candidates) or list(fallback)
    return "; did you mean " + " or ".join(repr(h) for h in hits) + "?" if hits else ""
