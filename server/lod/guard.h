/* guard.h - guard.c's entry points for the other files of the lod module: the guard's cost model,
 * its merges and pass limit.
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_GUARD_H
#define SQ_LOD_GUARD_H

#include "lod/lod_internal.h"

/* splits stop where the next frame and a pass of every level would pass this share of the
 * budget; a region the guard merged rests SQ_GUARD_REST_FRAMES frames before it may split */
#define SQ_GUARD_SPLIT_HEADROOM 0.8
#define SQ_GUARD_REST_FRAMES 25
/* the start of the cost per changed node (calibrate): box-big, with the caches' pages mapped at
 * load, measured 17.5 / 9.3 / 7.6 us per changed node of levels 0 / 1 / 2 (medians of 71
 * passes, the level's floor included; 90th percentiles 30 / 30 / 15 us). The start was 100 us
 * (measured once with first-touch page faults in the passes): falling 3 % a pass, it kept the
 * model 3-10x over the passes for 50 frames, and the guard held back the splits a moving tool
 * needs (box-big split every second frame: 1.45-1.57 mm against 1.07-1.14 mm from 30 us) */
#define SQ_GUARD_BLOCK_CHANGE_START 30e-6
/* a pass is planned at 1.25 x its model: 88 of 90 box-big passes were within 1.1 x, the worst
 * 1.57 x */
#define SQ_GUARD_PASS_MARGIN 1.25
/* the need of split node p of level k: its children's largest criterion (its own without
 * children), as the merge rule judges it, m */
double sq_lodx_need(const sq_lod *lod, int k, int p);
/* a measurement into a learned cost (docs/lod.md "Guaranteed frame rate", "An isolated spike"):
 * the decaying maximum (decay 0.9 a frame, 0.97 a pass), except that a measurement above
 * `spike` x the term with no other such within the last SPIKE_WINDOW measurements raises it
 * only to that bound, and the next ordinary one puts it back; returns the new cost */
double sq_lodx_learn(sq_cost_track *t, double cost, double measured, double decay, double spike);
/* a measured cost into its decaying maximum unless the costs are given: 10 % a frame (learn),
 * 3 % a pass (learn_pass) */
void sq_lodx_guard_learn(const sq_lod *lod, double *cost, sq_cost_track *t, double measured);
void sq_lodx_guard_learn_pass(const sq_lod *lod, double *cost, sq_cost_track *t, double measured);
/* the block rebuild a split or merge between levels k and k+1 costs, s */
double sq_lodx_guard_region_cost(const sq_lod *lod, int k);
/* the cost of adding the levels in `mask` (bits) to a pass that rebuilds the levels in `done`
 * already, before its changed nodes, s */
double sq_lodx_guard_pass_cost(const sq_lod *lod, unsigned mask, unsigned done);
/* every level that may take part in a pass (bits): up to the highest simulated level + 1 */
unsigned sq_lodx_guard_all_levels(const sq_lod *lod);
/* node updates that fit in `seconds` of a frame's budget after its fixed cost */
long sq_lodx_guard_updates_fitting(const sq_lod *lod, double seconds);
/* the model's cost of a frame with every region at level 0 (its fixed cost and level 0's free
 * nodes at level 0's substeps), s: above the budget, no layout fits (the coarse warning) */
double sq_lodx_guard_coarse_cost(const sq_lod *lod);
/* the resting nodes of level k masked out of the split pass (hide 1) or restored (hide 0) */
void sq_lodx_guard_rest_mask(sq_lod *lod, int k, int hide);
/* the guard: merge the least needed mergeable regions (smallest criterion over
 * their children) until *projected <= cap, at most `most` of them; each merged node rests
 * `rest` frames before it may split again. Returns the merges made (levels changed in
 * out->changed). */
long sq_lodx_guard_merge(sq_lod *lod, long cap, long *projected, adapt_out *out, int rest, long most);
/* the guard: when the split/merge pass of levels k, k+1 would change more than
 * `most` regions, keep the merges the criterion wants (least needed first) and then its splits
 * (most needed first) up to `most`, and hold the others out of the pass (their state masked
 * until sq_lodx_guard_limit_undo); returns the regions held out */
long sq_lodx_guard_limit(sq_lod *lod, int k, int allow_split, long most);
void sq_lodx_guard_limit_undo(sq_lod *lod, int k);

/* the guard's parts of frame.c's stages, on the frame's context (frame.h) */
typedef struct lod_frame lod_frame;
/* the guard stage: the frame's budget (less the time around the frame, learned), splits
 * allowed or not; returns 1 with a budget, then sq_lodx_guard_cap once the pass terms are
 * calibrated (pass.c's sq_lodx_pass_prepare): the node-update cap that fits */
int sq_lodx_guard_open(lod_frame *fr);
void sq_lodx_guard_cap(lod_frame *fr);
/* the ticks' thread CPU time (fr->c_ticks) per node update learned; the guard on once a cost
 * per update is known with a budget */
void sq_lodx_guard_ticks_measured(lod_frame *fr);
/* the criterion stage's split/merge within the budget and the guard's merges (the guard on);
 * now: the thread CPU clock at the stage's start; pairs: 1 if the split/merge pairs run */
void sq_lodx_guard_adapt(lod_frame *fr, double now, int pairs);
/* a measured pass (pass.c) into the pass terms: t_level[k] the rebuild of each level in mask,
 * nchg[k] its changed nodes, couple the sources and lists; the blocks' and the bound's times
 * read from lev[k].cpl.blocks_cpu and cpl.bound_cpu */
void sq_lodx_guard_pass_measured(sq_lod *lod, unsigned mask, const double *t_level, const long *nchg, double couple);
/* the calibration pass done (pass.c): the start of the cost per changed node */
void sq_lodx_guard_calibrated(sq_lod *lod);
/* the frame's end: its fixed cost learned, its modeled cost, the next frame's prediction;
 * returns the next frame's node updates (without a pass) */
long sq_lodx_guard_frame_end(lod_frame *fr, double c_end, double cpu);

#endif
