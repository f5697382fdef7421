/* read.c - what the mesh readers share: a whitespace tokenizer that tracks line numbers, a
 * node tag -> index map, and the growing mesh a reader builds (validated and finalized at the
 * end). Every error names file, line and problem. The formats: read_formats.c. */
#include "mesh/mesh.h"
#include "mesh/mesh_internal.h"
#include "mesh/io_internal.h"

#include <ctype.h>
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

void sq_rd_skip_ws(rd *r)
{
    while (r->pos < r->len) {
        char c = r->buf[r->pos];
        if (c == '\n') {
            r->line++;
            r->pos++;
        } else if (isspace((unsigned char)c)) {
            r->pos++;
        } else if (r->comment && c == r->comment) {
            while (r->pos < r->len && r->buf[r->pos] != '\n')
                r->pos++;
        } else {
            break;
        }
    }
}

/* skip to the start of the next line */
void sq_rd_skip_line(rd *r)
{
    while (r->pos < r->len && r->buf[r->pos] != '\n')
        r->pos++;
    if (r->pos < r->len) {
        r->pos++;
        r->line++;
    }
}

/* is there another token on the current line? */
int sq_rd_more_on_line(rd *r)
{
    size_t p = r->pos;
    while (p < r->len && r->buf[p] != '\n' && isspace((unsigned char)r->buf[p]))
        p++;
    if (p >= r->len || r->buf[p] == '\n')
        return 0;
    return !(r->comment && r->buf[p] == r->comment);
}

/* next token into tok (at most n-1 chars); 0 at end of file */
int sq_rd_next_tok(rd *r, char *tok, size_t n)
{
    sq_rd_skip_ws(r);
    if (r->pos >= r->len)
        return 0;
    size_t k = 0;
    while (r->pos < r->len && !isspace((unsigned char)r->buf[r->pos])) {
        if (k + 1 < n)
            tok[k++] = r->buf[r->pos];
        r->pos++;
    }
    tok[k] = 0;
    return 1;
}

int sq_rd_fail(rd *r, const char *fmt, const char *what, const char *tok)
{
    char msg[300];
    snprintf(msg, sizeof msg, fmt, what, tok);
    return sq_err_set(r->err, "%s:%d: %s", r->path, r->line, msg);
}

/* does a token end at position p (whitespace, end of file or a comment)? */
static int tok_end(const rd *r, size_t p)
{
    if (p >= r->len)
        return 1;
    char c = r->buf[p];
    return isspace((unsigned char)c) || c == 0 || (r->comment && c == r->comment);
}

/* the bad token at the current position, for a message */
static int bad_token(rd *r, const char *fmt, const char *what)
{
    char tok[64];
    sq_rd_next_tok(r, tok, sizeof tok);
    return sq_rd_fail(r, fmt, what, tok);
}

/* integers are parsed in place (the loaders' hot path); anything odd is a message */
int sq_rd_read_long(rd *r, long long *v, const char *what)
{
    *v = 0;
    sq_rd_skip_ws(r);
    if (r->pos >= r->len)
        return sq_rd_fail(r, "unexpected end of file while reading %s%s; the file is truncated", what, "");
    size_t p = r->pos;
    int neg = 0;
    if (r->buf[p] == '-' || r->buf[p] == '+')
        neg = r->buf[p++] == '-';
    size_t d0 = p;
    unsigned long long x = 0;
    int big = 0;
    /* accumulate while x stays within LLONG_MAX; any longer run of digits is out of range
     * (so -9223372036854775808 is refused as well: no negation can overflow) */
    while (p < r->len && r->buf[p] >= '0' && r->buf[p] <= '9') {
        unsigned d = (unsigned)(r->buf[p++] - '0');
        if (x > ((unsigned long long)LLONG_MAX - d) / 10)
            big = 1;
        else if (!big)
            x = 10 * x + d;
    }
    if (p == d0 || !tok_end(r, p))
        return bad_token(r, "expected an integer for %s, found '%s'", what);
    if (big)
        return bad_token(r, "%s out of range: '%s'; integers in mesh files must lie within "
                         "+-9223372036854775807", what);
    r->pos = p;
    *v = neg ? -(long long)x : (long long)x;
    return 0;
}

int sq_rd_read_int(rd *r, int *v, const char *what)
{
    long long x;
    *v = 0;
    if (sq_rd_read_long(r, &x, what) < 0)
        return -1;
    if (x < INT_MIN || x > INT_MAX) {
        char t[32];
        snprintf(t, sizeof t, "%lld", x);
        return sq_rd_fail(r, "%s out of range: %s", what, t);
    }
    *v = (int)x;
    return 0;
}

int sq_rd_read_double(rd *r, double *v, const char *what)
{
    *v = 0;
    sq_rd_skip_ws(r);
    if (r->pos >= r->len)
        return sq_rd_fail(r, "unexpected end of file while reading %s%s; the file is truncated", what, "");
    /* the buffer is NUL-terminated, so strtod stops inside it */
    char *end;
    double x = strtod(r->buf + r->pos, &end);
    size_t p = (size_t)(end - r->buf);
    if (p == r->pos || !tok_end(r, p))
        return bad_token(r, "expected a number for %s, found '%s'", what);
    if (!isfinite(x)) {
        char tok[64];
        sq_rd_next_tok(r, tok, sizeof tok);
        return sq_rd_fail(r, "%s is not finite ('%s'); fix the coordinates", what, tok);
    }
    r->pos = p;
    *v = x;
    return 0;
}

/* a count from a header, guarded against absurd values: each entry needs at least
 * min_bytes of the remaining file */
int sq_rd_read_count(rd *r, long long *v, const char *what, int min_bytes)
{
    if (sq_rd_read_long(r, v, what) < 0)
        return -1;
    long long room = (long long)(r->len - r->pos) / min_bytes + 1;
    /* loose on purpose: a merely truncated file is caught, with its line, while reading */
    if (*v < 0 || *v > INT_MAX / 4 || *v > room) {
        char t[160];
        snprintf(t, sizeof t, "%lld, but only %zu bytes follow: the header is wrong or the file truncated",
                 *v, r->len - r->pos);
        return sq_rd_fail(r, "impossible %s: %s", what, t);
    }
    return 0;
}

/* ---- node tag -> index map (tags may be sparse) ---- */

typedef struct tagmap {
    long long *tag;
    int *index;
    int n;
    long long dense_lo; /* when tags are dense: index of tag t is dense[t - dense_lo] */
    long long dense_n;
    int *dense;
} tagmap;

static int tag_cmp(const void *pa, const void *pb)
{
    const long long *a = pa, *b = pb;
    return (*a > *b) - (*a < *b);
}

/* sort tags (index packed in a parallel array by sorting pairs) */
typedef struct tagpair {
    long long tag;
    int index;
    int line;
} tagpair;

static int pair_cmp(const void *pa, const void *pb)
{
    return tag_cmp(&((const tagpair *)pa)->tag, &((const tagpair *)pb)->tag);
}

static void tagmap_free(tagmap *tm)
{
    free(tm->tag);
    free(tm->index);
    free(tm->dense);
    tm->tag = NULL;
    tm->index = NULL;
    tm->dense = NULL;
}

/* build the map from tags[i] = tag of node i; error on duplicates */
static int tagmap_build(tagmap *tm, const long long *tags, const int *lines, int n, rd *r)
{
    tagpair *p = sq_malloc((size_t)(n ? n : 1) * sizeof *p);
    for (int i = 0; i < n; i++) {
        p[i].tag = tags[i];
        p[i].index = i;
        p[i].line = lines[i];
    }
    qsort(p, (size_t)n, sizeof *p, pair_cmp);
    tm->tag = sq_malloc((size_t)(n ? n : 1) * sizeof *tm->tag);
    tm->index = sq_malloc((size_t)(n ? n : 1) * sizeof *tm->index);
    tm->n = n;
    for (int i = 0; i < n; i++) {
        if (i && p[i].tag == p[i - 1].tag) {
            int l1 = p[i - 1].line < p[i].line ? p[i - 1].line : p[i].line;
            int l2 = p[i - 1].line < p[i].line ? p[i].line : p[i - 1].line;
            sq_err_set(r->err, "%s:%d: node number %lld defined twice (also at line %d); node numbers "
                       "must be unique", r->path, l2, p[i].tag, l1);
            free(p);
            tagmap_free(tm);
            return -1;
        }
        tm->tag[i] = p[i].tag;
        tm->index[i] = p[i].index;
    }
    free(p);
    /* dense tags (the usual case): a direct table instead of a binary search */
    unsigned long long span = n > 0 ? (unsigned long long)tm->tag[n - 1] - (unsigned long long)tm->tag[0] : 0;
    if (n > 0 && span < 4ULL * (unsigned long long)n + 16) {
        tm->dense_lo = tm->tag[0];
        tm->dense_n = (long long)span + 1;
        tm->dense = sq_malloc((size_t)tm->dense_n * sizeof *tm->dense);
        for (long long k = 0; k < tm->dense_n; k++)
            tm->dense[k] = -1;
        for (int i = 0; i < n; i++)
            tm->dense[tm->tag[i] - tm->dense_lo] = tm->index[i];
    }
    return 0;
}

static int tagmap_find(const tagmap *tm, long long tag)
{
    if (tm->dense) {
        /* unsigned compare also rejects tags below the range (no overflow for any tag) */
        unsigned long long k = (unsigned long long)tag - (unsigned long long)tm->dense_lo;
        return k < (unsigned long long)tm->dense_n ? tm->dense[k] : -1;
    }
    int lo = 0, hi = tm->n - 1;
    while (lo <= hi) {
        int mid = lo + (hi - lo) / 2;
        if (tm->tag[mid] == tag)
            return tm->index[mid];
        if (tm->tag[mid] < tag)
            lo = mid + 1;
        else
            hi = mid - 1;
    }
    return -1;
}


/* ---- the growing result of a reader ---- */

void sq_rd_build_free(build *b)
{
    free(b->x);
    free(b->ntag);
    free(b->nline);
    free(b->ttag);
    free(b->tline);
}

void sq_rd_build_reserve_nodes(build *b, long long extra)
{
    long long need = b->nn + extra;
    if (need <= b->cap_n)
        return;
    b->cap_n = (int)need;
    b->x = sq_realloc(b->x, (size_t)b->cap_n * 3 * sizeof *b->x);
    b->ntag = sq_realloc(b->ntag, (size_t)b->cap_n * sizeof *b->ntag);
    b->nline = sq_realloc(b->nline, (size_t)b->cap_n * sizeof *b->nline);
}

void sq_rd_build_add_tet(build *b, const long long v[4], int line)
{
    if (b->nt == b->cap_t) {
        b->cap_t = b->cap_t ? 2 * b->cap_t : 1024;
        b->ttag = sq_realloc(b->ttag, (size_t)b->cap_t * 4 * sizeof *b->ttag);
        b->tline = sq_realloc(b->tline, (size_t)b->cap_t * sizeof *b->tline);
    }
    memcpy(b->ttag + 4 * (size_t)b->nt, v, 4 * sizeof *v);
    b->tline[b->nt++] = line;
}

/* resolve tags, validate and finalize; consumes b; node_file names the node file if not r's */
sq_mesh *sq_rd_build_finish(build *b, rd *r, const char *node_file)
{
    tagmap tm = {0};
    if (b->nt == 0 && b->ho_tets > 0) {
        sq_err_set(r->err, "%s: only higher-order tetrahedra (%lld of them); save a first-order mesh "
                   "(gmsh -order 1) with 4-node tets", r->path, b->ho_tets);
        sq_rd_build_free(b);
        return NULL;
    }
    if (tagmap_build(&tm, b->ntag, b->nline, b->nn, r) < 0) {
        sq_rd_build_free(b);
        return NULL;
    }
    int *tets = sq_malloc((size_t)(b->nt ? b->nt : 1) * 4 * sizeof *tets);
    for (int t = 0; t < b->nt; t++)
        for (int k = 0; k < 4; k++) {
            long long tag = b->ttag[4 * (size_t)t + k];
            int idx = tagmap_find(&tm, tag);
            if (idx < 0) {
                sq_err_set(r->err, "%s:%d: tetrahedron refers to node %lld, which the file does not "
                           "define; fix the node numbers", r->path, b->tline[t], tag);
                free(tets);
                tagmap_free(&tm);
                sq_rd_build_free(b);
                return NULL;
            }
            tets[4 * (size_t)t + k] = idx;
        }
    tagmap_free(&tm);
    double *x = b->x;
    if (!x)
        x = sq_malloc(3 * sizeof *x);
    b->x = NULL;
    sq_mesh *m = sq_mesh_new_owned(b->nn, x, b->nt, tets, r->path);
    m = sq_mesh_validate_finalize(m, node_file, b->nline, b->tline, r->err);
    sq_rd_build_free(b);
    return m;
}
