"""Sparse GP regression (collapsed VFE bound): exactness, gradients, recovery, files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fmu_greybox.errors import ModelFormatError, NumericalError
from fmu_greybox.gp import CollapsedBound, Hyperparameters, SparseGPR, SquaredExponentialARD
from fmu_greybox.gp.inducing import equispaced_indices, make_selector
from fmu_greybox.gp.linalg import jittered_cholesky

# --------------------------------------------------------------------------- helpers


class ExactGP:
    """Reference exact GP regression (N×N Cholesky), SE-ARD kernel, zero mean."""

    def __init__(self, X, y, hyp: Hyperparameters) -> None:
        self.X, self.y = X, y
        self.kernel = SquaredExponentialARD(hyp.lengthscales, hyp.signal_variance)
        self.noise = hyp.noise_variance
        K = self.kernel(X, X) + self.noise * np.eye(len(X))
        self.L = np.linalg.cholesky(K)
        self.alpha = np.linalg.solve(self.L.T, np.linalg.solve(self.L, y))

    def log_marginal_likelihood(self) -> float:
        n = len(self.y)
        return float(
            -0.5 * self.y @ self.alpha
            - np.sum(np.log(np.diag(self.L)))
            - 0.5 * n * np.log(2 * np.pi)
        )

    def predict(self, Xt):
        Ks = self.kernel(Xt, self.X)
        V = np.linalg.solve(self.L, Ks.T)
        return Ks @ self.alpha, self.kernel.diag(Xt) - np.sum(V * V, axis=0)


def toy_data(n=40, d=2, seed=0, noise=0.1):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2.0, 2.0, size=(n, d))
    y = np.sin(2.0 * X[:, 0]) + 0.5 * X[:, -1] ** 2 + noise * rng.standard_normal(n)
    return X, y


def standardised(X, y):
    return (X - X.mean(0)) / X.std(0), (y - y.mean()) / y.std()


HYP = Hyperparameters(np.array([0.7, 1.6, 1.1]), 1.3, 0.08)


# ----------------------------------------------------------------- exactness (M = N)


def test_bound_equals_exact_log_marginal_likelihood_when_inducing_equal_inputs():
    X, y = toy_data(n=35, d=3)
    result = CollapsedBound(X, y).evaluate(HYP, X.copy(), gradient=False)
    assert result.jitter == pytest.approx(1e-10 * HYP.signal_variance)
    exact = ExactGP(X, y, HYP).log_marginal_likelihood()
    assert result.value == pytest.approx(exact, rel=1e-8)


def test_fitted_predictions_equal_exact_gp_when_inducing_equal_inputs():
    X, y = toy_data(n=30, d=2, noise=0.2)
    # the default jitter floor (1e-10 s²) acts like extra noise σ²·1e-10·Kff⁻¹ along Kff's
    # weakest directions; switch it off to check the algebra to 1e-8
    model = SparseGPR(n_inducing=len(X), max_iter=100, min_jitter=0.0).fit(X, y)
    assert model.jitter_ == 0.0
    assert model.inducing_points_ == pytest.approx(X, rel=1e-12, abs=1e-12)
    post = model.posterior_
    Xs, ys = standardised(X, y)
    hyp = Hyperparameters(post.lengthscales, post.signal_variance, post.noise_variance)
    exact = ExactGP(Xs, ys, hyp)
    assert model.bound_ == pytest.approx(exact.log_marginal_likelihood(), rel=1e-8)

    Xt = np.random.default_rng(5).uniform(-2.5, 2.5, size=(25, 2))
    mean, var = model.predict(Xt)
    mean_ref, var_ref = exact.predict((Xt - X.mean(0)) / X.std(0))
    assert mean == pytest.approx(mean_ref * y.std() + y.mean(), rel=1e-8)
    assert var == pytest.approx(var_ref * y.var(), rel=1e-8)
    _, var_noisy = model.predict(Xt, full_noise=True)
    assert var_noisy == pytest.approx(var + model.noise_variance_, rel=1e-12)


@pytest.mark.parametrize("m", [3, 10, 25])
def test_bound_is_below_exact_log_marginal_likelihood(m):
    X, y = toy_data(n=60, d=3, seed=2)
    Z = X[equispaced_indices(len(X), m)]
    sparse = CollapsedBound(X, y).evaluate(HYP, Z, gradient=False).value
    assert sparse < ExactGP(X, y, HYP).log_marginal_likelihood()


# -------------------------------------------------------------------------- gradients


def test_analytic_gradients_match_finite_differences():
    X, y = toy_data(n=50, d=3, seed=3)
    Z = X[:12] + 0.05
    bound = CollapsedBound(X, y)
    log_theta = np.concatenate([np.log(HYP.lengthscales), np.log([1.3, 0.08])])

    def value(theta, Zp):
        hyp = Hyperparameters(np.exp(theta[:3]), np.exp(theta[3]), np.exp(theta[4]))
        return bound.evaluate(hyp, Zp, gradient=False).value

    g = bound.evaluate(HYP, Z, inducing_gradient=True).gradient
    analytic = np.concatenate(
        [
            g.log_lengthscales,
            [g.log_signal_variance, g.log_noise_variance],
            g.inducing_points.ravel(),
        ]
    )
    h = 1e-6
    numeric = []
    for i in range(5):
        e = np.zeros(5)
        e[i] = h
        numeric.append((value(log_theta + e, Z) - value(log_theta - e, Z)) / (2 * h))
    for i in range(Z.size):
        E = np.zeros(Z.size)
        E[i] = h
        E = E.reshape(Z.shape)
        numeric.append((value(log_theta, Z + E) - value(log_theta, Z - E)) / (2 * h))
    assert analytic == pytest.approx(np.array(numeric), rel=1e-5, abs=1e-5)


# --------------------------------------------------------------------------- fitting


def test_relevant_and_irrelevant_lengthscales_recovered():
    rng = np.random.default_rng(7)
    X = rng.uniform(-3.0, 3.0, size=(600, 2))
    y = np.sin(1.5 * X[:, 0]) + 0.05 * rng.standard_normal(600)
    model = SparseGPR(n_inducing=30, inducing="kmeans", seed=1).fit(X, y)
    relevant, irrelevant = model.lengthscales_
    assert 0.3 < relevant < 3.0
    assert irrelevant > 20.0 * relevant
    assert model.noise_variance_ == pytest.approx(0.05**2, rel=0.3)


def test_optimising_inducing_points_raises_the_bound():
    X, y = toy_data(n=150, d=2, seed=4)
    fixed = SparseGPR(n_inducing=6, max_iter=100).fit(X, y)
    moved = SparseGPR(n_inducing=6, optimise_inducing=True, max_iter=100).fit(X, y)
    assert moved.bound_ > fixed.bound_
    assert not np.allclose(moved.inducing_points_, fixed.inducing_points_)


@pytest.mark.parametrize("strategy", ["equispaced", "kmeans", "greedy"])
def test_inducing_strategies_fit_and_are_deterministic(strategy):
    X, y = toy_data(n=200, d=2, seed=6)
    a = SparseGPR(n_inducing=15, inducing=strategy, seed=3, max_iter=60).fit(X, y)
    b = SparseGPR(n_inducing=15, inducing=strategy, seed=3, max_iter=60).fit(X, y)
    assert a.inducing_points_.shape == (15, 2)
    assert len(np.unique(a.inducing_points_, axis=0)) == 15
    assert np.array_equal(a.inducing_points_, b.inducing_points_)
    assert a.bound_ == b.bound_
    mean, _ = a.predict(X)
    assert np.sqrt(np.mean((mean - y) ** 2)) < 0.2


def test_greedy_selection_picks_training_points_that_reduce_variance():
    X, _ = toy_data(n=300, d=2, seed=8)
    kernel = SquaredExponentialARD(np.array([0.5, 0.5]), 1.0)
    Z = make_selector("greedy").select(X, 20, kernel, np.random.default_rng(0))
    assert all(any(np.array_equal(z, x) for x in X) for z in Z)
    L, _ = jittered_cholesky(kernel(Z, Z))
    V = np.linalg.solve(L, kernel(Z, X))
    random_Z = X[np.random.default_rng(1).choice(300, 20, replace=False)]
    Lr, _ = jittered_cholesky(kernel(random_Z, random_Z))
    Vr = np.linalg.solve(Lr, kernel(random_Z, X))
    assert np.sum(1.0 - np.sum(V * V, 0)) < np.sum(1.0 - np.sum(Vr * Vr, 0))


def test_unknown_inducing_strategy_is_named():
    with pytest.raises(ValueError, match="kmeans"):
        SparseGPR(inducing="sobol").fit(*toy_data())


def test_fit_is_deterministic_and_reports_progress():
    X, y = toy_data(n=600, d=2, seed=9)
    calls = []
    kwargs = dict(n_inducing=20, inducing="kmeans", max_iter=50, seed=11)
    a = SparseGPR(**kwargs).fit(X, y, progress=lambda i, b: calls.append((i, b)))
    b = SparseGPR(**kwargs).fit(X, y)
    assert [i for i, _ in calls] == list(range(1, a.n_iter_ + 1))
    assert calls[-1][1] == pytest.approx(a.bound_, rel=1e-9)
    assert a.bound_ == b.bound_
    assert np.array_equal(a.predict(X)[0], b.predict(X)[0])


def test_invalid_training_data_is_reported():
    X, y = toy_data()
    with pytest.raises(ValueError, match="shape"):
        SparseGPR().fit(X, y[:-1])
    X[3, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        SparseGPR().fit(X, y)


# ------------------------------------------------------------------------- numerics


def test_jittered_cholesky_adds_only_the_jitter_needed():
    K = np.ones((3, 3))  # rank one
    L, jitter = jittered_cholesky(K, min_relative_jitter=0.0)
    assert 0.0 < jitter <= 1e-8
    assert L @ L.T == pytest.approx(K + jitter * np.eye(3), abs=1e-14)
    assert jittered_cholesky(np.eye(2))[1] == 1e-10
    assert jittered_cholesky(np.eye(2), min_relative_jitter=0.0)[1] == 0.0


def test_hopeless_cholesky_raises_numerical_error_with_advice():
    with pytest.raises(NumericalError, match="inducing"):
        jittered_cholesky(np.array([[1.0, 2.0], [2.0, 1.0]]))
    with pytest.raises(NumericalError, match="NaN"):
        jittered_cholesky(np.array([[1.0, np.nan], [np.nan, 1.0]]))


def test_duplicated_inducing_points_without_jitter_raise_numerical_error():
    X = np.ones((10, 2))
    y = np.arange(10.0)
    with pytest.raises(NumericalError, match="max_jitter"):
        SparseGPR(n_inducing=10, min_jitter=0.0, max_jitter=0.0).fit(X, y)


# ----------------------------------------------------------------------- prediction


@pytest.fixture(scope="module")
def fitted():
    X, y = toy_data(n=300, d=3, seed=12)
    return SparseGPR(n_inducing=25, max_iter=80).fit(X * [1.0, 10.0, 0.1] + 3.0, 5.0 * y - 2.0)


def test_predict_one_equals_batched_predict(fitted):
    Xt = np.random.default_rng(13).uniform(-2.0, 2.0, size=(40, 3)) * [1.0, 10.0, 0.1] + 3.0
    for full_noise in (False, True):
        mean, var = fitted.predict(Xt, full_noise=full_noise)
        one = np.array([fitted.predict_one(x, full_noise=full_noise) for x in Xt])
        assert one[:, 0] == pytest.approx(mean, rel=1e-10)
        # the variance is s² less a nearly equal quantity: compare on the scale of s²
        assert one[:, 1] == pytest.approx(var, rel=1e-10, abs=1e-11 * fitted.signal_variance_)
    assert all(isinstance(v, float) for v in fitted.predict_one(Xt[0]))


def test_predict_one_grad_gives_the_mean_gradient(fitted):
    x = np.array([0.3, 12.0, 0.05]) + 3.0
    mean, var, grad = fitted.predict_one_grad(x)
    ref_mean, ref_var = fitted.predict(x[None])
    assert mean == pytest.approx(ref_mean[0], rel=1e-9)
    assert var == pytest.approx(ref_var[0], rel=1e-7)
    steps = np.array([1e-5, 1e-4, 1e-6])
    numeric = [
        (fitted.predict(x[None] + h * e)[0][0] - fitted.predict(x[None] - h * e)[0][0]) / (2 * h)
        for h, e in zip(steps, np.eye(3), strict=True)
    ]
    numeric = np.array(numeric)
    assert grad == pytest.approx(numeric, rel=1e-5, abs=1e-7 * np.abs(numeric).max())


def test_predict_checks_the_input_shape(fitted):
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        fitted.predict(np.zeros((4, 2)))


# ----------------------------------------------------------------------- save / load


def test_save_load_round_trip_is_bitwise(fitted, tmp_path):
    npz, js = fitted.save(tmp_path / "corrector.v1")
    assert npz.name == "corrector.v1.npz" and js.name == "corrector.v1.json"
    loaded = SparseGPR.load(tmp_path / "corrector.v1")
    Xt = np.random.default_rng(14).normal(size=(30, 3)) * [1.0, 10.0, 0.1] + 3.0
    for full_noise in (False, True):
        assert np.array_equal(loaded.predict(Xt, full_noise)[0], fitted.predict(Xt, full_noise)[0])
        assert np.array_equal(loaded.predict(Xt, full_noise)[1], fitted.predict(Xt, full_noise)[1])
    assert loaded.predict_one(Xt[0]) == fitted.predict_one(Xt[0])
    assert np.array_equal(loaded.lengthscales_, fitted.lengthscales_)
    assert loaded.bound_ == fitted.bound_
    assert loaded.training_data_sha256_ == fitted.training_data_sha256_
    meta = json.loads(js.read_text())
    assert meta["format_version"] == 1
    assert meta["settings"]["n_inducing"] == 25


def test_unknown_format_version_is_refused(fitted, tmp_path):
    _, js = fitted.save(tmp_path / "m")
    meta = json.loads(js.read_text())
    meta["format_version"] = 99
    js.write_text(json.dumps(meta))
    with pytest.raises(ModelFormatError, match=r"m\.json.*unknown format version 99"):
        SparseGPR.load(tmp_path / "m")


def test_missing_array_is_named(fitted, tmp_path):
    npz, js = fitted.save(tmp_path / "m")
    with np.load(npz) as data:
        arrays = {k: data[k] for k in data.files if k != "chol_b"}
    np.savez(npz, **arrays)
    meta = json.loads(js.read_text())
    meta["arrays_sha256"] = __import__("hashlib").sha256(npz.read_bytes()).hexdigest()
    js.write_text(json.dumps(meta))
    with pytest.raises(ModelFormatError, match=r"m\.npz.*missing array.*chol_b"):
        SparseGPR.load(tmp_path / "m")


def test_tampered_or_missing_files_are_refused(fitted, tmp_path):
    npz, _ = fitted.save(tmp_path / "m")
    npz.write_bytes(npz.read_bytes()[:-10] + b"0123456789")
    with pytest.raises(ModelFormatError, match=r"m\.npz.*SHA-256"):
        SparseGPR.load(tmp_path / "m")
    npz.unlink()
    with pytest.raises(ModelFormatError, match=r"m\.npz.*missing"):
        SparseGPR.load(tmp_path / "m")
    with pytest.raises(ModelFormatError, match=r"other\.json.*not found"):
        SparseGPR.load(tmp_path / "other")


def test_object_arrays_are_never_unpickled(fitted, tmp_path):
    npz, js = fitted.save(tmp_path / "m")
    with np.load(npz) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["mean_weights"] = np.array([object()], dtype=object)
    np.savez(npz, **arrays)
    meta = json.loads(js.read_text())
    meta["arrays_sha256"] = __import__("hashlib").sha256(npz.read_bytes()).hexdigest()
    js.write_text(json.dumps(meta))
    with pytest.raises(ModelFormatError, match=r"m\.npz"):
        SparseGPR.load(tmp_path / "m")


# ------------------------------------------------- warm starts, given hyperparameters


def test_given_hyperparameters_give_the_fits_posterior_without_optimising(fitted):
    """``max_iter = 0`` with ``start`` at a fit's hyperparameters (original units) gives that
    fit's posterior on the same data: one bound evaluation, no iteration; the data's other
    standardisation (a subset) is converted, so the posterior is at the same kernel."""
    X, y = toy_data(n=300, d=3, seed=12)
    X, y = X * [1.0, 10.0, 0.1] + 3.0, 5.0 * y - 2.0
    again = SparseGPR(n_inducing=25, max_iter=0).fit(X, y, start=fitted.hyperparameters_)
    assert (again.n_iter_, again.n_eval_) == (0, 1)
    assert again.bound_ == pytest.approx(fitted.bound_, rel=1e-10)
    Xt = X[::7] + 0.01
    np.testing.assert_allclose(again.predict(Xt)[0], fitted.predict(Xt)[0], rtol=1e-8, atol=1e-8)
    half = SparseGPR(n_inducing=25, max_iter=0).fit(X[:150], y[:150], start=fitted.hyperparameters_)
    np.testing.assert_allclose(half.lengthscales_, fitted.lengthscales_, rtol=1e-12)
    assert half.noise_variance_ == pytest.approx(fitted.noise_variance_, rel=1e-12)


def test_a_warm_start_at_the_optimum_stops_at_once(fitted):
    """Started at its own optimum, the optimiser has almost nothing left to do."""
    X, y = toy_data(n=300, d=3, seed=12)
    X, y = X * [1.0, 10.0, 0.1] + 3.0, 5.0 * y - 2.0
    warm = SparseGPR(n_inducing=25, max_iter=80).fit(X, y, start=fitted.hyperparameters_)
    assert warm.n_iter_ <= 3 < fitted.n_iter_
    assert warm.bound_ >= fitted.bound_ - 1e-6 * abs(fitted.bound_)


def test_hyperparameters_optimised_on_spread_rows_condition_on_every_row():
    """``optimise_rows``: the optimisation sees that many rows evenly spread; the posterior
    and the bound are those of every row at the hyperparameters found (what a fit with those
    hyperparameters given gives); at least N rows is a plain fit."""
    X, y = toy_data(n=2000, d=2, seed=5)
    thinned = SparseGPR(n_inducing=30, max_iter=60, optimise_rows=400).fit(X, y)
    rows = np.linspace(0, 1999, 400).round().astype(int)
    # (standardised and given inducing points with every row, hence not bit for bit)
    on_rows = SparseGPR(n_inducing=30, max_iter=60).fit(X[rows], y[rows])
    np.testing.assert_allclose(thinned.lengthscales_, on_rows.lengthscales_, rtol=0.05)
    given = SparseGPR(n_inducing=30, max_iter=0).fit(X, y, start=thinned.hyperparameters_)
    assert thinned.bound_ == pytest.approx(given.bound_, rel=1e-10)
    Xt = X[::50] + 0.01
    np.testing.assert_allclose(thinned.predict(Xt)[0], given.predict(Xt)[0], atol=1e-10)
    plain = SparseGPR(n_inducing=30, max_iter=60).fit(X, y)
    everything = SparseGPR(n_inducing=30, max_iter=60, optimise_rows=2000).fit(X, y)
    assert everything.bound_ == plain.bound_ and everything.n_eval_ == plain.n_eval_


# ------------------------------------------------------------- the bound in two blocks


def _bound_parts(result) -> np.ndarray:
    g = result.gradient
    return np.concatenate(
        [
            [result.value, g.log_signal_variance, g.log_noise_variance],
            g.log_lengthscales,
            g.inducing_points.ravel(),
            result.mean_weights,
        ]
    )


@pytest.fixture()
def blocked(monkeypatch):
    """Bounds of 50 rows or more are evaluated in two blocks."""
    import fmu_greybox.gp.bound as bound_module

    monkeypatch.setattr(bound_module, "BLOCK_ROWS", 50)
    return bound_module


def test_the_bound_in_two_blocks_equals_the_bound_in_one(blocked):
    X, y = toy_data(n=80, d=3, seed=4)
    Z = X[:15] + 0.05
    whole = CollapsedBound(X[:49], y[:49]).evaluate(HYP, Z, inducing_gradient=True)
    assert len(CollapsedBound(X[:49], y[:49])._blocks) == 1
    two = CollapsedBound(X, y)
    assert [b.y.size for b in two._blocks] == [40, 40]
    one = CollapsedBound(X, y)
    one._blocks = [blocked._Block(np.vstack([b.features for b in two._blocks]), y)]
    expected = _bound_parts(one.evaluate(HYP, Z, inducing_gradient=True))
    assert _bound_parts(two.evaluate(HYP, Z, inducing_gradient=True)) == pytest.approx(
        expected, rel=1e-11, abs=1e-11
    )
    assert not np.allclose(_bound_parts(whole), expected)  # the rows count


def test_the_blocks_give_the_same_bits_side_by_side_or_one_after_the_other(blocked, monkeypatch):
    import threading

    from fmu_greybox import side_by_side

    monkeypatch.setattr(side_by_side, "available_cores", lambda: 2)  # one core runs two too
    X, y = toy_data(n=120, d=3, seed=5)
    Z = X[:20] + 0.05
    threads: set[str] = set()
    gram = blocked._Block.gram
    together_now: list[threading.Barrier] = []

    def spied(block, *args):
        threads.add(threading.current_thread().name)
        for barrier in together_now:  # both blocks at once, or a timeout
            barrier.wait(timeout=10)
        return gram(block, *args)

    monkeypatch.setattr(blocked._Block, "gram", spied)
    in_turn = _bound_parts(CollapsedBound(X, y).evaluate(HYP, Z, inducing_gradient=True))
    assert threads == {threading.current_thread().name}  # BLAS not held to one thread
    threads.clear()
    together_now.append(threading.Barrier(2))
    with side_by_side.one_blas_thread():
        assert side_by_side.spare_core()
        together = _bound_parts(CollapsedBound(X, y).evaluate(HYP, Z, inducing_gradient=True))
    assert len(threads) == 2 and threading.current_thread().name not in threads
    np.testing.assert_array_equal(together, in_turn)
