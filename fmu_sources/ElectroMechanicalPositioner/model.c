/*
 * model.c -- physics of the electro-mechanical positioner: DC motor, gearbox and ball screw
 * (one elastic transmission) driving a load mass on a spring-damper mount.
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
    [S_CURRENT] = 10.0, [S_MOTOR_SPEED] = 100.0, [S_DEFLECTION] = 1e-5,
    [S_POSITION] = 1e-2, [S_VELOCITY] = 1e-1,
};

/* Nut travel per motor radian r = p / (2 pi N) [m/rad]. */
static double transmission_ratio(const SimData *d) {
    return REAL(d, screw_lead) / (TWO_PI * REAL(d, gear_ratio));
}

/* Force of the elastic transmission on the load [N] for deflection delta [m] and its rate
 * [m/s]: k_s e(delta) + c_s e'(delta) delta', where e is the deflection carried by the
 * transmission (delta itself in the white-box). */
static double transmission_force(const SimData *d, double deflection, double rate) {
    double carried = deflection, slope = 1.0;
#ifdef TRUTH_MODEL
    if (REAL(d, backlash) > 0.0) {
        /* Smooth dead zone of half-width g: e = delta - g above the gap, delta + g below it,
         * about 0 inside; the corners rounded over eps, e' rising from 0 to 1 at contact. */
        const double g = 0.5 * REAL(d, backlash), eps = REAL(d, backlash_smoothing);
        const double above = sqrt((deflection - g) * (deflection - g) + eps * eps);
        const double below = sqrt((deflection + g) * (deflection + g) + eps * eps);
        carried = deflection + 0.5 * (above - below);
        slope = 1.0 + 0.5 * ((deflection - g) / above - (deflection + g) / below);
    }
#endif
    return REAL(d, transmission_stiffness) * carried +
           REAL(d, transmission_damping) * slope * rate;
}

void model_derivatives(const SimData *d, const double x[N_STATES], double dx[N_STATES]) {
    const double r = transmission_ratio(d);
    const double current = x[S_CURRENT], speed = x[S_MOTOR_SPEED];
    const double position = x[S_POSITION], velocity = x[S_VELOCITY];
    const double rate = r * speed - velocity; /* deflection rate */
    const double force = transmission_force(d, x[S_DEFLECTION], rate);
    const double eta = REAL(d, transmission_efficiency);
    /* Mesh friction on the motor shaft, proportional to the transmitted force and opposing
     * rotation: r |F| (1 - eta) / eta, so the motor supplies r F / eta when driving. */
    const double mesh_friction = r * fabs(force) * (1.0 - eta) / eta *
                                 tanh(speed / REAL(d, efficiency_smoothing_speed));
    double voltage = REAL(d, motor_voltage), torque_constant = REAL(d, torque_constant);
    double load = force - REAL(d, mount_stiffness) * position -
                  REAL(d, viscous_friction) * velocity - REAL(d, load_force);
#ifdef TRUTH_MODEL
    voltage += REAL(d, offset);
    torque_constant *= 1.0 + REAL(d, gain_error);
    load -= REAL(d, coulomb_friction) * tanh(velocity / REAL(d, friction_smoothing_velocity));
    load -= REAL(d, viscous_friction_extra) * velocity;
#endif
    /* Pressed against an end stop the load stays there: the stop takes the net force. */
    if ((position >= REAL(d, stroke) && load > 0.0) ||
        (position <= -REAL(d, stroke) && load < 0.0)) {
        load = 0.0;
    }

    /* Armature circuit. */
    dx[S_CURRENT] = (voltage - REAL(d, resistance) * current -
                     REAL(d, back_emf_constant) * speed) / REAL(d, inductance);
    /* Motor shaft: electromagnetic torque against the transmission's reaction and losses. */
    dx[S_MOTOR_SPEED] = (torque_constant * current - r * force - mesh_friction) /
                        REAL(d, rotor_inertia);
    /* Transmission: nut travel r omega minus load travel. */
    dx[S_DEFLECTION] = rate;
    /* Load on its mount: Newton's law. */
    dx[S_POSITION] = velocity;
    dx[S_VELOCITY] = load / REAL(d, load_mass);
}

void model_project(const SimData *d, double x[N_STATES]) {
    /* A load arriving at an end stop stops there. The nut is not stopped: the travel taken
     * from the load goes to the deflection, so nut travel x + delta is unchanged. */
    const double limit = REAL(d, stroke);
    const double beyond = x[S_POSITION] - fmax(fmin(x[S_POSITION], limit), -limit);
    if (beyond != 0.0) {
        x[S_POSITION] -= beyond;
        x[S_DEFLECTION] += beyond;
        if (x[S_VELOCITY] * beyond > 0.0) x[S_VELOCITY] = 0.0;
    }
}

int model_check(const SimData *d, char *message, size_t size) {
    static const struct {
        const char *name;
        int index;
    } positive[] = {
        {"resistance", R_resistance},
        {"inductance", R_inductance},
        {"torque_constant", R_torque_constant},
        {"rotor_inertia", R_rotor_inertia},
        {"gear_ratio", R_gear_ratio},
        {"screw_lead", R_screw_lead},
        {"transmission_efficiency", R_transmission_efficiency},
        {"efficiency_smoothing_speed", R_efficiency_smoothing_speed},
        {"transmission_stiffness", R_transmission_stiffness},
        {"load_mass", R_load_mass},
        {"stroke", R_stroke},
#ifdef TRUTH_MODEL
        {"friction_smoothing_velocity", R_friction_smoothing_velocity},
        {"backlash_smoothing", R_backlash_smoothing},
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
    /* At rest at mid-stroke, transmission unloaded (nut centred in any backlash). */
    for (int i = 0; i < N_STATES; i++) d->x[i] = 0.0;
}

int model_after_step(SimData *d, char *message, size_t size) {
    (void)d, (void)message, (void)size;
    return 0;
}

void model_outputs(SimData *d) {
    const double rate = transmission_ratio(d) * d->x[S_MOTOR_SPEED] - d->x[S_VELOCITY];
    REAL(d, motor_current) = d->x[S_CURRENT];
    REAL(d, motor_speed) = d->x[S_MOTOR_SPEED];
    REAL(d, position) = d->x[S_POSITION];
    REAL(d, velocity) = d->x[S_VELOCITY];
    REAL(d, transmission_deflection) = d->x[S_DEFLECTION];
    REAL(d, transmission_force) = transmission_force(d, d->x[S_DEFLECTION], rate);
}
