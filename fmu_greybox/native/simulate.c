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

/* The white-box's last LOG_KEPT log messages, "[status] text" (as the Python runtime's
 * FmuInstance quotes them in an error). */
#define LOG_KEPT 3
#define LOG_TEXT 512

typedef struct {
    char text[LOG_KEPT][LOG_TEXT];
    int count;
} RecentLog;

static const char *const STATUS_NAMES[] = {"fmi2OK",    "fmi2Warning", "fmi2Discard",
                                           "fmi2Error", "fmi2Fatal",   "fmi2Pending"};

static void keep_message(fmi2ComponentEnvironment environment, fmi2String instance,
                         fmi2Status status, fmi2String category, fmi2String message, ...) {
    RecentLog *log = environment;
    char *text;
    va_list args;
    int written;
    (void)instance;
    (void)category;
    if (log == NULL || message == NULL) return;
    text = log->text[log->count % LOG_KEPT];
    written = snprintf(text, LOG_TEXT, "[%s] ",
                       (int)status >= 0 && (int)status < 6 ? STATUS_NAMES[status] : "?");
    if (written < 0 || written >= LOG_TEXT) return;
    va_start(args, message);
    vsnprintf(text + written, LOG_TEXT - (size_t)written, message, args);
    va_end(args);
    log->count++;
}

/* The kept messages, oldest first, joined by " | ". */
static void recent_text(const RecentLog *log, char *out, size_t size) {
    const int first = log->count > LOG_KEPT ? log->count - LOG_KEPT : 0;
    size_t used = 0;
    out[0] = '\0';
    for (int k = first; k < log->count && used < size; k++) {
        const int n = snprintf(out + used, size - used, "%s%s", k > first ? " | " : "",
                               log->text[k % LOG_KEPT]);
        if (n < 0) break;
        used += (size_t)n;
    }
}

static void *allocate(size_t n, size_t size) { return calloc(n, size); }
static void release(void *p) { free(p); }

/* Run the white-box laid out by the data file at data_path (checked against data_sha256) over
 * n_rows input rows u (n_rows x n_inputs, row-major), from start_time with steps of dt. y
 * (n_rows x n_outputs) gets row 0 the initial outputs and row k + 1 those after applying
 * u[k]. resources_dir holds whitebox/: the unpacked white-box FMU.
 *
 * Returns 0, or -1 with a message. When a call of the white-box failed, failure gets its name
 * (empty otherwise), *fmi_status its status, *at the instance's time and log the white-box's
 * last messages. */
int fgb_simulate(const char *data_path, const char *data_sha256, const char *resources_dir,
                 double dt, double start_time, const double *u, ptrdiff_t n_rows, double *y,
                 char *message, size_t size, char *failure, size_t failure_size,
                 int *fmi_status, double *at, char *log_text, size_t log_size) {
    GreyboxData data;
    Whitebox w;
    RecentLog log;
    fmi2CallbackFunctions callbacks = {keep_message, allocate, release, NULL, &log};
    int status;
    memset(&data, 0, sizeof data);
    memset(&w, 0, sizeof w);
    log.count = 0;
    failure[0] = '\0';
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
    for (ptrdiff_t k = 0; status != 0 && k < w.n_parts && w.parts != NULL; k++) {
        const WbPart *p = &w.parts[k];
        if (p->failed_call == NULL) continue;
        snprintf(failure, failure_size, "%s", p->failed_call);
        *fmi_status = p->failed_status;
        *at = p->time;
    }
    recent_text(&log, log_text, log_size);
    wb_terminate(&w);
    wb_close(&w);
    data_free(&data, release);
    return status;
}
