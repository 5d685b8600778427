/*
 * dynlib.h -- load a shared library and find its functions, on POSIX (dlopen) and Windows
 * (LoadLibrary), and the FMI 2.0 binary folder of the platform compiled for.
 *
 * Used by whitebox.c (the grey-box loads its white-box) and by benchmarks/c_master.c (a bare
 * master loads an FMU): one shim for both, header-only so that each compiles it in.
 */
#ifndef DYNLIB_H
#define DYNLIB_H

#include <stddef.h>
#include <stdio.h>
#include <string.h>

#if defined(_WIN32)
#include <windows.h>
#define DYNLIB_PLATFORM "win64"
#define DYNLIB_EXTENSION ".dll"
#else
#include <dlfcn.h>
#if defined(__APPLE__)
#define DYNLIB_PLATFORM "darwin64"
#define DYNLIB_EXTENSION ".dylib"
#elif defined(__linux__) && (defined(__x86_64__) || defined(__aarch64__))
#define DYNLIB_PLATFORM "linux64"
#define DYNLIB_EXTENSION ".so"
#elif defined(__linux__)
#define DYNLIB_PLATFORM "linux32"
#define DYNLIB_EXTENSION ".so"
#else
#error "dynlib.h knows the FMI 2.0 binary folders of Linux, macOS and Windows only"
#endif

/* glibc's RTLD_DEEPBIND: the loaded library's own fmi2 functions win over the loader's. The
   sanitizer runtimes refuse it (google/sanitizers issue 611): a build with AddressSanitizer
   loads without it. (Windows resolves each DLL's calls within it: nothing to ask for.) */
#if defined(__SANITIZE_ADDRESS__)
#define DYNLIB_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define DYNLIB_SANITIZED 1
#endif
#endif
#if defined(RTLD_DEEPBIND) && !defined(DYNLIB_SANITIZED)
#define DYNLIB_FLAGS (RTLD_NOW | RTLD_LOCAL | RTLD_DEEPBIND)
#else
#define DYNLIB_FLAGS (RTLD_NOW | RTLD_LOCAL)
#endif
#endif

/* The library at path, or NULL (then dynlib_error says why). */
static inline void *dynlib_open(const char *path) {
#if defined(_WIN32)
    return (void *)LoadLibraryA(path);
#else
    return dlopen(path, DYNLIB_FLAGS);
#endif
}

/* The function or variable name of a library, or NULL. */
static inline void *dynlib_symbol(void *library, const char *name) {
#if defined(_WIN32)
    FARPROC found = GetProcAddress((HMODULE)library, name);
    void *symbol;
    memcpy(&symbol, &found, sizeof symbol); /* a function pointer as the data pointer dlsym gives */
    return symbol;
#else
    return dlsym(library, name);
#endif
}

static inline void dynlib_close(void *library) {
#if defined(_WIN32)
    FreeLibrary((HMODULE)library);
#else
    dlclose(library);
#endif
}

/* Why the last dynlib_open failed, into message (size bytes); returns message. */
static inline const char *dynlib_error(char *message, size_t size) {
#if defined(_WIN32)
    DWORD code = GetLastError();
    char text[256] = "";
    size_t n = FormatMessageA(FORMAT_MESSAGE_FROM_SYSTEM | FORMAT_MESSAGE_IGNORE_INSERTS, NULL,
                              code, 0, text, sizeof text, NULL);
    while (n > 0 && (text[n - 1] == '\n' || text[n - 1] == '\r' || text[n - 1] == ' ')) {
        text[--n] = '\0';  /* the system's text ends with a line break */
    }
    snprintf(message, size, "Windows error %lu%s%s", (unsigned long)code, n > 0 ? ": " : "",
             text);
#else
    const char *reason = dlerror();
    snprintf(message, size, "%s", reason != NULL ? reason : "unknown reason");
#endif
    return message;
}

#endif
