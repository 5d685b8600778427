"""Fits made once per training run (``fmu_greybox/model/fit_cache.py``).

A hit must be the fit that would have been made: the model trained with the passes sharing
their fits equals, to the last bit, the one trained with every fit made afresh.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from test_export import synth_recording
from test_fmu_archive import description, rewrite

import fmu_greybox.model.simulate as simulate
import fmu_greybox.workflow.train as train
from fmu_greybox.gp import SparseGPR
from fmu_greybox.model.fit_cache import FitCache
from fmu_greybox.model.terms import CoulombForce
from fmu_greybox.project.config import load_config

ROOT = Path(__file__).resolve().parent.parent


def _problem(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(200, 2))
    return X, np.sin(X[:, 0]) + 0.1 * rng.normal(size=200)


def test_the_same_problem_is_fitted_once_even_side_by_side() -> None:
    cache = FitCache()
    X, t = _problem(0)
    started, calls = threading.Event(), []

    def slow_fit() -> SparseGPR:
        calls.append(1)
        started.set()
        return SparseGPR(n_inducing=10, max_iter=5).fit(X, t)

    results = [None, None]

    def ask(i: int) -> None:
        if i == 1:
            started.wait()  # the other thread is making the fit: this one must wait for it
        results[i] = cache.fit(SparseGPR(n_inducing=10, max_iter=5), X, t, slow_fit)

    threads = [threading.Thread(target=ask, args=(i,)) for i in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(calls) == 1 and (cache.made, cache.reused) == (1, 1)
    assert results[0][0] is results[1][0] and [r[1] for r in results] == [False, True]
    # another target, other settings: other problems
    other_t = t.copy()
    other_t[7] += 1e-12
    for corrector, targets in (
        (SparseGPR(n_inducing=10, max_iter=5), other_t),
        (SparseGPR(n_inducing=11, max_iter=5), t),
    ):
        cache.fit(corrector, X, targets, lambda c=corrector, y=targets: c.fit(X, y))
    assert (cache.made, cache.reused) == (3, 1)


def test_a_failed_fit_is_not_remembered() -> None:
    cache = FitCache()
    X, t = _problem(1)

    def broken() -> SparseGPR:
        raise FloatingPointError("no")

    with pytest.raises(FloatingPointError):
        cache.fit(SparseGPR(n_inducing=10), X, t, broken)
    fitted, reused = cache.fit(
        SparseGPR(n_inducing=10, max_iter=5), X, t, lambda: SparseGPR(10, max_iter=5).fit(X, t)
    )
    assert not reused and fitted.bound_ is not None


class _NoSharing(FitCache):
    """Makes every fit (the reference the shared fits are compared with)."""

    def fit(self, corrector, X, t, make):
        self.made += 1
        return make(), False


def test_training_with_shared_fits_equals_training_without(monkeypatch) -> None:
    """``train --terms`` shipping terms + correctors: the calibration's fits on the first half
    of the training rows are the comparison chain's (three stages: three fits fewer), and the
    model is the same to the last bit."""
    config = train.with_inducing(
        load_config(ROOT / "bench_configs" / "hydraulic_actuator.toml"), 30
    )
    config = dataclasses.replace(config, gp=dataclasses.replace(config.gp, max_iter=15))
    recording = synth_recording(3.0, seed=21)
    terms = [CoulombForce(input="load_force", source="ram_velocity", force=400.0, smoothing=2e-3)]
    models, caches = [], []
    for kind in (FitCache, _NoSharing):

        def spy(kind=kind) -> FitCache:
            caches.append(kind())
            return caches[-1]

        monkeypatch.setattr(train, "FitCache", spy)
        models.append(train.train_model(config, recording, terms=terms, ship="terms+correctors"))
    shared, fresh = caches
    assert shared.reused == 3 and shared.made == fresh.made - 3
    a, b = (m.chain for m in models)
    for ca, cb in zip(a.correctors_, b.correctors_, strict=True):
        for name in ("lengthscales_", "inducing_points_", "signal_variance_", "noise_variance_"):
            np.testing.assert_array_equal(getattr(ca, name), getattr(cb, name))
    assert a.calibration_ == b.calibration_


def test_a_row_limit_that_keeps_every_row_is_the_same_fit() -> None:
    """``optimise_rows`` at or above the rows given changes nothing: the same problem."""
    cache = FitCache()
    X, t = _problem(2)
    for limit in (None, 200, 10_000):
        corrector = SparseGPR(n_inducing=10, max_iter=5, optimise_rows=limit)
        cache.fit(corrector, X, t, lambda c=corrector: c.fit(X, t))
    assert (cache.made, cache.reused) == (1, 2)
    limited = SparseGPR(n_inducing=10, max_iter=5, optimise_rows=100)
    cache.fit(limited, X, t, lambda: limited.fit(X, t))
    assert cache.made == 2


class _Settings(FitCache):
    """Records each fit's row limit and row count."""

    def __init__(self) -> None:
        super().__init__()
        self.asked: list[tuple[int | None, int]] = []

    def fit(self, corrector, X, t, make):
        self.asked.append((corrector.optimise_rows, len(t)))
        return super().fit(corrector, X, t, make)


def test_only_the_fits_that_choose_optimise_on_spread_rows(monkeypatch) -> None:
    """``[gp] optimise_rows`` limits the fits that only choose (each stage's two candidate
    targets, the two comparison chains of ``train --terms``); the correctors that ship and the
    calibration's halves optimise on every row (with the limit for them too, more of Experiment
    1's bands failed: docs/greybox.md)."""
    limit = 300
    config = train.with_inducing(
        load_config(ROOT / "bench_configs" / "hydraulic_actuator.toml"), 30
    )
    config = dataclasses.replace(
        config, gp=dataclasses.replace(config.gp, max_iter=15, optimise_rows=limit)
    )
    recording = synth_recording(3.0, seed=21)
    terms = [CoulombForce(input="load_force", source="ram_velocity", force=400.0, smoothing=2e-3)]
    spy = _Settings()
    monkeypatch.setattr(train, "FitCache", lambda: spy)
    model = train.train_model(config, recording, terms=terms, ship="terms+correctors")
    stages = len(model.chain.stages)
    # two comparison chains: per stage two candidate targets and a final fit, all limited
    limited = [rows for rows_limit, rows in spy.asked if rows_limit == limit]
    assert len(limited) == 2 * 3 * stages and min(limited) > limit
    # the model that ships: per stage its corrector and one per calibration half, every row
    every = [rows for rows_limit, rows in spy.asked if rows_limit is None]
    assert len(every) == 3 * stages == len(spy.asked) - len(limited)
    assert min(every) > limit
    for corrector in model.chain.correctors_:
        assert corrector.optimise_rows is None and corrector.n_eval_ > 1


def test_a_white_box_instantiated_once_per_process_is_never_run_twice_at_once(
    monkeypatch, whitebox_fmu, tmp_path, two_cores
) -> None:
    """An FMU that says it can be instantiated only once per process: the comparison's two
    passes (each runs the white-box) and the noise model's runs go one after the other."""
    xml = description(whitebox_fmu).replace(
        b'canBeInstantiatedOnlyOncePerProcess="false"',
        b'canBeInstantiatedOnlyOncePerProcess="true"',
    )
    assert b'canBeInstantiatedOnlyOncePerProcess="true"' in xml
    once = rewrite(whitebox_fmu, tmp_path / "once.fmu", {"modelDescription.xml": xml})
    config = train.with_inducing(
        load_config(ROOT / "bench_configs" / "hydraulic_actuator.toml"), 20
    )
    config = dataclasses.replace(
        config, fmu=str(once), gp=dataclasses.replace(config.gp, max_iter=5)
    )
    running, most, lock = [0], [0], threading.Lock()
    real = simulate.run_native

    def counted(*args, **kwargs):
        with lock:
            running[0] += 1
            most[0] = max(most[0], running[0])
        try:
            time.sleep(0.05)  # two runs at once would overlap here
            return real(*args, **kwargs)
        finally:
            with lock:
                running[0] -= 1

    monkeypatch.setattr(simulate, "run_native", counted)
    terms = [CoulombForce(input="load_force", source="ram_velocity", force=400.0, smoothing=2e-3)]
    model = train.train_model(config, synth_recording(3.0, seed=22), terms=terms)
    assert model.training.parts is not None
    assert most == [1]
