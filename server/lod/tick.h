/* tick.h - tick.c's entry points for the other files of the lod module: one tick: ring values, row
 * kernels, d + b v, ring reactions, integration.
 * Not part of the module's contract (lod.h).
 */
#ifndef SQ_LOD_TICK_H
#define SQ_LOD_TICK_H

#include "lod/lod_internal.h"

/* one tick of the finest substep clock, the kernels it runs */
typedef struct sq_tick_count {
    long updates;                               /* node integrations */
    long ring_values, ring_rows, frontier_rows; /* the interface's work (profile) */
} sq_tick_count;
/* ring ghost values of every level due at tick t (level k due every stride[k] ticks; sets
 * lev[k].tk.due) */
void sq_lodx_tick_pull(sq_lod *lod, long t, const long *stride, sq_tick_count *c);
/* forces of the due levels, the coupling reactions between levels, integration of the free
 * active nodes (and their contact) */
void sq_lodx_tick_step(sq_lod *lod, const sq_lod_frame_in *in, long t, const long *stride, sq_tick_count *c);
/* forces of the inner active nodes of level k (no viscosity), from the rows in column form */
void sq_lodx_rows(sq_lod *lod, const sq_material *mat, const double gravity[3], int k);
/* w_tick of level k (active nodes and ring ghosts) = d + b v, b the material's stiffness
 * damping: what the row kernels of a due linear level without viscosity read */
void sq_lodx_form_w(sq_lod *lod, const sq_material *mat, int k);
void sq_lodx_integrate(sq_lod *lod, int k, double dt);
void sq_lodx_save_prev(sq_lod *lod, int k);
/* frontier forces of level k (correction after a full-row pass; merged rows) */
void sq_lodx_front_correct(sq_lod *lod, const sq_material *mat, int k);
void sq_lodx_front_rows(sq_lod *lod, const sq_material *mat, const double gravity[3], int k);
/* ring values of level k at tick t; only the ring ghosts read by the ring rows with a source
 * on a level in mask (returns how many); ring reactions (returns the rows) */
void sq_lodx_eval_ring(sq_lod *lod, int k, long t);
int sq_lodx_eval_ring_hot(sq_lod *lod, int k, long t, unsigned mask);
int sq_lodx_couple_out(sq_lod *lod, const sq_material *mat, int k, long t);

/* the other stages' writes of a level's tick state: the frame's substep clock (level k steps
 * every stride[k] ticks, its last step ended at tick 0); the hot ring list of level k out of date;
 * node j of level k's step-start values from its current d and v; the buffer of d + b v (made
 * if not yet, returned) */
void sq_lodx_tick_clock(sq_lod *lod, const long *stride);
void sq_lodx_tick_hot_stale(sq_lod *lod, int k);
void sq_lodx_tick_start_node(sq_lod *lod, int k, int j);
double *sq_lodx_tick_w(sq_lod *lod, int k);

#endif
