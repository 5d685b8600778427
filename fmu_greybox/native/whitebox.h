/*
 * whitebox.h -- the white-box FMU embedded in a native grey-box FMU, stepped with its named
 * terms: the C counterpart of fmu_greybox/model/whitebox.py (NamedModel).
 *
 * The white-box sits unpacked in the grey-box's resources/whitebox/. Its binary is loaded with
 * dlopen (after its SHA-256 was checked against the data file) and driven through its own fmi2
 * functions. As in NamedModel, the white-box runs as one instance per distinct entry stage of
 * the terms ("parts"), each stepped with the terms that act from that stage on; every output is
 * read from the part of its stage.
 */
#ifndef GREYBOX_WHITEBOX_H
#define GREYBOX_WHITEBOX_H

#include <stddef.h>
#include <stdint.h>

#include "fmi2Functions.h"
#include "greybox_data.h"
#include "terms.h"

/* The white-box's fmi2 functions. */
typedef struct {
    void *library;
    fmi2InstantiateTYPE *instantiate;
    fmi2FreeInstanceTYPE *free_instance;
    fmi2SetupExperimentTYPE *setup_experiment;
    fmi2EnterInitializationModeTYPE *enter_initialization;
    fmi2ExitInitializationModeTYPE *exit_initialization;
    fmi2TerminateTYPE *terminate;
    fmi2ResetTYPE *reset;
    fmi2SetRealTYPE *set_real;
    fmi2GetRealTYPE *get_real;
    fmi2DoStepTYPE *do_step;
    fmi2GetFMUstateTYPE *get_state;
    fmi2SetFMUstateTYPE *set_state;
    fmi2FreeFMUstateTYPE *free_state;
    fmi2SerializedFMUstateSizeTYPE *state_size;
    fmi2SerializeFMUstateTYPE *serialize;
    fmi2DeSerializeFMUstateTYPE *deserialize;
} WbApi;

/* One white-box instance with the terms active from its entry stage on. */
typedef struct {
    fmi2Component component;
    char *name;
    ptrdiff_t n_columns, n_bound, n_params, n_terms;
    const int64_t *columns;       /* positions of its observed outputs among all outputs */
    fmi2ValueReference *bound_vr; /* observed outputs, then outputs the terms read */
    fmi2ValueReference *start_vr; /* parameters, then the inputs */
    double *start_values;         /* the parameters' values, then the inputs at the start */
    Term *terms;
    int substeps, plain;
    const char *failed_call; /* the fmi2 call that failed last, and its status */
    int failed_status;
    double time;
    double *current, *sensed; /* n_bound: outputs at the last (sub-)step, as the sensors see them */
    double *held, *row;       /* n_inputs: inputs after the terms of the step, of the sub-step */
} WbPart;

typedef struct {
    WbApi api;
    ptrdiff_t n_inputs, n_outputs, n_parts;
    fmi2ValueReference *input_vr;
    WbPart *parts;
    double dt;
    int started; /* the instances have been initialised (fmi2Reset needed before again) */
    void *tables; /* the data file's part and term tables, copied (whitebox.c) */
    void *(*allocate)(size_t, size_t);
    void (*release)(void *);
} Whitebox;

/* Load the white-box binary from resources_dir/whitebox/ (checking its SHA-256 against the
 * data file), resolve its functions and instantiate one instance per part, named after
 * instance_name. callbacks: what the white-box instances get (their logger forwards to the
 * master's). Returns 0, or -1 with a message; wb_close frees what was made either way. */
int wb_open(Whitebox *w, const GreyboxData *data, const char *resources_dir,
            const char *instance_name, const fmi2CallbackFunctions *callbacks, double dt,
            char *message, size_t size);

/* Initialise every instance at `time` with the inputs u (n_inputs) and the parts' parameters
 * (after fmi2Reset if they ran before); the terms start afresh. */
int wb_start(Whitebox *w, const double *u, double time, char *message, size_t size);

/* One communication step of dt with the inputs u (n_inputs). */
int wb_step(Whitebox *w, const double *u, char *message, size_t size);

/* The observed outputs now, into y (n_outputs). */
void wb_outputs(const Whitebox *w, double *y);

/* fmi2Terminate every initialised instance (they can be reset and started again). */
void wb_terminate(Whitebox *w);

void wb_close(Whitebox *w);

/* The white-box's part of an FMU state: per part the instance's own FMU state, its time,
 * outputs and terms' memory (wb_values doubles in values). */
ptrdiff_t wb_values(const Whitebox *w);
int wb_save(Whitebox *w, fmi2FMUstate *states, double *values, char *message, size_t size);
/* Whether values (wb_values doubles) are ones wb_save could have written at grey-box time
 * `time`: each part within a step of it, its outputs finite, its terms' memory whole
 * (term_memory_fault). Returns 0, or -1 with what is wrong (naming the part) in message. */
int wb_values_fault(const Whitebox *w, const double *values, double time, char *message,
                    size_t size);
int wb_restore(Whitebox *w, fmi2FMUstate *states, const double *values, char *message,
               size_t size);
void wb_free_states(Whitebox *w, fmi2FMUstate *states);
/* Serialised instance states: their sizes, the bytes, and back (states filled per part). */
int wb_serialized_size(Whitebox *w, fmi2FMUstate *states, size_t *sizes, char *message,
                       size_t size);
int wb_serialize(Whitebox *w, fmi2FMUstate *states, unsigned char *bytes, const size_t *sizes,
                 char *message, size_t size);
int wb_deserialize(Whitebox *w, const unsigned char *bytes, const size_t *sizes,
                   fmi2FMUstate *states, char *message, size_t size);

#endif /* GREYBOX_WHITEBOX_H */
