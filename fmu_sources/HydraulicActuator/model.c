/*
 * model.c -- physics of the servo-hydraulic actuator (EHV, ITFV, RAM).
 *
 * Equations, parameters and sources: README.md beside this file. Compiled with -DTRUTH_MODEL
 * it adds the effects the white-box leaves out; every one of them is off at its default value
 * (zero), and then the arithmetic is the white-box's, operation for operation.
 */
#include <math.h>
#include <stdio.h>

#include "fmu_framework.h"

#define TWO_PI 6.283185307179586477

const double model_state_nominal[N_STATES] = {
    [S_SPOOL_POSITION] = 1e-4, [S_SPOOL_VELOCITY] = 1e-1, [S_RAM_POSITION] = 1e-2,
    [S_RAM_VELOCITY] = 1e-1,   [S_PRESSURE_A] = 1e7,      [S_PRESSURE_B] = 1e7,
    [S_MONITOR] = 1e7,
};

/* Flows through the valve and the ITFV [m3/s] for one state. */
typedef struct {
    double supply_pressure; /* effective supply pressure at the valve [Pa] */
    double into_a;          /* valve flow into chamber A */
    double out_of_b;        /* valve flow out of chamber B */
    double supply;          /* flow drawn from the supply */
    double cross;           /* A -> B through leakage and (disengaged) bypass */
    double relief;          /* A -> B through the cross-port relief valve */
} Flows;

/* Turbulent orifice flow k sqrt(dp), k = Cd w |x| sqrt(2/rho), with the square root replaced by
 * dp / (dp^2 + pt^2)^(1/4): odd, smooth, and with finite slope 1/sqrt(pt) at dp = 0. */
static double orifice(double k, double dp, double pt) {
    return k * dp / sqrt(sqrt(dp * dp + pt * pt));
}

#ifdef TRUTH_MODEL
/* d(orifice)/d(dp). */
static double orifice_slope(double k, double dp, double pt) {
    const double s = dp * dp + pt * pt;
    return k * (0.5 * dp * dp + pt * pt) / (s * sqrt(sqrt(s)));
}

/* Effective supply pressure p with p = ps - r * k * sqrt~(p - p_load): supply line resistance r
 * (supply_pressure_droop) against the flow drawn through the open supply land. The left side
 * minus the right is increasing in p and changes sign between p_load and ps: safeguarded
 * Newton iteration on that bracket. */
static double drooped_supply(double ps, double r, double k, double p_load, double pt) {
    double lo = fmin(ps, p_load), hi = fmax(ps, p_load), p = ps;
    for (int iteration = 0; iteration < 60; iteration++) {
        const double g = p - ps + r * orifice(k, p - p_load, pt);
        if (g == 0.0) return p;
        if (g > 0.0) hi = p; else lo = p;
        double next = p - g / (1.0 + r * orifice_slope(k, p - p_load, pt));
        if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
        if (fabs(next - p) <= 1e-12 * fabs(ps) + 1e-9) return next;
        p = next;
    }
    return p;
}
#endif

/* Spool opening seen by the metering edges [m]. */
static double opening(const SimData *d, double spool_position) {
#ifdef TRUTH_MODEL
    /* Spool overlap: no flow until |x_s| exceeds the deadband. */
    return copysign(fmax(fabs(spool_position) - REAL(d, deadband), 0.0), spool_position);
#else
    (void)d;
    return spool_position;
#endif
}

static void flows(const SimData *d, const double x[N_STATES], Flows *f) {
    const double pa = x[S_PRESSURE_A], pb = x[S_PRESSURE_B], dp = pa - pb;
    const double pr = REAL(d, return_pressure), pt = REAL(d, transition_pressure);
    const double xe = opening(d, x[S_SPOOL_POSITION]);
    const double k = REAL(d, discharge_coefficient) * REAL(d, area_gradient) * fabs(xe) *
                     sqrt(2.0 / REAL(d, fluid_density));
    const int engaged = REAL(d, engage) >= 0.5;
    double leakage = REAL(d, leakage_coefficient);
    double ps = REAL(d, supply_pressure);
#ifdef TRUTH_MODEL
    leakage += REAL(d, internal_leakage);
    if (engaged && REAL(d, supply_pressure_droop) > 0.0) {
        ps = drooped_supply(ps, REAL(d, supply_pressure_droop), k, xe >= 0.0 ? pa : pb, pt);
    }
#endif
    f->supply_pressure = ps;
    if (!engaged) {
        /* ITFV disengaged: valve ports blocked, bypass connects A and B. */
        f->into_a = f->out_of_b = f->supply = 0.0;
        f->cross = (leakage + REAL(d, bypass_coefficient)) * dp;
    } else {
        if (xe >= 0.0) { /* P -> A, B -> T */
            f->into_a = orifice(k, ps - pa, pt);
            f->out_of_b = orifice(k, pb - pr, pt);
            f->supply = f->into_a;
        } else { /* P -> B, A -> T */
            f->into_a = -orifice(k, pa - pr, pt);
            f->out_of_b = -orifice(k, ps - pb, pt);
            f->supply = -f->out_of_b;
        }
        f->cross = leakage * dp;
    }
    f->relief = REAL(d, relief_gain) *
                copysign(fmax(fabs(dp) - REAL(d, relief_cracking_pressure), 0.0), dp);
}

/* Friction force of the ram seals opposing velocity v [N] (truth model only). */
#ifdef TRUTH_MODEL
static double friction(const SimData *d, double v) {
    const double vs = v / REAL(d, stribeck_velocity);
    const double direction = tanh(v / REAL(d, friction_smoothing_velocity));
    return (REAL(d, coulomb_friction) + REAL(d, stribeck_friction) * exp(-vs * vs)) * direction +
           REAL(d, friction_asymmetry) * fabs(direction);
}
#endif

void model_derivatives(const SimData *d, const double x[N_STATES], double dx[N_STATES]) {
    Flows f;
    const double area = REAL(d, piston_area), stroke = REAL(d, ram_stroke);
    const double position = x[S_RAM_POSITION], velocity = x[S_RAM_VELOCITY];
    const double omega = TWO_PI * REAL(d, valve_natural_frequency);
    double current = REAL(d, valve_current), gain = REAL(d, valve_gain);
    double beta = REAL(d, bulk_modulus);
    double force = area * (x[S_PRESSURE_A] - x[S_PRESSURE_B]) -
                   REAL(d, viscous_damping) * velocity - REAL(d, load_force);
#ifdef TRUTH_MODEL
    current += REAL(d, offset);
    gain *= 1.0 + REAL(d, gain_error);
    beta *= 1.0 - REAL(d, compliance);
    force -= friction(d, velocity);
#endif
    flows(d, x, &f);

    /* EHV: second-order spool dynamics driven by the commanded position K i. */
    dx[S_SPOOL_POSITION] = x[S_SPOOL_VELOCITY];
    dx[S_SPOOL_VELOCITY] = omega * omega * (gain * current - x[S_SPOOL_POSITION]) -
                           2.0 * REAL(d, valve_damping) * omega * x[S_SPOOL_VELOCITY];

    /* RAM: Newton's law. */
    dx[S_RAM_POSITION] = velocity;
    dx[S_RAM_VELOCITY] = force / REAL(d, ram_mass);

    /* Chamber pressures: continuity with compressibility, V = dead volume + swept volume. */
    {
        const double va = REAL(d, dead_volume) + area * (stroke + position);
        const double vb = REAL(d, dead_volume) + area * (stroke - position);
        const double through_piston = f.cross + f.relief;
        dx[S_PRESSURE_A] = beta / va * (f.into_a - area * velocity - through_piston);
        dx[S_PRESSURE_B] = beta / vb * (area * velocity + through_piston - f.out_of_b);
    }

    /* ITFV pressure monitor: first-order lag of p_A - p_B. */
    dx[S_MONITOR] = (x[S_PRESSURE_A] - x[S_PRESSURE_B] - x[S_MONITOR]) /
                    REAL(d, monitor_time_constant);
}

/* Clamp a position to [-limit, limit], zeroing a velocity that points into the stop. */
static void stop(double *position, double *velocity, double limit) {
    if (*position > limit) {
        *position = limit;
        if (*velocity > 0.0) *velocity = 0.0;
    } else if (*position < -limit) {
        *position = -limit;
        if (*velocity < 0.0) *velocity = 0.0;
    }
}

void model_project(const SimData *d, double x[N_STATES]) {
    stop(&x[S_SPOOL_POSITION], &x[S_SPOOL_VELOCITY], REAL(d, spool_stroke));
    stop(&x[S_RAM_POSITION], &x[S_RAM_VELOCITY], REAL(d, ram_stroke));
    /* Cavitation floor. */
    if (x[S_PRESSURE_A] < 0.0) x[S_PRESSURE_A] = 0.0;
    if (x[S_PRESSURE_B] < 0.0) x[S_PRESSURE_B] = 0.0;
}

int model_check(const SimData *d, char *message, size_t size) {
    static const struct {
        const char *name;
        int index;
    } positive[] = {
        {"valve_natural_frequency", R_valve_natural_frequency},
        {"spool_stroke", R_spool_stroke},
        {"discharge_coefficient", R_discharge_coefficient},
        {"area_gradient", R_area_gradient},
        {"fluid_density", R_fluid_density},
        {"bulk_modulus", R_bulk_modulus},
        {"dead_volume", R_dead_volume},
        {"piston_area", R_piston_area},
        {"ram_mass", R_ram_mass},
        {"ram_stroke", R_ram_stroke},
        {"monitor_time_constant", R_monitor_time_constant},
        {"transition_pressure", R_transition_pressure},
#ifdef TRUTH_MODEL
        {"stribeck_velocity", R_stribeck_velocity},
        {"friction_smoothing_velocity", R_friction_smoothing_velocity},
#endif
    };
    for (size_t i = 0; i < sizeof positive / sizeof positive[0]; i++) {
        if (!(d->real[positive[i].index] > 0.0)) {
            snprintf(message, size, "%s = %g must be positive.", positive[i].name,
                     d->real[positive[i].index]);
            return -1;
        }
    }
    if (fabs(REAL(d, initial_ram_position)) > REAL(d, ram_stroke)) {
        snprintf(message, size, "initial_ram_position = %g m lies beyond the end stops at "
                 "+/-ram_stroke = %g m.", REAL(d, initial_ram_position), REAL(d, ram_stroke));
        return -1;
    }
    return 0;
}

/* ---------------------------------------------------------------------------------------------
 * Sensed signals and, in the truth model, their delay line.
 * ------------------------------------------------------------------------------------------- */

#ifdef TRUTH_MODEL
static void sensed(const double x[N_STATES], double y[N_SENSED]) {
    y[SENSED_SPOOL_POSITION] = x[S_SPOOL_POSITION];
    y[SENSED_RAM_POSITION] = x[S_RAM_POSITION];
    y[SENSED_ITFV_PRESSURE] = x[S_MONITOR];
    y[SENSED_RAM_VELOCITY] = x[S_RAM_VELOCITY];
    y[SENSED_PRESSURE_A] = x[S_PRESSURE_A];
    y[SENSED_PRESSURE_B] = x[S_PRESSURE_B];
}

/* Ring index of the j-th oldest sample. */
static int ring(const ModelMemory *m, int j) {
    return (m->newest - m->count + 1 + j + HISTORY_CAPACITY) % HISTORY_CAPACITY;
}

static void record(ModelMemory *m, double time, const double x[N_STATES]) {
    m->newest = (m->newest + 1) % HISTORY_CAPACITY;
    if (m->count < HISTORY_CAPACITY) m->count++;
    m->time[m->newest] = time;
    sensed(x, m->value[m->newest]);
}

/* Sensed signals at time t by linear interpolation in the history; before the oldest sample the
 * oldest value holds (the actuator rests before the start). */
static void delayed(const ModelMemory *m, double t, double y[N_SENSED]) {
    int lo = 0, hi = m->count - 1; /* find the last sample with time <= t */
    if (t <= m->time[ring(m, 0)]) {
        for (int s = 0; s < N_SENSED; s++) y[s] = m->value[ring(m, 0)][s];
        return;
    }
    while (lo < hi) {
        const int mid = (lo + hi + 1) / 2;
        if (m->time[ring(m, mid)] <= t) lo = mid; else hi = mid - 1;
    }
    if (lo == m->count - 1) {
        for (int s = 0; s < N_SENSED; s++) y[s] = m->value[m->newest][s];
        return;
    }
    {
        const int a = ring(m, lo), b = ring(m, lo + 1);
        const double w = (t - m->time[a]) / (m->time[b] - m->time[a]);
        for (int s = 0; s < N_SENSED; s++) {
            y[s] = m->value[a][s] + w * (m->value[b][s] - m->value[a][s]);
        }
    }
}
#endif

#ifdef TRUTH_MODEL
int model_check_memory(const SimData *d, char *message, size_t size) {
    const ModelMemory *m = &d->memory;
    if (m->newest < 0 || m->newest >= HISTORY_CAPACITY || m->count < 0 ||
        m->count > HISTORY_CAPACITY) {
        snprintf(message, size, "history ring index %d or count %d outside 0..%d", m->newest,
                 m->count, HISTORY_CAPACITY);
        return -1;
    }
    for (int j = 0; j < m->count; j++) {
        const int k = ring(m, j);
        int finite = isfinite(m->time[k]);
        for (int s = 0; s < N_SENSED; s++) finite = finite && isfinite(m->value[k][s]);
        if (!finite) {
            snprintf(message, size, "history sample %d is not finite", j);
            return -1;
        }
    }
    return 0;
}
#endif

void model_initialize(SimData *d) {
    const double mid = 0.5 * (REAL(d, supply_pressure) + REAL(d, return_pressure));
    for (int i = 0; i < N_STATES; i++) d->x[i] = 0.0;
    /* At rest with the critical-centre valve at null both chambers sit at mid pressure. */
    d->x[S_RAM_POSITION] = REAL(d, initial_ram_position);
    d->x[S_PRESSURE_A] = mid;
    d->x[S_PRESSURE_B] = mid;
#ifdef TRUTH_MODEL
    d->memory.count = 0;
    d->memory.newest = HISTORY_CAPACITY - 1;
    record(&d->memory, d->time, d->x);
#endif
}

int model_after_step(SimData *d, char *message, size_t size) {
#ifdef TRUTH_MODEL
    ModelMemory *m = &d->memory;
    record(m, d->time, d->x);
    if (m->count == HISTORY_CAPACITY && m->time[ring(m, 0)] > d->time - REAL(d, time_delay)) {
        snprintf(message, size, "time_delay = %g s needs more than %d history samples at this "
                 "internal step (%g s); raise solver_step or the communication step, or lower "
                 "time_delay.", REAL(d, time_delay), HISTORY_CAPACITY,
                 d->time - m->time[ring(m, m->count - 2)]);
        return -1;
    }
#else
    (void)d, (void)message, (void)size;
#endif
    return 0;
}

void model_outputs(SimData *d) {
    Flows f;
    flows(d, d->x, &f);
    REAL(d, spool_velocity) = d->x[S_SPOOL_VELOCITY];
    REAL(d, load_flow) = 0.5 * (f.into_a + f.out_of_b);
    REAL(d, relief_flow) = f.relief;
    REAL(d, supply_flow) = f.supply;
#ifdef TRUTH_MODEL
    if (REAL(d, time_delay) > 0.0) {
        double y[N_SENSED];
        delayed(&d->memory, d->time - REAL(d, time_delay), y);
        REAL(d, spool_position) = y[SENSED_SPOOL_POSITION];
        REAL(d, ram_position) = y[SENSED_RAM_POSITION];
        REAL(d, itfv_pressure) = y[SENSED_ITFV_PRESSURE];
        REAL(d, ram_velocity) = y[SENSED_RAM_VELOCITY];
        REAL(d, pressure_a) = y[SENSED_PRESSURE_A];
        REAL(d, pressure_b) = y[SENSED_PRESSURE_B];
        return;
    }
#endif
    REAL(d, spool_position) = d->x[S_SPOOL_POSITION];
    REAL(d, ram_position) = d->x[S_RAM_POSITION];
    REAL(d, itfv_pressure) = d->x[S_MONITOR];
    REAL(d, ram_velocity) = d->x[S_RAM_VELOCITY];
    REAL(d, pressure_a) = d->x[S_PRESSURE_A];
    REAL(d, pressure_b) = d->x[S_PRESSURE_B];
}
