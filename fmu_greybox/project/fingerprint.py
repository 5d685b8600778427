"""Rows recognised by their values: which rows of a recording a model was trained on.

A model keeps one 64-bit digest per training row, over the values the chain saw in that row
(every FMU input as fed, then every stage target, in the project's units). ``validate`` digests
the rows of the recording it is given the same way and scores only the rows whose digest is not
among them, whatever the file is called, wherever its rows sit and whatever units sidecar lies
beside it. Times are not part of a row: a copy with shifted time stamps is recognised too.
"""

from __future__ import annotations

import hashlib

import numpy as np

from fmu_greybox.project.data import ProjectData

__all__ = ["data_rows", "row_digests", "trained_mask"]


def data_rows(data: ProjectData) -> np.ndarray:
    """The values the chain sees in each row: every FMU input as fed, then every stage target.

    Returns
    -------
    ndarray, shape (n, n_inputs + Q)
    """
    return np.column_stack([data.binding.matrix(data.recording), data.outputs])


def row_digests(values: np.ndarray) -> np.ndarray:
    """One digest per row of ``values``.

    Parameters
    ----------
    values : ndarray, shape (n, k)
        The rows (float64; ``-0.0`` counts as ``0.0``).

    Returns
    -------
    ndarray of uint64, shape (n,)
        BLAKE2b digests of each row's bytes, 8 bytes each.
    """
    rows = np.ascontiguousarray(np.asarray(values, dtype="<f8") + 0.0)
    digests = np.empty(rows.shape[0], dtype=np.uint64)
    for i, row in enumerate(rows):
        digests[i] = int.from_bytes(
            hashlib.blake2b(row.tobytes(), digest_size=8).digest(), "little"
        )
    return digests


def trained_mask(values: np.ndarray, trained: np.ndarray) -> np.ndarray:
    """Which rows of ``values`` a model was trained on.

    Parameters
    ----------
    values : ndarray, shape (n, k)
        Rows arranged as for :func:`row_digests`.
    trained : ndarray of uint64, shape (m,)
        The digests of the training rows.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    return np.isin(row_digests(values), trained)
