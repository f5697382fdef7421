/* pass.c - stage: the split/merge pass (docs/lod.md "The frame", "Guaranteed frame rate"): the
 * levels whose layout changed rebuilt, the ring's sources, the coupling blocks and the bound
 * over the new layout, the lists; each part timed for the guard's cost model (guard.c learns
 * it). Run by frame.c's layout stage (the caps' merges) and adapt stage; calibrate, a pass
 * that changes nothing, times a pass's floor before the guard allows one.
 */
#include "lod/lod.h"
#include "lod/activeset.h"
#include "lod/bound.h"
#include "lod/coupling.h"
#include "lod/guard.h"
#include "lod/pass.h"
#include "lod/reserve.h"
#include "lod/ring.h"
#include "lod/state.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

/* levels whose layout changed (ao.changed) rebuilt, then the coupling over the new layout:
 * one split/merge pass, its parts timed for the cost model. With the guard on (measured
 * costs), the pass's sharp estimates end where the frame must go on to fit its budget: the
 * rest of the pass (sources and lists: cost_couple), the frame's fixed cost and `after` (its
 * ticks when the pass runs before them); an estimate that cannot is left for a frame with
 * room, its level on its Gershgorin substeps (bound.c). after < 0: no limit */
void sq_lodx_pass(lod_frame *fr, int lists, double after)
{
    sq_lod *lod = fr->lod;
    int L = lod->L;
    int trace = sq_debug()->guard_trace && fr->in->budget_s > 0;
    long flt0 = trace ? sq_minor_faults() : 0;
    long late0 = 0, later0 = 0;
    sq_lodx_sharp_late(lod, &late0, &later0);
    double deadline = 0;
    if (fr->guard_on && !lod->guard.cost_given && after >= 0)
        deadline = fmax(fr->c_start + fr->fr_budget - lod->guard.cost_fixed - lod->guard.cost_couple - after, 1e-9);
    sq_lodx_sharp_deadline(lod, deadline);
    double c0 = sq_thread_cpu(), c = c0;
    unsigned mask = 0;
    double t_level[SQ_MAX_LEVELS] = {0};
    for (int k = 0; k < L; k++)
        if (fr->ao.changed[k]) {
            sq_lodx_rebuild_level(lod, k);
            fr->ao.changed[k] = 0;
            double t = sq_thread_cpu();
            t_level[k] = t - c;
            c = t;
            mask |= 1u << k;
        }
    if (!mask)
        return;
    long nchg[SQ_MAX_LEVELS] = {0};
    for (int k = 0; k < L; k++)
        nchg[k] = lod->lev[k].cpl.nchg;
    double model = sq_lodx_guard_pass_cost(lod, mask, 0);
    for (int k = 0; k < L; k++)
        model += lod->guard.cost_block_change[k] * (double)nchg[k];
    /* (holds are mapped again onto the new active nodes at the next frame) */
    sq_lodx_build_sources(lod);
    sq_lodx_update_ring_blocks(lod, fr->in->mat);
    sq_lodx_sharp_deadline(lod, 0);
    double slack = deadline > 0 ? deadline - sq_thread_cpu() : INFINITY; /* (trace) */
    if (lists)
        sq_lodx_refresh_lists(lod);
    double t = sq_thread_cpu(), blocks = 0;
    for (int k = 0; k < L; k++)
        blocks += lod->lev[k].cpl.blocks_cpu;
    double couple = fmax(0.0, t - c - blocks - lod->cpl.bound_cpu); /* sources, lists */
    long late1 = 0, later1 = 0;
    sq_lodx_sharp_late(lod, &late1, &later1);
    if (trace)
        fprintf(stderr, "  pass %#x, changed %ld/%ld/%ld/%ld: %.2f ms (levels %.2f, blocks %.2f/%.2f/%.2f/%.2f, "
                "bound %.2f, sources+lists %.2f); model %.2f ms; page faults %ld; sharp estimates late %ld, "
                "bound ended %.2f ms before its deadline\n", mask,
                nchg[0], nchg[1], nchg[2], nchg[3], 1e3 * (t - c0), 1e3 * (c - c0), 1e3 * lod->lev[0].cpl.blocks_cpu,
                1e3 * lod->lev[1].cpl.blocks_cpu, 1e3 * lod->lev[2].cpl.blocks_cpu, 1e3 * lod->lev[3].cpl.blocks_cpu,
                1e3 * lod->cpl.bound_cpu, 1e3 * couple, 1e3 * model, sq_minor_faults() - flt0, late1 - late0, 1e3 * slack);
    /* learn: each level's list rebuild, its block build, the bound, the rest (guard.c) */
    if (!fr->unmeasured)
        sq_lodx_guard_pass_measured(lod, mask, t_level, nchg, couple);
    fr->c_pass += t - c0;
    fr->modeled_pass += model;
    fr->rebuilt |= mask;
    fr->passes++;
}

/* time a pass that rebuilds every level without a change of state (the floor of a real pass:
 * the lists' scans, the coupling, each level's step estimate), once, before the first
 * budgeted pass, so the guard knows what a pass costs before it allows one */
void sq_lodx_pass_calibrate(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    /* the lod's first pass is not what a pass costs: its sharp estimates start cold (a fixed
     * start vector, ITERS_COLD steps, later passes start from the last Ritz vector) and its
     * arrays see their first use. Measured as the floor, it held every later pass out of the
     * budget on a body with a large coarsest level (box_12 at level 0: a 16 ms calibration
     * against 2-3 ms passes, and the pass terms decay only when a pass runs: no split in 100
     * frames). So the first pass runs unmeasured (nothing learned from it), then the
     * calibration pass is measured warm */
    for (int warm = lod->guard.cost_given ? 1 : 0; warm < 2; warm++) {
        for (int k = 0; k <= lod->top && k < lod->L; k++)
            fr->ao.changed[k] = 1;
        sq_lodx_sharp_invalidate(lod);
        fr->unmeasured = !warm;
        sq_lodx_pass(fr, 1, -1);
        fr->unmeasured = 0;
    }
    fr->passes = 0;
    fr->modeled_pass = 0;
    sq_lodx_guard_calibrated(lod); /* the calibration done, a start for the cost per changed node */
}

/* a live budget follows: every array a pass writes reserved and mapped, and the guard's pass
 * terms calibrated, now (at load) instead of in the first budgeted frame */
long sq_lod_prepare_budget(sq_lod *lod)
{
    if (lod->reserve.reserve_live || !lod->cpl.have_mat)
        return 0;
    long pages = sq_lodx_reserve_live(lod);
    if (!lod->guard.cost_calibrated) {
        sq_lod_frame_in in;
        memset(&in, 0, sizeof in);
        in.mat = &lod->cpl.mat;
        lod_frame fr;
        memset(&fr, 0, sizeof fr);
        fr.lod = lod;
        fr.in = &in;
        sq_lodx_pass_calibrate(&fr);
    }
    return pages;
}

/* the first budgeted frame, unless done at load (sq_lod_prepare_budget): every array a pass
 * writes reserved and mapped, whatever it costs (a run without a budget does not hold them),
 * then kept ahead of need at the end of frames with room (frame.c's reserve_ahead); the pass
 * terms calibrated */
void sq_lodx_pass_prepare(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    if (!lod->reserve.reserve_live && lod->cpl.have_mat) {
        double c = sq_thread_cpu();
        fr->reserved_pages += sq_lod_prepare_budget(lod);
        fr->c_reserve += sq_thread_cpu() - c; /* (not the frame's fixed cost) */
    }
    if (!lod->guard.cost_calibrated)
        sq_lodx_pass_calibrate(fr);
}
