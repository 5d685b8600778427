"""Inducing-point selection strategies behind one small interface.

* ``equispaced`` — rows of X at equally spaced indices of the training sequence (the paper's
  choice for time series; the default).
* ``kmeans`` — k-means++ seeding and Lloyd iterations; the centroids.
* ``greedy`` — greedy variance reduction: the partial pivoted Cholesky of K(X, X), each new
  point being the training input worst explained by the points chosen so far.

All strategies are deterministic for a given ``numpy.random.Generator`` state; when
``n_inducing >= N`` every strategy returns all training inputs (the exact GP).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from fmu_greybox.gp.kernel import SquaredExponentialARD

FloatArray = NDArray[np.float64]


class InducingSelector(ABC):
    """Chooses inducing points for a training set."""

    name: ClassVar[str]

    def select(
        self,
        X: FloatArray,
        n_inducing: int,
        kernel: SquaredExponentialARD,
        rng: np.random.Generator,
    ) -> FloatArray:
        """Choose inducing points.

        Parameters
        ----------
        X : ndarray, shape (N, D)
            Training inputs, in the order of the training sequence.
        n_inducing : int
            Wanted number of points M (>= 1).
        kernel : SquaredExponentialARD
            Current kernel (used by strategies that measure coverage).
        rng : numpy.random.Generator

        Returns
        -------
        ndarray, shape (M', D)
            M' = min(M, N); ``greedy`` may return fewer when the rest of the data is
            already explained to within rounding.
        """
        if n_inducing < 1:
            raise ValueError(f"n_inducing must be at least 1, got {n_inducing}")
        if n_inducing >= X.shape[0]:
            return X.copy()
        return self._select(X, n_inducing, kernel, rng)

    @abstractmethod
    def _select(
        self,
        X: FloatArray,
        n_inducing: int,
        kernel: SquaredExponentialARD,
        rng: np.random.Generator,
    ) -> FloatArray:
        """Strategy proper, for ``1 <= n_inducing < N``."""


class EquispacedInducing(InducingSelector):
    """Rows of X at equally spaced indices, first and last row included."""

    name = "equispaced"

    def _select(
        self,
        X: FloatArray,
        n_inducing: int,
        kernel: SquaredExponentialARD,
        rng: np.random.Generator,
    ) -> FloatArray:
        return X[equispaced_indices(X.shape[0], n_inducing)].copy()


class KMeansInducing(InducingSelector):
    """k-means centroids (k-means++ seeding, at most ``max_iter`` Lloyd iterations).

    Parameters
    ----------
    max_iter : int
        Lloyd iterations.
    """

    name = "kmeans"

    def __init__(self, max_iter: int = 25) -> None:
        self.max_iter = max_iter

    def _select(
        self,
        X: FloatArray,
        n_inducing: int,
        kernel: SquaredExponentialARD,
        rng: np.random.Generator,
    ) -> FloatArray:
        centres = _kmeans_plus_plus(X, n_inducing, rng)
        sq_norms = np.einsum("nd,nd->n", X, X)
        for _ in range(self.max_iter):
            labels, dist = _nearest(X, sq_norms, centres)
            updated = _centroids(X, labels, dist, centres)
            if np.array_equal(updated, centres):
                break
            centres = updated
        return centres


class GreedyVarianceInducing(InducingSelector):
    """Greedy variance reduction (partial pivoted Cholesky of K(X, X)).

    Parameters
    ----------
    relative_tolerance : float
        Stop early once every residual variance is below this fraction of s².
    """

    name = "greedy"

    def __init__(self, relative_tolerance: float = 1e-12) -> None:
        self.relative_tolerance = relative_tolerance

    def _select(
        self,
        X: FloatArray,
        n_inducing: int,
        kernel: SquaredExponentialARD,
        rng: np.random.Generator,
    ) -> FloatArray:
        n = X.shape[0]
        residual = kernel.diag(X).astype(np.float64)  # (N,) diag(Kff − Qff)
        rows = np.empty((n_inducing, n))  # (M, N) rows of the partial Cholesky factor
        chosen: list[int] = []
        j = int(rng.integers(n))
        stop = self.relative_tolerance * float(kernel.variance)
        for i in range(n_inducing):
            if i > 0:
                j = int(np.argmax(residual))
            if residual[j] <= stop:
                break
            k_j = kernel(X[j : j + 1], X)[0]  # (N,)
            row = (k_j - rows[:i, j] @ rows[:i]) / np.sqrt(residual[j])
            rows[i] = row
            residual -= row * row
            residual[j] = 0.0
            chosen.append(j)
        return X[np.array(chosen)].copy()


SELECTORS: dict[str, type[InducingSelector]] = {
    cls.name: cls for cls in (EquispacedInducing, KMeansInducing, GreedyVarianceInducing)
}


def make_selector(strategy: str | InducingSelector) -> InducingSelector:
    """The selector named ``strategy`` (or ``strategy`` itself if already a selector).

    Raises
    ------
    ValueError
        Unknown name.
    """
    if isinstance(strategy, InducingSelector):
        return strategy
    try:
        return SELECTORS[strategy]()
    except KeyError:
        known = ", ".join(sorted(SELECTORS))
        raise ValueError(f"unknown inducing strategy {strategy!r}; use one of: {known}") from None


def equispaced_indices(n: int, m: int) -> NDArray[np.intp]:
    """``m`` distinct, equally spaced indices into ``range(n)`` (first and last if m > 1).

    Parameters
    ----------
    n : int
    m : int, 1 <= m <= n

    Returns
    -------
    ndarray, shape (m,), strictly increasing
    """
    if m == 1:
        return np.array([(n - 1) // 2], dtype=np.intp)
    return (np.arange(m, dtype=np.int64) * (n - 1) // (m - 1)).astype(np.intp)


def _kmeans_plus_plus(X: FloatArray, m: int, rng: np.random.Generator) -> FloatArray:
    """k-means++ seeding: ``m`` rows of X, each drawn with probability ∝ squared distance."""
    n = X.shape[0]
    centres = np.empty((m, X.shape[1]))
    centres[0] = X[rng.integers(n)]
    d2 = np.sum((X - centres[0]) ** 2, axis=1)
    for i in range(1, m):
        total = float(d2.sum())
        j = int(rng.choice(n, p=d2 / total)) if total > 0.0 else int(rng.integers(n))
        centres[i] = X[j]
        np.minimum(d2, np.sum((X - centres[i]) ** 2, axis=1), out=d2)
    return centres


def _nearest(
    X: FloatArray, sq_norms: FloatArray, centres: FloatArray
) -> tuple[NDArray[np.intp], FloatArray]:
    """Index of and squared distance to the nearest centre, each shape (N,)."""
    d2 = sq_norms[:, None] - 2.0 * (X @ centres.T) + np.einsum("md,md->m", centres, centres)
    labels = np.argmin(d2, axis=1)
    return labels, np.maximum(d2[np.arange(X.shape[0]), labels], 0.0)


def _centroids(
    X: FloatArray, labels: NDArray[np.intp], dist: FloatArray, previous: FloatArray
) -> FloatArray:
    """Cluster means; an empty cluster takes the point farthest from its centre."""
    m, d = previous.shape
    counts = np.bincount(labels, minlength=m)
    sums = np.column_stack([np.bincount(labels, weights=X[:, j], minlength=m) for j in range(d)])
    centres = previous.copy()
    filled = counts > 0
    centres[filled] = sums[filled] / counts[filled, None]
    for i, far in zip(np.flatnonzero(~filled), np.argsort(dist)[::-1], strict=False):
        centres[i] = X[far]
    return centres
