/*
 * terms.c -- the named correction terms (terms.h), kind by kind as in terms.py.
 */
#include "terms.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "greybox_config.h"

/* Python's min(a, b) and max(a, b): the first argument unless the second compares beyond it. */
static double py_min(double a, double b) { return b < a ? b : a; }
static double py_max(double a, double b) { return b > a ? b : a; }

/* ------------------------------------------------------------------ delay line */

static int line_init(DelayLine *l, double whole, double frac, ptrdiff_t width,
                     void *(*allocate)(size_t, size_t)) {
    l->whole = (ptrdiff_t)whole;
    l->frac = frac;
    l->size = l->whole + 2;
    l->width = width;
    /* one more than needed: a sensor delay of no channel still gets memory */
    l->buffer = allocate((size_t)(l->size * width + width + 1), sizeof(double));
    l->out = l->buffer + l->size * width;
    l->count = 0;
    l->head = -1;
    return l->buffer == NULL ? -1 : 0;
}

static ptrdiff_t wrap(ptrdiff_t i, ptrdiff_t n) { return ((i % n) + n) % n; }

/* Push this step's values x (width) and return the delayed ones (l->out). */
static const double *line_push(DelayLine *l, const double *x) {
    const ptrdiff_t w = l->width;
    const double *newer, *older;
    l->head = (l->head + 1) % l->size;
    if (l->count == 0) {
        for (ptrdiff_t r = 0; r < l->size; r++) memcpy(l->buffer + r * w, x, (size_t)w * 8);
    } else {
        memcpy(l->buffer + l->head * w, x, (size_t)w * sizeof(double));
    }
    l->count++;
    newer = l->buffer + wrap(l->head - l->whole, l->size) * w;
    older = l->buffer + wrap(l->head - l->whole - 1, l->size) * w;
    for (ptrdiff_t i = 0; i < w; i++) l->out[i] = newer[i] + l->frac * (older[i] - newer[i]);
    return l->out;
}

/* ------------------------------------------------------------------ kinds */

static int has_line(int kind) {
    return kind == TERM_InputDelay || kind == TERM_SensorDelay || kind == TERM_SensorChannelDelay;
}

int term_init(Term *t, const int64_t *ints, const double *reals, const int64_t *channels,
              void *(*allocate)(size_t, size_t), char *message, size_t size) {
    memset(t, 0, sizeof *t);
    t->kind = (int)ints[0];
    t->input = (ptrdiff_t)ints[1];
    t->source = (ptrdiff_t)ints[2];
    t->output = (ptrdiff_t)ints[3];
    t->rate = (int)ints[4];
    t->n_channels = (ptrdiff_t)ints[5];
    t->channels = channels;
    memcpy(t->p, reals, sizeof t->p);
    switch (t->kind) {
        case TERM_ParameterChange: case TERM_InputGain: case TERM_InputOffset:
        case TERM_ForceOffset: case TERM_InputSaturation: case TERM_InputHysteresis:
        case TERM_InputLag: case TERM_InputDeadband: case TERM_InputDelay:
        case TERM_CoulombForce: case TERM_ViscousForce: case TERM_StribeckForce:
        case TERM_SpringForce: case TERM_FlowDroop: case TERM_SensorDelay:
        case TERM_SensorGain: case TERM_SensorOffset: case TERM_SensorChannelDelay:
            break;
        default:
            snprintf(message, size, "term kind %d is not one this binary implements; export "
                     "the FMU again with this version of fmu-greybox", t->kind);
            return -1;
    }
    if (has_line(t->kind)) {
        const ptrdiff_t width = t->kind == TERM_SensorDelay ? t->n_channels : 1;
        if (line_init(&t->line, t->p[0], t->p[1], width, allocate) != 0) {
            snprintf(message, size, "out of memory for a delay line");
            return -1;
        }
    }
    term_reset(t);
    return 0;
}

void term_free(Term *t, void (*release)(void *)) {
    if (t->line.buffer != NULL) release(t->line.buffer);
    t->line.buffer = NULL;
}

int term_is_feedback(const Term *t) {
    switch (t->kind) {
        case TERM_CoulombForce: case TERM_ViscousForce: case TERM_StribeckForce:
        case TERM_SpringForce: case TERM_FlowDroop:
            return 1;
        default:
            return 0;
    }
}

int term_on_inputs(const Term *t) {
    switch (t->kind) {
        case TERM_InputGain: case TERM_InputOffset: case TERM_ForceOffset:
        case TERM_InputSaturation: case TERM_InputHysteresis: case TERM_InputLag:
        case TERM_InputDeadband: case TERM_InputDelay:
            return 1;
        default:
            return term_is_feedback(t);
    }
}

int term_on_outputs(const Term *t) {
    return t->kind == TERM_SensorDelay || t->kind == TERM_SensorGain ||
           t->kind == TERM_SensorOffset || t->kind == TERM_SensorChannelDelay;
}

void term_reset(Term *t) {
    t->acting = NAN;
    t->last = NAN;
    t->line.count = 0;
    t->line.head = -1;
}

/* What a feedback term adds to its input for the source value x (the kinds' value()). */
static double feedback_value(const Term *t, double x) {
    const double *p = t->p;
    switch (t->kind) {
        case TERM_CoulombForce: { /* force, smoothing, asymmetry */
            const double th = tanh(x / p[1]);
            return p[0] * th + p[2] * fabs(th);
        }
        case TERM_ViscousForce: /* coefficient */
            return p[0] * x;
        case TERM_StribeckForce: { /* force, velocity, smoothing; r * r as terms.py squares */
            const double r = x / p[1];
            return p[0] * exp(-(r * r)) * tanh(x / p[2]);
        }
        case TERM_SpringForce: /* coefficient, rest */
            return p[0] * (x - p[1]);
        default: /* TERM_FlowDroop: resistance */
            return -p[0] * x;
    }
}

void term_input(Term *t, double *u, const double *y) {
    const double *p = t->p;
    double *v = u + t->input;
    switch (t->kind) {
        case TERM_InputGain: *v *= 1.0 + p[0]; break;
        case TERM_InputOffset: case TERM_ForceOffset: *v += p[0]; break;
        case TERM_InputSaturation: *v = py_min(py_max(*v, p[0]), p[1]); break;
        case TERM_InputHysteresis: { /* width */
            const double x = *v, half = 0.5 * fabs(p[0]);
            const double acting = isnan(t->acting) ? x : t->acting;
            t->acting = py_min(py_max(acting, x - half), x + half);
            *v = t->acting;
            break;
        }
        case TERM_InputLag: { /* alpha */
            const double x = *v;
            const double acting = isnan(t->acting) ? x : t->acting;
            t->acting = acting + p[0] * (x - acting);
            *v = t->acting;
            break;
        }
        case TERM_InputDeadband: *v = copysign(py_max(fabs(*v) - p[0], 0.0), *v); break;
        case TERM_InputDelay: *v = line_push(&t->line, v)[0]; break;
        default: { /* feedback; the sub-step is the last real */
            double x = y[t->source];
            if (t->rate) {
                const double last = t->last;
                t->last = x;
                x = isnan(last) ? 0.0 : (x - last) / p[TERM_REALS - 1];
            }
            *v += feedback_value(t, x);
            break;
        }
    }
}

void term_output(Term *t, double *y) {
    switch (t->kind) {
        case TERM_SensorDelay: {
            const double *delayed;
            for (ptrdiff_t i = 0; i < t->n_channels; i++) t->line.out[i] = y[t->channels[i]];
            delayed = line_push(&t->line, t->line.out);
            for (ptrdiff_t i = 0; i < t->n_channels; i++) y[t->channels[i]] = delayed[i];
            break;
        }
        case TERM_SensorGain:
            if (t->output >= 0) y[t->output] = y[t->output] * (1.0 + t->p[0]);
            break;
        case TERM_SensorOffset:
            if (t->output >= 0) y[t->output] = y[t->output] + t->p[0];
            break;
        default: /* TERM_SensorChannelDelay */
            if (t->output >= 0) y[t->output] = line_push(&t->line, y + t->output)[0];
            break;
    }
}

ptrdiff_t term_memory_size(const Term *t) {
    return 4 + (has_line(t->kind) ? t->line.size * t->line.width : 0);
}

void term_save(const Term *t, double *memory) {
    memory[0] = t->acting;
    memory[1] = t->last;
    memory[2] = (double)t->line.count;
    memory[3] = (double)t->line.head;
    if (has_line(t->kind)) {
        memcpy(memory + 4, t->line.buffer, (size_t)(t->line.size * t->line.width) * 8);
    }
}

void term_load(Term *t, const double *memory) {
    t->acting = memory[0];
    t->last = memory[1];
    t->line.count = (ptrdiff_t)memory[2];
    t->line.head = (ptrdiff_t)memory[3];
    if (has_line(t->kind)) {
        memcpy(t->line.buffer, memory + 4, (size_t)(t->line.size * t->line.width) * 8);
    }
}

const char *term_memory_fault(const Term *t, const double *memory) {
    const double count = memory[2], head = memory[3];
    const ptrdiff_t rows = has_line(t->kind) ? t->line.size : 0;
    if (isinf(memory[0]) || isinf(memory[1])) return "a play, lag or rate memory is infinite";
    if (!(count >= 0.0 && count <= 9007199254740992.0 && count == floor(count))) {
        return "its delay line's sample count is not a whole number of samples";
    }
    if (!(head >= -1.0 && head < (double)rows && head == floor(head))) {
        return "its delay line's head lies outside the line";
    }
    if ((count == 0.0) != (head == -1.0)) return "its delay line's head and count disagree";
    for (ptrdiff_t i = 0; i < rows * t->line.width; i++) {
        if (!isfinite(memory[4 + i])) return "a delay line sample is not finite";
    }
    return NULL;
}
