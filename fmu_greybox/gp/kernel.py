"""Squared-exponential kernel with ARD length-scales, and its derivatives.

k(x, x') = s² · exp(−½ Σ_d (x_d − x'_d)² / ℓ_d²)

Two ways to evaluate it live here:

* :class:`SquaredExponentialARD` — the plain kernel, for small matrices and references.
* the *expanded* form used on the training hot path. The exponent is bilinear in the
  feature rows ``[x, x², 1]`` (inputs, ``(N, 2D+1)``) and ``[z/ℓ², −1/(2ℓ²), log s² − ½|z/ℓ|²]``
  (inducing points, ``(M, 2D+1)``), so a whole cross-covariance matrix is one thin matrix
  product followed by one in-place ``exp``. The input features do not depend on the
  hyperparameters and are built once per training set.

Derivatives come from *moments*: given a weight matrix ``W = (∂F/∂K) ∘ K`` of shape
``(M, N)``, every derivative of ``F`` with respect to the length-scales, the first argument's
points and the signal variance follows from the thin product ``S = W @ [x, x², 1]``
(``(M, 2D+1)``) — one pass over ``W`` instead of one per input dimension.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SquaredExponentialARD:
    """The SE-ARD covariance function.

    Parameters
    ----------
    lengthscales : ndarray, shape (D,)
        Positive length-scale per input dimension.
    variance : float
        Signal variance s² (> 0).
    """

    lengthscales: FloatArray
    variance: float

    def __call__(self, X1: FloatArray, X2: FloatArray) -> FloatArray:
        """Covariance matrix between two sets of points.

        Parameters
        ----------
        X1 : ndarray, shape (n1, D)
        X2 : ndarray, shape (n2, D)

        Returns
        -------
        ndarray, shape (n1, n2)
        """
        A = X1 / self.lengthscales
        B = X2 / self.lengthscales
        sq = np.einsum("id,id->i", A, A)[:, None] + np.einsum("jd,jd->j", B, B)[None, :]
        sq -= 2.0 * (A @ B.T)
        np.maximum(sq, 0.0, out=sq)
        return self.variance * np.exp(-0.5 * sq)

    def diag(self, X: FloatArray) -> FloatArray:
        """Prior variances k(x, x), shape (n,), for ``X`` of shape (n, D)."""
        return np.full(X.shape[0], float(self.variance))


def expand_inputs(X: FloatArray) -> FloatArray:
    """Input feature rows ``[x, x², 1]``.

    Parameters
    ----------
    X : ndarray, shape (N, D)

    Returns
    -------
    ndarray, shape (N, 2D+1), C-contiguous float64
    """
    n = X.shape[0]
    return np.ascontiguousarray(np.hstack([X, X * X, np.ones((n, 1))]), dtype=np.float64)


def expand_inducing(Z: FloatArray, lengthscales: FloatArray, variance: float) -> FloatArray:
    """Inducing feature rows ``[z/ℓ², −1/(2ℓ²), log s² − ½|z/ℓ|²]``.

    ``expand_inducing(Z, ℓ, s²) @ expand_inputs(X).T`` is the log of the covariance matrix
    ``K(Z, X)``.

    Parameters
    ----------
    Z : ndarray, shape (M, D)
    lengthscales : ndarray, shape (D,)
    variance : float

    Returns
    -------
    ndarray, shape (M, 2D+1)
    """
    inv_sq = 1.0 / (lengthscales * lengthscales)
    Zs = Z / lengthscales
    offset = np.log(variance) - 0.5 * np.einsum("md,md->m", Zs, Zs)
    m = Z.shape[0]
    return np.hstack([Z * inv_sq, np.broadcast_to(-0.5 * inv_sq, (m, Z.shape[1])), offset[:, None]])


def cross_covariance(
    Z_features: FloatArray, X_features: FloatArray, out: FloatArray | None = None
) -> FloatArray:
    """``K(Z, X)`` from expanded features: one matrix product and one in-place exp.

    Parameters
    ----------
    Z_features : ndarray, shape (M, 2D+1)
        From :func:`expand_inducing`.
    X_features : ndarray, shape (N, 2D+1)
        From :func:`expand_inputs`.
    out : ndarray, shape (M, N), optional
        Preallocated C-contiguous buffer (avoids page faults on large matrices).

    Returns
    -------
    ndarray, shape (M, N)
    """
    K = np.matmul(Z_features, X_features.T, out=out)
    return np.exp(K, out=K)


def inducing_covariance(Z: FloatArray, lengthscales: FloatArray, variance: float) -> FloatArray:
    """``K(Z, Z)`` with the expanded form and an exact diagonal ``s²``.

    Parameters
    ----------
    Z : ndarray, shape (M, D)
    lengthscales : ndarray, shape (D,)
    variance : float

    Returns
    -------
    ndarray, shape (M, M), symmetric
    """
    K = cross_covariance(expand_inducing(Z, lengthscales, variance), expand_inputs(Z))
    K = 0.5 * (K + K.T)
    np.fill_diagonal(K, variance)
    return K


def moment_gradients(
    Z: FloatArray, lengthscales: FloatArray, moments: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Derivatives of ``F`` from the moments of ``W = (∂F/∂K) ∘ K``, ``K = K(Z, X)``.

    Parameters
    ----------
    Z : ndarray, shape (M, D)
        The first argument of the kernel matrix.
    lengthscales : ndarray, shape (D,)
    moments : ndarray, shape (M, 2D+1)
        ``W @ expand_inputs(X)``: columns ``Σ_n W x``, ``Σ_n W x²``, ``Σ_n W``.

    Returns
    -------
    d_log_lengthscales : ndarray, shape (D,)
        ∂F/∂log ℓ_d = Σ_mn W_mn (z_md − x_nd)² / ℓ_d².
    d_first_argument : ndarray, shape (M, D)
        ∂F/∂z_md through the first argument only = −Σ_n W_mn (z_md − x_nd) / ℓ_d².

    Notes
    -----
    ∂F/∂log s² = ``moments[:, -1].sum()`` since K is proportional to s².
    """
    d = Z.shape[1]
    wx, wxx, w = moments[:, :d], moments[:, d : 2 * d], moments[:, 2 * d]
    inv_sq = 1.0 / (lengthscales * lengthscales)
    d_log_ell = (w @ (Z * Z) - 2.0 * np.einsum("md,md->d", Z, wx) + wxx.sum(axis=0)) * inv_sq
    d_first = -(Z * w[:, None] - wx) * inv_sq
    return d_log_ell, d_first
