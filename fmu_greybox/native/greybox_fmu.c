/*
 * greybox_fmu.c -- the FMI 2.0 co-simulation functions of a native grey-box FMU.
 *
 * Each fmi2DoStep does what fmu_greybox/export/slave.py (the Python runtime) does for one row:
 * step the embedded white-box with its named terms (whitebox.c), then the corrector chain
 * (chain_core.c, the code the Python runtime runs too), and publish the corrected outputs,
 * their standard deviations, the white-box outputs and the out-of-domain score. The trained
 * numbers come from resources/greybox.dat (greybox_data.h), checked against the SHA-256
 * compiled in (greybox_config.h, generated at export). What a step must satisfy, and the words
 * of each refusal, are rules.c's: the Python runtime refuses with the same functions.
 *
 * The phases, the table of calls allowed in each, the logging and error policy (every error to
 * the master's logger whatever the logging level, answered with fmi2Error; nothing here aborts
 * the process), the serialised state's header and the unsupported calls are the shell's
 * (fmi2_shell.h), which the reference FMUs share. An instance holds all its data: several
 * instances run side by side in one process.
 */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "chain_core.h"
#include "fmi2Functions.h"
#include "fmi2_shell.h"
#include "greybox_config.h"
#include "greybox_data.h"
#include "rules.h"
#include "sha256.h"
#include "whitebox.h"

#define MESSAGE_SIZE 1024

typedef struct {
    Shell shell;                     /* first: the shell's functions take the instance */
    fmi2CallbackFunctions forwarded; /* what the white-box gets: its logger forwards to ours */
    int phase;                       /* ShellPhase */
    /* the chain (chain_core.h) */
    ChainSizes sizes;
    int64_t *plan;
    double *params, *params_block, *work, *chain;
    /* the interface: reals = inputs, outputs, stds, white-box outputs, score, threshold;
     * booleans = out_of_domain, correction_enabled */
    ptrdiff_t n_inputs, n_outputs, n_stages, n_exo, n_reals;
    int64_t *stage_output, *exo_index;
    double *input_low, *input_high, *input_start;
    char **input_names;
    double dt, step_tolerance, threshold_start;
    double *reals, *started_with, *y, *y_wb, *exo;
    fmi2Boolean out_of_domain, correction_enabled;
    int running;
    double time;
    Whitebox wb;
} Instance;

/* ------------------------------------------------------------------ logging */

/* Log "call failed: message" as an error and return fmi2Error (the phase does not change). */
#define refuse(inst, ...) shell_refuse(&(inst)->shell, __VA_ARGS__)

/* refuse, and the instance goes into the error phase (a failure, not a misuse). */
static fmi2Status fail(Instance *inst, const char *call, const char *detail) {
    return shell_fail(&inst->shell, &inst->phase, call, "%s", detail);
}

/* The white-box's logger: its messages go to the master's, under the white-box's name. */
static void forward(fmi2ComponentEnvironment environment, fmi2String name, fmi2Status status,
                    fmi2String category, fmi2String message, ...) {
    const Instance *inst = environment;
    char text[MESSAGE_SIZE];
    va_list args;
    if (inst == NULL || inst->shell.callbacks.logger == NULL) return;
    if (status < fmi2Error && !inst->shell.logging) return;
    va_start(args, message);
    vsnprintf(text, sizeof text, message, args);
    va_end(args);
    inst->shell.callbacks.logger(inst->shell.callbacks.componentEnvironment, name, status,
                                 category, "%s", text);
}

static int allowed(const Instance *inst, ShellCall call) {
    return shell_allowed(&inst->shell, call, inst->phase, NULL);
}

double shell_core_time(const Shell *shell) { return ((const Instance *)shell)->time; }

/* ------------------------------------------------------------------ loading */

static void *table(ptrdiff_t n, size_t item) { return calloc((size_t)(n > 0 ? n : 1), item); }

/* A section copied into new memory, or NULL (message set). */
static void *section_copy(const GreyboxData *d, const char *name, int type, ptrdiff_t count,
                          char *message) {
    const DataSection *s = data_section(d, name, type, count, message, MESSAGE_SIZE);
    void *out = s != NULL ? data_copy(s, calloc) : NULL;
    if (s != NULL && out == NULL) snprintf(message, MESSAGE_SIZE, "out of memory");
    return out;
}

/* The input names: the section's text, one name per line. */
static int read_names(Instance *inst, const GreyboxData *d, char *message) {
    const DataSection *s = data_section(d, "input_names", DATA_BYTES, -1, message, MESSAGE_SIZE);
    const char *at, *end;
    if (s == NULL) return -1;
    inst->input_names = table(inst->n_inputs, sizeof(char *));
    if (inst->input_names == NULL) return -1;
    at = (const char *)s->data;
    end = at + s->count;
    for (ptrdiff_t i = 0; i < inst->n_inputs; i++) {
        const char *stop = memchr(at, '\n', (size_t)(end - at));
        const size_t n = (size_t)((stop != NULL ? stop : end) - at);
        inst->input_names[i] = calloc(n + 1, 1);
        if (inst->input_names[i] == NULL) return -1;
        memcpy(inst->input_names[i], at, n);
        at = stop != NULL ? stop + 1 : end;
    }
    return 0;
}

/* The chain's arrays: plan, parameters on a cache-line boundary, scratch and state. */
static int load_chain(Instance *inst, const GreyboxData *d, char *message) {
    const DataSection *plan = data_section(d, "plan", DATA_INT64, -1, message, MESSAGE_SIZE);
    const DataSection *params;
    if (plan == NULL) return -1;
    inst->plan = section_copy(d, "plan", DATA_INT64, -1, message);
    if (inst->plan == NULL) return -1;
    if (chain_plan_sizes(inst->plan, plan->count, &inst->sizes, message, MESSAGE_SIZE) != 0) {
        return -1;
    }
    params = data_section(d, "params", DATA_FLOAT64, inst->sizes.params, message, MESSAGE_SIZE);
    if (params == NULL) return -1;
    inst->params_block = table(inst->sizes.params + 8, sizeof(double));
    inst->work = table(inst->sizes.work, sizeof(double));
    inst->chain = table(inst->sizes.state, sizeof(double));
    if (!inst->params_block || !inst->work || !inst->chain) {
        snprintf(message, MESSAGE_SIZE, "out of memory");
        return -1;
    }
    inst->params = inst->params_block + (8 - ((uintptr_t)inst->params_block / 8) % 8) % 8;
    data_float64s(params, inst->params);
    return 0;
}

/* The interface's sizes and tables. */
static int load_interface(Instance *inst, const GreyboxData *d, char *message) {
    const DataSection *sizes = data_section(d, "sizes", DATA_INT64, 6, message, MESSAGE_SIZE);
    double *settings;
    int64_t n[6];
    if (sizes == NULL) return -1;
    data_int64s(sizes, n);
    inst->n_inputs = n[0];
    inst->n_outputs = n[1];
    inst->n_stages = n[2];
    inst->n_exo = n[3];
    if (inst->n_stages != inst->sizes.n_stages || inst->n_exo != inst->sizes.n_exo) {
        snprintf(message, MESSAGE_SIZE, "the data file's interface does not fit its plan; "
                 "export the FMU again");
        return -1;
    }
    inst->n_reals = inst->n_inputs + inst->n_outputs + 2 * inst->n_stages + 2;
    inst->stage_output = section_copy(d, "stage_output", DATA_INT64, inst->n_stages, message);
    inst->exo_index = section_copy(d, "exo_index", DATA_INT64, inst->n_exo, message);
    inst->input_start = section_copy(d, "input_start", DATA_FLOAT64, inst->n_inputs, message);
    inst->input_low = section_copy(d, "input_low", DATA_FLOAT64, inst->n_inputs, message);
    inst->input_high = section_copy(d, "input_high", DATA_FLOAT64, inst->n_inputs, message);
    settings = section_copy(d, "settings", DATA_FLOAT64, 3, message);
    if (!inst->stage_output || !inst->exo_index || !inst->input_start || !inst->input_low ||
        !inst->input_high || !settings || read_names(inst, d, message) != 0) {
        free(settings);
        return -1;
    }
    inst->dt = settings[0];
    inst->threshold_start = settings[1];
    inst->step_tolerance = settings[2] * settings[0];
    free(settings);
    inst->reals = table(inst->n_reals, sizeof(double));
    inst->started_with = table(inst->n_inputs, sizeof(double));
    inst->y = table(inst->n_outputs, sizeof(double));
    inst->y_wb = table(inst->n_stages, sizeof(double));
    inst->exo = table(inst->n_exo, sizeof(double));
    if (!inst->reals || !inst->started_with || !inst->y || !inst->y_wb || !inst->exo) {
        snprintf(message, MESSAGE_SIZE, "out of memory");
        return -1;
    }
    return 0;
}

/* The start values of every variable (after fmi2Instantiate and fmi2Reset). */
static void load_start_values(Instance *inst) {
    memset(inst->reals, 0, (size_t)inst->n_reals * sizeof(double));
    memcpy(inst->reals, inst->input_start, (size_t)inst->n_inputs * sizeof(double));
    inst->reals[inst->n_reals - 1] = inst->threshold_start;
    inst->out_of_domain = fmi2False;
    inst->correction_enabled = fmi2True;
    inst->running = 0;
    inst->time = 0.0;
    inst->phase = SHELL_INSTANTIATED;
}

/* The resources folder, into path: from a file: URI (FMI 2.0, percent-escapes decoded) or a
 * path (FMI 3.0's resourcePath, through the FMI 3.0 face, taken as it is). */
static int uri_folder(const char *uri, char *path, size_t size) {
    const char *at = uri;
    size_t n = 0;
    int escaped = 1;
    if (strncmp(at, "file://localhost/", 17) == 0) {
        at += 16;
    } else if (strncmp(at, "file://", 7) == 0) {
        at += 7;
    } else if (strncmp(at, "file:", 5) == 0) {
        at += 5;
    } else if (*at != '\0') {
        escaped = 0;
    } else {
        return -1;
    }
    for (; *at != '\0' && n + 1 < size; at++) {
        unsigned code;
        if (escaped && at[0] == '%' && sscanf(at + 1, "%2x", &code) == 1) {
            path[n++] = (char)code;
            at += 2;
        } else {
            path[n++] = *at;
        }
    }
    while (n > 1 && path[n - 1] == '/') n--;
    path[n] = '\0';
#if defined(_WIN32)
    if (n > 2 && path[0] == '/' && path[2] == ':') memmove(path, path + 1, n); /* /C:/x -> C:/x */
#endif
    return *at == '\0' ? 0 : -1;
}

static void free_instance(Instance *inst) {
    wb_close(&inst->wb);
    if (inst->input_names != NULL) {
        for (ptrdiff_t i = 0; i < inst->n_inputs; i++) free(inst->input_names[i]);
    }
    shell_close(&inst->shell);
    void *owned[] = {inst->plan,         inst->params_block, inst->work,
                     inst->chain,      inst->stage_output, inst->exo_index,    inst->input_low,
                     inst->input_high, inst->input_start,  inst->input_names,  inst->reals,
                     inst->started_with, inst->y,          inst->y_wb,         inst->exo};
    for (size_t i = 0; i < sizeof owned / sizeof owned[0]; i++) free(owned[i]);
    free(inst);
}

/* Everything fmi2Instantiate reads and checks, for an allocated instance. */
static int load(Instance *inst, const char *location, char *message) {
    char resources[4096], path[4200];
    GreyboxData data;
    int status;
    if (location == NULL || uri_folder(location, resources, sizeof resources) != 0) {
        snprintf(message, MESSAGE_SIZE, "fmuResourceLocation \"%s\" is neither a file: URI nor "
                 "a path of the FMU's resources folder", location != NULL ? location : "(null)");
        return -1;
    }
    snprintf(path, sizeof path, "%s/" GREYBOX_DATA_FILE, resources);
    status = data_read(&data, path, GREYBOX_DATA_SHA256, calloc, message, MESSAGE_SIZE);
    if (status == 0) status = load_chain(inst, &data, message);
    if (status == 0) status = load_interface(inst, &data, message);
    if (status == 0) {
        inst->wb.allocate = calloc;
        inst->wb.release = free;
        status = wb_open(&inst->wb, &data, resources, inst->shell.name, &inst->forwarded, inst->dt,
                         message, MESSAGE_SIZE);
    }
    data_free(&data, free);
    return status;
}

/* ------------------------------------------------------------------ FMI: set-up */

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    char message[MESSAGE_SIZE];
    Instance *inst;
    (void)visible;
    if (functions == NULL) return NULL;
    inst = calloc(1, sizeof *inst);
    if (inst == NULL) return NULL;
    if (shell_open(&inst->shell, instanceName, functions, loggingOn) != 0) {
        free(inst);
        return NULL;
    }
    inst->forwarded = *functions;
    inst->forwarded.logger = forward;
    inst->forwarded.allocateMemory = calloc;
    inst->forwarded.freeMemory = free;
    inst->forwarded.componentEnvironment = inst;
    if (shell_instantiable(&inst->shell, fmuType, fmuGUID, GREYBOX_GUID, GREYBOX_IDENTIFIER, 0) ==
        0) {
        if (load(inst, fmuResourceLocation, message) == 0) {
            load_start_values(inst);
            return inst;
        }
        refuse(inst, "fmi2Instantiate", "%s", message);
    }
    free_instance(inst);
    return NULL;
}

void fmi2FreeInstance(fmi2Component c) {
    if (c != NULL) free_instance(c);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    Instance *inst = c;
    (void)toleranceDefined, (void)tolerance, (void)stopTimeDefined, (void)stopTime;
    if (inst == NULL || !allowed(inst, CALL_SETUP_EXPERIMENT)) return fmi2Error;
    if (!isfinite(startTime)) {
        return refuse(inst, "fmi2SetupExperiment", "startTime = %g s is not a finite time",
                      startTime);
    }
    inst->time = startTime;
    return fmi2OK;
}

/* ------------------------------------------------------------------ the inputs' domain */

/* Whether the inputs u are finite and within the input domain (rules.h); the reason into
 * message. */
static int inputs_acceptable(const Instance *inst, const double *u, char *message) {
    const ptrdiff_t i = rules_refused_input(inst->n_inputs, u, inst->input_low, inst->input_high);
    if (i < 0) return 1;
    rules_input_message(inst->input_names[i], u[i], inst->input_low[i], inst->input_high[i],
                        inst->time, message, MESSAGE_SIZE);
    return 0;
}

/* ------------------------------------------------------------------ stepping */

/* Offset of the chain state's out_var (then outside) block: after the shared sources. */
static ptrdiff_t shared_sources(const Instance *inst) {
    return (inst->sizes.depth + 1) * (2 * inst->n_stages + inst->n_exo);
}

/* The outputs after a step (slave.py, GreyBoxSlave._publish). */
static void publish(Instance *inst, double score) {
    double *out = inst->reals + inst->n_inputs;
    const double *mean = inst->chain + inst->n_stages, *var = inst->chain + shared_sources(inst);
    const double *outside = var + inst->n_stages;
    int any_outside = 0;
    memcpy(out, inst->y, (size_t)inst->n_outputs * sizeof(double));
    for (ptrdiff_t q = 0; q < inst->n_stages; q++) {
        out[inst->stage_output[q]] = mean[q];
        out[inst->n_outputs + q] = sqrt(var[q]);
        out[inst->n_outputs + inst->n_stages + q] = inst->y_wb[q];
        any_outside |= outside[q] == 1.0;
    }
    inst->reals[inst->n_reals - 2] = score;
    inst->out_of_domain = any_outside || score < inst->reals[inst->n_reals - 1];
}

/* The white-box's outputs now: all of them, the stages', and the chain's inputs. */
static void read_whitebox(Instance *inst, const double *u) {
    wb_outputs(&inst->wb, inst->y);
    for (ptrdiff_t q = 0; q < inst->n_stages; q++) inst->y_wb[q] = inst->y[inst->stage_output[q]];
    for (ptrdiff_t i = 0; i < inst->n_exo; i++) inst->exo[i] = u[inst->exo_index[i]];
}

/* The white-box initialised with the current inputs and the chain's first memory; in
 * initialization mode again whenever the inputs changed since (slave.py, _prepare). */
static fmi2Status prepare(Instance *inst, const char *call) {
    char message[MESSAGE_SIZE];
    const double *u = inst->reals;
    int same = inst->running;
    for (ptrdiff_t i = 0; same && i < inst->n_inputs; i++) same = u[i] == inst->started_with[i];
    if (same) return fmi2OK;
    if (!inputs_acceptable(inst, u, message)) return refuse(inst, call, "%s", message);
    if (wb_start(&inst->wb, u, inst->time, message, sizeof message) != 0) {
        return fail(inst, call, message);
    }
    read_whitebox(inst, u);
    chain_start(inst->plan, inst->chain, inst->y_wb, inst->exo);
    memcpy(inst->started_with, u, (size_t)inst->n_inputs * sizeof(double));
    inst->running = 1;
    publish(inst, 1.0);
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    Instance *inst = c;
    if (inst == NULL || !allowed(inst, CALL_ENTER_INITIALIZATION_MODE)) return fmi2Error;
    inst->phase = SHELL_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Instance *inst = c;
    fmi2Status status;
    if (inst == NULL || !allowed(inst, CALL_EXIT_INITIALIZATION_MODE)) return fmi2Error;
    status = prepare(inst, "fmi2ExitInitializationMode");
    if (status == fmi2OK) inst->phase = SHELL_STEP_COMPLETE;
    return status;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    static const char *const call = "fmi2DoStep";
    Instance *inst = c;
    char message[MESSAGE_SIZE];
    const double t = currentCommunicationPoint, h = communicationStepSize;
    double score;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (inst == NULL || !allowed(inst, CALL_DO_STEP)) return fmi2Error;
    if (rules_step(t, h, inst->time, inst->dt, inst->step_tolerance, message, sizeof message)) {
        return refuse(inst, call, "%s", message);
    }
    if (!inputs_acceptable(inst, inst->reals, message)) return refuse(inst, call, "%s", message);
    /* by exactly the trained step: the outputs do not depend on how a master rounds its time */
    if (wb_step(&inst->wb, inst->reals, message, sizeof message) != 0) {
        return fail(inst, call, message);
    }
    read_whitebox(inst, inst->reals);
    score = chain_step(inst->plan, inst->params, inst->work, inst->chain, inst->exo, inst->y_wb,
                       inst->correction_enabled == fmi2True);
    publish(inst, score);
    inst->time = t + h;
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    Instance *inst = c;
    if (inst == NULL || !allowed(inst, CALL_TERMINATE)) return fmi2Error;
    wb_terminate(&inst->wb);
    inst->running = 0;
    inst->phase = SHELL_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    Instance *inst = c;
    if (inst == NULL) return fmi2Error;
    load_start_values(inst);
    return fmi2OK;
}

/* ------------------------------------------------------------------ variables */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    Instance *inst = c;
    if (inst == NULL || !allowed(inst, CALL_GET_REAL)) return fmi2Error;
    if (inst->phase == SHELL_INITIALIZATION && prepare(inst, "fmi2GetReal") != fmi2OK) {
        return fmi2Error;
    }
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= (fmi2ValueReference)inst->n_reals) {
            return refuse(inst, "fmi2GetReal", "value reference %u is not a Real variable",
                          (unsigned)vr[i]);
        }
        value[i] = inst->reals[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    Instance *inst = c;
    const fmi2ValueReference threshold = (fmi2ValueReference)(inst ? inst->n_reals - 1 : 0);
    if (inst == NULL || !allowed(inst, CALL_SET_REAL)) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] >= (fmi2ValueReference)inst->n_inputs && vr[i] != threshold) {
            return refuse(inst, "fmi2SetReal", "value reference %u is not a Real input or "
                          "tunable parameter", (unsigned)vr[i]);
        }
        /* NaN compares false: it would switch the domain flag off without a word */
        if (vr[i] == threshold && !(value[i] >= 0.0 && value[i] <= 1.0)) {
            return refuse(inst, "fmi2SetReal", "ood_threshold = %g must lie between 0 and 1 "
                          "(a domain_score); nothing was set", value[i]);
        }
    }
    for (size_t i = 0; i < nvr; i++) inst->reals[vr[i]] = value[i];
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    Instance *inst = c;
    if (inst == NULL || !allowed(inst, CALL_GET_BOOLEAN)) return fmi2Error;
    if (inst->phase == SHELL_INITIALIZATION && prepare(inst, "fmi2GetBoolean") != fmi2OK) {
        return fmi2Error;
    }
    for (size_t i = 0; i < nvr; i++) {
        const ptrdiff_t k = (ptrdiff_t)vr[i] - inst->n_reals;
        if (k != 0 && k != 1) {
            return refuse(inst, "fmi2GetBoolean", "value reference %u is not a Boolean variable",
                          (unsigned)vr[i]);
        }
        value[i] = k == 0 ? inst->out_of_domain : inst->correction_enabled;
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    Instance *inst = c;
    if (inst == NULL || !allowed(inst, CALL_SET_BOOLEAN)) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        if ((ptrdiff_t)vr[i] != inst->n_reals + 1) {
            return refuse(inst, "fmi2SetBoolean", "value reference %u is not a Boolean tunable "
                          "parameter", (unsigned)vr[i]);
        }
    }
    for (size_t i = 0; i < nvr; i++) inst->correction_enabled = value[i] ? fmi2True : fmi2False;
    return fmi2OK;
}

/* The FMU has no Integer or String variable: only empty requests succeed. */
static fmi2Status no_such_variables(fmi2Component c, const char *call, size_t nvr) {
    if (c == NULL) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    return shell_refuse(c, call, "the grey-box has no variable of this type");
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    (void)vr, (void)value;
    return no_such_variables(c, "fmi2GetInteger", nvr);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    (void)vr, (void)value;
    return no_such_variables(c, "fmi2SetInteger", nvr);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    (void)vr, (void)value;
    return no_such_variables(c, "fmi2GetString", nvr);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    (void)vr, (void)value;
    return no_such_variables(c, "fmi2SetString", nvr);
}

/* ------------------------------------------------------------------ FMU state */

/* A saved state: the instance's own numbers (values) and the white-box instances' states.
 * values: time, phase, running, out_of_domain, correction_enabled, reals, started_with, chain
 * state, then the white-box's (wb_values). */
typedef struct {
    ptrdiff_t n_values;
    double *values;
    fmi2FMUstate *wb_states;
} Snapshot;

#define SNAPSHOT_HEAD 5

static ptrdiff_t snapshot_values(const Instance *inst) {
    return SNAPSHOT_HEAD + inst->n_reals + inst->n_inputs + inst->sizes.state +
           wb_values(&inst->wb);
}

static Snapshot *snapshot_new(const Instance *inst) {
    Snapshot *s = calloc(1, sizeof *s);
    if (s == NULL) return NULL;
    s->n_values = snapshot_values(inst);
    s->values = table(s->n_values, sizeof(double));
    s->wb_states = table(inst->wb.n_parts, sizeof(fmi2FMUstate));
    if (s->values == NULL || s->wb_states == NULL) {
        free(s->values);
        free(s->wb_states);
        free(s);
        return NULL;
    }
    return s;
}

static void snapshot_free(Instance *inst, Snapshot *s) {
    wb_free_states(&inst->wb, s->wb_states);
    free(s->values);
    free(s->wb_states);
    free(s);
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    static const char *const call = "fmi2GetFMUstate";
    Instance *inst = c;
    char message[MESSAGE_SIZE];
    Snapshot *s;
    double *v;
    if (inst == NULL || !allowed(inst, CALL_GET_FMU_STATE)) return fmi2Error;
    s = *FMUstate != NULL ? *FMUstate : snapshot_new(inst);
    if (s == NULL) return refuse(inst, call, "out of memory");
    v = s->values;
    v[0] = inst->time;
    v[1] = inst->phase;
    v[2] = inst->running;
    v[3] = inst->out_of_domain;
    v[4] = inst->correction_enabled;
    v += SNAPSHOT_HEAD;
    memcpy(v, inst->reals, (size_t)inst->n_reals * sizeof(double));
    v += inst->n_reals;
    memcpy(v, inst->started_with, (size_t)inst->n_inputs * sizeof(double));
    v += inst->n_inputs;
    memcpy(v, inst->chain, (size_t)inst->sizes.state * sizeof(double));
    v += inst->sizes.state;
    if (!inst->running) {
        wb_free_states(&inst->wb, s->wb_states);
    } else if (wb_save(&inst->wb, s->wb_states, v, message, sizeof message) != 0) {
        if (*FMUstate == NULL) snapshot_free(inst, s);
        return refuse(inst, call, "%s", message);
    }
    *FMUstate = s;
    return fmi2OK;
}

/* Whether a state's values are ones fmi2GetFMUstate could have written: time finite, a phase,
 * flags 0 or 1, the computed outputs finite and, for a running state, the inputs it started
 * with, the chain's memory and the white-box's (wb_values_fault) too. Inputs and the threshold
 * may hold any value fmi2SetReal took (a step refuses those outside the domain). Returns 0, or
 * -1 with what is wrong in message. */
static int values_fault(const Instance *inst, const double *values, char *message) {
    static const char *const flags[] = {"running", "out_of_domain", "correction_enabled"};
    const double *reals = values + SNAPSHOT_HEAD, *started = reals + inst->n_reals;
    const double *chain = started + inst->n_inputs;
    if (!isfinite(values[0])) {
        snprintf(message, MESSAGE_SIZE, "its time = %g s is not finite", values[0]);
        return -1;
    }
    if (!(values[1] >= SHELL_INSTANTIATED && values[1] <= SHELL_ERROR &&
          values[1] == floor(values[1]))) {
        snprintf(message, MESSAGE_SIZE, "its phase = %g is none of 0 (%s) to %d (%s)", values[1],
                 shell_phase_name(SHELL_INSTANTIATED), SHELL_ERROR, shell_phase_name(SHELL_ERROR));
        return -1;
    }
    for (int k = 0; k < 3; k++) {
        if (values[2 + k] != 0.0 && values[2 + k] != 1.0) {
            snprintf(message, MESSAGE_SIZE, "its flag %s = %g is neither 0 nor 1", flags[k],
                     values[2 + k]);
            return -1;
        }
    }
    for (ptrdiff_t i = inst->n_inputs; i < inst->n_reals - 1; i++) {
        if (!isfinite(reals[i])) {
            snprintf(message, MESSAGE_SIZE, "its output (value reference %td) = %g is not "
                     "finite", i, reals[i]);
            return -1;
        }
    }
    if (values[2] == 0.0) return 0; /* no run: the rest is not restored */
    for (ptrdiff_t i = 0; i < inst->n_inputs + inst->sizes.state; i++) {
        if (!isfinite(started[i])) {
            snprintf(message, MESSAGE_SIZE, "its %s %td = %g is not finite",
                     i < inst->n_inputs ? "start input" : "corrector memory value",
                     i < inst->n_inputs ? i : i - inst->n_inputs, started[i]);
            return -1;
        }
    }
    return wb_values_fault(&inst->wb, chain + inst->sizes.state, values[0], message,
                           MESSAGE_SIZE);
}

/* values_fault, the remedy appended to its message. */
static int state_fault(const Instance *inst, const double *values, char *message) {
    size_t n;
    if (values_fault(inst, values, message) == 0) return 0;
    n = strlen(message);
    snprintf(message + n, MESSAGE_SIZE - n, "; not a state this grey-box saved (damaged or "
             "forged): restore one it saved");
    return -1;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    static const char *const call = "fmi2SetFMUstate";
    Instance *inst = c;
    const Snapshot *s = FMUstate;
    char message[MESSAGE_SIZE];
    const double *v;
    if (inst == NULL || !allowed(inst, CALL_SET_FMU_STATE)) return fmi2Error;
    if (s == NULL || s->n_values != snapshot_values(inst)) {
        return refuse(inst, call, "not an FMU state of this grey-box");
    }
    if (state_fault(inst, s->values, message) != 0) {
        return refuse(inst, call, "%s", message);
    }
    v = s->values + SNAPSHOT_HEAD;
    if (s->values[2] != 0.0) { /* the run it saved: the white-box goes back to its states */
        const double *after = v + inst->n_reals + inst->n_inputs + inst->sizes.state;
        if (!inst->wb.started &&
            wb_start(&inst->wb, v + inst->n_reals, s->values[0], message, sizeof message) != 0) {
            return fail(inst, call, message);
        }
        if (wb_restore(&inst->wb, s->wb_states, after, message, sizeof message) != 0) {
            return fail(inst, call, message);
        }
    }
    inst->time = s->values[0];
    inst->phase = (int)s->values[1];
    inst->running = s->values[2] != 0.0;
    inst->out_of_domain = s->values[3] != 0.0;
    inst->correction_enabled = s->values[4] != 0.0;
    memcpy(inst->reals, v, (size_t)inst->n_reals * sizeof(double));
    v += inst->n_reals;
    memcpy(inst->started_with, v, (size_t)inst->n_inputs * sizeof(double));
    v += inst->n_inputs;
    memcpy(inst->chain, v, (size_t)inst->sizes.state * sizeof(double));
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    Instance *inst = c;
    if (inst == NULL) return fmi2Error;
    if (FMUstate != NULL && *FMUstate != NULL) {
        snapshot_free(inst, *FMUstate);
        *FMUstate = NULL;
    }
    return fmi2OK;
}

/* Serialised (fmi2_shell.h): the shell's header (n_parts white-box states, n_values values),
 * the white-box states' sizes (uint64 each), the values, the white-box states' bytes, and the
 * shell's SHA-256 trailer. Valid for the binary that wrote it (same GUID). */
static size_t serialized_size(const Instance *inst, const size_t *sizes) {
    size_t n = (size_t)inst->wb.n_parts * 8 + (size_t)snapshot_values(inst) * sizeof(double);
    for (ptrdiff_t k = 0; k < inst->wb.n_parts; k++) n += sizes[k];
    return shell_state_size(n);
}

/* The white-box states' serialised sizes (zero when the state holds no run). */
static int state_sizes(Instance *inst, const Snapshot *s, size_t *sizes, char *message) {
    memset(sizes, 0, (size_t)(inst->wb.n_parts > 0 ? inst->wb.n_parts : 1) * sizeof(size_t));
    if (s->values[2] == 0.0) return 0;
    return wb_serialized_size(&inst->wb, s->wb_states, sizes, message, MESSAGE_SIZE);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    static const char *const call = "fmi2SerializedFMUstateSize";
    Instance *inst = c;
    char message[MESSAGE_SIZE];
    size_t *sizes;
    if (inst == NULL) return fmi2Error;
    if (FMUstate == NULL) return refuse(inst, call, "the FMU state is NULL");
    sizes = table(inst->wb.n_parts, sizeof(size_t));
    if (sizes == NULL) return refuse(inst, call, "out of memory");
    if (state_sizes(inst, FMUstate, sizes, message) != 0) {
        free(sizes);
        return refuse(inst, call, "%s", message);
    }
    *size = serialized_size(inst, sizes);
    free(sizes);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    static const char *const call = "fmi2SerializeFMUstate";
    Instance *inst = c;
    const Snapshot *s = FMUstate;
    char message[MESSAGE_SIZE];
    unsigned char *at = (unsigned char *)serializedState;
    size_t *sizes;
    int status;
    if (inst == NULL) return fmi2Error;
    if (s == NULL) return refuse(inst, call, "the FMU state is NULL");
    sizes = table(inst->wb.n_parts, sizeof(size_t));
    if (sizes == NULL) return refuse(inst, call, "out of memory");
    status = state_sizes(inst, s, sizes, message);
    if (status == 0 && size < serialized_size(inst, sizes)) {
        snprintf(message, sizeof message, "a buffer of %zu bytes is too small (%zu needed)",
                 size, serialized_size(inst, sizes));
        status = -1;
    }
    if (status == 0) {
        shell_state_begin(at, GREYBOX_GUID, (uint32_t)inst->wb.n_parts, (uint64_t)s->n_values);
        at += sizeof(ShellStateHeader);
        for (ptrdiff_t k = 0; k < inst->wb.n_parts; k++, at += 8) {
            const uint64_t n = sizes[k];
            memcpy(at, &n, 8);
        }
        memcpy(at, s->values, (size_t)s->n_values * sizeof(double));
        at += (size_t)s->n_values * sizeof(double);
        if (s->values[2] != 0.0) {
            status = wb_serialize(&inst->wb, s->wb_states, at, sizes, message, sizeof message);
        }
    }
    if (status == 0) shell_state_seal((unsigned char *)serializedState, serialized_size(inst, sizes));
    free(sizes);
    return status == 0 ? fmi2OK : refuse(inst, call, "%s", message);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *FMUstate) {
    static const char *const call = "fmi2DeSerializeFMUstate";
    Instance *inst = c;
    const unsigned char *at = (const unsigned char *)serializedState;
    char message[MESSAGE_SIZE];
    ShellStateHeader header;
    Snapshot *s;
    size_t *sizes, expected;
    int status = 0;
    if (inst == NULL) return fmi2Error;
    if (shell_state_open(&inst->shell, call, at, size, GREYBOX_GUID, &header) != 0) {
        return fmi2Error;
    }
    if (header.n_parts != (uint32_t)inst->wb.n_parts ||
        header.n_values != (uint64_t)snapshot_values(inst)) {
        return refuse(inst, call, "the state holds %u white-box states and %llu values, this "
                      "grey-box %td and %td", (unsigned)header.n_parts,
                      (unsigned long long)header.n_values, inst->wb.n_parts,
                      snapshot_values(inst));
    }
    at += sizeof header;
    sizes = table(inst->wb.n_parts, sizeof(size_t));
    s = snapshot_new(inst);
    if (sizes == NULL || s == NULL || size < shell_state_size((size_t)inst->wb.n_parts * 8)) {
        free(sizes);
        if (s != NULL) snapshot_free(inst, s);
        return refuse(inst, call, "out of memory or truncated state");
    }
    for (ptrdiff_t k = 0; k < inst->wb.n_parts; k++, at += 8) {
        uint64_t n;
        memcpy(&n, at, 8);
        sizes[k] = n <= size ? (size_t)n : size + 1; /* too large either way, no overflow */
    }
    expected = serialized_size(inst, sizes);
    if (size != expected) {
        snprintf(message, sizeof message, "%zu bytes given, this state has %zu", size, expected);
        status = -1;
    } else {
        memcpy(s->values, at, (size_t)s->n_values * sizeof(double));
        at += (size_t)s->n_values * sizeof(double);
        status = state_fault(inst, s->values, message);
        if (status == 0 && s->values[2] != 0.0) {
            status = wb_deserialize(&inst->wb, at, sizes, s->wb_states, message, sizeof message);
        }
    }
    free(sizes);
    if (status != 0) {
        snapshot_free(inst, s);
        return refuse(inst, call, "%s", message);
    }
    if (*FMUstate != NULL) snapshot_free(inst, *FMUstate);
    *FMUstate = s;
    return fmi2OK;
}
