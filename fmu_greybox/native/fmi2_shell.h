/*
 * fmi2_shell.h -- what every co-simulation FMU the project builds shares of its FMI 2.0 face.
 *
 * Two cores plug into it: the reference FMUs' framework (fmu_sources/framework/
 * fmi2_cosimulation.c, with model.c holding the physics) and the native grey-box
 * (greybox_fmu.c, the white-box and the corrector chain). A core's instance struct starts with
 * a Shell; the shell owns
 *   - the phases of FMI 2.0 co-simulation and one table of the phases each call is allowed in
 *     (shell_allowed);
 *   - one logging and error policy: every error goes to the master's logger, whatever the
 *     logging level, as "<call> failed: <what is wrong and how to mend it>"; a misuse is
 *     refused (shell_refuse: the phase stays), a failure moves the instance to the error phase
 *     (shell_fail); other messages only while debug logging is on;
 *   - the instance's name, callbacks and log categories (shell_open, shell_close,
 *     fmi2SetDebugLogging);
 *   - one serialised state format: a header with one magic and one version, the core's bytes,
 *     and the SHA-256 of both as a 64-hex-digit trailer (shell_state_*);
 *   - the FMI 2.0 functions no FMU here supports, and the status inquiries (fmi2_shell.c).
 * The FMI 3.0 face (fmi3_shell.c) wraps the FMI 2.0 functions of either core.
 */
#ifndef FMI2_SHELL_H
#define FMI2_SHELL_H

#include <stddef.h>
#include <stdint.h>

#include "fmi2Functions.h"

/* Phases of FMI 2.0 co-simulation (model exchange spends "step complete" in event mode or
 * continuous-time mode: the core names those, shell_allowed's label). */
typedef enum {
    SHELL_INSTANTIATED,
    SHELL_INITIALIZATION,
    SHELL_STEP_COMPLETE,
    SHELL_TERMINATED,
    SHELL_ERROR
} ShellPhase;

/* Masks of phases. */
#define SHELL_IN(phase) (1u << (phase))
#define SHELL_GETTABLE                                                                  \
    (SHELL_IN(SHELL_INITIALIZATION) | SHELL_IN(SHELL_STEP_COMPLETE) |                   \
     SHELL_IN(SHELL_TERMINATED) | SHELL_IN(SHELL_ERROR))
#define SHELL_ANY_PHASE (SHELL_IN(SHELL_INSTANTIATED) | SHELL_GETTABLE)

/* The calls of the table (shell_allowed): FMI 2.0 co-simulation. */
typedef enum {
    CALL_SETUP_EXPERIMENT,
    CALL_ENTER_INITIALIZATION_MODE,
    CALL_EXIT_INITIALIZATION_MODE,
    CALL_DO_STEP,
    CALL_TERMINATE,
    CALL_GET_REAL,
    CALL_GET_INTEGER,
    CALL_GET_BOOLEAN,
    CALL_GET_STRING,
    CALL_SET_REAL,
    CALL_SET_INTEGER,
    CALL_SET_BOOLEAN,
    CALL_SET_STRING,
    CALL_GET_FMU_STATE,
    CALL_SET_FMU_STATE,
    SHELL_CALLS
} ShellCall;

/* The name of a call of the table, e.g. "fmi2DoStep". */
const char *shell_call_name(ShellCall call);

/* The shell's part of an instance: the first member of a core's instance struct. */
typedef struct {
    char *name;
    fmi2CallbackFunctions callbacks;
    int logging;                   /* debug logging on: messages below errors go out too */
    const char *const *categories; /* the log categories of modelDescription.xml, NULL-ended */
} Shell;

/* The log categories of every FMU here (modelDescription.xml declares them). */
extern const char *const SHELL_CATEGORIES[];

/* Fill a shell (the name copied); 0, or -1 when out of memory (logged). */
int shell_open(Shell *shell, const char *name, const fmi2CallbackFunctions *callbacks,
               fmi2Boolean loggingOn);
void shell_close(Shell *shell);

/* Whether an instance of this binary may be made: co-simulation (or model exchange when
 * model_exchange_too), the modelDescription.xml's GUID the binary's. 0, or -1 with the refusal
 * logged as fmi2Instantiate's. */
int shell_instantiable(const Shell *shell, fmi2Type type, const char *guid, const char *own_guid,
                       const char *identifier, int model_exchange_too);

/* Send a message (errors always, the rest while debug logging is on). */
void shell_log(const Shell *shell, fmi2Status status, const char *format, ...);

/* Log "<call> failed: <detail>" as an error and return fmi2Error (the phase stays). */
fmi2Status shell_refuse(const Shell *shell, const char *call, const char *format, ...);

/* shell_refuse, and *phase becomes SHELL_ERROR (a failure of the model, not a misuse). */
fmi2Status shell_fail(const Shell *shell, int *phase, const char *call, const char *format, ...);

/* Whether the call is allowed in phase (the table); else refused, logged with label (the
 * phase's name when NULL). shell_allowed_in: the same for a call and mask of a core's own. */
int shell_allowed(const Shell *shell, ShellCall call, int phase, const char *label);
int shell_allowed_in(const Shell *shell, const char *call, unsigned mask, int phase,
                     const char *label);

/* The name of a phase, e.g. "step complete". */
const char *shell_phase_name(int phase);

/* The core's communication time (fmi2GetRealStatus's fmi2LastSuccessfulTime). */
double shell_core_time(const Shell *shell);

/* ---------------------------------------------------------------------- serialised states */

#define SHELL_STATE_MAGIC "FGBXSTAT"
#define SHELL_STATE_VERSION 3
#define SHELL_STATE_DIGEST 64 /* the trailer: SHA-256 (hex) of the bytes before */

/* Serialised: this header, the core's bytes, the trailer. Valid for the binary that wrote it
 * (same GUID); n_parts and n_values describe the core's bytes (the core checks them). */
typedef struct {
    char magic[8];
    uint32_t version, n_parts;
    char guid[48];
    uint64_t n_values;
} ShellStateHeader;

/* The size of a serialised state whose core bytes are body bytes long. */
size_t shell_state_size(size_t body);

/* Write the header at bytes[0] (the core then writes its bytes after it). */
void shell_state_begin(unsigned char *bytes, const char *guid, uint32_t n_parts,
                       uint64_t n_values);

/* Write the trailer of a serialised state of size bytes. */
void shell_state_seal(unsigned char *bytes, size_t size);

/* Check a serialised state's size, trailer, magic, version and GUID, and copy its header out;
 * 0, or -1 with the refusal logged as call's. */
int shell_state_open(const Shell *shell, const char *call, const unsigned char *bytes,
                     size_t size, const char *own_guid, ShellStateHeader *header);

#endif /* FMI2_SHELL_H */
