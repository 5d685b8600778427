/*
 * config.h -- state layout and private memory of the HydraulicActuator models.
 *
 * Compiled twice: as HydraulicActuator (white-box) and, with -DTRUTH_MODEL, as
 * HydraulicActuatorTruth, whose extra memory is the history of the sensed signals needed for
 * the sensor time delay.
 */
#ifndef HYDRAULIC_ACTUATOR_CONFIG_H
#define HYDRAULIC_ACTUATOR_CONFIG_H

/* Continuous states, in the order of SimData.x. */
enum {
    S_SPOOL_POSITION, /* EHV spool position x_s [m] */
    S_SPOOL_VELOCITY, /* EHV spool velocity v_s [m/s] */
    S_RAM_POSITION,   /* ram position x [m] */
    S_RAM_VELOCITY,   /* ram velocity v [m/s] */
    S_PRESSURE_A,     /* chamber A pressure p_A [Pa] */
    S_PRESSURE_B,     /* chamber B pressure p_B [Pa] */
    S_MONITOR,        /* ITFV-monitored differential pressure p_m [Pa] */
    N_STATES
};

#ifdef TRUTH_MODEL

/* Sensed signals (delayed by time_delay in the truth model). */
enum {
    SENSED_SPOOL_POSITION,
    SENSED_RAM_POSITION,
    SENSED_ITFV_PRESSURE,
    SENSED_RAM_VELOCITY,
    SENSED_PRESSURE_A,
    SENSED_PRESSURE_B,
    N_SENSED
};

/* History samples kept: covers time_delay at internal steps down to time_delay / 4095. */
#define HISTORY_CAPACITY 4096

#define MODEL_HAS_MEMORY
typedef struct {
    double time[HISTORY_CAPACITY];            /* sample times [s], increasing */
    double value[HISTORY_CAPACITY][N_SENSED]; /* undelayed sensed signals */
    int newest;                               /* ring index of the newest sample */
    int count;                                /* number of valid samples */
} ModelMemory;

#endif /* TRUTH_MODEL */

#endif /* HYDRAULIC_ACTUATOR_CONFIG_H */
