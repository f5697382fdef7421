/* locate.c - point location (uniform grids over tet and boundary-triangle centroids) and
 * mesh measurements. */
#include "mesh/mesh.h"
#include "mesh/mesh_internal.h"

#include <float.h>
#include <limits.h>
#include <stdint.h>
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

/* a uniform grid; each item (tet or triangle) is listed in every cell its bounding box
 * overlaps, so the cell of a point lists every item that can contain it */
typedef struct grid {
    int dim[3];
    double lo[3], cell[3];
    int *start; /* CSR over cells (ncells + 1) */
    int *item;
} grid;

struct sq_locator {
    grid tets, tris;
};

static pthread_mutex_t locator_lock = PTHREAD_MUTEX_INITIALIZER;

size_t sq_locator_cells(const sq_mesh *m, size_t *items)
{
    double b[4], p[3] = {m->bbox_min[0], m->bbox_min[1], m->bbox_min[2]};
    sq_mesh_locate(m, p, b); /* builds the grids */
    const struct sq_locator *loc = m->locator;
    if (!loc)
        return 0;
    size_t cells = 0, n = 0;
    const grid *g[2] = {&loc->tets, &loc->tris};
    for (int k = 0; k < 2; k++) {
        size_t c = (size_t)g[k]->dim[0] * g[k]->dim[1] * g[k]->dim[2];
        cells += c;
        n += (size_t)g[k]->start[c];
    }
    if (items)
        *items = n;
    return cells;
}

static void grid_free(grid *g)
{
    free(g->start);
    free(g->item);
}

void sq_locator_free(struct sq_locator *loc)
{
    if (!loc)
        return;
    grid_free(&loc->tets);
    grid_free(&loc->tris);
    free(loc);
}

static int cell_coord(const grid *g, int c, double v)
{
    double f = (v - g->lo[c]) / g->cell[c];
    if (!(f >= 0))
        return 0;
    if (f >= g->dim[c])
        return g->dim[c] - 1;
    return (int)f;
}

/* cell range of an item's bounding box */
static void item_cells(const grid *g, const sq_mesh *m, const int *v, int nv, int lo[3], int hi[3])
{
    for (int c = 0; c < 3; c++) {
        double mn = m->x[3 * (size_t)v[0] + c], mx = mn;
        for (int k = 1; k < nv; k++) {
            double x = m->x[3 * (size_t)v[k] + c];
            mn = x < mn ? x : mn;
            mx = x > mx ? x : mx;
        }
        lo[c] = cell_coord(g, c, mn);
        hi[c] = cell_coord(g, c, mx);
    }
}

/* bin n items of nv vertices each (indices into x) by bounding box; cells start at scale times
 * the mean item edge; at most 4 n + 64 cells */
static void grid_build(grid *g, const sq_mesh *m, const int *items, int n, int nv, double scale,
                       double max_per_item)
{
    /* small cells list few items per cell, but list each item in more cells: the cell edge
     * grows while the listing would exceed max_per_item entries per item (or the cell cap) */
    double esum = 0;
    for (int e = 0; e < n; e++) {
        const int *v = items + (size_t)nv * e;
        const double *a = m->x + 3 * (size_t)v[0], *b = m->x + 3 * (size_t)v[1];
        esum += sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]));
    }
    double ext[3];
    for (int c = 0; c < 3; c++) {
        ext[c] = m->bbox_max[c] - m->bbox_min[c];
        if (!(ext[c] > 0))
            ext[c] = 1e-30;
        if (!(ext[c] <= DBL_MAX))
            ext[c] = DBL_MAX; /* +-1e308 coordinates: the difference overflows */
    }
    /* cells are bounded by the item count, not by the extent: two tets far apart must not
     * make a grid of millions of empty cells (shipped meshes use 0.1-0.6 cells per item) */
    size_t max_cells = 4 * (size_t)n + 64;
    if (max_cells > 16000000)
        max_cells = 16000000;
    double h = n ? scale * esum / n : 0;
    if (!(h > 0))
        h = cbrt(ext[0] * ext[1] * ext[2]);
    size_t total;
    for (;;) {
        total = 1;
        for (int c = 0; c < 3; c++) {
            double d = ceil(ext[c] / h);
            g->dim[c] = d < 1 ? 1 : d > 4096 ? 4096 : (int)d;
            g->lo[c] = m->bbox_min[c];
            g->cell[c] = ext[c] / g->dim[c];
            total *= (size_t)g->dim[c];
        }
        double entries = 0;
        if (total <= max_cells)
            for (int e = 0; e < n; e++) {
                int lo[3], hi[3];
                item_cells(g, m, items + (size_t)nv * e, nv, lo, hi);
                entries += (double)(hi[0] - lo[0] + 1) * (hi[1] - lo[1] + 1) * (hi[2] - lo[2] + 1);
            }
        if (total <= max_cells && entries <= max_per_item * n + 64)
            break;
        h *= 1.26;
    }
    g->start = sq_calloc(total + 1, sizeof *g->start);
    size_t entries = 0;
    for (int e = 0; e < n; e++) {
        int lo[3], hi[3];
        item_cells(g, m, items + (size_t)nv * e, nv, lo, hi);
        for (int k = lo[2]; k <= hi[2]; k++)
            for (int j = lo[1]; j <= hi[1]; j++)
                for (int i = lo[0]; i <= hi[0]; i++)
                    g->start[((size_t)k * g->dim[1] + j) * g->dim[0] + i + 1]++;
        entries += (size_t)(hi[0] - lo[0] + 1) * (hi[1] - lo[1] + 1) * (hi[2] - lo[2] + 1);
    }
    if (entries > INT_MAX)
        sq_malloc(SIZE_MAX); /* too large for int offsets: reported as out of memory */
    for (size_t c = 0; c < total; c++)
        g->start[c + 1] += g->start[c];
    g->item = sq_malloc((entries + 1) * sizeof *g->item);
    int *fill = sq_malloc(total * sizeof *fill);
    memcpy(fill, g->start, total * sizeof *fill);
    for (int e = 0; e < n; e++) {
        int lo[3], hi[3];
        item_cells(g, m, items + (size_t)nv * e, nv, lo, hi);
        for (int k = lo[2]; k <= hi[2]; k++)
            for (int j = lo[1]; j <= hi[1]; j++)
                for (int i = lo[0]; i <= hi[0]; i++)
                    g->item[fill[((size_t)k * g->dim[1] + j) * g->dim[0] + i]++] = e;
    }
    free(fill);
}

static struct sq_locator *get_locator(const sq_mesh *m)
{
    struct sq_locator *loc = __atomic_load_n(&m->locator, __ATOMIC_ACQUIRE);
    if (loc)
        return loc;
    pthread_mutex_lock(&locator_lock);
    loc = m->locator;
    if (!loc) {
        loc = sq_calloc(1, sizeof *loc);
        /* tets: small cells, few candidates per point; triangles: larger cells, since
         * the search for the nearest one walks over mostly empty cells */
        grid_build(&loc->tets, m, m->tets, m->ntets, 4, 0.5, 8);
        grid_build(&loc->tris, m, m->tris, m->ntris, 3, 2.0, 8);
        /* the locator is a cache: building it does not change the mesh's meaning */
        __atomic_store_n(&((sq_mesh *)m)->locator, loc, __ATOMIC_RELEASE);
    }
    pthread_mutex_unlock(&locator_lock);
    return loc;
}

/* barycentric coordinates of p in tet t; returns the smallest */
static double tet_bary(const sq_mesh *m, int t, const double p[3], double bary[4])
{
    double g[4][3];
    sq_tet_gradients(m, t, g);
    const int *v = m->tets + 4 * (size_t)t;
    double mn = DBL_MAX;
    for (int i = 0; i < 4; i++) {
        const double *xi = m->x + 3 * (size_t)v[i];
        bary[i] = 1 + g[i][0] * (p[0] - xi[0]) + g[i][1] * (p[1] - xi[1]) + g[i][2] * (p[2] - xi[2]);
        if (bary[i] < mn)
            mn = bary[i];
    }
    return mn;
}

/* squared distance from p to triangle abc (closest point by Voronoi regions) */
static double tri_dist2(const double *p, const double *a, const double *b, const double *c)
{
    double ab[3], ac[3], ap[3], q[3];
    for (int k = 0; k < 3; k++) {
        ab[k] = b[k] - a[k];
        ac[k] = c[k] - a[k];
        ap[k] = p[k] - a[k];
    }
#define DOT(u, w) ((u)[0] * (w)[0] + (u)[1] * (w)[1] + (u)[2] * (w)[2])
    double d1 = DOT(ab, ap), d2 = DOT(ac, ap);
    if (d1 <= 0 && d2 <= 0) {
        memcpy(q, a, sizeof q);
        goto done;
    }
    double bp[3] = {p[0] - b[0], p[1] - b[1], p[2] - b[2]};
    double d3 = DOT(ab, bp), d4 = DOT(ac, bp);
    if (d3 >= 0 && d4 <= d3) {
        memcpy(q, b, sizeof q);
        goto done;
    }
    double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        double v = d1 / (d1 - d3);
        for (int k = 0; k < 3; k++)
            q[k] = a[k] + v * ab[k];
        goto done;
    }
    double cp[3] = {p[0] - c[0], p[1] - c[1], p[2] - c[2]};
    double d5 = DOT(ab, cp), d6 = DOT(ac, cp);
    if (d6 >= 0 && d5 <= d6) {
        memcpy(q, c, sizeof q);
        goto done;
    }
    double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        double w = d2 / (d2 - d6);
        for (int k = 0; k < 3; k++)
            q[k] = a[k] + w * ac[k];
        goto done;
    }
    double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
        double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        for (int k = 0; k < 3; k++)
            q[k] = b[k] + w * (c[k] - b[k]);
        goto done;
    }
    {
        double denom = 1 / (va + vb + vc);
        double v = vb * denom, w = vc * denom;
        for (int k = 0; k < 3; k++)
            q[k] = a[k] + ab[k] * v + ac[k] * w;
    }
done:;
    double d[3] = {p[0] - q[0], p[1] - q[1], p[2] - q[2]};
    return DOT(d, d);
#undef DOT
}

int sq_mesh_locate(const sq_mesh *m, const double p[3], double bary[4])
{
    if (!m || m->ntets <= 0)
        return -1;
    struct sq_locator *loc = get_locator(m);
    const grid *g = &loc->tets;
    int best = -1;
    double best_min = -DBL_MAX, b[4];
    /* a tiny tolerance for points on shared faces, relative to barycentric scale */
    const double tol = 1e-12;
    int inside_possible = 1;
    for (int c = 0; c < 3; c++)
        if (p[c] < m->bbox_min[c] - 1e-12 * (1 + fabs(p[c])) || p[c] > m->bbox_max[c] + 1e-12 * (1 + fabs(p[c])))
            inside_possible = 0;
    if (inside_possible) {
        /* inside: p's cell lists every tet whose bounding box holds p */
        int cell = (cell_coord(g, 2, p[2]) * g->dim[1] + cell_coord(g, 1, p[1])) * g->dim[0] +
                   cell_coord(g, 0, p[0]);
        for (int e = g->start[cell]; e < g->start[cell + 1]; e++) {
            int t = g->item[e];
            /* cheap rejection by the tet's bounding box (with a relative margin) */
            const int *v = m->tets + 4 * (size_t)t;
            int out = 0;
            for (int c = 0; c < 3 && !out; c++) {
                double lo = m->x[3 * (size_t)v[0] + c], hi = lo;
                for (int k = 1; k < 4; k++) {
                    double x = m->x[3 * (size_t)v[k] + c];
                    lo = x < lo ? x : lo;
                    hi = x > hi ? x : hi;
                }
                double margin = 1e-9 * (hi - lo);
                out = p[c] < lo - margin || p[c] > hi + margin;
            }
            if (out)
                continue;
            double mn = tet_bary(m, t, p, b);
            if (mn > best_min) {
                best_min = mn;
                best = t;
                memcpy(bary, b, sizeof b);
                if (mn >= 0)
                    return t;
            }
        }
        if (best >= 0 && best_min >= -tol)
            return best;
    }
    /* outside: the nearest tet is the one under the nearest boundary triangle */
    const grid *gt = &loc->tris;
    if (m->ntris <= 0)
        return best;
    int ci[3], maxr = 0;
    for (int c = 0; c < 3; c++) {
        ci[c] = cell_coord(gt, c, p[c]);
        if (gt->dim[c] > maxr)
            maxr = gt->dim[c];
    }
    double best_d2 = DBL_MAX;
    int best_tri = -1;
    for (int r = 0; r <= maxr; r++) {
        for (int k = ci[2] - r; k <= ci[2] + r; k++) {
            if (k < 0 || k >= gt->dim[2])
                continue;
            for (int j = ci[1] - r; j <= ci[1] + r; j++) {
                if (j < 0 || j >= gt->dim[1])
                    continue;
                /* only the shell at Chebyshev distance r: inner rows jump from the first to the last i */
                int inner = abs(j - ci[1]) != r && abs(k - ci[2]) != r;
                for (int i = ci[0] - r; i <= ci[0] + r; i += (inner && r > 0 && i == ci[0] - r) ? 2 * r : 1) {
                    if (i < 0 || i >= gt->dim[0])
                        continue;
                    int cell = (k * gt->dim[1] + j) * gt->dim[0] + i;
                    for (int e = gt->start[cell]; e < gt->start[cell + 1]; e++) {
                        int tr = gt->item[e];
                        const int *v = m->tris + 3 * (size_t)tr;
                        const double *a = m->x + 3 * (size_t)v[0], *bb = m->x + 3 * (size_t)v[1],
                                     *cc = m->x + 3 * (size_t)v[2];
                        /* skip unless the triangle's bounding box is nearer than the best */
                        double box2 = 0;
                        for (int c = 0; c < 3; c++) {
                            double lo = SQ_MIN(a[c], SQ_MIN(bb[c], cc[c])), hi = SQ_MAX(a[c], SQ_MAX(bb[c], cc[c]));
                            double d = p[c] < lo ? lo - p[c] : p[c] > hi ? p[c] - hi : 0;
                            box2 += d * d;
                        }
                        if (box2 >= best_d2)
                            continue;
                        double d2 = tri_dist2(p, a, bb, cc);
                        if (d2 < best_d2) {
                            best_d2 = d2;
                            best_tri = tr;
                        }
                    }
                }
            }
        }
        /* unvisited cells lie beyond a face of the visited block that is not the grid's
         * edge; a triangle nearer than that face is listed in a visited cell */
        double bound = DBL_MAX;
        int more = 0;
        for (int c = 0; c < 3; c++) {
            if (ci[c] - r > 0) {
                double face = gt->lo[c] + (ci[c] - r) * gt->cell[c];
                double d = p[c] - face;
                bound = d < bound ? d : bound;
                more = 1;
            }
            if (ci[c] + r < gt->dim[c] - 1) {
                double face = gt->lo[c] + (ci[c] + r + 1) * gt->cell[c];
                double d = face - p[c];
                bound = d < bound ? d : bound;
                more = 1;
            }
        }
        if (!more)
            break;
        if (best_tri >= 0 && bound > 0 && bound * bound >= best_d2)
            break;
    }
    if (best_tri < 0)
        return best;
    int t = m->tri_tet[best_tri];
    tet_bary(m, t, p, bary);
    return t;
}

void sq_mesh_measure(const sq_mesh *m, sq_mesh_info *info)
{
    memset(info, 0, sizeof *info);
    info->nnodes = m->nnodes;
    info->ntets = m->ntets;
    info->ntris = m->ntris;
    info->nsurf = m->nsurf;
    /* edges from the adjacency (each once, j > i) */
    double emin = DBL_MAX, emax = 0, esum = 0;
    long ne = 0;
    if (m->adj_start)
        for (int i = 0; i < m->nnodes; i++)
            for (int e = m->adj_start[i]; e < m->adj_start[i + 1]; e++) {
                int j = m->adj[e];
                if (j <= i)
                    continue;
                double d2 = 0;
                for (int c = 0; c < 3; c++) {
                    double d = m->x[3 * (size_t)i + c] - m->x[3 * (size_t)j + c];
                    d2 += d * d;
                }
                double l = sqrt(d2);
                emin = l < emin ? l : emin;
                emax = l > emax ? l : emax;
                esum += l;
                ne++;
            }
    info->nedges = (int)ne;
    info->edge_min = ne ? emin : 0;
    info->edge_max = emax;
    info->edge_mean = ne ? esum / (double)ne : 0;
    /* per tet: volume, heights 1/|a_i|, dihedral angles from the face normals */
    double dmin = 180, dmax = 0, hmin = DBL_MAX, aspect = 0, vol = 0;
    static const int pairs[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};
    for (int t = 0; t < m->ntets; t++) {
        double g[4][3], len[4];
        vol += sq_tet_gradients(m, t, g);
        double th = DBL_MAX;
        for (int i = 0; i < 4; i++) {
            len[i] = sqrt(g[i][0] * g[i][0] + g[i][1] * g[i][1] + g[i][2] * g[i][2]);
            double h = len[i] > 0 ? 1 / len[i] : 0;
            th = h < th ? h : th;
        }
        double lmax = 0;
        const int *v = m->tets + 4 * (size_t)t;
        for (int q = 0; q < 6; q++) {
            int a = pairs[q][0], b = pairs[q][1];
            /* the dihedral angle at the edge opposite (a, b) is between faces a and b */
            double c = -(g[a][0] * g[b][0] + g[a][1] * g[b][1] + g[a][2] * g[b][2]) / (len[a] * len[b]);
            c = c > 1 ? 1 : c < -1 ? -1 : c;
            double ang = acos(c) * 180.0 / M_PI;
            dmin = ang < dmin ? ang : dmin;
            dmax = ang > dmax ? ang : dmax;
            double d2 = 0;
            for (int k = 0; k < 3; k++) {
                double d = m->x[3 * (size_t)v[a] + k] - m->x[3 * (size_t)v[b] + k];
                d2 += d * d;
            }
            lmax = d2 > lmax ? d2 : lmax;
        }
        lmax = sqrt(lmax);
        hmin = th < hmin ? th : hmin;
        if (th > 0 && lmax / th > aspect)
            aspect = lmax / th;
    }
    info->volume = vol;
    info->dihedral_min_deg = m->ntets ? dmin : 0;
    info->dihedral_max_deg = dmax;
    info->height_min = m->ntets ? hmin : 0;
    info->aspect_max = aspect;
    double area = 0;
    for (int i = 0; i < m->ntris; i++) {
        const int *v = m->tris + 3 * (size_t)i;
        const double *a = m->x + 3 * (size_t)v[0], *b = m->x + 3 * (size_t)v[1], *c = m->x + 3 * (size_t)v[2];
        double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, w[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double n[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
        area += 0.5 * sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    }
    info->surface_area = area;
}
