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
together: 6× the mean error above for ``kᵀα``). ``α`` serves only the mean's gradient.

The single-point path is compiled (``fmu_greybox/native/chain_core.c``, shared with the
chain's step): one pass over the inducing points for the kernel row (and the gradient's
moments), one column-oriented forward substitution with H, two dots. Everything that does
not depend on x is laid out once in :attr:`Posterior.packed`: input standardisation and
length-scales folded into one affine map of x, ``log s² − ½|Z/ℓ|²`` as one offset per
inducing point, H column-major, two scalars back to original units. No BLAS call, so no
OpenBLAS worker thread to wake (a multi-threaded matrix-vector product took a median of
8 ms per call on a loaded 2-CPU machine at M = 200).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cho_solve, solve_triangular

from fmu_greybox import _chainstep
from fmu_greybox.gp.linalg import aligned_zeros, jittered_cholesky

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
    _chol_uu_f: FloatArray = field(init=False, repr=False)
    _chol_b_f: FloatArray = field(init=False, repr=False)
    packed: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        weight = 1.0 / (self.x_scale * self.lengthscales)  # (D,)
        z_scaled = np.ascontiguousarray(self.inducing_points / self.lengthscales)  # (M, D)
        z_offset = math.log(self.signal_variance) - 0.5 * np.einsum("md,md->m", z_scaled, z_scaled)
        offset = self.x_mean * weight
        alpha = solve_triangular(
            self.chol_uu, self.mean_weights, lower=True, trans="T", check_finite=False
        )
        factor, point_weights = point_factor(self.chol_uu, self.chol_b, self.mean_weights)
        scalars = np.array([self.y_scale, self.y_mean, self.signal_variance, self.noise_variance])
        derived = {
            "_input_weight": weight,
            "_input_offset": offset,
            "_z_scaled": z_scaled,
            "_z_offset": z_offset,
            "_chol_uu_f": np.asfortranarray(self.chol_uu),
            "_chol_b_f": np.asfortranarray(self.chol_b),
            "packed": pack_posterior(
                factor,
                [weight, offset, z_scaled.T.ravel(), z_offset, alpha, point_weights, scalars],
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

        The co-simulation hot path (see the module notes): compiled, no allocation beyond
        the two returned floats.

        Parameters
        ----------
        x : ndarray, shape (D,), float64, C-contiguous
        full_noise : bool

        Returns
        -------
        mean, var : float
        """
        return _chainstep.predict(self.packed, self.n_inducing, self.input_dim, x, None, full_noise)

    def predict_one_grad(self, x: FloatArray) -> tuple[float, float, FloatArray]:
        """Latent mean and variance at one point, and the gradient of the mean.

        The quantities the chain propagates its variance with (first order).

        Parameters
        ----------
        x : ndarray, shape (D,), float64, C-contiguous

        Returns
        -------
        mean, var : float
            Original units; ``var`` is the latent variance.
        grad : ndarray, shape (D,)
            ∂mean/∂x, original units.
        """
        grad = np.empty(self.input_dim)
        mean, var = _chainstep.predict(self.packed, self.n_inducing, self.input_dim, x, grad, False)
        return mean, var, grad


def packed_factor(factor: FloatArray) -> FloatArray:
    """H by columns as ``chain_core.c`` reads it: column j from row 8⌊j/8⌋ to LD − 1.

    Parameters
    ----------
    factor : ndarray, shape (M, M)
        Lower triangular.

    Returns
    -------
    ndarray, shape (Σ_j (LD − 8⌊j/8⌋),)
        LD = M rounded up to a multiple of 8; rows from M on are zero, so every column
        starts on a cache line when the first one does.
    """
    m = factor.shape[0]
    ld = -(-m // 8) * 8
    padded = np.zeros((ld, m))
    padded[:m] = factor
    return np.concatenate([padded[j // 8 * 8 :, j] for j in range(m)])


def pack_posterior(factor: FloatArray, vectors: list[FloatArray]) -> FloatArray:
    """The layout ``fmu_greybox/native/chain_core.c`` reads (its header comment).

    Parameters
    ----------
    factor : ndarray, shape (M, M)
        H, lower triangular.
    vectors : list of ndarray
        weight (D), offset (D), Z/ℓ by dimension (D·M: the M coordinates i, then i + 1),
        log s² − ½|Z/ℓ|² (M), α (M), β (M), and the scalars y_scale, y_mean, s², σ² (4), in
        this order.

    Returns
    -------
    ndarray
        :func:`packed_factor`, then the vectors, starting on a cache-line boundary.
    """
    parts = [packed_factor(factor), *vectors]
    packed = aligned_zeros(sum(part.size for part in parts))
    np.concatenate(parts, out=packed)
    return packed


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
