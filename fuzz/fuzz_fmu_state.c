/*
 * fuzz_fmu_state.c -- libFuzzer target for a restored state of the native grey-box FMU:
 * fmi2DeSerializeFMUstate, then fmi2SetFMUstate and fmi2DoStep where it is accepted.
 *
 * Each input is a state's body: the harness appends the SHA-256 trailer a state ends with, as
 * a forger would, so the fuzzer reaches the check of every field behind the hash. Environment:
 * that of fmu_harness.h (FUZZ_FMU_DIR, FUZZ_DT), and FUZZ_WRITE_SEED (optional: a file that
 * receives the body of the state after 5 steps, a seed for the corpus). Built and run by
 * tests/test_fuzz.py.
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu_harness.h"
#include "sha256.h"

static void write_seed(const char *path) {
    fmi2FMUstate state = NULL;
    size_t size = 0;
    fmi2GetFMUstate(instance, &state);
    fmi2SerializedFMUstateSize(instance, state, &size);
    char *bytes = malloc(size);
    fmi2SerializeFMUstate(instance, state, bytes, size);
    FILE *file = fopen(path, "wb");
    if (file != NULL) {
        fwrite(bytes, 1, size - 64, file); /* the body, without its SHA-256 trailer */
        fclose(file);
    }
    free(bytes);
    fmi2FreeFMUstate(instance, &state);
}

int LLVMFuzzerInitialize(int *argc, char ***argv) {
    (void)argc, (void)argv;
    harness_start();
    for (int k = 0; k < 5; k++, now += dt) fmi2DoStep(instance, now, dt, fmi2True);
    if (getenv("FUZZ_WRITE_SEED") != NULL) write_seed(getenv("FUZZ_WRITE_SEED"));
    return 0;
}

int LLVMFuzzerTestOneInput(const uint8_t *body, size_t size) {
    char *bytes = malloc(size + 64), hex[65];
    fmi2FMUstate state = NULL;
    if (bytes == NULL) return 0;
    memcpy(bytes, body, size);
    sha256_bytes(body, size, hex);
    memcpy(bytes + size, hex, 64);
    if (fmi2DeSerializeFMUstate(instance, bytes, size + 64, &state) == fmi2OK) {
        /* the seed's time: a state saved there steps on from it (others are refused) */
        if (fmi2SetFMUstate(instance, state) == fmi2OK) fmi2DoStep(instance, now, dt, fmi2True);
        fmi2FreeFMUstate(instance, &state);
    }
    free(bytes);
    return 0;
}
