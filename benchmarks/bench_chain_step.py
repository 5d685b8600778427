"""The chain step at M inducing points per stage: its cost, what bounds it, and the routes to a
cheaper one measured against the 1e-6 accuracy the standard deviations must keep.

The three-stage actuator is trained as in ``bench_export.py`` (6 s recording, M inducing points
per stage, 5 optimiser iterations) and its compiled chain step (``native/chain_core.c``, the
code both runtimes run) is run over the recording's white-box outputs (a free run). Printed:

- ``exact``: CPU time per step of the compiled step, called from a Python loop (the median of
  ``--repeats`` runs, with their range, the date and the load: ``spread.py``), and its size:
  the bytes of the stages' packed triangular factors, which it streams once per step;
- ``streaming floor``: the time of one pass of numpy's (vectorised) maximum over those bytes,
  the least of 500 (wall clock: the least pass is one the process was not preempted in): no
  step that reads every factor once can be much faster on this machine;
- ``in C`` (``chain_floor.c``, compiled here with the chain core's options): the same step
  timed in C, with no Python between the steps (CPU time per step of one run over the
  recording, the median of ``--repeats`` runs), and two floors under it, each the least of 500
  passes: one pass *reading* the factors (a vectorised sum: the bytes alone), and one pass of
  *multiply-adds* over factors of the same size with no entry waiting for another (the explicit
  inverses ``G = H^-1``, ``g = G k``: an exact form that has no serial dependency, unlike the
  solve; its standard deviations are compared with the solve's over the recording). Each floor
  also for one stage's factor three times in a row, which stays in the core's cache: what is
  left then is arithmetic;
- ``float32 factors``: the largest relative error of any stage's standard deviation, over the
  free run, when the factors are rounded to float32 (half the bytes; computed in float64);
- ``low rank``: per stage, the singular values of the whitened kernel rows ``g = H^-1 k`` over
  the run (relative to the largest), and the least rank r whose projection keeps every
  standard deviation of the run within 1e-6 (relative; in-sample, so optimistic): a low-rank
  variance costs about r M per stage instead of M^2 / 2; with it, how dense the kernel rows
  are (the entries above 1e-16 of their row's largest: a step could skip the others' columns of
  ``H^-1`` exactly), and the cancellation: the prior variance over the least latent variance
  of the run (the variance is the prior minus a quadratic form, so a relative error of the
  form is multiplied by that ratio in the variance; why rounded factors fail).

Usage: ``.venv/bin/python benchmarks/bench_chain_step.py [--inducing 400] [--repeats 5]``.
"""

from __future__ import annotations

import argparse
import ctypes
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.linalg import solve_triangular

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bench_export import ROOT, chain_step, recording
from spread import conditions, conditions_line

from fmu_greybox import _chainstep
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.fmi.compiler import NATIVE_DIR, CBuild, compile_library, core_flags
from fmu_greybox.gp.linalg import aligned_zeros
from fmu_greybox.gp.predictive import packed_factor, point_factor
from fmu_greybox.model.stage_data import prepare
from fmu_greybox.model.store import load_model, save_model
from fmu_greybox.project.config import load_config
from fmu_greybox.workflow.train import train_model, with_inducing

#: Accuracy every standard deviation must keep (relative to the exact one).
STD_RTOL = 1e-6


def factor_length(m: int) -> int:
    """Doubles of a packed factor of m inducing points (chain_core.c, column_start(m, LD))."""
    ld = -(-m // 8) * 8
    return sum(ld - j // 8 * 8 for j in range(m))


#: Fields of the plan's header before the stage records (``ChainPlan``'s layout).
PLAN_HEADER = 7


def stage_record(plan: np.ndarray, q: int) -> np.ndarray:
    """Stage ``q``'s record of the plan (params offset, M, ..., active, ...), whatever the
    record's length in this plan version."""
    length = (plan.size - PLAN_HEADER) // int(plan[1])
    return plan[PLAN_HEADER + q * length : PLAN_HEADER + (q + 1) * length]


def free_run_std(plan: np.ndarray, params: np.ndarray, chain, data) -> np.ndarray:
    """Standard deviations of the compiled chain over the recording, shape (n - 1, Q)."""
    exo, y_wb = np.ascontiguousarray(data.exo), np.ascontiguousarray(data.y_wb)
    state = chain.plan().start(y_wb[0], exo[0])
    work = np.zeros(int(plan[4]))
    std = np.empty((exo.shape[0] - 1, y_wb.shape[1]))
    for j in range(1, exo.shape[0]):
        _chainstep.step(plan, params, work, state.values, exo[j - 1], y_wb[j], True)
        std[j - 1] = np.sqrt(state.out_var)
    return std


def float32_factors(plan: np.ndarray, params: np.ndarray) -> np.ndarray:
    """The parameters with every stage's packed factor rounded to float32."""
    rounded = params.copy()
    for q in range(int(plan[1])):
        offset, m, active = (int(stage_record(plan, q)[k]) for k in (0, 1, 6))
        if active:
            block = slice(offset, offset + factor_length(m))
            rounded[block] = params[block].astype(np.float32).astype(np.float64)
    return rounded


def kernel_rows(chain, data, q: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Stage ``q``'s kernel rows over the recording (teacher-forced inputs), shape (M, n), its
    triangular factor H, shape (M, M), and its signal variance (standardised units)."""
    posterior = chain.correctors_[q].posterior_
    X, _ = chain.stages[q].teacher_forced(chain.layout, data.exo, data.y_wb, data.outputs)
    xs = X * posterior._input_weight - posterior._input_offset
    exponent = posterior._z_scaled @ xs.T + posterior._z_offset[:, None]
    K = np.exp(exponent - 0.5 * np.einsum("nd,nd->n", xs, xs)[None, :])
    H, _ = point_factor(posterior.chol_uu, posterior.chol_b, posterior.mean_weights)
    return K, H, float(posterior.signal_variance)


def low_rank(chain, data) -> list[dict[str, object]]:
    """Per stage the singular values of the whitened kernel rows and the least rank that keeps
    the latent standard deviations within STD_RTOL (see the module docstring)."""
    figures = []
    for q, stage in enumerate(chain.stages):
        K, H, signal_variance = kernel_rows(chain, data, q)
        G = solve_triangular(H, K, lower=True)
        var = signal_variance - np.einsum("mn,mn->n", G, G)
        U, s, _ = np.linalg.svd(G, full_matrices=False)
        rank = G.shape[0]
        for r in range(8, G.shape[0], 8):
            kept = U[:, :r].T @ G
            approx = signal_variance - np.einsum("rn,rn->n", kept, kept)
            if np.all(np.abs(np.sqrt(np.maximum(approx, 0)) / np.sqrt(var) - 1) <= STD_RTOL):
                rank = r
                break
        ratios = {r: float(s[r] / s[0]) for r in (50, 100, 200, 300) if r < s.size}
        # entries a step could skip exactly: below 1e-16 of its row's largest
        dense = np.sum(np.abs(K) > 1e-16 * np.abs(K).max(axis=0), axis=0)
        figures.append(
            {
                "stage": stage.name,
                "M": G.shape[0],
                "rank": rank,
                "sv": ratios,
                "dense_min": int(dense.min()),
                "dense_median": float(np.median(dense)),
                "cancellation": float(signal_variance / var.min()),
            }
        )
    return figures


def streaming_floor(plan: np.ndarray, params: np.ndarray) -> float:
    """Time [us] of one pass of numpy's maximum over the stages' factors (least of 500)."""
    blocks = []
    for q in range(int(plan[1])):
        offset, m = (int(v) for v in stage_record(plan, q)[:2])
        blocks.append(params[offset : offset + factor_length(m)])
    best = np.inf
    for _ in range(500):
        start = time.perf_counter()
        for block in blocks:
            np.maximum.reduce(block)
        best = min(best, time.perf_counter() - start)
    return best * 1e6


def packed(factor: np.ndarray) -> np.ndarray:
    """A lower-triangular (M, M) matrix in the chain core's packed layout, on a cache line."""
    flat = packed_factor(np.tril(factor))
    out = aligned_zeros(flat.size)
    out[:] = flat
    return out


def floor_library(folder: Path) -> ctypes.CDLL:
    """``chain_floor.c`` and the chain core, compiled into ``folder`` with the core's options."""
    library = folder / "libchainfloor.so"
    sources = (Path(__file__).with_name("chain_floor.c"), NATIVE_DIR / "chain_core.c")
    build = CBuild("the chain floor benchmark", sources, core_flags(), include_dirs=(NATIVE_DIR,))
    compile_library(build, library)
    lib = ctypes.CDLL(str(library))
    pointer, size = ctypes.c_void_p, ctypes.c_ssize_t
    checksum = ctypes.POINTER(ctypes.c_double)
    lib.floor_read.argtypes = [pointer, pointer, ctypes.c_int, ctypes.c_int, ctypes.c_int, checksum]
    lib.floor_multiply.argtypes = [
        pointer,
        pointer,
        size,
        ctypes.c_int,
        ctypes.c_int,
        ctypes.c_int,
        pointer,
        checksum,
    ]
    lib.step_seconds.argtypes = [pointer, pointer, pointer, pointer, size, checksum]
    for name in ("floor_read", "floor_multiply", "step_seconds"):
        getattr(lib, name).restype = ctypes.c_double
    return lib


def explicit_inverses(plan, chain, data) -> tuple[list, list, float]:
    """Per active stage its explicit inverse ``G = H^-1`` (packed) and one kernel row (the
    recording's middle), and the largest relative difference of ``sqrt(s2 - |G k|^2)`` from the
    solve's latent standard deviation over the recording."""
    inverses, rows, error = [], [], 0.0
    for q in range(int(plan[1])):
        m, active = (int(stage_record(plan, q)[k]) for k in (1, 6))
        if not active:
            continue
        K, H, signal_variance = kernel_rows(chain, data, q)
        inverse = solve_triangular(H, np.eye(m), lower=True)
        solved, multiplied = solve_triangular(H, K, lower=True), inverse @ K
        std = np.sqrt(signal_variance - np.einsum("mn,mn->n", solved, solved))
        other = np.sqrt(signal_variance - np.einsum("mn,mn->n", multiplied, multiplied))
        error = max(error, float(np.max(np.abs(other / std - 1.0))))
        inverses.append(packed(inverse))
        rows.append(K[:, K.shape[1] // 2])
    return inverses, rows, error


def c_figures(plan, params, chain, data, repeats: int) -> dict[str, float]:
    """The step timed in C and the floors under it [us], and the largest relative difference
    of the explicit-inverse form's latent standard deviations from the solve's (see the module
    docstring)."""
    checksum = ctypes.c_double(0.0)
    total = ctypes.byref(checksum)
    blocks = []
    for q in range(int(plan[1])):
        offset, m, active = (int(stage_record(plan, q)[k]) for k in (0, 1, 6))
        if active:
            blocks.append(params[offset : offset + factor_length(m)])
    inverses, rows, error = explicit_inverses(plan, chain, data)
    figures: dict[str, float] = {"inverse_std_error": error}
    lengths = [b.size for b in blocks]
    m = int(stage_record(plan, 0)[1])
    addresses = (ctypes.c_void_p * len(blocks))(*(b.ctypes.data for b in blocks))
    sizes = np.array(lengths, dtype=np.intp)
    factors = (ctypes.c_void_p * len(inverses))(*(g.ctypes.data for g in inverses))
    k = np.ascontiguousarray(np.stack(rows))
    g = np.zeros(-(-m // 8) * 8)
    with tempfile.TemporaryDirectory() as tmp:
        lib = floor_library(Path(tmp))
        exo, y_wb = np.ascontiguousarray(data.exo), np.ascontiguousarray(data.y_wb)
        steps = [
            lib.step_seconds(
                plan.ctypes.data,
                params.ctypes.data,
                exo.ctypes.data,
                y_wb.ctypes.data,
                exo.shape[0],
                total,
            )
            for _ in range(repeats)
        ]
        figures["step"] = float(np.median(steps)) * 1e6
        count = len(blocks)
        read = lib.floor_read(addresses, sizes.ctypes.data, count, 1, 500, total)
        cached = lib.floor_read(addresses, sizes.ctypes.data, 1, count, 500, total)
        times = (m, count, 1, 500, g.ctypes.data, total)
        multiply = lib.floor_multiply(factors, k.ctypes.data, *times)
        times = (m, 1, count, 500, g.ctypes.data, total)
        multiply_cached = lib.floor_multiply(factors, k.ctypes.data, *times)
    figures.update(
        read=read * 1e6,
        read_cached=cached * 1e6,
        multiply=multiply * 1e6,
        multiply_cached=multiply_cached * 1e6,
    )
    return figures


def main() -> None:
    """Train, measure, print."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--inducing", type=int, default=400, help="inducing points per stage")
    parser.add_argument("--repeats", type=int, default=5, help="runs of the exact step")
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    rec = recording()
    project = load_config(ROOT / "bench_configs" / "hydraulic_actuator.toml")
    config = with_inducing(project, args.inducing)
    config = dataclasses.replace(config, gp=dataclasses.replace(config.gp, max_iter=5))
    with tempfile.TemporaryDirectory() as tmp:
        folder = save_model(train_model(config, rec), Path(tmp) / "model")
        exact = chain_step(folder, rec, 3000, args.repeats)
        model = load_model(folder)
        with open_fmu(model.whitebox_fmu) as archive:
            data = prepare(model.config, model.chain, archive, rec)
    chain = model.chain
    plan, params = chain.plan().arrays
    factor_bytes = 8 * sum(
        factor_length(int(stage_record(plan, q)[1])) for q in range(int(plan[1]))
    )
    reference = free_run_std(plan, params, chain, data)
    rounded = free_run_std(plan, float32_factors(plan, params), chain, data)
    in_c = c_figures(plan, params, chain, data, args.repeats)
    error = float(np.max(np.abs(rounded / reference - 1.0)))
    print(f"chain step of three stages at M = {args.inducing} per stage (CPU time per step)")
    print(conditions_line(conditions(load_before), args.repeats))
    low, high = exact["cpu_us_range"]
    print(
        f"exact: {exact['cpu_us']:.1f} us ({low:.1f}-{high:.1f}; {exact['wall_us']:.1f} wall), "
        f"streaming {factor_bytes / 1e6:.2f} MB of factors per step"
    )
    print(f"streaming floor: {streaming_floor(plan, params):.1f} us to read those factors once")
    print(
        f"in C: the step {in_c['step']:.1f} us; reading the factors once {in_c['read']:.1f} us "
        f"(one stage's thrice, cached: {in_c['read_cached']:.1f}); multiply-adds over them with "
        f"no serial dependency (explicit inverses, std within {in_c['inverse_std_error']:.0e} "
        f"of the solve's) {in_c['multiply']:.1f} us (one stage's thrice, cached: "
        f"{in_c['multiply_cached']:.1f})"
    )
    print(
        f"float32 factors: {factor_bytes / 2e6:.2f} MB; largest relative std error {error:.1e} "
        f"({'within' if error <= STD_RTOL else 'beyond'} {STD_RTOL:g})"
    )
    for figure in low_rank(chain, data):
        sv = ", ".join(f"s{r}/s0 {v:.0e}" for r, v in figure["sv"].items())
        print(
            f"low rank, stage {figure['stage']}: rank {figure['rank']} of {figure['M']} keeps "
            f"every std within {STD_RTOL:g} in-sample ({sv}); kernel rows dense: "
            f"{figure['dense_median']:.0f} (least {figure['dense_min']}) of {figure['M']} "
            f"entries above 1e-16 of the row's largest; the latent variance down to 1/"
            f"{figure['cancellation']:.0f} of the prior's (cancellation)"
        )


if __name__ == "__main__":
    main()
