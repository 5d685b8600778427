/*
 * fmu_framework.h -- a small generic FMI 2.0 co-simulation framework.
 *
 * The framework owns everything that is not physics: the FMI state machine, the variable
 * storage, get/set by value reference, FMU state snapshots and their serialisation, logging,
 * and the fixed-step linearly-implicit integrator that advances the continuous states inside
 * fmi2DoStep. It knows nothing about any particular model.
 *
 * A model is one folder holding
 *   variables.toml  the variable table; the builder (fmu_greybox.fmi.build) generates from it
 *                   fmu_variables.h / fmu_variables.c (value references, storage indices,
 *                   start values) and modelDescription.xml;
 *   config.h        N_STATES and, optionally, MODEL_HAS_MEMORY with a ModelMemory struct
 *                   (model-private persistent data that is part of the FMU state);
 *   model.c         the physics: the functions declared under "Model interface" below.
 *
 * All mutable data of an instance lives in one plain struct (SimData) without pointers, so an
 * FMU state is a byte copy of it and serialisation is a header plus those bytes.
 */
#ifndef FMU_FRAMEWORK_H
#define FMU_FRAMEWORK_H

#include <stddef.h>

#include "config.h"
#include "fmu_variables.h"

/* Data types, causalities and variabilities of the variable table. */
typedef enum { FW_ABSENT = 0, FW_REAL, FW_INTEGER, FW_BOOLEAN, FW_STRING } FwType;
typedef enum { FW_PARAMETER, FW_INPUT, FW_OUTPUT } FwCausality;
typedef enum { FW_FIXED, FW_TUNABLE, FW_DISCRETE, FW_CONTINUOUS } FwVariability;

/* One row of the generated variable table, indexed by value reference. Value references of
 * variables that belong to another model of the same table are FW_ABSENT here. */
typedef struct {
    const char *name;
    unsigned char type;        /* FwType */
    unsigned char causality;   /* FwCausality */
    unsigned char variability; /* FwVariability */
    int index;                 /* position in the SimData array of its type */
} FwVariable;

/* Phases of the FMI 2.0 co-simulation state machine. */
typedef enum {
    FW_INSTANTIATED,
    FW_INITIALIZATION_MODE,
    FW_STEP_COMPLETE,
    FW_TERMINATED,
    FW_ERROR
} FwPhase;

/* Capacity of one String variable, terminating zero included. */
#define FW_STRING_SIZE 256

/* Everything an FMU state holds. The "+ 1" keeps arrays of an unused type non-empty. */
typedef struct {
    int phase;                   /* FwPhase */
    int parameters_changed;      /* parameters set since the last check */
    int outputs_valid;           /* output variables up to date with states and inputs */
    double time;                 /* current communication point [s] */
    double real[N_REAL + 1];
    int integer[N_INTEGER + 1];
    int boolean[N_BOOLEAN + 1];
    char string[N_STRING + 1][FW_STRING_SIZE];
    double x[N_STATES];          /* continuous states */
#ifdef MODEL_HAS_MEMORY
    ModelMemory memory;
#endif
} SimData;

/* Generated tables (fmu_variables.c). */
extern const FwVariable fw_variables[N_VALUE_REFERENCES];
extern const double fw_real_start[N_REAL + 1];
extern const double fw_real_min[N_REAL + 1]; /* -HUGE_VAL where the table gives no min */
extern const double fw_real_max[N_REAL + 1]; /* +HUGE_VAL where the table gives no max */
extern const int fw_integer_start[N_INTEGER + 1];
extern const int fw_boolean_start[N_BOOLEAN + 1];
extern const char *const fw_string_start[N_STRING + 1];

/* Access a variable of the table by name, e.g. REAL(d, ram_mass). */
#define REAL(d, name) ((d)->real[R_##name])
#define INTEGER(d, name) ((d)->integer[I_##name])
#define BOOLEAN(d, name) ((d)->boolean[B_##name])
#define STRING(d, name) ((d)->string[S_##name])

/* ---------------------------------------------------------------------------------------------
 * Model interface: implemented by the model's model.c.
 *
 * Variables (parameters, inputs) are read from d; inputs hold their value over a
 * communication step. Functions returning int return 0 on success and otherwise write a
 * message (what is wrong and how to mend it) into message[0 .. size-1].
 * ------------------------------------------------------------------------------------------- */

/* Typical magnitude of each state; scales the finite-difference Jacobian. */
extern const double model_state_nominal[N_STATES];

/* Check parameter values before they are used (the framework has already checked the min/max
 * ranges of the table and that solver_step is positive). */
int model_check(const SimData *d, char *message, size_t size);

/* Set the initial states d->x (and model memory) from parameters and inputs at d->time. */
void model_initialize(SimData *d);

/* State derivatives dx = f(x) for the current inputs and parameters. */
void model_derivatives(const SimData *d, const double x[N_STATES], double dx[N_STATES]);

/* Project x back onto the admissible set (stops, floors) after each internal step. */
void model_project(const SimData *d, double x[N_STATES]);

/* Called after each internal step with d->time and d->x updated (e.g. to record history). */
int model_after_step(SimData *d, char *message, size_t size);

/* Compute every output variable from states, inputs and parameters. */
void model_outputs(SimData *d);

#ifdef MODEL_HAS_MEMORY
/* Check the memory of a state being restored (indices in range, values finite): 0, or -1 with
 * what is wrong. The framework has checked everything else of the state. */
int model_check_memory(const SimData *d, char *message, size_t size);
#endif

/* ---------------------------------------------------------------------------------------------
 * Integrator (rosenbrock.c)
 * ------------------------------------------------------------------------------------------- */

/* Internal steps one Jacobian serves at most. */
#define FW_JACOBIAN_STEPS 10

/* The iteration matrix of the Rosenbrock-W steps of one communication step: the Jacobian J
 * taken at the first internal step and W = I - gamma h J factorised, kept for the next
 * FW_JACOBIAN_STEPS - 1 steps (a W-method keeps its order with any J), then taken again. Set
 * fresh = 1 before the first step. */
typedef struct {
    double jac[N_STATES][N_STATES];
    double lu[N_STATES][N_STATES];
    int pivot[N_STATES];
    double h;
    int fresh;
    int served; /* steps taken with this J */
} FwIteration;

/* Advance x by one step h of the L-stable Rosenbrock-W method ROS34PW2 (order 3), with the
 * finite-difference Jacobian of `it` (taken here at x when it->fresh, h changed or it has served
 * FW_JACOBIAN_STEPS steps). Returns 0, or -1 if the iteration matrix is singular. */
int fw_rosenbrock_step(const SimData *d, double x[N_STATES], double h, FwIteration *it);

#endif /* FMU_FRAMEWORK_H */
