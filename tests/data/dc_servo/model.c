/*
 * model.c -- DC servo axis: armature circuit, rotor and load (README.md). Compiled with
 * -DTRUTH_MODEL it adds bearing friction; with -DSPEED_OUTPUT it reports the shaft speed.
 */
#include <math.h>
#include <stdio.h>

#include "fmu_framework.h"

const double model_state_nominal[N_STATES] = {[S_IA] = 1.0, [S_W] = 10.0, [S_TH] = 1.0};

void model_derivatives(const SimData *d, const double x[N_STATES], double dx[N_STATES]) {
    double torque = REAL(d, kt) * x[S_IA] - REAL(d, b) * x[S_W] - REAL(d, tl);
#ifdef TRUTH_MODEL
    const double direction = tanh(x[S_W] / REAL(d, ws));
    torque -= REAL(d, fc) * direction + REAL(d, fa) * fabs(direction);
#endif
    dx[S_IA] = (REAL(d, u) - REAL(d, R) * x[S_IA] - REAL(d, ke) * x[S_W]) / REAL(d, L);
    dx[S_W] = torque / REAL(d, J);
    dx[S_TH] = x[S_W];
}

void model_project(const SimData *d, double x[N_STATES]) { (void)d, (void)x; }

int model_check(const SimData *d, char *message, size_t size) {
    static const struct {
        const char *name;
        int index;
    } positive[] = {
        {"R", R_R}, {"L", R_L}, {"J", R_J},
#ifdef TRUTH_MODEL
        {"ws", R_ws},
#endif
    };
    for (size_t i = 0; i < sizeof positive / sizeof positive[0]; i++) {
        if (!(d->real[positive[i].index] > 0.0)) {
            snprintf(message, size, "%s = %g must be positive.", positive[i].name,
                     d->real[positive[i].index]);
            return -1;
        }
    }
    return 0;
}

void model_initialize(SimData *d) {
    for (int i = 0; i < N_STATES; i++) d->x[i] = 0.0;
}

int model_after_step(SimData *d, char *message, size_t size) {
    (void)d, (void)message, (void)size;
    return 0;
}

void model_outputs(SimData *d) {
    REAL(d, ia) = d->x[S_IA];
    REAL(d, th) = d->x[S_TH];
#ifdef SPEED_OUTPUT
    REAL(d, w) = d->x[S_W];
#endif
}
