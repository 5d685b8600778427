"""Rows recognised by their values: which rows of a recording a model was trained on.

A model keeps one 64-bit digest per training row, over the values the chain saw in that row
(every FMU input as fed, then every stage target, in the project's units). ``validate`` digests
the rows of the recording it is given the same way and scores only the rows whose digest is not
among them, whatever the file is called, wherever its rows sit and whatever units sidecar lies
beside it. Times are not part of a row: a copy with shifted time stamps is recognised too.

Values are compared at the recordings' resolution, not bit for bit: each column is cut into
cells of :data:`RESOLUTION` times its full scale (the largest magnitude among the training
rows), and a row's digest is that of its cells. A value within :data:`TOLERANCE` of full scale
of a cell's edge is looked up in both cells, so a copy re-saved with 12 or more significant
digits (as spreadsheet tools do), or converted to other units and back, is recognised too;
two rows that differ by less than :data:`TOLERANCE` of full scale in every column count as the
same row.
"""

from __future__ import annotations

import hashlib
import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fmu_greybox.data.recording import Recording
from fmu_greybox.project.data import ProjectData

__all__ = [
    "COPY_SHARE",
    "RESOLUTION",
    "TOLERANCE",
    "RowFingerprint",
    "copy_message",
    "data_rows",
    "find_copy",
    "fingerprint",
    "recorded_rows",
    "row_digests",
    "shared_rows",
    "trained_mask",
]

#: Width of a cell, as a fraction of its column's full scale.
RESOLUTION = 1e-9
#: Two values closer than this fraction of full scale are the same value: a copy with 12
#: significant digits moves a value by at most 5e-12 of its magnitude.
TOLERANCE = 1e-11
#: A recording more than this share of whose rows are rows of another is a copy of it.
COPY_SHARE = 0.5
#: Largest cell index kept (values far beyond full scale share the last cell).
_LARGEST_CELL = 2.0**52


@dataclass(frozen=True)
class RowFingerprint:
    """The digests of a set of rows, and the scale their values were cut at.

    Attributes
    ----------
    digests : ndarray of uint64, shape (m,)
        Sorted, distinct digests (:func:`row_digests`).
    scale : ndarray of float64, shape (k,), or None
        Full scale of each column; ``None`` for digests of exact values (model folders of
        format version 4 and earlier), recognising only bit-identical rows.
    """

    digests: np.ndarray
    scale: np.ndarray | None = None


def data_rows(data: ProjectData) -> np.ndarray:
    """The values the chain sees in each row: every FMU input as fed, then every stage target.

    Returns
    -------
    ndarray, shape (n, n_inputs + Q)
    """
    return np.column_stack([data.binding.matrix(data.recording), data.outputs])


def _digest(rows: np.ndarray) -> np.ndarray:
    """BLAKE2b digest of each row's bytes, 8 bytes each, shape (n,) of uint64."""
    rows = np.ascontiguousarray(rows)
    digests = np.empty(rows.shape[0], dtype=np.uint64)
    for i, row in enumerate(rows):
        digests[i] = int.from_bytes(
            hashlib.blake2b(row.tobytes(), digest_size=8).digest(), "little"
        )
    return digests


def _mix(x: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser: every bit of ``x`` (uint64) moves every bit of the result."""
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def _cell_digest(cells: np.ndarray) -> np.ndarray:
    """A 64-bit digest of each row of cell indices, shape (n,) of uint64 (vectorised)."""
    digest = np.full(cells.shape[0], cells.shape[1], dtype=np.uint64)
    for column in np.ascontiguousarray(cells).view(np.uint64).T:
        digest = _mix(digest + np.uint64(0x9E3779B97F4A7C15) + column)
    return digest


def _cells(values: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each value's cell and its place in it.

    Returns
    -------
    cells : ndarray of int64, shape (n, k)
    offset : ndarray, shape (n, k)
        From the cell's centre, in cells (-0.5 to 0.5).
    """
    z = np.clip(
        np.asarray(values, dtype=float) / (scale * RESOLUTION), -_LARGEST_CELL, _LARGEST_CELL
    )
    centre = np.rint(z)
    return centre.astype("<i8"), z - centre


def full_scale(values: np.ndarray) -> np.ndarray:
    """The largest magnitude of each column (1 for a column of zeros), shape (k,)."""
    scale = np.max(np.abs(values), axis=0) if len(values) else np.ones(values.shape[1])
    return np.where(scale > 0, scale, 1.0)


def row_digests(values: np.ndarray, scale: np.ndarray | None = None) -> np.ndarray:
    """One digest per row of ``values``.

    Parameters
    ----------
    values : ndarray, shape (n, k)
        The rows (float64; ``-0.0`` counts as ``0.0``).
    scale : ndarray, shape (k,), optional
        Full scale of each column: the digests are those of the rows' cells. Without it, of
        the exact values.

    Returns
    -------
    ndarray of uint64, shape (n,)
    """
    if scale is None:
        return _digest(np.asarray(values, dtype="<f8") + 0.0)
    return _cell_digest(_cells(values, scale)[0])


def fingerprint(values: np.ndarray) -> RowFingerprint:
    """The fingerprint of rows, cut at their own full scale.

    Parameters
    ----------
    values : ndarray, shape (n, k)

    Returns
    -------
    RowFingerprint
    """
    values = np.asarray(values, dtype=float)
    scale = full_scale(values)
    return RowFingerprint(np.unique(row_digests(values, scale)), scale)


def trained_mask(values: np.ndarray, trained: RowFingerprint) -> np.ndarray:
    """Which rows of ``values`` are among the fingerprinted rows (within :data:`TOLERANCE`).

    Parameters
    ----------
    values : ndarray, shape (n, k)
        Rows arranged as for :func:`row_digests`.
    trained : RowFingerprint
        The training rows.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    known = np.sort(trained.digests)
    if trained.scale is None:
        return _among(row_digests(values), known)
    cells, offset = _cells(values, trained.scale)
    found = _among(_cell_digest(cells), known)
    near = np.abs(offset) > 0.5 - TOLERANCE / RESOLUTION
    unsure = np.flatnonzero(~found & near.any(axis=1))
    patterns, group = np.unique(near[unsure], axis=0, return_inverse=True)
    for g, pattern in enumerate(patterns):
        rows = unsure[group.ravel() == g]
        found[rows] = _found_next_door(cells[rows], np.sign(offset[rows]), pattern, known)
    return found


def _found_next_door(
    cells: np.ndarray, sides: np.ndarray, near: np.ndarray, known: np.ndarray
) -> np.ndarray:
    """Whether rows near cell edges in the same columns are known once moved across them.

    Parameters
    ----------
    cells : ndarray of int64, shape (n, k)
        The rows' cells.
    sides : ndarray, shape (n, k)
        The side of its cell's centre each value lies on (-1, 0 or 1).
    near : ndarray of bool, shape (k,)
        The columns whose values lie near a cell's edge, the same in every row.
    known : ndarray of uint64, shape (m,), sorted
        The training rows' digests.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    columns = np.flatnonzero(near)
    steps = sides[:, columns].astype("<i8")
    found = np.zeros(len(cells), dtype=bool)
    for moved in itertools.product((0, 1), repeat=columns.size):
        if any(moved):
            candidate = cells.copy()
            candidate[:, columns] += steps * np.array(moved, dtype="<i8")
            found |= _among(_cell_digest(candidate), known)
    return found


def _among(digests: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Which ``digests`` are in the sorted array ``known``, by binary search.

    Parameters
    ----------
    digests : ndarray of uint64, shape (n,)
    known : ndarray of uint64, shape (m,), sorted

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    if known.size == 0:
        return np.zeros(digests.shape, dtype=bool)
    at = np.minimum(np.searchsorted(known, digests), known.size - 1)
    return known[at] == digests


def shared_rows(values: np.ndarray, other: RowFingerprint) -> float:
    """The share of the rows of ``values`` that are rows of ``other``, 0 to 1.

    Parameters
    ----------
    values : ndarray, shape (n, k)
    other : RowFingerprint

    Returns
    -------
    float
    """
    return float(np.mean(trained_mask(values, other))) if len(values) else 0.0


def recorded_rows(recordings: Sequence[Recording]) -> list[tuple[str, np.ndarray]]:
    """Each recording's file and its rows of the signals they all hold (sorted by name), for
    :func:`find_copy`.

    Returns
    -------
    list of (str, ndarray of shape (n_i, k))
    """
    names = sorted(set.intersection(*(set(r.signals) for r in recordings))) if recordings else []
    return [
        (
            str(r.source),
            np.column_stack([r.signals[n] for n in names]) if names else np.empty((r.n_samples, 0)),
        )
        for r in recordings
    ]


def find_copy(
    recordings: Sequence[tuple[str, np.ndarray]],
) -> tuple[str, str, float] | None:
    """The first recording most of whose rows are rows of one given before it.

    Parameters
    ----------
    recordings : sequence of (name, ndarray of shape (n_i, k))
        Each recording's name and rows, all with the same columns.

    Returns
    -------
    (copy, original, share) or None
        The names, and the share of the copy's rows found in the original (over
        :data:`COPY_SHARE`); ``None`` when no recording is such a copy.
    """
    seen: list[tuple[str, RowFingerprint]] = []
    if any(np.shape(values)[1] == 0 for _, values in recordings):
        return None  # nothing to compare
    for name, values in recordings:
        for original, rows in seen:
            share = shared_rows(values, rows)
            if share > COPY_SHARE:
                return name, original, share
        seen.append((name, fingerprint(values)))
    return None


def copy_message(copy: str, original: str, share: float) -> str:
    """What :func:`find_copy`'s finding means, for an error message."""
    return (
        f"{copy}: {share:.1%} of its rows are rows of {original} (at that recording's "
        f"resolution: a copy, rounded to 12 or more significant digits, or with other time "
        "stamps, counts as the same recording), so it is not independent evidence"
    )
