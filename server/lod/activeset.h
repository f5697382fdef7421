/* activeset.h - activeset.c's entry points for the other files of the lod module: per-level index
 * lists, the needed set, on-demand ghost values.
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_ACTIVESET_H
#define SQ_LOD_ACTIVESET_H

#include "lod/lod_internal.h"

/* per-level index lists (active, inner, integrated), the nodes whose values at
 * the start of a step are read, the coarse ghosts something reads (the rest are pushed only
 * on demand) */
void sq_lodx_level_lists(sq_lod *lod, int k);
void sq_lodx_refresh_lists(sq_lod *lod);
void sq_lodx_mask_list(sq_lod *lod, int k);
void sq_lodx_push_needed(sq_lod *lod);
/* the cascade values of the ring ghosts, before sq_lodx_eval_ring replaces them (for sq_lod_flush) */
void sq_lodx_save_cascade(sq_lod *lod);
/* d and v of node j of level k for a read inside the frame: the stored value, except for a
 * coarse ghost outside the needed set, interpolated afresh from the coarser level */
void sq_lodx_value(const sq_lod *lod, int k, int j, double d[3], double v[3]);
/* interp_node reading stale coarse-ghost corners on demand */
void sq_lodx_interp(sq_lod *lod, sq_level *dst, int i, int src_level, int t, const double *b);
void sq_lodx_free(sq_lod *lod, int k);
void sq_lodx_sort_ints(int *a, int n);

#endif
