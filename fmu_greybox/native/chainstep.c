/*
 * chainstep.c -- the CPython glue of the grey-box's numerical core (chain_core.c).
 *
 * Its functions, for the Python module fmu_greybox._chainstep:
 *
 *   predict(posterior, m, d, x, grad, full_noise) -> (mean, var)
 *       One point through one sparse-GP posterior (SparseGPR.predict_one).
 *   step(plan, params, work, state, exo_prev, y_wb, enabled) -> domain_score
 *       One communication step of the whole corrector chain (GreyBoxChain.step).
 *   start(plan, state, y_wb, exo)
 *       The chain's state from one row of white-box outputs (ChainPlan.start).
 *   run(plan, params, work, state, exo, y_wb, first, taps, out)
 *       A free run of the chain over many rows (ChainPlan.run).
 *   step_refusal(t, h, now, dt, tolerance) -> str | None
 *   input_refusal(names, u, low, high, now) -> str | None
 *       Why a step is refused, in the native FMU's words (rules.c; the Python FMU's slave.py
 *       and model/domain.py InputDomain.refusal).
 *
 * The arrays are laid out by Python (fmu_greybox/gp/predictive.py: Posterior.packed;
 * fmu_greybox/model/chain_step.py: ChainPlan) and passed as buffers; this file holds no state,
 * no numerics and no rules: they live in chain_core.c and rules.c, which the native grey-box
 * FMU compiles too.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <string.h>

#include "chain_core.h"
#include "rules.h"

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
        too_short(&b[0], chain_posterior_size(m, d), "posterior") || too_short(&b[1], d, "x") ||
        (with_grad && too_short(&b[2], d, "grad"))) {
        release(b, 3);
        return NULL;
    }
    work = chain_predict_work(m, d) <= 4096
               ? stack
               : PyMem_Malloc((size_t)chain_predict_work(m, d) * sizeof(double));
    if (work == NULL) {
        release(b, 3);
        return PyErr_NoMemory();
    }
    chain_predict(b[0].view.buf, m, d, b[1].view.buf, &mean, &var,
                  with_grad ? b[2].view.buf : NULL, full_noise, work);
    if (work != stack) PyMem_Free(work);
    release(b, 3);
    result = PyTuple_New(2);
    if (result != NULL) {
        PyTuple_SET_ITEM(result, 0, PyFloat_FromDouble(mean));
        PyTuple_SET_ITEM(result, 1, PyFloat_FromDouble(var));
    }
    return result;
}

/* Take the plan (buffer 0) and check it; its sizes into *sizes. */
static int take_plan(PyObject *object, Buffer *b, ChainSizes *sizes) {
    char message[160];
    if (take(object, b, "plan", 'q', 0)) return -1;
    if (chain_plan_sizes(b->view.buf, length(b), sizes, message, sizeof message) != 0) {
        PyErr_SetString(PyExc_ValueError, message);
        return -1;
    }
    return 0;
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
    ChainSizes sizes;
    double score;
    int enabled;
    (void)self;
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "step takes 7 arguments");
        return NULL;
    }
    enabled = PyObject_IsTrue(args[6]);
    if (enabled < 0) return NULL;
    if (take_plan(args[0], &b[0], &sizes)) {
        release(b, 1);
        return NULL;
    }
    for (int i = 1; i < 6; i++) {
        if (take(args[i], &b[i], names[i], formats[i], writable[i])) {
            release(b, i + 1);
            return NULL;
        }
    }
    if (too_short(&b[1], sizes.params, "params") ||
        too_short(&b[2], sizes.work, "work") || too_short(&b[3], sizes.state, "state") ||
        too_short(&b[4], sizes.n_exo, "exo_prev") || too_short(&b[5], sizes.n_stages, "y_wb")) {
        release(b, 6);
        return NULL;
    }
    score = chain_step(b[0].view.buf, b[1].view.buf, b[2].view.buf, b[3].view.buf,
                       b[4].view.buf, b[5].view.buf, enabled);
    release(b, 6);
    return PyFloat_FromDouble(score);
}

PyDoc_STRVAR(start_doc,
             "start(plan, state, y_wb, exo)\n\n"
             "Fill the chain state from one row: y_wb, this row's white-box stage outputs, "
             "stand in for the stage outputs of every remembered row (a zero residual); exo, "
             "the exogenous inputs, for every remembered row of inputs.");

static PyObject *py_start(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    Buffer b[4];
    const char *names[4] = {"plan", "state", "y_wb", "exo"};
    const char formats[4] = {'q', 'd', 'd', 'd'};
    const int writable[4] = {0, 1, 0, 0};
    ChainSizes sizes;
    (void)self;
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "start takes 4 arguments");
        return NULL;
    }
    if (take_plan(args[0], &b[0], &sizes)) {
        release(b, 1);
        return NULL;
    }
    for (int i = 1; i < 4; i++) {
        if (take(args[i], &b[i], names[i], formats[i], writable[i])) {
            release(b, i + 1);
            return NULL;
        }
    }
    if (too_short(&b[1], sizes.state, "state") ||
        too_short(&b[2], sizes.n_stages, "y_wb") || too_short(&b[3], sizes.n_exo, "exo")) {
        release(b, 4);
        return NULL;
    }
    chain_start(b[0].view.buf, b[1].view.buf, b[2].view.buf, b[3].view.buf);
    release(b, 4);
    Py_RETURN_NONE;
}

PyDoc_STRVAR(run_doc,
             "run(plan, params, work, state, exo, y_wb, first, taps, out)\n\n"
             "Free-run the chain over rows first .. n - 1 of exo (n, n_exo) and y_wb (n, Q), "
             "in place on state, with every corrector enabled: what step does row after row, "
             "without Python between the rows (and without the GIL). taps: int64, the state's "
             "offsets of each stage's output mean, calibrated variance, propagated variance "
             "and out-of-range flag (4 Q values); out: writable float64 (n - first, 3 Q + 2) "
             "receiving per row the Q means, Q calibrated variances, Q propagated variances, "
             "the domain score and 1.0 where some stage's features left their range.");

static PyObject *py_run(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    Buffer b[8];
    const char *names[8] = {"plan", "params", "work", "state", "exo", "y_wb", "taps", "out"};
    const char formats[8] = {'q', 'd', 'd', 'd', 'd', 'd', 'q', 'd'};
    const int writable[8] = {0, 0, 1, 1, 0, 0, 0, 1};
    const int slot[8] = {0, 1, 2, 3, 4, 5, 7, 8};
    ChainSizes sizes;
    Py_ssize_t first, rows, q, width;
    (void)self;
    if (nargs != 9) {
        PyErr_SetString(PyExc_TypeError, "run takes 9 arguments");
        return NULL;
    }
    first = PyLong_AsSsize_t(args[6]);
    if (first == -1 && PyErr_Occurred()) return NULL;
    if (take_plan(args[0], &b[0], &sizes)) {
        release(b, 1);
        return NULL;
    }
    for (int i = 1; i < 8; i++) {
        if (take(args[slot[i]], &b[i], names[i], formats[i], writable[i])) {
            release(b, i + 1);
            return NULL;
        }
    }
    q = sizes.n_stages;
    width = 3 * q + 2;
    rows = sizes.n_exo > 0 ? length(&b[4]) / sizes.n_exo : 0;
    if (first < 1 || first > rows || length(&b[5]) != rows * q) {
        PyErr_Format(PyExc_ValueError, "run needs 1 <= first <= n and y_wb of n x %zd values", q);
        release(b, 8);
        return NULL;
    }
    if (too_short(&b[1], sizes.params, "params") || too_short(&b[2], sizes.work, "work") ||
        too_short(&b[3], sizes.state, "state") || too_short(&b[6], 4 * q, "taps") ||
        too_short(&b[7], (rows - first) * width, "out")) {
        release(b, 8);
        return NULL;
    }
    {
        const int64_t *taps = b[6].view.buf;
        const double *exo = b[4].view.buf, *y_wb = b[5].view.buf;
        double *state = b[3].view.buf, *out = b[7].view.buf;
        for (Py_ssize_t k = 0; k < 4 * q; k++) {
            if (taps[k] < 0 || taps[k] >= sizes.state) {
                PyErr_SetString(PyExc_ValueError, "run: a tap lies outside the state");
                release(b, 8);
                return NULL;
            }
        }
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t j = first; j < rows; j++) {
            double *row = out + (j - first) * width, outside = 0.0;
            row[3 * q] = chain_step(b[0].view.buf, b[1].view.buf, b[2].view.buf, state,
                                    exo + (j - 1) * sizes.n_exo, y_wb + j * q, 1);
            for (Py_ssize_t s = 0; s < q; s++) {
                row[s] = state[taps[s]];
                row[q + s] = state[taps[q + s]];
                row[2 * q + s] = state[taps[2 * q + s]];
                if (state[taps[3 * q + s]] == 1.0) outside = 1.0;
            }
            row[3 * q + 1] = outside;
        }
        Py_END_ALLOW_THREADS
    }
    release(b, 8);
    Py_RETURN_NONE;
}

/* ------------------------------------------------------------------ the rules of a step */

PyDoc_STRVAR(step_refusal_doc,
             "step_refusal(t, h, now, dt, tolerance) -> str | None\n\n"
             "Why a step from t of size h [s] is refused by a grey-box at time now trained at "
             "the step dt (times agree within tolerance [s]): a jump in time, or another step "
             "than the trained one. None when the step may start. The native FMU's rules and "
             "words (rules.c).");

static PyObject *py_step_refusal(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    char message[RULES_MESSAGE_SIZE];
    double x[5];
    (void)self;
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "step_refusal takes 5 arguments");
        return NULL;
    }
    for (int i = 0; i < 5; i++) {
        x[i] = PyFloat_AsDouble(args[i]);
        if (x[i] == -1.0 && PyErr_Occurred()) return NULL;
    }
    if (rules_step(x[0], x[1], x[2], x[3], x[4], message, sizeof message) == 0) Py_RETURN_NONE;
    return PyUnicode_DecodeUTF8(message, (Py_ssize_t)strlen(message), "replace");
}

/* The n numbers of a sequence, in new memory (PyMem_Free), or NULL with an exception set. */
static double *numbers(PyObject *object, Py_ssize_t n, const char *name) {
    PyObject *items = PySequence_Fast(object, name);
    double *out = NULL;
    if (items == NULL) return NULL;
    if (PySequence_Fast_GET_SIZE(items) != n) {
        PyErr_Format(PyExc_ValueError, "%s holds %zd values, one per input (%zd) is needed", name,
                     PySequence_Fast_GET_SIZE(items), n);
    } else if ((out = PyMem_Malloc((size_t)(n > 0 ? n : 1) * sizeof(double))) == NULL) {
        PyErr_NoMemory();
    } else {
        for (Py_ssize_t i = 0; i < n; i++) {
            out[i] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(items, i));
            if (out[i] == -1.0 && PyErr_Occurred()) {
                PyMem_Free(out);
                out = NULL;
                break;
            }
        }
    }
    Py_DECREF(items);
    return out;
}

PyDoc_STRVAR(input_refusal_doc,
             "input_refusal(names, u, low, high, now) -> str | None\n\n"
             "Why the inputs u are refused at time now [s]: the first that is not finite or "
             "lies outside its domain [low, high], named by names. None when all are accepted. "
             "names: sequence of str; u, low, high: sequences of as many floats. The native "
             "FMU's rules and words (rules.c).");

static PyObject *py_input_refusal(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    char message[RULES_MESSAGE_SIZE];
    double *u = NULL, *low = NULL, *high = NULL, now;
    PyObject *result = NULL;
    Py_ssize_t n, i;
    (void)self;
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "input_refusal takes 5 arguments");
        return NULL;
    }
    n = PySequence_Size(args[0]);
    now = PyFloat_AsDouble(args[4]);
    if (n < 0 || (now == -1.0 && PyErr_Occurred())) return NULL;
    if ((u = numbers(args[1], n, "u")) != NULL && (low = numbers(args[2], n, "low")) != NULL &&
        (high = numbers(args[3], n, "high")) != NULL) {
        i = rules_refused_input(n, u, low, high);
        if (i < 0) {
            result = Py_NewRef(Py_None);
        } else {
            PyObject *name = PySequence_GetItem(args[0], i);
            const char *text = name != NULL ? PyUnicode_AsUTF8(name) : NULL;
            if (text != NULL) {
                rules_input_message(text, u[i], low[i], high[i], now, message, sizeof message);
                result = PyUnicode_DecodeUTF8(message, (Py_ssize_t)strlen(message), "replace");
            }
            Py_XDECREF(name);
        }
    }
    PyMem_Free(u);
    PyMem_Free(low);
    PyMem_Free(high);
    return result;
}

static PyMethodDef methods[] = {
    {"predict", (PyCFunction)(void (*)(void))py_predict, METH_FASTCALL, predict_doc},
    {"step", (PyCFunction)(void (*)(void))py_step, METH_FASTCALL, step_doc},
    {"start", (PyCFunction)(void (*)(void))py_start, METH_FASTCALL, start_doc},
    {"run", (PyCFunction)(void (*)(void))py_run, METH_FASTCALL, run_doc},
    {"step_refusal", (PyCFunction)(void (*)(void))py_step_refusal, METH_FASTCALL,
     step_refusal_doc},
    {"input_refusal", (PyCFunction)(void (*)(void))py_input_refusal, METH_FASTCALL,
     input_refusal_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_chainstep",
    "The grey-box's co-simulation hot path, compiled (see chainstep.c and chain_core.c).", -1,
    methods,
};

PyMODINIT_FUNC PyInit__chainstep(void) {
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) return NULL;
    if (PyModule_AddIntConstant(m, "PLAN_VERSION", CHAIN_PLAN_VERSION) ||
        PyModule_AddIntConstant(m, "CALIBRATION", CHAIN_CALIBRATION) ||
        PyModule_AddIntConstant(m, "PLAN_HEADER", CHAIN_PLAN_HEADER) ||
        PyModule_AddIntConstant(m, "STAGE_RECORD", CHAIN_STAGE_RECORD) ||
        PyModule_AddIntConstant(m, "POSTERIOR_SCALARS", CHAIN_POSTERIOR_SCALARS)) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
