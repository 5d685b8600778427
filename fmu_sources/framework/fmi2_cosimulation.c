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
 */
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmu_framework.h"
#include "sha256.h"

/* The log category declared in modelDescription.xml: every message is an error saying what
 * failed and how to mend it. */
#define LOG_CATEGORY "logStatusError"

/* Masks of the phases in which a call is allowed. */
#define IN(phase) (1u << (phase))
#define MASK_GET \
    (IN(FW_INITIALIZATION_MODE) | IN(FW_STEP_COMPLETE) | IN(FW_TERMINATED) | IN(FW_ERROR))
#define MASK_FMU_STATE (IN(FW_INSTANTIATED) | MASK_GET)

/* Relative mismatch tolerated between the master's communication point and the FMU's time. */
#define TIME_TOLERANCE 1e-9

typedef struct {
    char *name;
    fmi2CallbackFunctions callbacks;
    int logging; /* errors are logged unless switched off with fmi2SetDebugLogging */
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

/* Serialised FMU state: this header, the SimData bytes, and the SHA-256 of both as 64 hex
 * digits (STATE_DIGEST). Valid only for the binary that wrote it (same GUID, same layout). */
#define STATE_MAGIC "FGBXST02"
#define STATE_DIGEST 64
typedef struct {
    char magic[8];
    char guid[48];
    uint64_t data_size;
} StateHeader;

/* ------------------------------------------------------------------------------------------ */
/* Memory and logging                                                                          */
/* ------------------------------------------------------------------------------------------ */

static void *allocate(const Instance *inst, size_t size) {
    if (inst->callbacks.allocateMemory) return inst->callbacks.allocateMemory(1, size);
    return calloc(1, size);
}

static void release(const Instance *inst, void *pointer) {
    if (!pointer) return;
    if (inst->callbacks.freeMemory) {
        inst->callbacks.freeMemory(pointer);
    } else {
        free(pointer);
    }
}

static void log_message(const Instance *inst, fmi2Status status, const char *format, ...) {
    char message[1024];
    va_list args;
    if (!inst->callbacks.logger || !inst->logging) return;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    inst->callbacks.logger(inst->callbacks.componentEnvironment, inst->name, status,
                           LOG_CATEGORY, message);
}

/* Log a refused call (a misuse, not a model failure: the phase does not change). */
static fmi2Status refuse(Instance *inst, const char *call, const char *format, ...) {
    char detail[900];
    va_list args;
    va_start(args, format);
    vsnprintf(detail, sizeof detail, format, args);
    va_end(args);
    log_message(inst, fmi2Error, "%s: %s", call, detail);
    return fmi2Error;
}

/* Log a model or numerical failure, move to the error phase and return fmi2Error. */
static fmi2Status fail(Instance *inst, const char *call, const char *format, ...) {
    char detail[900];
    va_list args;
    va_start(args, format);
    vsnprintf(detail, sizeof detail, format, args);
    va_end(args);
    log_message(inst, fmi2Error, "%s: %s", call, detail);
    inst->data.phase = FW_ERROR;
    return fmi2Error;
}

static const char *phase_name(int phase) {
    switch (phase) {
        case FW_INSTANTIATED: return "instantiated";
        case FW_INITIALIZATION_MODE: return "initialization mode";
        case FW_STEP_COMPLETE: return "step complete";
        case FW_TERMINATED: return "terminated";
        default: return "error";
    }
}

/* The phase in words, as the instance's interface names it (model exchange: event mode or
 * continuous-time mode instead of step complete). */
static const char *phase_label(const Instance *inst) {
#ifdef FW_MODEL_EXCHANGE
    if (inst->model_exchange && inst->data.phase == FW_STEP_COMPLETE) {
        return inst->continuous_time ? "continuous-time mode" : "event mode";
    }
#endif
    return phase_name(inst->data.phase);
}

/* Refuse a call outside its phases. Does not change the phase (a misuse is not a model error). */
static int allowed(Instance *inst, const char *call, unsigned mask) {
    if (mask & IN(inst->data.phase)) return 1;
    log_message(inst, fmi2Error, "%s is not allowed in phase \"%s\".", call, phase_label(inst));
    return 0;
}

/* ------------------------------------------------------------------------------------------ */
/* Variables                                                                                   */
/* ------------------------------------------------------------------------------------------ */

static void load_start_values(SimData *d) {
    memset(d, 0, sizeof *d);
    d->phase = FW_INSTANTIATED;
    memcpy(d->real, fw_real_start, sizeof d->real);
    memcpy(d->integer, fw_integer_start, sizeof d->integer);
    memcpy(d->boolean, fw_boolean_start, sizeof d->boolean);
    for (int i = 0; i < N_STRING; i++) {
        strncpy(d->string[i], fw_string_start[i], FW_STRING_SIZE - 1);
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
        log_message(inst, fmi2Error, "%s: unknown value reference %u.", call, (unsigned)vr);
        return NULL;
    }
    if (fw_variables[vr].type != type) {
        log_message(inst, fmi2Error, "%s: value reference %u (%s) is of type %s.", call,
                    (unsigned)vr, fw_variables[vr].name, type_names[fw_variables[vr].type]);
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
        log_message(inst, fmi2Error, "%s: variable \"%s\" cannot be set in phase \"%s\"%s.", call,
                    v->name, phase_label(inst),
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

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    Instance *inst = (Instance *)c;
    if (!inst) return fmi2Error;
    for (size_t i = 0; i < nCategories; i++) {
        if (!categories[i] || strcmp(categories[i], LOG_CATEGORY) != 0) {
            log_message(inst, fmi2Error, "fmi2SetDebugLogging: unknown log category \"%s\"; "
                        "the only one is \"" LOG_CATEGORY "\".",
                        categories[i] ? categories[i] : "(null)");
            return fmi2Error;
        }
    }
    inst->logging = loggingOn ? 1 : 0;
    return fmi2OK;
}

/* ------------------------------------------------------------------------------------------ */
/* Creation and destruction                                                                    */
/* ------------------------------------------------------------------------------------------ */

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    Instance probe;
    Instance *inst;
    const char *name = instanceName ? instanceName : "";
    (void)fmuResourceLocation;
    (void)visible;
    (void)loggingOn; /* errors are logged unless fmi2SetDebugLogging switches them off */
    if (!functions) return NULL;

    /* A temporary instance so that the checks below can log through the callbacks. */
    memset(&probe, 0, sizeof probe);
    probe.name = (char *)name;
    probe.callbacks = *functions;
    probe.logging = 1;
#ifdef FW_MODEL_EXCHANGE
    probe.model_exchange = fmuType == fmi2ModelExchange;
    if (fmuType != fmi2CoSimulation && fmuType != fmi2ModelExchange) {
        log_message(&probe, fmi2Error, "fmi2Instantiate: %s supports model exchange and "
                    "co-simulation only.", MODEL_IDENTIFIER_STRING);
        return NULL;
    }
#else
    if (fmuType != fmi2CoSimulation) {
        log_message(&probe, fmi2Error, "fmi2Instantiate: %s supports co-simulation only.",
                    MODEL_IDENTIFIER_STRING);
        return NULL;
    }
#endif
    if (!fmuGUID || strcmp(fmuGUID, MODEL_GUID) != 0) {
        log_message(&probe, fmi2Error,
                    "fmi2Instantiate: GUID \"%s\" does not match the binary's \"%s\"; the "
                    "modelDescription.xml belongs to another build.",
                    fmuGUID ? fmuGUID : "(null)", MODEL_GUID);
        return NULL;
    }

    inst = (Instance *)allocate(&probe, sizeof *inst);
    if (!inst) {
        log_message(&probe, fmi2Fatal, "fmi2Instantiate: out of memory.");
        return NULL;
    }
    *inst = probe;
    inst->name = (char *)allocate(&probe, strlen(name) + 1);
    if (!inst->name) {
        release(&probe, inst);
        log_message(&probe, fmi2Fatal, "fmi2Instantiate: out of memory.");
        return NULL;
    }
    strcpy(inst->name, name);
    load_start_values(&inst->data);
    return inst;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst) return;
    release(inst, inst->name);
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
    if (!inst || !allowed(inst, "fmi2SetupExperiment", IN(FW_INSTANTIATED))) return fmi2Error;
    inst->data.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst || !allowed(inst, "fmi2EnterInitializationMode", IN(FW_INSTANTIATED))) {
        return fmi2Error;
    }
    inst->data.phase = FW_INITIALIZATION_MODE;
    inst->data.outputs_valid = 0;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Instance *inst = (Instance *)c;
    if (!inst || !allowed(inst, "fmi2ExitInitializationMode", IN(FW_INITIALIZATION_MODE))) {
        return fmi2Error;
    }
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
    if (!inst || !allowed(inst, "fmi2Terminate", IN(FW_STEP_COMPLETE))) return fmi2Error;
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

static fmi2Status get_values(fmi2Component c, const char *call, const fmi2ValueReference vr[],
                             size_t nvr, int type, void *values, ReadValue read) {
    Instance *inst = (Instance *)c;
    if (!inst || !allowed(inst, call, MASK_GET)) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        const FwVariable *v = lookup(inst, call, vr[i], type);
        if (!v) return fmi2Error;
        if (v->causality == FW_OUTPUT) refresh_outputs(&inst->data);
        read(inst, v, i, values);
    }
    return fmi2OK;
}

static fmi2Status set_values(fmi2Component c, const char *call, const fmi2ValueReference vr[],
                             size_t nvr, int type, const void *values, WriteValue write) {
    Instance *inst = (Instance *)c;
    if (!inst) return fmi2Error;
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
        log_message(inst, fmi2Error, "fmi2SetReal: %s = %g is not a finite number.", v->name,
                    value);
        return fmi2Error;
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
        log_message(inst, fmi2Error, "fmi2SetString: %s must be a string of at most %d bytes.",
                    v->name, FW_STRING_SIZE - 1);
        return fmi2Error;
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
    return get_values(c, "fmi2GetReal", vr, nvr, FW_REAL, value, read_real);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    return get_values(c, "fmi2GetInteger", vr, nvr, FW_INTEGER, value, read_integer);
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    return get_values(c, "fmi2GetBoolean", vr, nvr, FW_BOOLEAN, value, read_boolean);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    return get_values(c, "fmi2GetString", vr, nvr, FW_STRING, value, read_string);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    return set_values(c, "fmi2SetReal", vr, nvr, FW_REAL, value, write_real);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    return set_values(c, "fmi2SetInteger", vr, nvr, FW_INTEGER, value, write_integer);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    return set_values(c, "fmi2SetBoolean", vr, nvr, FW_BOOLEAN, value, write_boolean);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    return set_values(c, "fmi2SetString", vr, nvr, FW_STRING, value, write_string);
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
    if (!inst || !allowed(inst, "fmi2GetFMUstate", MASK_FMU_STATE)) return fmi2Error;
    if (!*FMUstate) {
        *FMUstate = allocate(inst, sizeof(SimData));
        if (!*FMUstate) return fail(inst, "fmi2GetFMUstate", "out of memory.");
    }
    memcpy(*FMUstate, &inst->data, sizeof(SimData));
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    Instance *inst = (Instance *)c;
    if (!inst || !allowed(inst, "fmi2SetFMUstate", MASK_FMU_STATE)) return fmi2Error;
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
    *size = sizeof(StateHeader) + sizeof(SimData) + STATE_DIGEST;
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    Instance *inst = (Instance *)c;
    StateHeader header;
    char digest[65];
    if (!inst) return fmi2Error;
    if (!FMUstate) return refuse(inst, "fmi2SerializeFMUstate", "the FMU state is NULL.");
    if (size < sizeof header + sizeof(SimData) + STATE_DIGEST) {
        return refuse(inst, "fmi2SerializeFMUstate", "buffer of %zu bytes is too small (need %zu).",
                    size, sizeof header + sizeof(SimData) + STATE_DIGEST);
    }
    memset(&header, 0, sizeof header);
    memcpy(header.magic, STATE_MAGIC, sizeof header.magic);
    strncpy(header.guid, MODEL_GUID, sizeof header.guid - 1);
    header.data_size = sizeof(SimData);
    memcpy(serializedState, &header, sizeof header);
    memcpy(serializedState + sizeof header, FMUstate, sizeof(SimData));
    sha256_bytes(serializedState, sizeof header + sizeof(SimData), digest);
    memcpy(serializedState + sizeof header + sizeof(SimData), digest, STATE_DIGEST);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    Instance *inst = (Instance *)c;
    StateHeader header;
    SimData *data;
    char digest[65];
    static const char *const call = "fmi2DeSerializeFMUstate";
    if (!inst) return fmi2Error;
    if (size != sizeof header + sizeof(SimData) + STATE_DIGEST) {
        return refuse(inst, call, "%zu bytes given, a state of this FMU has %zu.", size,
                    sizeof header + sizeof(SimData) + STATE_DIGEST);
    }
    sha256_bytes(serializedState, sizeof header + sizeof(SimData), digest);
    if (memcmp(digest, serializedState + sizeof header + sizeof(SimData), STATE_DIGEST) != 0) {
        return refuse(inst, call, "the state's bytes do not match their SHA-256: they were "
                      "damaged or edited after fmi2SerializeFMUstate wrote them; restore an "
                      "undamaged copy.");
    }
    memcpy(&header, serializedState, sizeof header);
    if (memcmp(header.magic, STATE_MAGIC, sizeof header.magic) != 0 ||
        header.data_size != sizeof(SimData)) {
        return refuse(inst, call, "the bytes are not a serialised state of this FMU.");
    }
    if (strncmp(header.guid, MODEL_GUID, sizeof header.guid) != 0) {
        return refuse(inst, call, "the state was written by another FMU (GUID %.40s).",
                      header.guid);
    }
    data = allocate(inst, sizeof(SimData)); /* not on the stack: a model's memory may be large */
    if (!data) return fail(inst, call, "out of memory.");
    memcpy(data, serializedState + sizeof header, sizeof(SimData));
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
/* Capabilities this FMU does not declare (modelDescription.xml sets them false)                */
/* ------------------------------------------------------------------------------------------ */

static fmi2Status unsupported(fmi2Component c, const char *call) {
    Instance *inst = (Instance *)c;
    if (inst) log_message(inst, fmi2Error, "%s is not supported by this FMU.", call);
    return fmi2Error;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown,
        (void)dvUnknown;
    return unsupported(c, "fmi2GetDirectionalDerivative");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    return unsupported(c, "fmi2SetRealInputDerivatives (canInterpolateInputs is false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    return unsupported(c, "fmi2GetRealOutputDerivatives (maxOutputDerivativeOrder is 0)");
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    return unsupported(c, "fmi2CancelStep (steps are never asynchronous)");
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
    if (!inst || !allowed(inst, call, IN(FW_STEP_COMPLETE))) return fmi2Error;
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
        for (long k = 1; k <= n; k++) {
            if (fw_rosenbrock_step(d, d->x, hs) != 0) {
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

/* ------------------------------------------------------------------------------------------ */
/* Status inquiry (steps are synchronous: only the last successful time is of interest)        */
/* ------------------------------------------------------------------------------------------ */

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s, (void)value;
    return unsupported(c, "fmi2GetStatus (steps are never asynchronous)");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    Instance *inst = (Instance *)c;
    if (!inst || s != fmi2LastSuccessfulTime) return unsupported(c, "fmi2GetRealStatus");
    *value = inst->data.time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s, (void)value;
    return unsupported(c, "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    Instance *inst = (Instance *)c;
    if (!inst || s != fmi2Terminated) return unsupported(c, "fmi2GetBooleanStatus");
    *value = fmi2False; /* the FMU never asks the master to stop */
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s, (void)value;
    return unsupported(c, "fmi2GetStringStatus");
}

#ifdef FW_MODEL_EXCHANGE
#include "me/fmi2_model_exchange.c"
#endif
