/*
 * rules.h -- what a grey-box step must satisfy, and the words of each refusal: one source for
 * both runtimes. The native FMU (greybox_fmu.c) checks its steps with these functions; the
 * Python FMU calls them through the extension fmu_greybox._chainstep (chainstep.c:
 * step_refusal, input_refusal), so the two cannot refuse differently or in other words.
 *
 * The rules, in the order fmi2DoStep checks them:
 *   1. no jump in time: the step starts where the grey-box is (its correctors remember the
 *      last steps);
 *   2. the trained step: the correctors were trained at one communication step dt;
 *   3. the inputs: each finite and within the input domain (fmu_greybox/model/domain.py
 *      computes the domain's bounds).
 * Plain C, no Python, no FMI.
 */
#ifndef RULES_H
#define RULES_H

#include <stddef.h>

/* Room for every refusal's text (a longer input name is cut). */
#define RULES_MESSAGE_SIZE 1024

/* Whether a step from t of size h may start on a grey-box at time now, trained at the step
 * dt: 0, or -1 with why (and how to mend it) in message (rules 1 and 2). Times agree within
 * tolerance [s] (both absolute). */
int rules_step(double t, double h, double now, double dt, double tolerance, char *message,
               size_t size);

/* The first of the n inputs u that is not finite or lies outside [low, high], or -1 when all
 * are accepted (rule 3). */
ptrdiff_t rules_refused_input(ptrdiff_t n, const double *u, const double *low,
                              const double *high);

/* Why the input name = value, of the domain [low, high], is refused at time now, into
 * message (for the input rules_refused_input found). */
void rules_input_message(const char *name, double value, double low, double high, double now,
                         char *message, size_t size);

#endif
