/*
 * chain_floor.c -- the chain step and two floors under it, timed in C (no Python between the
 * calls), for benchmarks/bench_chain_step.py. Compiled there with the chain core's options and
 * linked with fmu_greybox/native/chain_core.c.
 *
 * The factors are packed as the chain core packs them (chain_core.c: column j holds rows
 * 8 floor(j/8) .. LD-1, LD = M rounded up to a multiple of 8, columns one after the other,
 * each on a cache line). Every timing is the least over `repeats` passes (a pass the process
 * was not preempted in), in seconds of the thread's CPU clock, except step_seconds (a run's
 * mean).
 */
#define _POSIX_C_SOURCE 200809L
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <time.h>

#include "chain_core.h"

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
#define VECTOR_VERSIONS __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define VECTOR_VERSIONS
#endif

#define LANES 32

static double cpu_seconds(void) {
    struct timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* The sum of n numbers with LANES running sums: a loop bound by reading, not by adding. */
VECTOR_VERSIONS
static double read_once(const double *restrict a, ptrdiff_t n) {
    double sums[LANES] = {0.0}, total = 0.0;
    ptrdiff_t i = 0;
    for (; i + LANES <= n; i += LANES) {
        for (int l = 0; l < LANES; l++) sums[l] += a[i + l];
    }
    for (; i < n; i++) total += a[i];
    for (int l = 0; l < LANES; l++) total += sums[l];
    return total;
}

/* g (ld) = G k for a packed lower-triangular G (m x m) and k (m): eight columns per pass over
 * g, each a multiply-add per entry, and no entry waits for another (unlike a solve). */
VECTOR_VERSIONS
static void multiply_once(ptrdiff_t m, ptrdiff_t ld, const double *restrict h,
                          const double *restrict k, double *restrict g) {
    for (ptrdiff_t i = 0; i < ld; i++) g[i] = 0.0;
    for (ptrdiff_t j = 0; j < m; j += 8) {
        const ptrdiff_t size = ld - j;
        const double *c[8];
        double kj[8];
        for (int l = 0; l < 8; l++) {
            c[l] = h + l * size - j;
            kj[l] = j + l < m ? k[j + l] : 0.0;
        }
        for (ptrdiff_t i = j; i < ld; i++) {
            g[i] += ((kj[0] * c[0][i] + kj[1] * c[1][i]) + (kj[2] * c[2][i] + kj[3] * c[3][i])) +
                    ((kj[4] * c[4][i] + kj[5] * c[5][i]) + (kj[6] * c[6][i] + kj[7] * c[7][i]));
        }
        h += 8 * size;
    }
}

/* Least time [s] of one pass reading `count` blocks (the stages' factors) in turn; each block
 * is read `times` times in a row within the pass (times = 3, count = 1: one stage's factor,
 * which may stay in the core's cache). */
double floor_read(const double *const *blocks, const ptrdiff_t *lengths, int count, int times,
                  int repeats, double *checksum) {
    double best = 1e30;
    for (int r = 0; r < repeats; r++) {
        const double start = cpu_seconds();
        for (int b = 0; b < count; b++) {
            for (int t = 0; t < times; t++) *checksum += read_once(blocks[b], lengths[b]);
        }
        const double spent = cpu_seconds() - start;
        if (spent < best) best = spent;
    }
    return best;
}

/* Least time [s] of one pass multiplying `count` packed factors (m x m) by kernel rows k
 * (count x m, row-major), each `times` times in a row; g: scratch of LD doubles. */
double floor_multiply(const double *const *factors, const double *k, ptrdiff_t m, int count,
                      int times, int repeats, double *g, double *checksum) {
    const ptrdiff_t ld = (m + 7) / 8 * 8;
    double best = 1e30;
    for (int r = 0; r < repeats; r++) {
        const double start = cpu_seconds();
        for (int b = 0; b < count; b++) {
            for (int t = 0; t < times; t++) {
                multiply_once(m, ld, factors[b], k + b * m, g);
                *checksum += g[m - 1];
            }
        }
        const double spent = cpu_seconds() - start;
        if (spent < best) best = spent;
    }
    return best;
}

/* CPU time [s] per chain_step over rows - 1 steps (exo, y_wb: rows x n_exo and rows x Q,
 * row-major), the state started from the first row. Returns -1 when out of memory. */
double step_seconds(const int64_t *plan, const double *params, const double *exo,
                    const double *y_wb, ptrdiff_t rows, double *checksum) {
    ChainSizes sizes;
    char message[256];
    double *state, *work, start, spent;
    if (chain_plan_sizes(plan, CHAIN_PLAN_HEADER + plan[1] * CHAIN_STAGE_RECORD, &sizes,
                         message, sizeof message) != 0) {
        return -1.0;
    }
    state = calloc((size_t)sizes.state, sizeof(double));
    work = calloc((size_t)sizes.work, sizeof(double));
    if (state == NULL || work == NULL) {
        free(state), free(work);
        return -1.0;
    }
    chain_start(plan, state, y_wb, exo);
    start = cpu_seconds();
    for (ptrdiff_t j = 1; j < rows; j++) {
        *checksum += chain_step(plan, params, work, state, exo + (j - 1) * sizes.n_exo,
                                y_wb + j * sizes.n_stages, 1);
    }
    spent = cpu_seconds() - start;
    *checksum += state[sizes.n_stages];
    free(state), free(work);
    return spent / (double)(rows - 1);
}
