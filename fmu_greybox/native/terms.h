/*
 * terms.h -- the named correction terms of a grey-box, in C: the native FMU's counterpart of
 * fmu_greybox/model/terms.py, with the same arithmetic in the same order.
 *
 * A term acts on the white-box's inputs before a (sub-)step (term_input) or on the outputs its
 * sensors report after a step (term_output). Each kind is one function of terms.c, named by
 * the kind's declaration in terms.py (Native); the FMU's generated greybox_config.h holds the
 * table of kinds, TERM_KIND_TABLE (fmu_greybox/model/native_terms.py: per kind code, from 1,
 * its function, where it acts and whether it keeps a delay line). What a term needs that
 * depends on names or on the step (positions, delay lengths, lag coefficients) was computed
 * at export by the Python term's own bind().
 */
#ifndef GREYBOX_TERMS_H
#define GREYBOX_TERMS_H

#include <stddef.h>
#include <stdint.h>

/* Integers and reals per term in the data file (sections term_int and term_real). */
#define TERM_INTS 6
#define TERM_REALS 6

/* Where a kind acts (the place of its row in TERM_KIND_TABLE): through FMU parameters only, on
 * one input, on one input from an output (feedback, at every sub-step), on one sensed output,
 * on several sensed outputs at once. */
enum { TERM_PARAMETER, TERM_INPUT, TERM_FEEDBACK, TERM_OUTPUT, TERM_CHANNELS };

/* A delay line of `width` signals sampled every step: `whole` + `frac` steps late, linear
 * interpolation, the first value held before the delay has elapsed (terms.py, DelayLine). */
typedef struct {
    ptrdiff_t whole, size, width, count, head;
    double frac;
    double *buffer; /* size * width */
    double *out;    /* width */
} DelayLine;

typedef struct {
    int kind;
    ptrdiff_t input;      /* position among the white-box inputs, or -1 */
    ptrdiff_t source;     /* position among the part's bound outputs (feedback), or -1 */
    ptrdiff_t output;     /* position among the bound outputs of a sensor channel, or -1 */
    int rate;             /* feedback from the rate of the source */
    ptrdiff_t n_channels; /* outputs a sensor delay acts on */
    const int64_t *channels;
    double p[TERM_REALS]; /* the kind's numbers (terms.py: Native.reals) */
    double acting, last;  /* memory of a play or lag, of a rate */
    DelayLine line;
} Term;

/* Fill a term from its record (ints: TERM_INTS, reals: TERM_REALS) and give its delay line,
 * if it has one, memory from allocate (calloc-like). Returns 0, or -1 (out of memory, or an
 * unknown kind: message says which). */
int term_init(Term *t, const int64_t *ints, const double *reals, const int64_t *channels,
              void *(*allocate)(size_t, size_t), char *message, size_t size);
void term_free(Term *t, void (*release)(void *));

/* What the term does: acts on inputs once per communication step, on inputs at every
 * sub-step from the outputs (feedback), on the outputs the sensors report. */
int term_on_inputs(const Term *t);
int term_is_feedback(const Term *t);
int term_on_outputs(const Term *t);

/* Forget the memory (before a run, as bind does). */
void term_reset(Term *t);
/* Correct the inputs u in place, given the outputs y at the start of the (sub-)step. */
void term_input(Term *t, double *u, const double *y);
/* Correct the outputs the sensors report, in place. */
void term_output(Term *t, double *y);

/* The memory as doubles (for the FMU state): how many, save, load. */
ptrdiff_t term_memory_size(const Term *t);
void term_save(const Term *t, double *memory);
void term_load(Term *t, const double *memory);
/* What is wrong with memory (term_memory_size doubles) as this term's, or NULL if it is one
 * the term could have saved: its play, lag or rate NaN (not started) or finite, its delay
 * line's head a row of the line (or -1 before the first push, with no sample yet), its
 * sample count a whole number, its samples finite. */
const char *term_memory_fault(const Term *t, const double *memory);

#endif /* GREYBOX_TERMS_H */
