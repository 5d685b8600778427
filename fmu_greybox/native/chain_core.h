/*
 * chain_core.h -- the grey-box's numerical core: one sparse-GP prediction and one step of the
 * corrector chain, in plain C (no Python, no FMI).
 *
 * Compiled twice from the same sources: into the CPython extension fmu_greybox._chainstep
 * (chainstep.c, the glue) and into every native grey-box FMU (greybox_fmu.c). Both runtimes
 * therefore step the chain with the same code on the same numbers.
 *
 * The plan (int64) and the parameters (float64) are laid out by Python
 * (fmu_greybox/model/chain_step.py, ChainPlan); the layouts are described in chain_core.c.
 */
#ifndef GREYBOX_CHAIN_CORE_H
#define GREYBOX_CHAIN_CORE_H

#include <stddef.h>
#include <stdint.h>

/* Layout version of the plan and its fixed sizes (mirrored by ChainPlan). */
#define CHAIN_PLAN_VERSION 3
#define CHAIN_PLAN_HEADER 7
#define CHAIN_STAGE_RECORD 9
#define CHAIN_POSTERIOR_SCALARS 4
/* Doubles of a stage's calibration: a, b, the white-box's residual variance, and the domain
 * scores at and above which its corrector acts fully, at and below which not at all. */
#define CHAIN_CALIBRATION 5

/* Sizes a plan declares: stages, exogenous inputs, history depth, and the lengths (in doubles)
 * of the parameters, the scratch space and the chain state it needs. */
typedef struct {
    ptrdiff_t n_stages, n_exo, depth, params, work, state;
} ChainSizes;

/* Read the sizes of a plan of `length` entries into *sizes. Returns 0, or -1 with a message
 * (what is wrong) in message[0 .. size-1] when the plan is too short or of another version. */
int chain_plan_sizes(const int64_t *plan, ptrdiff_t length, ChainSizes *sizes, char *message,
                     size_t size);

/* Doubles a packed posterior of m inducing points and d inputs occupies. */
ptrdiff_t chain_posterior_size(ptrdiff_t m, ptrdiff_t d);

/* Doubles of scratch space chain_predict needs for m inducing points and d inputs. */
ptrdiff_t chain_predict_work(ptrdiff_t m, ptrdiff_t d);

/* Mean and latent variance (original units) of one packed posterior at the raw point x (d);
 * the gradient of the mean into grad (d) unless NULL; the noise variance added to *var when
 * full_noise. work: chain_predict_work(m, d) doubles. */
void chain_predict(const double *posterior, ptrdiff_t m, ptrdiff_t d, const double *x,
                   double *mean, double *var, double *grad, int full_noise, double *work);

/* Advance the chain by one communication step, in place on state: exo_prev holds the exogenous
 * inputs of the previous row, y_wb this row's white-box stage outputs; enabled = 0 passes the
 * white-box through. A corrector whose domain score falls below its stage's full-action score
 * fades out smoothly towards the white-box, and the stage's variance towards the white-box's
 * residual variance. Returns the domain score (1.0 when no corrector ran). */
double chain_step(const int64_t *plan, const double *params, double *work, double *state,
                  const double *exo_prev, const double *y_wb, int enabled);

/* The chain's state when all that is known is one row: this row's white-box stage outputs
 * y_wb (taken as the stage outputs too, a zero residual) and the exogenous inputs exo. */
void chain_start(const int64_t *plan, double *state, const double *y_wb, const double *exo);

#endif /* GREYBOX_CHAIN_CORE_H */
