/* surface.c - the finest surface as combinations of active nodes, for an adaptive body that is
 * another body's contact target (docs/physics.md section 13, sq_lod_surface_map_get).
 *
 * A finest surface node that is active stands for itself; a ghost is expanded through the
 * hierarchy as the ring ghosts are (ring.c): a coarse ghost into its parent tet's corners, a
 * split ghost into its child tet's, each corner again until an active node is reached, within
 * a depth of levels + 1 hops (a coarse ghost's chain to level 0 plus one detour through a split
 * corner), sources still ghosts dropped, a ghost with a constrained axis taken as the anchor
 * (the push holds it at zero there), duplicates merged and the weights renormalised to sum 1; when the negative weights outweigh the net one only the positive sources are kept (the
 * ring's rule, ring.c states why). The map is rebuilt only when the node states change.
 */
#include "lod/lod.h"
#include "lod/ring.h"
#include "lod/surface.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define ROW_MAX 32   /* terms kept per row (the largest weights; a row seldom has over 16) */

typedef sq_lodx_source term;

static int cmp_weight(const void *pa, const void *pb) /* largest |w| first, then by node */
{
    const term *a = pa, *b = pb;
    const double x = fabs(a->w), y = fabs(b->w);
    if (x != y)
        return x > y ? -1 : 1;
    return sq_lodx_source_cmp(pa, pb);
}

/* finest node j's row: its active terms (and the anchor's share), merged, renormalised; the
 * count (0: no source, the anchor alone) */
static int row_of(const sq_lod *lod, int j, term **bufp, int *cap)
{
    int n;
    sq_lodx_expand(lod, lod->L - 1, j, lod->L + 1, 1, bufp, &n, cap);
    term *buf = *bufp;
    double sum;
    int u = sq_lodx_sources_combine(buf, n, &sum);
    if (u > ROW_MAX) {
        qsort(buf, (size_t)u, sizeof *buf, cmp_weight);
        u = ROW_MAX;
        sum = 0;
        for (int i = 0; i < u; i++)
            sum += buf[i].w;
        qsort(buf, (size_t)u, sizeof *buf, sq_lodx_source_cmp);
    }
    if (!(fabs(sum) > 1e-3))
        return 0;
    for (int i = 0; i < u; i++)
        buf[i].w /= sum;
    return u;
}

static int dof_of(sq_lod_surface_store *s, int level, int node)
{
    if (level < 0)
        return 0; /* the anchor */
    int *at = &s->dof_at[s->off[level] + node];
    if (*at < 0) {
        if (s->map.ndof == s->dof_cap) {
            s->dof_cap = s->dof_cap ? 2 * s->dof_cap : 256;
            s->level = sq_realloc(s->level, sizeof(int) * (size_t)s->dof_cap);
            s->node = sq_realloc(s->node, sizeof(int) * (size_t)s->dof_cap);
        }
        *at = s->map.ndof++;
        s->level[*at] = level;
        s->node[*at] = node;
    }
    return *at;
}

static void build(sq_lod *lod)
{
    sq_lod_surface_store *s = &lod->surf;
    const int F = lod->L - 1;
    const sq_level *Lf = &lod->lv[F];
    const sq_mesh *fm = Lf->model.mesh;
    const int nf = Lf->model.n;
    if (!s->dof_at) {
        s->off[0] = 0;
        for (int k = 0; k < lod->L; k++)
            s->off[k + 1] = s->off[k] + lod->lv[k].model.n;
        s->dof_at = sq_malloc(sizeof(int) * (size_t)SQ_MAX(s->off[lod->L], 1));
        for (int i = 0; i < s->off[lod->L]; i++)
            s->dof_at[i] = -1;
        s->start = sq_malloc(sizeof(int) * (size_t)(nf + 1));
    } else {
        for (int q = 0; q < s->map.ndof; q++) /* forget the last build's unknowns */
            if (s->level[q] >= 0)
                s->dof_at[s->off[s->level[q]] + s->node[q]] = -1;
    }
    if (!s->dof_cap) {
        s->dof_cap = 256;
        s->level = sq_malloc(sizeof(int) * (size_t)s->dof_cap);
        s->node = sq_malloc(sizeof(int) * (size_t)s->dof_cap);
    }
    s->map.ndof = 1; /* unknown 0: the anchor */
    s->level[0] = s->node[0] = -1;
    term *buf = NULL;
    int bcap = 0;
    int ne = 0;
    /* rows in node order */
    unsigned char *on = sq_calloc((size_t)SQ_MAX(nf, 1), 1);
    for (int k = 0; k < fm->nsurf; k++)
        on[fm->surf_nodes[k]] = 1;
    for (int j = 0; j < nf; j++) {
        s->start[j] = ne;
        if (!on[j])
            continue;
        int u = Lf->model.fixed[j] ? 0 : row_of(lod, j, &buf, &bcap);
        if (ne + SQ_MAX(u, 1) > s->cap) {
            s->cap = SQ_MAX(2 * s->cap, ne + ROW_MAX + 1024);
            s->dof = sq_realloc(s->dof, sizeof(int) * (size_t)s->cap);
            s->w = sq_realloc(s->w, sizeof(double) * (size_t)s->cap);
        }
        if (u == 0) { /* constrained, or no active source: the anchor */
            s->dof[ne] = 0;
            s->w[ne++] = 1.0;
            continue;
        }
        for (int i = 0; i < u; i++) {
            s->dof[ne] = dof_of(s, buf[i].level, buf[i].node);
            s->w[ne++] = buf[i].w;
        }
    }
    s->start[nf] = ne;
    free(on);
    free(buf);
    s->map.nrow = nf;
    s->map.start = s->start;
    s->map.dof = s->dof;
    s->map.w = s->w;
    s->map.level = s->level;
    s->map.node = s->node;
    s->gen = lod->view.gen;
}

const sq_lod_surface_map *sq_lod_surface_map_get(sq_lod *lod)
{
    if (lod->surf.gen != lod->view.gen || !lod->surf.start)
        build(lod);
    return &lod->surf.map;
}

void sq_lodx_surface_free(sq_lod *lod)
{
    sq_lod_surface_store *s = &lod->surf;
    free(s->start);
    free(s->dof);
    free(s->w);
    free(s->level);
    free(s->node);
    free(s->dof_at);
    memset(s, 0, sizeof *s);
}
