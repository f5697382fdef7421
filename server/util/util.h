/* util.h - small shared helpers: errors, timing, progress bar, growable arrays; and the JSON
 * field readers that scene files (server/scene) and protocol requests (server/net) share. */
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
/* CPU time of the calling thread in seconds: what a piece of work costs on an idle core,
 * meaningful when other work shares the cores */
double sq_thread_cpu(void);
/* the calling thread's minor page faults so far (a first touch of a page costs 12-15 us on
 * this kind of machine; the lod guard learns that cost) */
long sq_minor_faults(void);
/* the calling thread's user and system CPU time (s), minor faults and involuntary context
 * switches so far (getrusage; for traces) */
void sq_thread_usage(double *user_s, double *sys_s, long *minflt, long *ivcsw);

/* the debug switches of the whole program: traces on stderr and check paths, never read by a
 * normal run. All off by default; only the command line sets them (server/app/main.c, from the
 * one environment variable SQ_DEBUG), tests may set them around a check. Set before any
 * simulation thread starts; read anywhere. */
typedef struct sq_debug_options {
    int progress;      /* draw the progress bar even when stderr is not a terminal */
    int guard_trace;   /* lod: each budgeted frame's cost model, passes, usage (frame.c) */
    int sharp_trace;   /* lod: each sharp estimate, or that it was not made (bound.c) */
    int sharp_check;   /* lod: 1 checks each sharp estimate against a full reference Lanczos
                        * run, 2 also assembles the operator densely (<= 3,000 axes) and prints
                        * its asymmetry (bound.c) */
    int sharp_no_stop; /* lod: the sharp estimates run their full Lanczos steps, no early stop
                        * (to compare, bound.c) */
    int static_trace;  /* lod: the corotational static solves (corotational.c) */
} sq_debug_options;
void sq_debug_set(const sq_debug_options *o);
const sq_debug_options *sq_debug(void);

/* cancellation of a long computation: a thread points sq_cancel_flag at an int another
 * thread sets (atomically) to ask it to stop; the frame loops poll sq_cancelled() every few
 * substeps and abandon the frame. NULL (the default): never cancelled. */
extern _Thread_local const int *sq_cancel_flag;
static inline int sq_cancelled(void)
{
    return sq_cancel_flag && __atomic_load_n(sq_cancel_flag, __ATOMIC_RELAXED);
}

/* out = B^-1 for a 3x3 B (row-major), by cofactors; 0, or -1 when B is singular or its
 * determinant not finite (then out = 0) */
int sq_inv3(const double B[9], double out[9]);

/* position of column j in row i of a CSR pattern whose rows are sorted (row i is
 * col[row_start[i] .. row_start[i + 1] - 1]), or -1: the mesh adjacency, a level's rows */
static inline int sq_csr_find(const int *row_start, const int *col, int i, int j)
{
    int lo = row_start[i], hi = row_start[i + 1] - 1;
    while (lo <= hi) {
        int mid = (lo + hi) / 2;
        if (col[mid] == j)
            return mid;
        if (col[mid] < j)
            lo = mid + 1;
        else
            hi = mid - 1;
    }
    return -1;
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

/* ---------------------------------------------------------------- JSON field readers
 * (util/json.c) The checks of one JSON value that scene files and protocol requests share:
 * JSON type, finiteness, range, whole numbers, string length and control characters, arrays
 * of 3, the keys of an object. A reader that refuses a value describes what is wrong in a
 * sq_json_fault and hands it to the caller's report(), which words the message in its own
 * terms (scene files: server/scene/fields.c, "see docs/scenes.md"; requests:
 * server/net/request.c, with a protocol error code) and returns -1; the reader returns that.
 * Values are written only on success. */
struct cJSON;

typedef enum sq_json_fault_kind {
    SQ_JSON_WRONG_TYPE,      /* not of the JSON type wanted (want) */
    SQ_JSON_NOT_FINITE,      /* a number that is not finite (x) */
    SQ_JSON_OUT_OF_RANGE,    /* a number outside lo..hi (x; lo excluded when lo_open) */
    SQ_JSON_BAD_INT,         /* an integer wanted: x not whole, or outside [lo, hi], or both */
    SQ_JSON_TOO_LONG,        /* a string of len bytes, at most cap - 1 allowed */
    SQ_JSON_CONTROL_CHAR,    /* a control character at byte at of a plain string */
    SQ_JSON_WRONG_LENGTH,    /* an array of n items where 3 are wanted */
    SQ_JSON_UNKNOWN_KEY,     /* key of an object not in known */
    SQ_JSON_DUPLICATE_KEY    /* key given twice in an object */
} sq_json_fault_kind;

typedef enum sq_json_want {
    SQ_JSON_NUMBER, SQ_JSON_STRING, SQ_JSON_BOOL, SQ_JSON_ARRAY, SQ_JSON_OBJECT, SQ_JSON_VEC3
} sq_json_want;

typedef struct sq_json_fault {
    sq_json_fault_kind kind;
    const struct cJSON *item;  /* the value at fault (the object, for key faults) */
    const char *path;          /* its path: as given, or "<array path>[i]" for an element */
    const char *array_path;    /* element of an array of 3: the array's path (index >= 0) */
    int index;                 /* that element's index, else -1 */
    sq_json_want want;         /* WRONG_TYPE */
    double x, lo, hi;          /* numbers */
    int lo_open;
    int whole, in_range;       /* BAD_INT: which of the two failed (either or both 0) */
    size_t len, cap, at;       /* strings */
    int n;                     /* WRONG_LENGTH */
    const char *key;           /* key faults */
    const char *const *known;  /* UNKNOWN_KEY: the keys allowed (NULL-terminated) */
} sq_json_fault;

typedef struct sq_json_reader {
    int (*report)(struct sq_json_reader *r, const sq_json_fault *f); /* words f; returns -1 */
    void *ctx;                 /* the caller's (its error slot, label, ...) */
    int dup_at_first;          /* a key given twice is refused where it first appears (before
                                  later unknown keys; requests), else at its second (scene files) */
} sq_json_reader;

/* "a number", "a string", "a boolean", "null", "an array", "an object"; NULL if none */
const char *sq_json_kind(const struct cJSON *v);
/* a finite number in lo..hi (lo excluded when lo_open; +-INFINITY for no bound) */
int sq_json_number(sq_json_reader *r, const struct cJSON *v, const char *path, double lo,
                   double hi, int lo_open, double *out);
/* a whole number in [lo, hi] */
int sq_json_int(sq_json_reader *r, const struct cJSON *v, const char *path, double lo, double hi,
                double *out);
int sq_json_bool(sq_json_reader *r, const struct cJSON *v, const char *path, int *out);
/* a string of at most cap - 1 bytes; plain: without control characters (< 0x20) */
int sq_json_string(sq_json_reader *r, const struct cJSON *v, const char *path, char *out,
                   size_t cap, int plain);
/* [x, y, z], each a finite number in lo..hi (as sq_json_number) */
int sq_json_vec3(sq_json_reader *r, const struct cJSON *v, const char *path, double lo,
                 double hi, int lo_open, double out[3]);
/* an object (want SQ_JSON_OBJECT) or an array (SQ_JSON_ARRAY) */
int sq_json_expect(sq_json_reader *r, const struct cJSON *v, const char *path, sq_json_want want);
/* every key of obj in known (NULL-terminated), none twice */
int sq_json_keys(sq_json_reader *r, const struct cJSON *obj, const char *path,
                 const char *const *known);

#endif
