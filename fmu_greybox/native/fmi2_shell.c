/*
 * fmi2_shell.c -- the shared FMI 2.0 co-simulation shell (see fmi2_shell.h): the table of
 * allowed phases, the logging and error policy, the serialised state's header and trailer,
 * and the FMI 2.0 functions every FMU here answers the same way.
 */
#include "fmi2_shell.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sha256.h"

#define MESSAGE_SIZE 1024
#define LOG_ERROR "logStatusError"
#define LOG_WARNING "logStatusWarning"
#define LOG_ALL "logAll"

const char *const SHELL_CATEGORIES[] = {"logStatusWarning", "logStatusDiscard", "logStatusError",
                                        "logStatusFatal", "logAll", NULL};

/* The table: each call and the phases it is allowed in (FMI 2.0, section 4.2.4). */
#define SETTABLE \
    (SHELL_IN(SHELL_INSTANTIATED) | SHELL_IN(SHELL_INITIALIZATION) | SHELL_IN(SHELL_STEP_COMPLETE))
static const struct {
    const char *name;
    unsigned phases;
} CALLS[SHELL_CALLS] = {
    [CALL_SETUP_EXPERIMENT] = {"fmi2SetupExperiment", SHELL_IN(SHELL_INSTANTIATED)},
    [CALL_ENTER_INITIALIZATION_MODE] = {"fmi2EnterInitializationMode",
                                        SHELL_IN(SHELL_INSTANTIATED)},
    [CALL_EXIT_INITIALIZATION_MODE] = {"fmi2ExitInitializationMode",
                                       SHELL_IN(SHELL_INITIALIZATION)},
    [CALL_DO_STEP] = {"fmi2DoStep", SHELL_IN(SHELL_STEP_COMPLETE)},
    [CALL_TERMINATE] = {"fmi2Terminate", SHELL_IN(SHELL_INITIALIZATION) |
                                             SHELL_IN(SHELL_STEP_COMPLETE) | SHELL_IN(SHELL_ERROR)},
    [CALL_GET_REAL] = {"fmi2GetReal", SHELL_GETTABLE},
    [CALL_GET_INTEGER] = {"fmi2GetInteger", SHELL_GETTABLE},
    [CALL_GET_BOOLEAN] = {"fmi2GetBoolean", SHELL_GETTABLE},
    [CALL_GET_STRING] = {"fmi2GetString", SHELL_GETTABLE},
    [CALL_SET_REAL] = {"fmi2SetReal", SETTABLE},
    [CALL_SET_INTEGER] = {"fmi2SetInteger", SETTABLE},
    [CALL_SET_BOOLEAN] = {"fmi2SetBoolean", SETTABLE},
    [CALL_SET_STRING] = {"fmi2SetString", SETTABLE},
    [CALL_GET_FMU_STATE] = {"fmi2GetFMUstate", SHELL_ANY_PHASE},
    [CALL_SET_FMU_STATE] = {"fmi2SetFMUstate", SHELL_ANY_PHASE},
};

const char *shell_call_name(ShellCall call) { return CALLS[call].name; }

const char *shell_phase_name(int phase) {
    static const char *const names[] = {"instantiated", "initialization mode", "step complete",
                                        "terminated", "error"};
    return phase >= SHELL_INSTANTIATED && phase <= SHELL_ERROR ? names[phase] : "unknown";
}

/* ------------------------------------------------------------------ instance, logging */

int shell_open(Shell *shell, const char *name, const fmi2CallbackFunctions *callbacks,
               fmi2Boolean loggingOn) {
    const char *own = name != NULL ? name : "";
    shell->callbacks = *callbacks;
    shell->logging = loggingOn ? 1 : 0;
    shell->categories = SHELL_CATEGORIES;
    shell->name = calloc(strlen(own) + 1, 1);
    if (shell->name == NULL) {
        shell->name = (char *)own; /* for the message only */
        shell_refuse(shell, "fmi2Instantiate", "out of memory");
        shell->name = NULL;
        return -1;
    }
    strcpy(shell->name, own);
    return 0;
}

void shell_close(Shell *shell) {
    free(shell->name);
    shell->name = NULL;
}

static void send(const Shell *shell, fmi2Status status, const char *text) {
    const char *category = status >= fmi2Error ? LOG_ERROR
                           : status == fmi2Warning ? LOG_WARNING
                                                   : LOG_ALL;
    if (shell->callbacks.logger == NULL) return;
    if (status < fmi2Error && !shell->logging) return; /* errors go out at any logging level */
    shell->callbacks.logger(shell->callbacks.componentEnvironment, shell->name, status, category,
                            "%s", text);
}

void shell_log(const Shell *shell, fmi2Status status, const char *format, ...) {
    char text[MESSAGE_SIZE];
    va_list args;
    va_start(args, format);
    vsnprintf(text, sizeof text, format, args);
    va_end(args);
    send(shell, status, text);
}

static fmi2Status refuse_with(const Shell *shell, const char *call, const char *format,
                              va_list args) {
    char detail[MESSAGE_SIZE], text[MESSAGE_SIZE + 64];
    vsnprintf(detail, sizeof detail, format, args);
    snprintf(text, sizeof text, "%s failed: %s", call, detail);
    send(shell, fmi2Error, text);
    return fmi2Error;
}

fmi2Status shell_refuse(const Shell *shell, const char *call, const char *format, ...) {
    va_list args;
    va_start(args, format);
    refuse_with(shell, call, format, args);
    va_end(args);
    return fmi2Error;
}

fmi2Status shell_fail(const Shell *shell, int *phase, const char *call, const char *format, ...) {
    char detail[MESSAGE_SIZE];
    size_t n;
    va_list args;
    va_start(args, format);
    vsnprintf(detail, sizeof detail, format, args);
    va_end(args);
    n = strlen(detail);
    if (n > 0 && detail[n - 1] == '.') detail[n - 1] = '\0'; /* not ".; fmi2Reset ..." */
    *phase = SHELL_ERROR;
    return shell_refuse(shell, call, "%s; fmi2Reset or an earlier FMU state continues", detail);
}

int shell_allowed_in(const Shell *shell, const char *call, unsigned mask, int phase,
                     const char *label) {
    if (mask & SHELL_IN(phase)) return 1;
    shell_refuse(shell, call, "not allowed in phase \"%s\"",
                 label != NULL ? label : shell_phase_name(phase));
    return 0;
}

int shell_allowed(const Shell *shell, ShellCall call, int phase, const char *label) {
    return shell_allowed_in(shell, CALLS[call].name, CALLS[call].phases, phase, label);
}

int shell_instantiable(const Shell *shell, fmi2Type type, const char *guid, const char *own_guid,
                       const char *identifier, int model_exchange_too) {
    static const char *const call = "fmi2Instantiate";
    if (type != fmi2CoSimulation && !(model_exchange_too && type == fmi2ModelExchange)) {
        shell_refuse(shell, call, "%s supports %s only", identifier,
                     model_exchange_too ? "model exchange and co-simulation" : "co-simulation");
        return -1;
    }
    if (guid == NULL || strcmp(guid, own_guid) != 0) {
        shell_refuse(shell, call, "GUID \"%s\" is not this binary's \"%s\"; the "
                     "modelDescription.xml belongs to another build or export",
                     guid != NULL ? guid : "(null)", own_guid);
        return -1;
    }
    return 0;
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    Shell *shell = c;
    if (shell == NULL) return fmi2Error;
    for (size_t i = 0; i < nCategories; i++) {
        int found = 0;
        for (size_t k = 0; shell->categories[k] != NULL; k++) {
            found |= categories[i] != NULL && strcmp(categories[i], shell->categories[k]) == 0;
        }
        if (!found) {
            return shell_refuse(shell, "fmi2SetDebugLogging", "unknown log category \"%s\"; the "
                                "categories are those of modelDescription.xml",
                                categories[i] ? categories[i] : "(null)");
        }
    }
    shell->logging = loggingOn ? 1 : 0;
    return fmi2OK;
}

/* ------------------------------------------------------------------ serialised states */

size_t shell_state_size(size_t body) { return sizeof(ShellStateHeader) + body + SHELL_STATE_DIGEST; }

void shell_state_begin(unsigned char *bytes, const char *guid, uint32_t n_parts,
                       uint64_t n_values) {
    ShellStateHeader header;
    memset(&header, 0, sizeof header);
    memcpy(header.magic, SHELL_STATE_MAGIC, sizeof header.magic);
    header.version = SHELL_STATE_VERSION;
    header.n_parts = n_parts;
    strncpy(header.guid, guid, sizeof header.guid - 1);
    header.n_values = n_values;
    memcpy(bytes, &header, sizeof header);
}

void shell_state_seal(unsigned char *bytes, size_t size) {
    char digest[65];
    sha256_bytes(bytes, size - SHELL_STATE_DIGEST, digest);
    memcpy(bytes + size - SHELL_STATE_DIGEST, digest, SHELL_STATE_DIGEST);
}

int shell_state_open(const Shell *shell, const char *call, const unsigned char *bytes,
                     size_t size, const char *own_guid, ShellStateHeader *header) {
    char digest[65];
    if (bytes == NULL || size < shell_state_size(0)) {
        shell_refuse(shell, call, "%zu bytes are no serialised state of this FMU", size);
        return -1;
    }
    sha256_bytes(bytes, size - SHELL_STATE_DIGEST, digest);
    if (memcmp(digest, bytes + size - SHELL_STATE_DIGEST, SHELL_STATE_DIGEST) != 0) {
        shell_refuse(shell, call, "the state's bytes do not match their SHA-256: they were "
                     "damaged or edited after they were serialised; restore an undamaged copy");
        return -1;
    }
    memcpy(header, bytes, sizeof *header);
    if (memcmp(header->magic, SHELL_STATE_MAGIC, sizeof header->magic) != 0 ||
        header->version != SHELL_STATE_VERSION) {
        shell_refuse(shell, call, "the bytes are not a state serialised by this version of the "
                     "FMU (magic %s, version %d expected)", SHELL_STATE_MAGIC,
                     SHELL_STATE_VERSION);
        return -1;
    }
    if (strncmp(header->guid, own_guid, sizeof header->guid) != 0) {
        shell_refuse(shell, call, "the state was written by another FMU or export (GUID %.47s, "
                     "this one's is %s)", header->guid, own_guid);
        return -1;
    }
    return 0;
}

/* ------------------------------------------------------------------ the same for every FMU */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

static fmi2Status unsupported(fmi2Component c, const char *call) {
    if (c != NULL) shell_refuse(c, call, "not supported by this FMU");
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

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s, (void)value;
    return unsupported(c, "fmi2GetStatus (steps are never asynchronous)");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    if (c == NULL || s != fmi2LastSuccessfulTime) return unsupported(c, "fmi2GetRealStatus");
    *value = shell_core_time(c);
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s, (void)value;
    return unsupported(c, "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    if (c == NULL || s != fmi2Terminated) return unsupported(c, "fmi2GetBooleanStatus");
    *value = fmi2False; /* no FMU here asks the master to stop */
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s, (void)value;
    return unsupported(c, "fmi2GetStringStatus");
}
