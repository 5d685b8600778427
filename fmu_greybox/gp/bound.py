"""The collapsed variational free energy bound (Titsias 2009) and its analytic gradient.

With ``Kuu = L Lᵀ`` (M×M), ``A = L⁻¹ Kuf / σ`` (M×N), ``B = I + A Aᵀ = L_B L_Bᵀ`` and
``c = L_B⁻¹ A y / σ`` (M,), the bound on ``log p(y)`` is

    F = −N/2 log(2πσ²) − Σ log diag L_B − yᵀy / (2σ²) + cᵀc / 2
        − N s² / (2σ²) + tr(A Aᵀ) / 2

Its gradient is taken through the three kernel matrices. With ``β = B⁻¹ A y`` (M,) and
``C = I − B⁻¹`` (M×M):

* ``∂F/∂Kuf = L⁻ᵀ [C A + σ⁻² β (y − Aᵀβ)ᵀ] / σ``                         (M×N)
* ``∂F/∂Kuu = ½ L⁻ᵀ [C − σ⁻² β βᵀ − A Aᵀ] L⁻¹``                          (M×M)
* ``∂F/∂log σ² = −N/2 + yᵀy/(2σ²) − cᵀc + (N s² − σ² tr AAᵀ)/(2σ²)
  + ½ [tr(B⁻¹ AAᵀ) + σ⁻² βᵀ AAᵀ β]``
* ``∂F/∂tr Kff = −1/(2σ²)``

and from there to the hyperparameters through :func:`kernel.moment_gradients`. The N×M
work per call is: one thin product and one in-place ``exp`` for Kuf, one triangular solve
for A, one syrk ``[A; yᵀ][A; yᵀ]ᵀ`` (giving AAᵀ and Ay together), one gemm ``[H, u][A; yᵀ]``
(∂F/∂Kuf up to the factor ``L⁻ᵀ`` folded into H), one elementwise product with Kuf and one
thin moment product. Nothing N×N is ever formed, and the three M×N buffers are reused.

From :data:`BLOCK_ROWS` training rows on, that work is done in two blocks of columns, each with
its own buffers and BLAS calls, whose M×M products are added: when a core is free
(:func:`~fmu_greybox.side_by_side.spare_core`, a fit running alone with one BLAS thread) the
two blocks run side by side, otherwise one after the other. The blocks do not depend on where
the fit runs, so neither do its numbers.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fmu_greybox.gp.kernel import (
    cross_covariance,
    expand_inducing,
    expand_inputs,
    inducing_covariance,
    moment_gradients,
)
from fmu_greybox.gp.linalg import (
    MIN_RELATIVE_JITTER,
    jittered_cholesky,
    lower_inverse,
    solve_lower_wide,
)
from fmu_greybox.side_by_side import spare_core

FloatArray = NDArray[np.float64]

LOG_2PI = float(np.log(2.0 * np.pi))
#: Training rows from which the bound's M×N work is done in two blocks of columns.
BLOCK_ROWS = 8192


@dataclass(frozen=True)
class Hyperparameters:
    """Kernel and likelihood hyperparameters (in the units of the data they apply to).

    Parameters
    ----------
    lengthscales : ndarray, shape (D,)
    signal_variance : float
        s².
    noise_variance : float
        σ².
    """

    lengthscales: FloatArray
    signal_variance: float
    noise_variance: float


@dataclass(frozen=True)
class BoundGradient:
    """∂F with respect to the log-parameters (and the inducing points, if asked)."""

    log_lengthscales: FloatArray  # (D,)
    log_signal_variance: float
    log_noise_variance: float
    inducing_points: FloatArray | None  # (M, D) or None


@dataclass(frozen=True)
class BoundResult:
    """Value of the bound, its gradient and the factors that prediction needs.

    Attributes
    ----------
    value : float
        F, in nats.
    gradient : BoundGradient or None
    chol_uu : ndarray, shape (M, M)
        L, lower Cholesky factor of ``Kuu + jitter·I``.
    chol_b : ndarray, shape (M, M)
        L_B, lower Cholesky factor of ``B``.
    mean_weights : ndarray, shape (M,)
        ``γ = L_B⁻ᵀ c``: the predictive mean is ``(L⁻¹ K(Z, x)) @ γ``.
    jitter : float
        Absolute jitter added to Kuu.
    """

    value: float
    gradient: BoundGradient | None
    chol_uu: FloatArray
    chol_b: FloatArray
    mean_weights: FloatArray
    jitter: float


@dataclass(frozen=True)
class _Factors:
    """Intermediate quantities of one evaluation, shared by the bound and its gradient."""

    Kuu: FloatArray  # (M, M), without jitter
    L: FloatArray  # (M, M), chol(Kuu + jitter·I)
    jitter: float
    AAT: FloatArray  # (M, M)
    Ay: FloatArray  # (M,)
    LB: FloatArray  # (M, M), chol(I + AAᵀ)
    LB_inv: FloatArray  # (M, M)
    c: FloatArray  # (M,), L_B⁻¹ A y / σ


class _Block:
    """A block of consecutive training rows with its M×n work buffers: Kuf; ``[A; yᵀ]``,
    whose last row is y; the gradient weights W.

    Parameters
    ----------
    features : ndarray, shape (n, 2D+1)
        The rows' :func:`~fmu_greybox.gp.kernel.expand_inputs`.
    y : ndarray, shape (n,)
    """

    def __init__(self, features: FloatArray, y: FloatArray) -> None:
        self.features = features
        self.y = y
        self._buffers: tuple[FloatArray, FloatArray, FloatArray] | None = None

    def buffers(self, m: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Kuf (M, n), ``[A; yᵀ]`` (M+1, n) and W (M, n), allocated once per M."""
        if self._buffers is None or self._buffers[0].shape[0] != m:
            n = self.y.size
            A_aug = np.empty((m + 1, n))
            A_aug[m] = self.y
            self._buffers = (np.empty((m, n)), A_aug, np.empty((m, n)))
        return self._buffers

    def gram(self, Z_features: FloatArray, L: FloatArray, sigma: float) -> FloatArray:
        """Kuf and ``A = L⁻¹ Kuf / σ`` of these rows into the buffers; returns their share of
        ``[A; yᵀ][A; yᵀ]ᵀ``, shape (M+1, M+1)."""
        m = L.shape[0]
        Kuf, A_aug, _ = self.buffers(m)
        cross_covariance(Z_features, self.features, out=Kuf)
        solve_lower_wide(L, Kuf, A_aug[:m], scale=1.0 / sigma)
        return A_aug @ A_aug.T  # one syrk

    def moments(self, H_aug: FloatArray) -> FloatArray:
        """These rows' share of ``W @ features`` with ``W = ([H, u] @ [A; yᵀ]) ∘ Kuf``, from
        the buffers :meth:`gram` filled; shape (M, 2D+1)."""
        Kuf, A_aug, W = self.buffers(H_aug.shape[0])
        np.matmul(H_aug, A_aug, out=W)
        W *= Kuf
        return W @ self.features


class CollapsedBound:
    """The collapsed VFE bound for one training set, evaluated at any hyperparameters.

    Holds the input features and three preallocated M×N work buffers (per block of rows, see
    the module docstring), so repeated evaluations (one per optimiser step) allocate nothing
    large.

    Parameters
    ----------
    X : ndarray, shape (N, D)
        Training inputs.
    y : ndarray, shape (N,)
        Training targets.
    min_relative_jitter, max_relative_jitter : float
        Smallest (always added) and largest jitter tried on Kuu, relative to its mean
        diagonal; see :func:`fmu_greybox.gp.linalg.jittered_cholesky`.
    """

    def __init__(
        self,
        X: FloatArray,
        y: FloatArray,
        *,
        min_relative_jitter: float = MIN_RELATIVE_JITTER,
        max_relative_jitter: float = 1e-4,
    ) -> None:
        self.X = np.ascontiguousarray(X, dtype=np.float64)
        self.y = np.ascontiguousarray(y, dtype=np.float64)
        self.n = self.X.shape[0]
        self.min_relative_jitter = min_relative_jitter
        self.max_relative_jitter = max_relative_jitter
        features = expand_inputs(self.X)  # (N, 2D+1)
        self._yy = float(self.y @ self.y)
        edges = [0, self.n // 2, self.n] if self.n >= BLOCK_ROWS else [0, self.n]
        self._blocks = [_Block(features[a:b], self.y[a:b]) for a, b in itertools.pairwise(edges)]

    def _summed_over_blocks(self, work: Callable[[_Block], FloatArray]) -> FloatArray:
        """The sum of ``work`` over the blocks, added in block order (the same numbers however
        they ran); the blocks run side by side when a core is free."""
        if len(self._blocks) > 1 and spare_core():
            with ThreadPoolExecutor(len(self._blocks)) as pool:
                shares = list(pool.map(work, self._blocks))
        else:
            shares = [work(block) for block in self._blocks]
        total = shares[0]
        for share in shares[1:]:
            total += share
        return total

    def evaluate(
        self,
        hyp: Hyperparameters,
        Z: FloatArray,
        *,
        gradient: bool = True,
        inducing_gradient: bool = False,
    ) -> BoundResult:
        """Evaluate F (and optionally its gradient) at ``hyp`` with inducing points ``Z``.

        Parameters
        ----------
        hyp : Hyperparameters
        Z : ndarray, shape (M, D)
        gradient : bool
            Also compute ∂F with respect to the log-hyperparameters.
        inducing_gradient : bool
            Also compute ∂F/∂Z (implies ``gradient``).

        Returns
        -------
        BoundResult
        """
        f = self._factorise(hyp, Z)
        sn2 = float(hyp.noise_variance)
        value = (
            -0.5 * self.n * (LOG_2PI + np.log(sn2))
            + _log_det_term(f)
            + _data_fit_term(f, self._yy, sn2)
            + _trace_term(f, self.n, float(hyp.signal_variance), sn2)
        )
        grad = None
        if gradient or inducing_gradient:
            grad = self._gradient(f, hyp, Z, inducing_gradient)
        mean_weights = f.LB_inv.T @ f.c
        return BoundResult(float(value), grad, f.L, f.LB, mean_weights, f.jitter)

    def _factorise(self, hyp: Hyperparameters, Z: FloatArray) -> _Factors:
        ell = np.asarray(hyp.lengthscales, dtype=np.float64)
        s2 = float(hyp.signal_variance)
        sigma = float(np.sqrt(hyp.noise_variance))
        m = Z.shape[0]
        Kuu = inducing_covariance(Z, ell, s2)
        L, jitter = jittered_cholesky(
            Kuu,
            min_relative_jitter=self.min_relative_jitter,
            max_relative_jitter=self.max_relative_jitter,
            name="Kuu (inducing covariance)",
        )
        Z_features = expand_inducing(Z, ell, s2)
        # (M+1, M+1) = [[AAᵀ, Ay], [yᵀAᵀ, yᵀy]] with A = L⁻¹ Kuf / σ, added over the blocks
        gram = self._summed_over_blocks(lambda block: block.gram(Z_features, L, sigma))
        AAT, Ay = gram[:m, :m], gram[:m, m]
        LB, _ = jittered_cholesky(np.eye(m) + AAT, min_relative_jitter=0.0, name="B = I + AAᵀ")
        LB_inv = lower_inverse(LB)
        c = (LB_inv @ Ay) / sigma
        return _Factors(Kuu, L, jitter, AAT, Ay, LB, LB_inv, c)

    def _gradient(
        self, f: _Factors, hyp: Hyperparameters, Z: FloatArray, inducing_gradient: bool
    ) -> BoundGradient:
        n, m = self.n, Z.shape[0]
        ell = np.asarray(hyp.lengthscales, dtype=np.float64)
        s2, sn2 = float(hyp.signal_variance), float(hyp.noise_variance)
        sigma = np.sqrt(sn2)
        L_inv = lower_inverse(f.L)  # M×M only: the N-sized solve above stays a trsm
        B_inv = f.LB_inv.T @ f.LB_inv
        beta = B_inv @ f.Ay  # β = B⁻¹ A y
        C = np.eye(m) - B_inv

        d_log_noise = (
            -0.5 * n
            + 0.5 * self._yy / sn2
            - float(f.c @ f.c)
            + 0.5 * (n * s2 - sn2 * float(np.trace(f.AAT))) / sn2
            + 0.5 * (float(np.sum(B_inv * f.AAT)) + float(beta @ f.AAT @ beta) / sn2)
        )

        # one product L⁻ᵀ [C, β, inner] serves ∂F/∂Kuf and ∂F/∂Kuu
        inner = C - np.outer(beta, beta) / sn2 - f.AAT
        Lt = L_inv.T @ np.hstack([C, beta[:, None], inner])  # (M, 2M+1)

        # W = ∂F/∂Kuf ∘ Kuf = ([H, u] @ [A; yᵀ]) ∘ Kuf, H = L⁻ᵀC/σ − u βᵀ, u = L⁻ᵀβ/σ³ (per block)
        u = Lt[:, m] / (sigma * sn2)
        H_aug = np.empty((m, m + 1))
        H_aug[:, :m] = Lt[:, :m] / sigma - np.outer(u, beta)
        H_aug[:, m] = u
        moments_f = self._summed_over_blocks(lambda block: block.moments(H_aug))  # (M, 2D+1)

        G_uu = 0.5 * (Lt[:, m + 1 :] @ L_inv)  # ∂F/∂Kuu = ½ L⁻ᵀ inner L⁻¹
        moments_u = (G_uu * f.Kuu) @ expand_inputs(Z)  # (M, 2D+1)

        dl_f, dz_f = moment_gradients(Z, ell, moments_f)
        dl_u, dz_u = moment_gradients(Z, ell, moments_u)
        # Kuf and Kuu + jitter·I are proportional to s², and tr(G_uu (Kuu + jitter·I)) = ½ tr(inner)
        d_log_signal = (
            float(moments_f[:, -1].sum()) + 0.5 * float(np.trace(inner)) - 0.5 * n * s2 / sn2
        )
        return BoundGradient(
            log_lengthscales=dl_f + dl_u,
            log_signal_variance=d_log_signal,
            log_noise_variance=float(d_log_noise),
            inducing_points=(dz_f + 2.0 * dz_u) if inducing_gradient else None,
        )


def _log_det_term(f: _Factors) -> float:
    """−½ log|B| = −Σ log diag L_B (the rest of −½ log|Qff + σ²I| is −N/2 log σ²)."""
    return -float(np.sum(np.log(np.diag(f.LB))))


def _data_fit_term(f: _Factors, yy: float, sn2: float) -> float:
    """−½ yᵀ(Qff + σ²I)⁻¹y = −yᵀy/(2σ²) + cᵀc/2."""
    return -0.5 * yy / sn2 + 0.5 * float(f.c @ f.c)


def _trace_term(f: _Factors, n: int, s2: float, sn2: float) -> float:
    """−tr(Kff − Qff)/(2σ²) = −N s²/(2σ²) + tr(AAᵀ)/2."""
    return -0.5 * n * s2 / sn2 + 0.5 * float(np.trace(f.AAT))
