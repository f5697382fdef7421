/* util.c - errors, timing, progress bar, allocation, file reading. */
#include "util/util.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

int sq_err_set(sq_err *err, const char *fmt, ...)
{
    if (err) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(err->msg, sizeof err->msg, fmt, ap);
        va_end(ap);
    }
    return -1;
}

int sq_err_prefix(sq_err *err, const char *fmt, ...)
{
    if (err) {
        char pre[256], old[sizeof err->msg];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(pre, sizeof pre, fmt, ap);
        va_end(ap);
        memcpy(old, err->msg, sizeof old);
        size_t n = strlen(pre);
        if (n > sizeof err->msg - 3)
            n = sizeof err->msg - 3;
        memcpy(err->msg, pre, n);
        memcpy(err->msg + n, ": ", 2);
        size_t room = sizeof err->msg - n - 3;
        size_t m = strnlen(old, room);
        memcpy(err->msg + n + 2, old, m);
        err->msg[n + 2 + m] = 0;
    }
    return -1;
}

_Thread_local const int *sq_cancel_flag;

double sq_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

double sq_thread_cpu(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

long sq_minor_faults(void)
{
    struct rusage ru;
    return getrusage(RUSAGE_THREAD, &ru) == 0 ? ru.ru_minflt : 0;
}

void sq_thread_usage(double *user_s, double *sys_s, long *minflt, long *ivcsw)
{
    struct rusage ru;
    if (getrusage(RUSAGE_THREAD, &ru) != 0)
        memset(&ru, 0, sizeof ru);
    *user_s = (double)ru.ru_utime.tv_sec + 1e-6 * (double)ru.ru_utime.tv_usec;
    *sys_s = (double)ru.ru_stime.tv_sec + 1e-6 * (double)ru.ru_stime.tv_usec;
    *minflt = ru.ru_minflt;
    *ivcsw = ru.ru_nivcsw;
}

static sq_debug_options debug_options;

void sq_debug_set(const sq_debug_options *o)
{
    if (o)
        debug_options = *o;
    else
        memset(&debug_options, 0, sizeof debug_options);
}

const sq_debug_options *sq_debug(void)
{
    return &debug_options;
}

void sq_progress_begin(sq_progress *p, const char *label, double total)
{
    p->label = label;
    p->total = total > 0 ? total : 1;
    p->last_draw = 0;
    p->enabled = isatty(2) || sq_debug()->progress;
    sq_progress_update(p, 0);
}

void sq_progress_update(sq_progress *p, double done)
{
    if (!p->enabled)
        return;
    double t = sq_now();
    if (done < p->total && t - p->last_draw < 0.1)
        return;
    p->last_draw = t;
    double f = done / p->total;
    if (f > 1)
        f = 1;
    int width = 30, filled = (int)(f * width);
    char bar[64];
    for (int i = 0; i < width; i++)
        bar[i] = i < filled ? '#' : '.';
    bar[width] = 0;
    fprintf(stderr, "\r%s [%s] %5.1f%%", p->label, bar, 100.0 * f);
    fflush(stderr);
}

void sq_progress_end(sq_progress *p)
{
    if (!p->enabled)
        return;
    p->last_draw = 0;
    sq_progress_update(p, p->total);
    fputc('\n', stderr);
}

static void oom(size_t n)
{
    fprintf(stderr, "squish: out of memory allocating %zu bytes; use a smaller mesh or free memory\n", n);
    abort();
}

void *sq_malloc(size_t n)
{
    void *p = malloc(n ? n : 1);
    if (!p)
        oom(n);
    return p;
}

void *sq_calloc(size_t count, size_t size)
{
    void *p = calloc(count ? count : 1, size ? size : 1);
    if (!p)
        oom(count * size);
    return p;
}

void *sq_realloc(void *p, size_t n)
{
    void *q = realloc(p, n ? n : 1);
    if (!q)
        oom(n);
    return q;
}

char *sq_strdup(const char *s)
{
    size_t n = strlen(s) + 1;
    char *d = sq_malloc(n);
    memcpy(d, s, n);
    return d;
}

char *sq_read_file(const char *path, size_t *len, size_t max_len, sq_err *err)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        sq_err_set(err, "%s: cannot open: %s", path, strerror(errno));
        return NULL;
    }
    size_t cap = 1 << 16, n = 0;
    char *buf = sq_malloc(cap + 1);
    for (;;) {
        if (n == cap) {
            if (cap >= max_len) {
                free(buf);
                fclose(f);
                sq_err_set(err, "%s: file larger than the limit of %zu bytes", path, max_len);
                return NULL;
            }
            cap *= 2;
            buf = sq_realloc(buf, cap + 1);
        }
        size_t got = fread(buf + n, 1, cap - n, f);
        n += got;
        if (got == 0)
            break;
    }
    int bad = ferror(f);
    fclose(f);
    if (bad) {
        free(buf);
        sq_err_set(err, "%s: read error", path);
        return NULL;
    }
    buf[n] = 0;
    if (len)
        *len = n;
    return buf;
}

uint64_t sq_hash_bytes(uint64_t h, const void *data, size_t n)
{
    const unsigned char *p = data;
    for (size_t i = 0; i < n; i++) {
        h ^= p[i];
        h *= 1099511628211ULL;
    }
    return h;
}

int sq_mkdir_p(const char *dir)
{
    char buf[1024];
    if (snprintf(buf, sizeof buf, "%s", dir) >= (int)sizeof buf) {
        errno = ENAMETOOLONG;
        return -1;
    }
    for (char *p = buf + 1; *p; p++) {
        if (*p != '/')
            continue;
        *p = 0;
        if (mkdir(buf, 0777) && errno != EEXIST)
            return -1;
        *p = '/';
    }
    if (mkdir(buf, 0777) && errno != EEXIST)
        return -1;
    struct stat st;
    if (stat(buf, &st) != 0)
        return -1;
    if (!S_ISDIR(st.st_mode)) {
        errno = ENOTDIR;
        return -1;
    }
    return 0;
}

int sq_inv3(const double B[9], double out[9])
{
    const double c0 = B[4] * B[8] - B[5] * B[7], c1 = B[5] * B[6] - B[3] * B[8], c2 = B[3] * B[7] - B[4] * B[6];
    const double det = B[0] * c0 + B[1] * c1 + B[2] * c2;
    memset(out, 0, 9 * sizeof(double));
    if (!(fabs(det) > 0) || !isfinite(det))
        return -1;
    const double id = 1.0 / det;
    out[0] = c0 * id;
    out[1] = (B[2] * B[7] - B[1] * B[8]) * id;
    out[2] = (B[1] * B[5] - B[2] * B[4]) * id;
    out[3] = c1 * id;
    out[4] = (B[0] * B[8] - B[2] * B[6]) * id;
    out[5] = (B[2] * B[3] - B[0] * B[5]) * id;
    out[6] = c2 * id;
    out[7] = (B[1] * B[6] - B[0] * B[7]) * id;
    out[8] = (B[0] * B[4] - B[1] * B[3]) * id;
    return 0;
}
