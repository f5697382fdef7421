/* surface.h - surface.c's entry points for the other files of the lod module: the finest
 * surface as combinations of active nodes (sq_lod_surface_map_get).
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_SURFACE_H
#define SQ_LOD_SURFACE_H

#include "lod/lod_internal.h"

/* the map's arrays freed (sq_lod_destroy) */
void sq_lodx_surface_free(sq_lod *lod);

#endif
