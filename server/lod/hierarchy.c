/* hierarchy.c - parent/child tree and interpolation coordinates between non-nested levels.
 *
 * For each pair of consecutive levels (k, k+1):
 *  - parent of a level-(k+1) node = nearest level-k node (its Voronoi region), found with a
 *    uniform grid over the level-k nodes (expanding shells, O(1) per query on quasi-uniform
 *    meshes, never O(n^2));
 *  - children of a level-k node as CSR (counting sort by parent);
 *  - up coordinates: each level-(k+1) node in its containing (or nearest) level-k tet;
 *  - down coordinates: each level-k node in its containing (or nearest) level-(k+1) tet.
 * Validation: every fine node has a parent and every coordinate set sums to 1 within 1e-9.
 */
#include "lod/lod.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* uniform grid over a point set: cell lists as CSR */
typedef struct node_grid {
    double lo[3], inv_cell;
    int dim[3];
    int *start;  /* (cells + 1) */
    int *item;   /* point indices (n) */
} node_grid;

static int grid_coord(const node_grid *g, double x, int axis)
{
    int c = (int)floor((x - g->lo[axis]) * g->inv_cell);
    if (c < 0)
        c = 0;
    if (c >= g->dim[axis])
        c = g->dim[axis] - 1;
    return c;
}

/* build the grid with about one point per cell */
static void grid_build(node_grid *g, const double *x, int n)
{
    double hi[3];
    for (int a = 0; a < 3; a++) {
        g->lo[a] = DBL_MAX;
        hi[a] = -DBL_MAX;
    }
    for (int i = 0; i < n; i++)
        for (int a = 0; a < 3; a++) {
            g->lo[a] = SQ_MIN(g->lo[a], x[3 * i + a]);
            hi[a] = SQ_MAX(hi[a], x[3 * i + a]);
        }
    double ext[3], vol = 1.0, maxext = 0.0;
    for (int a = 0; a < 3; a++) {
        ext[a] = hi[a] - g->lo[a];
        maxext = SQ_MAX(maxext, ext[a]);
    }
    if (maxext <= 0.0)
        maxext = 1.0;
    for (int a = 0; a < 3; a++)
        vol *= SQ_MAX(ext[a], maxext * 1e-3);
    double cell = cbrt(vol / SQ_MAX(n, 1));
    if (!(cell > 0.0))
        cell = maxext;
    long cells = 1;
    for (int a = 0; a < 3; a++) {
        long d = (long)(ext[a] / cell) + 1;
        if (d > 1024)
            d = 1024;
        g->dim[a] = (int)d;
        cells *= d;
    }
    /* cap the cell count (degenerate spreads) by enlarging the cell */
    while (cells > 4L * n + 64) {
        cell *= 1.25;
        cells = 1;
        for (int a = 0; a < 3; a++) {
            g->dim[a] = (int)(ext[a] / cell) + 1;
            cells *= g->dim[a];
        }
    }
    g->inv_cell = 1.0 / cell;
    g->start = sq_calloc((size_t)cells + 1, sizeof(int));
    g->item = sq_malloc(sizeof(int) * (size_t)SQ_MAX(n, 1));
    int *cell_of = sq_malloc(sizeof(int) * (size_t)SQ_MAX(n, 1));
    for (int i = 0; i < n; i++) {
        int c[3];
        for (int a = 0; a < 3; a++)
            c[a] = grid_coord(g, x[3 * i + a], a);
        cell_of[i] = (c[2] * g->dim[1] + c[1]) * g->dim[0] + c[0];
        g->start[cell_of[i] + 1]++;
    }
    for (long c = 0; c < cells; c++)
        g->start[c + 1] += g->start[c];
    int *fill = sq_malloc(sizeof(int) * (size_t)cells);
    memcpy(fill, g->start, sizeof(int) * (size_t)cells);
    for (int i = 0; i < n; i++)
        g->item[fill[cell_of[i]]++] = i;
    free(fill);
    free(cell_of);
}

static void grid_free(node_grid *g)
{
    free(g->start);
    free(g->item);
}

/* nearest point of the grid's set to p (ties: lowest index); expands cubic shells until the
 * shell cannot contain anything closer */
static int grid_nearest(const node_grid *g, const double *x, const double p[3])
{
    int c[3];
    for (int a = 0; a < 3; a++)
        c[a] = grid_coord(g, p[a], a);
    int best = -1;
    double best_d2 = DBL_MAX;
    int maxr = SQ_MAX(g->dim[0], SQ_MAX(g->dim[1], g->dim[2]));
    double cell = 1.0 / g->inv_cell;
    for (int r = 0; r <= maxr; r++) {
        /* every point in shell r is at least (r - 1) cells away from p along some axis */
        if (best >= 0) {
            double reach = (r - 1) * cell;
            if (reach > 0 && reach * reach > best_d2)
                break;
        }
        for (int dz = -r; dz <= r; dz++) {
            int z = c[2] + dz;
            if (z < 0 || z >= g->dim[2])
                continue;
            for (int dy = -r; dy <= r; dy++) {
                int y = c[1] + dy;
                if (y < 0 || y >= g->dim[1])
                    continue;
                int on_shell_zy = (abs(dz) == r || abs(dy) == r);
                for (int dx = -r; dx <= r; dx++) {
                    if (!on_shell_zy && abs(dx) != r)
                        continue;
                    int xx = c[0] + dx;
                    if (xx < 0 || xx >= g->dim[0])
                        continue;
                    int cell_id = (z * g->dim[1] + y) * g->dim[0] + xx;
                    for (int s = g->start[cell_id]; s < g->start[cell_id + 1]; s++) {
                        int i = g->item[s];
                        double d2 = 0.0;
                        for (int a = 0; a < 3; a++) {
                            double t = x[3 * i + a] - p[a];
                            d2 += t * t;
                        }
                        if (d2 < best_d2 || (d2 == best_d2 && i < best)) {
                            best_d2 = d2;
                            best = i;
                        }
                    }
                }
            }
        }
    }
    return best;
}

/* locate every node of `from` in mesh `in`; check the coordinates */
static int locate_all(const sq_mesh *from, const sq_mesh *in, int *tet, double *bary,
                      int kfrom, int kin, sq_err *err)
{
    for (int i = 0; i < from->nnodes; i++) {
        const double *p = from->x + 3 * i;
        int t = sq_mesh_locate(in, p, bary + 4 * i);
        if (t < 0 || t >= in->ntets)
            return sq_err_set(err,
                              "lod hierarchy: node %d of level %d (%s) at (%g, %g, %g) could not be "
                              "located in level %d (%s); check that both meshes describe the same shape",
                              i, kfrom, from->source, p[0], p[1], p[2], kin, in->source);
        tet[i] = t;
        const double *b = bary + 4 * i;
        double s = b[0] + b[1] + b[2] + b[3];
        if (!(fabs(s - 1.0) <= 1e-9) || !isfinite(s))
            return sq_err_set(err,
                              "lod hierarchy: node %d of level %d (%s): barycentric coordinates in tet %d "
                              "of level %d sum to %.12g, not 1; the tet is degenerate, check the mesh",
                              i, kfrom, from->source, t, kin, s);
    }
    return 0;
}

int sq_hierarchy_build(sq_hierarchy *h, const sq_mesh *const *meshes, int nlevels, sq_err *err)
{
    memset(h, 0, sizeof(*h));
    if (nlevels < 1 || nlevels > SQ_MAX_LEVELS)
        return sq_err_set(err, "lod hierarchy: %d levels given, need 1 to %d", nlevels, SQ_MAX_LEVELS);
    for (int k = 0; k < nlevels; k++) {
        if (!meshes[k] || meshes[k]->nnodes < 1 || meshes[k]->ntets < 1)
            return sq_err_set(err, "lod hierarchy: level %d has no mesh or an empty mesh", k);
        h->mesh[k] = meshes[k];
    }
    h->nlevels = nlevels;
    for (int k = 0; k + 1 < nlevels; k++) {
        const sq_mesh *mc = meshes[k], *mf = meshes[k + 1];
        sq_lod_link *ln = &h->link[k];
        int nc = mc->nnodes, nf = mf->nnodes;
        ln->parent = sq_malloc(sizeof(int) * (size_t)nf);
        ln->child_start = sq_calloc((size_t)nc + 1, sizeof(int));
        ln->child = sq_malloc(sizeof(int) * (size_t)nf);
        ln->up_tet = sq_malloc(sizeof(int) * (size_t)nf);
        ln->up_bary = sq_malloc(sizeof(double) * 4 * (size_t)nf);
        ln->down_tet = sq_malloc(sizeof(int) * (size_t)nc);
        ln->down_bary = sq_malloc(sizeof(double) * 4 * (size_t)nc);

        /* parents: nearest coarse node */
        node_grid g;
        grid_build(&g, mc->x, nc);
        for (int j = 0; j < nf; j++) {
            int p = grid_nearest(&g, mc->x, mf->x + 3 * j);
            if (p < 0) {
                grid_free(&g);
                sq_hierarchy_free(h);
                return sq_err_set(err, "lod hierarchy: node %d of level %d (%s) found no parent in level %d",
                                  j, k + 1, mf->source, k);
            }
            ln->parent[j] = p;
            ln->child_start[p + 1]++;
        }
        grid_free(&g);

        /* children: counting sort by parent (children in increasing index order) */
        for (int p = 0; p < nc; p++)
            ln->child_start[p + 1] += ln->child_start[p];
        int *fill = sq_malloc(sizeof(int) * (size_t)nc);
        memcpy(fill, ln->child_start, sizeof(int) * (size_t)nc);
        for (int j = 0; j < nf; j++)
            ln->child[fill[ln->parent[j]]++] = j;
        free(fill);

        /* interpolation coordinates both ways */
        if (locate_all(mf, mc, ln->up_tet, ln->up_bary, k + 1, k, err) ||
            locate_all(mc, mf, ln->down_tet, ln->down_bary, k, k + 1, err)) {
            sq_hierarchy_free(h);
            return -1;
        }
    }
    return 0;
}

void sq_hierarchy_free(sq_hierarchy *h)
{
    for (int k = 0; k + 1 < SQ_MAX_LEVELS; k++) {
        sq_lod_link *ln = &h->link[k];
        free(ln->parent);
        free(ln->child_start);
        free(ln->child);
        free(ln->up_tet);
        free(ln->up_bary);
        free(ln->down_tet);
        free(ln->down_bary);
    }
    memset(h, 0, sizeof(*h));
}

void sq_hierarchy_stats(const sq_hierarchy *h, int k, sq_hierarchy_link_stats *st)
{
    memset(st, 0, sizeof(*st));
    if (k < 0 || k + 1 >= h->nlevels)
        return;
    const sq_lod_link *ln = &h->link[k];
    const sq_mesh *mc = h->mesh[k], *mf = h->mesh[k + 1];
    st->nparents = mc->nnodes;
    st->nchildren = mf->nnodes;
    st->min_children = mf->nnodes;
    for (int p = 0; p < mc->nnodes; p++) {
        int c = ln->child_start[p + 1] - ln->child_start[p];
        if (c == 0)
            st->childless++;
        st->min_children = SQ_MIN(st->min_children, c);
        st->max_children = SQ_MAX(st->max_children, c);
    }
    st->mean_children = mc->nnodes ? (double)mf->nnodes / mc->nnodes : 0.0;
    for (int j = 0; j < mf->nnodes; j++) {
        const double *b = ln->up_bary + 4 * j;
        double mn = SQ_MIN(SQ_MIN(b[0], b[1]), SQ_MIN(b[2], b[3]));
        if (mn < -1e-12) {
            st->up_outside++;
            st->up_min_bary = SQ_MIN(st->up_min_bary, mn);
        }
    }
    for (int i = 0; i < mc->nnodes; i++) {
        const double *b = ln->down_bary + 4 * i;
        double mn = SQ_MIN(SQ_MIN(b[0], b[1]), SQ_MIN(b[2], b[3]));
        if (mn < -1e-12) {
            st->down_outside++;
            st->down_min_bary = SQ_MIN(st->down_min_bary, mn);
        }
    }
}
