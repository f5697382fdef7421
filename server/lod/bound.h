/* bound.h - bound.c's entry points for the other files of the lod module: the sharp per-level
 * step: schedule, deadlines, owed estimates.
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_BOUND_H
#define SQ_LOD_BOUND_H

#include "lod/lod_internal.h"

/* the sharp per-level substeps ("step_bound": "sharp"), its state freed */
void sq_lodx_sharp_bound(sq_lod *lod);
void sq_lodx_sharp_free(sq_lod *lod);
/* the next sharp pass estimates every level again (the guard's calibration times it) */
void sq_lodx_sharp_invalidate(sq_lod *lod);
/* the sharp estimates of the next passes end by this thread CPU time (0: no limit); a level
 * whose estimate cannot is left on its Gershgorin substeps and owes it (the guard, frame.c) */
void sq_lodx_sharp_deadline(sq_lod *lod, double cpu_deadline);
/* the owed estimates made within `seconds` of thread CPU (INFINITY: all), each only when its
 * prediction fits; returns how many were made (their levels' substeps then change) */
int sq_lodx_sharp_owed(sq_lod *lod, double seconds);
/* owed estimates: of level k, or of every level (k < 0) */
int sq_lodx_sharp_owes(const sq_lod *lod, int k);
/* estimates not made by their deadline so far, and owed ones made later */
void sq_lodx_sharp_late(const sq_lod *lod, long *late, long *made_later);

#endif
