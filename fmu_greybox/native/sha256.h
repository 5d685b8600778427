/*
 * sha256.h -- SHA-256 (FIPS 180-4) of a file, for the native grey-box FMU's integrity checks
 * (its data file, its white-box, its serialised states) and the reference FMUs' states.
 */
#ifndef GREYBOX_SHA256_H
#define GREYBOX_SHA256_H

#include <stddef.h>
#include <stdint.h>

typedef struct {
    uint32_t h[8];
    uint64_t length; /* bytes hashed so far */
    unsigned char block[64];
    size_t used; /* bytes waiting in block */
} Sha256;

void sha256_begin(Sha256 *s);
void sha256_add(Sha256 *s, const void *data, size_t size);
/* The digest as 64 lower-case hex digits and a terminating zero. */
void sha256_hex(Sha256 *s, char hex[65]);

/* SHA-256 of size bytes at data as hex (64 digits and a terminating zero). */
void sha256_bytes(const void *data, size_t size, char hex[65]);

/* SHA-256 of a file's bytes as hex; returns 0, or -1 if the file cannot be read. */
int sha256_file(const char *path, char hex[65]);

#endif /* GREYBOX_SHA256_H */
