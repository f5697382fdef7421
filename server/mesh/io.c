/* io.c - mesh readers (Gmsh .msh 2.2/4.1 ASCII, TetGen .node/.ele, Medit .mesh) and writers
 * (legacy VTK, Gmsh 2.2, Medit, TetGen). Every reader error names file, line and problem. */
#include "mesh/mesh.h"
#include "mesh/mesh_internal.h"

#include <ctype.h>
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

/* largest mesh file read (bytes) */
#define SQ_MESH_MAX_FILE ((size_t)4 << 30)

/* ---- a whitespace tokenizer that tracks line numbers ---- */

typedef struct rd {
    const char *path;
    char *buf;
    size_t len, pos;
    int line;
    char comment; /* comment character to end of line, or 0 */
    sq_err *err;
} rd;

static void skip_ws(rd *r)
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
static void skip_line(rd *r)
{
    while (r->pos < r->len && r->buf[r->pos] != '\n')
        r->pos++;
    if (r->pos < r->len) {
        r->pos++;
        r->line++;
    }
}

/* is there another token on the current line? */
static int more_on_line(rd *r)
{
    size_t p = r->pos;
    while (p < r->len && r->buf[p] != '\n' && isspace((unsigned char)r->buf[p]))
        p++;
    if (p >= r->len || r->buf[p] == '\n')
        return 0;
    return !(r->comment && r->buf[p] == r->comment);
}

/* next token into tok (at most n-1 chars); 0 at end of file */
static int next_tok(rd *r, char *tok, size_t n)
{
    skip_ws(r);
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

static int fail(rd *r, const char *fmt, const char *what, const char *tok)
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
    next_tok(r, tok, sizeof tok);
    return fail(r, fmt, what, tok);
}

/* integers are parsed in place (the loaders' hot path); anything odd is a message */
static int read_long(rd *r, long long *v, const char *what)
{
    *v = 0;
    skip_ws(r);
    if (r->pos >= r->len)
        return fail(r, "unexpected end of file while reading %s%s; the file is truncated", what, "");
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

static int read_int(rd *r, int *v, const char *what)
{
    long long x;
    *v = 0;
    if (read_long(r, &x, what) < 0)
        return -1;
    if (x < INT_MIN || x > INT_MAX) {
        char t[32];
        snprintf(t, sizeof t, "%lld", x);
        return fail(r, "%s out of range: %s", what, t);
    }
    *v = (int)x;
    return 0;
}

static int read_double(rd *r, double *v, const char *what)
{
    *v = 0;
    skip_ws(r);
    if (r->pos >= r->len)
        return fail(r, "unexpected end of file while reading %s%s; the file is truncated", what, "");
    /* the buffer is NUL-terminated, so strtod stops inside it */
    char *end;
    double x = strtod(r->buf + r->pos, &end);
    size_t p = (size_t)(end - r->buf);
    if (p == r->pos || !tok_end(r, p))
        return bad_token(r, "expected a number for %s, found '%s'", what);
    if (!isfinite(x)) {
        char tok[64];
        next_tok(r, tok, sizeof tok);
        return fail(r, "%s is not finite ('%s'); fix the coordinates", what, tok);
    }
    r->pos = p;
    *v = x;
    return 0;
}

/* a count from a header, guarded against absurd values: each entry needs at least
 * min_bytes of the remaining file */
static int read_count(rd *r, long long *v, const char *what, int min_bytes)
{
    if (read_long(r, v, what) < 0)
        return -1;
    long long room = (long long)(r->len - r->pos) / min_bytes + 1;
    /* loose on purpose: a merely truncated file is caught, with its line, while reading */
    if (*v < 0 || *v > INT_MAX / 4 || *v > room) {
        char t[160];
        snprintf(t, sizeof t, "%lld, but only %zu bytes follow: the header is wrong or the file truncated",
                 *v, r->len - r->pos);
        return fail(r, "impossible %s: %s", what, t);
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

typedef struct build {
    int nn, nt, cap_n, cap_t;
    double *x;
    long long *ntag; /* node tag per node */
    int *nline;
    long long *ttag; /* node tags per tet (4 per tet) */
    int *tline;
    long long ho_tets; /* skipped higher-order tets (Gmsh types 11, 29, 30, 31) */
} build;

static void build_free(build *b)
{
    free(b->x);
    free(b->ntag);
    free(b->nline);
    free(b->ttag);
    free(b->tline);
}

static void build_reserve_nodes(build *b, long long extra)
{
    long long need = b->nn + extra;
    if (need <= b->cap_n)
        return;
    b->cap_n = (int)need;
    b->x = sq_realloc(b->x, (size_t)b->cap_n * 3 * sizeof *b->x);
    b->ntag = sq_realloc(b->ntag, (size_t)b->cap_n * sizeof *b->ntag);
    b->nline = sq_realloc(b->nline, (size_t)b->cap_n * sizeof *b->nline);
}

static void build_add_tet(build *b, const long long v[4], int line)
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
static sq_mesh *build_finish(build *b, rd *r, const char *node_file)
{
    tagmap tm = {0};
    if (b->nt == 0 && b->ho_tets > 0) {
        sq_err_set(r->err, "%s: only higher-order tetrahedra (%lld of them); save a first-order mesh "
                   "(gmsh -order 1) with 4-node tets", r->path, b->ho_tets);
        build_free(b);
        return NULL;
    }
    if (tagmap_build(&tm, b->ntag, b->nline, b->nn, r) < 0) {
        build_free(b);
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
                build_free(b);
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
    build_free(b);
    return m;
}

/* ---- Gmsh ---- */

/* skip a section up to its $End line */
static int skip_section(rd *r, const char *name)
{
    char end[96], tok[80];
    int start = r->line;
    snprintf(end, sizeof end, "$End%s", name + 1);
    while (next_tok(r, tok, sizeof tok))
        if (!strcmp(tok, end))
            return 0;
    r->line = start;
    return fail(r, "section %s has no %s; the file is truncated", name, end);
}

static int expect_end(rd *r, const char *end)
{
    char tok[80];
    if (!next_tok(r, tok, sizeof tok))
        return fail(r, "missing %s; the file is truncated%s", end, "");
    if (strcmp(tok, end))
        return fail(r, "expected %s, found '%s' (more entries than the section's count?)", end, tok);
    return 0;
}

static int msh_nodes_22(rd *r, build *b)
{
    long long n;
    if (read_count(r, &n, "node count", 2) < 0)
        return -1;
    build_reserve_nodes(b, n);
    for (long long i = 0; i < n; i++) {
        long long tag;
        int line;
        skip_ws(r);
        line = r->line;
        if (read_long(r, &tag, "node number") < 0)
            return -1;
        double *x = b->x + 3 * (size_t)b->nn;
        if (read_double(r, &x[0], "coordinate x") < 0 || read_double(r, &x[1], "coordinate y") < 0 || read_double(r, &x[2], "coordinate z") < 0)
            return -1;
        b->ntag[b->nn] = tag;
        b->nline[b->nn++] = line;
    }
    return expect_end(r, "$EndNodes");
}

static int msh_elements_22(rd *r, build *b)
{
    long long n;
    if (read_count(r, &n, "element count", 2) < 0)
        return -1;
    for (long long e = 0; e < n; e++) {
        long long id;
        int type, ntags, line;
        skip_ws(r);
        line = r->line;
        if (read_long(r, &id, "element number") < 0 || read_int(r, &type, "element type") < 0 ||
            read_int(r, &ntags, "tag count") < 0)
            return -1;
        if (r->line != line)
            return fail(r, "element line ended early%s%s; each element is one line", "", "");
        if (type != 4) {
            b->ho_tets += type == 11 || (type >= 29 && type <= 31);
            skip_line(r);
            continue;
        }
        if (ntags < 0 || ntags > 64)
            return fail(r, "bad %s %s", "tag count", "for a tetrahedron");
        for (int k = 0; k < ntags; k++) {
            long long t;
            if (read_long(r, &t, "element tag") < 0)
                return -1;
        }
        long long v[4];
        for (int k = 0; k < 4; k++) {
            if (!more_on_line(r))
                return fail(r, "tetrahedron has fewer than 4 nodes%s%s; the line is cut short", "", "");
            if (read_long(r, &v[k], "tetrahedron node") < 0)
                return -1;
        }
        build_add_tet(b, v, line);
    }
    return expect_end(r, "$EndElements");
}

static int msh_nodes_41(rd *r, build *b)
{
    long long nblocks, n, mintag, maxtag;
    if (read_count(r, &nblocks, "node block count", 2) < 0 || read_count(r, &n, "node count", 2) < 0 ||
        read_long(r, &mintag, "min node tag") < 0 || read_long(r, &maxtag, "max node tag") < 0)
        return -1;
    build_reserve_nodes(b, n);
    long long total = 0;
    for (long long blk = 0; blk < nblocks; blk++) {
        int dim, ent, param;
        long long cnt;
        if (read_int(r, &dim, "entity dimension") < 0 || read_int(r, &ent, "entity tag") < 0 ||
            read_int(r, &param, "parametric flag") < 0 || read_count(r, &cnt, "nodes in block", 2) < 0)
            return -1;
        if (total + cnt > n)
            return fail(r, "node blocks hold more nodes than the header's %s%s", "count", "");
        int first = b->nn;
        for (long long i = 0; i < cnt; i++) {
            skip_ws(r);
            b->nline[b->nn] = r->line;
            if (read_long(r, &b->ntag[b->nn], "node tag") < 0)
                return -1;
            b->nn++;
        }
        int npar = param ? (dim < 0 ? 0 : dim > 3 ? 3 : dim) : 0;
        for (long long i = 0; i < cnt; i++) {
            double *x = b->x + 3 * (size_t)(first + i);
            skip_ws(r);
            b->nline[first + i] = r->line;
            if (read_double(r, &x[0], "coordinate x") < 0 || read_double(r, &x[1], "coordinate y") < 0 ||
                read_double(r, &x[2], "coordinate z") < 0)
                return -1;
            for (int k = 0; k < npar; k++) {
                double u;
                if (read_double(r, &u, "parametric coordinate") < 0)
                    return -1;
            }
        }
        total += cnt;
    }
    if (total != n)
        return fail(r, "node blocks hold fewer nodes than the header's %s%s", "count", "");
    return expect_end(r, "$EndNodes");
}

static int msh_elements_41(rd *r, build *b)
{
    long long nblocks, n, mintag, maxtag;
    if (read_count(r, &nblocks, "element block count", 2) < 0 || read_count(r, &n, "element count", 2) < 0 ||
        read_long(r, &mintag, "min element tag") < 0 || read_long(r, &maxtag, "max element tag") < 0)
        return -1;
    long long total = 0;
    for (long long blk = 0; blk < nblocks; blk++) {
        int dim, ent, type;
        long long cnt;
        if (read_int(r, &dim, "entity dimension") < 0 || read_int(r, &ent, "entity tag") < 0 ||
            read_int(r, &type, "element type") < 0 || read_count(r, &cnt, "elements in block", 2) < 0)
            return -1;
        skip_line(r);
        for (long long e = 0; e < cnt; e++) {
            skip_ws(r);
            if (r->pos >= r->len)
                return fail(r, "unexpected end of file in an element block%s%s; the file is truncated", "", "");
            if (type != 4) {
                b->ho_tets += type == 11 || (type >= 29 && type <= 31);
                skip_line(r);
                continue;
            }
            int line = r->line;
            long long id, v[4];
            if (read_long(r, &id, "element tag") < 0)
                return -1;
            for (int k = 0; k < 4; k++) {
                if (!more_on_line(r))
                    return fail(r, "tetrahedron has fewer than 4 nodes%s%s; the line is cut short", "", "");
                if (read_long(r, &v[k], "tetrahedron node") < 0)
                    return -1;
            }
            build_add_tet(b, v, line);
        }
        total += cnt;
    }
    if (total != n)
        return fail(r, "element blocks hold a different number of elements than the header's %s%s", "count", "");
    return expect_end(r, "$EndElements");
}

/* a reader's end: the mesh when both its sections were read, else an error naming the missing one */
static sq_mesh *finish_sections(build *b, rd *r, int have_nodes, int have_elems, const char *nodes_name,
                                const char *elems_name)
{
    if (!have_nodes || !have_elems) {
        sq_err_set(r->err, "%s:%d: missing the %s section; the file is truncated or not a volume mesh",
                   r->path, r->line, have_nodes ? elems_name : nodes_name);
        build_free(b);
        return NULL;
    }
    return build_finish(b, r, NULL);
}

static sq_mesh *read_msh(rd *r)
{
    build b = {0};
    char tok[80];
    int version = 0, have_nodes = 0, have_elems = 0;
    while (next_tok(r, tok, sizeof tok)) {
        if (!strcmp(tok, "$MeshFormat")) {
            double ver;
            int ftype, dsize;
            if (read_double(r, &ver, "format version") < 0 || read_int(r, &ftype, "file type") < 0 ||
                read_int(r, &dsize, "data size") < 0)
                goto bad;
            if (ftype != 0) {
                fail(r, "binary .msh is not supported%s%s; save as ASCII (gmsh FILE -save -format msh22)", "", "");
                goto bad;
            }
            if (ver >= 2 && ver < 3)
                version = 2;
            else if (ver >= 4.1 - 1e-9 && ver < 5)
                version = 4;
            else {
                char t[32];
                snprintf(t, sizeof t, "%g", ver);
                fail(r, "unsupported %s %s; save as 2.2 or 4.1 ASCII (gmsh -format msh22)", "msh version", t);
                goto bad;
            }
            if (expect_end(r, "$EndMeshFormat") < 0)
                goto bad;
        } else if (!strcmp(tok, "$Nodes")) {
            if (!version) {
                fail(r, "$Nodes before $MeshFormat%s%s; not a Gmsh file?", "", "");
                goto bad;
            }
            if (have_nodes) {
                fail(r, "a second $Nodes section%s%s; only one is supported", "", "");
                goto bad;
            }
            have_nodes = 1;
            if ((version == 2 ? msh_nodes_22(r, &b) : msh_nodes_41(r, &b)) < 0)
                goto bad;
        } else if (!strcmp(tok, "$Elements")) {
            if (!version) {
                fail(r, "$Elements before $MeshFormat%s%s; not a Gmsh file?", "", "");
                goto bad;
            }
            have_elems = 1;
            if ((version == 2 ? msh_elements_22(r, &b) : msh_elements_41(r, &b)) < 0)
                goto bad;
        } else if (tok[0] == '$' && strncmp(tok, "$End", 4)) {
            if (skip_section(r, tok) < 0)
                goto bad;
        } else {
            fail(r, "unexpected '%s'%s where a $Section was expected; is this a Gmsh .msh file?", tok, "");
            goto bad;
        }
    }
    if (!version) {
        sq_err_set(r->err, "%s:%d: no $MeshFormat section; not a Gmsh .msh file", r->path, r->line);
        goto bad;
    }
    return finish_sections(&b, r, have_nodes, have_elems, "$Nodes", "$Elements");
bad:
    build_free(&b);
    return NULL;
}

/* ---- TetGen ---- */

/* a missing half of the pair: say that both files are needed */
static void tetgen_pair_hint(sq_err *err)
{
    if (err) {
        size_t n = strlen(err->msg);
        snprintf(err->msg + n, sizeof err->msg - n, "; a TetGen mesh needs both NAME.node and NAME.ele");
    }
}

static sq_mesh *read_tetgen(const char *path, sq_err *err)
{
    /* NAME.node and NAME.ele from either name (or NAME alone) */
    size_t n = strlen(path);
    char base[4096];
    if (n + 8 > sizeof base) {
        sq_err_set(err, "%s: path too long", path);
        return NULL;
    }
    memcpy(base, path, n + 1);
    char *dot = strrchr(base, '.');
    char *slash = strrchr(base, '/');
    if (dot && (!slash || dot > slash) && (!strcmp(dot, ".node") || !strcmp(dot, ".ele")))
        *dot = 0;
    char npath[4104], epath[4104];
    snprintf(npath, sizeof npath, "%s.node", base);
    snprintf(epath, sizeof epath, "%s.ele", base);

    build b = {0};
    size_t len;
    char *buf = sq_read_file(npath, &len, SQ_MESH_MAX_FILE, err);
    if (!buf) {
        tetgen_pair_hint(err);
        return NULL;
    }
    rd r = {npath, buf, len, 0, 1, '#', err};
    long long nn;
    int dim, nattr, nmark;
    if (read_count(&r, &nn, "point count", 2) < 0 || read_int(&r, &dim, "dimension") < 0 ||
        read_int(&r, &nattr, "attribute count") < 0 || read_int(&r, &nmark, "boundary marker flag") < 0)
        goto bad;
    if (dim != 3) {
        fail(&r, "dimension must be 3 for a tetrahedral mesh%s%s", "", "");
        goto bad;
    }
    if (nattr < 0 || nattr > 1000 || nmark < 0 || nmark > 1) {
        fail(&r, "bad attribute count or boundary marker flag%s%s (expected >= 0 and 0 or 1)", "", "");
        goto bad;
    }
    build_reserve_nodes(&b, nn);
    for (long long i = 0; i < nn; i++) {
        skip_ws(&r);
        int line = r.line;
        long long id;
        double *x = b.x + 3 * (size_t)b.nn;
        if (read_long(&r, &id, "point number") < 0 || read_double(&r, &x[0], "coordinate x") < 0 ||
            read_double(&r, &x[1], "coordinate y") < 0 || read_double(&r, &x[2], "coordinate z") < 0)
            goto bad;
        for (int k = 0; k < nattr; k++) {
            double a;
            if (read_double(&r, &a, "point attribute") < 0)
                goto bad;
        }
        for (int k = 0; k < nmark; k++) {
            long long mk;
            if (read_long(&r, &mk, "boundary marker") < 0)
                goto bad;
        }
        b.ntag[b.nn] = id;
        b.nline[b.nn++] = line;
    }
    free(buf);

    buf = sq_read_file(epath, &len, SQ_MESH_MAX_FILE, err);
    if (!buf) {
        tetgen_pair_hint(err);
        build_free(&b);
        return NULL;
    }
    rd re = {epath, buf, len, 0, 1, '#', err};
    long long nt;
    int npt, nreg;
    if (read_count(&re, &nt, "tetrahedron count", 2) < 0 || read_int(&re, &npt, "nodes per tetrahedron") < 0 ||
        read_int(&re, &nreg, "region attribute flag") < 0)
        goto bad_e;
    if (npt != 4 && npt != 10) {
        fail(&re, "nodes per tetrahedron must be 4 or 10%s%s", "", "");
        goto bad_e;
    }
    if (nreg < 0 || nreg > 1000) {
        fail(&re, "bad region attribute count%s%s", "", "");
        goto bad_e;
    }
    for (long long t = 0; t < nt; t++) {
        skip_ws(&re);
        int line = re.line;
        long long id, v[10];
        if (read_long(&re, &id, "tetrahedron number") < 0)
            goto bad_e;
        for (int k = 0; k < npt; k++)
            if (read_long(&re, &v[k], "tetrahedron node") < 0)
                goto bad_e;
        for (int k = 0; k < nreg; k++) {
            double a;
            if (read_double(&re, &a, "region attribute") < 0)
                goto bad_e;
        }
        build_add_tet(&b, v, line);
    }
    sq_mesh *m = build_finish(&b, &re, npath);
    if (m)
        snprintf(m->source, sizeof m->source, "%s", path);
    free(buf);
    return m;
bad_e:
    free(buf);
    build_free(&b);
    return NULL;
bad:
    free(buf);
    build_free(&b);
    return NULL;
}

/* ---- Medit ---- */

/* entries per line of the sections we skip (count, then this many numbers each) */
static int medit_width(const char *kw)
{
    static const struct {
        const char *kw;
        int w;
    } t[] = {{"Edges", 3}, {"Triangles", 4}, {"Quadrilaterals", 5}, {"Hexahedra", 9}, {"Prisms", 7},
             {"Pyramids", 6}, {"Corners", 1}, {"Ridges", 1}, {"RequiredVertices", 1},
             {"RequiredEdges", 1}, {"RequiredTriangles", 1}, {"Normals", 3}, {"Tangents", 3},
             {"NormalAtVertices", 2}, {"TangentAtEdges", 3}, {"Identifier", 0}, {"Geometry", 0}};
    for (size_t i = 0; i < SQ_COUNTOF(t); i++)
        if (!strcasecmp(kw, t[i].kw))
            return t[i].w;
    return -1;
}

static sq_mesh *read_medit(rd *r)
{
    build b = {0};
    char tok[80];
    int have_v = 0, have_t = 0;
    while (next_tok(r, tok, sizeof tok)) {
        if (!strcasecmp(tok, "MeshVersionFormatted")) {
            int v;
            if (read_int(r, &v, "format version") < 0)
                goto bad;
            if (v < 0 || v > 4) {
                fail(r, "unsupported MeshVersionFormatted%s%s", "", "");
                goto bad;
            }
        } else if (!strcasecmp(tok, "Dimension")) {
            int d;
            if (read_int(r, &d, "dimension") < 0)
                goto bad;
            if (d != 3) {
                fail(r, "Dimension must be 3 for a tetrahedral mesh%s%s", "", "");
                goto bad;
            }
        } else if (!strcasecmp(tok, "Vertices")) {
            long long n;
            if (have_v) {
                fail(r, "a second Vertices section%s%s", "", "");
                goto bad;
            }
            have_v = 1;
            if (read_count(r, &n, "vertex count", 2) < 0)
                goto bad;
            build_reserve_nodes(&b, n);
            for (long long i = 0; i < n; i++) {
                skip_ws(r);
                int line = r->line;
                double *x = b.x + 3 * (size_t)b.nn;
                long long ref;
                if (read_double(r, &x[0], "coordinate x") < 0 || read_double(r, &x[1], "coordinate y") < 0 ||
                    read_double(r, &x[2], "coordinate z") < 0 || read_long(r, &ref, "vertex reference") < 0)
                    goto bad;
                b.ntag[b.nn] = b.nn + 1;
                b.nline[b.nn++] = line;
            }
        } else if (!strcasecmp(tok, "Tetrahedra")) {
            long long n;
            have_t = 1;
            if (read_count(r, &n, "tetrahedron count", 2) < 0)
                goto bad;
            for (long long t = 0; t < n; t++) {
                skip_ws(r);
                int line = r->line;
                long long v[4], ref;
                for (int k = 0; k < 4; k++)
                    if (read_long(r, &v[k], "tetrahedron vertex") < 0)
                        goto bad;
                if (read_long(r, &ref, "tetrahedron reference") < 0)
                    goto bad;
                build_add_tet(&b, v, line);
            }
        } else if (!strcasecmp(tok, "End")) {
            break;
        } else {
            int w = medit_width(tok);
            if (w < 0) {
                fail(r, "unknown keyword '%s'%s; not a Medit .mesh file, or a section this reader does not know",
                     tok, "");
                goto bad;
            }
            if (w == 0) {
                skip_line(r);
                continue;
            }
            long long n;
            if (read_count(r, &n, tok, 2) < 0)
                goto bad;
            for (long long i = 0; i < n * w; i++) {
                double d;
                if (read_double(r, &d, tok) < 0)
                    goto bad;
            }
        }
    }
    return finish_sections(&b, r, have_v, have_t, "Vertices", "Tetrahedra");
bad:
    build_free(&b);
    return NULL;
}

static const char *ext_of(const char *path)
{
    const char *dot = strrchr(path, '.'), *slash = strrchr(path, '/');
    if (!dot || (slash && dot < slash))
        return "";
    return dot;
}

sq_mesh *sq_mesh_load(const char *path, sq_err *err)
{
    const char *ext = ext_of(path);
    if (!strcasecmp(ext, ".node") || !strcasecmp(ext, ".ele"))
        return read_tetgen(path, err);
    int kind = !strcasecmp(ext, ".msh") ? 1 : !strcasecmp(ext, ".mesh") ? 2 : 0;
    if (!kind) {
        sq_err_set(err, "%s: unknown mesh format '%s'; use .msh (Gmsh 2.2/4.1 ASCII), .node/.ele "
                   "(TetGen) or .mesh (Medit)", path, ext);
        return NULL;
    }
    size_t len;
    char *buf = sq_read_file(path, &len, SQ_MESH_MAX_FILE, err);
    if (!buf)
        return NULL;
    rd r = {path, buf, len, 0, 1, kind == 2 ? '#' : 0, err};
    sq_mesh *m = kind == 1 ? read_msh(&r) : read_medit(&r);
    free(buf);
    return m;
}

/* ---- writers ---- */

/* shortest of %.15g/%.17g that reads back exactly: deterministic and exact */
static void fmt_exact(char *buf, size_t n, double v)
{
    snprintf(buf, n, "%.15g", v);
    if (strtod(buf, NULL) != v)
        snprintf(buf, n, "%.17g", v);
}

static FILE *open_out(const char *path, sq_err *err)
{
    FILE *f = fopen(path, "w");
    if (!f)
        sq_err_set(err, "%s: cannot write: %s; check the directory exists and is writable", path,
                   strerror(errno));
    return f;
}

static int close_out(FILE *f, const char *path, sq_err *err)
{
    int bad = ferror(f);
    if (fclose(f) != 0 || bad)
        return sq_err_set(err, "%s: write failed (disk full?)", path);
    return 0;
}

static void put_xyz(FILE *f, const double *x)
{
    char a[32], b[32], c[32];
    fmt_exact(a, sizeof a, x[0]);
    fmt_exact(b, sizeof b, x[1]);
    fmt_exact(c, sizeof c, x[2]);
    fprintf(f, "%s %s %s", a, b, c);
}

int sq_mesh_write_vtk(const sq_mesh *m, const char *path, const double *displacement,
                      const double *velocity, const int *level, sq_err *err)
{
    FILE *f = open_out(path, err);
    if (!f)
        return -1;
    fprintf(f, "# vtk DataFile Version 3.0\nsquish tetrahedral mesh\nASCII\nDATASET UNSTRUCTURED_GRID\n");
    fprintf(f, "POINTS %d double\n", m->nnodes);
    for (int i = 0; i < m->nnodes; i++) {
        const double *x = m->x + 3 * (size_t)i;
        fprintf(f, "%.9g %.9g %.9g\n", x[0], x[1], x[2]);
    }
    fprintf(f, "CELLS %d %lld\n", m->ntets, 5LL * m->ntets);
    for (int t = 0; t < m->ntets; t++) {
        const int *v = m->tets + 4 * (size_t)t;
        fprintf(f, "4 %d %d %d %d\n", v[0], v[1], v[2], v[3]);
    }
    fprintf(f, "CELL_TYPES %d\n", m->ntets);
    for (int t = 0; t < m->ntets; t++)
        fputs("10\n", f);
    if (displacement || velocity || level)
        fprintf(f, "POINT_DATA %d\n", m->nnodes);
    const double *vec[2] = {displacement, velocity};
    const char *name[2] = {"displacement", "velocity"};
    for (int k = 0; k < 2; k++) {
        if (!vec[k])
            continue;
        fprintf(f, "VECTORS %s double\n", name[k]);
        for (int i = 0; i < m->nnodes; i++) {
            const double *d = vec[k] + 3 * (size_t)i;
            /* + 0.0 turns -0 into 0 so equal states print equally */
            fprintf(f, "%.9g %.9g %.9g\n", d[0] + 0.0, d[1] + 0.0, d[2] + 0.0);
        }
    }
    if (level) {
        fprintf(f, "SCALARS level int 1\nLOOKUP_TABLE default\n");
        for (int i = 0; i < m->nnodes; i++)
            fprintf(f, "%d\n", level[i]);
    }
    return close_out(f, path, err);
}

int sq_mesh_write_msh(const sq_mesh *m, const char *path, sq_err *err)
{
    FILE *f = open_out(path, err);
    if (!f)
        return -1;
    fprintf(f, "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n%d\n", m->nnodes);
    for (int i = 0; i < m->nnodes; i++) {
        fprintf(f, "%d ", i + 1);
        put_xyz(f, m->x + 3 * (size_t)i);
        fputc('\n', f);
    }
    fprintf(f, "$EndNodes\n$Elements\n%d\n", m->ntets);
    for (int t = 0; t < m->ntets; t++) {
        const int *v = m->tets + 4 * (size_t)t;
        fprintf(f, "%d 4 2 1 1 %d %d %d %d\n", t + 1, v[0] + 1, v[1] + 1, v[2] + 1, v[3] + 1);
    }
    fprintf(f, "$EndElements\n");
    return close_out(f, path, err);
}

int sq_mesh_write_medit(const sq_mesh *m, const char *path, sq_err *err)
{
    FILE *f = open_out(path, err);
    if (!f)
        return -1;
    fprintf(f, "MeshVersionFormatted 2\n\nDimension 3\n\nVertices\n%d\n", m->nnodes);
    for (int i = 0; i < m->nnodes; i++) {
        put_xyz(f, m->x + 3 * (size_t)i);
        fputs(" 0\n", f);
    }
    fprintf(f, "\nTetrahedra\n%d\n", m->ntets);
    for (int t = 0; t < m->ntets; t++) {
        const int *v = m->tets + 4 * (size_t)t;
        fprintf(f, "%d %d %d %d 1\n", v[0] + 1, v[1] + 1, v[2] + 1, v[3] + 1);
    }
    fprintf(f, "\nEnd\n");
    return close_out(f, path, err);
}

int sq_mesh_write_tetgen(const sq_mesh *m, const char *path, sq_err *err)
{
    size_t n = strlen(path);
    char base[4096], np[4104], ep[4104];
    if (n + 8 > sizeof base)
        return sq_err_set(err, "%s: path too long", path);
    memcpy(base, path, n + 1);
    const char *ext = ext_of(base);
    if (!strcmp(ext, ".node") || !strcmp(ext, ".ele"))
        base[n - strlen(ext)] = 0;
    snprintf(np, sizeof np, "%s.node", base);
    snprintf(ep, sizeof ep, "%s.ele", base);
    FILE *f = open_out(np, err);
    if (!f)
        return -1;
    fprintf(f, "# written by squish\n%d 3 0 0\n", m->nnodes);
    for (int i = 0; i < m->nnodes; i++) {
        fprintf(f, "%d ", i + 1);
        put_xyz(f, m->x + 3 * (size_t)i);
        fputc('\n', f);
    }
    if (close_out(f, np, err) < 0)
        return -1;
    f = open_out(ep, err);
    if (!f)
        return -1;
    fprintf(f, "# written by squish\n%d 4 0\n", m->ntets);
    for (int t = 0; t < m->ntets; t++) {
        const int *v = m->tets + 4 * (size_t)t;
        fprintf(f, "%d %d %d %d %d\n", t + 1, v[0] + 1, v[1] + 1, v[2] + 1, v[3] + 1);
    }
    return close_out(f, ep, err);
}

int sq_mesh_save(const sq_mesh *m, const char *path, sq_err *err)
{
    const char *ext = ext_of(path);
    if (!strcasecmp(ext, ".vtk"))
        return sq_mesh_write_vtk(m, path, NULL, NULL, NULL, err);
    if (!strcasecmp(ext, ".msh"))
        return sq_mesh_write_msh(m, path, err);
    if (!strcasecmp(ext, ".mesh"))
        return sq_mesh_write_medit(m, path, err);
    if (!strcasecmp(ext, ".node") || !strcasecmp(ext, ".ele"))
        return sq_mesh_write_tetgen(m, path, err);
    return sq_err_set(err, "%s: unknown output format '%s'; use .vtk, .msh, .mesh or .node/.ele", path, ext);
}
