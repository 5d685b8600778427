/*
 * c_master.c -- a bare FMI 2.0 co-simulation master in C, with no Python in its process.
 *
 * It does what a native bench does with an FMU: dlopen its binary, instantiate it with a logger,
 * initialise it with the first row of inputs, then per row set the inputs, fmi2DoStep and read
 * the outputs. Used by tests/test_native_fmu.py (equivalence, no Python in the process) and by
 * benchmarks/bench_export.py (cost per step, beside the white-box alone in the same master).
 *
 *   c_master FMU_DIR IDENTIFIER GUID STEP INPUT_VRS OUTPUT_VRS INPUTS OUTPUTS [REPEATS]
 *
 * FMU_DIR: the FMU unpacked; INPUT_VRS, OUTPUT_VRS: comma-separated value references; INPUTS: a
 * text file of rows of input values (whitespace-separated); OUTPUTS: written with the outputs
 * after each step, 17 significant digits. With REPEATS > 1 the run is repeated from
 * initialisation (fmi2Reset) and the least CPU time per step is printed. Prints
 * "steps N", "cpu_us_per_step X" and "python_in_process yes|no" (from /proc/self/maps), then
 * the status of three steps a bench must see refused, each from a fresh initialisation with
 * the first row: "refused_step_size S" (twice the step), "refused_time_jump S" (from 0.5 s
 * while the FMU is at 0 s) and "refused_input S" (every input 1e30).
 * Exit status 1 when a call fails (the FMU's messages are on stderr).
 *
 * It loads the FMU's binary for the platform it is compiled for (native/dynlib.h: dlopen, or
 * LoadLibrary on Windows, where it runs under Wine in the tests).
 *
 * Build: gcc -O2 -std=c11 -I<fmi2 headers> -I<fmu_greybox/native> c_master.c -o c_master -ldl
 *   or:  x86_64-w64-mingw32-gcc -O2 -std=c11 -static -I... c_master.c -o c_master.exe
 */
#define _POSIX_C_SOURCE 200809L
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "dynlib.h"
#include "fmi2Functions.h"

typedef struct {
    fmi2InstantiateTYPE *instantiate;
    fmi2FreeInstanceTYPE *free_instance;
    fmi2SetupExperimentTYPE *setup;
    fmi2EnterInitializationModeTYPE *enter;
    fmi2ExitInitializationModeTYPE *exit_init;
    fmi2ResetTYPE *reset;
    fmi2TerminateTYPE *terminate;
    fmi2SetRealTYPE *set_real;
    fmi2GetRealTYPE *get_real;
    fmi2DoStepTYPE *do_step;
} Api;

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                   fmi2String category, fmi2String message, ...) {
    va_list args;
    (void)env, (void)category;
    fprintf(stderr, "[%s, status %d] ", name, (int)status);
    va_start(args, message);
    vfprintf(stderr, message, args);
    va_end(args);
    fputc('\n', stderr);
}

static void *symbol(void *library, const char *name) {
    void *found = dynlib_symbol(library, name);
    if (found == NULL) {
        fprintf(stderr, "the FMU lacks %s\n", name);
        exit(1);
    }
    return found;
}

static void check(fmi2Status status, const char *call) {
    if (status > fmi2Warning) {
        fprintf(stderr, "%s returned status %d\n", call, (int)status);
        exit(1);
    }
}

/* Comma-separated value references into vr; returns how many. */
static size_t references(const char *text, fmi2ValueReference *vr, size_t capacity) {
    size_t n = 0;
    char *end;
    while (*text != '\0' && n < capacity) {
        vr[n++] = (fmi2ValueReference)strtoul(text, &end, 10);
        text = *end == ',' ? end + 1 : end;
    }
    return n;
}

/* Every number of a text file into *values; returns how many. */
static size_t read_numbers(const char *path, double **values) {
    size_t n = 0, capacity = 1024;
    FILE *file = fopen(path, "r");
    double v;
    if (file == NULL) {
        fprintf(stderr, "cannot open %s\n", path);
        exit(1);
    }
    *values = malloc(capacity * sizeof(double));
    while (fscanf(file, "%lf", &v) == 1) {
        if (n == capacity) *values = realloc(*values, (capacity *= 2) * sizeof(double));
        (*values)[n++] = v;
    }
    fclose(file);
    return n;
}

static int python_in_process(void) {
    char line[4096];
    int found = 0;
    FILE *maps = fopen("/proc/self/maps", "r");
    if (maps == NULL) return -1;
    while (fgets(line, sizeof line, maps) != NULL) found |= strstr(line, "python") != NULL;
    fclose(maps);
    return found;
}

static double cpu_seconds(void) {
#if defined(_WIN32)
    FILETIME created, exited, kernel, user; /* 100 ns units */
    GetProcessTimes(GetCurrentProcess(), &created, &exited, &kernel, &user);
    return 1e-7 * (double)(((unsigned long long)user.dwHighDateTime << 32) | user.dwLowDateTime);
#else
    struct timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
#endif
}

/* Set up the experiment at 0 s and initialise with the inputs u. */
static void initialise(const Api *api, fmi2Component c, const fmi2ValueReference *in_vr,
                       size_t n_in, const double *u) {
    check(api->setup(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), "fmi2SetupExperiment");
    check(api->set_real(c, in_vr, n_in, u), "fmi2SetReal");
    check(api->enter(c), "fmi2EnterInitializationMode");
    check(api->exit_init(c), "fmi2ExitInitializationMode");
}

/* Initialise with the first row, then step over the rows; the outputs into out. Returns the
 * CPU time of the stepping loop [s]. */
static double run(const Api *api, fmi2Component c, double step, const fmi2ValueReference *in_vr,
                  size_t n_in, const fmi2ValueReference *out_vr, size_t n_out, const double *u,
                  size_t rows, double *out) {
    double started;
    initialise(api, c, in_vr, n_in, u);
    started = cpu_seconds();
    for (size_t k = 0; k < rows; k++) {
        check(api->set_real(c, in_vr, n_in, u + k * n_in), "fmi2SetReal");
        check(api->do_step(c, (double)k * step, step, fmi2True), "fmi2DoStep");
        check(api->get_real(c, out_vr, n_out, out + k * n_out), "fmi2GetReal");
    }
    return cpu_seconds() - started;
}

/* The status of one step (from time, of size h, inputs u) after a fresh initialisation with
 * the first row u0; the FMU is reset after. */
static int probe(const Api *api, fmi2Component c, const fmi2ValueReference *in_vr, size_t n_in,
                 const double *u0, const double *u, double time, double h) {
    int status;
    initialise(api, c, in_vr, n_in, u0);
    status = (int)api->set_real(c, in_vr, n_in, u);
    if (status <= fmi2Warning) status = (int)api->do_step(c, time, h, fmi2True);
    check(api->reset(c), "fmi2Reset");
    return status;
}

/* Print the status of the three steps a bench must see refused (see the header). */
static void print_refusals(const Api *api, fmi2Component c, double step,
                           const fmi2ValueReference *in_vr, size_t n_in, const double *u) {
    double *absurd = malloc((n_in + 1) * sizeof(double));
    for (size_t i = 0; i < n_in; i++) absurd[i] = 1e30;
    printf("refused_step_size %d\n", probe(api, c, in_vr, n_in, u, u, 0.0, 2.0 * step));
    printf("refused_time_jump %d\n", probe(api, c, in_vr, n_in, u, u, 0.5, step));
    printf("refused_input %d\n", probe(api, c, in_vr, n_in, u, absurd, 0.0, step));
    free(absurd);
}

int main(int argc, char **argv) {
    fmi2ValueReference in_vr[256], out_vr[256];
    fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};
    char path[4096], uri[4200];
    double *u, *out, best = 1e300;
    size_t n_in, n_out, rows;
    int repeats;
    void *library;
    fmi2Component c;
    Api api;
    FILE *file;
    if (argc < 9) {
        fprintf(stderr, "usage: %s FMU_DIR IDENTIFIER GUID STEP INPUT_VRS OUTPUT_VRS INPUTS "
                "OUTPUTS [REPEATS]\n", argv[0]);
        return 2;
    }
    repeats = argc > 9 ? atoi(argv[9]) : 1;
    snprintf(path, sizeof path, "%s/binaries/" DYNLIB_PLATFORM "/%s" DYNLIB_EXTENSION, argv[1],
             argv[2]);
    library = dynlib_open(path);
    if (library == NULL) {
        char reason[512];
        fprintf(stderr, "loading %s: %s\n", path, dynlib_error(reason, sizeof reason));
        return 1;
    }
    api.instantiate = symbol(library, "fmi2Instantiate");
    api.free_instance = symbol(library, "fmi2FreeInstance");
    api.setup = symbol(library, "fmi2SetupExperiment");
    api.enter = symbol(library, "fmi2EnterInitializationMode");
    api.exit_init = symbol(library, "fmi2ExitInitializationMode");
    api.reset = symbol(library, "fmi2Reset");
    api.terminate = symbol(library, "fmi2Terminate");
    api.set_real = symbol(library, "fmi2SetReal");
    api.get_real = symbol(library, "fmi2GetReal");
    api.do_step = symbol(library, "fmi2DoStep");
    n_in = references(argv[5], in_vr, 256);
    n_out = references(argv[6], out_vr, 256);
    rows = read_numbers(argv[7], &u) / n_in;
    out = calloc(rows * n_out + 1, sizeof(double));
    snprintf(uri, sizeof uri, "file://%s/resources", argv[1]);
    c = api.instantiate("c_master", fmi2CoSimulation, argv[3], uri, &callbacks, fmi2False,
                        fmi2False);
    if (c == NULL) {
        fprintf(stderr, "fmi2Instantiate returned NULL\n");
        return 1;
    }
    for (int r = 0; r < repeats; r++) {
        const double cpu = run(&api, c, atof(argv[4]), in_vr, n_in, out_vr, n_out, u, rows, out);
        if (cpu < best) best = cpu;
        check(api.reset(c), "fmi2Reset");
    }
    file = fopen(argv[8], "w");
    for (size_t k = 0; file != NULL && k < rows; k++) {
        for (size_t i = 0; i < n_out; i++) {
            fprintf(file, "%.17g%c", out[k * n_out + i], i + 1 < n_out ? ' ' : '\n');
        }
    }
    if (file != NULL) fclose(file);
    printf("steps %zu\ncpu_us_per_step %.3f\npython_in_process %s\n", rows,
           1e6 * best / (double)rows, python_in_process() ? "yes" : "no");
    print_refusals(&api, c, atof(argv[4]), in_vr, n_in, u);
    api.free_instance(c);
    dynlib_close(library);
    free(u);
    free(out);
    return 0;
}
