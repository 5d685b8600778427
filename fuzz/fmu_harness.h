/*
 * fmu_harness.h -- what the libFuzzer targets that run an exported native grey-box FMU share
 * (fuzz_fmu_state.c, fuzz_fmu_inputs.c): the environment they read, a silent logger, and one
 * instance of the FMU, instantiated and initialised once per process.
 *
 * Each target is linked with the sources/ of an exported native FMU (they carry its GUID and
 * data hash). Environment: FUZZ_FMU_DIR (the unpacked FMU) and FUZZ_DT (its step [s]).
 * Built and run by tests/test_fuzz.py.
 */
#ifndef FMU_HARNESS_H
#define FMU_HARNESS_H

#include <stdio.h>
#include <stdlib.h>

#include "fmi2Functions.h"
#include "greybox_config.h"

static fmi2Component instance;
static double dt, now;

static void quiet(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                  fmi2String category, fmi2String message, ...) {
    (void)env, (void)name, (void)status, (void)category, (void)message;
}

static const fmi2CallbackFunctions callbacks = {quiet, calloc, free, NULL, NULL};

/* Setup and initialisation with the start values, at t = 0; 0 when all succeed. */
static int harness_initialise(void) {
    now = 0.0;
    return fmi2SetupExperiment(instance, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK ||
           fmi2EnterInitializationMode(instance) != fmi2OK ||
           fmi2ExitInitializationMode(instance) != fmi2OK;
}

/* The instance, instantiated from FUZZ_FMU_DIR and initialised; exits (2) if it cannot be. */
static void harness_start(void) {
    const char *folder = getenv("FUZZ_FMU_DIR"), *step = getenv("FUZZ_DT");
    char location[4096];
    if (folder == NULL || step == NULL) {
        fprintf(stderr, "set FUZZ_FMU_DIR (an unpacked native FMU) and FUZZ_DT\n");
        exit(2);
    }
    dt = atof(step);
    snprintf(location, sizeof location, "file://%s/resources", folder);
    instance = fmi2Instantiate("fuzz", fmi2CoSimulation, GREYBOX_GUID, location, &callbacks,
                               fmi2False, fmi2False);
    if (instance == NULL || harness_initialise() != 0) {
        fprintf(stderr, "the FMU in %s does not start\n", folder);
        exit(2);
    }
}

#endif
