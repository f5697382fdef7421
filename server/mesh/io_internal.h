/* io_internal.h - what the mesh files' readers and writers share: the tokenizer and mesh
 * builder of read.c, used by the format readers (read_formats.c), and the extension of a path
 * (read_formats.c, also used by write.c); not a public contract. */
#ifndef SQ_MESH_IO_INTERNAL_H
#define SQ_MESH_IO_INTERNAL_H

#include <stddef.h>

#include "mesh/mesh.h"

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

/* the growing result of a reader */
typedef struct build {
    int nn, nt, cap_n, cap_t;
    double *x;
    long long *ntag; /* node tag per node */
    int *nline;
    long long *ttag; /* node tags per tet (4 per tet) */
    int *tline;
    long long ho_tets; /* skipped higher-order tets (Gmsh types 11, 29, 30, 31) */
} build;

void sq_rd_skip_ws(rd *r);
void sq_rd_skip_line(rd *r);
int sq_rd_more_on_line(rd *r);
int sq_rd_next_tok(rd *r, char *tok, size_t n);
int sq_rd_fail(rd *r, const char *fmt, const char *what, const char *tok);
int sq_rd_read_long(rd *r, long long *v, const char *what);
int sq_rd_read_int(rd *r, int *v, const char *what);
int sq_rd_read_double(rd *r, double *v, const char *what);
int sq_rd_read_count(rd *r, long long *v, const char *what, int min_bytes);
void sq_rd_build_free(build *b);
void sq_rd_build_reserve_nodes(build *b, long long extra);
void sq_rd_build_add_tet(build *b, const long long v[4], int line);
sq_mesh *sq_rd_build_finish(build *b, rd *r, const char *node_file);

/* the extension of path's file name, dot included ("" when none) */
const char *sq_rd_ext_of(const char *path);

#endif
