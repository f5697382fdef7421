/* statics.h - statics.c's entry points for the other files of the lod module: the static loads the
 * criterion judges from.
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_STATICS_H
#define SQ_LOD_STATICS_H

#include "lod/lod_internal.h"

/* static equilibria of the levels up to the top for gravity (once per gravity and material) */
void sq_lodx_static_loads(sq_lod *lod, const double gravity[3]);

#endif
