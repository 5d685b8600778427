/*
 * simulate.c -- an open-loop run of the white-box FMU with its named terms, all in C: what
 * fmu_greybox/model/simulate.py's run_open_loop does with a NamedModel, without Python between
 * the steps. The white-box and its terms are laid out by the data file the native grey-box FMU
 * reads (whitebox.h, greybox_data.h); fmu_greybox/model/native_run.py builds this file into a
 * shared library on first use and calls fgb_simulate through ctypes.
 */
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "greybox_data.h"
#include "whitebox.h"

/* The white-box's last error-level log line (its reason for a failed call). */
typedef struct {
    char text[1024];
} LastError;

static void keep_error(fmi2ComponentEnvironment environment, fmi2String instance,
                       fmi2Status status, fmi2String category, fmi2String message, ...) {
    LastError *last = environment;
    va_list args;
    int written;
    (void)category;
    if (last == NULL || status < fmi2Error || message == NULL) return;
    written = snprintf(last->text, sizeof last->text, "%s: ", instance ? instance : "white-box");
    if (written < 0 || (size_t)written >= sizeof last->text) return;
    va_start(args, message);
    vsnprintf(last->text + written, sizeof last->text - (size_t)written, message, args);
    va_end(args);
}

static void *allocate(size_t n, size_t size) { return calloc(n, size); }
static void release(void *p) { free(p); }

/* Run the white-box laid out by the data file at data_path (checked against data_sha256) over
 * n_rows input rows u (n_rows x n_inputs, row-major), from start_time with steps of dt. y
 * (n_rows x n_outputs) gets row 0 the initial outputs and row k + 1 those after applying
 * u[k]. resources_dir holds whitebox/: the unpacked white-box FMU. Returns 0, or -1 with a
 * message (the white-box's own reason appended when it logged one). */
int fgb_simulate(const char *data_path, const char *data_sha256, const char *resources_dir,
                 double dt, double start_time, const double *u, ptrdiff_t n_rows, double *y,
                 char *message, size_t size) {
    GreyboxData data;
    Whitebox w;
    LastError last;
    fmi2CallbackFunctions callbacks = {keep_error, allocate, release, NULL, &last};
    int status;
    memset(&data, 0, sizeof data);
    memset(&w, 0, sizeof w);
    last.text[0] = '\0';
    w.allocate = allocate;
    w.release = release;
    status = data_read(&data, data_path, data_sha256, allocate, message, size);
    if (status == 0) {
        status = wb_open(&w, &data, resources_dir, "simulate", &callbacks, dt, message, size);
    }
    if (status == 0 && n_rows > 0) status = wb_start(&w, u, start_time, message, size);
    if (status == 0 && n_rows > 0) {
        wb_outputs(&w, y);
        for (ptrdiff_t k = 0; status == 0 && k + 1 < n_rows; k++) {
            status = wb_step(&w, u + k * w.n_inputs, message, size);
            if (status == 0) wb_outputs(&w, y + (k + 1) * w.n_outputs);
        }
    }
    if (status != 0 && last.text[0] != '\0') {
        const size_t used = strlen(message);
        if (used + 3 < size) snprintf(message + used, size - used, ": %s", last.text);
    }
    wb_terminate(&w);
    wb_close(&w);
    data_free(&data, release);
    return status;
}
