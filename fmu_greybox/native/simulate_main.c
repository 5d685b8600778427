/*
 * simulate_main.c -- the native simulation runner as a program that serves many runs: each
 * job read from stdin is one fgb_simulate call (simulate.c), its result written to stdout.
 * fmu_greybox/model/native_run.py cross-compiles it for win64 and runs it under Wine, so that
 * a white-box with Windows binaries only is stepped in C, one Wine process per thread of a
 * Python process, instead of one remote call per FMI function.
 *
 * Every integer is a little-endian int64, every real a double. A job:
 *     "FGB1", path_len, sha_len, dir_len, n_rows, n_inputs, n_outputs, dt, start_time,
 *     the three strings (no terminator), u (n_rows x n_inputs, row-major)
 * its answer:
 *     status, fmi_status, at, message_len, failure_len, log_len, the three strings,
 *     then y (n_rows x n_outputs) when status is 0.
 * The program ends with status 0 at the end of its input, 2 on a malformed job.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#if defined(_WIN32)
#include <fcntl.h>
#include <io.h>
#endif

#define TEXT_SIZE 2048
#define FAILURE_SIZE 64
/* Largest string or array a job may announce (bytes): far above any path or recording. */
#define MAX_BYTES ((int64_t)1 << 34)

int fgb_simulate(const char *data_path, const char *data_sha256, const char *resources_dir,
                 double dt, double start_time, const double *u, ptrdiff_t n_rows, double *y,
                 char *message, size_t size, char *failure, size_t failure_size,
                 int *fmi_status, double *at, char *log_text, size_t log_size);

static int read_exact(void *buffer, size_t n) { return fread(buffer, 1, n, stdin) == n; }

static int write_exact(const void *buffer, size_t n) { return fwrite(buffer, 1, n, stdout) == n; }

/* A string of `length` bytes, terminated, or NULL. */
static char *read_string(int64_t length) {
    char *text;
    if (length < 0 || length > 4096) return NULL;
    text = calloc((size_t)length + 1, 1);
    if (text != NULL && !read_exact(text, (size_t)length)) {
        free(text);
        return NULL;
    }
    return text;
}

static int write_answer(int64_t status, int64_t fmi_status, double at, const char *message,
                        const char *failure, const char *log_text, const double *y,
                        int64_t n_values) {
    const int64_t lengths[3] = {(int64_t)strlen(message), (int64_t)strlen(failure),
                                (int64_t)strlen(log_text)};
    int ok = write_exact(&status, 8) && write_exact(&fmi_status, 8) && write_exact(&at, 8) &&
             write_exact(lengths, sizeof lengths) && write_exact(message, (size_t)lengths[0]) &&
             write_exact(failure, (size_t)lengths[1]) && write_exact(log_text, (size_t)lengths[2]);
    if (ok && status == 0) ok = write_exact(y, (size_t)n_values * sizeof(double));
    return ok && fflush(stdout) == 0;
}

/* One job: 1 when served, 0 at the end of the input, -1 when malformed. */
static int serve_one(void) {
    char magic[4], message[TEXT_SIZE] = "", failure[FAILURE_SIZE] = "", log_text[TEXT_SIZE] = "";
    int64_t sizes[6];
    double times[2], at = 0.0;
    int fmi_status = 0, status, answered;
    char *path, *sha, *folder;
    double *u, *y;
    if (fread(magic, 1, 4, stdin) != 4) return 0;
    if (memcmp(magic, "FGB1", 4) != 0 || !read_exact(sizes, sizeof sizes) ||
        !read_exact(times, sizeof times)) {
        return -1;
    }
    for (int k = 3; k < 6; k++) {
        if (sizes[k] < 1 || sizes[k] > MAX_BYTES / 8) return -1;
    }
    if (sizes[3] > MAX_BYTES / 8 / sizes[4] || sizes[3] > MAX_BYTES / 8 / sizes[5]) return -1;
    path = read_string(sizes[0]);
    sha = read_string(sizes[1]);
    folder = read_string(sizes[2]);
    u = malloc((size_t)(sizes[3] * sizes[4]) * sizeof(double));
    y = malloc((size_t)(sizes[3] * sizes[5]) * sizeof(double));
    status = -1;
    if (path != NULL && sha != NULL && folder != NULL && u != NULL && y != NULL &&
        read_exact(u, (size_t)(sizes[3] * sizes[4]) * sizeof(double))) {
        status = fgb_simulate(path, sha, folder, times[0], times[1], u, (ptrdiff_t)sizes[3], y,
                              message, sizeof message, failure, sizeof failure, &fmi_status, &at,
                              log_text, sizeof log_text);
        answered = write_answer(status, fmi_status, at, message, failure, log_text, y,
                                sizes[3] * sizes[5]);
    } else {
        answered = 0;
    }
    free(path);
    free(sha);
    free(folder);
    free(u);
    free(y);
    return answered ? 1 : -1;
}

int main(void) {
    int served;
#if defined(_WIN32)
    _setmode(_fileno(stdin), _O_BINARY);
    _setmode(_fileno(stdout), _O_BINARY);
#endif
    while ((served = serve_one()) == 1) {
    }
    return served == 0 ? 0 : 2;
}
