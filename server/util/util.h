/* util.h - small shared helpers: errors, timing, progress bar, growable arrays. */
#ifndef SQ_UTIL_H
#define SQ_UTIL_H

#include <stddef.h>
#include <stdint.h>

/* an error message that names the problem and what to do; empty when no error */
typedef struct sq_err {
    char msg[512];
} sq_err;

/* set err->msg (printf format); returns -1 so callers can `return sq_err_set(...)` */
int sq_err_set(sq_err *err, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* prefix an existing message: "<prefix>: <old message>" */
int sq_err_prefix(sq_err *err, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* monotonic wall clock in seconds */
double sq_now(void);

/* cancellation of a long computation: a thread points sq_cancel_flag at an int another
 * thread sets (atomically) to ask it to stop; the frame loops poll sq_cancelled() every few
 * substeps and abandon the frame. NULL (the default): never cancelled. */
extern _Thread_local const int *sq_cancel_flag;
static inline int sq_cancelled(void)
{
    return sq_cancel_flag && __atomic_load_n(sq_cancel_flag, __ATOMIC_RELAXED);
}

/* progress bar on stderr, only when stderr is a terminal (or force is set) */
typedef struct sq_progress {
    const char *label;
    double total;
    double last_draw;
    int enabled;
} sq_progress;
void sq_progress_begin(sq_progress *p, const char *label, double total);
void sq_progress_update(sq_progress *p, double done);
void sq_progress_end(sq_progress *p);

/* checked allocation: aborts with a message on out-of-memory (the only fatal path) */
void *sq_malloc(size_t n);
void *sq_calloc(size_t count, size_t size);
void *sq_realloc(void *p, size_t n);
char *sq_strdup(const char *s);

/* read a whole file into a NUL-terminated buffer; NULL and err on failure */
char *sq_read_file(const char *path, size_t *len, size_t max_len, sq_err *err);

/* create a directory and its parents (like mkdir -p); 0 on success, -1 with errno set */
int sq_mkdir_p(const char *dir);

/* 64-bit FNV-1a hash of bytes, for determinism checks */
uint64_t sq_hash_bytes(uint64_t h, const void *data, size_t n);
#define SQ_HASH_INIT 1469598103934665603ULL

#define SQ_MIN(a, b) ((a) < (b) ? (a) : (b))
#define SQ_MAX(a, b) ((a) > (b) ? (a) : (b))
#define SQ_COUNTOF(a) (sizeof(a) / sizeof((a)[0]))

#endif
