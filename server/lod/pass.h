/* pass.h - pass.c's entry points for the other files of the lod module: the split/merge pass and
 * its calibration, on the frame's context (frame.h).
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_PASS_H
#define SQ_LOD_PASS_H

#include "lod/frame.h"

/* levels whose layout changed (fr->ao.changed) rebuilt, then the coupling over the new layout
 * (the lists too if `lists`), timed for the cost model; with the guard on, the pass's sharp
 * estimates end where the frame must go on to fit its budget, `after` the ticks still to come
 * (after < 0: no limit) */
void sq_lodx_pass(lod_frame *fr, int lists, double after);
/* a pass that changes nothing, timed as the floor of a pass (once, before the first budgeted
 * pass; the lod's very first pass runs unmeasured) */
void sq_lodx_pass_calibrate(lod_frame *fr);
/* the first budgeted frame (unless done at load, sq_lod_prepare_budget): the arrays a pass
 * writes reserved and mapped, the pass terms calibrated */
void sq_lodx_pass_prepare(lod_frame *fr);

#endif
