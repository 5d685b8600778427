/*
 * me_step.c -- one communication step of a model-exchange FMU integrated by CVode, in C.
 *
 * fmu_greybox/fmi/integrator.py makes CVode (the SUNDIALS fmpy ships) and hands this file's
 * functions the FMU's model-exchange functions and CVode's, as pointers: no SUNDIALS or FMI
 * header is needed, and nothing here is linked to either library. fgb_me_rhs is CVode's
 * right-hand side (time and states into the FMU, its derivatives out); fgb_me_step restarts
 * CVode from the FMU's states, integrates to the step's end one internal step at a time,
 * tells the FMU each completed step and handles the events it asks for, as the Python loop
 * of integrator.py does (the reference this is tested against): the same calls in the same
 * order, without Python between them. Compiled on first use and cached
 * (integrator.py, me_library).
 */
#include <stdbool.h>
#include <stddef.h>
#include <string.h>

/* CVode's itask and return values (cvode.h). */
#define CV_ONE_STEP 2
#define CV_TSTOP_RETURN 1

/* The FMU calls this file makes, in the order of FgbCall (what a failure names). */
enum {
    CALL_SET_TIME,
    CALL_SET_STATES,
    CALL_GET_STATES,
    CALL_DERIVATIVES,
    CALL_COMPLETED,
    CALL_EVENT_MODE,
    CALL_DISCRETE,
    CALL_CONTINUOUS_MODE,
    CALL_CVODE, /* CVode itself (status: its flag) */
    CALL_TERMINATE, /* the FMU asked to terminate (status: the call that asked) */
    CALL_TIME_EVENT /* the FMU asked for a time event (not supported) */
};

/* fmi2EventInfo (fmi2FunctionTypes.h): fmi2Boolean is an int. */
typedef struct {
    int newDiscreteStatesNeeded;
    int terminateSimulation;
    int nominalsOfContinuousStatesChanged;
    int valuesOfContinuousStatesChanged;
    int nextEventTimeDefined;
    double nextEventTime;
} EventInfo2;

typedef struct {
    void *component;
    int fmi3;      /* FMI 3.0 signatures of completed / discrete (bool), else FMI 2.0 (int) */
    size_t n;      /* continuous states */
    void *cvode;   /* CVode's memory */
    long max_steps; /* most internal steps in one communication step */
    void *x;       /* CVode's state vector (N_Vector) */
    /* the FMU's functions (status: 0 OK, 1 Warning, above: failure) */
    int (*set_time)(void *, double);
    int (*set_states)(void *, const double *, size_t);
    int (*get_states)(void *, double *, size_t);
    int (*derivatives)(void *, double *, size_t);
    void *completed;
    int (*event_mode)(void *);
    void *discrete;
    int (*continuous_mode)(void *);
    /* CVode's */
    int (*cv_step)(void *, double, void *, double *, int);
    int (*cv_reinit)(void *, double, void *);
    int (*cv_stop_time)(void *, double);
    double *(*array)(void *);
    /* out: the failed call (FgbCall), its status; internal steps and evaluations so far */
    int failed_call;
    int failed_status;
    long steps;
    long evaluations;
} FgbMe;

/* CVode's right-hand side; user data is the FgbMe. 0, or -1 (unrecoverable) when the FMU
 * refuses, with the call and status kept. */
int fgb_me_rhs(double t, void *y, void *ydot, void *user_data) {
    FgbMe *me = (FgbMe *)user_data;
    int status;
    me->evaluations++;
    if ((status = me->set_time(me->component, t)) > 1) {
        me->failed_call = CALL_SET_TIME;
    } else if ((status = me->set_states(me->component, me->array(y), me->n)) > 1) {
        me->failed_call = CALL_SET_STATES;
    } else if ((status = me->derivatives(me->component, me->array(ydot), me->n)) > 1) {
        me->failed_call = CALL_DERIVATIVES;
    } else {
        return 0;
    }
    me->failed_status = status;
    return -1;
}

static int fail(FgbMe *me, int call, int status) {
    me->failed_call = call;
    me->failed_status = status;
    return -1;
}

/* Event mode until no update is needed, then continuous-time mode; *changed: whether the
 * continuous states changed. 0 or -1. */
static int settle(FgbMe *me, int *changed) {
    int status;
    *changed = 0;
    for (int round = 0; round < 1000; round++) {
        int needed, terminate, values, timed;
        if (me->fmi3) {
            bool flags[5] = {false, false, false, false, false};
            double next = 0.0;
            status = ((int (*)(void *, bool *, bool *, bool *, bool *, bool *, double *))
                          me->discrete)(me->component, &flags[0], &flags[1], &flags[2],
                                        &flags[3], &flags[4], &next);
            needed = flags[0], terminate = flags[1], values = flags[3], timed = flags[4];
        } else {
            EventInfo2 info;
            memset(&info, 0, sizeof info);
            status = ((int (*)(void *, EventInfo2 *))me->discrete)(me->component, &info);
            needed = info.newDiscreteStatesNeeded, terminate = info.terminateSimulation;
            values = info.valuesOfContinuousStatesChanged, timed = info.nextEventTimeDefined;
        }
        if (status > 1) return fail(me, CALL_DISCRETE, status);
        if (terminate) return fail(me, CALL_TERMINATE, CALL_DISCRETE);
        if (timed) return fail(me, CALL_TIME_EVENT, 0);
        *changed = *changed || values;
        if (!needed) {
            status = me->continuous_mode(me->component);
            return status > 1 ? fail(me, CALL_CONTINUOUS_MODE, status) : 0;
        }
    }
    return fail(me, CALL_DISCRETE, -1);
}

/* After an accepted internal step at t (states in CVode's vector): the FMU takes them, then
 * the completed step; *restart when an event changed the states (now in CVode's vector).
 * 0 or -1. */
static int completed(FgbMe *me, double t, int *restart) {
    int status, enter, terminate, changed;
    double *x = me->array(me->x);
    *restart = 0;
    if ((status = me->set_time(me->component, t)) > 1) return fail(me, CALL_SET_TIME, status);
    if ((status = me->set_states(me->component, x, me->n)) > 1) {
        return fail(me, CALL_SET_STATES, status);
    }
    if (me->fmi3) {
        bool e = false, s = false;
        status = ((int (*)(void *, bool, bool *, bool *))me->completed)(me->component, true,
                                                                          &e, &s);
        enter = e, terminate = s;
    } else {
        int e = 0, s = 0;
        status = ((int (*)(void *, int, int *, int *))me->completed)(me->component, 1, &e, &s);
        enter = e, terminate = s;
    }
    if (status > 1) return fail(me, CALL_COMPLETED, status);
    if (terminate) return fail(me, CALL_TERMINATE, CALL_COMPLETED);
    if (!enter) return 0;
    if ((status = me->event_mode(me->component)) > 1) return fail(me, CALL_EVENT_MODE, status);
    if (settle(me, &changed) != 0) return -1;
    if (!changed) return 0;
    if ((status = me->get_states(me->component, x, me->n)) > 1) {
        return fail(me, CALL_GET_STATES, status);
    }
    *restart = 1;
    return 0;
}

/* One communication step from start to stop: the FMU's states at start are taken, CVode
 * restarted from them and stopped at stop. 0, or -1 with the failed call and status. */
int fgb_me_step(FgbMe *me, double start, double stop) {
    double *x = me->array(me->x);
    double reached = start;
    long taken = 0;
    int status, flag, restart = 1;
    me->failed_call = -1;
    me->failed_status = 0;
    if ((status = me->get_states(me->component, x, me->n)) > 1) {
        return fail(me, CALL_GET_STATES, status);
    }
    for (;;) {
        int done;
        if (restart) {
            if ((flag = me->cv_reinit(me->cvode, reached, me->x)) != 0 ||
                (flag = me->cv_stop_time(me->cvode, stop)) != 0) {
                return fail(me, CALL_CVODE, flag);
            }
        }
        flag = me->cv_step(me->cvode, stop, me->x, &reached, CV_ONE_STEP);
        if (flag < 0) return me->failed_call >= 0 ? -1 : fail(me, CALL_CVODE, flag);
        me->steps++;
        if (++taken > me->max_steps) return fail(me, CALL_CVODE, -1); /* CV_TOO_MUCH_WORK */
        done = flag == CV_TSTOP_RETURN || reached >= stop;
        if (completed(me, done ? stop : reached, &restart) != 0) return -1;
        if (done) return 0;
    }
}
