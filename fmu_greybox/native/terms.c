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
/* One function per kind, named by its declaration in terms.py (Native): what the kind makes of
 * the value x in place, reading its numbers t->p in the order the declaration lists them. x is
 * the input (TERM_INPUT), the source value or its rate, to become what is added to the input
 * (TERM_FEEDBACK), the sensed output (TERM_OUTPUT), or every sensed output of the term
 * (TERM_CHANNELS, t->line.width of them). */

static void kind_gain(Term *t, double *x) { *x *= 1.0 + t->p[0]; }         /* gain */
static void kind_offset(Term *t, double *x) { *x += t->p[0]; }             /* offset */
static void kind_clamp(Term *t, double *x) { *x = py_min(py_max(*x, t->p[0]), t->p[1]); }

static void kind_deadband(Term *t, double *x) { /* width */
    *x = copysign(py_max(fabs(*x) - t->p[0], 0.0), *x);
}

static void kind_play(Term *t, double *x) { /* width */
    const double half = 0.5 * fabs(t->p[0]);
    const double acting = isnan(t->acting) ? *x : t->acting;
    t->acting = py_min(py_max(acting, *x - half), *x + half);
    *x = t->acting;
}

static void kind_lag(Term *t, double *x) { /* alpha */
    const double acting = isnan(t->acting) ? *x : t->acting;
    t->acting = acting + t->p[0] * (*x - acting);
    *x = t->acting;
}

static void kind_delay(Term *t, double *x) { /* the line's whole steps, fraction */
    const double *delayed = line_push(&t->line, x);
    for (ptrdiff_t i = 0; i < t->line.width; i++) x[i] = delayed[i];
}

static void kind_coulomb(Term *t, double *x) { /* force, smoothing, asymmetry */
    const double th = tanh(*x / t->p[1]);
    *x = t->p[0] * th + t->p[2] * fabs(th);
}

static void kind_viscous(Term *t, double *x) { *x = t->p[0] * *x; } /* coefficient */

static void kind_stribeck(Term *t, double *x) { /* force, velocity, smoothing */
    const double r = *x / t->p[1]; /* squared as r * r, as terms.py squares */
    *x = t->p[0] * exp(-(r * r)) * tanh(*x / t->p[2]);
}

static void kind_spring(Term *t, double *x) { *x = t->p[0] * (*x - t->p[1]); } /* k, rest */
static void kind_droop(Term *t, double *x) { *x = -t->p[0] * *x; }            /* resistance */

/* The kinds, by code (row 0 unused): the generated table of greybox_config.h. */
typedef struct {
    void (*function)(Term *, double *);
    int place; /* TERM_PARAMETER ... TERM_CHANNELS */
    int line;  /* keeps a delay line */
} Kind;

#define KIND_ROW(function, place, line) {function, place, line},
static const Kind KINDS[] = {{NULL, TERM_PARAMETER, 0}, TERM_KIND_TABLE(KIND_ROW)};
#define N_KINDS ((int)(sizeof KINDS / sizeof KINDS[0]))

static const Kind *kind_of(const Term *t) { return &KINDS[t->kind]; }
static int has_line(const Term *t) { return kind_of(t)->line; }

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
    if (ints[0] < 1 || ints[0] >= N_KINDS) {
        snprintf(message, size, "term kind %lld is not one this binary implements; export "
                 "the FMU again with this version of fmu-greybox", (long long)ints[0]);
        return -1;
    }
    if (has_line(t)) {
        const ptrdiff_t width = kind_of(t)->place == TERM_CHANNELS ? t->n_channels : 1;
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

int term_is_feedback(const Term *t) { return kind_of(t)->place == TERM_FEEDBACK; }

int term_on_inputs(const Term *t) {
    return kind_of(t)->place == TERM_INPUT || kind_of(t)->place == TERM_FEEDBACK;
}

int term_on_outputs(const Term *t) {
    return kind_of(t)->place == TERM_OUTPUT || kind_of(t)->place == TERM_CHANNELS;
}

void term_reset(Term *t) {
    t->acting = NAN;
    t->last = NAN;
    t->line.count = 0;
    t->line.head = -1;
}

void term_input(Term *t, double *u, const double *y) {
    const Kind *kind = kind_of(t);
    if (kind->place == TERM_INPUT) {
        kind->function(t, u + t->input);
    } else { /* feedback; the sub-step is the last real */
        double x = y[t->source];
        if (t->rate) {
            const double last = t->last;
            t->last = x;
            x = isnan(last) ? 0.0 : (x - last) / t->p[TERM_REALS - 1];
        }
        kind->function(t, &x);
        u[t->input] += x;
    }
}

void term_output(Term *t, double *y) {
    const Kind *kind = kind_of(t);
    if (kind->place == TERM_CHANNELS) { /* gathered into the line's output row */
        double *x = t->line.out;
        for (ptrdiff_t i = 0; i < t->n_channels; i++) x[i] = y[t->channels[i]];
        kind->function(t, x);
        for (ptrdiff_t i = 0; i < t->n_channels; i++) y[t->channels[i]] = x[i];
    } else if (t->output >= 0) {
        kind->function(t, y + t->output);
    }
}

ptrdiff_t term_memory_size(const Term *t) {
    return 4 + (has_line(t) ? t->line.size * t->line.width : 0);
}

void term_save(const Term *t, double *memory) {
    memory[0] = t->acting;
    memory[1] = t->last;
    memory[2] = (double)t->line.count;
    memory[3] = (double)t->line.head;
    if (has_line(t)) {
        memcpy(memory + 4, t->line.buffer, (size_t)(t->line.size * t->line.width) * 8);
    }
}

void term_load(Term *t, const double *memory) {
    t->acting = memory[0];
    t->last = memory[1];
    t->line.count = (ptrdiff_t)memory[2];
    t->line.head = (ptrdiff_t)memory[3];
    if (has_line(t)) {
        memcpy(t->line.buffer, memory + 4, (size_t)(t->line.size * t->line.width) * 8);
    }
}

const char *term_memory_fault(const Term *t, const double *memory) {
    const double count = memory[2], head = memory[3];
    const ptrdiff_t rows = has_line(t) ? t->line.size : 0;
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
