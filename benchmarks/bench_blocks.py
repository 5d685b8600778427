"""A sparse-GP fit that runs alone: its bound's two blocks of rows one after the other, against
side by side on two threads (``fmu_greybox/gp/bound.py``, ``side_by_side.spare_core``).

Training holds BLAS to one thread and runs independent fits side by side; a fit with nothing
beside it (a stage of the chain that ships, one after the other) splits its M x N work in two
blocks of rows, each on its own thread, from ``BLOCK_ROWS`` rows on. The peer is the same fit
with the same blocks in turn on one thread, which gives the same numbers bit for bit (checked
here). The data: N rows of D standard-normal inputs, a smooth target with 10 % noise.

Usage::

    .venv/bin/python benchmarks/bench_blocks.py [--n 30000] [--m 300] [--d 8] [--iters 25]
        [--repeat 3]

Prints the median fit time of each with its range, and the ratio.
"""

from __future__ import annotations

import argparse
import functools
import os

import numpy as np
from spread import alternated, print_against, yes

import fmu_greybox.gp.bound as bound_module
from fmu_greybox import side_by_side
from fmu_greybox.gp import SparseGPR


def fit(X: np.ndarray, y: np.ndarray, m: int, iters: int, spare: bool) -> SparseGPR:
    """One fit, its blocks side by side (``spare``) or in turn."""
    bound_module.spare_core = lambda: spare
    return SparseGPR(n_inducing=m, max_iter=iters, seed=0).fit(X, y)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=30000)
    parser.add_argument("--m", type=int, default=300)
    parser.add_argument("--d", type=int, default=8)
    parser.add_argument("--iters", type=int, default=25)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    if args.n < bound_module.BLOCK_ROWS:
        parser.error(f"--n must be at least BLOCK_ROWS = {bound_module.BLOCK_ROWS}")
    load_before = os.getloadavg()[0]
    rng = np.random.default_rng(0)
    X = rng.standard_normal((args.n, args.d))
    y = np.sin(X[:, 0]) + 0.3 * X[:, 1] * X[:, 2] + 0.1 * rng.standard_normal(args.n)
    ways = {
        "blocks in turn": functools.partial(fit, X, y, args.m, args.iters, False),
        "side by side": functools.partial(fit, X, y, args.m, args.iters, True),
    }
    with side_by_side.one_blas_thread():
        figures, fits = alternated(ways, args.repeat)
    turn, both = fits["blocks in turn"], fits["side by side"]
    same = turn.bound_ == both.bound_ and np.array_equal(
        turn.posterior_.mean_weights, both.posterior_.mean_weights
    )
    print_against(
        f"one fit, N = {args.n}, M = {args.m}, D = {args.d}, {turn.n_eval_} bound evaluations",
        figures,
        "side by side",
        "blocks in turn",
        f"the same numbers: {yes(same)}",
        load_before,
        args.repeat,
    )


if __name__ == "__main__":
    main()
