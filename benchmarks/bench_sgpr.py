"""Benchmark fmu-greybox's SparseGPR against GPy's SparseGPRegression, in one run.

Both fit the same standardised data (a simulated servo loop: lagged command, position,
velocity, load and pressure signals sampled at 1 kHz; the target is a smooth nonlinear
"missing physics" term plus 5 % noise), with the same fixed, equally spaced inducing points,
from the same initial hyperparameters and with the same cap on L-BFGS-B iterations. Reported:
fit time, the collapsed bound each reached (nats, on the standardised targets both see), and
the median latency of a single-point prediction with noise (GPy ``m.predict(x[None])``
against ``SparseGPR.predict_one``).

Usage::

    python benchmarks/bench_sgpr.py [--n N] [--m M] [--d D] [--iters K] [--repeat R] [--json]

Each figure is the median of ``--repeat`` runs (3 by default), printed with the range of the
runs, the date and the load average (``benchmarks/spread.py``); ``--json`` ends with one line
holding every run, the medians and ranges.

BLAS threads: numpy and scipy wheels each bundle their own OpenBLAS. After every call an
OpenBLAS pool keeps its worker threads spinning for about 0.1 s; GPy alternates numpy
products with scipy LAPACK calls, so on a machine with few cores each LAPACK call waits for
cores the other pool's spinning threads hold (measured here: a 400×400 Cholesky inside GPy
took 0.5 s instead of 2 ms). Unless ``--keep-blas-env`` is given, this script therefore
sets ``OPENBLAS_THREAD_TIMEOUT=1`` (idle workers sleep at once) before numpy is imported,
for both contenders alike. ``--threads K`` sets ``OPENBLAS_NUM_THREADS=K`` for both: on a
shared machine, multi-threaded OpenBLAS slows down many-fold whenever another process holds
a core, single-threaded runs do not. The 1-minute load average before and after the run
is reported.
"""

from __future__ import annotations

import os
import sys

if __name__ == "__main__":  # BLAS settings must precede the first numpy import
    if "--keep-blas-env" not in sys.argv:
        os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "1")
    if "--threads" in sys.argv[:-1]:
        os.environ["OPENBLAS_NUM_THREADS"] = sys.argv[sys.argv.index("--threads") + 1]

import argparse
import json
import time
import warnings
from collections.abc import Callable

import numpy as np
from scipy.optimize import fmin_l_bfgs_b
from spread import conditions, conditions_line, shown, summary

from fmu_greybox.gp import CollapsedBound, Hyperparameters, SparseGPR
from fmu_greybox.gp.inducing import equispaced_indices
from fmu_greybox.gp.sgpr import initial_hyperparameters

#: The figures summarised over the runs.
FIGURES = (
    "fit_ratio",
    "predict_ratio",
    "ours_fit_s",
    "gpy_fit_s",
    "ours_predict_us",
    "gpy_predict_us",
    "bound_gain",
)

SAMPLE_RATE = 1000.0  # Hz
LAG = 50  # samples (50 ms) for the lagged signals
NOISE_FRACTION = 0.05


def make_dataset(n: int, d: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Inputs and target of a servo loop recorded at 1 kHz.

    A command (multisine plus steps) drives a second-order position loop (2 Hz, ζ = 0.7);
    a slow random load acts on it. Candidate inputs, in order: command, position, velocity,
    load, pressure, then the same signals 50 ms earlier (repeatedly, for large ``d``).

    Returns
    -------
    X : ndarray, shape (n, d)
    y : ndarray, shape (n,)
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n) / SAMPLE_RATE
    phases = rng.uniform(0.0, 2.0 * np.pi, 4)
    command = sum(
        a * np.sin(2.0 * np.pi * f * t + p)
        for a, f, p in zip((1.0, 0.6, 0.4, 0.3), (0.13, 0.47, 1.3, 3.1), phases, strict=True)
    ) + 0.5 * np.sign(np.sin(2.0 * np.pi * 0.05 * t + 1.0))
    wn, zeta, dt = 2.0 * np.pi * 2.0, 0.7, 1.0 / SAMPLE_RATE
    position, velocity = np.zeros(n), np.zeros(n)
    for i in range(1, n):
        accel = wn * wn * (command[i - 1] - position[i - 1]) - 2.0 * zeta * wn * velocity[i - 1]
        velocity[i] = velocity[i - 1] + dt * accel
        position[i] = position[i - 1] + dt * velocity[i]
    load = 0.04 * np.cumsum(rng.standard_normal(n)) / np.sqrt(SAMPLE_RATE) * 20.0
    pressure = command - 0.3 * velocity / wn + 0.2 * load
    signals = [command, position, velocity, load, pressure]
    while len(signals) < d:
        s = signals[len(signals) - 5]
        signals.append(np.concatenate([np.full(LAG, s[0]), s[:-LAG]]))
    X = np.column_stack(signals[:d])
    f = 0.8 * np.tanh(3.0 * velocity / wn) + 0.4 * position * load + 0.3 * np.sin(2.0 * command)
    f += 0.1 * pressure**2
    y = f + NOISE_FRACTION * f.std() * rng.standard_normal(n)
    return X, y


def standardise(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Zero-mean, unit-variance columns and target (what both contenders are given)."""
    return (X - X.mean(0)) / X.std(0), (y - y.mean()) / y.std()


def median_latencies(
    calls: list[Callable[[np.ndarray], object]],
    points: np.ndarray,
    repeats: int,
    block: int = 100,
) -> list[float]:
    """Median wall time [s] of each ``call(x)``, timed in alternating blocks of calls.

    Alternating blocks expose every contender to the same machine load (on a shared
    machine it changes within seconds), while each block runs warm, as a tight loop.
    """
    times = np.empty((len(calls), repeats))
    for start in range(0, repeats, block):
        stop = min(start + block, repeats)
        for j, call in enumerate(calls):
            for x in points[:5]:
                call(x)
            for i in range(start, stop):
                x = points[i % len(points)]
                t0 = time.perf_counter()
                call(x)
                times[j, i] = time.perf_counter() - t0
    return [float(t) for t in np.median(times, axis=1)]


def fit_ours(Xs, ys, m: int, iters: int, seed: int) -> tuple[SparseGPR, float]:
    t0 = time.perf_counter()
    model = SparseGPR(n_inducing=m, max_iter=iters, seed=seed).fit(Xs, ys)
    return model, time.perf_counter() - t0


def fit_gpy(GPy, Xs, ys, Z, start: Hyperparameters, iters: int) -> tuple[object, float, dict]:
    """GPy's sparse GP with Z fixed, started where ours starts, ``iters`` L-BFGS-B iterations.

    ``m.optimize('lbfgsb', max_iters=K)`` would also cap function evaluations at K
    (paramz passes ``maxfun=maxiter=K``); scipy's L-BFGS-B is therefore called on GPy's own
    objective directly, with GPy's default tolerances and an iteration cap only.
    """
    kernel = GPy.kern.RBF(
        Xs.shape[1], variance=start.signal_variance, lengthscale=start.lengthscales, ARD=True
    )
    model = GPy.models.SparseGPRegression(Xs, ys[:, None], kernel=kernel, Z=Z.copy())
    model.likelihood.variance = start.noise_variance
    model.inducing_inputs.fix()
    t0 = time.perf_counter()
    x, _, info = fmin_l_bfgs_b(
        model._objective_grads, model.optimizer_array.copy(), maxiter=iters, maxfun=100 * iters
    )
    model.optimizer_array = x
    seconds = time.perf_counter() - t0
    return model, seconds, {"nit": int(info["nit"]), "funcalls": int(info["funcalls"])}


def gpy_hyperparameters(model) -> Hyperparameters:
    return Hyperparameters(
        np.array(model.kern.lengthscale, dtype=float),
        float(model.kern.variance[0]),
        float(model.likelihood.variance[0]),
    )


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=25_000, help="training samples (default 25000)")
    p.add_argument("--m", type=int, default=400, help="inducing points (default 400)")
    p.add_argument("--d", type=int, default=6, help="inputs (default 6)")
    p.add_argument("--iters", type=int, default=200, help="L-BFGS-B iteration cap (default 200)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--calls", type=int, default=2000, help="single-point calls timed, each")
    p.add_argument("--repeat", type=int, default=3, help="runs; figures are their median")
    p.add_argument("--json", action="store_true", help="end with one JSON line of results")
    p.add_argument(
        "--keep-blas-env", action="store_true", help="do not set OPENBLAS_THREAD_TIMEOUT"
    )
    p.add_argument("--threads", type=int, help="OPENBLAS_NUM_THREADS for both (default: all)")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        import GPy
    except ImportError:
        print(
            "GPy is not installed: the comparison needs it. Install the benchmark extras with\n"
            "    pip install -e .[bench]",
            file=sys.stderr,
        )
        return 2
    warnings.filterwarnings("ignore", module="GPy|paramz")

    load_before = os.getloadavg()[0]
    log = (lambda *a: print(*a, file=sys.stderr)) if args.json else print
    runs = [one_run(args, GPy, log) for _ in range(max(1, args.repeat))]
    facts = conditions(load_before)
    figures = summary(runs, FIGURES)
    for run in runs:
        print_table(run)
    print_summary(figures, len(runs), facts)
    if args.json:
        medians = {key: value["median"] for key, value in figures.items()}
        print(json.dumps({**medians, "figures": figures, **facts, "runs": runs}))
    return 0


def one_run(args: argparse.Namespace, GPy, log) -> dict:
    """Fit both on the same data, time single-point predictions; one run's figures."""
    X, y = make_dataset(args.n + 500, args.d, args.seed)
    Xs, ys = standardise(X, y)
    Xtrain, ytrain, Xquery = Xs[: args.n], ys[: args.n], Xs[args.n :]
    Xtrain, ytrain = np.ascontiguousarray(Xtrain), np.ascontiguousarray(ytrain)

    log(f"data: N={args.n} D={args.d} M={args.m}, iteration cap {args.iters}")
    log("fitting fmu-greybox SparseGPR ...")
    ours, ours_fit = fit_ours(Xtrain, ytrain, args.m, args.iters, args.seed)
    log(f"  {ours_fit:.1f} s, bound {ours.bound_:.3f}")
    # GPy gets bit for bit the data, inducing points and start ours used internally (ours
    # standardises again; on standardised data that changes only the last bits)
    Xtrain = (Xtrain - ours.x_mean_) / ours.x_scale_
    ytrain = (ytrain - ours.y_mean_) / ours.y_scale_
    Z = Xtrain[equispaced_indices(args.n, args.m)]
    assert np.array_equal(ours.posterior_.inducing_points, Z), "both must use the same Z"
    start = initial_hyperparameters(Xtrain)
    log("fitting GPy SparseGPRegression (Z fixed) ...")
    gpy, gpy_fit, gpy_info = fit_gpy(GPy, Xtrain, ytrain, Z, start, args.iters)
    gpy_bound = np.asarray(gpy.log_likelihood()).item()  # GPy returns [[value]]
    gpy_by_ours = (
        CollapsedBound(Xtrain, ytrain).evaluate(gpy_hyperparameters(gpy), Z, gradient=False).value
    )
    log(f"  {gpy_fit:.1f} s, bound {gpy_bound:.3f}")

    ours_lat, gpy_lat = median_latencies(
        [lambda x: ours.predict_one(x, full_noise=True), lambda x: gpy.predict(x[None])],
        Xquery,
        args.calls,
    )

    ours_mean = ours.predict(Xquery)[0]
    gpy_mean = gpy.predict(Xquery)[0][:, 0]
    result = {
        "n": args.n,
        "m": args.m,
        "d": args.d,
        "iters": args.iters,
        "fit_ratio": gpy_fit / ours_fit,
        "predict_ratio": gpy_lat / ours_lat,
        "ours_bound": ours.bound_,
        "gpy_bound": gpy_bound,
        "gpy_bound_recomputed_by_ours": gpy_by_ours,
        "bound_gain": ours.bound_ - gpy_bound,
        "ours_fit_s": ours_fit,
        "gpy_fit_s": gpy_fit,
        "ours_predict_us": ours_lat * 1e6,
        "gpy_predict_us": gpy_lat * 1e6,
        "ours_iterations": ours.n_iter_,
        "ours_evaluations": ours.n_eval_,
        "gpy_iterations": gpy_info["nit"],
        "gpy_evaluations": gpy_info["funcalls"],
        "held_out_rmse_ours": float(np.sqrt(np.mean((ours_mean - ys[args.n :]) ** 2))),
        "held_out_rmse_gpy": float(np.sqrt(np.mean((gpy_mean - ys[args.n :]) ** 2))),
        "openblas_thread_timeout": os.environ.get("OPENBLAS_THREAD_TIMEOUT"),
        "openblas_num_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
        "load": os.getloadavg()[0],
    }
    result["targets_met"] = bool(
        result["fit_ratio"] >= 5.0 and result["predict_ratio"] >= 10.0 and result["bound_gain"] >= 0
    )
    return result


def print_summary(figures: dict, repeat: int, facts: dict) -> None:
    """The medians and ranges over the runs."""
    print(f"SGPR benchmark, {conditions_line(facts, repeat)}:")
    print(
        f"  fit: ours {shown(figures['ours_fit_s'], 3, ' s')}, GPy "
        f"{shown(figures['gpy_fit_s'], 3, ' s')}, ratio {shown(figures['fit_ratio'], 2, 'x')}"
    )
    print(
        f"  predict one: ours {shown(figures['ours_predict_us'], 3, ' us')}, GPy "
        f"{shown(figures['gpy_predict_us'], 3, ' us')}, ratio "
        f"{shown(figures['predict_ratio'], 3, 'x')}"
    )
    print(f"  bound gain over GPy: {shown(figures['bound_gain'], 3, ' nats')}")


def print_table(r: dict) -> None:
    rows = [
        (
            "fit time [s]",
            f"{r['ours_fit_s']:.2f}",
            f"{r['gpy_fit_s']:.2f}",
            f"{r['fit_ratio']:.1f}x",
        ),
        (
            "bound [nats, std. data]",
            f"{r['ours_bound']:.3f}",
            f"{r['gpy_bound']:.3f}",
            f"{r['bound_gain']:+.3f}",
        ),
        (
            "L-BFGS-B iterations",
            f"{r['ours_iterations']}",
            f"{r['gpy_iterations']}",
            "",
        ),
        ("bound evaluations", f"{r['ours_evaluations']}", f"{r['gpy_evaluations']}", ""),
        (
            "predict one [us]",
            f"{r['ours_predict_us']:.1f}",
            f"{r['gpy_predict_us']:.1f}",
            f"{r['predict_ratio']:.1f}x",
        ),
        (
            "held-out RMSE [std.]",
            f"{r['held_out_rmse_ours']:.4f}",
            f"{r['held_out_rmse_gpy']:.4f}",
            "",
        ),
    ]
    print(f"SGPR benchmark: N={r['n']} M={r['m']} D={r['d']}, iteration cap {r['iters']}")
    print(f"{'':26s}{'fmu-greybox':>22s}{'GPy':>14s}{'ratio/gain':>12s}")
    for name, ours, gpy, ratio in rows:
        print(f"{name:26s}{ours:>22s}{gpy:>14s}{ratio:>12s}")
    print(f"GPy bound recomputed by ours: {r['gpy_bound_recomputed_by_ours']:.3f}")
    print(
        f"OPENBLAS_THREAD_TIMEOUT={r['openblas_thread_timeout']} "
        f"OPENBLAS_NUM_THREADS={r['openblas_num_threads']}, load average {r['load']:.2f} after"
    )
    print(f"targets (fit >= 5x at >= bound, predict >= 10x) met: {r['targets_met']}")


if __name__ == "__main__":
    sys.exit(main())
