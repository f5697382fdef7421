/* holds.h - holds.c's entry points for the other files of the lod module: tool holds onto active
 * nodes.
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_HOLDS_H
#define SQ_LOD_HOLDS_H

#include "lod/lod_internal.h"

/* the frame's holds onto active nodes (held nodes prescribed over frame_dt, left out
 * of the integrated lists); the internal force on the held nodes of level k at its step;
 * the tool feedback into force[tool] (may be NULL) and the holds released */
void sq_lodx_hold_start(sq_lod *lod, const sq_hold *holds, int nholds, int ntools, double frame_dt);
void sq_lodx_hold_sample(sq_lod *lod, int k, const double gravity[3]);
/* at a tick of a frame with live holds (in->live): their nodes moved to the newest targets */
void sq_lodx_hold_live(sq_lod *lod, const sq_lod_frame_in *in, double frac);
void sq_lodx_hold_end(sq_lod *lod, const sq_hold *holds, int nholds, double (*force)[3]);

#endif
