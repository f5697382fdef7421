/* mesh.c - mesh construction, validation, topology (boundary, adjacency) and the box mesh. */
#include "mesh/mesh.h"
#include "mesh/mesh_internal.h"

#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* a tet whose volume is below this fraction of (longest edge)^3 is degenerate;
 * a regular tet has 1/(6 sqrt 2) ~ 0.118, a sliver the Gmsh optimiser would keep ~1e-3 */
#define SQ_DEGENERATE_RATIO 1e-9

/* outward counter-clockwise faces of a positively oriented tet, face k opposite vertex k */
const int sq_tet_face[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};

/* free what sq_mesh_finalize derives from x and tets (faces, surface, adjacency, locator) */
static void clear_derived(sq_mesh *m);

void sq_mesh_free(sq_mesh *m)
{
    if (!m)
        return;
    free(m->x);
    free(m->tets);
    clear_derived(m);
    free(m);
}

static double vol6(const double *a, const double *b, const double *c, const double *d)
{
    double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    double e3[3] = {d[0] - a[0], d[1] - a[1], d[2] - a[2]};
    return e1[0] * (e2[1] * e3[2] - e2[2] * e3[1]) - e1[1] * (e2[0] * e3[2] - e2[2] * e3[0]) +
           e1[2] * (e2[0] * e3[1] - e2[1] * e3[0]);
}

double sq_tet_volume(const sq_mesh *m, int t)
{
    const int *v = m->tets + 4 * (size_t)t;
    return vol6(m->x + 3 * (size_t)v[0], m->x + 3 * (size_t)v[1], m->x + 3 * (size_t)v[2],
                m->x + 3 * (size_t)v[3]) / 6.0;
}

static void cross(const double a[3], const double b[3], double c[3])
{
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

double sq_tet_gradients(const sq_mesh *m, int t, double grad[4][3])
{
    const int *v = m->tets + 4 * (size_t)t;
    const double *x0 = m->x + 3 * (size_t)v[0];
    double e[3][3];
    for (int k = 0; k < 3; k++)
        for (int c = 0; c < 3; c++)
            e[k][c] = m->x[3 * (size_t)v[k + 1] + c] - x0[c];
    double c23[3], c31[3], c12[3];
    cross(e[1], e[2], c23);
    cross(e[2], e[0], c31);
    cross(e[0], e[1], c12);
    double det = e[0][0] * c23[0] + e[0][1] * c23[1] + e[0][2] * c23[2];
    double inv = det != 0 ? 1.0 / det : 0.0;
    for (int c = 0; c < 3; c++) {
        grad[1][c] = c23[c] * inv;
        grad[2][c] = c31[c] * inv;
        grad[3][c] = c12[c] * inv;
        grad[0][c] = -(grad[1][c] + grad[2][c] + grad[3][c]);
    }
    return det / 6.0;
}

/* where a node or tet came from, for messages: "file:LINE" or "source: tet N" */
static void where_node(const sq_mesh *m, const char *node_file, const int *line, int i, char *buf, size_t n)
{
    const char *src = node_file ? node_file : m->source;
    if (line)
        snprintf(buf, n, "%s:%d: node", src, line[i]);
    else
        snprintf(buf, n, "%s: node %d", src, i);
}

/* from a file the line says which tet; from arrays the index and nodes do */
static void where_tet(const sq_mesh *m, const int *line, int t, char *buf, size_t n)
{
    const int *v = m->tets + 4 * (size_t)t;
    if (line)
        snprintf(buf, n, "%s:%d: tetrahedron", m->source, line[t]);
    else
        snprintf(buf, n, "%s: tet %d (nodes %d %d %d %d)", m->source, t, v[0], v[1], v[2], v[3]);
}

int sq_mesh_validate(sq_mesh *m, const char *node_file, const int *node_line, const int *tet_line, sq_err *err)
{
    char w[300];
    if (m->nnodes <= 0)
        return sq_err_set(err, "%s: no nodes; a tetrahedral mesh needs nodes and 4-node tets", m->source);
    if (m->ntets <= 0)
        return sq_err_set(err, "%s: no tetrahedra (4-node volume elements); mesh the volume "
                          "(e.g. gmsh -3) and save again", m->source);
    for (int i = 0; i < m->nnodes; i++)
        for (int c = 0; c < 3; c++)
            if (!isfinite(m->x[3 * (size_t)i + c])) {
                where_node(m, node_file, node_line, i, w, sizeof w);
                return sq_err_set(err, "%s: coordinate %c is not finite (%g); fix the coordinates",
                                  w, "xyz"[c], m->x[3 * (size_t)i + c]);
            }
    for (int t = 0; t < m->ntets; t++)
        for (int k = 0; k < 4; k++) {
            int v = m->tets[4 * (size_t)t + k];
            if (v < 0 || v >= m->nnodes) {
                where_tet(m, tet_line, t, w, sizeof w);
                return sq_err_set(err, "%s: node index %d out of range [0, %d); the file's "
                                  "node numbering and element list disagree", w, v, m->nnodes);
            }
        }
    /* degenerate tets, then orientation: all negative = the file's convention, flip all */
    int npos = 0, nneg = 0, first_pos = -1, first_neg = -1;
    for (int t = 0; t < m->ntets; t++) {
        const int *v = m->tets + 4 * (size_t)t;
        const double *p[4];
        for (int k = 0; k < 4; k++)
            p[k] = m->x + 3 * (size_t)v[k];
        double lmax2 = 0;
        for (int a = 0; a < 4; a++)
            for (int b = a + 1; b < 4; b++) {
                double d0 = p[a][0] - p[b][0], d1 = p[a][1] - p[b][1], d2 = p[a][2] - p[b][2];
                double l2 = d0 * d0 + d1 * d1 + d2 * d2;
                if (l2 > lmax2)
                    lmax2 = l2;
            }
        double vol = vol6(p[0], p[1], p[2], p[3]) / 6.0;
        double lmax = sqrt(lmax2);
        if (!(fabs(vol) > SQ_DEGENERATE_RATIO * lmax * lmax * lmax) || lmax == 0) {
            where_tet(m, tet_line, t, w, sizeof w);
            return sq_err_set(err, "%s: degenerate, volume %.3g for longest edge %.3g; remove it or "
                              "remesh", w, vol, lmax);
        }
        if (vol > 0) {
            if (first_pos < 0)
                first_pos = t;
            npos++;
        } else {
            if (first_neg < 0)
                first_neg = t;
            nneg++;
        }
    }
    if (npos && nneg) {
        /* the minority is the wrong one */
        int bad = npos >= nneg ? first_neg : first_pos;
        where_tet(m, tet_line, bad, w, sizeof w);
        return sq_err_set(err, "%s: inverted (volume %.3g) while %d of %d tets have the other "
                          "orientation; swap two of its nodes or remesh", w, sq_tet_volume(m, bad),
                          npos >= nneg ? npos : nneg, m->ntets);
    }
    if (nneg) {
        for (int t = 0; t < m->ntets; t++) {
            int *v = m->tets + 4 * (size_t)t;
            int s = v[2];
            v[2] = v[3];
            v[3] = s;
        }
    }
    /* unreferenced nodes */
    unsigned char *used = sq_calloc((size_t)m->nnodes, 1);
    for (size_t k = 0; k < 4 * (size_t)m->ntets; k++)
        used[m->tets[k]] = 1;
    for (int i = 0; i < m->nnodes; i++)
        if (!used[i]) {
            free(used);
            where_node(m, node_file, node_line, i, w, sizeof w);
            return sq_err_set(err, "%s: not used by any tetrahedron; remove unreferenced nodes "
                              "(gmsh: Mesh.SaveAll=0, or 'squish mesh convert')", w);
        }
    free(used);
    return 0;
}

/* a face sorted by nodes, with the tet and local face it came from */
typedef struct face_rec {
    int b, c;   /* the two larger sorted nodes (the smallest is the bucket) */
    int tet;
    int local;
} face_rec;

static int face_cmp(const void *pa, const void *pb)
{
    const face_rec *a = pa, *b = pb;
    if (a->b != b->b)
        return a->b < b->b ? -1 : 1;
    if (a->c != b->c)
        return a->c < b->c ? -1 : 1;
    return 0;
}

static void sort3(int *a, int *b, int *c)
{
    int t;
    if (*a > *b) { t = *a; *a = *b; *b = t; }
    if (*b > *c) { t = *b; *b = *c; *c = t; }
    if (*a > *b) { t = *a; *a = *b; *b = t; }
}

/* sort a small set of faces: insertion sort, qsort when large */
static void sort_faces(face_rec *f, int n)
{
    if (n > 64) {
        qsort(f, (size_t)n, sizeof *f, face_cmp);
        return;
    }
    for (int i = 1; i < n; i++) {
        face_rec r = f[i];
        int j = i - 1;
        while (j >= 0 && face_cmp(&f[j], &r) > 0) {
            f[j + 1] = f[j];
            j--;
        }
        f[j + 1] = r;
    }
}

static int int_cmp(const void *pa, const void *pb)
{
    int a = *(const int *)pa, b = *(const int *)pb;
    return (a > b) - (a < b);
}

static void sort_ints(int *v, int n)
{
    if (n > 32) {
        qsort(v, (size_t)n, sizeof *v, int_cmp);
        return;
    }
    for (int i = 1; i < n; i++) {
        int r = v[i], j = i - 1;
        while (j >= 0 && v[j] > r) {
            v[j + 1] = v[j];
            j--;
        }
        v[j + 1] = r;
    }
}

static void clear_derived(sq_mesh *m)
{
    free(m->tris);
    free(m->on_boundary);
    free(m->surf_nodes);
    free(m->surf_of_node);
    free(m->surf_tris);
    free(m->adj_start);
    free(m->adj);
    free(m->tri_tet);
    m->tris = m->surf_nodes = m->surf_of_node = m->surf_tris = m->adj_start = m->adj = NULL;
    m->tri_tet = NULL;
    m->on_boundary = NULL;
    m->ntris = m->nsurf = 0;
    sq_locator_free(m->locator);
    m->locator = NULL;
}

/* the bounding box of the nodes (zero for an empty mesh) */
static void finalize_bbox(sq_mesh *m)
{
    const int n = m->nnodes;
    for (int c = 0; c < 3; c++) {
        m->bbox_min[c] = n ? m->x[c] : 0;
        m->bbox_max[c] = n ? m->x[c] : 0;
    }
    for (int i = 0; i < n; i++)
        for (int c = 0; c < 3; c++) {
            double v = m->x[3 * (size_t)i + c];
            if (v < m->bbox_min[c])
                m->bbox_min[c] = v;
            if (v > m->bbox_max[c])
                m->bbox_max[c] = v;
        }
}

/* the boundary triangles (the faces mask marks per tet: nb in all), boundary nodes and the
 * surface numbering */
static void finalize_surface(sq_mesh *m, const unsigned char *mask, int nb)
{
    const int n = m->nnodes, nt = m->ntets;
    /* boundary triangles in a deterministic order: by tet, then local face */
    m->ntris = nb;
    m->tris = sq_malloc((size_t)(nb ? nb : 1) * 3 * sizeof *m->tris);
    m->tri_tet = sq_malloc((size_t)(nb ? nb : 1) * sizeof *m->tri_tet);
    m->on_boundary = sq_calloc((size_t)(n ? n : 1), 1);
    int p = 0;
    for (int t = 0; t < nt; t++)
        for (int k = 0; k < 4; k++)
            if (mask[t] & (1u << k)) {
                const int *v = m->tets + 4 * (size_t)t;
                const int *f = sq_tet_face[k];
                for (int q = 0; q < 3; q++) {
                    m->tris[3 * p + q] = v[f[q]];
                    m->on_boundary[v[f[q]]] = 1;
                }
                m->tri_tet[p++] = t;
            }
    m->surf_of_node = sq_malloc((size_t)(n ? n : 1) * sizeof *m->surf_of_node);
    m->nsurf = 0;
    for (int i = 0; i < n; i++)
        m->surf_of_node[i] = m->on_boundary[i] ? m->nsurf++ : -1;
    m->surf_nodes = sq_malloc((size_t)(m->nsurf ? m->nsurf : 1) * sizeof *m->surf_nodes);
    for (int i = 0; i < n; i++)
        if (m->surf_of_node[i] >= 0)
            m->surf_nodes[m->surf_of_node[i]] = i;
    m->surf_tris = sq_malloc((size_t)(nb ? nb : 1) * 3 * sizeof *m->surf_tris);
    for (int i = 0; i < 3 * nb; i++)
        m->surf_tris[i] = m->surf_of_node[m->tris[i]];
}

int sq_mesh_finalize(sq_mesh *m, sq_err *err)
{
    const int n = m->nnodes, nt = m->ntets;
    clear_derived(m);

    finalize_bbox(m);


    /* node -> tets incidence (CSR) */
    int *start = sq_calloc((size_t)n + 1, sizeof *start);
    for (size_t k = 0; k < 4 * (size_t)nt; k++)
        start[m->tets[k] + 1]++;
    for (int i = 0; i < n; i++)
        start[i + 1] += start[i];
    int *inc = sq_malloc((4 * (size_t)nt + 1) * sizeof *inc);
    int *fill = sq_malloc(((size_t)n + 1) * sizeof *fill);
    memcpy(fill, start, ((size_t)n + 1) * sizeof *fill);
    for (int t = 0; t < nt; t++)
        for (int k = 0; k < 4; k++)
            inc[fill[m->tets[4 * (size_t)t + k]]++] = t;
    free(fill);

    /* per node a: the faces whose smallest node is a come from a's tets; sort them and
     * match equal ones (O(n) overall, no global face array). The same pass gathers the
     * adjacency: the distinct vertices of a's tets, found with a marker array. */
    unsigned char *mask = sq_calloc((size_t)(nt ? nt : 1), 1); /* boundary faces per tet */
    int *mark = sq_malloc((size_t)(n ? n : 1) * sizeof *mark);
    for (int i = 0; i < n; i++)
        mark[i] = -1;
    m->adj_start = sq_malloc(((size_t)n + 1) * sizeof *m->adj_start);
    size_t acap = 16 * (size_t)n + 16, an = 0;
    m->adj = sq_malloc(acap * sizeof *m->adj);
    int fcap = 256;
    face_rec *fr = sq_malloc((size_t)fcap * sizeof *fr);
    int nb = 0;
    for (int a = 0; a < n; a++) {
        int deg = start[a + 1] - start[a], nfa = 0;
        if (3 * deg > fcap) {
            fcap = 3 * deg;
            fr = sq_realloc(fr, (size_t)fcap * sizeof *fr);
        }
        /* adjacency row */
        size_t row = an;
        if (an + 4 * (size_t)deg + 1 > acap) {
            while (an + 4 * (size_t)deg + 1 > acap)
                acap *= 2;
            m->adj = sq_realloc(m->adj, acap * sizeof *m->adj);
        }
        m->adj_start[a] = (int)an;
        mark[a] = a;
        m->adj[an++] = a;
        for (int e = start[a]; e < start[a + 1]; e++) {
            int t = inc[e];
            const int *v = m->tets + 4 * (size_t)t;
            for (int k = 0; k < 4; k++) {
                if (mark[v[k]] != a) {
                    mark[v[k]] = a;
                    m->adj[an++] = v[k];
                }
                const int *f = sq_tet_face[k];
                int x = v[f[0]], y = v[f[1]], z = v[f[2]];
                sort3(&x, &y, &z);
                if (x != a)
                    continue;
                fr[nfa].b = y;
                fr[nfa].c = z;
                fr[nfa].tet = t;
                fr[nfa].local = k;
                nfa++;
            }
        }
        sort_ints(m->adj + row, (int)(an - row));
        if (an > INT_MAX) {
            free(fr);
            free(mark);
            free(mask);
            free(inc);
            free(start);
            return sq_err_set(err, "%s: too many node neighbours for 32-bit indices; use a smaller mesh",
                              m->source);
        }
        sort_faces(fr, nfa);
        for (int i = 0; i < nfa;) {
            int j = i + 1;
            while (j < nfa && fr[j].b == fr[i].b && fr[j].c == fr[i].c)
                j++;
            const char *bad = NULL;
            if (j - i > 2)
                bad = "shared by more than two tets: overlapping or duplicate elements";
            else if (j - i == 2 && fr[i].tet == fr[i + 1].tet)
                bad = "repeated inside one tet";
            if (bad) {
                sq_err_set(err, "%s: face (nodes %d %d %d) of tet %d %s; remesh", m->source, a, fr[i].b,
                           fr[i].c, fr[i].tet, bad);
                free(fr);
                free(mark);
                free(mask);
                free(inc);
                free(start);
                return -1;
            }
            if (j - i == 1) {
                mask[fr[i].tet] |= (unsigned char)(1u << fr[i].local);
                nb++;
            }
            i = j;
        }
    }
    m->adj_start[n] = (int)an;
    m->adj = sq_realloc(m->adj, (an ? an : 1) * sizeof *m->adj);
    free(fr);
    free(mark);
    free(inc);
    free(start);

    finalize_surface(m, mask, nb);
    free(mask);
    return 0;
}

sq_mesh *sq_mesh_new_owned(int nnodes, double *x, int ntets, int *tets, const char *source)
{
    sq_mesh *m = sq_calloc(1, sizeof *m);
    m->nnodes = nnodes;
    m->ntets = ntets;
    m->x = x;
    m->tets = tets;
    snprintf(m->source, sizeof m->source, "%s", source ? source : "(mesh)");
    return m;
}

sq_mesh *sq_mesh_validate_finalize(sq_mesh *m, const char *node_file, const int *node_line,
                                   const int *tet_line, sq_err *err)
{
    if (sq_mesh_validate(m, node_file, node_line, tet_line, err) < 0 || sq_mesh_finalize(m, err) < 0) {
        sq_mesh_free(m);
        return NULL;
    }
    return m;
}

sq_mesh *sq_mesh_from_arrays(int nnodes, const double *x, int ntets, const int *tets,
                             const char *source, sq_err *err)
{
    if (nnodes < 0 || ntets < 0 || (nnodes > 0 && !x) || (ntets > 0 && !tets)) {
        sq_err_set(err, "%s: invalid arrays (nnodes %d, ntets %d)", source ? source : "(mesh)", nnodes,
                   ntets);
        return NULL;
    }
    double *xc = sq_malloc((size_t)(nnodes ? nnodes : 1) * 3 * sizeof *xc);
    int *tc = sq_malloc((size_t)(ntets ? ntets : 1) * 4 * sizeof *tc);
    if (nnodes)
        memcpy(xc, x, (size_t)nnodes * 3 * sizeof *xc);
    if (ntets)
        memcpy(tc, tets, (size_t)ntets * 4 * sizeof *tc);
    sq_mesh *m = sq_mesh_new_owned(nnodes, xc, ntets, tc, source);
    return sq_mesh_validate_finalize(m, NULL, NULL, NULL, err);
}

sq_mesh *sq_mesh_box(int nx, int ny, int nz, const double size[3], const double origin[3], sq_err *err)
{
    static const double unit[3] = {1, 1, 1}, zero[3] = {0, 0, 0};
    if (!size)
        size = unit;
    if (!origin)
        origin = zero;
    if (nx < 1 || ny < 1 || nz < 1) {
        sq_err_set(err, "box: cell counts must be >= 1 (got %d %d %d)", nx, ny, nz);
        return NULL;
    }
    for (int c = 0; c < 3; c++)
        if (!(size[c] > 0) || !isfinite(size[c]) || !isfinite(origin[c])) {
            sq_err_set(err, "box: size must be positive and finite and origin finite (axis %c: size %g, "
                       "origin %g)", "xyz"[c], size[c], origin[c]);
            return NULL;
        }
    double nn = ((double)nx + 1) * ((double)ny + 1) * ((double)nz + 1), ntd = 6.0 * nx * ny * nz;
    if (nn > 2e8 || ntd > (double)INT_MAX / 4) {
        sq_err_set(err, "box: %d x %d x %d cells is too large (%.3g tets); use fewer cells", nx, ny, nz, ntd);
        return NULL;
    }
    int n = (int)nn, nt = (int)ntd;
    double *x = sq_malloc((size_t)n * 3 * sizeof *x);
    int *tets = sq_malloc((size_t)nt * 4 * sizeof *tets);
    const int sx = 1, sy = nx + 1, sz = (nx + 1) * (ny + 1);
    for (int k = 0; k <= nz; k++)
        for (int j = 0; j <= ny; j++)
            for (int i = 0; i <= nx; i++) {
                double *p = x + 3 * ((size_t)k * sz + (size_t)j * sy + i);
                /* i == nx gives exactly size, so the far faces are exact */
                p[0] = origin[0] + (i == nx ? size[0] : size[0] * i / nx);
                p[1] = origin[1] + (j == ny ? size[1] : size[1] * j / ny);
                p[2] = origin[2] + (k == nz ? size[2] : size[2] * k / nz);
            }
    /* Kuhn split: the 6 monotone paths from corner 000 to 111, one per axis permutation */
    static const int perm[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
    const int step[3] = {sx, sy, sz};
    size_t t = 0;
    for (int k = 0; k < nz; k++)
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++) {
                int base = k * sz + j * sy + i;
                for (int p = 0; p < 6; p++) {
                    int v0 = base, v1 = v0 + step[perm[p][0]], v2 = v1 + step[perm[p][1]],
                        v3 = v2 + step[perm[p][2]];
                    int *q = tets + 4 * t++;
                    /* odd permutations give negative volume: swap the last two */
                    int odd = p == 1 || p == 2 || p == 5;
                    q[0] = v0;
                    q[1] = v1;
                    q[2] = odd ? v3 : v2;
                    q[3] = odd ? v2 : v3;
                }
            }
    char src[128];
    snprintf(src, sizeof src, "box %dx%dx%d", nx, ny, nz);
    sq_mesh *m = sq_mesh_new_owned(n, x, nt, tets, src);
    if (sq_mesh_finalize(m, err) < 0) {
        sq_mesh_free(m);
        return NULL;
    }
    return m;
}
