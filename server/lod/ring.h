/* ring.h - ring.c's entry points for the other files of the lod module: the ring ghosts' active
 * sources.
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_RING_H
#define SQ_LOD_RING_H

#include "lod/lod_internal.h"

/* sources of every ring ghost */
void sq_lodx_build_sources(sq_lod *lod);

#endif
