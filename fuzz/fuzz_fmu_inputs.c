/*
 * fuzz_fmu_inputs.c -- libFuzzer target for what a master sets and steps on the native
 * grey-box FMU: fmi2SetReal (the inputs, ood_threshold, and value references that are no
 * settable Real), fmi2SetBoolean (correction_enabled, and references that are not it) and
 * fmi2DoStep (any current time and step size), in any order, with fmi2Reset now and then.
 *
 * Each input is a sequence of calls (see LLVMFuzzerTestOneInput), run on one instance reset
 * and initialised with its start values. Values are drawn mostly from NaN, +-inf, +-DBL_MAX,
 * +-1e30, subnormals, +-0, the variable's current value and values near it, or any 64 bits.
 * Besides the sanitizers, the harness checks the FMU's documented rules (greybox_fmu.c,
 * docs/bench.md "Input domain and refused steps"), and aborts (a finding) on any breach:
 *
 *   - every status is fmi2OK or fmi2Error (the only ones the native FMU answers with);
 *   - fmi2SetReal succeeds exactly when every reference is an input, or ood_threshold with a
 *     value in [0, 1], and the instance is not in its error phase; then each value reads back
 *     bit for bit; fmi2SetBoolean likewise for correction_enabled; a refused call sets nothing
 *     (every Real and Boolean reads back unchanged);
 *   - a step is accepted only at a finite time with a finite positive step, and its outputs
 *     are then finite; a refused step changes nothing (the serialised FMU state is identical
 *     byte for byte), unless it was a failure that put the instance into its error phase;
 *     there every later fmi2SetReal and fmi2DoStep is refused until fmi2Reset.
 *
 * Environment: that of fmu_harness.h (FUZZ_FMU_DIR, FUZZ_DT). Built and run by
 * tests/test_fuzz.py.
 */
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu_harness.h"

#define MAX_CALLS 32
#define MAX_REALS 1024

#define CHECK(condition, ...)                                                                  \
    do {                                                                                       \
        if (!(condition)) {                                                                    \
            fprintf(stderr, "fuzz_fmu_inputs: rule broken: " __VA_ARGS__);                     \
            fputc('\n', stderr);                                                               \
            abort();                                                                           \
        }                                                                                      \
    } while (0)

/* reals: the inputs (value references 0 to n_inputs - 1) first, ood_threshold last; then
 * the Booleans out_of_domain (n_reals) and correction_enabled (n_reals + 1) */
static fmi2ValueReference n_reals, n_inputs, threshold;

typedef struct {
    const uint8_t *at;
    size_t left;
} Bytes;

typedef struct {
    fmi2Real reals[MAX_REALS];
    fmi2Boolean booleans[2];
} Values;

static uint8_t take(Bytes *b) {
    if (b->left == 0) return 0;
    b->left--;
    return *b->at++;
}

/* A value for a variable now at near (or a time, a step): mostly one a master might get wrong. */
static double value(Bytes *b, double near) {
    const uint8_t k = take(b);
    const int scale = (k >> 4) - 8;
    double any = 0.0;
    uint8_t raw[8];
    switch (k % 16) {
    case 0: return NAN;
    case 1: return INFINITY;
    case 2: return -INFINITY;
    case 3: return DBL_MAX;
    case 4: return -DBL_MAX;
    case 5: return scale < 0 ? -1e30 : 1e30;
    case 6: return DBL_TRUE_MIN;
    case 7: return -DBL_MIN / 3.0; /* a negative subnormal */
    case 8: return scale < 0 ? -0.0 : 0.0;
    case 9: return near;
    case 10: return -near;
    case 11: return near + scale * 4.0 * DBL_EPSILON * fabs(near); /* within rounding */
    case 12: return near * (1.0 + scale * 1e-7);
    case 13: return near * (1.0 + scale / 32.0);
    case 14: return near + scale;
    default:
        for (int i = 0; i < 8; i++) raw[i] = take(b);
        memcpy(&any, raw, sizeof any);
        return any;
    }
}

static void check_status(fmi2Status status, const char *call) {
    CHECK(status == fmi2OK || status == fmi2Error, "%s answered status %d", call, (int)status);
}

static void read_values(Values *v) {
    memset(v, 0, sizeof *v);
    for (fmi2ValueReference vr = 0; vr < n_reals; vr++) {
        check_status(fmi2GetReal(instance, &vr, 1, &v->reals[vr]), "fmi2GetReal");
    }
    const fmi2ValueReference booleans[2] = {n_reals, n_reals + 1};
    check_status(fmi2GetBoolean(instance, booleans, 2, v->booleans), "fmi2GetBoolean");
}

/* The serialised FMU state (into a buffer kept between calls); its size. */
static size_t serialise(unsigned char **buffer, size_t *capacity) {
    static fmi2FMUstate state;
    size_t size = 0;
    CHECK(fmi2GetFMUstate(instance, &state) == fmi2OK, "fmi2GetFMUstate failed");
    CHECK(fmi2SerializedFMUstateSize(instance, state, &size) == fmi2OK, "state size failed");
    if (size > *capacity) {
        free(*buffer);
        *buffer = malloc(size);
        *capacity = size;
        CHECK(*buffer != NULL, "out of memory");
    }
    CHECK(fmi2SerializeFMUstate(instance, state, (fmi2Byte *)*buffer, size) == fmi2OK,
          "fmi2SerializeFMUstate failed");
    return size;
}

/* Whether the instance takes values (not in its error phase): an empty fmi2SetReal. */
static int settable(void) {
    const fmi2Status status = fmi2SetReal(instance, NULL, 0, NULL);
    check_status(status, "fmi2SetReal (empty)");
    return status == fmi2OK;
}

/* A value reference: byte 255 is ood_threshold, 254 out_of_domain, others taken modulo the
 * number of variables (Reals, then the two Booleans), so a corpus suits any export. */
static fmi2ValueReference reference(Bytes *b) {
    const uint8_t k = take(b);
    if (k == 255) return threshold;
    if (k == 254) return n_reals;
    return k % (n_reals + 2);
}

static void set_reals(Bytes *b, int failed) {
    fmi2ValueReference vr[2];
    fmi2Real v[2];
    Values before, after;
    const size_t n = 1 + (take(b) & 1);
    int valid = !failed;
    read_values(&before);
    for (size_t i = 0; i < n; i++) {
        vr[i] = reference(b);
        v[i] = value(b, vr[i] < n_reals ? before.reals[vr[i]] : 0.0);
        valid &= vr[i] < n_inputs || (vr[i] == threshold && v[i] >= 0.0 && v[i] <= 1.0);
    }
    const fmi2Status status = fmi2SetReal(instance, vr, n, v);
    check_status(status, "fmi2SetReal");
    CHECK((status == fmi2OK) == valid, "fmi2SetReal of %u = %g answered %d", (unsigned)vr[0],
          v[0], (int)status);
    read_values(&after);
    if (status == fmi2OK) {
        for (size_t i = 0; i < n; i++) {
            if (i + 1 < n && vr[i + 1] == vr[i]) continue; /* the last one counts */
            before.reals[vr[i]] = v[i];
        }
    }
    CHECK(memcmp(&before, &after, sizeof before) == 0, "fmi2SetReal (status %d) left other "
          "values than it should", (int)status);
}

static void set_boolean(Bytes *b, int failed) {
    Values before, after;
    const fmi2ValueReference vr = n_reals + take(b) % 3;
    const fmi2Boolean v = take(b) % 3; /* 2: true, though not fmi2True */
    read_values(&before);
    const fmi2Status status = fmi2SetBoolean(instance, &vr, 1, &v);
    check_status(status, "fmi2SetBoolean");
    CHECK((status == fmi2OK) == (!failed && vr == n_reals + 1),
          "fmi2SetBoolean of %u answered %d", (unsigned)vr, (int)status);
    read_values(&after);
    if (status == fmi2OK) before.booleans[1] = v ? fmi2True : fmi2False;
    CHECK(memcmp(&before, &after, sizeof before) == 0, "fmi2SetBoolean (status %d) left other "
          "values than it should", (int)status);
}

/* One fmi2DoStep; returns whether the instance is (now) in its error phase. */
static int step(Bytes *b, int failed) {
    static unsigned char *before, *after;
    static size_t before_capacity, after_capacity;
    const uint8_t how = take(b);
    const double t = how & 3 ? now : value(b, now), h = how & 12 ? dt : value(b, dt);
    const size_t size = serialise(&before, &before_capacity);
    const fmi2Status status = fmi2DoStep(instance, t, h, how >> 7);
    check_status(status, "fmi2DoStep");
    if (status == fmi2OK) {
        Values v;
        CHECK(!failed, "fmi2DoStep accepted in the error phase");
        CHECK(isfinite(t) && isfinite(h) && h > 0.0, "fmi2DoStep(%g, %g) accepted", t, h);
        read_values(&v);
        for (fmi2ValueReference vr = n_inputs; vr < n_reals; vr++) {
            CHECK(isfinite(v.reals[vr]), "after a step, Real %u = %g", (unsigned)vr, v.reals[vr]);
        }
        now = t + h;
        return 0;
    }
    if (!failed && !settable()) return 1; /* a failure: the error phase, until fmi2Reset */
    CHECK(serialise(&after, &after_capacity) == size && memcmp(before, after, size) == 0,
          "a refused fmi2DoStep(%.17g, %.17g) changed the FMU state", t, h);
    CHECK(settable() == !failed, "a refused fmi2DoStep changed the phase");
    return failed;
}

static void restart(void) {
    CHECK(fmi2Reset(instance) == fmi2OK && harness_initialise() == 0,
          "fmi2Reset and initialisation with the start values failed");
}

int LLVMFuzzerInitialize(int *argc, char ***argv) {
    (void)argc, (void)argv;
    fmi2Real v = 0.0;
    harness_start();
    while (n_reals < MAX_REALS && fmi2GetReal(instance, &n_reals, 1, &v) == fmi2OK) n_reals++;
    while (n_inputs < n_reals && fmi2GetReal(instance, &n_inputs, 1, &v) == fmi2OK &&
           fmi2SetReal(instance, &n_inputs, 1, &v) == fmi2OK) {
        n_inputs++;
    }
    threshold = n_reals - 1;
    if (n_inputs == 0 || n_reals == MAX_REALS || n_inputs >= threshold) {
        fprintf(stderr, "unexpected interface: %u Reals, %u inputs\n", (unsigned)n_reals,
                (unsigned)n_inputs);
        exit(2);
    }
    return 0;
}

/* Each call is one byte (modulo 8) and its arguments:
 *   0-2  fmi2SetReal: a byte (bit 0: one or two references), then for each a reference
 *        (reference()) and a value (value(), near the variable's current value);
 *   3    fmi2SetBoolean: a reference byte (out_of_domain, correction_enabled or none), a value;
 *   4-6  fmi2DoStep: a byte: bits 0-1 zero: the time from value() near the current time,
 *        else the current time; bits 2-3 likewise for the step; bit 7: noSetFMUStatePrior...;
 *   7    fmi2Reset, and initialisation with the start values. */
int LLVMFuzzerTestOneInput(const uint8_t *bytes, size_t size) {
    Bytes b = {bytes, size};
    int failed = 0;
    restart();
    for (int call = 0; call < MAX_CALLS && b.left > 0; call++) {
        switch (take(&b) % 8) {
        case 0:
        case 1:
        case 2: set_reals(&b, failed); break;
        case 3: set_boolean(&b, failed); break;
        case 7:
            restart();
            failed = 0;
            break;
        default: failed = step(&b, failed);
        }
    }
    return 0;
}
