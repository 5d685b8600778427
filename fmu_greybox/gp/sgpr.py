"""Sparse GP regression with the collapsed VFE bound: the estimator.

:class:`SparseGPR` standardises the data, picks inducing points, maximises the bound of
:mod:`fmu_greybox.gp.bound` over the hyperparameters (and optionally the inducing points)
and keeps a :class:`~fmu_greybox.gp.predictive.Posterior` for prediction in original units.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fmu_greybox.gp import storage
from fmu_greybox.gp.bound import CollapsedBound, Hyperparameters
from fmu_greybox.gp.inducing import InducingSelector, make_selector
from fmu_greybox.gp.kernel import SquaredExponentialARD
from fmu_greybox.gp.optimise import OptimisationResult, ProgressCallback, maximise_bound
from fmu_greybox.gp.predictive import Posterior

FloatArray = NDArray[np.float64]

INITIAL_NOISE_FRACTION = 0.1
"""Initial σ² as a fraction of the target variance."""


class SparseGPR:
    """Sparse GP regressor (SE-ARD kernel, Gaussian noise, collapsed VFE bound).

    Parameters
    ----------
    n_inducing : int
        Number of inducing points M (all training points if M >= N: the exact GP).
    inducing : {"equispaced", "kmeans", "greedy"} or InducingSelector
        How to choose them; ``"equispaced"`` takes rows at equally spaced indices of the
        training sequence (the paper's choice).
    optimise_inducing : bool
        Also optimise the inducing point locations.
    max_iter : int
        Cap on L-BFGS-B iterations.
    optimise_rows : int or None
        Optimise the hyperparameters on at most this many training rows, evenly spread over
        the sequence, then condition the posterior on every row at the hyperparameters found
        (one more evaluation of the bound, over all rows). The bound's cost is linear in the
        rows, so an optimisation over a fifth of them takes about a fifth of the time; rows
        sampled much faster than the signal changes add little to what the hyperparameters
        are. ``None`` optimises over every row.
    seed : int
        Seed for every random choice (k-means seeding, the greedy start); a fit is
        reproducible bit for bit.
    min_noise_variance : float
        Lower bound on the noise variance, as a fraction of the target variance.
    min_jitter, max_jitter : float
        Jitter always added to Kuu, and the largest tried before giving up, both relative
        to its diagonal.

    Attributes
    ----------
    lengthscales_ : ndarray, shape (D,)
        Length-scales in original input units.
    signal_variance_ : float
        s², original target units squared.
    noise_variance_ : float
        σ², original target units squared.
    inducing_points_ : ndarray, shape (M, D)
        In original input units.
    bound_ : float
        The collapsed bound reached, in nats, on the standardised targets (add
        ``−N·log(y_scale_)`` for the bound on ``log p(y)`` in original units).
    n_iter_ : int
        L-BFGS-B iterations.
    n_eval_ : int
        Bound evaluations.
    jitter_ : float
        Jitter added to Kuu at the optimum (standardised units).
    optimiser_message_ : str
    x_mean_, x_scale_ : ndarray, shape (D,)
    y_mean_, y_scale_ : float
    posterior_ : Posterior
    training_data_sha256_ : str
        Hash of the training arrays (float64 bytes of X then y).
    """

    def __init__(
        self,
        n_inducing: int = 200,
        inducing: str | InducingSelector = "equispaced",
        optimise_inducing: bool = False,
        max_iter: int = 200,
        optimise_rows: int | None = None,
        seed: int = 0,
        min_noise_variance: float = 1e-6,
        min_jitter: float = 1e-10,
        max_jitter: float = 1e-4,
    ) -> None:
        self.n_inducing = n_inducing
        self.inducing = inducing
        self.optimise_inducing = optimise_inducing
        self.max_iter = max_iter
        self.optimise_rows = optimise_rows
        self.seed = seed
        self.min_noise_variance = min_noise_variance
        self.min_jitter = min_jitter
        self.max_jitter = max_jitter

    # ------------------------------------------------------------------ fitting

    def fit(
        self,
        X: ArrayLike,
        y: ArrayLike,
        progress: ProgressCallback | None = None,
        start: Hyperparameters | None = None,
    ) -> SparseGPR:
        """Fit to training data.

        Parameters
        ----------
        X : array_like, shape (N, D)
            Training inputs, rows in the order of the training sequence.
        y : array_like, shape (N,) or (N, 1)
            Training targets.
        progress : callable, optional
            ``progress(iteration, bound)`` after each optimiser iteration (bound in nats on
            the standardised targets).
        start : Hyperparameters, optional
            Where the optimisation starts, in original units (for example
            :attr:`hyperparameters_` of a fit on related data: a warm start); by default
            :func:`initial_hyperparameters`. With ``max_iter = 0`` the model is the posterior
            on this data at exactly these hyperparameters.

        Returns
        -------
        SparseGPR
            self.
        """
        X, y = _validated(X, y)
        self.x_mean_, self.x_scale_ = _location_scale(X)
        y_mean, y_scale = _location_scale(y[:, None])
        self.y_mean_, self.y_scale_ = float(y_mean[0]), float(y_scale[0])
        Xs = (X - self.x_mean_) / self.x_scale_
        ys = (y - self.y_mean_) / self.y_scale_
        self.training_data_sha256_ = hashlib.sha256(X.tobytes() + y.tobytes()).hexdigest()

        start = (
            initial_hyperparameters(Xs)
            if start is None
            else _standardised(start, self.x_scale_, self.y_scale_)
        )
        rng = np.random.default_rng(self.seed)
        kernel = SquaredExponentialARD(start.lengthscales, start.signal_variance)
        Z = make_selector(self.inducing).select(Xs, self.n_inducing, kernel, rng)
        jitter = {"min_relative_jitter": self.min_jitter, "max_relative_jitter": self.max_jitter}
        bound = CollapsedBound(Xs, ys, **jitter)
        # with no optimisation, the one evaluation is the posterior's, on every row
        rows = spread_rows(ys.size, self.optimise_rows) if self.max_iter > 0 else None
        result = maximise_bound(
            bound if rows is None else CollapsedBound(Xs[rows], ys[rows], **jitter),
            start,
            Z,
            optimise_inducing=self.optimise_inducing,
            max_iter=self.max_iter,
            min_noise_variance=self.min_noise_variance,
            progress=progress,
        )
        if rows is not None:  # the posterior on every row
            hyp = result.hyperparameters
            result = dataclasses.replace(
                result,
                bound=bound.evaluate(hyp, result.inducing_points, gradient=False),
                n_eval=result.n_eval + 1,
            )
        self._store_result(result)
        return self

    def _store_result(self, result: OptimisationResult) -> None:
        hyp = result.hyperparameters
        self.posterior_ = Posterior(
            x_mean=self.x_mean_,
            x_scale=self.x_scale_,
            y_mean=self.y_mean_,
            y_scale=self.y_scale_,
            lengthscales=np.array(hyp.lengthscales, dtype=np.float64),
            signal_variance=float(hyp.signal_variance),
            noise_variance=float(hyp.noise_variance),
            inducing_points=np.array(result.inducing_points, dtype=np.float64),
            mean_weights=result.bound.mean_weights,
            chol_uu=result.bound.chol_uu,
            chol_b=result.bound.chol_b,
        )
        self.bound_ = result.bound.value
        self.n_iter_ = result.n_iter
        self.n_eval_ = result.n_eval
        self.jitter_ = result.bound.jitter
        self.optimiser_message_ = result.message
        self._set_fitted_attributes()

    def _set_fitted_attributes(self) -> None:
        """Original-unit views of the posterior's hyperparameters."""
        post = self.posterior_
        y_var = post.y_scale * post.y_scale
        self.lengthscales_ = post.lengthscales * post.x_scale
        self.signal_variance_ = post.signal_variance * y_var
        self.noise_variance_ = post.noise_variance * y_var
        self.inducing_points_ = post.inducing_points * post.x_scale + post.x_mean

    @property
    def hyperparameters_(self) -> Hyperparameters:
        """The fitted hyperparameters in original units (what :meth:`fit`'s ``start`` takes)."""
        return Hyperparameters(
            self.lengthscales_.copy(), float(self.signal_variance_), float(self.noise_variance_)
        )

    # --------------------------------------------------------------- prediction

    def predict(self, X: ArrayLike, full_noise: bool = False) -> tuple[FloatArray, FloatArray]:
        """Predictive mean and variance, original units.

        Parameters
        ----------
        X : array_like, shape (n, D)
        full_noise : bool
            Include the noise variance (observation rather than latent-function variance).

        Returns
        -------
        mean, var : ndarray, shape (n,)
        """
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != self.posterior_.input_dim:
            raise ValueError(f"X must have shape (n, {self.posterior_.input_dim}), got {X.shape}")
        return self.posterior_.predict(X, full_noise)

    def predict_one(self, x: FloatArray, full_noise: bool = False) -> tuple[float, float]:
        """Predictive mean and variance at one point (the co-simulation hot path).

        Parameters
        ----------
        x : ndarray, shape (D,), float64
            Not validated, for speed.
        full_noise : bool
            Include the noise variance.

        Returns
        -------
        mean, var : float
        """
        return self.posterior_.predict_one(x, full_noise)

    def predict_one_grad(self, x: FloatArray) -> tuple[float, float, FloatArray]:
        """Latent mean, variance and mean gradient at one point (see ``Posterior``).

        Parameters
        ----------
        x : ndarray, shape (D,), float64
            Not validated, for speed.

        Returns
        -------
        mean, var : float
        grad : ndarray, shape (D,)
        """
        return self.posterior_.predict_one_grad(x)

    # ------------------------------------------------------------- persistence

    def save(self, path_stem: str | Path) -> tuple[Path, Path]:
        """Write ``<stem>.npz`` (arrays) and ``<stem>.json`` (metadata, format version).

        Returns
        -------
        npz_path, json_path : Path
        """
        fit_info = {
            "bound": self.bound_,
            "n_iter": self.n_iter_,
            "n_eval": self.n_eval_,
            "jitter": self.jitter_,
            "optimiser_message": self.optimiser_message_,
            "training_data_sha256": self.training_data_sha256_,
        }
        return storage.save(path_stem, self.posterior_, self.settings(), fit_info)

    def settings(self) -> dict[str, Any]:
        """The constructor's settings (an inducing selector by its name), as saved."""
        return {
            "n_inducing": self.n_inducing,
            "inducing": self.inducing if isinstance(self.inducing, str) else self.inducing.name,
            "optimise_inducing": self.optimise_inducing,
            "max_iter": self.max_iter,
            "optimise_rows": self.optimise_rows,
            "seed": self.seed,
            "min_noise_variance": self.min_noise_variance,
            "min_jitter": self.min_jitter,
            "max_jitter": self.max_jitter,
        }

    @classmethod
    def load(cls, path_stem: str | Path) -> SparseGPR:
        """Read a model written by :meth:`save`.

        Raises
        ------
        ModelFormatError
            A file is missing, unreadable, of an unknown format version or incomplete.
        """
        posterior, settings, fit_info = storage.load(path_stem)
        model = cls(**settings)
        model.posterior_ = posterior
        model.x_mean_, model.x_scale_ = posterior.x_mean, posterior.x_scale
        model.y_mean_, model.y_scale_ = posterior.y_mean, posterior.y_scale
        model.bound_ = float(fit_info["bound"])
        model.n_iter_ = int(fit_info["n_iter"])
        model.n_eval_ = int(fit_info["n_eval"])
        model.jitter_ = float(fit_info["jitter"])
        model.optimiser_message_ = str(fit_info["optimiser_message"])
        model.training_data_sha256_ = str(fit_info["training_data_sha256"])
        model._set_fitted_attributes()
        return model


def initial_hyperparameters(Xs: FloatArray) -> Hyperparameters:
    """Starting point from the data's scales, for standardised data.

    Every standardised input has unit spread, so each length-scale starts at √D (typical
    distances between points are then about one length-scale); the signal takes the target
    variance less an initial noise of 10 %.

    Parameters
    ----------
    Xs : ndarray, shape (N, D)
        Standardised inputs.

    Returns
    -------
    Hyperparameters
    """
    d = Xs.shape[1]
    return Hyperparameters(
        lengthscales=np.full(d, np.sqrt(d)),
        signal_variance=1.0 - INITIAL_NOISE_FRACTION,
        noise_variance=INITIAL_NOISE_FRACTION,
    )


def every_row(n: int, limit: int | None) -> bool:
    """Whether an optimisation limited to ``limit`` rows (``optimise_rows``) sees all ``n``."""
    return limit is None or n <= limit


def spread_rows(n: int, limit: int | None) -> NDArray[np.intp] | None:
    """At most ``limit`` row indices evenly spread over ``n`` rows, first and last included;
    ``None`` when every row is kept (:func:`every_row`)."""
    if every_row(n, limit):
        return None
    return np.linspace(0, n - 1, limit).round().astype(np.intp)


def _standardised(hyp: Hyperparameters, x_scale: FloatArray, y_scale: float) -> Hyperparameters:
    """Original-unit hyperparameters in the units of data standardised by these scales."""
    y_var = y_scale * y_scale
    return Hyperparameters(
        np.asarray(hyp.lengthscales, dtype=np.float64) / x_scale,
        float(hyp.signal_variance) / y_var,
        float(hyp.noise_variance) / y_var,
    )


def _validated(X: ArrayLike, y: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Training arrays as float64, X (N, D) and y (N,), or ValueError saying what is wrong."""
    X = np.ascontiguousarray(X, dtype=np.float64)
    y = np.ascontiguousarray(y, dtype=np.float64)
    if y.ndim == 2 and y.shape[1] == 1:
        y = y[:, 0].copy()
    if X.ndim != 2:
        raise ValueError(f"X must be 2-D (N, D), got shape {X.shape}")
    if y.ndim != 1 or y.shape[0] != X.shape[0]:
        raise ValueError(f"y must have shape ({X.shape[0]},) to match X, got {y.shape}")
    if X.shape[0] < 2:
        raise ValueError("need at least 2 training points")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(y))):
        raise ValueError("X and y must be finite (no NaN or inf): drop or fill those samples")
    return X, y


def _location_scale(A: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Column means and standard deviations (1.0 where a column is constant), shapes (D,)."""
    mean = A.mean(axis=0)
    scale = A.std(axis=0)
    return mean, np.where(scale > 0.0, scale, 1.0)
