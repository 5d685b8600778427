/*
 * chain_core.c -- the grey-box's numerical core (see chain_core.h): one sparse-GP prediction
 * and one communication step of the corrector chain.
 *
 * The equations and why they are evaluated this way: docs/sgpr.md ("Prediction") and
 * docs/greybox.md ("The chain step").
 *
 * Packed posterior, float64, M inducing points, D inputs (standardised units inside):
 *   factor[F]             H = L U^-T, lower triangular, by columns: column j holds rows
 *                         8 floor(j/8) .. LD-1 (LD = M rounded up to a multiple of 8,
 *                         rows from M on zero), the columns one after the other. Every
 *                         column starts on a cache line (Python keeps the array on a 64-byte
 *                         boundary) and H streams as one contiguous block of about M^2/2
 *                         numbers; F = sum_j (LD - 8 floor(j/8)).
 *   weight[D] offset[D]   x_s = x * weight - offset   (standardisation and 1/lengthscale)
 *   zt[D*M]               inducing points / lengthscale, by dimension (row i: the M
 *                         inducing points' coordinate i)
 *   zoff[M]               log s^2 - |zs_m|^2 / 2
 *   alpha[M]              L^-T gamma (mean gradient)
 *   beta[M]               U^-1 gamma (mean)
 *   y_scale y_mean s2 noise
 * so that k_m = exp(zoff_m + z_m . x_s - |x_s|^2 / 2), g = H^-1 k, mean = beta . g,
 * latent variance = s2 - g . g, d mean / d x_s = sum_m alpha_m k_m (z_m - x_s).
 *
 * Plan, int64 (fmu_greybox/model/chain_step.py, ChainPlan):
 *   version, Q, n_exo, params length, work length, state length, history depth H
 *   per stage: params offset, M, D, sources S, memory length n, target mode, active,
 *              memory offset in the state, calibration offset in params (CHAIN_CALIBRATION
 *              doubles: a, b, the white-box residual variance c, the fade scores full, none)
 */
#include "chain_core.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

enum { MODE_RESIDUAL = 0, MODE_INCREMENT = 1, MODE_OUTPUT = 2 };

/* Versions of a loop-heavy function for wide vector units, chosen when the module loads (GCC on
 * x86-64 ELF: the choice needs ifunc, which Windows DLLs lack; elsewhere the one portable
 * version). */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(_WIN32)
#define VECTOR_VERSIONS __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define VECTOR_VERSIONS
#endif


/* ------------------------------------------------------------------ one posterior */

typedef struct {
    ptrdiff_t m, d, ld;
    const double *factor, *weight, *offset, *zt, *zoff, *alpha, *beta;
    double y_scale, y_mean, s2, noise;
} PosteriorView;

static ptrdiff_t leading_dimension(ptrdiff_t m) { return (m + 7) / 8 * 8; }

/* Doubles before column j of the packed factor. */
static ptrdiff_t column_start(ptrdiff_t j, ptrdiff_t ld) {
    const ptrdiff_t blocks = j / 8; /* whole blocks of 8 columns before j */
    return 8 * (blocks * ld - 4 * blocks * (blocks - 1)) + (j - 8 * blocks) * (ld - 8 * blocks);
}

ptrdiff_t chain_posterior_size(ptrdiff_t m, ptrdiff_t d) {
    return column_start(m, leading_dimension(m)) + 2 * d + m * d + 3 * m + CHAIN_POSTERIOR_SCALARS;
}

static PosteriorView posterior_view(const double *p, ptrdiff_t m, ptrdiff_t d) {
    PosteriorView v;
    v.m = m;
    v.d = d;
    v.ld = leading_dimension(m);
    v.factor = p;
    v.weight = v.factor + column_start(m, v.ld);
    v.offset = v.weight + d;
    v.zt = v.offset + d;
    v.zoff = v.zt + m * d;
    v.alpha = v.zoff + m;
    v.beta = v.alpha + m;
    {
        const double *scalars = v.beta + m;
        v.y_scale = scalars[0];
        v.y_mean = scalars[1];
        v.s2 = scalars[2];
        v.noise = scalars[3];
    }
    return v;
}

/* g <- H^-1 g for the packed lower triangular factor H (m x m): forward substitution four
 * columns at a time, so that each pass over the rest of g applies four columns (one load and
 * store of g per four multiply-adds); the inner loop is vectorised, in versions for wide
 * vector units chosen at load time where the compiler can make them. H streams once, in
 * order: at M = 400 and three stages the solves are bound by the caches' bandwidth, and one
 * contiguous stream with aligned columns was a quarter faster than columns of a square
 * array. */
VECTOR_VERSIONS
static void forward_substitution(ptrdiff_t m, ptrdiff_t ld, const double *restrict h,
                                 double *restrict g) {
    ptrdiff_t j = 0;
    for (; j + 4 <= m; j += 4) {
        /* columns j..j+3 lie in one block of 8 and share their first row and length */
        const ptrdiff_t first = j / 8 * 8, size = ld - first;
        const double *c0 = h - first, *c1 = c0 + size, *c2 = c1 + size, *c3 = c2 + size;
        const double g0 = g[j] / c0[j];
        const double g1 = (g[j + 1] - g0 * c0[j + 1]) / c1[j + 1];
        const double g2 = (g[j + 2] - g0 * c0[j + 2] - g1 * c1[j + 2]) / c2[j + 2];
        const double g3 =
            (g[j + 3] - g0 * c0[j + 3] - g1 * c1[j + 3] - g2 * c2[j + 3]) / c3[j + 3];
        g[j] = g0;
        g[j + 1] = g1;
        g[j + 2] = g2;
        g[j + 3] = g3;
        for (ptrdiff_t i = j + 4; i < m; i++) {
            g[i] -= g0 * c0[i] + g1 * c1[i] + g2 * c2[i] + g3 * c3[i];
        }
        h += 4 * size;
    }
    for (; j < m; j++) {
        const ptrdiff_t first = j / 8 * 8;
        const double *column = h - first;
        const double gj = g[j] / column[j];
        g[j] = gj;
        for (ptrdiff_t i = j + 1; i < m; i++) g[i] -= gj * column[i];
        h += ld - first;
    }
}

/* a . b with eight running sums, so that the loop vectorises without reordering one sum. */
VECTOR_VERSIONS
static double dot(ptrdiff_t n, const double *restrict a, const double *restrict b) {
    double sums[8] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0}, total = 0.0;
    ptrdiff_t j = 0;
    for (; j + 8 <= n; j += 8) {
        for (int l = 0; l < 8; l++) sums[l] += a[j + l] * b[j + l];
    }
    for (; j < n; j++) total += a[j] * b[j];
    for (int l = 0; l < 8; l++) total += sums[l];
    return total;
}

/* e^x of every x[j] in place, in a loop the compiler vectorises (libm's exp is one call per
 * number: 1200 of them took 9 us of a 40 us step at M = 400). x = n ln 2 + r with |r| <=
 * ln(2)/2 (Cody and Waite's two-part ln 2), e^r by its Taylor polynomial to degree 13
 * (truncation below 4e-18 relative), times 2^n assembled in the exponent bits. Within about
 * one unit in the last place of libm's exp; arguments below EXP_LOWEST (kernel entries below
 * 1e-307, far beyond any that counts) give 0. */
#define EXP_LOWEST -708.0
#define EXP_HIGHEST 709.0
VECTOR_VERSIONS
static void exp_in_place(ptrdiff_t m, double *restrict x) {
    static const double shifter = 6755399441055744.0; /* 1.5 * 2^52: adding it rounds */
    static const double log2e = 1.4426950408889634, ln2_hi = 0.6931471803691238,
                        ln2_lo = 1.9082149292705877e-10;
    for (ptrdiff_t j = 0; j < m; j++) {
        const double v = x[j] < EXP_LOWEST ? EXP_LOWEST : x[j] > EXP_HIGHEST ? EXP_HIGHEST : x[j];
        const double t = v * log2e + shifter, n = t - shifter;
        const double r = (v - n * ln2_hi) - n * ln2_lo;
        double p = 1.0 / 6227020800.0, scale;
        uint64_t bits;
        p = p * r + 1.0 / 479001600.0;
        p = p * r + 1.0 / 39916800.0;
        p = p * r + 1.0 / 3628800.0;
        p = p * r + 1.0 / 362880.0;
        p = p * r + 1.0 / 40320.0;
        p = p * r + 1.0 / 5040.0;
        p = p * r + 1.0 / 720.0;
        p = p * r + 1.0 / 120.0;
        p = p * r + 1.0 / 24.0;
        p = p * r + 1.0 / 6.0;
        p = p * r + 0.5;
        p = p * r + 1.0;
        p = p * r + 1.0;
        memcpy(&bits, &t, sizeof bits);
        bits = (bits + 1023) << 52; /* the low bits of t hold n */
        memcpy(&scale, &bits, sizeof scale);
        x[j] = x[j] < EXP_LOWEST ? 0.0 : p * scale;
    }
}

/* Kernel row into k (M) for a scaled point xs (D), one dimension at a time over all inducing
 * points (vectorised); the gradient moments sum_m alpha_m k_m z_m (D) into moments[0..D-1]
 * and alpha . k into moments[D] when moments is not NULL (w: M doubles of scratch). Returns
 * the largest kernel entry. */
VECTOR_VERSIONS
static double kernel_row(const PosteriorView *p, const double *xs, double *restrict k,
                         double *moments, double *restrict w) {
    const ptrdiff_t m = p->m, d = p->d;
    double half_xx = 0.0, largest = 0.0;
    for (ptrdiff_t i = 0; i < d; i++) half_xx += xs[i] * xs[i];
    half_xx *= 0.5;
    for (ptrdiff_t j = 0; j < m; j++) k[j] = p->zoff[j] - half_xx;
    for (ptrdiff_t i = 0; i < d; i++) {
        const double *restrict z = p->zt + i * m;
        const double xi = xs[i];
        for (ptrdiff_t j = 0; j < m; j++) k[j] += z[j] * xi;
    }
    exp_in_place(m, k);
    for (ptrdiff_t j = 0; j < m; j++) {
        if (k[j] > largest) largest = k[j];
    }
    if (moments != NULL) {
        for (ptrdiff_t j = 0; j < m; j++) w[j] = p->alpha[j] * k[j];
        for (ptrdiff_t i = 0; i < d; i++) moments[i] = dot(m, w, p->zt + i * m);
        moments[d] = 0.0;
        for (ptrdiff_t j = 0; j < m; j++) moments[d] += w[j];
    }
    return largest;
}

/* Mean and latent variance in original units at raw point x (D); gradient of the mean with
 * respect to x into grad (D) unless NULL. work holds 2M + 2D + 1 doubles. Returns the
 * largest kernel entry (standardised units). */
static double predict_point(const PosteriorView *p, const double *x, double *mean, double *var,
                            double *grad, double *work) {
    const ptrdiff_t m = p->m, d = p->d;
    double *k = work, *xs = work + m, *moments = xs + d, *w = moments + d + 1;
    double mean_s = 0.0, gg = 0.0, largest;
    for (ptrdiff_t i = 0; i < d; i++) xs[i] = x[i] * p->weight[i] - p->offset[i];
    largest = kernel_row(p, xs, k, grad != NULL ? moments : NULL, w);
    forward_substitution(m, p->ld, p->factor, k); /* k <- g */
    for (ptrdiff_t j = 0; j < m; j++) {
        mean_s += p->beta[j] * k[j];
        gg += k[j] * k[j];
    }
    *mean = mean_s * p->y_scale + p->y_mean;
    *var = fmax(p->s2 - gg, 0.0) * (p->y_scale * p->y_scale);
    if (grad != NULL) {
        for (ptrdiff_t i = 0; i < d; i++) {
            grad[i] = (moments[i] - moments[d] * xs[i]) * p->weight[i] * p->y_scale;
        }
    }
    return largest;
}

/* ------------------------------------------------------------------ the chain */

/* State (float64), Q stages, n_exo inputs, history depth H (fmu_greybox/model/stage.py,
 * SourceLayout; fmu_greybox/model/chain_step.py, ChainState):
 *   for h = 0..H: wb[Q] out[Q]          white-box and stage outputs of row j - h
 *   for h = 0..H: exo[n_exo]            exogenous inputs of row j - 1 - h
 *                                       (together: the shared sources, S0 of them)
 *   out_var[Q] outside[Q]
 *   per stage, at memory_offset: levels[n] (most recent first), their covariance[n * n]
 * A stage's sources are the shared ones followed by its own stored levels; its features are
 * A s, A (D x (S0 + n)) row-major in its params block (at an offset that is a multiple of 8):
 * packed posterior, then A, low[D], high[D]. Every stage's variance calibration lies at its
 * calibration offset in params (fmu_greybox/model/calibration.py). */
typedef struct {
    ptrdiff_t params_offset, m, d, s, memory, mode, active, memory_offset, calibration;
} StageRecord;

static StageRecord stage_record(const int64_t *plan, ptrdiff_t q) {
    const int64_t *r = plan + CHAIN_PLAN_HEADER + q * CHAIN_STAGE_RECORD;
    StageRecord s = {r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8]};
    return s;
}

typedef struct {
    ptrdiff_t n_stages, n_exo, depth, shared;
} Layout;

/* The history moves one row back; this row's white-box outputs and the previous row's inputs
 * enter it. The stage outputs of row j start as those of row j - 1 until each stage writes
 * its own. */
static void shift_history(const Layout *l, double *state, const double *y_wb,
                          const double *exo_prev) {
    const ptrdiff_t row = 2 * l->n_stages;
    double *exo = state + row * (l->depth + 1);
    memmove(state + row, state, (size_t)(row * l->depth) * sizeof(double));
    memcpy(state, y_wb, (size_t)l->n_stages * sizeof(double));
    memmove(exo + l->n_exo, exo, (size_t)(l->n_exo * l->depth) * sizeof(double));
    memcpy(exo, exo_prev, (size_t)l->n_exo * sizeof(double));
}

/* Push a new level into a memory of n levels with covariance P (n x n, row-major): the levels
 * move one back, the new one (variance var, covariance cov[k] with the old level k) enters in
 * front, the oldest leaves. */
static void push_level(double *memory, double *p, ptrdiff_t n, double level, double var,
                       const double *cov) {
    if (n < 1) return;
    memmove(memory + 1, memory, (size_t)(n - 1) * sizeof(double));
    memory[0] = level;
    for (ptrdiff_t i = n - 1; i > 0; i--) {
        for (ptrdiff_t j = n - 1; j > 0; j--) p[i * n + j] = p[(i - 1) * n + (j - 1)];
    }
    p[0] = var;
    for (ptrdiff_t k = 1; k < n; k++) p[k] = p[k * n] = cov[k - 1];
}

/* The variance a stage reports: a * var + b, var the propagated variance (which the memory
 * keeps), a and b the stage's calibration (b alone for a stage passed through, var = 0). */
static double calibrated_variance(const double *calibration, double var) {
    return calibration[0] * var + calibration[1];
}

/* The largest kernel correlation between the raw point x (D) and an inducing point (work: M + D
 * doubles). */
static double largest_correlation(const PosteriorView *p, const double *x, double *work) {
    double *k = work, *xs = work + p->m;
    for (ptrdiff_t i = 0; i < p->d; i++) xs[i] = x[i] * p->weight[i] - p->offset[i];
    return kernel_row(p, xs, k, NULL, NULL) / p->s2;
}

/* How much of a corrector acts at domain score `score`: 1 at and above `full`, 0 at and below
 * `none`, smooth in between (a cubic with zero slope at both ends). */
static double fade_weight(double score, double full, double none) {
    if (!(score < full)) return 1.0;
    if (!(score > none)) return 0.0;
    const double t = (score - none) / (full - none);
    return t * t * (3.0 - 2.0 * t);
}

/* One stage of one step. Returns the stage's domain score (largest kernel correlation), or
 * 2.0 when the stage passes its white-box through. Below the stage's full-action score its
 * corrector's contribution (the residual level, or the distance of the output from the
 * white-box) fades with fade_weight, its propagated variance with the square of it, and the
 * reported variance moves from a V + b towards the white-box's residual variance c. */
static double stage_step(const StageRecord *r, const Layout *l, const double *params,
                         double *state, ptrdiff_t q, int enabled, double *work) {
    const ptrdiff_t n_stages = l->n_stages, shared = l->shared;
    double *out = state + n_stages, *out_var = state + shared, *outside = out_var + n_stages;
    double *memory = state + r->memory_offset, *memory_cov = memory + r->memory;
    double *cov = work; /* the new level's covariance with the stored ones (memory long) */
    const double y = state[q]; /* this row's white-box output */
    const double *calibration = params + r->calibration;
    double level, var = 0.0, score = 2.0, weight = 1.0;

    work += r->memory;

    if (enabled && r->active) {
        const ptrdiff_t d = r->d, s = r->s, n = r->memory;
        const PosteriorView p = posterior_view(params + r->params_offset, r->m, d);
        const double *a = params + r->params_offset + chain_posterior_size(r->m, d);
        const double *low = a + d * s, *high = low + d;
        double *x = work, *grad = x + d, *clipped = grad + d, *c = clipped + d;
        double *rest = c + n;
        double mu, var_gp, any_clipped = 0.0;
        for (ptrdiff_t i = 0; i < d; i++) {
            const double *row = a + i * s;
            double v = 0.0;
            for (ptrdiff_t j = 0; j < shared; j++) v += row[j] * state[j];
            for (ptrdiff_t j = 0; j < n; j++) v += row[shared + j] * memory[j];
            /* NaN compares false and passes unclipped, as it came; clipped keeps how far the
             * feature lay beyond its range (0 when inside) */
            clipped[i] = 0.0;
            if (v < low[i]) clipped[i] = v - low[i], v = low[i];
            else if (v > high[i]) clipped[i] = v - high[i], v = high[i];
            any_clipped += clipped[i] != 0.0;
            x[i] = v;
        }
        outside[q] = any_clipped > 0.0 ? 1.0 : 0.0;
        score = predict_point(&p, x, &mu, &var_gp, grad, rest) / p.s2;
        if (any_clipped > 0.0) { /* the score of where the features are, not of the clipped */
            for (ptrdiff_t i = 0; i < d; i++) rest[i] = x[i] + clipped[i];
            score = largest_correlation(&p, rest, rest + d);
        }
        /* a clipped feature no longer moves the output */
        for (ptrdiff_t i = 0; i < d; i++) {
            if (clipped[i] != 0.0) grad[i] = 0.0;
        }
        /* first-order propagation: the corrector's latent variance, the stage outputs of this
         * row (independent of each other and of the memory), and the stored levels through
         * their covariance P: var = var_gp + sum c_out^2 out_var + c' P c */
        var = var_gp;
        for (ptrdiff_t j = 0; j < n_stages; j++) {
            double sensitivity = 0.0;
            for (ptrdiff_t i = 0; i < d; i++) sensitivity += grad[i] * a[i * s + n_stages + j];
            var += sensitivity * sensitivity * out_var[j];
        }
        for (ptrdiff_t j = 0; j < n; j++) {
            c[j] = r->mode == MODE_INCREMENT && j == 0 ? 1.0 : 0.0;
            for (ptrdiff_t i = 0; i < d; i++) c[j] += grad[i] * a[i * s + shared + j];
        }
        for (ptrdiff_t k = 0; k < n; k++) {
            double pc = 0.0; /* (P c)_k: the new level's covariance with stored level k */
            for (ptrdiff_t l = 0; l < n; l++) pc += memory_cov[k * n + l] * c[l];
            cov[k] = pc;
            var += c[k] * pc;
        }
        level = r->mode == MODE_INCREMENT ? memory[0] + mu : mu;
        weight = fade_weight(score, calibration[3], calibration[4]);
        if (weight < 1.0) {
            level = r->mode == MODE_OUTPUT ? y + weight * (level - y) : weight * level;
            var *= weight * weight;
            for (ptrdiff_t k = 0; k < n; k++) cov[k] *= weight;
        }
        out[q] = r->mode == MODE_OUTPUT ? level : y + level;
    } else {
        outside[q] = 0.0;
        level = r->mode == MODE_OUTPUT ? y : 0.0;
        out[q] = y;
        for (ptrdiff_t k = 0; k < r->memory; k++) cov[k] = 0.0;
    }
    push_level(memory, memory_cov, r->memory, level, var, cov);
    out_var[q] = weight < 1.0 ? calibration[0] * var + weight * calibration[1] +
                                    (1.0 - weight) * calibration[2]
                              : calibrated_variance(calibration, var);
    return score;
}

/* ------------------------------------------------------------------ entry points */

int chain_plan_sizes(const int64_t *plan, ptrdiff_t length, ChainSizes *sizes, char *message,
                     size_t size) {
    if (length < CHAIN_PLAN_HEADER || plan[0] != CHAIN_PLAN_VERSION) {
        snprintf(message, size,
                 "plan of another version (%lld; this code reads version %d, whose stages "
                 "carry their variance calibration and domain fade): export the FMU again with "
                 "this fmu-greybox",
                 length < 1 ? -1LL : (long long)plan[0], CHAIN_PLAN_VERSION);
        return -1;
    }
    if (plan[1] < 1 || plan[2] < 0 || plan[6] < 1 ||
        length < CHAIN_PLAN_HEADER + plan[1] * CHAIN_STAGE_RECORD) {
        snprintf(message, size, "plan of %lld entries does not hold %lld stage records",
                 (long long)length, (long long)plan[1]);
        return -1;
    }
    sizes->n_stages = plan[1];
    sizes->n_exo = plan[2];
    sizes->params = plan[3];
    sizes->work = plan[4];
    sizes->state = plan[5];
    sizes->depth = plan[6];
    return 0;
}

ptrdiff_t chain_predict_work(ptrdiff_t m, ptrdiff_t d) { return 2 * m + 2 * d + 1; }

void chain_predict(const double *posterior, ptrdiff_t m, ptrdiff_t d, const double *x,
                   double *mean, double *var, double *grad, int full_noise, double *work) {
    const PosteriorView p = posterior_view(posterior, m, d);
    predict_point(&p, x, mean, var, grad, work);
    if (full_noise) *var += p.noise * (p.y_scale * p.y_scale);
}

static Layout plan_layout(const int64_t *plan) {
    Layout layout;
    layout.n_stages = plan[1];
    layout.n_exo = plan[2];
    layout.depth = plan[6];
    layout.shared = (layout.depth + 1) * (2 * layout.n_stages + layout.n_exo);
    return layout;
}

double chain_step(const int64_t *plan, const double *params, double *work, double *state,
                  const double *exo_prev, const double *y_wb, int enabled) {
    const Layout layout = plan_layout(plan);
    double score = 1.0;
    shift_history(&layout, state, y_wb, exo_prev);
    for (ptrdiff_t q = 0; q < layout.n_stages; q++) {
        const StageRecord r = stage_record(plan, q);
        const double stage_score = stage_step(&r, &layout, params, state, q, enabled, work);
        if (stage_score < score) score = stage_score;
    }
    return score;
}

void chain_start(const int64_t *plan, double *state, const double *y_wb, const double *exo) {
    const Layout l = plan_layout(plan);
    const ptrdiff_t row = 2 * l.n_stages;
    double *inputs = state + row * (l.depth + 1);
    memset(state, 0, (size_t)plan[5] * sizeof(double));
    for (ptrdiff_t h = 0; h <= l.depth; h++) {
        memcpy(state + h * row, y_wb, (size_t)l.n_stages * sizeof(double));
        memcpy(state + h * row + l.n_stages, y_wb, (size_t)l.n_stages * sizeof(double));
        memcpy(inputs + h * l.n_exo, exo, (size_t)l.n_exo * sizeof(double));
    }
    for (ptrdiff_t q = 0; q < l.n_stages; q++) {
        const StageRecord r = stage_record(plan, q);
        /* the level of a zero residual, or the output itself (StageLayout.level) */
        const double level = r.mode == MODE_OUTPUT ? y_wb[q] : y_wb[q] - y_wb[q];
        for (ptrdiff_t k = 0; k < r.memory; k++) state[r.memory_offset + k] = level;
    }
}
