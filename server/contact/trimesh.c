/* trimesh.c - triangle meshes for obstacles: OBJ and STL (ASCII and binary) readers, normals,
 * the hierarchy and the nearest-point query. */
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "contact/contact_internal.h"

#define TRIMESH_MAX 2000000 /* vertices or triangles: beyond, the file is refused */

typedef struct grow {
    double *x;
    int nv, capv;
    int *t;
    int nt, capt;
} grow;

static int add_vertex(grow *g, const double p[3])
{
    if (g->nv >= TRIMESH_MAX)
        return -1;
    if (g->nv == g->capv) {
        g->capv = g->capv ? 2 * g->capv : 256;
        g->x = sq_realloc(g->x, sizeof(double) * 3 * (size_t)g->capv);
    }
    memcpy(g->x + 3 * (size_t)g->nv, p, sizeof(double) * 3);
    g->nv++;
    return 0;
}

static int add_tri(grow *g, int a, int b, int c)
{
    if (g->nt >= TRIMESH_MAX)
        return -1;
    if (g->nt == g->capt) {
        g->capt = g->capt ? 2 * g->capt : 256;
        g->t = sq_realloc(g->t, sizeof(int) * 3 * (size_t)g->capt);
    }
    g->t[3 * g->nt] = a;
    g->t[3 * g->nt + 1] = b;
    g->t[3 * g->nt + 2] = c;
    g->nt++;
    return 0;
}

/* OBJ: "v x y z" and "f a b c ..." (a may be a/b/c, negative indices count from the end);
 * everything else is ignored */
static int read_obj(FILE *f, const char *path, grow *g, sq_err *err)
{
    char line[4096];
    int lineno = 0;
    while (fgets(line, sizeof line, f)) {
        lineno++;
        char *s = line;
        while (isspace((unsigned char)*s))
            s++;
        if (s[0] == 'v' && isspace((unsigned char)s[1])) {
            double p[3];
            char *end = s + 1;
            for (int c = 0; c < 3; c++) {
                char *q = end;
                p[c] = strtod(q, &end);
                if (end == q || !isfinite(p[c]))
                    return sq_err_set(err, "%s:%d: a vertex needs three finite numbers (\"v x y z\"); fix the line",
                                      path, lineno);
            }
            if (add_vertex(g, p) < 0)
                return sq_err_set(err, "%s:%d: more than %d vertices; simplify the mesh", path, lineno, TRIMESH_MAX);
        } else if (s[0] == 'f' && isspace((unsigned char)s[1])) {
            int idx[64], n = 0;
            char *tok = strtok(s + 1, " \t\r\n");
            while (tok && n < 64) {
                char *end;
                errno = 0;
                long k = strtol(tok, &end, 10);
                if (end == tok || errno || k == 0)
                    return sq_err_set(err, "%s:%d: \"%s\" is not a vertex index (1-based, or negative from the "
                                      "end); fix the face", path, lineno, tok);
                if (k < 0)
                    k += g->nv + 1;
                if (k < 1 || k > g->nv)
                    return sq_err_set(err, "%s:%d: vertex %ld does not exist (the file has %d so far); fix the face",
                                      path, lineno, k, g->nv);
                idx[n++] = (int)k - 1;
                tok = strtok(NULL, " \t\r\n");
            }
            if (n < 3)
                return sq_err_set(err, "%s:%d: a face needs at least 3 vertices; fix the line", path, lineno);
            for (int k = 1; k + 1 < n; k++)
                if (add_tri(g, idx[0], idx[k], idx[k + 1]) < 0)
                    return sq_err_set(err, "%s:%d: more than %d triangles; simplify the mesh", path, lineno,
                                      TRIMESH_MAX);
        }
    }
    return 0;
}

static int read_stl_ascii(FILE *f, const char *path, grow *g, sq_err *err)
{
    char line[1024];
    int lineno = 0, corner = 0;
    while (fgets(line, sizeof line, f)) {
        lineno++;
        char *s = line;
        while (isspace((unsigned char)*s))
            s++;
        if (strncmp(s, "vertex", 6))
            continue;
        double p[3];
        if (sscanf(s + 6, "%lf %lf %lf", &p[0], &p[1], &p[2]) != 3 || !isfinite(p[0]) || !isfinite(p[1]) ||
            !isfinite(p[2]))
            return sq_err_set(err, "%s:%d: a vertex needs three finite numbers; fix the line", path, lineno);
        if (add_vertex(g, p) < 0)
            return sq_err_set(err, "%s:%d: more than %d vertices; simplify the mesh", path, lineno, TRIMESH_MAX);
        if (++corner == 3) {
            corner = 0;
            if (add_tri(g, g->nv - 3, g->nv - 2, g->nv - 1) < 0)
                return sq_err_set(err, "%s:%d: more than %d triangles; simplify the mesh", path, lineno, TRIMESH_MAX);
        }
    }
    if (corner)
        return sq_err_set(err, "%s: the last facet has %d vertices, not 3; the file is cut short", path, corner);
    return 0;
}

static int read_stl_binary(FILE *f, const char *path, long size, grow *g, sq_err *err)
{
    unsigned char head[84];
    if (fread(head, 1, 84, f) != 84)
        return sq_err_set(err, "%s: shorter than a binary STL header (84 bytes); the file is cut short", path);
    unsigned long n = head[80] | head[81] << 8 | head[82] << 16 | (unsigned long)head[83] << 24;
    if (n > TRIMESH_MAX)
        return sq_err_set(err, "%s: %lu triangles, more than %d; simplify the mesh", path, n, TRIMESH_MAX);
    if (size != 84 + 50 * (long)n)
        return sq_err_set(err, "%s: a binary STL of %lu triangles is %ld bytes, this one %ld; the file is cut short "
                          "or not STL", path, n, 84 + 50 * (long)n, size);
    for (unsigned long t = 0; t < n; t++) {
        unsigned char rec[50];
        if (fread(rec, 1, 50, f) != 50)
            return sq_err_set(err, "%s: triangle %lu is cut short", path, t);
        for (int c = 0; c < 3; c++) {
            double p[3];
            for (int k = 0; k < 3; k++) {
                float v;
                memcpy(&v, rec + 12 + 12 * c + 4 * k, 4); /* little-endian, as the format is */
                p[k] = v;
                if (!isfinite(p[k]))
                    return sq_err_set(err, "%s: triangle %lu has a non-finite coordinate; fix the file", path, t);
            }
            add_vertex(g, p);
        }
        add_tri(g, g->nv - 3, g->nv - 2, g->nv - 1);
    }
    return 0;
}

static int ends_with(const char *s, const char *suffix)
{
    size_t n = strlen(s), m = strlen(suffix);
    return n >= m && !strcasecmp(s + n - m, suffix);
}

sq_trimesh *sq_trimesh_load(const char *path, double scale, const double offset[3], sq_err *err)
{
    if (!(scale > 0) || !isfinite(scale)) {
        sq_err_set(err, "%s: scale %g must be a positive number", path, scale);
        return NULL;
    }
    int obj = ends_with(path, ".obj"), stl = ends_with(path, ".stl");
    if (!obj && !stl) {
        sq_err_set(err, "%s: not an obstacle mesh format; use a .obj or .stl file", path);
        return NULL;
    }
    FILE *f = fopen(path, "rb");
    if (!f) {
        sq_err_set(err, "%s: cannot open (%s); check the path (relative to the scene file)", path, strerror(errno));
        return NULL;
    }
    grow g = {0};
    int rc;
    if (obj) {
        rc = read_obj(f, path, &g, err);
    } else {
        char word[6] = {0};
        fseek(f, 0, SEEK_END);
        long size = ftell(f);
        rewind(f);
        size_t got = fread(word, 1, 5, f);
        rewind(f);
        /* "solid" opens an ASCII file; binary files whose header says "solid" have the exact size */
        if (got == 5 && !memcmp(word, "solid", 5) && !(size >= 84 && (size - 84) % 50 == 0 && size > 84))
            rc = read_stl_ascii(f, path, &g, err);
        else
            rc = read_stl_binary(f, path, size, &g, err);
    }
    fclose(f);
    sq_trimesh *m = NULL;
    if (rc == 0) {
        for (int i = 0; i < g.nv; i++)
            for (int c = 0; c < 3; c++)
                g.x[3 * i + c] = scale * g.x[3 * i + c] + (offset ? offset[c] : 0);
        m = sq_trimesh_from_arrays(g.nv, g.x, g.nt, g.t, path, err);
    }
    free(g.x);
    free(g.t);
    return m;
}

sq_trimesh *sq_trimesh_from_arrays(int nverts, const double *x, int ntris, const int *tris, const char *source,
                                   sq_err *err)
{
    if (ntris < 1 || nverts < 3) {
        sq_err_set(err, "%s: %d triangles and %d vertices; an obstacle mesh needs at least one triangle", source, ntris,
                   nverts);
        return NULL;
    }
    for (int t = 0; t < 3 * ntris; t++)
        if (tris[t] < 0 || tris[t] >= nverts) {
            sq_err_set(err, "%s: triangle %d names vertex %d of %d; fix the file", source, t / 3, tris[t], nverts);
            return NULL;
        }
    sq_trimesh *m = sq_calloc(1, sizeof *m);
    m->nverts = nverts;
    m->ntris = ntris;
    m->x = sq_malloc(sizeof(double) * 3 * (size_t)nverts);
    m->tris = sq_malloc(sizeof(int) * 3 * (size_t)ntris);
    m->normal = sq_malloc(sizeof(double) * 3 * (size_t)ntris);
    memcpy(m->x, x, sizeof(double) * 3 * (size_t)nverts);
    memcpy(m->tris, tris, sizeof(int) * 3 * (size_t)ntris);
    snprintf(m->source, sizeof m->source, "%s", source);
    for (int c = 0; c < 3; c++) {
        m->bbox_min[c] = INFINITY;
        m->bbox_max[c] = -INFINITY;
    }
    for (int i = 0; i < nverts; i++)
        for (int c = 0; c < 3; c++) {
            m->bbox_min[c] = fmin(m->bbox_min[c], x[3 * i + c]);
            m->bbox_max[c] = fmax(m->bbox_max[c], x[3 * i + c]);
        }
    for (int i = 0; i < 3 * nverts; i++)
        if (!(fabs(x[i]) <= 1e6)) {
            sq_err_set(err, "%s: vertex %d has coordinate %g, beyond 1e6 m; check the file's units (\"scale\")",
                       source, i / 3, x[i]);
            sq_trimesh_free(m);
            return NULL;
        }
    /* zero-area triangles have no side: dropped (the kept ones are compacted in file order) */
    int kept = 0;
    for (int t = 0; t < ntris; t++) {
        const double *a = x + 3 * tris[3 * t], *b = x + 3 * tris[3 * t + 1], *c = x + 3 * tris[3 * t + 2];
        double u[3], v[3], n[3];
        for (int k = 0; k < 3; k++) {
            u[k] = b[k] - a[k];
            v[k] = c[k] - a[k];
        }
        n[0] = u[1] * v[2] - u[2] * v[1];
        n[1] = u[2] * v[0] - u[0] * v[2];
        n[2] = u[0] * v[1] - u[1] * v[0];
        double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (!(len > 1e-300) || !isfinite(len))
            continue;
        for (int k = 0; k < 3; k++) {
            m->normal[3 * kept + k] = n[k] / len;
            m->tris[3 * kept + k] = tris[3 * t + k];
        }
        kept++;
    }
    if (kept == 0) {
        sq_err_set(err, "%s: every triangle has zero area; fix the file", source);
        sq_trimesh_free(m);
        return NULL;
    }
    m->ntris = ntris = kept;
    m->bvh = sq_bvh_build(m->x, m->tris, ntris);
    return m;
}

void sq_trimesh_free(sq_trimesh *m)
{
    if (!m)
        return;
    sq_bvh_free(m->bvh);
    free(m->x);
    free(m->tris);
    free(m->normal);
    free(m);
}

int sq_trimesh_nearest(const sq_trimesh *m, const double p[3], double reach, double *dist, double closest[3],
                       double bary[3])
{
    return sq_bvh_nearest(m->bvh, m->x, m->tris, p, reach, dist, closest, bary);
}
