/* ring.h - ring.c's entry points for the other files of the lod module: the ring ghosts' active
 * sources.
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_RING_H
#define SQ_LOD_RING_H

#include "lod/lod_internal.h"

/* sources of every ring ghost */
void sq_lodx_build_sources(sq_lod *lod);

/* an interpolated node's active sources, expanded through the hierarchy: weight w of node
 * `node` of level `level` (surface.c: level -1 for its anchor) */
typedef struct sq_lodx_source {
    int level, node;
    double w;
} sq_lodx_source;

/* node j of level lev (not of itself a source) expanded through the hierarchy into active
 * sources, in *buf[0..*n) (grown as needed, *cap its size): an active node is a source; any
 * other is replaced by its interpolation tet's corners (sq_lodx_interp_tet), each with its
 * weight, up to max_depth hops, and sources still not active after them dropped. anchors 1: a
 * node with a constrained axis also ends the expansion, as the anchor (level and node -1; the
 * push holds it at zero there) */
void sq_lodx_expand(const sq_lod *lod, int lev, int j, int max_depth, int anchors, sq_lodx_source **buf, int *n,
                    int *cap);
/* sources by level, then node */
int sq_lodx_source_cmp(const void *a, const void *b);

/* buf[0..n) made a combination: sorted by level and node, duplicates merged, the positive
 * sources only when the negative weights outweigh the net one (a bounded combination); returns
 * the count kept (0 when the weights sum to under 1e-3: no active source) and their sum */
int sq_lodx_sources_combine(sq_lodx_source *buf, int n, double *sum);

/* one step of the hierarchy's interpolation of node j of level lev that is not active: a coarse
 * node (ST_COARSE) takes the values of its tet one level coarser, a refined one those of its
 * tet one level finer. Returns that tet's four nodes (at level *m, barycentric weights *b), or
 * NULL at the ends of the hierarchy */
static inline const int *sq_lodx_interp_tet(const sq_lod *lod, int lev, int j, int coarse, int *m, const double **b)
{
    int t;
    if (coarse) {
        if (lev == 0)
            return NULL;
        *m = lev - 1;
        t = lod->h.link[*m].up_tet[j];
        *b = lod->h.link[*m].up_bary + 4 * (size_t)j;
    } else {
        if (lev + 1 >= lod->L)
            return NULL;
        *m = lev + 1;
        t = lod->h.link[lev].down_tet[j];
        *b = lod->h.link[lev].down_bary + 4 * (size_t)j;
    }
    return lod->lv[*m].model.mesh->tets + 4 * (size_t)t;
}

#endif
