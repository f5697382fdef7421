/* coupling.h - coupling.c's entry points for the other files of the lod module: the coupling
 * blocks of the ring and frontier rows, the interface substeps.
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_COUPLING_H
#define SQ_LOD_COUPLING_H

#include "lod/lod_internal.h"

/* ring and frontier blocks up to date for material mat (NULL: the last one seen) */
void sq_lodx_update_ring_blocks(sq_lod *lod, const sq_material *mat);
/* the interface substeps again (Gershgorin, then the sharp rule if on) for the current blocks */
void sq_lodx_coupling_bound(sq_lod *lod);

#endif
