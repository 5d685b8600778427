/*
 * fmi3_model_exchange.c -- the FMI 3.0 model-exchange functions as a face over the FMI 2.0
 * ones (me/fmi2_model_exchange.c).
 *
 * Included at the end of the FMI 3.0 face, fmu_greybox/native/fmi3_shell.c, when the builder
 * compiles an FMI 3.0 model-exchange FMU (-DFW_MODEL_EXCHANGE); not a translation unit of its
 * own. Each call translates its arguments and calls the FMI 2.0 function doing the work, as the
 * co-simulation face does, so the FMI 2.0 and FMI 3.0 model-exchange builds evaluate the same
 * derivatives.
 */

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    return face_new(instanceName, fmi2ModelExchange, instantiationToken, resourcePath, visible,
                    loggingOn, instanceEnvironment, logMessage);
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    return instance ? status3(fmi2EnterEventMode(INNER(instance))) : fmi3Error;
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    fmi2EventInfo info;
    fmi2Status status;
    if (!instance) return fmi3Error;
    memset(&info, 0, sizeof info);
    status = fmi2NewDiscreteStates(INNER(instance), &info);
    if (discreteStatesNeedUpdate) *discreteStatesNeedUpdate = info.newDiscreteStatesNeeded != 0;
    if (terminateSimulation) *terminateSimulation = info.terminateSimulation != 0;
    if (nominalsOfContinuousStatesChanged) {
        *nominalsOfContinuousStatesChanged = info.nominalsOfContinuousStatesChanged != 0;
    }
    if (valuesOfContinuousStatesChanged) {
        *valuesOfContinuousStatesChanged = info.valuesOfContinuousStatesChanged != 0;
    }
    if (nextEventTimeDefined) *nextEventTimeDefined = info.nextEventTimeDefined != 0;
    if (nextEventTime) *nextEventTime = info.nextEventTime;
    return status3(status);
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    return instance ? status3(fmi2EnterContinuousTimeMode(INNER(instance))) : fmi3Error;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    fmi2Boolean enter = fmi2False, terminate = fmi2False;
    fmi2Status status;
    if (!instance) return fmi3Error;
    status = fmi2CompletedIntegratorStep(INNER(instance), noSetFMUStatePriorToCurrentPoint,
                                         &enter, &terminate);
    if (enterEventMode) *enterEventMode = enter != fmi2False;
    if (terminateSimulation) *terminateSimulation = terminate != fmi2False;
    return status3(status);
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    return instance ? status3(fmi2SetTime(INNER(instance), time)) : fmi3Error;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 values[], size_t n) {
    return instance ? status3(fmi2SetContinuousStates(INNER(instance), values, n)) : fmi3Error;
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 values[],
                                             size_t n) {
    return instance ? status3(fmi2GetDerivatives(INNER(instance), values, n)) : fmi3Error;
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 values[], size_t n) {
    return instance ? status3(fmi2GetEventIndicators(INNER(instance), values, n)) : fmi3Error;
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 values[], size_t n) {
    return instance ? status3(fmi2GetContinuousStates(INNER(instance), values, n)) : fmi3Error;
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 values[],
                                             size_t n) {
    if (!instance) return fmi3Error;
    return status3(fmi2GetNominalsOfContinuousStates(INNER(instance), values, n));
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *n) {
    if (!instance || !n) return fmi3Error;
    *n = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *n) {
    if (!instance || !n) return fmi3Error;
    *n = N_STATES;
    return fmi3OK;
}
