/* state.h - state.c's entry points for the other files of the lod module: creation, reset, a
 * level's state lists, ghost values (pull, cascade).
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_STATE_H
#define SQ_LOD_STATE_H

#include "lod/lod_internal.h"

/* recompute the active mask, the ghost lists and the integration mask of level k */
void sq_lodx_rebuild_level(sq_lod *lod, int k);
/* split ghosts of level k from their child tets in level k+1 */
void sq_lodx_pull_level(sq_lod *lod, int k);
/* the end-of-frame cascade (coarse ghosts pushed only where something reads them) */
void sq_lodx_cascade_needed(sq_lod *lod);

/* one split of node i of level k (children active at interpolated values, i fresh), one merge
 * of node p (its value interpolated from its child tet, children coarse ghosts at theirs);
 * the fresh marks of level k cleared at the end of a pass */
void sq_lodx_split_node(sq_lod *lod, int k, int i);
void sq_lodx_merge_node(sq_lod *lod, int k, int p);
void sq_lodx_fresh_clear(sq_lod *lod, int k);

/* Laplacian weights of the criterion per CSR entry of the mesh adjacency (made at creation) */
double *sq_lodx_criterion_weights(const sq_mesh *m);

#endif
