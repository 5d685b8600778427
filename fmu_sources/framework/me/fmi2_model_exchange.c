/*
 * fmi2_model_exchange.c -- the FMI 2.0 model-exchange functions on the framework's model.
 *
 * Included at the end of fmi2_cosimulation.c when the builder compiles a model-exchange FMU
 * (-DFW_MODEL_EXCHANGE, `fmu-greybox fmu build --interface me`); not a translation unit of its
 * own. The model is the one the co-simulation build integrates with rosenbrock.c: its states
 * d->x, model_derivatives, model_project and model_after_step, nothing duplicated. The master's
 * integrator owns the states between its calls:
 *
 *   fmi2SetTime, fmi2SetContinuousStates    the point it evaluates
 *   fmi2GetDerivatives                      model_derivatives there
 *   fmi2CompletedIntegratorStep             after each accepted step: model_after_step (the
 *                                           truth model's delay line) or, where model_project
 *                                           would move the states (an end stop, the cavitation
 *                                           floor), a request for event mode
 *   fmi2NewDiscreteStates                   (event mode) applies model_project and says the
 *                                           states changed
 *
 * as the co-simulation build projects and records after each of its internal steps. No event
 * indicators: the stops act at completed steps, as in fmi2DoStep.
 *
 * On the admissible set's boundary the derivatives are those of the motion held there: a
 * state component that model_project put exactly on the boundary (a ram against its stop at
 * zero velocity, a chamber at the cavitation floor) has derivative 0 while the projection would
 * put it back there after two explicit Euler steps of solver_step along the derivatives (the
 * model pushes outward), as the co-simulation build's next internal step would. Held against a
 * stop, the states then stay on it instead of crossing it at every integrator step (an event
 * and a restart of the integrator each time); off the boundary the derivatives are the model's.
 *
 * The states and their derivatives are variables of the model description, with value
 * references past the table's (the table's count is the FMI 3.0 time): FW_VR_STATES + i and
 * FW_VR_DERIVATIVES + i for state i; fmi2GetReal reads them.
 */

#define FW_VR_STATES (N_VALUE_REFERENCES + 1)
#define FW_VR_DERIVATIVES (FW_VR_STATES + N_STATES)

/* The variable table declares as many states as config.h has (compile-time check). */
typedef char fw_declared_states_match_config_h[(FW_DECLARED_STATES == N_STATES) ? 1 : -1];

/* The instance, if made for model exchange and in one of the phases of mask; with
 * continuous >= 0 also in that mode (0 event mode, 1 continuous-time mode). */
static Instance *me_instance(fmi2Component c, const char *call, unsigned mask, int continuous) {
    Instance *inst = (Instance *)c;
    if (!inst) return NULL;
    if (!inst->model_exchange) {
        refuse(inst, call, "the instance was made for co-simulation: fmi2DoStep advances it.");
        return NULL;
    }
    if (!allowed_in(inst, call, mask)) return NULL;
    if (continuous >= 0 && inst->data.phase == FW_STEP_COMPLETE &&
        inst->continuous_time != continuous) {
        refuse(inst, call, "not allowed in %s; call it in %s.", phase_label(inst),
               continuous ? "continuous-time mode (fmi2EnterContinuousTimeMode)"
                          : "event mode (fmi2EnterEventMode)");
        return NULL;
    }
    return inst;
}

/* The derivatives at d's states: the model's, held at 0 where a state sits on the boundary
 * and the model pushes it outward (see the top of this file). */
static void me_derivatives(const SimData *d, double dx[N_STATES]) {
    const double ahead = d->real[FW_SOLVER_STEP];
    double probe[N_STATES], slope[N_STATES], projected[N_STATES];
    model_derivatives(d, d->x, dx);
    for (int i = 0; i < N_STATES; i++) probe[i] = d->x[i] + ahead * dx[i];
    model_derivatives(d, probe, slope);
    for (int i = 0; i < N_STATES; i++) probe[i] += ahead * slope[i];
    memcpy(projected, probe, sizeof projected);
    model_project(d, projected);
    for (int i = 0; i < N_STATES; i++) {
        if (projected[i] == d->x[i] && probe[i] != d->x[i]) dx[i] = 0.0;
    }
}

static int me_count(Instance *inst, const char *call, size_t n, size_t expected,
                    const char *what) {
    if (n == expected) return 1;
    refuse(inst, call, "%zu %s given, the model has %zu.", n, what, expected);
    return 0;
}

/* In initialization mode the states are those model_initialize gives (as for the outputs). */
static void me_initial_states(Instance *inst) {
    if (inst->data.phase == FW_INITIALIZATION_MODE) model_initialize(&inst->data);
}

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    Instance *inst = me_instance(c, "fmi2EnterEventMode", IN(FW_STEP_COMPLETE), -1);
    if (!inst) return fmi2Error;
    inst->continuous_time = 0;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    static const char *const call = "fmi2NewDiscreteStates";
    Instance *inst = me_instance(c, call, IN(FW_STEP_COMPLETE), 0);
    SimData *d;
    double projected[N_STATES];
    char message[512];
    if (!inst) return fmi2Error;
    if (!eventInfo) return refuse(inst, call, "eventInfo is NULL.");
    d = &inst->data;
    if (check_parameters(inst, call) != fmi2OK) return fmi2Error;
    memset(eventInfo, 0, sizeof *eventInfo);
    memcpy(projected, d->x, sizeof projected);
    model_project(d, projected);
    if (memcmp(projected, d->x, sizeof projected) != 0) {
        memcpy(d->x, projected, sizeof projected);
        d->outputs_valid = 0;
        eventInfo->valuesOfContinuousStatesChanged = fmi2True;
    }
    if (inst->projection_due) {
        inst->projection_due = 0;
        if (model_after_step(d, message, sizeof message) != 0) {
            return fail(inst, call, "at t = %.9g s: %s", d->time, message);
        }
        d->outputs_valid = 0;
    }
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    Instance *inst = me_instance(c, "fmi2EnterContinuousTimeMode", IN(FW_STEP_COMPLETE), 0);
    if (!inst) return fmi2Error;
    inst->continuous_time = 1;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c,
                                       fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode,
                                       fmi2Boolean *terminateSimulation) {
    static const char *const call = "fmi2CompletedIntegratorStep";
    Instance *inst = me_instance(c, call, IN(FW_STEP_COMPLETE), 1);
    SimData *d;
    double projected[N_STATES];
    char message[512];
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!inst) return fmi2Error;
    if (!enterEventMode || !terminateSimulation) {
        return refuse(inst, call, "enterEventMode and terminateSimulation must not be NULL.");
    }
    d = &inst->data;
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    memcpy(projected, d->x, sizeof projected);
    model_project(d, projected);
    if (memcmp(projected, d->x, sizeof projected) != 0) { /* the event projects, then records */
        inst->projection_due = 1;
        *enterEventMode = fmi2True;
        return fmi2OK;
    }
    if (model_after_step(d, message, sizeof message) != 0) {
        return fail(inst, call, "at t = %.9g s: %s", d->time, message);
    }
    d->outputs_valid = 0;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    static const char *const call = "fmi2SetTime";
    Instance *inst = me_instance(c, call, IN(FW_STEP_COMPLETE), -1);
    if (!inst) return fmi2Error;
    if (!isfinite(time)) return refuse(inst, call, "time = %g s is not finite.", time);
    inst->data.time = time;
    inst->data.outputs_valid = 0;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    static const char *const call = "fmi2SetContinuousStates";
    Instance *inst = me_instance(c, call, IN(FW_STEP_COMPLETE), 1);
    if (!inst || !me_count(inst, call, nx, N_STATES, "states")) return fmi2Error;
    for (size_t i = 0; i < nx; i++) {
        if (!isfinite(x[i])) {
            return refuse(inst, call, "state %zu = %g is not finite.", i, x[i]);
        }
    }
    memcpy(inst->data.x, x, sizeof inst->data.x);
    inst->data.outputs_valid = 0;
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    static const char *const call = "fmi2GetDerivatives";
    Instance *inst = me_instance(c, call, MASK_GET, -1);
    SimData *d;
    if (!inst || !me_count(inst, call, nx, N_STATES, "derivatives")) return fmi2Error;
    d = &inst->data;
    if (check_parameters(inst, call) != fmi2OK) return fmi2Error;
    me_initial_states(inst);
    me_derivatives(d, derivatives);
    for (size_t i = 0; i < nx; i++) {
        if (!isfinite(derivatives[i])) {
            return fail(inst, call, "the derivative of state %zu is %g at t = %.9g s; check the "
                        "parameters, inputs and states.", i, derivatives[i], d->time);
        }
    }
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    static const char *const call = "fmi2GetEventIndicators";
    Instance *inst = me_instance(c, call, MASK_GET, -1);
    (void)eventIndicators;
    return inst && me_count(inst, call, ni, 0, "event indicators") ? fmi2OK : fmi2Error;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    static const char *const call = "fmi2GetContinuousStates";
    Instance *inst = me_instance(c, call, MASK_GET, -1);
    if (!inst || !me_count(inst, call, nx, N_STATES, "states")) return fmi2Error;
    me_initial_states(inst);
    memcpy(x, inst->data.x, sizeof inst->data.x);
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    static const char *const call = "fmi2GetNominalsOfContinuousStates";
    Instance *inst = me_instance(c, call, MASK_FMU_STATE, -1);
    if (!inst || !me_count(inst, call, nx, N_STATES, "nominals")) return fmi2Error;
    memcpy(x_nominal, model_state_nominal, sizeof model_state_nominal);
    return fmi2OK;
}

/* fmi2GetReal with states (FW_VR_STATES + i) and derivatives (FW_VR_DERIVATIVES + i) among
 * the value references: one by one. */
static fmi2Status me_get_real(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                              fmi2Real value[]) {
    Instance *inst = (Instance *)c;
    double dx[N_STATES];
    if (!inst || !allowed(inst, CALL_GET_REAL)) return fmi2Error;
    for (size_t i = 0; i < nvr; i++) {
        const fmi2ValueReference r = vr[i];
        fmi2Status status = fmi2OK;
        if (r >= FW_VR_STATES && r < FW_VR_STATES + N_STATES) {
            me_initial_states(inst);
            value[i] = inst->data.x[r - FW_VR_STATES];
        } else if (r >= FW_VR_DERIVATIVES && r < FW_VR_DERIVATIVES + N_STATES) {
            me_initial_states(inst);
            me_derivatives(&inst->data, dx);
            value[i] = dx[r - FW_VR_DERIVATIVES];
        } else {
            status = get_values(c, CALL_GET_REAL, &vr[i], 1, FW_REAL, &value[i], read_real);
        }
        if (status != fmi2OK) return status;
    }
    return fmi2OK;
}
