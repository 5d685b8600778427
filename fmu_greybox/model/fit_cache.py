"""Sparse-GP fits made once per training run, whoever asks for them.

One ``train`` fits the same corrector more than once when nothing tells the fits apart: the two
comparison chains (correctors on the white-box with named terms, and on the plain white-box)
see the same rows, features and targets on every stage upstream of the first named term; and a
calibration half of the model that ships is often the very rows a comparison chain was trained
on. A :class:`FitCache` shared by those chains fits each distinct problem once: the key is a
digest of the feature matrix, the targets and every setting of the fit, so a hit is the fit
that would have been made, bit for bit (a fit is deterministic for its inputs and seed). Chains
fitting side by side wait for a fit the other has started instead of making it again.
"""

from __future__ import annotations

import hashlib
import threading
from collections.abc import Callable
from concurrent.futures import Future

import numpy as np

from fmu_greybox.gp import SparseGPR
from fmu_greybox.gp.sgpr import every_row


class FitCache:
    """Fitted correctors by what they were fitted to (thread-safe).

    Attributes
    ----------
    made, reused : int
        Fits made, and fits answered from the cache (also while another thread was making it).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._fits: dict[str, Future[SparseGPR]] = {}
        self.made = 0
        self.reused = 0

    def fit(
        self, corrector: SparseGPR, X: np.ndarray, t: np.ndarray, make: Callable[[], SparseGPR]
    ) -> tuple[SparseGPR, bool]:
        """The fit of ``corrector`` (unfitted, its settings) to ``X``, ``t``.

        Parameters
        ----------
        corrector : SparseGPR
            The unfitted corrector; its settings are part of the key.
        X : ndarray, shape (n, d)
            Features.
        t : ndarray, shape (n,)
            Targets.
        make : callable
            Makes the fit when no one has (returns the fitted corrector).

        Returns
        -------
        (SparseGPR, bool)
            The fitted corrector, shared with whoever asked before, and whether it was reused.
        """
        key = fit_key(corrector, X, t)
        with self._lock:
            future = self._fits.get(key)
            owner = future is None
            if owner:
                future = self._fits[key] = Future()
                self.made += 1
            else:
                self.reused += 1
        if owner:
            try:
                future.set_result(make())
            except BaseException as exc:
                future.set_exception(exc)
                with self._lock:  # a failed fit is not remembered: the next asker tries again
                    self._fits.pop(key, None)
                raise
        return future.result(), not owner


def fit_key(corrector: SparseGPR, X: np.ndarray, t: np.ndarray) -> str:
    """Digest of a fit's problem: the settings of ``corrector`` and the exact bytes and shapes
    of ``X`` and ``t``. A limit on the rows the hyperparameters are optimised on that keeps
    every row is no limit: such a fit is the same as one without it."""
    settings = corrector.settings()
    if every_row(len(t), settings["optimise_rows"]):
        settings["optimise_rows"] = None
    digest = hashlib.sha256(repr(sorted(settings.items())).encode())
    for array in (X, t):
        array = np.ascontiguousarray(array, dtype=np.float64)
        digest.update(repr(array.shape).encode())
        digest.update(array.data)
    return digest.hexdigest()
