"""The fitted posterior, precomputed for fast prediction in original units.

With ``k = K(Z, x)`` (M,), ``L`` the Cholesky factor of Kuu and ``L_B`` that of
``B = I + AAᵀ`` (see :mod:`fmu_greybox.gp.bound`), the VFE predictive distribution of the
latent function is

    v    = L⁻¹ k                                                             (M,)
    mean = vᵀ γ,                      γ = L_B⁻ᵀ c                           (M,)
    var  = s² − |v|² + |L_B⁻¹ v|² = s² − vᵀ C v,    C = I − B⁻¹            (M×M)

i.e. mean ``kᵀ L⁻ᵀ L_B⁻ᵀ c`` and variance ``s² − kᵀ Kuu⁻¹ k + kᵀ (Kuu + σ⁻² Kuf Kfu)⁻¹ k``.
Batched prediction (:meth:`Posterior.predict`) evaluates exactly this, with two triangular
solves per block of points.

Single points (:meth:`Posterior.predict_one`, the co-simulation hot path) need one
triangular solve only. ``C`` is positive semi-definite with eigenvalues in [0, 1); its
*reverse* Cholesky factorisation ``C = U Uᵀ`` (U upper triangular) makes ``Uᵀ L⁻¹`` lower
triangular, the inverse of ``H = L U⁻ᵀ``, so that

    g    = H⁻¹ k = Uᵀ v                                                      (M,)
    mean = βᵀ g,                      β = U⁻¹ γ                              (M,)
    var  = s² − |g|²

H and β are derived once per posterior. One ``trsv`` streams M²/2 numbers instead of two
solves' M², and nothing is lost in accuracy: the solve is backward stable in H (whose
condition number was below L's on the fitted benchmark models), β is bounded (in the
eigenbasis of AAᵀ it is (Wᵀy)ᵢ / (σ √(1 + μᵢ)), no small divisor), and against an
extended-precision evaluation of the two-solve form the errors of both forms were the same
(N = 25 000, M = 400: mean 1e-11 absolute, variance 1e-9 relative, standardised units).

The textbook shortcuts — ``kᵀα`` with ``α = L⁻ᵀγ``, and ``kᵀ(Kuu⁻¹ − Σ)k`` with an explicit
M×M matrix or its explicit triangular factor — lose digits to cancellation as Kuu's
condition number grows (equally spaced inducing points on a slow trajectory are close
together: 6× the mean error above for ``kᵀα``), and their matrix-vector products (BLAS
``trmv``/``gemv``/``symv``) are multi-threaded in OpenBLAS from M ≈ 100 on, so a call may
have to wake a worker thread (a median of 8 ms per call was measured on a loaded 2-CPU
machine at M = 200); ``trsv`` never threads. ``α`` serves only the mean's gradient.

The kernel row is one thin matrix-vector product with the precomputed ``[Z/ℓ, log s² −
½|Z/ℓ|², 1]`` (M, D+2) and the point ``[x_s, 1, −½|x_s|²]``, followed by one in-place
``exp``; input standardisation and length-scales are folded into one affine map of x, and
outputs are mapped back to original units by two scalars. BLAS routines are called through
scipy's wrappers with positional arguments (a microsecond per call less than keywords and
``scipy.linalg`` functions).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cho_solve, solve_triangular
from scipy.linalg.blas import daxpy, ddot, dgemv, dtrsv

from fmu_greybox.gp.linalg import jittered_cholesky

FloatArray = NDArray[np.float64]

PREDICT_CHUNK = 8192
"""Rows per block in batched prediction (bounds the (n, M) temporaries)."""

EIGENVALUE_FLOOR = 1e-12
"""Smallest eigenvalue of ``C = I − B⁻¹`` kept for its reverse Cholesky factorisation.

C's eigenvalues μ/(1+μ), μ those of AAᵀ, lie in [0, 1), but the stored factor L_B fixes the
small ones only to about 1e-16 ‖B‖ (B's largest eigenvalue reaches 1e10 when the noise is
small), so C computed from it can be slightly indefinite: down to −4e-8 on a fitted
300-point stage. Eigenvalues below the floor are raised to it by a low-rank correction along
their eigenvectors q, which changes the variance by ``(floor − eigenvalue) ((L⁻¹k)ᵀq)²``
each, i.e. by less than ``(floor + |eigenvalue|) s²``: by what the stored factor leaves
undetermined (prediction through L_B⁻¹ is uncertain by as much). Measured alternatives were
worse: a uniform jitter
shifts every eigenvalue (up to 7e-4 relative change in the variance), and rebuilding C
from all its eigenpairs adds their rounding errors (10× the variance error)."""


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
    _kernel_map: FloatArray = field(init=False, repr=False)
    _chol_uu_f: FloatArray = field(init=False, repr=False)
    _chol_b_f: FloatArray = field(init=False, repr=False)
    _point_factor: FloatArray = field(init=False, repr=False)
    _point_weights: FloatArray = field(init=False, repr=False)
    _grad_map: FloatArray = field(init=False, repr=False)
    _grad_scale: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        weight = 1.0 / (self.x_scale * self.lengthscales)  # (D,)
        z_scaled = np.ascontiguousarray(self.inducing_points / self.lengthscales)  # (M, D)
        z_offset = math.log(self.signal_variance) - 0.5 * np.einsum("md,md->m", z_scaled, z_scaled)
        ones = np.ones((z_scaled.shape[0], 1))
        alpha = solve_triangular(
            self.chol_uu, self.mean_weights, lower=True, trans="T", check_finite=False
        )
        factor, point_weights = point_factor(self.chol_uu, self.chol_b, self.mean_weights)
        derived = {
            "_input_weight": weight,
            "_input_offset": self.x_mean * weight,
            "_z_scaled": z_scaled,
            "_z_offset": z_offset,
            # e = [Z/ℓ, log s² − ½|Z/ℓ|², 1] @ [x_s, 1, −½|x_s|²] is log K(Z, x)
            "_kernel_map": np.asfortranarray(np.hstack([z_scaled, z_offset[:, None], ones])),
            "_chol_uu_f": np.asfortranarray(self.chol_uu),
            "_chol_b_f": np.asfortranarray(self.chol_b),
            "_point_factor": factor,
            "_point_weights": point_weights,
            # [α ∘ Z/ℓ, α]ᵀ k = [Σ α k z/ℓ, αᵀk], the moments of the mean's gradient
            "_grad_map": np.asfortranarray(np.hstack([alpha[:, None] * z_scaled, alpha[:, None]])),
            "_grad_scale": weight * self.y_scale,
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

        The co-simulation hot path (see the module notes): one thin matrix-vector product
        and an ``exp`` for the kernel row, one triangular solve, two dots; no loop over
        inducing points, no BLAS thread hand-offs.

        Parameters
        ----------
        x : ndarray, shape (D,)
        full_noise : bool
            Add the noise variance.

        Returns
        -------
        mean, var : float
        """
        k, _ = self._kernel_row(x, None)
        mean, var = self._latent_moments(k, 1)
        if full_noise:
            var += self.noise_variance
        return mean * self.y_scale + self.y_mean, var * (self.y_scale * self.y_scale)

    def predict_one_grad(
        self, x: FloatArray, kernel: FloatArray | None = None
    ) -> tuple[float, float, FloatArray]:
        """Latent mean and variance at one point, and the gradient of the mean.

        For first-order propagation of input uncertainty through the corrector chain.

        Parameters
        ----------
        x : ndarray, shape (D,)
        kernel : ndarray, shape (M,), optional
            C-contiguous float64 buffer that receives the kernel row ``K(Z, x)`` (standardised
            units, so that ``kernel / signal_variance`` is the correlation with each inducing
            point).

        Returns
        -------
        mean, var : float
            Original units; ``var`` is the latent variance (no noise).
        grad : ndarray, shape (D,)
            ∂mean/∂x, original units.
        """
        k, xs = self._kernel_row(x, kernel)
        # mean = αᵀk and ∂k_m/∂x_s = k_m (z_m/ℓ − x_s): ∂mean/∂x_s = Σ α k z/ℓ − (αᵀk) x_s
        moments = dgemv(1.0, self._grad_map, k, 0.0, None, 0, 1, 0, 1, 1)  # (D+1,)
        d = xs.shape[0]
        grad = daxpy(xs, moments[:d], d, -moments[d])  # in place: Σ α k z/ℓ − (αᵀk) x_s
        grad *= self._grad_scale
        mean, var = self._latent_moments(k, 0)
        return mean * self.y_scale + self.y_mean, var * (self.y_scale * self.y_scale), grad

    def _kernel_row(self, x: FloatArray, out: FloatArray | None) -> tuple[FloatArray, FloatArray]:
        """Kernel row k = K(Z, x) (M,), into ``out`` if given, and the scaled point x_s (D,)."""
        d = x.shape[0]
        point = np.empty(d + 2)  # [x_s, 1, −½|x_s|²]
        xs = point[:d]
        np.multiply(x, self._input_weight, out=xs)
        xs -= self._input_offset
        point[d] = 1.0
        point[d + 1] = -0.5 * ddot(xs, xs)
        # dgemv(alpha, a, x, beta, y, offx, incx, offy, incy, trans, overwrite_y): positional
        # arguments save a microsecond per call
        if out is None:
            e = dgemv(1.0, self._kernel_map, point)
        else:
            e = dgemv(1.0, self._kernel_map, point, 0.0, out, 0, 1, 0, 1, 0, 1)
        return np.exp(e, out=e), xs

    def _latent_moments(self, k: FloatArray, overwrite: int) -> tuple[float, float]:
        """Standardised latent mean βᵀg and variance s² − |g|², g = H⁻¹k (k kept unless
        ``overwrite``)."""
        # dtrsv(a, x, incx, offx, lower, trans, diag, overwrite_x)
        g = dtrsv(self._point_factor, k, 1, 0, 1, 0, 0, overwrite)
        return ddot(self._point_weights, g), max(self.signal_variance - ddot(g, g), 0.0)


def point_factor(
    chol_uu: FloatArray, chol_b: FloatArray, mean_weights: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The single-solve form of the predictive distribution (see the module notes).

    Parameters
    ----------
    chol_uu, chol_b : ndarray, shape (M, M)
        L and L_B, lower triangular.
    mean_weights : ndarray, shape (M,)
        γ.

    Returns
    -------
    factor : ndarray, shape (M, M), Fortran-ordered
        H = L U⁻ᵀ, lower triangular, with ``C = I − B⁻¹ = U Uᵀ`` and U upper triangular.
    weights : ndarray, shape (M,)
        β = U⁻¹ γ.

    Raises
    ------
    NumericalError
        The factors hold NaN or inf.
    """
    m = chol_uu.shape[0]
    c = -cho_solve((chol_b, True), np.eye(m), check_finite=False)  # −B⁻¹
    c[np.diag_indices(m)] += 1.0
    # raise the eigenvalues below the floor to it (a low-rank correction: C is not
    # reconstructed from its eigenvectors, whose rounding errors would reach the variance)
    eigenvalues, vectors = np.linalg.eigh(c)
    low = eigenvalues < EIGENVALUE_FLOOR
    c += (vectors[:, low] * (EIGENVALUE_FLOOR - eigenvalues[low])) @ vectors[:, low].T
    # the Cholesky factor of C with rows and columns reversed, reversed back, is upper
    # triangular (the jitter is a safeguard: the floor keeps C positive definite)
    reversed_factor, _ = jittered_cholesky(
        c[::-1, ::-1], min_relative_jitter=0.0, name="I − B⁻¹ (predictive variance)"
    )
    upper = np.ascontiguousarray(reversed_factor[::-1, ::-1])  # U, U Uᵀ = C
    factor_t = solve_triangular(upper, chol_uu.T, lower=False, check_finite=False)  # Hᵀ
    factor = np.asfortranarray(np.tril(factor_t.T))
    weights = solve_triangular(upper, mean_weights, lower=False, check_finite=False)
    return factor, weights
