/*
 * fmi2_cosimulation.c -- the FMI 2.0 co-simulation API on top of the model interface.
 *
 * State machine of FMI 2.0 co-simulation: instantiated -> initialization mode -> step complete
 * -> terminated, with fmi2Reset back to instantiated from any phase and an error phase after a
 * failed call in which only getters, fmi2Reset and fmi2FreeInstance are allowed.
 *
 * Built with FW_MODEL_EXCHANGE (a model-exchange FMU), the FMI 2.0 model-exchange functions of
 * me/fmi2_model_exchange.c are compiled in as well (included at the end of this file): an
 * instance made with fmi2ModelExchange spends "step complete" in event mode or continuous-time
 * mode, and is stepped by the master's integrator instead of fmi2DoStep.
 *
 * The phases' table of allowed calls, the logging and error policy, the serialised state's
 * header and trailer, fmi2SetDebugLogging and the calls no FMU here supports are the shell's
 * (fmu_greybox/native/fmi2_shell.h), which the native grey-box FMU shares.
 */
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmi2_shell.h"
#include "fmu_framework.h"

/* Masks of the phases in which a call of model exchange is allowed (me/; the co-simulation
 * calls are the shell's table). */
#define IN(phase) SHELL_IN(phase)
#define MASK_GET SHELL_GETTABLE
#define MASK_FMU_STATE SHELL_ANY_PHASE

/* The framework's phases are the shell's (compile-time check). */
typedef char fw_phases_are_the_shells[((int)FW_INSTANTIATED == (int)SHELL_INSTANTIATED &&
                                       (int)FW_STEP_COMPLETE == (int)SHELL_STEP_COMPLETE &&
                                       (int)FW_ERROR == (int)SHELL_ERROR) ? 1 : -1];

/* Relative mismatch tolerated between the master's communication point and the FMU's time. */
#define TIME_TOLERANCE 1e-9

typedef struct {
    Shell shell; /* first: the shell's functions take the instance */
    SimData data;
#ifdef FW_MODEL_EXCHANGE
    int model_exchange;  /* instantiated as fmi2ModelExchange */
    int continuous_time; /* in continuous-time mode (else event mode), after initialisation */
    int projection_due;  /* a completed integrator step left states for the event to project */
#endif
} Instance;

#ifdef FW_MODEL_EXCHANGE
static fmi2Status me_get_real(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                              fmi2Real value[]);
#endif

/* Serialised FMU state (fmi2_shell.h): the shell's header (no parts, n_values the size of
 * SimData), the SimData bytes and the shell's SHA-256 trailer. Valid only for the binary that
 * wrote it (same GUID, same layout). */
#define STATE_SIZE shell_state_size(sizeof(SimData))

/* ------------------------------------------------------------------------------------------ */
/* Memory and logging                                                                          */
/* ------------------------------------------------------------------------------------------ */

static void *allocate(const Instance *inst, size_t size) {
    if (inst->shell.callbacks.allocateMemory) return inst->shell.callbacks.allocateMemory(1, size);
    return calloc(1, size);
}

static void release(const Instance *inst, void *pointer) {
    if (!pointer) return;
    if (inst->shell.callbacks.freeMemory) {
        inst->shell.callbacks.freeMemory(pointer);
    } else {
        free(pointer);
    }
}

/* Log "call failed: ..." as an error and return fmi2Error: a misuse (refuse: the phase does
 * not change) or a model or numerical failure (fail: the error phase). */
#define refuse(inst, ...) shell_refuse(&(inst)->shell, __VA_ARGS__)
#define fail(inst, call, ...) shell_fail(&(inst)->shell, &(inst)->data.phase, call, __VA_ARGS__)

/* The phase in words, as the instance's interface names it (model exchange: event mode or
 * continuous-time mode instead of step complete). */
static const char *phase_label(const Instance *inst) {
#ifdef FW_MODEL_EXCHANGE
    if (inst->model_exchange && inst->data.phase == FW_STEP_COMPLETE) {
        return inst->continuous_time ? "continuous-time mode" : "event mode";
    }
#endif
    return shell_phase_name(inst->data.phase);
}

/* Refuse a call outside its phases (the shell's table; allowed_in: a mask of model exchange).
 * Does not change the phase (a misuse is not a model error). */
static int allowed(const Instance *inst, ShellCall call) {
    return shell_allowed(&inst->shell, call, inst->data.phase, phase_label(inst));
}

#ifdef FW_MODEL_EXCHANGE
static int allowed_in(const Instance *inst, const char *call, unsigned mask) {
    return shell_allowed_in(&inst->shell, call, mask, inst->data.phase, phase_label(inst));
}
#endif

double shell_core_time(const Shell *shell) { return ((const Instance *)shell)->data.time; }

/* ------------------------------------------------------------------------------------------ */
/* Variables                                                                                   */
/* ------------------------------------------------------------------------------------------ */

static void load_start_values(SimData *d) {
    memset(d, 0, sizeof *d);
    d->phase = FW_INSTANTIATED;
    memcpy(d->real, fw_real_start, sizeof d->real);
    memcpy(d->integer, fw_integer_start, sizeof d->integer);
    memcpy(d->boolean, fw_boolean_start, sizeof d->boolean);
    for (int i = 0; i < N_STRING; i++) { /* memset above: the last byte stays the terminator */
        snprintf(d->string[i], FW_STRING_SIZE, "%s", fw_string_start[i]);
    }
    d->parameters_changed = 1;
}

/* Whether the parameters are valid (the framework's ranges first, then the model's check):
 * 0, or -1 with what is wrong in message. */
static int parameters_fault(const SimData *d, char *message, size_t size) {
    for (int vr = 0; vr < N_VALUE_REFERENCES; vr++) {
        const FwVariable *v = &fw_variables[vr];
        double value;
        if (v->type != FW_REAL || v->causality != FW_PARAMETER) continue;
        value = d->real[v->index];
        if (value < fw_real_min[v->index] || value > fw_real_max[v->index]) {
            snprintf(message, size, "%s = %g is outside its range [%g, %g].", v->name, value,
                     fw_real_min[v->index], fw_real_max[v->index]);
            return -1;
        }
    }
    if (!(d->real[FW_SOLVER_STEP] > 0.0)) {
        snprintf(message, size, "solver_step = %g s must be positive.", d->real[FW_SOLVER_STEP]);
        return -1;
    }
    return model_check(d, message, size);
}

/* Check the parameters if any changed. */
static fmi2Status check_parameters(Instance *inst, const char *call) {
    char message[512];
    SimData *d = &inst->data;
    if (!d->parameters_changed) return fmi2OK;
    if (parameters_fault(d, message, sizeof message) != 0) return fail(inst, call, "%s", message);
    d->parameters_changed = 0;
    return fmi2OK;
}

static void refresh_outputs(SimData *d) {
    if (d->outputs_valid) return;
    if (d->phase == FW_INITIALIZATION_MODE) model_initialize(d); /* initial unknowns */
    model_outputs(d);
    d->outputs_valid = 1;
}

/* The table row of vr if it is a variable of type `type`, else NULL (error logged). */
static const FwVariable *lookup(Instance *inst, const char *call, fmi2ValueReference vr, int type) {
    static const char *const type_names[] = {"absent", "Real", "Integer", "Boolean", "String"};
    if (vr >= N_VALUE_REFERENCES || fw_variables[vr].type == FW_ABSENT) {
        refuse(inst, call, "unknown value reference %u", (unsigned)vr);
        return NULL;
    }
    if (fw_variables[vr].type != type) {
        refuse(inst, call, "value reference %u (%s) is of type %s", (unsigned)vr,
               fw_variables[vr].name, type_names[fw_variables[vr].type]);
        return NULL;
    }
    return &fw_variables[vr];
}

/* May a variable be set in the current phase (FMI 2.0 co-simulation state table)? */
static int settable(Instance *inst, const char *call, const FwVariable *v) {
    const int phase = inst->data.phase;
    int ok = 0;
    if (phase == FW_INSTANTIATED || phase == FW_INITIALIZATION_MODE) {
        ok = v->causality == FW_PARAMETER || v->causality == FW_INPUT;
    } else if (phase == FW_STEP_COMPLETE) {
        ok = v->causality == FW_INPUT ||
             (v->causality == FW_PARAMETER && v->variability == FW_TUNABLE);
#ifdef FW_MODEL_EXCHANGE
        if (inst->model_exchange && inst->continuous_time) ok = v->causality == FW_INPUT;
#endif
    }
    if (!ok) {
        refuse(inst, call, "variable \"%s\" cannot be set in phase \"%s\"%s", v->name,
               phase_label(inst),
               phase == FW_STEP_COMPLETE ? " (only inputs and tunable parameters can)" : "");
    }
    return ok;
}

static void mark_set(SimData *d, const FwVariable *v) {
    d->outputs_valid = 0;
    if (v->causality == FW_PARAMETER) d->parameters_changed = 1;
}

/* ------------------------------------------------------------------------------------------ */
/* Inquire version numbers, logging                                                            */
/* ------------------------------------------------------------------------------------------ */

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    Instance probe; /* so that the checks below can log through the callbacks */
    Instance *inst;
    int model_exchange_too = 0;
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions) return NULL;
    memset(&probe, 0, sizeof probe);
    if (shell_open(&probe.shell, instanceName, functions, loggingOn) != 0) return NULL;
#ifdef FW_MODEL_EXCHANGE
    probe.model_exchange = fmuType == fmi2ModelExchange;
    model_exchange_too = 1;
#endif
    if (shell_instantiable(&probe.shell, fmuType, fmuGUID, MODEL_GUID, MODEL_IDENTIFIER_STRING,
                           model_exchange_too) != 0) {
        shell_close(&probe.shell);
        return NULL;
    }
    inst = (Instance *)allocate(&probe, sizeof *inst);
    if (!inst) {
        refuse(&probe, "fmi2Instantiate", "out of memory");
        shell_close(&probe.shell);
        return NULL;
    }
    *inst = probe;
    load_start_values(&inst->data);
    return inst;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst) return;
    shell_close(&inst->shell);
    release(inst, inst);
}

/* ------------------------------------------------------------------------------------------ */
/* Initialisation, termination, reset                                                          */
/* ------------------------------------------------------------------------------------------ */

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    Instance *inst = (Instance *)c;
    (void)toleranceDefined; /* fixed-step integration: the tolerance is not used */
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (!inst || !allowed(inst, CALL_SETUP_EXPERIMENT)) return fmi2Error;
    inst->data.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst || !allowed(inst, CALL_ENTER_INITIALIZATION_MODE)) return fmi2Error;
    inst->data.phase = FW_INITIALIZATION_MODE;
    inst->data.outputs_valid = 0;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst || !allowed(inst, CALL_EXIT_INITIALIZATION_MODE)) return fmi2Error;
    if (check_parameters(inst, "fmi2ExitInitializationMode") != fmi2OK) return fmi2Error;
    model_initialize(&inst->data);
    inst->data.phase = FW_STEP_COMPLETE; /* model exchange: event mode */
    inst->data.outputs_valid = 0;
#ifdef FW_MODEL_EXCHANGE
    inst->continuous_time = 0;
    inst->projection_due = 0;
#endif
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst || !allowed(inst, CALL_TERMINATE)) return fmi2Error;
    inst->data.phase = FW_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst) return fmi2Error;
    load_start_values(&inst->data);
    return fmi2OK;
}

/* ------------------------------------------------------------------------------------------ */
/* Getting and setting variable values                                                         */
/* ------------------------------------------------------------------------------------------ */

/* One value copied from the instance into the master's array (at index i), or from the
 * master's array into the instance; a write may refuse the value (it logs why). */
typedef void (*ReadValue)(const Instance *inst, const FwVariable *v, size_t i, void *values);
typedef fmi2Status (*WriteValue)(Instance *inst, const FwVariable *v, size_t i,
                                 const void *values);

static fmi2Status get_values(fmi2Component c, ShellCall get, const fmi2ValueReference vr[],
                             size_t nvr, int type, void *values, ReadValue read) {
    Instance *inst = (Instance *)c;
    const char *call = shell_call_name(get);
    if (!inst || !allowed(inst, get)) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        const FwVariable *v = lookup(inst, call, vr[i], type);
        if (!v) return fmi2Error;
        if (v->causality == FW_OUTPUT) refresh_outputs(&inst->data);
        read(inst, v, i, values);
    }
    return fmi2OK;
}

static fmi2Status set_values(fmi2Component c, ShellCall set, const fmi2ValueReference vr[],
                             size_t nvr, int type, const void *values, WriteValue write) {
    Instance *inst = (Instance *)c;
    const char *call = shell_call_name(set);
    if (!inst || !allowed(inst, set)) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        const FwVariable *v = lookup(inst, call, vr[i], type);
        if (!v || !settable(inst, call, v)) return fmi2Error;
        if (write(inst, v, i, values) != fmi2OK) return fmi2Error;
        mark_set(&inst->data, v);
    }
    return fmi2OK;
}

static void read_real(const Instance *inst, const FwVariable *v, size_t i, void *values) {
    ((fmi2Real *)values)[i] = inst->data.real[v->index];
}

static void read_integer(const Instance *inst, const FwVariable *v, size_t i, void *values) {
    ((fmi2Integer *)values)[i] = inst->data.integer[v->index];
}

static void read_boolean(const Instance *inst, const FwVariable *v, size_t i, void *values) {
    ((fmi2Boolean *)values)[i] = inst->data.boolean[v->index] ? fmi2True : fmi2False;
}

static void read_string(const Instance *inst, const FwVariable *v, size_t i, void *values) {
    ((fmi2String *)values)[i] = inst->data.string[v->index];
}

static fmi2Status write_real(Instance *inst, const FwVariable *v, size_t i, const void *values) {
    fmi2Real value = ((const fmi2Real *)values)[i];
    if (!isfinite(value)) {
        return refuse(inst, "fmi2SetReal", "%s = %g is not a finite number", v->name, value);
    }
    inst->data.real[v->index] = value;
    return fmi2OK;
}

static fmi2Status write_integer(Instance *inst, const FwVariable *v, size_t i, const void *values) {
    inst->data.integer[v->index] = ((const fmi2Integer *)values)[i];
    return fmi2OK;
}

static fmi2Status write_boolean(Instance *inst, const FwVariable *v, size_t i, const void *values) {
    inst->data.boolean[v->index] = ((const fmi2Boolean *)values)[i] ? 1 : 0;
    return fmi2OK;
}

static fmi2Status write_string(Instance *inst, const FwVariable *v, size_t i, const void *values) {
    fmi2String value = ((const fmi2String *)values)[i];
    if (!value || strlen(value) >= FW_STRING_SIZE) {
        return refuse(inst, "fmi2SetString", "%s must be a string of at most %d bytes", v->name,
                      FW_STRING_SIZE - 1);
    }
    strcpy(inst->data.string[v->index], value);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
#ifdef FW_MODEL_EXCHANGE
    for (size_t i = 0; i < nvr; i++) { /* states and derivatives: past the table */
        if (vr[i] >= N_VALUE_REFERENCES) return me_get_real(c, vr, nvr, value);
    }
#endif
    return get_values(c, CALL_GET_REAL, vr, nvr, FW_REAL, value, read_real);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    return get_values(c, CALL_GET_INTEGER, vr, nvr, FW_INTEGER, value, read_integer);
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    return get_values(c, CALL_GET_BOOLEAN, vr, nvr, FW_BOOLEAN, value, read_boolean);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    return get_values(c, CALL_GET_STRING, vr, nvr, FW_STRING, value, read_string);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    return set_values(c, CALL_SET_REAL, vr, nvr, FW_REAL, value, write_real);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    return set_values(c, CALL_SET_INTEGER, vr, nvr, FW_INTEGER, value, write_integer);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    return set_values(c, CALL_SET_BOOLEAN, vr, nvr, FW_BOOLEAN, value, write_boolean);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    return set_values(c, CALL_SET_STRING, vr, nvr, FW_STRING, value, write_string);
}

/* ------------------------------------------------------------------------------------------ */
/* FMU state: get, set, free, serialise                                                        */
/* ------------------------------------------------------------------------------------------ */

/* Whether d is a state this FMU could have saved: a phase, flags 0 or 1, time, Reals and
 * continuous states finite, Booleans 0 or 1, Strings ended within their capacity, parameters
 * valid once checked, the model's memory whole (model_check_memory). 0, or -1 with what is
 * wrong in message. */
static int state_fault(const SimData *d, char *message, size_t size) {
    if (d->phase < FW_INSTANTIATED || d->phase > FW_ERROR) {
        snprintf(message, size, "phase %d is none of %d to %d", d->phase, FW_INSTANTIATED,
                 FW_ERROR);
        return -1;
    }
    if ((d->parameters_changed | d->outputs_valid) & ~1) {
        snprintf(message, size, "a flag (parameters_changed %d, outputs_valid %d) is neither 0 "
                 "nor 1", d->parameters_changed, d->outputs_valid);
        return -1;
    }
    if (!isfinite(d->time)) {
        snprintf(message, size, "time = %g s is not finite", d->time);
        return -1;
    }
    for (int i = 0; i < N_REAL; i++) {
        if (!isfinite(d->real[i])) {
            snprintf(message, size, "Real %d = %g is not finite", i, d->real[i]);
            return -1;
        }
    }
    for (int i = 0; i < N_STATES; i++) {
        if (!isfinite(d->x[i])) {
            snprintf(message, size, "continuous state %d = %g is not finite", i, d->x[i]);
            return -1;
        }
    }
    for (int i = 0; i < N_BOOLEAN; i++) {
        if (d->boolean[i] & ~1) {
            snprintf(message, size, "Boolean %d = %d is neither 0 nor 1", i, d->boolean[i]);
            return -1;
        }
    }
    for (int i = 0; i < N_STRING; i++) {
        if (memchr(d->string[i], '\0', FW_STRING_SIZE) == NULL) {
            snprintf(message, size, "String %d has no end within %d bytes", i, FW_STRING_SIZE);
            return -1;
        }
    }
    if (!d->parameters_changed && parameters_fault(d, message, size) != 0) return -1;
#ifdef MODEL_HAS_MEMORY
    if (model_check_memory(d, message, size) != 0) return -1;
#endif
    return 0;
}

/* Refuse a state that state_fault finds wrong (the instance is unchanged). */
static fmi2Status check_state(Instance *inst, const char *call, const SimData *d) {
    char message[512];
    if (state_fault(d, message, sizeof message) == 0) return fmi2OK;
    return refuse(inst, call, "%s; not a state this FMU saved (damaged or forged): restore one "
                  "it saved.", message);
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Instance *inst = (Instance *)c;
    if (!inst || !allowed(inst, CALL_GET_FMU_STATE)) return fmi2Error;
    if (!*FMUstate) {
        *FMUstate = allocate(inst, sizeof(SimData));
        if (!*FMUstate) return fail(inst, "fmi2GetFMUstate", "out of memory.");
    }
    memcpy(*FMUstate, &inst->data, sizeof(SimData));
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    Instance *inst = (Instance *)c;
    if (!inst || !allowed(inst, CALL_SET_FMU_STATE)) return fmi2Error;
    if (!FMUstate) return refuse(inst, "fmi2SetFMUstate", "the FMU state is NULL.");
    if (check_state(inst, "fmi2SetFMUstate", FMUstate) != fmi2OK) return fmi2Error;
    memcpy(&inst->data, FMUstate, sizeof(SimData));
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Instance *inst = (Instance *)c;
    if (!inst) return fmi2Error;
    if (FMUstate && *FMUstate) {
        release(inst, *FMUstate);
        *FMUstate = NULL;
    }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    Instance *inst = (Instance *)c;
    (void)FMUstate;
    if (!inst) return fmi2Error;
    *size = STATE_SIZE;
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    Instance *inst = (Instance *)c;
    unsigned char *bytes = (unsigned char *)serializedState;
    if (!inst) return fmi2Error;
    if (!FMUstate) return refuse(inst, "fmi2SerializeFMUstate", "the FMU state is NULL");
    if (size < STATE_SIZE) {
        return refuse(inst, "fmi2SerializeFMUstate", "a buffer of %zu bytes is too small (%zu "
                      "needed)", size, STATE_SIZE);
    }
    shell_state_begin(bytes, MODEL_GUID, 0, sizeof(SimData));
    memcpy(bytes + sizeof(ShellStateHeader), FMUstate, sizeof(SimData));
    shell_state_seal(bytes, STATE_SIZE);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    static const char *const call = "fmi2DeSerializeFMUstate";
    Instance *inst = (Instance *)c;
    const unsigned char *bytes = (const unsigned char *)serializedState;
    ShellStateHeader header;
    SimData *data;
    if (!inst) return fmi2Error;
    if (shell_state_open(&inst->shell, call, bytes, size, MODEL_GUID, &header) != 0) {
        return fmi2Error;
    }
    if (size != STATE_SIZE || header.n_parts != 0 || header.n_values != sizeof(SimData)) {
        return refuse(inst, call, "%zu bytes given, a state of this FMU has %zu", size,
                      STATE_SIZE);
    }
    data = allocate(inst, sizeof(SimData)); /* not on the stack: a model's memory may be large */
    if (!data) return fail(inst, call, "out of memory");
    memcpy(data, bytes + sizeof header, sizeof(SimData));
    if (check_state(inst, call, data) != fmi2OK) {
        release(inst, data);
        return fmi2Error;
    }
    if (*FMUstate) {
        memcpy(*FMUstate, data, sizeof(SimData));
        release(inst, data);
    } else {
        *FMUstate = data;
    }
    return fmi2OK;
}

/* ------------------------------------------------------------------------------------------ */
/* Stepping                                                                                    */
/* ------------------------------------------------------------------------------------------ */

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    static const char *const call = "fmi2DoStep";
    Instance *inst = (Instance *)c;
    SimData *d;
    char message[512];
    const double t0 = currentCommunicationPoint;
    const double h = communicationStepSize;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!inst || !allowed(inst, CALL_DO_STEP)) return fmi2Error;
#ifdef FW_MODEL_EXCHANGE
    if (inst->model_exchange) {
        return refuse(inst, call, "the instance was made for model exchange: the master's "
                      "integrator advances it (fmi2SetTime, fmi2SetContinuousStates, "
                      "fmi2GetDerivatives).");
    }
#endif
    d = &inst->data;

    if (!(h > 0.0) || !isfinite(h)) {
        return refuse(inst, call, "communicationStepSize = %g s must be positive.", h);
    }
    if (fabs(t0 - d->time) > TIME_TOLERANCE * fmax(1.0, fabs(t0))) {
        return refuse(inst, call,
                    "currentCommunicationPoint = %.17g s but the FMU is at %.17g s; restore an "
                    "FMU state to step from another time.", t0, d->time);
    }
    if (check_parameters(inst, call) != fmi2OK) return fmi2Error;

    {
        /* n equal internal steps no longer than solver_step (1e-9: h/solver_step may round up). */
        const double n_real = ceil(h / d->real[FW_SOLVER_STEP] - 1e-9);
        const long n = n_real < 1.0 ? 1 : (long)n_real;
        const double hs = h / (double)n;
        FwIteration iteration = {.fresh = 1};
        for (long k = 1; k <= n; k++) {
            if (fw_rosenbrock_step(d, d->x, hs, &iteration) != 0) {
                return fail(inst, call, "singular iteration matrix at t = %.9g s; reduce "
                            "solver_step or check the parameters.", d->time);
            }
            model_project(d, d->x);
            d->time = k == n ? t0 + h : t0 + (double)k * hs;
            if (model_after_step(d, message, sizeof message) != 0) {
                return fail(inst, call, "at t = %.9g s: %s", d->time, message);
            }
        }
    }
    for (int i = 0; i < N_STATES; i++) {
        if (!isfinite(d->x[i])) {
            return fail(inst, call, "state %d became %g at t = %.9g s; reduce solver_step or "
                        "check the parameters and inputs.", i, d->x[i], d->time);
        }
    }
    d->outputs_valid = 0;
    return fmi2OK;
}

#ifdef FW_MODEL_EXCHANGE
#include "me/fmi2_model_exchange.c"
#endif
