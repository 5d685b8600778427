/*
 * rules.c -- what a grey-box step must satisfy, and the words of each refusal (rules.h).
 */
#include "rules.h"

#include <math.h>
#include <stdio.h>

/* Where docs/bench.md explains the input domain (quoted in the refusals). */
#define DOMAIN_DOCS "docs/bench.md, 'Input domain'"

int rules_step(double t, double h, double now, double dt, double tolerance, char *message,
               size_t size) {
    if (!(fabs(t - now) <= tolerance)) {
        snprintf(message, size, "currentCommunicationPoint = %.17g s, but the grey-box is at "
                 "%.17g s; it cannot jump in time (its correctors remember the last steps): "
                 "step on from %.17g s, or restore an FMU state saved at %.17g s", t, now, now,
                 t);
        return -1;
    }
    if (!(fabs(h - dt) <= tolerance)) {
        snprintf(message, size, "communication step %g s at t = %g s; the correctors were "
                 "trained at %g s and need exactly that step. Set the bench's step to %g s", h,
                 t, dt, dt);
        return -1;
    }
    return 0;
}

ptrdiff_t rules_refused_input(ptrdiff_t n, const double *u, const double *low,
                              const double *high) {
    for (ptrdiff_t i = 0; i < n; i++) {
        if (!isfinite(u[i]) || u[i] < low[i] || u[i] > high[i]) return i;
    }
    return -1;
}

void rules_input_message(const char *name, double value, double low, double high, double now,
                         char *message, size_t size) {
    if (!isfinite(value)) {
        snprintf(message, size, "input %s = %g at t = %.9g s is not a finite number; the "
                 "grey-box refuses it (set a finite value and step again)", name, value, now);
        return;
    }
    snprintf(message, size, "input %s = %.9g at t = %.9g s lies outside the grey-box's input "
             "domain [%.9g, %.9g] (the training range widened, " DOMAIN_DOCS "); the grey-box "
             "refuses to extrapolate this far: keep the input within the domain, or retrain "
             "with recordings that cover it", name, value, now, low, high);
}
