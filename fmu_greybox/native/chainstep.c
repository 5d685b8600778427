/*
 * chainstep.c -- the co-simulation hot path of the grey-box, compiled.
 *
 * Two functions, for the Python module fmu_greybox._chainstep:
 *
 *   predict(posterior, m, d, x, grad, full_noise) -> (mean, var)
 *       One point through one sparse-GP posterior (SparseGPR.predict_one).
 *   step(plan, params, work, state, exo_prev, y_wb, enabled) -> domain_score
 *       One communication step of the whole corrector chain (GreyBoxChain.step).
 *
 * The arrays are laid out by Python (fmu_greybox/gp/predictive.py: Posterior.packed;
 * fmu_greybox/chain_plan.py: ChainPlan) and passed as buffers; this file holds no state.
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
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

#define PLAN_VERSION 2
#define PLAN_HEADER 7
#define STAGE_RECORD 9
#define POSTERIOR_SCALARS 4

enum { MODE_RESIDUAL = 0, MODE_INCREMENT = 1, MODE_OUTPUT = 2 };

/* Versions of a loop-heavy function for wide vector units, chosen when the module loads (GCC on
 * x86-64; elsewhere the one portable version). */
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
#define VECTOR_VERSIONS __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define VECTOR_VERSIONS
#endif


/* ------------------------------------------------------------------ one posterior */

typedef struct {
    Py_ssize_t m, d, ld;
    const double *factor, *weight, *offset, *zt, *zoff, *alpha, *beta;
    double y_scale, y_mean, s2, noise;
} PosteriorView;

static Py_ssize_t leading_dimension(Py_ssize_t m) { return (m + 7) / 8 * 8; }

/* Doubles before column j of the packed factor. */
static Py_ssize_t column_start(Py_ssize_t j, Py_ssize_t ld) {
    const Py_ssize_t blocks = j / 8; /* whole blocks of 8 columns before j */
    return 8 * (blocks * ld - 4 * blocks * (blocks - 1)) + (j - 8 * blocks) * (ld - 8 * blocks);
}

static Py_ssize_t posterior_size(Py_ssize_t m, Py_ssize_t d) {
    return column_start(m, leading_dimension(m)) + 2 * d + m * d + 3 * m + POSTERIOR_SCALARS;
}

static PosteriorView posterior_view(const double *p, Py_ssize_t m, Py_ssize_t d) {
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
static void forward_substitution(Py_ssize_t m, Py_ssize_t ld, const double *restrict h,
                                 double *restrict g) {
    Py_ssize_t j = 0;
    for (; j + 4 <= m; j += 4) {
        /* columns j..j+3 lie in one block of 8 and share their first row and length */
        const Py_ssize_t first = j / 8 * 8, size = ld - first;
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
        for (Py_ssize_t i = j + 4; i < m; i++) {
            g[i] -= g0 * c0[i] + g1 * c1[i] + g2 * c2[i] + g3 * c3[i];
        }
        h += 4 * size;
    }
    for (; j < m; j++) {
        const Py_ssize_t first = j / 8 * 8;
        const double *column = h - first;
        const double gj = g[j] / column[j];
        g[j] = gj;
        for (Py_ssize_t i = j + 1; i < m; i++) g[i] -= gj * column[i];
        h += ld - first;
    }
}

/* a . b with eight running sums, so that the loop vectorises without reordering one sum. */
VECTOR_VERSIONS
static double dot(Py_ssize_t n, const double *restrict a, const double *restrict b) {
    double sums[8] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0}, total = 0.0;
    Py_ssize_t j = 0;
    for (; j + 8 <= n; j += 8) {
        for (int l = 0; l < 8; l++) sums[l] += a[j + l] * b[j + l];
    }
    for (; j < n; j++) total += a[j] * b[j];
    for (int l = 0; l < 8; l++) total += sums[l];
    return total;
}

/* Kernel row into k (M) for a scaled point xs (D), one dimension at a time over all inducing
 * points (vectorised); the gradient moments sum_m alpha_m k_m z_m (D) into moments[0..D-1]
 * and alpha . k into moments[D] when moments is not NULL (w: M doubles of scratch). Returns
 * the largest kernel entry. */
VECTOR_VERSIONS
static double kernel_row(const PosteriorView *p, const double *xs, double *restrict k,
                         double *moments, double *restrict w) {
    const Py_ssize_t m = p->m, d = p->d;
    double half_xx = 0.0, largest = 0.0;
    for (Py_ssize_t i = 0; i < d; i++) half_xx += xs[i] * xs[i];
    half_xx *= 0.5;
    for (Py_ssize_t j = 0; j < m; j++) k[j] = p->zoff[j] - half_xx;
    for (Py_ssize_t i = 0; i < d; i++) {
        const double *restrict z = p->zt + i * m;
        const double xi = xs[i];
        for (Py_ssize_t j = 0; j < m; j++) k[j] += z[j] * xi;
    }
    for (Py_ssize_t j = 0; j < m; j++) {
        k[j] = exp(k[j]);
        if (k[j] > largest) largest = k[j];
    }
    if (moments != NULL) {
        for (Py_ssize_t j = 0; j < m; j++) w[j] = p->alpha[j] * k[j];
        for (Py_ssize_t i = 0; i < d; i++) moments[i] = dot(m, w, p->zt + i * m);
        moments[d] = 0.0;
        for (Py_ssize_t j = 0; j < m; j++) moments[d] += w[j];
    }
    return largest;
}

/* Mean and latent variance in original units at raw point x (D); gradient of the mean with
 * respect to x into grad (D) unless NULL. work holds 2M + 2D + 1 doubles. Returns the
 * largest kernel entry (standardised units). */
static double predict_point(const PosteriorView *p, const double *x, double *mean, double *var,
                            double *grad, double *work) {
    const Py_ssize_t m = p->m, d = p->d;
    double *k = work, *xs = work + m, *moments = xs + d, *w = moments + d + 1;
    double mean_s = 0.0, gg = 0.0, largest;
    for (Py_ssize_t i = 0; i < d; i++) xs[i] = x[i] * p->weight[i] - p->offset[i];
    largest = kernel_row(p, xs, k, grad != NULL ? moments : NULL, w);
    forward_substitution(m, p->ld, p->factor, k); /* k <- g */
    for (Py_ssize_t j = 0; j < m; j++) {
        mean_s += p->beta[j] * k[j];
        gg += k[j] * k[j];
    }
    *mean = mean_s * p->y_scale + p->y_mean;
    *var = fmax(p->s2 - gg, 0.0) * (p->y_scale * p->y_scale);
    if (grad != NULL) {
        for (Py_ssize_t i = 0; i < d; i++) {
            grad[i] = (moments[i] - moments[d] * xs[i]) * p->weight[i] * p->y_scale;
        }
    }
    return largest;
}

/* ------------------------------------------------------------------ the chain */

/* State (float64), Q stages, n_exo inputs, history depth H (fmu_greybox/stage.py,
 * SourceLayout; fmu_greybox/chain_step.py, ChainState):
 *   for h = 0..H: wb[Q] out[Q]          white-box and stage outputs of row j - h
 *   for h = 0..H: exo[n_exo]            exogenous inputs of row j - 1 - h
 *                                       (together: the shared sources, S0 of them)
 *   out_var[Q] outside[Q]
 *   per stage, at memory_offset: levels[n] (most recent first), their covariance[n * n]
 * A stage's sources are the shared ones followed by its own stored levels; its features are
 * A s, A (D x (S0 + n)) row-major in its params block (at an offset that is a multiple of 8):
 * packed posterior, then A, low[D], high[D]. Every stage's variance calibration a, b lies at
 * its calibration offset in params (fmu_greybox/model/calibration.py). */
typedef struct {
    Py_ssize_t params_offset, m, d, s, memory, mode, active, memory_offset, calibration;
} StageRecord;

static StageRecord stage_record(const long long *plan, Py_ssize_t q) {
    const long long *r = plan + PLAN_HEADER + q * STAGE_RECORD;
    StageRecord s = {r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8]};
    return s;
}

typedef struct {
    Py_ssize_t n_stages, n_exo, depth, shared;
} Layout;

/* The history moves one row back; this row's white-box outputs and the previous row's inputs
 * enter it. The stage outputs of row j start as those of row j - 1 until each stage writes
 * its own. */
static void shift_history(const Layout *l, double *state, const double *y_wb,
                          const double *exo_prev) {
    const Py_ssize_t row = 2 * l->n_stages;
    double *exo = state + row * (l->depth + 1);
    memmove(state + row, state, (size_t)(row * l->depth) * sizeof(double));
    memcpy(state, y_wb, (size_t)l->n_stages * sizeof(double));
    memmove(exo + l->n_exo, exo, (size_t)(l->n_exo * l->depth) * sizeof(double));
    memcpy(exo, exo_prev, (size_t)l->n_exo * sizeof(double));
}

/* Push a new level into a memory of n levels with covariance P (n x n, row-major): the levels
 * move one back, the new one (variance var, covariance cov[k] with the old level k) enters in
 * front, the oldest leaves. */
static void push_level(double *memory, double *p, Py_ssize_t n, double level, double var,
                       const double *cov) {
    if (n < 1) return;
    memmove(memory + 1, memory, (size_t)(n - 1) * sizeof(double));
    memory[0] = level;
    for (Py_ssize_t i = n - 1; i > 0; i--) {
        for (Py_ssize_t j = n - 1; j > 0; j--) p[i * n + j] = p[(i - 1) * n + (j - 1)];
    }
    p[0] = var;
    for (Py_ssize_t k = 1; k < n; k++) p[k] = p[k * n] = cov[k - 1];
}

/* The variance a stage reports: a * var + b, var the propagated variance (which the memory
 * keeps), a and b the stage's calibration (b alone for a stage passed through, var = 0). */
static double calibrated_variance(const double *calibration, double var) {
    return calibration[0] * var + calibration[1];
}

/* One stage of one step. Returns the stage's domain score (largest kernel correlation), or
 * 2.0 when the stage passes its white-box through. */
static double stage_step(const StageRecord *r, const Layout *l, const double *params,
                         double *state, Py_ssize_t q, int enabled, double *work) {
    const Py_ssize_t n_stages = l->n_stages, shared = l->shared;
    double *out = state + n_stages, *out_var = state + shared, *outside = out_var + n_stages;
    double *memory = state + r->memory_offset, *memory_cov = memory + r->memory;
    double *cov = work; /* the new level's covariance with the stored ones (memory long) */
    const double y = state[q]; /* this row's white-box output */
    double level, var = 0.0, score = 2.0;

    work += r->memory;

    if (enabled && r->active) {
        const Py_ssize_t d = r->d, s = r->s, n = r->memory;
        const PosteriorView p = posterior_view(params + r->params_offset, r->m, d);
        const double *a = params + r->params_offset + posterior_size(r->m, d);
        const double *low = a + d * s, *high = low + d;
        double *x = work, *grad = x + d, *clipped = grad + d, *c = clipped + d;
        double *rest = c + n;
        double mu, var_gp, any_clipped = 0.0;
        for (Py_ssize_t i = 0; i < d; i++) {
            const double *row = a + i * s;
            double v = 0.0;
            for (Py_ssize_t j = 0; j < shared; j++) v += row[j] * state[j];
            for (Py_ssize_t j = 0; j < n; j++) v += row[shared + j] * memory[j];
            /* NaN compares false and passes unclipped, as it came */
            clipped[i] = 0.0;
            if (v < low[i]) v = low[i], clipped[i] = 1.0;
            else if (v > high[i]) v = high[i], clipped[i] = 1.0;
            any_clipped += clipped[i];
            x[i] = v;
        }
        outside[q] = any_clipped > 0.0 ? 1.0 : 0.0;
        score = predict_point(&p, x, &mu, &var_gp, grad, rest) / p.s2;
        /* a clipped feature no longer moves the output */
        for (Py_ssize_t i = 0; i < d; i++) {
            if (clipped[i] != 0.0) grad[i] = 0.0;
        }
        /* first-order propagation: the corrector's latent variance, the stage outputs of this
         * row (independent of each other and of the memory), and the stored levels through
         * their covariance P: var = var_gp + sum c_out^2 out_var + c' P c */
        var = var_gp;
        for (Py_ssize_t j = 0; j < n_stages; j++) {
            double sensitivity = 0.0;
            for (Py_ssize_t i = 0; i < d; i++) sensitivity += grad[i] * a[i * s + n_stages + j];
            var += sensitivity * sensitivity * out_var[j];
        }
        for (Py_ssize_t j = 0; j < n; j++) {
            c[j] = r->mode == MODE_INCREMENT && j == 0 ? 1.0 : 0.0;
            for (Py_ssize_t i = 0; i < d; i++) c[j] += grad[i] * a[i * s + shared + j];
        }
        for (Py_ssize_t k = 0; k < n; k++) {
            double pc = 0.0; /* (P c)_k: the new level's covariance with stored level k */
            for (Py_ssize_t l = 0; l < n; l++) pc += memory_cov[k * n + l] * c[l];
            cov[k] = pc;
            var += c[k] * pc;
        }
        level = r->mode == MODE_INCREMENT ? memory[0] + mu : mu;
        out[q] = r->mode == MODE_OUTPUT ? level : y + level;
    } else {
        outside[q] = 0.0;
        level = r->mode == MODE_OUTPUT ? y : 0.0;
        out[q] = y;
        for (Py_ssize_t k = 0; k < r->memory; k++) cov[k] = 0.0;
    }
    push_level(memory, memory_cov, r->memory, level, var, cov);
    out_var[q] = calibrated_variance(params + r->calibration, var);
    return score;
}

/* ------------------------------------------------------------------ Python glue */

typedef struct {
    Py_buffer view;
    int held;
} Buffer;

/* Whether a buffer format names a native 8-byte float ('d') or integer ('q', or 'l' where
 * long is 8 bytes, as numpy reports int64 on LP64 platforms). */
static int format_matches(const char *format, char wanted) {
    if (format == NULL) return 0;
    if (format[0] == '@' || format[0] == '=' || format[0] == '<') format++;
    if (format[0] == '\0' || format[1] != '\0') return 0;
    if (wanted == 'q') return format[0] == 'q' || (format[0] == 'l' && sizeof(long) == 8);
    return format[0] == wanted;
}

static int take(PyObject *object, Buffer *b, const char *name, char format, int writable) {
    const int flags = PyBUF_FORMAT | PyBUF_C_CONTIGUOUS | (writable ? PyBUF_WRITABLE : 0);
    b->held = 0;
    if (PyObject_GetBuffer(object, &b->view, flags) != 0) {
        PyErr_Format(PyExc_TypeError, "%s: a C-contiguous%s buffer is needed", name,
                     writable ? " writable" : "");
        return -1;
    }
    b->held = 1;
    if (b->view.itemsize != 8 || !format_matches(b->view.format, format)) {
        PyErr_Format(PyExc_TypeError, "%s: buffer of %s needed", name,
                     format == 'd' ? "float64" : "int64");
        return -1;
    }
    return 0;
}

static void release(Buffer *buffers, int n) {
    for (int i = 0; i < n; i++) {
        if (buffers[i].held) PyBuffer_Release(&buffers[i].view);
    }
}

static Py_ssize_t length(const Buffer *b) { return b->view.len / 8; }

static int too_short(const Buffer *b, Py_ssize_t needed, const char *name) {
    if (length(b) < needed) {
        PyErr_Format(PyExc_ValueError, "%s holds %zd values, %zd needed", name, length(b), needed);
        return 1;
    }
    return 0;
}

PyDoc_STRVAR(predict_doc,
             "predict(posterior, m, d, x, grad, full_noise) -> (mean, var)\n\n"
             "Mean and variance of one sparse-GP posterior at one point, original units.\n"
             "posterior: packed float64 parameters; x: float64 (d,); grad: writable float64 "
             "(d,) that receives d mean / d x, or None; full_noise: add the noise variance.");

static PyObject *py_predict(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    Buffer b[3] = {{.held = 0}, {.held = 0}, {.held = 0}};
    PyObject *result = NULL;
    Py_ssize_t m, d;
    int full_noise, with_grad;
    double mean, var, stack[4096], *work;
    (void)self;
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "predict takes 6 arguments");
        return NULL;
    }
    m = PyLong_AsSsize_t(args[1]);
    d = PyLong_AsSsize_t(args[2]);
    full_noise = PyObject_IsTrue(args[5]);
    if (PyErr_Occurred() || full_noise < 0) return NULL;
    if (m < 1 || d < 1) {
        PyErr_SetString(PyExc_ValueError, "m and d must be positive");
        return NULL;
    }
    with_grad = args[4] != Py_None;
    if (take(args[0], &b[0], "posterior", 'd', 0) || take(args[3], &b[1], "x", 'd', 0) ||
        (with_grad && take(args[4], &b[2], "grad", 'd', 1)) ||
        too_short(&b[0], posterior_size(m, d), "posterior") || too_short(&b[1], d, "x") ||
        (with_grad && too_short(&b[2], d, "grad"))) {
        release(b, 3);
        return NULL;
    }
    work = 2 * m + 2 * d + 1 <= 4096 ? stack
                                     : PyMem_Malloc((size_t)(2 * m + 2 * d + 1) * sizeof(double));
    if (work == NULL) {
        release(b, 3);
        return PyErr_NoMemory();
    }
    {
        const PosteriorView p = posterior_view(b[0].view.buf, m, d);
        predict_point(&p, b[1].view.buf, &mean, &var, with_grad ? b[2].view.buf : NULL, work);
        if (full_noise) var += p.noise * (p.y_scale * p.y_scale);
    }
    if (work != stack) PyMem_Free(work);
    release(b, 3);
    result = PyTuple_New(2);
    if (result != NULL) {
        PyTuple_SET_ITEM(result, 0, PyFloat_FromDouble(mean));
        PyTuple_SET_ITEM(result, 1, PyFloat_FromDouble(var));
    }
    return result;
}

PyDoc_STRVAR(step_doc,
             "step(plan, params, work, state, exo_prev, y_wb, enabled) -> domain_score\n\n"
             "Advance the corrector chain by one communication step, in place on state.\n"
             "plan: int64 layout; params: float64 feature maps, ranges and posteriors; work: "
             "writable float64 scratch; state: writable float64 chain state; exo_prev: the "
             "exogenous inputs of the previous row; y_wb: this row's white-box stage outputs; "
             "enabled: false passes the white-box through. Returns the smallest kernel "
             "correlation over the stages whose correctors ran (1.0 if none).");

static PyObject *py_step(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    Buffer b[6];
    const char *names[6] = {"plan", "params", "work", "state", "exo_prev", "y_wb"};
    const char formats[6] = {'q', 'd', 'd', 'd', 'd', 'd'};
    const int writable[6] = {0, 0, 1, 1, 0, 0};
    const long long *plan;
    double *state, score = 1.0;
    Layout layout;
    int enabled;
    (void)self;
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "step takes 7 arguments");
        return NULL;
    }
    enabled = PyObject_IsTrue(args[6]);
    if (enabled < 0) return NULL;
    for (int i = 0; i < 6; i++) {
        if (take(args[i], &b[i], names[i], formats[i], writable[i])) {
            release(b, i + 1);
            return NULL;
        }
    }
    plan = b[0].view.buf;
    if (too_short(&b[0], PLAN_HEADER, "plan") || plan[0] != PLAN_VERSION ||
        too_short(&b[0], PLAN_HEADER + plan[1] * STAGE_RECORD, "plan")) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "plan of another version");
        release(b, 6);
        return NULL;
    }
    layout.n_stages = plan[1];
    layout.n_exo = plan[2];
    layout.depth = plan[6];
    layout.shared = (layout.depth + 1) * (2 * layout.n_stages + layout.n_exo);
    if (too_short(&b[1], plan[3], "params") || too_short(&b[2], plan[4], "work") ||
        too_short(&b[3], plan[5], "state") || too_short(&b[4], layout.n_exo, "exo_prev") ||
        too_short(&b[5], layout.n_stages, "y_wb")) {
        release(b, 6);
        return NULL;
    }
    state = b[3].view.buf;
    shift_history(&layout, state, b[5].view.buf, b[4].view.buf);
    for (Py_ssize_t q = 0; q < layout.n_stages; q++) {
        const StageRecord r = stage_record(plan, q);
        const double stage_score =
            stage_step(&r, &layout, b[1].view.buf, state, q, enabled, b[2].view.buf);
        if (stage_score < score) score = stage_score;
    }
    release(b, 6);
    return PyFloat_FromDouble(score);
}

static PyMethodDef methods[] = {
    {"predict", (PyCFunction)(void (*)(void))py_predict, METH_FASTCALL, predict_doc},
    {"step", (PyCFunction)(void (*)(void))py_step, METH_FASTCALL, step_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_chainstep",
    "The grey-box's co-simulation hot path, compiled (see chainstep.c).", -1, methods,
};

PyMODINIT_FUNC PyInit__chainstep(void) {
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) return NULL;
    if (PyModule_AddIntConstant(m, "PLAN_VERSION", PLAN_VERSION) ||
        PyModule_AddIntConstant(m, "PLAN_HEADER", PLAN_HEADER) ||
        PyModule_AddIntConstant(m, "STAGE_RECORD", STAGE_RECORD) ||
        PyModule_AddIntConstant(m, "POSTERIOR_SCALARS", POSTERIOR_SCALARS)) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
