/* criterion.h - criterion.c's entry points for the other files of the lod module: the split/merge
 * criterion, split/merge of a pair of levels, the node-update cap.
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_CRITERION_H
#define SQ_LOD_CRITERION_H

#include "lod/lod_internal.h"

/* the criterion delta = hbar^2 |Lap(d - d_static)| at node i of level k, ghost
 * neighbours the last cascade did not push read on demand (sq_lodx_value) */
double sq_lodx_delta(const sq_lod *lod, int k, int i);
/* split/merge between levels k and k+1; merges until the node-update cap fits */
void sq_lodx_adapt_pair(sq_lod *lod, int k, int allow_split, long *projected, adapt_out *out);
void sq_lodx_enforce_cap(sq_lod *lod, long *projected, adapt_out *out);

#endif
