"""The fitted posterior, precomputed for fast prediction in original units.

With ``k = K(Z, x)`` (M,), ``L`` the Cholesky factor of Kuu and ``L_B`` that of
``B = I + AAᵀ`` (see :mod:`fmu_greybox.gp.bound`), the VFE predictive distribution of the
latent function is

    v    = L⁻¹ k                                                             (M,)
    mean = vᵀ γ,                      γ = L_B⁻ᵀ c                           (M,)
    var  = s² − |v|² + |L_B⁻¹ v|²

i.e. mean ``kᵀ L⁻ᵀ L_B⁻ᵀ c`` and variance ``s² − kᵀ Kuu⁻¹ k + kᵀ (Kuu + σ⁻² Kuf Kfu)⁻¹ k``,
evaluated through the bounded vector v with two backward-stable triangular solves.

The textbook shortcuts — ``kᵀα`` with ``α = L⁻ᵀγ``, and ``kᵀ(Kuu⁻¹ − Σ)k`` with a
precomputed M×M matrix or its triangular factor — lose digits to cancellation as Kuu's
condition number grows (equally spaced inducing points on a slow trajectory are close
together), and are not faster where it matters: the factor's matrix-vector product (BLAS
``trmv``/``gemv``/``symv``) is multi-threaded in OpenBLAS from M ≈ 100 on, so every
single-point call may have to wake a worker thread — median 8 ms per call measured on a
loaded 2-CPU machine at M = 200. ``trsv`` never threads: a single-point prediction is one
affine map of x, one thin matrix-vector product and an ``exp`` for the kernel row, two
in-place ``trsv`` and three dots, with no thread hand-offs. Input standardisation and
length-scales are folded into one scaling of the inducing points; outputs are mapped back
to original units by two scalars.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_triangular
from scipy.linalg.blas import dtrsv

FloatArray = NDArray[np.float64]

PREDICT_CHUNK = 8192
"""Rows per block in batched prediction (bounds the (n, M) temporaries)."""


@dataclass(frozen=True)
class Posterior:
    """A fitted sparse GP: standardisation, hyperparameters and posterior factors.

    All primary fields are what a model file stores; everything prediction needs beyond
    them is derived deterministically in ``__post_init__``, so a loaded model predicts
    bit-for-bit like the fitted one.

    Parameters
    ----------
    x_mean, x_scale : ndarray, shape (D,)
        Input standardisation: ``x_std = (x − x_mean) / x_scale``.
    y_mean, y_scale : float
        Target standardisation.
    lengthscales : ndarray, shape (D,)
        In standardised input units.
    signal_variance, noise_variance : float
        In standardised target units.
    inducing_points : ndarray, shape (M, D)
        In standardised input units.
    mean_weights : ndarray, shape (M,)
        γ = L_B⁻ᵀ c, standardised units.
    chol_uu, chol_b : ndarray, shape (M, M)
        Lower Cholesky factors of ``Kuu + jitter·I`` and ``B``.
    """

    x_mean: FloatArray
    x_scale: FloatArray
    y_mean: float
    y_scale: float
    lengthscales: FloatArray
    signal_variance: float
    noise_variance: float
    inducing_points: FloatArray
    mean_weights: FloatArray
    chol_uu: FloatArray
    chol_b: FloatArray
    _input_weight: FloatArray = field(init=False, repr=False)
    _input_offset: FloatArray = field(init=False, repr=False)
    _z_scaled: FloatArray = field(init=False, repr=False)
    _z_offset: FloatArray = field(init=False, repr=False)
    _chol_uu_f: FloatArray = field(init=False, repr=False)
    _chol_b_f: FloatArray = field(init=False, repr=False)
    _alpha: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        weight = 1.0 / (self.x_scale * self.lengthscales)  # (D,)
        z_scaled = np.ascontiguousarray(self.inducing_points / self.lengthscales)  # (M, D)
        derived = {
            "_input_weight": weight,
            "_input_offset": self.x_mean * weight,
            "_z_scaled": z_scaled,
            "_z_offset": math.log(self.signal_variance)
            - 0.5 * np.einsum("md,md->m", z_scaled, z_scaled),
            "_chol_uu_f": np.asfortranarray(self.chol_uu),
            "_chol_b_f": np.asfortranarray(self.chol_b),
            "_alpha": solve_triangular(
                self.chol_uu, self.mean_weights, lower=True, trans="T", check_finite=False
            ),
        }
        for name, value in derived.items():
            object.__setattr__(self, name, value)

    @property
    def n_inducing(self) -> int:
        """M, the number of inducing points."""
        return int(self.inducing_points.shape[0])

    @property
    def input_dim(self) -> int:
        """D, the number of inputs."""
        return int(self.inducing_points.shape[1])

    def predict(self, X: FloatArray, full_noise: bool = False) -> tuple[FloatArray, FloatArray]:
        """Predictive mean and variance at many points, in original units.

        Parameters
        ----------
        X : ndarray, shape (n, D)
        full_noise : bool
            Add the noise variance (predict observations rather than the latent function).

        Returns
        -------
        mean, var : ndarray, shape (n,)
        """
        n = X.shape[0]
        mean = np.empty(n)
        var = np.empty(n)
        for start in range(0, n, PREDICT_CHUNK):
            rows = slice(start, min(start + PREDICT_CHUNK, n))
            mean[rows], var[rows] = self._predict_block(X[rows])
        if full_noise:
            var += self.noise_variance
        return mean * self.y_scale + self.y_mean, var * (self.y_scale * self.y_scale)

    def _predict_block(self, X: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Standardised mean and latent variance, shapes (n,), for raw inputs (n, D)."""
        Xs = X * self._input_weight - self._input_offset  # (n, D)
        E = self._z_scaled @ Xs.T  # (M, n)
        E += self._z_offset[:, None]
        E -= 0.5 * np.einsum("nd,nd->n", Xs, Xs)[None, :]
        Kzx = np.exp(E, out=E)  # (M, n)
        V = solve_triangular(self._chol_uu_f, Kzx, lower=True, check_finite=False)  # (M, n)
        mean = self.mean_weights @ V
        Wb = solve_triangular(self._chol_b_f, V, lower=True, check_finite=False)  # (M, n)
        var = self.signal_variance - np.einsum("mn,mn->n", V, V) + np.einsum("mn,mn->n", Wb, Wb)
        return mean, np.maximum(var, 0.0)

    def predict_one(self, x: FloatArray, full_noise: bool = False) -> tuple[float, float]:
        """Predictive mean and variance at one point, in original units.

        The co-simulation hot path (see the module notes): no loop over inducing points,
        no allocation beyond a few length-M vectors, no BLAS thread hand-offs.

        Parameters
        ----------
        x : ndarray, shape (D,)
        full_noise : bool
            Add the noise variance.

        Returns
        -------
        mean, var : float
        """
        xs = x * self._input_weight
        xs -= self._input_offset
        mean, var = self._mean_and_variance(self._kernel_row(xs))
        if full_noise:
            var += self.noise_variance
        return mean * self.y_scale + self.y_mean, var * (self.y_scale * self.y_scale)

    def predict_one_grad(self, x: FloatArray) -> tuple[float, float, FloatArray]:
        """Latent mean and variance at one point, and the gradient of the mean.

        For first-order propagation of input uncertainty through the corrector chain.

        Parameters
        ----------
        x : ndarray, shape (D,)

        Returns
        -------
        mean, var : float
            Original units; ``var`` is the latent variance (no noise).
        grad : ndarray, shape (D,)
            ∂mean/∂x, original units.
        """
        xs = x * self._input_weight
        xs -= self._input_offset
        k = self._kernel_row(xs)
        # mean = αᵀk with α = L⁻ᵀγ, and ∂k_m/∂xs = k_m (zs_m − xs)
        weighted = self._alpha * k
        grad = (weighted @ self._z_scaled - weighted.sum() * xs) * self._input_weight
        mean, var = self._mean_and_variance(k)
        return (
            mean * self.y_scale + self.y_mean,
            var * (self.y_scale * self.y_scale),
            grad * self.y_scale,
        )

    def _kernel_row(self, xs: FloatArray) -> FloatArray:
        """k = K(Z, x), shape (M,), for a standardised, length-scale-scaled point xs (D,)."""
        e = self._z_scaled @ xs
        e += self._z_offset
        e -= 0.5 * (xs @ xs)
        return np.exp(e, out=e)

    def _mean_and_variance(self, k: FloatArray) -> tuple[float, float]:
        """Latent mean vᵀγ and variance s² − |v|² + |L_B⁻¹v|², v = L⁻¹k; overwrites k."""
        # dtrsv(a, x, incx, offx, lower, trans, diag, overwrite_x): positional arguments
        # save a microsecond per call
        v = dtrsv(self._chol_uu_f, k, 1, 0, 1, 0, 0, 1)  # L⁻¹k, in place
        mean = float(self.mean_weights @ v)
        vv = float(v @ v)
        w = dtrsv(self._chol_b_f, v, 1, 0, 1, 0, 0, 1)  # L_B⁻¹v, in place
        return mean, max(self.signal_variance - vv + float(w @ w), 0.0)
