/*
 * fmi3_shell.c -- the FMI 3.0 co-simulation face of an FMI 2.0 co-simulation core.
 *
 * One file serves every FMU the project builds: the reference FMUs (the framework,
 * fmu_sources/framework/fmi2_cosimulation.c) and the native grey-box (greybox_fmu.c). The core
 * owns the state machine, the variables, the FMU state and the stepping; every FMI 3.0 call
 * here translates its arguments and calls the FMI 2.0 function that does the work, so both
 * faces of one core step the same numbers. Types: Float64 is the core's Real, Int32 its
 * Integer, Boolean and String as in FMI 2.0; the other FMI 3.0 types, clocks, event mode,
 * model exchange and scheduled execution are refused with a message (modelDescription.xml
 * declares none of them). The core's identity comes from fmi_shell_config.h, generated at
 * build: FMI_SHELL_IDENTIFIER (a string) and FMI_SHELL_TIME_VR (the value reference of the
 * independent variable time, one past the core's own). Built with FW_MODEL_EXCHANGE, the FMI
 * 3.0 model-exchange functions of the framework's me/fmi3_model_exchange.c (a face over the
 * FMI 2.0 ones of me/fmi2_model_exchange.c) replace the refusals of model exchange and event
 * mode at the end of this file.
 */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmi3Functions.h"
#include "fmi_shell_config.h"
#ifdef FW_MODEL_EXCHANGE
#include "fmu_framework.h"
#endif

/* One FMI 3.0 instance: the FMI 2.0 instance doing the work and the master's logger (errors
 * go to it at any logging level: the shell's policy, fmi2_shell.h). */
typedef struct {
    fmi2Component inner;
    fmi3InstanceEnvironment environment;
    fmi3LogMessageCallback log;
} Face;

/* The FMI 2.0 logger of the inner instance: formats its message (a printf format and its
 * arguments, as FMI 2.0 has it) and hands it on, without the name of the FMI 2.0 function it
 * starts with (the master knows which FMI 3.0 call failed). */
static void relay(fmi2ComponentEnvironment environment, fmi2String instanceName,
                  fmi2Status status, fmi2String category, fmi2String message, ...) {
    const Face *face = (const Face *)environment;
    char text[2048];
    const char *call_end;
    va_list args;
    (void)instanceName;
    if (!face || !face->log || !message) return;
    va_start(args, message);
    vsnprintf(text, sizeof text, message, args);
    va_end(args);
    call_end = strncmp(text, "fmi2", 4) == 0 ? strstr(text, ": ") : NULL;
    face->log(face->environment, (fmi3Status)status, category, call_end ? call_end + 2 : text);
}

static fmi3Status status3(fmi2Status status) {
    return status == fmi2Pending ? fmi3Error : (fmi3Status)status;
}

#ifdef FW_MODEL_EXCHANGE
#define FW_FMI3_INTERFACE "model exchange"
#else
#define FW_FMI3_INTERFACE "co-simulation"
#endif

/* Log a call this FMU does not support and refuse it (as the shell words a refusal). */
static fmi3Status unsupported(fmi3Instance instance, const char *call) {
    const Face *face = (const Face *)instance;
    if (face && face->log) {
        char message[256];
        snprintf(message, sizeof message, "%s failed: not supported by %s (FMI 3.0 %s with "
                 "Float64, Int32, Boolean and String variables only)", call,
                 FMI_SHELL_IDENTIFIER, FW_FMI3_INTERFACE);
        face->log(face->environment, fmi3Error, "logStatusError", message);
    }
    return fmi3Error;
}

#define INNER(instance) (((Face *)(instance))->inner)

/* ------------------------------------------------------------------------------------------ */
/* Version, logging, creation and destruction                                                  */
/* ------------------------------------------------------------------------------------------ */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    if (!instance) return fmi3Error;
    return status3(fmi2SetDebugLogging(INNER(instance), loggingOn, nCategories, categories));
}

/* A new FMI 3.0 instance over an instance of the core of the given type; NULL when out of
 * memory or when the core refuses (its reason logged through relay). */
static Face *face_new(fmi3String instanceName, fmi2Type type, fmi3String instantiationToken,
                      fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                      fmi3InstanceEnvironment instanceEnvironment,
                      fmi3LogMessageCallback logMessage) {
    fmi2CallbackFunctions callbacks;
    Face *face = (Face *)calloc(1, sizeof *face);
    if (!face) return NULL;
    face->environment = instanceEnvironment;
    face->log = logMessage;
    memset(&callbacks, 0, sizeof callbacks);
    callbacks.logger = relay;
    callbacks.componentEnvironment = face;
    face->inner = fmi2Instantiate(instanceName, type, instantiationToken, resourcePath,
                                  &callbacks, visible, loggingOn);
    if (!face->inner) {
        free(face);
        return NULL;
    }
    return face;
}

fmi3Instance fmi3InstantiateCoSimulation(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
    fmi3Boolean earlyReturnAllowed, const fmi3ValueReference requiredIntermediateVariables[],
    size_t nRequiredIntermediateVariables, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3IntermediateUpdateCallback intermediateUpdate) {
    Face refusal = {NULL, instanceEnvironment, logMessage};
    (void)earlyReturnAllowed; /* steps never return early */
    (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;
    if (eventModeUsed) {
        unsupported(&refusal, "fmi3InstantiateCoSimulation with eventModeUsed (no event mode)");
        return NULL;
    }
    return face_new(instanceName, fmi2CoSimulation, instantiationToken, resourcePath, visible,
                    loggingOn, instanceEnvironment, logMessage);
}

void fmi3FreeInstance(fmi3Instance instance) {
    if (!instance) return;
    fmi2FreeInstance(INNER(instance));
    free(instance);
}

/* ------------------------------------------------------------------------------------------ */
/* Initialisation, termination, reset                                                          */
/* ------------------------------------------------------------------------------------------ */

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    fmi2Status status;
    if (!instance) return fmi3Error;
    status = fmi2SetupExperiment(INNER(instance), toleranceDefined, tolerance, startTime,
                                 stopTimeDefined, stopTime);
    if (status > fmi2Warning) return status3(status);
    return status3(fmi2EnterInitializationMode(INNER(instance)));
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    return instance ? status3(fmi2ExitInitializationMode(INNER(instance))) : fmi3Error;
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    return instance ? status3(fmi2Terminate(INNER(instance))) : fmi3Error;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    return instance ? status3(fmi2Reset(INNER(instance))) : fmi3Error;
}

/* ------------------------------------------------------------------------------------------ */
/* Getting and setting variable values                                                         */
/* ------------------------------------------------------------------------------------------ */

/* FMI 3.0 passes the number of values besides the number of references: scalars only here. */
static int scalars(fmi3Instance instance, const char *call, size_t nvr, size_t nValues) {
    if (nValues == nvr) return 1;
    unsupported(instance, call);
    return 0;
}

/* The independent variable time (modelDescription.xml). */
#define VR_TIME FMI_SHELL_TIME_VR

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Float64 values[], size_t nValues) {
    if (!instance || !scalars(instance, "fmi3GetFloat64 of arrays", nvr, nValues)) return fmi3Error;
    for (size_t i = 0; i < nvr; i++) {
        if (vr[i] != VR_TIME) continue;
        for (i = 0; i < nvr; i++) { /* time among the references: one by one */
            fmi2Status status = vr[i] == VR_TIME
                ? fmi2GetRealStatus(INNER(instance), fmi2LastSuccessfulTime, &values[i])
                : fmi2GetReal(INNER(instance), &vr[i], 1, &values[i]);
            if (status > fmi2Warning) return status3(status);
        }
        return fmi3OK;
    }
    return status3(fmi2GetReal(INNER(instance), vr, nvr, values));
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues) {
    if (!instance || !scalars(instance, "fmi3SetFloat64 of arrays", nvr, nValues)) return fmi3Error;
    return status3(fmi2SetReal(INNER(instance), vr, nvr, values));
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Int32 values[], size_t nValues) {
    if (!instance || !scalars(instance, "fmi3GetInt32 of arrays", nvr, nValues)) return fmi3Error;
    return status3(fmi2GetInteger(INNER(instance), vr, nvr, (fmi2Integer *)values));
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Int32 values[], size_t nValues) {
    if (!instance || !scalars(instance, "fmi3SetInt32 of arrays", nvr, nValues)) return fmi3Error;
    return status3(fmi2SetInteger(INNER(instance), vr, nvr, (const fmi2Integer *)values));
}

fmi3Status fmi3GetBoolean(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          fmi3Boolean values[], size_t nValues) {
    if (!instance || !scalars(instance, "fmi3GetBoolean of arrays", nvr, nValues)) return fmi3Error;
    for (size_t i = 0; i < nvr; i++) { /* fmi2Boolean is an int, fmi3Boolean a bool */
        fmi2Boolean value = fmi2False;
        fmi2Status status = fmi2GetBoolean(INNER(instance), &vr[i], 1, &value);
        if (status > fmi2Warning) return status3(status);
        values[i] = value != fmi2False;
    }
    return fmi3OK;
}

fmi3Status fmi3SetBoolean(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Boolean values[], size_t nValues) {
    if (!instance || !scalars(instance, "fmi3SetBoolean of arrays", nvr, nValues)) return fmi3Error;
    for (size_t i = 0; i < nvr; i++) {
        const fmi2Boolean value = values[i] ? fmi2True : fmi2False;
        fmi2Status status = fmi2SetBoolean(INNER(instance), &vr[i], 1, &value);
        if (status > fmi2Warning) return status3(status);
    }
    return fmi3OK;
}

fmi3Status fmi3GetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         fmi3String values[], size_t nValues) {
    if (!instance || !scalars(instance, "fmi3GetString of arrays", nvr, nValues)) return fmi3Error;
    return status3(fmi2GetString(INNER(instance), vr, nvr, values));
}

fmi3Status fmi3SetString(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const fmi3String values[], size_t nValues) {
    if (!instance || !scalars(instance, "fmi3SetString of arrays", nvr, nValues)) return fmi3Error;
    return status3(fmi2SetString(INNER(instance), vr, nvr, values));
}

/* ------------------------------------------------------------------------------------------ */
/* FMU state                                                                                   */
/* ------------------------------------------------------------------------------------------ */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *state) {
    return instance ? status3(fmi2GetFMUstate(INNER(instance), state)) : fmi3Error;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState state) {
    return instance ? status3(fmi2SetFMUstate(INNER(instance), state)) : fmi3Error;
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *state) {
    return instance ? status3(fmi2FreeFMUstate(INNER(instance), state)) : fmi3Error;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState state, size_t *size) {
    return instance ? status3(fmi2SerializedFMUstateSize(INNER(instance), state, size))
                    : fmi3Error;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState state,
                                 fmi3Byte serializedState[], size_t size) {
    if (!instance) return fmi3Error;
    return status3(fmi2SerializeFMUstate(INNER(instance), state, (fmi2Byte *)serializedState,
                                         size));
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *state) {
    if (!instance) return fmi3Error;
    return status3(fmi2DeSerializeFMUstate(INNER(instance), (const fmi2Byte *)serializedState,
                                           size, state));
}

/* ------------------------------------------------------------------------------------------ */
/* Stepping                                                                                    */
/* ------------------------------------------------------------------------------------------ */

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    fmi2Status status;
    if (!instance) return fmi3Error;
    status = fmi2DoStep(INNER(instance), currentCommunicationPoint, communicationStepSize,
                        noSetFMUStatePriorToCurrentPoint);
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (lastSuccessfulTime) fmi2GetRealStatus(INNER(instance), fmi2LastSuccessfulTime,
                                              lastSuccessfulTime);
    return status3(status);
}

/* ------------------------------------------------------------------------------------------ */
/* What this FMU does not declare: refused with a message                                      */
/* ------------------------------------------------------------------------------------------ */

#pragma GCC diagnostic ignored "-Wunused-parameter"

#define ARRAY_ACCESS(call, type, constness)                                                  \
    fmi3Status call(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,        \
                    constness type values[], size_t nValues) {                               \
        return unsupported(instance, #call);                                                 \
    }
ARRAY_ACCESS(fmi3GetFloat32, fmi3Float32, )
ARRAY_ACCESS(fmi3GetInt8, fmi3Int8, )
ARRAY_ACCESS(fmi3GetUInt8, fmi3UInt8, )
ARRAY_ACCESS(fmi3GetInt16, fmi3Int16, )
ARRAY_ACCESS(fmi3GetUInt16, fmi3UInt16, )
ARRAY_ACCESS(fmi3GetUInt32, fmi3UInt32, )
ARRAY_ACCESS(fmi3GetInt64, fmi3Int64, )
ARRAY_ACCESS(fmi3GetUInt64, fmi3UInt64, )
ARRAY_ACCESS(fmi3SetFloat32, fmi3Float32, const)
ARRAY_ACCESS(fmi3SetInt8, fmi3Int8, const)
ARRAY_ACCESS(fmi3SetUInt8, fmi3UInt8, const)
ARRAY_ACCESS(fmi3SetInt16, fmi3Int16, const)
ARRAY_ACCESS(fmi3SetUInt16, fmi3UInt16, const)
ARRAY_ACCESS(fmi3SetUInt32, fmi3UInt32, const)
ARRAY_ACCESS(fmi3SetInt64, fmi3Int64, const)
ARRAY_ACCESS(fmi3SetUInt64, fmi3UInt64, const)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues) {
    return unsupported(instance, "fmi3GetBinary");
}
fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues) {
    return unsupported(instance, "fmi3SetBinary");
}
fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        fmi3Clock values[]) {
    return unsupported(instance, "fmi3GetClock");
}
fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                        const fmi3Clock values[]) {
    return unsupported(instance, "fmi3SetClock");
}
fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference vr,
                                               size_t *nDependencies) {
    return unsupported(instance, "fmi3GetNumberOfVariableDependencies");
}
fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    return unsupported(instance, "fmi3GetVariableDependencies");
}
fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance,
                                        const fmi3ValueReference unknowns[], size_t nUnknowns,
                                        const fmi3ValueReference knowns[], size_t nKnowns,
                                        const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity) {
    return unsupported(instance, "fmi3GetDirectionalDerivative");
}
fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity) {
    return unsupported(instance, "fmi3GetAdjointDerivative");
}

#define INSTANCE_ONLY(call) \
    fmi3Status call(fmi3Instance instance) { return unsupported(instance, #call); }
INSTANCE_ONLY(fmi3EnterConfigurationMode)
INSTANCE_ONLY(fmi3ExitConfigurationMode)
INSTANCE_ONLY(fmi3EvaluateDiscreteStates)
INSTANCE_ONLY(fmi3EnterStepMode)

#define CLOCK_DECIMAL(call, constness)                                                 \
    fmi3Status call(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,  \
                    constness fmi3Float64 values[]) {                                  \
        return unsupported(instance, #call);                                           \
    }
CLOCK_DECIMAL(fmi3GetShiftDecimal, )
CLOCK_DECIMAL(fmi3SetIntervalDecimal, const)
CLOCK_DECIMAL(fmi3SetShiftDecimal, const)

#define CLOCK_FRACTION(call, constness)                                                \
    fmi3Status call(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,  \
                    constness fmi3UInt64 counters[], constness fmi3UInt64 resolutions[]) { \
        return unsupported(instance, #call);                                           \
    }
CLOCK_FRACTION(fmi3GetShiftFraction, )
CLOCK_FRACTION(fmi3SetIntervalFraction, const)
CLOCK_FRACTION(fmi3SetShiftFraction, const)

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference vr[],
                                  size_t nvr, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    return unsupported(instance, "fmi3GetIntervalDecimal");
}
fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference vr[],
                                   size_t nvr, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[]) {
    return unsupported(instance, "fmi3GetIntervalFraction");
}
fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference vr[],
                                    size_t nvr, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues) {
    return unsupported(instance, "fmi3GetOutputDerivatives");
}
fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    return unsupported(instance, "fmi3ActivateModelPartition");
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    return NULL;
}

#ifdef FW_MODEL_EXCHANGE
#include "me/fmi3_model_exchange.c"
#else
/* Model exchange and event mode (not declared). */
INSTANCE_ONLY(fmi3EnterEventMode)
INSTANCE_ONLY(fmi3EnterContinuousTimeMode)
fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    return unsupported(instance, "fmi3UpdateDiscreteStates");
}
fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    return NULL;
}
fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    return unsupported(instance, "fmi3CompletedIntegratorStep");
}
fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    return unsupported(instance, "fmi3SetTime");
}

#define STATE_VECTOR(call, constness)                                                \
    fmi3Status call(fmi3Instance instance, constness fmi3Float64 values[], size_t n) { \
        return unsupported(instance, #call);                                         \
    }
STATE_VECTOR(fmi3SetContinuousStates, const)
STATE_VECTOR(fmi3GetContinuousStateDerivatives, )
STATE_VECTOR(fmi3GetEventIndicators, )
STATE_VECTOR(fmi3GetContinuousStates, )
STATE_VECTOR(fmi3GetNominalsOfContinuousStates, )

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *n) {
    return unsupported(instance, "fmi3GetNumberOfEventIndicators");
}
fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *n) {
    return unsupported(instance, "fmi3GetNumberOfContinuousStates");
}
#endif /* FW_MODEL_EXCHANGE */
