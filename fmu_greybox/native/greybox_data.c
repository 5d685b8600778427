/*
 * greybox_data.c -- reading the native grey-box FMU's data file (format: greybox_data.h).
 */
#include "greybox_data.h"

#include <stdio.h>
#include <string.h>

#include "sha256.h"

#define MAGIC "FGBXDATA"
#define SECTION_HEADER (DATA_NAME_SIZE + 16)

static uint64_t read_u64(const unsigned char *p) {
    uint64_t v = 0;
    for (int i = 7; i >= 0; i--) v = v << 8 | p[i];
    return v;
}

static uint32_t read_u32(const unsigned char *p) {
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* The whole file into *bytes (allocated), its size into *size. */
static int read_file(const char *path, unsigned char **bytes, size_t *size,
                     void *(*allocate)(size_t, size_t), char *message, size_t message_size) {
    FILE *file = fopen(path, "rb");
    long length;
    if (file == NULL) {
        snprintf(message, message_size, "cannot open %s; the FMU is incomplete, export it again",
                 path);
        return -1;
    }
    if (fseek(file, 0, SEEK_END) != 0 || (length = ftell(file)) < 0 ||
        fseek(file, 0, SEEK_SET) != 0) {
        fclose(file);
        snprintf(message, message_size, "cannot read %s; export the FMU again", path);
        return -1;
    }
    *size = (size_t)length;
    *bytes = allocate(*size + 1, 1);
    if (*bytes == NULL || fread(*bytes, 1, *size, file) != *size) {
        fclose(file);
        snprintf(message, message_size, "cannot read %s (%s); export the FMU again", path,
                 *bytes == NULL ? "out of memory" : "read error");
        return -1;
    }
    fclose(file);
    return 0;
}

static int corrupt(char *message, size_t size, const char *path, const char *what) {
    snprintf(message, size, "%s is not a grey-box data file of version %d (%s); export the FMU "
             "again with this version of fmu-greybox", path, DATA_VERSION, what);
    return -1;
}

int data_read(GreyboxData *data, const char *path, const char *sha256,
              void *(*allocate)(size_t, size_t), char *message, size_t size) {
    const uint16_t probe = 1;
    char digest[65];
    size_t at;
    memset(data, 0, sizeof *data);
    if (*(const unsigned char *)&probe != 1) {
        snprintf(message, size, "this platform is big-endian; the FMU's data file and its "
                 "reader need a little-endian platform (every FMI 2.0 platform is)");
        return -1;
    }
    if (read_file(path, &data->bytes, &data->size, allocate, message, size) != 0) return -1;
    sha256_bytes(data->bytes, data->size, digest);
    if (strcmp(digest, sha256) != 0) {
        snprintf(message, size, "%s has SHA-256 %.12s..., not the %.12s... recorded in the "
                 "binary at export; the file was modified or belongs to another export. "
                 "Export the FMU again", path, digest, sha256);
        return -1;
    }
    if (data->size < 16 || memcmp(data->bytes, MAGIC, 8) != 0) {
        return corrupt(message, size, path, "no magic");
    }
    if (read_u32(data->bytes + 8) != DATA_VERSION) return corrupt(message, size, path, "version");
    data->n_sections = read_u32(data->bytes + 12);
    /* no more sections than the file holds headers (a count of 4e9 would allocate 200 GB) */
    if ((size_t)data->n_sections > (data->size - 16) / SECTION_HEADER) {
        data->n_sections = 0;
        return corrupt(message, size, path, "section count");
    }
    data->sections = allocate((size_t)data->n_sections + 1, sizeof(DataSection));
    if (data->sections == NULL) {
        snprintf(message, size, "out of memory reading %s", path);
        return -1;
    }
    at = 16;
    for (ptrdiff_t i = 0; i < data->n_sections; i++) {
        DataSection *s = &data->sections[i];
        uint64_t count, bytes;
        if (data->size - at < SECTION_HEADER) return corrupt(message, size, path, "truncated");
        memcpy(s->name, data->bytes + at, DATA_NAME_SIZE);
        s->name[DATA_NAME_SIZE] = '\0';
        s->type = (int)read_u32(data->bytes + at + DATA_NAME_SIZE);
        count = read_u64(data->bytes + at + DATA_NAME_SIZE + 8);
        at += SECTION_HEADER;
        if (s->type < DATA_INT64 || s->type > DATA_BYTES || count > data->size) {
            return corrupt(message, size, path, s->name);
        }
        bytes = s->type == DATA_BYTES ? (count + 7) / 8 * 8 : count * 8;
        if (data->size - at < bytes) return corrupt(message, size, path, s->name);
        s->count = (ptrdiff_t)count;
        s->data = data->bytes + at;
        at += bytes;
    }
    return 0;
}

const DataSection *data_section(const GreyboxData *data, const char *name, int type,
                                ptrdiff_t count, char *message, size_t size) {
    for (ptrdiff_t i = 0; i < data->n_sections; i++) {
        const DataSection *s = &data->sections[i];
        if (strcmp(s->name, name) != 0) continue;
        if (s->type != type || (count >= 0 && s->count != count)) {
            snprintf(message, size, "section %s of the data file holds %td values of type %d, "
                     "%td of type %d expected; export the FMU again", name, s->count, s->type,
                     count, type);
            return NULL;
        }
        return s;
    }
    snprintf(message, size, "the data file has no section %s; export the FMU again", name);
    return NULL;
}

void data_int64s(const DataSection *section, int64_t *out) {
    for (ptrdiff_t i = 0; i < section->count; i++) {
        out[i] = (int64_t)read_u64(section->data + 8 * i);
    }
}

void data_float64s(const DataSection *section, double *out) {
    memcpy(out, section->data, (size_t)section->count * sizeof(double));
}

void *data_copy(const DataSection *section, void *(*allocate)(size_t, size_t)) {
    void *out = allocate((size_t)(section->count > 0 ? section->count : 1), 8);
    if (out == NULL) return NULL;
    if (section->type == DATA_INT64) {
        data_int64s(section, out);
    } else {
        data_float64s(section, out);
    }
    return out;
}

void data_free(GreyboxData *data, void (*release)(void *)) {
    if (data->sections != NULL) release(data->sections);
    if (data->bytes != NULL) release(data->bytes);
    memset(data, 0, sizeof *data);
}
