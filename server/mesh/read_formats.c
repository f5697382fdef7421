/* read_formats.c - mesh readers (Gmsh .msh 2.2/4.1 ASCII, TetGen .node/.ele, Medit .mesh) and
 * sq_mesh_load, on the shared tokenizer of read.c. Every reader error names file, line and
 * problem. */
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

/* ---- Gmsh ---- */

/* skip a section up to its $End line */
static int skip_section(rd *r, const char *name)
{
    char end[96], tok[80];
    int start = r->line;
    snprintf(end, sizeof end, "$End%s", name + 1);
    while (sq_rd_next_tok(r, tok, sizeof tok))
        if (!strcmp(tok, end))
            return 0;
    r->line = start;
    return sq_rd_fail(r, "section %s has no %s; the file is truncated", name, end);
}

static int expect_end(rd *r, const char *end)
{
    char tok[80];
    if (!sq_rd_next_tok(r, tok, sizeof tok))
        return sq_rd_fail(r, "missing %s; the file is truncated%s", end, "");
    if (strcmp(tok, end))
        return sq_rd_fail(r, "expected %s, found '%s' (more entries than the section's count?)", end, tok);
    return 0;
}

static int msh_nodes_22(rd *r, build *b)
{
    long long n;
    if (sq_rd_read_count(r, &n, "node count", 2) < 0)
        return -1;
    sq_rd_build_reserve_nodes(b, n);
    for (long long i = 0; i < n; i++) {
        long long tag;
        int line;
        sq_rd_skip_ws(r);
        line = r->line;
        if (sq_rd_read_long(r, &tag, "node number") < 0)
            return -1;
        double *x = b->x + 3 * (size_t)b->nn;
        if (sq_rd_read_double(r, &x[0], "coordinate x") < 0 || sq_rd_read_double(r, &x[1], "coordinate y") < 0 || sq_rd_read_double(r, &x[2], "coordinate z") < 0)
            return -1;
        b->ntag[b->nn] = tag;
        b->nline[b->nn++] = line;
    }
    return expect_end(r, "$EndNodes");
}

/* the four node numbers that end a tetrahedron's element line (both .msh versions); -1, reported,
 * when the line is cut short or a number is bad */
static int read_tet_nodes(rd *r, long long v[4])
{
    for (int k = 0; k < 4; k++) {
        if (!sq_rd_more_on_line(r))
            return sq_rd_fail(r, "tetrahedron has fewer than 4 nodes%s%s; the line is cut short", "", "");
        if (sq_rd_read_long(r, &v[k], "tetrahedron node") < 0)
            return -1;
    }
    return 0;
}

static int msh_elements_22(rd *r, build *b)
{
    long long n;
    if (sq_rd_read_count(r, &n, "element count", 2) < 0)
        return -1;
    for (long long e = 0; e < n; e++) {
        long long id;
        int type, ntags, line;
        sq_rd_skip_ws(r);
        line = r->line;
        if (sq_rd_read_long(r, &id, "element number") < 0 || sq_rd_read_int(r, &type, "element type") < 0 ||
            sq_rd_read_int(r, &ntags, "tag count") < 0)
            return -1;
        if (r->line != line)
            return sq_rd_fail(r, "element line ended early%s%s; each element is one line", "", "");
        if (type != 4) {
            b->ho_tets += type == 11 || (type >= 29 && type <= 31);
            sq_rd_skip_line(r);
            continue;
        }
        if (ntags < 0 || ntags > 64)
            return sq_rd_fail(r, "bad %s %s", "tag count", "for a tetrahedron");
        for (int k = 0; k < ntags; k++) {
            long long t;
            if (sq_rd_read_long(r, &t, "element tag") < 0)
                return -1;
        }
        long long v[4];
        if (read_tet_nodes(r, v) < 0)
            return -1;
        sq_rd_build_add_tet(b, v, line);
    }
    return expect_end(r, "$EndElements");
}

static int msh_nodes_41(rd *r, build *b)
{
    long long nblocks, n, mintag, maxtag;
    if (sq_rd_read_count(r, &nblocks, "node block count", 2) < 0 || sq_rd_read_count(r, &n, "node count", 2) < 0 ||
        sq_rd_read_long(r, &mintag, "min node tag") < 0 || sq_rd_read_long(r, &maxtag, "max node tag") < 0)
        return -1;
    sq_rd_build_reserve_nodes(b, n);
    long long total = 0;
    for (long long blk = 0; blk < nblocks; blk++) {
        int dim, ent, param;
        long long cnt;
        if (sq_rd_read_int(r, &dim, "entity dimension") < 0 || sq_rd_read_int(r, &ent, "entity tag") < 0 ||
            sq_rd_read_int(r, &param, "parametric flag") < 0 || sq_rd_read_count(r, &cnt, "nodes in block", 2) < 0)
            return -1;
        if (total + cnt > n)
            return sq_rd_fail(r, "node blocks hold more nodes than the header's %s%s", "count", "");
        int first = b->nn;
        for (long long i = 0; i < cnt; i++) {
            sq_rd_skip_ws(r);
            b->nline[b->nn] = r->line;
            if (sq_rd_read_long(r, &b->ntag[b->nn], "node tag") < 0)
                return -1;
            b->nn++;
        }
        int npar = param ? (dim < 0 ? 0 : dim > 3 ? 3 : dim) : 0;
        for (long long i = 0; i < cnt; i++) {
            double *x = b->x + 3 * (size_t)(first + i);
            sq_rd_skip_ws(r);
            b->nline[first + i] = r->line;
            if (sq_rd_read_double(r, &x[0], "coordinate x") < 0 || sq_rd_read_double(r, &x[1], "coordinate y") < 0 ||
                sq_rd_read_double(r, &x[2], "coordinate z") < 0)
                return -1;
            for (int k = 0; k < npar; k++) {
                double u;
                if (sq_rd_read_double(r, &u, "parametric coordinate") < 0)
                    return -1;
            }
        }
        total += cnt;
    }
    if (total != n)
        return sq_rd_fail(r, "node blocks hold fewer nodes than the header's %s%s", "count", "");
    return expect_end(r, "$EndNodes");
}

static int msh_elements_41(rd *r, build *b)
{
    long long nblocks, n, mintag, maxtag;
    if (sq_rd_read_count(r, &nblocks, "element block count", 2) < 0 || sq_rd_read_count(r, &n, "element count", 2) < 0 ||
        sq_rd_read_long(r, &mintag, "min element tag") < 0 || sq_rd_read_long(r, &maxtag, "max element tag") < 0)
        return -1;
    long long total = 0;
    for (long long blk = 0; blk < nblocks; blk++) {
        int dim, ent, type;
        long long cnt;
        if (sq_rd_read_int(r, &dim, "entity dimension") < 0 || sq_rd_read_int(r, &ent, "entity tag") < 0 ||
            sq_rd_read_int(r, &type, "element type") < 0 || sq_rd_read_count(r, &cnt, "elements in block", 2) < 0)
            return -1;
        sq_rd_skip_line(r);
        for (long long e = 0; e < cnt; e++) {
            sq_rd_skip_ws(r);
            if (r->pos >= r->len)
                return sq_rd_fail(r, "unexpected end of file in an element block%s%s; the file is truncated", "", "");
            if (type != 4) {
                b->ho_tets += type == 11 || (type >= 29 && type <= 31);
                sq_rd_skip_line(r);
                continue;
            }
            int line = r->line;
            long long id, v[4];
            if (sq_rd_read_long(r, &id, "element tag") < 0)
                return -1;
            if (read_tet_nodes(r, v) < 0)
                return -1;
            sq_rd_build_add_tet(b, v, line);
        }
        total += cnt;
    }
    if (total != n)
        return sq_rd_fail(r, "element blocks hold a different number of elements than the header's %s%s", "count", "");
    return expect_end(r, "$EndElements");
}

/* a reader's end: the mesh when both its sections were read, else an error naming the missing one */
static sq_mesh *finish_sections(build *b, rd *r, int have_nodes, int have_elems, const char *nodes_name,
                                const char *elems_name)
{
    if (!have_nodes || !have_elems) {
        sq_err_set(r->err, "%s:%d: missing the %s section; the file is truncated or not a volume mesh",
                   r->path, r->line, have_nodes ? elems_name : nodes_name);
        sq_rd_build_free(b);
        return NULL;
    }
    return sq_rd_build_finish(b, r, NULL);
}

static sq_mesh *read_msh(rd *r)
{
    build b = {0};
    char tok[80];
    int version = 0, have_nodes = 0, have_elems = 0;
    while (sq_rd_next_tok(r, tok, sizeof tok)) {
        if (!strcmp(tok, "$MeshFormat")) {
            double ver;
            int ftype, dsize;
            if (sq_rd_read_double(r, &ver, "format version") < 0 || sq_rd_read_int(r, &ftype, "file type") < 0 ||
                sq_rd_read_int(r, &dsize, "data size") < 0)
                goto bad;
            if (ftype != 0) {
                sq_rd_fail(r, "binary .msh is not supported%s%s; save as ASCII (gmsh FILE -save -format msh22)", "", "");
                goto bad;
            }
            if (ver >= 2 && ver < 3)
                version = 2;
            else if (ver >= 4.1 - 1e-9 && ver < 5)
                version = 4;
            else {
                char t[32];
                snprintf(t, sizeof t, "%g", ver);
                sq_rd_fail(r, "unsupported %s %s; save as 2.2 or 4.1 ASCII (gmsh -format msh22)", "msh version", t);
                goto bad;
            }
            if (expect_end(r, "$EndMeshFormat") < 0)
                goto bad;
        } else if (!strcmp(tok, "$Nodes")) {
            if (!version) {
                sq_rd_fail(r, "$Nodes before $MeshFormat%s%s; not a Gmsh file?", "", "");
                goto bad;
            }
            if (have_nodes) {
                sq_rd_fail(r, "a second $Nodes section%s%s; only one is supported", "", "");
                goto bad;
            }
            have_nodes = 1;
            if ((version == 2 ? msh_nodes_22(r, &b) : msh_nodes_41(r, &b)) < 0)
                goto bad;
        } else if (!strcmp(tok, "$Elements")) {
            if (!version) {
                sq_rd_fail(r, "$Elements before $MeshFormat%s%s; not a Gmsh file?", "", "");
                goto bad;
            }
            have_elems = 1;
            if ((version == 2 ? msh_elements_22(r, &b) : msh_elements_41(r, &b)) < 0)
                goto bad;
        } else if (tok[0] == '$' && strncmp(tok, "$End", 4)) {
            if (skip_section(r, tok) < 0)
                goto bad;
        } else {
            sq_rd_fail(r, "unexpected '%s'%s where a $Section was expected; is this a Gmsh .msh file?", tok, "");
            goto bad;
        }
    }
    if (!version) {
        sq_err_set(r->err, "%s:%d: no $MeshFormat section; not a Gmsh .msh file", r->path, r->line);
        goto bad;
    }
    return finish_sections(&b, r, have_nodes, have_elems, "$Nodes", "$Elements");
bad:
    sq_rd_build_free(&b);
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
    if (sq_rd_read_count(&r, &nn, "point count", 2) < 0 || sq_rd_read_int(&r, &dim, "dimension") < 0 ||
        sq_rd_read_int(&r, &nattr, "attribute count") < 0 || sq_rd_read_int(&r, &nmark, "boundary marker flag") < 0)
        goto bad;
    if (dim != 3) {
        sq_rd_fail(&r, "dimension must be 3 for a tetrahedral mesh%s%s", "", "");
        goto bad;
    }
    if (nattr < 0 || nattr > 1000 || nmark < 0 || nmark > 1) {
        sq_rd_fail(&r, "bad attribute count or boundary marker flag%s%s (expected >= 0 and 0 or 1)", "", "");
        goto bad;
    }
    sq_rd_build_reserve_nodes(&b, nn);
    for (long long i = 0; i < nn; i++) {
        sq_rd_skip_ws(&r);
        int line = r.line;
        long long id;
        double *x = b.x + 3 * (size_t)b.nn;
        if (sq_rd_read_long(&r, &id, "point number") < 0 || sq_rd_read_double(&r, &x[0], "coordinate x") < 0 ||
            sq_rd_read_double(&r, &x[1], "coordinate y") < 0 || sq_rd_read_double(&r, &x[2], "coordinate z") < 0)
            goto bad;
        for (int k = 0; k < nattr; k++) {
            double a;
            if (sq_rd_read_double(&r, &a, "point attribute") < 0)
                goto bad;
        }
        for (int k = 0; k < nmark; k++) {
            long long mk;
            if (sq_rd_read_long(&r, &mk, "boundary marker") < 0)
                goto bad;
        }
        b.ntag[b.nn] = id;
        b.nline[b.nn++] = line;
    }
    free(buf);

    buf = sq_read_file(epath, &len, SQ_MESH_MAX_FILE, err);
    if (!buf) {
        tetgen_pair_hint(err);
        sq_rd_build_free(&b);
        return NULL;
    }
    rd re = {epath, buf, len, 0, 1, '#', err};
    long long nt;
    int npt, nreg;
    if (sq_rd_read_count(&re, &nt, "tetrahedron count", 2) < 0 || sq_rd_read_int(&re, &npt, "nodes per tetrahedron") < 0 ||
        sq_rd_read_int(&re, &nreg, "region attribute flag") < 0)
        goto bad_e;
    if (npt != 4 && npt != 10) {
        sq_rd_fail(&re, "nodes per tetrahedron must be 4 or 10%s%s", "", "");
        goto bad_e;
    }
    if (nreg < 0 || nreg > 1000) {
        sq_rd_fail(&re, "bad region attribute count%s%s", "", "");
        goto bad_e;
    }
    for (long long t = 0; t < nt; t++) {
        sq_rd_skip_ws(&re);
        int line = re.line;
        long long id, v[10];
        if (sq_rd_read_long(&re, &id, "tetrahedron number") < 0)
            goto bad_e;
        for (int k = 0; k < npt; k++)
            if (sq_rd_read_long(&re, &v[k], "tetrahedron node") < 0)
                goto bad_e;
        for (int k = 0; k < nreg; k++) {
            double a;
            if (sq_rd_read_double(&re, &a, "region attribute") < 0)
                goto bad_e;
        }
        sq_rd_build_add_tet(&b, v, line);
    }
    sq_mesh *m = sq_rd_build_finish(&b, &re, npath);
    if (m)
        snprintf(m->source, sizeof m->source, "%s", path);
    free(buf);
    return m;
bad_e:
    free(buf);
    sq_rd_build_free(&b);
    return NULL;
bad:
    free(buf);
    sq_rd_build_free(&b);
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
    while (sq_rd_next_tok(r, tok, sizeof tok)) {
        if (!strcasecmp(tok, "MeshVersionFormatted")) {
            int v;
            if (sq_rd_read_int(r, &v, "format version") < 0)
                goto bad;
            if (v < 0 || v > 4) {
                sq_rd_fail(r, "unsupported MeshVersionFormatted%s%s", "", "");
                goto bad;
            }
        } else if (!strcasecmp(tok, "Dimension")) {
            int d;
            if (sq_rd_read_int(r, &d, "dimension") < 0)
                goto bad;
            if (d != 3) {
                sq_rd_fail(r, "Dimension must be 3 for a tetrahedral mesh%s%s", "", "");
                goto bad;
            }
        } else if (!strcasecmp(tok, "Vertices")) {
            long long n;
            if (have_v) {
                sq_rd_fail(r, "a second Vertices section%s%s", "", "");
                goto bad;
            }
            have_v = 1;
            if (sq_rd_read_count(r, &n, "vertex count", 2) < 0)
                goto bad;
            sq_rd_build_reserve_nodes(&b, n);
            for (long long i = 0; i < n; i++) {
                sq_rd_skip_ws(r);
                int line = r->line;
                double *x = b.x + 3 * (size_t)b.nn;
                long long ref;
                if (sq_rd_read_double(r, &x[0], "coordinate x") < 0 || sq_rd_read_double(r, &x[1], "coordinate y") < 0 ||
                    sq_rd_read_double(r, &x[2], "coordinate z") < 0 || sq_rd_read_long(r, &ref, "vertex reference") < 0)
                    goto bad;
                b.ntag[b.nn] = b.nn + 1;
                b.nline[b.nn++] = line;
            }
        } else if (!strcasecmp(tok, "Tetrahedra")) {
            long long n;
            have_t = 1;
            if (sq_rd_read_count(r, &n, "tetrahedron count", 2) < 0)
                goto bad;
            for (long long t = 0; t < n; t++) {
                sq_rd_skip_ws(r);
                int line = r->line;
                long long v[4], ref;
                for (int k = 0; k < 4; k++)
                    if (sq_rd_read_long(r, &v[k], "tetrahedron vertex") < 0)
                        goto bad;
                if (sq_rd_read_long(r, &ref, "tetrahedron reference") < 0)
                    goto bad;
                sq_rd_build_add_tet(&b, v, line);
            }
        } else if (!strcasecmp(tok, "End")) {
            break;
        } else {
            int w = medit_width(tok);
            if (w < 0) {
                sq_rd_fail(r, "unknown keyword '%s'%s; not a Medit .mesh file, or a section this reader does not know",
                     tok, "");
                goto bad;
            }
            if (w == 0) {
                sq_rd_skip_line(r);
                continue;
            }
            long long n;
            if (sq_rd_read_count(r, &n, tok, 2) < 0)
                goto bad;
            for (long long i = 0; i < n * w; i++) {
                double d;
                if (sq_rd_read_double(r, &d, tok) < 0)
                    goto bad;
            }
        }
    }
    return finish_sections(&b, r, have_v, have_t, "Vertices", "Tetrahedra");
bad:
    sq_rd_build_free(&b);
    return NULL;
}

const char *sq_rd_ext_of(const char *path)
{
    const char *dot = strrchr(path, '.'), *slash = strrchr(path, '/');
    if (!dot || (slash && dot < slash))
        return "";
    return dot;
}

sq_mesh *sq_mesh_load(const char *path, sq_err *err)
{
    const char *ext = sq_rd_ext_of(path);
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
