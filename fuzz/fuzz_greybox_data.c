/*
 * fuzz_greybox_data.c -- libFuzzer target for the native grey-box's data-file reader.
 *
 * Each input is written to a file and read with data_read (fmu_greybox/native/greybox_data.c)
 * against its own SHA-256, so the fuzzer reaches the parser behind the hash check; every
 * section found is then looked up by name and copied as the FMU's loader does. Build and run
 * (tests/test_fuzz.py does both):
 *
 *   clang -g -O1 -fsanitize=fuzzer,address,undefined -I fmu_greybox/native \
 *       fuzz/fuzz_greybox_data.c fmu_greybox/native/greybox_data.c \
 *       fmu_greybox/native/sha256.c -o fuzz_greybox_data
 *   ./fuzz_greybox_data -seed=1 -runs=100000 CORPUS_COPY fuzz/corpus/greybox_data
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

#include "greybox_data.h"
#include "sha256.h"

static char path[64];

int LLVMFuzzerTestOneInput(const uint8_t *bytes, size_t size) {
    if (path[0] == '\0') snprintf(path, sizeof path, "/tmp/fuzz_greybox_data.%ld", (long)getpid());
    FILE *file = fopen(path, "wb");
    if (file == NULL) return 0;
    fwrite(bytes, 1, size, file);
    fclose(file);
    char hex[65], message[512];
    sha256_bytes(bytes, size, hex);
    GreyboxData data = {0};
    if (data_read(&data, path, hex, calloc, message, sizeof message) == 0) {
        for (ptrdiff_t i = 0; i < data.n_sections; i++) {
            const DataSection *s = data_section(&data, data.sections[i].name,
                                                data.sections[i].type, -1, message,
                                                sizeof message);
            if (s != NULL && s->type != DATA_BYTES) free(data_copy(s, calloc));
        }
        data_section(&data, "no such section", DATA_FLOAT64, 3, message, sizeof message);
    }
    data_free(&data, free);
    return 0;
}
