/*
 * greybox_data.h -- the trained numbers of a native grey-box FMU, read from its data file.
 *
 * The file (resources/greybox.dat, written by fmu_greybox/model/native_data.py) is
 * little-endian:
 *
 *   "FGBXDATA"            8 bytes, magic
 *   version               uint32 (DATA_VERSION)
 *   n_sections            uint32
 *   per section:
 *     name                24 bytes, ASCII, zero-padded
 *     type                uint32: 1 int64, 2 float64, 3 bytes (UTF-8 text)
 *     reserved            uint32, 0
 *     count               uint64: elements (bytes for type 3)
 *     data                count * 8 bytes, or count bytes zero-padded to a multiple of 8
 *
 * Its SHA-256 is compiled into the FMU's binary and checked before anything is read, so a
 * modified or truncated file is refused at fmi2Instantiate.
 */
#ifndef GREYBOX_DATA_H
#define GREYBOX_DATA_H

#include <stddef.h>
#include <stdint.h>

#define DATA_VERSION 1
#define DATA_NAME_SIZE 24

enum { DATA_INT64 = 1, DATA_FLOAT64 = 2, DATA_BYTES = 3 };

typedef struct {
    char name[DATA_NAME_SIZE + 1];
    int type;
    ptrdiff_t count;
    const unsigned char *data; /* into GreyboxData.bytes */
} DataSection;

typedef struct {
    unsigned char *bytes; /* the whole file */
    size_t size;
    DataSection *sections;
    ptrdiff_t n_sections;
} GreyboxData;

/* Read and check the file at path against the SHA-256 (hex) it must have. Returns 0, or -1
 * with a message saying what is wrong and how to mend it (free what was read with data_free
 * either way). allocate: the master's calloc-like memory function. */
int data_read(GreyboxData *data, const char *path, const char *sha256,
              void *(*allocate)(size_t, size_t), char *message, size_t size);

/* The section `name` of `type` holding exactly `count` elements (any count if count < 0), or
 * NULL with a message. */
const DataSection *data_section(const GreyboxData *data, const char *name, int type,
                                ptrdiff_t count, char *message, size_t size);

/* Copy a section's elements (int64 or float64) into out (count elements). */
void data_int64s(const DataSection *section, int64_t *out);
void data_float64s(const DataSection *section, double *out);

/* A section's elements (int64 or float64) in new memory from allocate (calloc-like; at least
 * one element), or NULL when out of memory. */
void *data_copy(const DataSection *section, void *(*allocate)(size_t, size_t));

void data_free(GreyboxData *data, void (*release)(void *));

#endif /* GREYBOX_DATA_H */
