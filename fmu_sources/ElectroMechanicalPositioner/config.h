/*
 * config.h -- state layout of the ElectroMechanicalPositioner models.
 *
 * Compiled twice: as ElectroMechanicalPositioner (white-box) and, with -DTRUTH_MODEL, as
 * ElectroMechanicalPositionerTruth. Both have the same states and no private memory.
 */
#ifndef ELECTRO_MECHANICAL_POSITIONER_CONFIG_H
#define ELECTRO_MECHANICAL_POSITIONER_CONFIG_H

/* Continuous states, in the order of SimData.x. */
enum {
    S_CURRENT,     /* armature current i [A] */
    S_MOTOR_SPEED, /* motor shaft speed omega [rad/s] */
    S_DEFLECTION,  /* transmission deflection delta = nut travel - load position [m] */
    S_POSITION,    /* load position x [m] */
    S_VELOCITY,    /* load velocity v [m/s] */
    N_STATES
};

#endif /* ELECTRO_MECHANICAL_POSITIONER_CONFIG_H */
