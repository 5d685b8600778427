/*
 * whitebox.c -- the embedded white-box FMU, stepped with its named terms (whitebox.h).
 *
 * The loops mirror fmu_greybox/model/whitebox.py (_Part.step, _Part._start) call for call, so
 * that the white-box sees the same inputs at the same times in both runtimes.
 */
#define _POSIX_C_SOURCE 200809L
#include "whitebox.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "dynlib.h"
#include "sha256.h"

#define WB_PLATFORM DYNLIB_PLATFORM
#define WB_EXTENSION DYNLIB_EXTENSION

#define PART_FIELDS 6 /* columns, bound outputs, parameters, terms, sub-steps, entry stage */

/* ------------------------------------------------------------------ loading */

/* The text of a bytes section as a zero-terminated string (allocated). */
static char *section_text(const Whitebox *w, const GreyboxData *data, const char *name,
                          char *message, size_t size) {
    const DataSection *s = data_section(data, name, DATA_BYTES, -1, message, size);
    char *text;
    if (s == NULL) return NULL;
    text = w->allocate((size_t)s->count + 1, 1);
    if (text == NULL) {
        snprintf(message, size, "out of memory");
        return NULL;
    }
    memcpy(text, s->data, (size_t)s->count);
    return text;
}

/* The SHA-256 recorded for this platform's binary ("platform hash" lines), or -1. */
static int recorded_hash(const char *lines, char hash[65]) {
    const char *at = lines;
    const size_t n = strlen(WB_PLATFORM);
    while (at != NULL && *at != '\0') {
        if (strncmp(at, WB_PLATFORM, n) == 0 && at[n] == ' ' && strlen(at + n + 1) >= 64) {
            memcpy(hash, at + n + 1, 64);
            hash[64] = '\0';
            return 0;
        }
        at = strchr(at, '\n');
        if (at != NULL) at++;
    }
    return -1;
}

static int load_library(Whitebox *w, const GreyboxData *data, const char *resources_dir,
                        const char *identifier, char *message, size_t size) {
    char path[4096], recorded[65], actual[65];
    char *lines = section_text(w, data, "wb_binaries", message, size);
    int found;
    if (lines == NULL) return -1;
    found = recorded_hash(lines, recorded);
    w->release(lines);
    snprintf(path, sizeof path, "%s/whitebox/binaries/" WB_PLATFORM "/%s" WB_EXTENSION,
             resources_dir, identifier);
    if (found != 0) {
        snprintf(message, size, "the embedded white-box has no " WB_PLATFORM " binary; export "
                 "the grey-box with a white-box FMU built for " WB_PLATFORM);
        return -1;
    }
    if (sha256_file(path, actual) != 0) {
        snprintf(message, size, "cannot read the embedded white-box binary %s; the FMU is "
                 "incomplete, export it again", path);
        return -1;
    }
    if (strcmp(actual, recorded) != 0) {
        snprintf(message, size, "the embedded white-box binary %s has SHA-256 %.12s..., not "
                 "the %.12s... recorded at export; it was modified. Export the FMU again",
                 path, actual, recorded);
        return -1;
    }
    w->api.library = dynlib_open(path);
    if (w->api.library == NULL) {
        char reason[512];
        snprintf(message, size, "cannot load the embedded white-box binary %s: %s", path,
                 dynlib_error(reason, sizeof reason));
        return -1;
    }
    return 0;
}

/* Resolve one fmi2 function of the white-box into *slot. */
static int resolve(Whitebox *w, const char *name, void *slot, char *message, size_t size) {
    void *symbol = dynlib_symbol(w->api.library, name);
    if (symbol == NULL) {
        snprintf(message, size, "the embedded white-box lacks %s; it is not an FMI 2.0 "
                 "co-simulation FMU with state functions", name);
        return -1;
    }
    memcpy(slot, &symbol, sizeof symbol);
    return 0;
}

static int resolve_api(Whitebox *w, char *message, size_t size) {
    WbApi *a = &w->api;
    const struct {
        const char *name;
        void *slot;
    } table[] = {
        {"fmi2Instantiate", &a->instantiate},
        {"fmi2FreeInstance", &a->free_instance},
        {"fmi2SetupExperiment", &a->setup_experiment},
        {"fmi2EnterInitializationMode", &a->enter_initialization},
        {"fmi2ExitInitializationMode", &a->exit_initialization},
        {"fmi2Terminate", &a->terminate},
        {"fmi2Reset", &a->reset},
        {"fmi2SetReal", &a->set_real},
        {"fmi2GetReal", &a->get_real},
        {"fmi2DoStep", &a->do_step},
        {"fmi2GetFMUstate", &a->get_state},
        {"fmi2SetFMUstate", &a->set_state},
        {"fmi2FreeFMUstate", &a->free_state},
        {"fmi2SerializedFMUstateSize", &a->state_size},
        {"fmi2SerializeFMUstate", &a->serialize},
        {"fmi2DeSerializeFMUstate", &a->deserialize},
    };
    for (size_t i = 0; i < sizeof table / sizeof table[0]; i++) {
        if (resolve(w, table[i].name, table[i].slot, message, size) != 0) return -1;
    }
    return 0;
}

/* A file: URI of a folder, with the characters a URI may not hold percent-encoded (a Windows
   folder C:/x gives file:///C:/x). */
static void folder_uri(const char *folder, char *uri, size_t size) {
    static const char hex[] = "0123456789ABCDEF";
    const int drive = folder[0] != '\0' && folder[1] == ':';
    size_t at = (size_t)snprintf(uri, size, drive ? "file:///" : "file://");
    for (const unsigned char *c = (const unsigned char *)folder; *c && at + 4 < size; c++) {
        if ((*c >= 'a' && *c <= 'z') || (*c >= 'A' && *c <= 'Z') || (*c >= '0' && *c <= '9') ||
            strchr("/-._~", *c) != NULL || (drive && c == (const unsigned char *)folder + 1)) {
            uri[at++] = (char)*c;
        } else {
            uri[at++] = '%';
            uri[at++] = hex[*c >> 4];
            uri[at++] = hex[*c & 15];
        }
    }
    uri[at] = '\0';
}

/* ------------------------------------------------------------------ parts */

static void *table_of(Whitebox *w, ptrdiff_t n, size_t item) {
    return w->allocate((size_t)(n > 0 ? n : 1), item);
}

/* The part's arrays from the data file's concatenated sections, at the offsets given. */
static int build_part(Whitebox *w, WbPart *p, const int64_t *record, const int64_t *columns,
                      const int64_t *bound, const int64_t *param_vr, const double *param_value,
                      const int64_t *term_int, const double *term_real, const int64_t *channels,
                      ptrdiff_t *channel_at, char *message, size_t size) {
    p->n_columns = record[0];
    p->n_bound = record[1];
    p->n_params = record[2];
    p->n_terms = record[3];
    p->substeps = (int)record[4];
    p->columns = columns;
    p->bound_vr = table_of(w, p->n_bound, sizeof(fmi2ValueReference));
    p->start_vr = table_of(w, p->n_params + w->n_inputs, sizeof(fmi2ValueReference));
    p->start_values = table_of(w, p->n_params + w->n_inputs, sizeof(double));
    p->current = table_of(w, 2 * p->n_bound, sizeof(double));
    p->held = table_of(w, 2 * w->n_inputs, sizeof(double));
    p->terms = table_of(w, p->n_terms, sizeof(Term));
    if (!p->bound_vr || !p->start_vr || !p->start_values || !p->current || !p->held ||
        !p->terms) {
        snprintf(message, size, "out of memory");
        return -1;
    }
    p->sensed = p->current + p->n_bound;
    p->row = p->held + w->n_inputs;
    for (ptrdiff_t i = 0; i < p->n_bound; i++) p->bound_vr[i] = (fmi2ValueReference)bound[i];
    for (ptrdiff_t i = 0; i < p->n_params; i++) {
        p->start_vr[i] = (fmi2ValueReference)param_vr[i];
        p->start_values[i] = param_value[i];
    }
    for (ptrdiff_t i = 0; i < w->n_inputs; i++) p->start_vr[p->n_params + i] = w->input_vr[i];
    p->plain = 1;
    for (ptrdiff_t k = 0; k < p->n_terms; k++) {
        Term *t = &p->terms[k];
        const int64_t *ints = term_int + TERM_INTS * k;
        if (term_init(t, ints, term_real + TERM_REALS * k, channels + *channel_at, w->allocate,
                      message, size) != 0) {
            return -1;
        }
        *channel_at += ints[5];
        if (term_on_inputs(t) || term_on_outputs(t)) p->plain = 0;
    }
    return 0;
}

/* The sections describing the parts, each checked for its length. */
typedef struct {
    const DataSection *part, *columns, *bound, *param_vr, *param_value, *term_int, *term_real,
        *channels, *input_vr;
} PartSections;

static int part_sections(const GreyboxData *data, ptrdiff_t n_parts, ptrdiff_t n_terms,
                         PartSections *s, char *message, size_t size) {
    s->part = data_section(data, "part", DATA_INT64, PART_FIELDS * n_parts, message, size);
    s->columns = data_section(data, "part_columns", DATA_INT64, -1, message, size);
    s->bound = data_section(data, "part_bound_vr", DATA_INT64, -1, message, size);
    s->param_vr = data_section(data, "part_param_vr", DATA_INT64, -1, message, size);
    s->param_value = data_section(data, "part_param_value", DATA_FLOAT64, -1, message, size);
    s->term_int = data_section(data, "term_int", DATA_INT64, TERM_INTS * n_terms, message, size);
    s->term_real =
        data_section(data, "term_real", DATA_FLOAT64, TERM_REALS * n_terms, message, size);
    s->channels = data_section(data, "term_channels", DATA_INT64, -1, message, size);
    s->input_vr = data_section(data, "wb_input_vr", DATA_INT64, -1, message, size);
    return s->part && s->columns && s->bound && s->param_vr && s->param_value && s->term_int &&
                   s->term_real && s->channels && s->input_vr
               ? 0
               : -1;
}

/* The copies of the parts' sections stay for the white-box's life: kept in this block. */
typedef struct {
    int64_t *part, *columns, *bound, *param_vr, *term_int, *channels, *input_vr;
    double *param_value, *term_real;
} PartTables;

static int build_parts(Whitebox *w, const GreyboxData *data, const char *instance_name,
                       char *message, size_t size) {
    PartSections s;
    PartTables t;
    const DataSection *sizes = data_section(data, "sizes", DATA_INT64, 6, message, size);
    int64_t n[6];
    ptrdiff_t at_columns = 0, at_bound = 0, at_params = 0, at_terms = 0, at_channels = 0;
    if (sizes == NULL) return -1;
    data_int64s(sizes, n);
    w->n_inputs = n[0];
    w->n_outputs = n[1];
    w->n_parts = n[4];
    if (part_sections(data, w->n_parts, n[5], &s, message, size) != 0) return -1;
    t.part = data_copy(s.part, w->allocate);
    t.columns = data_copy(s.columns, w->allocate);
    t.bound = data_copy(s.bound, w->allocate);
    t.param_vr = data_copy(s.param_vr, w->allocate);
    t.param_value = data_copy(s.param_value, w->allocate);
    t.term_int = data_copy(s.term_int, w->allocate);
    t.term_real = data_copy(s.term_real, w->allocate);
    t.channels = data_copy(s.channels, w->allocate);
    t.input_vr = data_copy(s.input_vr, w->allocate);
    w->parts = table_of(w, w->n_parts, sizeof(WbPart));
    w->input_vr = table_of(w, w->n_inputs, sizeof(fmi2ValueReference));
    w->tables = w->allocate(1, sizeof t);
    if (!t.part || !t.columns || !t.bound || !t.param_vr || !t.param_value || !t.term_int ||
        !t.term_real || !t.channels || !t.input_vr || !w->parts || !w->input_vr || !w->tables) {
        snprintf(message, size, "out of memory");
        return -1;
    }
    memcpy(w->tables, &t, sizeof t);
    for (ptrdiff_t i = 0; i < w->n_inputs; i++) w->input_vr[i] = (fmi2ValueReference)t.input_vr[i];
    for (ptrdiff_t k = 0; k < w->n_parts; k++) {
        WbPart *p = &w->parts[k];
        const int64_t *record = t.part + PART_FIELDS * k;
        char name[512];
        if (build_part(w, p, record, t.columns + at_columns, t.bound + at_bound,
                       t.param_vr + at_params, t.param_value + at_params,
                       t.term_int + TERM_INTS * at_terms, t.term_real + TERM_REALS * at_terms,
                       t.channels, &at_channels, message, size) != 0) {
            return -1;
        }
        if (k == 0) {
            snprintf(name, sizeof name, "%s.whitebox", instance_name);
        } else {
            snprintf(name, sizeof name, "%s.whitebox@%lld", instance_name, (long long)record[5]);
        }
        p->name = w->allocate(strlen(name) + 1, 1);
        if (p->name == NULL) {
            snprintf(message, size, "out of memory");
            return -1;
        }
        strcpy(p->name, name);
        at_columns += p->n_columns;
        at_bound += p->n_bound;
        at_params += p->n_params;
        at_terms += p->n_terms;
    }
    return 0;
}

int wb_open(Whitebox *w, const GreyboxData *data, const char *resources_dir,
            const char *instance_name, const fmi2CallbackFunctions *callbacks, double dt,
            char *message, size_t size) {
    char uri[4200], folder[4096];
    char *guid, *identifier;
    int status;
    w->dt = dt;
    if (build_parts(w, data, instance_name, message, size) != 0) return -1;
    guid = section_text(w, data, "wb_guid", message, size);
    identifier = section_text(w, data, "wb_identifier", message, size);
    status = guid && identifier ? load_library(w, data, resources_dir, identifier, message, size)
                                : -1;
    if (status == 0) status = resolve_api(w, message, size);
    snprintf(folder, sizeof folder, "%s/whitebox/resources", resources_dir);
    folder_uri(folder, uri, sizeof uri);
    for (ptrdiff_t k = 0; status == 0 && k < w->n_parts; k++) {
        WbPart *p = &w->parts[k];
        p->component = w->api.instantiate(p->name, fmi2CoSimulation, guid, uri, callbacks,
                                          fmi2False, fmi2False);
        if (p->component == NULL) {
            snprintf(message, size, "the embedded white-box (%s) refused fmi2Instantiate for "
                     "instance '%s'; its reason is in the log", identifier, p->name);
            status = -1;
        }
    }
    if (guid != NULL) w->release(guid);
    if (identifier != NULL) w->release(identifier);
    return status;
}

/* ------------------------------------------------------------------ running */

static int failed(WbPart *p, const char *call, fmi2Status status, char *message,
                  size_t size) {
    p->failed_call = call;
    p->failed_status = (int)status;
    snprintf(message, size, "the embedded white-box instance '%s' answered %s with status %d "
             "at t = %.9g s (its own message is in the log)", p->name, call, (int)status, p->time);
    return -1;
}

#define CALL(p, name, expression)                                                              \
    do {                                                                                       \
        const fmi2Status status_ = (expression);                                               \
        if (status_ > fmi2Warning) return failed(p, name, status_, message, size);             \
    } while (0)

/* Terms reset, the outputs read, the sensors applied (NamedModel's _Part._start). */
static int start_terms(const Whitebox *w, WbPart *p, char *message, size_t size) {
    for (ptrdiff_t k = 0; k < p->n_terms; k++) term_reset(&p->terms[k]);
    CALL(p, "fmi2GetReal",
         w->api.get_real(p->component, p->bound_vr, (size_t)p->n_bound, p->current));
    memcpy(p->sensed, p->current, (size_t)p->n_bound * sizeof(double));
    for (ptrdiff_t k = 0; k < p->n_terms; k++) {
        if (term_on_outputs(&p->terms[k])) term_output(&p->terms[k], p->sensed);
    }
    return 0;
}

int wb_start(Whitebox *w, const double *u, double time, char *message, size_t size) {
    for (ptrdiff_t k = 0; k < w->n_parts; k++) {
        WbPart *p = &w->parts[k];
        const size_t n = (size_t)(p->n_params + w->n_inputs);
        p->time = time;
        memcpy(p->start_values + p->n_params, u, (size_t)w->n_inputs * sizeof(double));
        if (w->started) CALL(p, "fmi2Reset", w->api.reset(p->component));
        CALL(p, "fmi2SetupExperiment",
             w->api.setup_experiment(p->component, fmi2False, 0.0, time, fmi2False, 0.0));
        CALL(p, "fmi2SetReal", w->api.set_real(p->component, p->start_vr, n, p->start_values));
        CALL(p, "fmi2EnterInitializationMode", w->api.enter_initialization(p->component));
        CALL(p, "fmi2ExitInitializationMode", w->api.exit_initialization(p->component));
        if (start_terms(w, p, message, size) != 0) return -1;
    }
    w->started = 1;
    return 0;
}

/* One FMU step of h with the inputs u; the bound outputs into out (FmuInstance.step). */
static int instance_step(const Whitebox *w, WbPart *p, const double *u, double h, double *out,
                         char *message, size_t size) {
    CALL(p, "fmi2SetReal", w->api.set_real(p->component, w->input_vr, (size_t)w->n_inputs, u));
    CALL(p, "fmi2DoStep", w->api.do_step(p->component, p->time, h, fmi2True));
    p->time += h;
    CALL(p, "fmi2GetReal", w->api.get_real(p->component, p->bound_vr, (size_t)p->n_bound, out));
    return 0;
}

/* NamedModel's _Part.step. */
static int part_step(const Whitebox *w, WbPart *p, const double *u, char *message, size_t size) {
    const size_t inputs = (size_t)w->n_inputs * sizeof(double);
    double h;
    if (p->plain) return instance_step(w, p, u, w->dt, p->sensed, message, size);
    memcpy(p->held, u, inputs);
    for (ptrdiff_t k = 0; k < p->n_terms; k++) {
        Term *t = &p->terms[k];
        if (term_on_inputs(t) && !term_is_feedback(t)) term_input(t, p->held, p->current);
    }
    h = w->dt / (double)p->substeps;
    for (int s = 0; s < p->substeps; s++) {
        memcpy(p->row, p->held, inputs);
        for (ptrdiff_t k = 0; k < p->n_terms; k++) {
            if (term_is_feedback(&p->terms[k])) term_input(&p->terms[k], p->row, p->current);
        }
        if (instance_step(w, p, p->row, h, p->current, message, size) != 0) return -1;
    }
    memcpy(p->sensed, p->current, (size_t)p->n_bound * sizeof(double));
    for (ptrdiff_t k = 0; k < p->n_terms; k++) {
        if (term_on_outputs(&p->terms[k])) term_output(&p->terms[k], p->sensed);
    }
    return 0;
}

int wb_step(Whitebox *w, const double *u, char *message, size_t size) {
    for (ptrdiff_t k = 0; k < w->n_parts; k++) {
        if (part_step(w, &w->parts[k], u, message, size) != 0) return -1;
    }
    return 0;
}

void wb_outputs(const Whitebox *w, double *y) {
    for (ptrdiff_t k = 0; k < w->n_parts; k++) {
        const WbPart *p = &w->parts[k];
        for (ptrdiff_t i = 0; i < p->n_columns; i++) y[p->columns[i]] = p->sensed[i];
    }
}

void wb_terminate(Whitebox *w) {
    if (!w->started) return;
    for (ptrdiff_t k = 0; k < w->n_parts; k++) w->api.terminate(w->parts[k].component);
}

void wb_close(Whitebox *w) {
    for (ptrdiff_t k = 0; w->parts != NULL && k < w->n_parts; k++) {
        WbPart *p = &w->parts[k];
        if (p->component != NULL) w->api.free_instance(p->component);
        for (ptrdiff_t i = 0; p->terms != NULL && i < p->n_terms; i++) {
            term_free(&p->terms[i], w->release);
        }
        void *owned[] = {p->name, p->bound_vr, p->start_vr, p->start_values, p->current,
                         p->held, p->terms};
        for (size_t i = 0; i < sizeof owned / sizeof owned[0]; i++) {
            if (owned[i] != NULL) w->release(owned[i]);
        }
    }
    if (w->tables != NULL) {
        PartTables *t = w->tables;
        void *owned[] = {t->part, t->columns, t->bound, t->param_vr, t->term_int,
                         t->channels, t->input_vr, t->param_value, t->term_real};
        for (size_t i = 0; i < sizeof owned / sizeof owned[0]; i++) {
            if (owned[i] != NULL) w->release(owned[i]);
        }
        w->release(t);
    }
    if (w->parts != NULL) w->release(w->parts);
    if (w->input_vr != NULL) w->release(w->input_vr);
    if (w->api.library != NULL) dynlib_close(w->api.library);
    w->parts = NULL;
    w->input_vr = NULL;
    w->tables = NULL;
    w->api.library = NULL;
}

/* ------------------------------------------------------------------ state */

/* Doubles a part keeps in values: its time, current and sensed outputs, terms' memory. */
static ptrdiff_t part_values(const WbPart *p) {
    ptrdiff_t n = 1 + 2 * p->n_bound;
    for (ptrdiff_t k = 0; k < p->n_terms; k++) n += term_memory_size(&p->terms[k]);
    return n;
}

ptrdiff_t wb_values(const Whitebox *w) {
    ptrdiff_t n = 0;
    for (ptrdiff_t k = 0; k < w->n_parts; k++) n += part_values(&w->parts[k]);
    return n;
}

int wb_save(Whitebox *w, fmi2FMUstate *states, double *values, char *message, size_t size) {
    for (ptrdiff_t k = 0; k < w->n_parts; k++) {
        WbPart *p = &w->parts[k];
        CALL(p, "fmi2GetFMUstate", w->api.get_state(p->component, &states[k]));
        *values++ = p->time;
        memcpy(values, p->current, (size_t)(2 * p->n_bound) * sizeof(double));
        values += 2 * p->n_bound;
        for (ptrdiff_t i = 0; i < p->n_terms; i++) {
            term_save(&p->terms[i], values);
            values += term_memory_size(&p->terms[i]);
        }
    }
    return 0;
}

int wb_values_fault(const Whitebox *w, const double *values, double time, char *message,
                    size_t size) {
    for (ptrdiff_t k = 0; k < w->n_parts; k++) {
        const WbPart *p = &w->parts[k];
        if (!(fabs(values[0] - time) <= w->dt)) {
            snprintf(message, size, "white-box part %s is at t = %g s, not within a step of the "
                     "grey-box's %g s", p->name, values[0], time);
            return -1;
        }
        values++;
        for (ptrdiff_t i = 0; i < 2 * p->n_bound; i++) {
            if (!isfinite(values[i])) {
                snprintf(message, size, "white-box part %s: output value %td is %g, not finite",
                         p->name, i % p->n_bound, values[i]);
                return -1;
            }
        }
        values += 2 * p->n_bound;
        for (ptrdiff_t i = 0; i < p->n_terms; i++) {
            const char *fault = term_memory_fault(&p->terms[i], values);
            if (fault != NULL) {
                snprintf(message, size, "white-box part %s, term %td: %s", p->name, i, fault);
                return -1;
            }
            values += term_memory_size(&p->terms[i]);
        }
    }
    return 0;
}

int wb_restore(Whitebox *w, fmi2FMUstate *states, const double *values, char *message,
               size_t size) {
    for (ptrdiff_t k = 0; k < w->n_parts; k++) {
        WbPart *p = &w->parts[k];
        CALL(p, "fmi2SetFMUstate", w->api.set_state(p->component, states[k]));
        p->time = *values++;
        memcpy(p->current, values, (size_t)(2 * p->n_bound) * sizeof(double));
        values += 2 * p->n_bound;
        for (ptrdiff_t i = 0; i < p->n_terms; i++) {
            term_load(&p->terms[i], values);
            values += term_memory_size(&p->terms[i]);
        }
    }
    w->started = 1;
    return 0;
}

void wb_free_states(Whitebox *w, fmi2FMUstate *states) {
    for (ptrdiff_t k = 0; k < w->n_parts; k++) {
        if (states[k] != NULL) w->api.free_state(w->parts[k].component, &states[k]);
        states[k] = NULL;
    }
}

int wb_serialized_size(Whitebox *w, fmi2FMUstate *states, size_t *sizes, char *message,
                       size_t size) {
    for (ptrdiff_t k = 0; k < w->n_parts; k++) {
        WbPart *p = &w->parts[k];
        CALL(p, "fmi2SerializedFMUstateSize",
             w->api.state_size(p->component, states[k], &sizes[k]));
    }
    return 0;
}

int wb_serialize(Whitebox *w, fmi2FMUstate *states, unsigned char *bytes, const size_t *sizes,
                 char *message, size_t size) {
    for (ptrdiff_t k = 0; k < w->n_parts; k++) {
        WbPart *p = &w->parts[k];
        CALL(p, "fmi2SerializeFMUstate",
             w->api.serialize(p->component, states[k], (fmi2Byte *)bytes, sizes[k]));
        bytes += sizes[k];
    }
    return 0;
}

int wb_deserialize(Whitebox *w, const unsigned char *bytes, const size_t *sizes,
                   fmi2FMUstate *states, char *message, size_t size) {
    for (ptrdiff_t k = 0; k < w->n_parts; k++) {
        WbPart *p = &w->parts[k];
        CALL(p, "fmi2DeSerializeFMUstate",
             w->api.deserialize(p->component, (const fmi2Byte *)bytes, sizes[k], &states[k]));
        bytes += sizes[k];
    }
    return 0;
}
