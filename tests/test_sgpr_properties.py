"""Property tests of the sparse GP: shapes, positive variances, standardisation invariance."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmu_greybox.gp import CollapsedBound, Hyperparameters, SparseGPR
from fmu_greybox.gp.predictive import Posterior

FAST = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])

seeds = st.integers(0, 2**32 - 1)
dims = st.integers(1, 4)


def sample(seed: int, n: int, d: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, d))
    y = np.sin(X @ rng.normal(size=d)) + 0.1 * rng.standard_normal(n)
    return X, y


def posterior_at(X, y, Z, hyp: Hyperparameters) -> Posterior:
    """Posterior for already standardised data at fixed hyperparameters (no optimisation)."""
    r = CollapsedBound(X, y).evaluate(hyp, Z, gradient=False)
    d = X.shape[1]
    return Posterior(
        x_mean=np.zeros(d), x_scale=np.ones(d), y_mean=0.0, y_scale=1.0,
        lengthscales=hyp.lengthscales, signal_variance=hyp.signal_variance,
        noise_variance=hyp.noise_variance, inducing_points=Z,
        mean_weights=r.mean_weights, chol_uu=r.chol_uu, chol_b=r.chol_b,
    )  # fmt: skip


@FAST
@given(
    seed=seeds,
    d=dims,
    n=st.integers(5, 60),
    m=st.integers(1, 20),
    log_ell=st.floats(-1.5, 2.0),
    log_s2=st.floats(-2.0, 2.0),
    log_sn2=st.floats(-6.0, 0.0),
)
def test_shapes_and_positive_variances(seed, d, n, m, log_ell, log_s2, log_sn2):
    X, y = sample(seed, n, d)
    Z = X[: min(m, n)] + 0.01
    hyp = Hyperparameters(
        np.full(d, np.exp(log_ell)), float(np.exp(log_s2)), float(np.exp(log_sn2))
    )
    post = posterior_at(X, y, Z, hyp)
    Xt = np.random.default_rng(seed + 1).normal(scale=2.0, size=(7, d))
    mean, var = post.predict(Xt)
    assert mean.shape == var.shape == (7,)
    assert np.all(np.isfinite(mean))
    assert np.all(var >= -1e-9 * hyp.signal_variance)
    assert np.all(var <= hyp.signal_variance * (1 + 1e-9))
    _, noisy = post.predict(Xt, full_noise=True)
    assert np.all(noisy > 0.0)
    m1, v1 = post.predict_one(Xt[0])
    assert isinstance(m1, float) and isinstance(v1, float)
    assert m1 == pytest.approx(mean[0], rel=1e-9, abs=1e-9)
    assert v1 == pytest.approx(var[0], rel=1e-8, abs=1e-10 * hyp.signal_variance)


@FAST
@given(seed=seeds, d=dims, m=st.integers(1, 15))
def test_bound_never_exceeds_exact_evidence(seed, d, m):
    X, y = sample(seed, 30, d)
    hyp = Hyperparameters(np.full(d, 1.0), 1.0, 0.1)
    sparse = CollapsedBound(X, y).evaluate(hyp, X[:m], gradient=False).value
    exact = CollapsedBound(X, y).evaluate(hyp, X, gradient=False).value
    assert sparse <= exact + 1e-9 * abs(exact)


@FAST
@given(
    seed=seeds,
    d=st.integers(1, 3),
    x_scale=st.lists(st.floats(1e-3, 1e3), min_size=3, max_size=3),
    x_shift=st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3),
    y_scale=st.floats(1e-3, 1e3),
    y_shift=st.floats(-1e3, 1e3),
)
def test_posterior_maps_standardised_predictions_to_original_units(
    seed, d, x_scale, x_shift, y_scale, y_shift
):
    X, y = sample(seed, 40, d)
    hyp = Hyperparameters(np.full(d, 1.2), 0.9, 0.05)
    std = posterior_at(X, y, X[::5].copy(), hyp)
    a, b = np.array(x_scale[:d]), np.array(x_shift[:d])
    raw = Posterior(
        x_mean=b, x_scale=a, y_mean=y_shift, y_scale=y_scale,
        lengthscales=std.lengthscales, signal_variance=std.signal_variance,
        noise_variance=std.noise_variance, inducing_points=std.inducing_points,
        mean_weights=std.mean_weights, chol_uu=std.chol_uu, chol_b=std.chol_b,
    )  # fmt: skip
    Xt = np.random.default_rng(seed).normal(size=(9, d))
    mean, var = std.predict(Xt, full_noise=True)
    mean2, var2 = raw.predict(Xt * a + b, full_noise=True)
    assert mean2 == pytest.approx(mean * y_scale + y_shift, rel=1e-9, abs=1e-9 * y_scale)
    assert var2 == pytest.approx(var * y_scale**2, rel=1e-9)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=seeds,
    d=st.integers(1, 3),
    x_scale=st.lists(st.floats(1e-3, 1e3), min_size=3, max_size=3),
    x_sign=st.lists(st.sampled_from([-1.0, 1.0]), min_size=3, max_size=3),
    x_shift=st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3),
    y_scale=st.floats(1e-3, 1e3),
    y_shift=st.floats(-1e3, 1e3),
)
def test_fit_is_invariant_to_scaling_and_shifting_the_data(
    seed, d, x_scale, x_sign, x_shift, y_scale, y_shift
):
    """Scaling/shifting X and y scales/shifts the fitted predictions accordingly.

    Both fits see the same standardised data up to rounding; they are run to convergence
    because the optimiser's path amplifies rounding differences before it gets there.
    """
    X, y = sample(seed, 80, d)
    a = np.array(x_scale[:d]) * np.array(x_sign[:d])
    b = np.array(x_shift[:d])
    kwargs = dict(n_inducing=8, max_iter=500)
    base = SparseGPR(**kwargs).fit(X, y)
    moved = SparseGPR(**kwargs).fit(X * a + b, y * y_scale + y_shift)
    Xt = np.random.default_rng(seed).normal(size=(10, d))
    mean, var = base.predict(Xt)
    mean2, var2 = moved.predict(Xt * a + b)
    spread = np.std(y) * y_scale
    assert mean2 == pytest.approx(mean * y_scale + y_shift, abs=1e-3 * spread)
    assert var2 == pytest.approx(var * y_scale**2, rel=1e-3, abs=1e-6 * spread**2)
    assert moved.bound_ == pytest.approx(base.bound_, rel=1e-6, abs=1e-6)


@FAST
@given(seed=seeds, d=dims, n_query=st.integers(1, 12))
def test_predict_one_equals_predict(seed, d, n_query):
    X, y = sample(seed, 50, d)
    model = SparseGPR(n_inducing=10, max_iter=20).fit(X * 3.0 - 1.0, 2.0 * y + 7.0)
    Xt = np.random.default_rng(seed).normal(size=(n_query, d)) * 3.0 - 1.0
    mean, var = model.predict(Xt)
    for i, x in enumerate(Xt):
        m1, v1 = model.predict_one(x)
        assert m1 == pytest.approx(mean[i], rel=1e-9, abs=1e-9 * np.std(y))
        assert v1 == pytest.approx(var[i], rel=1e-8, abs=1e-10 * model.signal_variance_)
