/* frame.c - stage: one adaptive frame (docs/lod.md, "The frame"), as a list of named, timed
 * stages sharing a frame context (lod_frame):
 *
 *   guard      the budget: are splits allowed, the node-update cap that fits the period
 *   layout     coupling blocks and substeps, merges the cap asks for, the substep clock
 *   holds      tool holds onto active nodes
 *   per tick of the finest substep clock (2^nmax ticks; level k is due every 2^(nmax - n_k)):
 *     pull     ring ghost values of the due levels from their active sources
 *     step     forces of the due levels, coupling reactions, integration of the free nodes
 *   criterion  split/merge decisions, when every level is at the same time (the frame's end)
 *   adapt      the levels whose layout changed rebuilt, coupling rebuilt
 *   push       every ghost the viewer, probes and the next frame read brought up to date
 *   feedback   tool forces from the held nodes, holds released
 *   profile    cost model of the guard, the frame's profile and events
 *
 * Each stage's time goes to prof->t_stage[]; t_pull, t_integrate, t_push and t_adapt are
 * the pull, step, push and criterion + adapt stages.
 */
#include "lod/lod.h"
#include "lod/activeset.h"
#include "lod/bound.h"
#include "lod/corotational.h"
#include "lod/coupling.h"
#include "lod/criterion.h"
#include "lod/guard.h"
#include "lod/holds.h"
#include "lod/reserve.h"
#include "lod/ring.h"
#include "lod/state.h"
#include "lod/tick.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>




/* ---------------------------------------------------------------- the frame context */

/* what the stages of one frame share */
typedef struct lod_frame {
    sq_lod *lod;
    const sq_lod_frame_in *in;
    double (*force)[3];              /* feedback force of each tool, N (in->ntools), or NULL */
    /* clocks */
    double t_start, c_start;         /* wall and thread CPU time at the start of the frame, s */
    double mark;                     /* wall time the last timed stage ended, s */
    double t[SQ_LOD_STAGES];         /* wall time of each stage, s */
    /* guard */
    double prev_time;                /* CPU time of the previous frame, s */
    int over_budget;                 /* 1: the previous frame was over budget, no splits */
    long cap_user, cap_guard;        /* the user's node-update cap; the guard's (0: none) */
    double coarse_ms;                /* predicted cost of every region at level 0, ms */
    double c_ticks;                  /* thread CPU time of the ticks (pull, step), s */
    double c_pass;                   /* thread CPU time of the split/merge passes' rebuilds, s */
    double c_mark;                   /* thread CPU time the last non-tick stage ended, s */
    unsigned rebuilt;                /* levels rebuilt by this frame's passes (bit k) */
    int passes;                      /* split/merge passes rebuilt (0, 1 or 2) */
    int unmeasured;                  /* 1: the pass running learns no cost (calibrate's warm-up) */
    long guard_merges;               /* regions the guard merged this frame */
    /* layout and clock */
    long projected;                  /* node updates one frame of the current layout costs */
    adapt_out ao;                    /* splits, merges, refusals, levels whose layout changed */
    long nticks, tick;               /* finest substeps of the frame; the current one */
    long stride[SQ_MAX_LEVELS];      /* level k steps every stride[k] ticks */
    sq_tick_count tc;                /* node integrations and the interface's work so far (tick.c) */
    double fr_budget;                /* def.budget x in->budget_s, s */
    int guard_on;                    /* a budget and a measured (or given) cost per update */
    double modeled_pass;             /* the model's cost of this frame's passes, s */
    double outside_raw;              /* thread CPU time since the last frame's end, s */
    double c_reserve;                /* thread CPU time of the coupling arrays' reserve, s */
    long reserved_pages;             /* pages it mapped */
    double c_owed;                   /* thread CPU time of the owed sharp estimates, s */
    int sharp_made;                  /* owed sharp estimates made at this frame's end */
    double u0_user, u0_sys;          /* guard_trace: the thread's user, system time at the start */
    long u0_flt, u0_ivcsw;           /* ... its minor faults and involuntary context switches */
} lod_frame;

void sq_lod_untimed(sq_lod *lod, double cpu_s)
{
    if (cpu_s > 0)
        lod->guard.untimed += cpu_s;
}

/* run one stage and add its wall time to its entry */
static inline void run(lod_frame *fr, void (*stage)(lod_frame *), int which)
{
    stage(fr);
    double now = sq_now();
    fr->t[which] += now - fr->mark;
    fr->mark = now;
}

/* a stage that runs once a frame: the thread CPU clock read after it too (the ticks' CPU
 * time, for the guard's cost model, is what passes between holds and criterion) */
static inline void run_once(lod_frame *fr, void (*stage)(lod_frame *), int which)
{
    run(fr, stage, which);
    fr->c_mark = sq_thread_cpu();
}

/* levels whose layout changed (ao.changed) rebuilt, then the coupling over the new layout:
 * one split/merge pass, its parts timed for the cost model. With the guard on (measured
 * costs), the pass's sharp estimates end where the frame must go on to fit its budget: the
 * rest of the pass (sources and lists: cost_couple), the frame's fixed cost and `after` (its
 * ticks when the pass runs before them); an estimate that cannot is left for a frame with
 * room, its level on its Gershgorin substeps (bound.c). after < 0: no limit */
static void rebuild_pass(lod_frame *fr, int lists, double after)
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
    double couple = fmax(0.0, t - c - blocks - lod->guard.bound_cpu); /* sources, lists */
    long late1 = 0, later1 = 0;
    sq_lodx_sharp_late(lod, &late1, &later1);
    if (trace)
        fprintf(stderr, "  pass %#x, changed %ld/%ld/%ld/%ld: %.2f ms (levels %.2f, blocks %.2f/%.2f/%.2f/%.2f, "
                "bound %.2f, sources+lists %.2f); model %.2f ms; page faults %ld; sharp estimates late %ld, "
                "bound ended %.2f ms before its deadline\n", mask,
                nchg[0], nchg[1], nchg[2], nchg[3], 1e3 * (t - c0), 1e3 * (c - c0), 1e3 * lod->lev[0].cpl.blocks_cpu,
                1e3 * lod->lev[1].cpl.blocks_cpu, 1e3 * lod->lev[2].cpl.blocks_cpu, 1e3 * lod->lev[3].cpl.blocks_cpu,
                1e3 * lod->guard.bound_cpu, 1e3 * couple, 1e3 * model, sq_minor_faults() - flt0, late1 - late0, 1e3 * slack);
    /* learn: each level's list rebuild; its block build, as a floor when none of its nodes
     * changed (the calibration pass), else per changed node above the floor; the bound; the
     * rest (sources, needed set) */
    for (int k = 0; k < L && !fr->unmeasured; k++) {
        if (!(mask & (1u << k)) && lod->lev[k].cpl.blocks_cpu == 0)
            continue;
        if (mask & (1u << k))
            sq_lodx_guard_learn_pass(lod, &lod->guard.cost_level[k], &lod->guard.tr_level[k], t_level[k]);
        if (nchg[k] == 0)
            sq_lodx_guard_learn_pass(lod, &lod->guard.cost_blocks[k], &lod->guard.tr_blocks[k], lod->lev[k].cpl.blocks_cpu);
        else
            sq_lodx_guard_learn_pass(lod, &lod->guard.cost_block_change[k], &lod->guard.tr_block_change[k],
                  fmax(0.0, lod->lev[k].cpl.blocks_cpu - lod->guard.cost_blocks[k]) / (double)nchg[k]);
    }
    if (!fr->unmeasured) {
        sq_lodx_guard_learn_pass(lod, &lod->guard.cost_bound, &lod->guard.tr_bound, lod->guard.bound_cpu);
        sq_lodx_guard_learn_pass(lod, &lod->guard.cost_couple, &lod->guard.tr_couple, couple);
    }
    fr->c_pass += t - c0;
    fr->modeled_pass += model;
    fr->rebuilt |= mask;
    fr->passes++;
}

/* time a pass that rebuilds every level without a change of state (the floor of a real pass:
 * the lists' scans, the coupling, each level's step estimate), once, before the first
 * budgeted pass, so the guard knows what a pass costs before it allows one */
static void calibrate(lod_frame *fr)
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
        rebuild_pass(fr, 1, -1);
        fr->unmeasured = 0;
    }
    fr->passes = 0;
    fr->modeled_pass = 0;
    lod->guard.cost_calibrated = 1;
    /* a start for the cost per changed node until passes measure it (the decaying maximum then
     * rises at once to a higher measurement, and falls 3 % a pass) */
    for (int k = 0; k < lod->L && !lod->guard.cost_given; k++)
        lod->guard.cost_block_change[k] = fmax(lod->guard.cost_block_change[k], SQ_GUARD_BLOCK_CHANGE_START);
}

/* a live budget follows: every array a pass writes reserved and mapped, and the guard's pass
 * terms calibrated, now (at load) instead of in the first budgeted frame */
long sq_lod_prepare_budget(sq_lod *lod)
{
    if (lod->reserve.reserve_live || !lod->cpl.have_mat)
        return 0;
    lod->reserve.reserve_live = 1;
    long pages = sq_lodx_reserve_blocks(lod, 1e9, SQ_RESERVE_LOAD_CHUNKS) + sq_lodx_map_state(lod);
    if (!lod->guard.cost_calibrated) {
        sq_lod_frame_in in;
        memset(&in, 0, sizeof in);
        in.mat = &lod->cpl.mat;
        lod_frame fr;
        memset(&fr, 0, sizeof fr);
        fr.lod = lod;
        fr.in = &in;
        calibrate(&fr);
    }
    return pages;
}

/* ---------------------------------------------------------------- the stages */

/* guaranteed frame rate: no splitting after a frame over budget (merging still allowed); the
 * node updates the next frames may have (the cost model above) */
static void stage_guard(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    double budget_s = fr->in->budget_s;
    sq_lodx_static_loads(lod, fr->in->gravity); /* no-op unless gravity or material changed */
    fr->prev_time = lod->guard.last_time;
    fr->fr_budget = lod->def.budget * budget_s;
    /* the thread's time between two frames of this body (the body's own work around the lod
     * frame: tool holds, node levels, health; the caller's between its steps, less what it
     * declared not the product's, sq_lod_untimed), up to a quarter of the period, is not the
     * lod's */
    fr->outside_raw = lod->guard.last_c_end > 0 ? fr->c_start - lod->guard.last_c_end - lod->guard.untimed : 0;
    lod->guard.untimed = 0;
    if (budget_s > 0 && lod->guard.last_c_end > 0) {
        double outside = fmin(fmax(fr->outside_raw, 0.0), 0.25 * budget_s);
        sq_lodx_guard_learn(lod, &lod->guard.cost_outside, &lod->guard.tr_outside, outside);
        fr->fr_budget = fmax(0.0, fr->fr_budget - lod->guard.cost_outside);
    }
    fr->over_budget = budget_s > 0 && fr->prev_time > fr->fr_budget;
    fr->cap_user = lod->def.max_node_updates;
    fr->cap_guard = 0;
    fr->coarse_ms = 0;
    if (budget_s <= 0)
        return;
    lod->guard.guard_clock++;
    if (!lod->reserve.reserve_live && lod->cpl.have_mat) {
        /* the first budgeted frame, unless done at load (sq_lod_prepare_budget): every array a
         * pass writes reserved and mapped, whatever it costs (a run without a budget does not
         * hold them), then kept ahead of need at the end of frames with room (reserve_ahead) */
        double c = sq_thread_cpu();
        fr->reserved_pages += sq_lod_prepare_budget(lod);
        fr->c_reserve += sq_thread_cpu() - c; /* (not the frame's fixed cost) */
    }
    if (!lod->guard.cost_calibrated)
        calibrate(fr);
    fr->guard_on = lod->guard.cost_update > 0;
    if (fr->guard_on) {
        /* the layout must fit without a pass; level 0 alone, the cheapest layout */
        fr->cap_guard = sq_lodx_guard_updates_fitting(lod, fr->fr_budget);
        fr->coarse_ms = 1e3 * (lod->guard.cost_fixed + lod->guard.cost_update *
                                                     (double)((long)lod->lv[0].model.nfree << sub_log2(lod, 0)));
    }
}

/* coupling blocks and the substeps they need (which may push the cost over a cap: merge
 * first then: the user's cap as before, the finest regions; the guard's, the least needed
 * regions), then the substep clock of the finest step */
static void stage_layout(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    const sq_material *mat = fr->in->mat;
    int L = lod->L;
    sq_lodx_update_ring_blocks(lod, mat);
    fr->projected = sq_lod_projected_updates(lod);
    int merged = 0;
    if (fr->cap_user > 0 && fr->projected > fr->cap_user) {
        sq_lodx_enforce_cap(lod, &fr->projected, &fr->ao);
        merged = 1;
    }
    if (fr->guard_on && fr->projected > fr->cap_guard) {
        /* the cost model rose since the last frame's end (or the budget fell): this frame
         * would not fit; merging now costs a pass, but less than the frame over */
        fr->guard_merges += sq_lodx_guard_merge(lod, fr->cap_guard, &fr->projected, &fr->ao, SQ_GUARD_REST_FRAMES,
                                                 1000000000L);
        merged = 1;
    }
    if (merged) {
        rebuild_pass(fr, 0, lod->guard.cost_update * (double)fr->projected);
        fr->projected = sq_lod_projected_updates(lod);
    }
    int nmax = 0;
    for (int k = 0; k < L; k++)
        nmax = SQ_MAX(nmax, sub_log2(lod, k));
    fr->nticks = 1L << nmax;
    for (int k = 0; k < L; k++)
        fr->stride[k] = 1L << (nmax - sub_log2(lod, k));
    for (int k = 0; k < L; k++) {
        lod->lev[k].tk.step_start = -fr->stride[k]; /* the previous frame's last step ended at tick 0 */
        lod->lev[k].tk.step_len = fr->stride[k];
    }
    if (sq_lodx_corot_on(lod))
        sq_lodx_corot_layout(lod, mat); /* corotational levels: tet lists of the layout */
}

/* tool holds onto active nodes (holds.c) */
static void stage_holds(lod_frame *fr)
{
    sq_lodx_hold_start(fr->lod, fr->in->holds, fr->in->nholds, fr->in->ntools, fr->in->frame_dt);
}

/* (1) ghost values of every due level at this tick (tick.c) */
static void tick_pull(lod_frame *fr)
{
    sq_lodx_tick_pull(fr->lod, fr->tick, fr->stride, &fr->tc);
}

/* (2) forces, coupling reactions and integration of the due levels at this tick (tick.c) */
static void tick_step(lod_frame *fr)
{
    sq_lodx_tick_step(fr->lod, fr->in, fr->tick, fr->stride, &fr->tc);
}

/* (4) split/merge at the end of the frame, when every level is at the same time (see
 * docs/lod.md: a region changes level at most once per frame, and the coupling is rebuilt
 * once), on fresh ring values. With a budget (the guard), a pair of levels is adapted only
 * when its rebuild fits in what is left of the frame; splits stop where the next frame and a
 * pass would pass SQ_GUARD_SPLIT_HEADROOM of the budget; regions the guard merged rest; and when the
 * next frame would not fit even without a pass, the least needed regions merge. */
static void stage_criterion(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    int L = lod->L;
    for (int k = 0; k < L; k++)
        sq_lodx_eval_ring(lod, k, fr->nticks);
    /* def.adapt_every: the split/merge pairs run every Nth frame only (the caps' merges below
     * run every frame) */
    int every = lod->def.adapt_every;
    int pairs = every <= 1 || lod->frames % every == 0;
    double now = sq_thread_cpu();
    fr->c_ticks = now - fr->c_mark;
    fr->c_mark = now;
    if (fr->tc.updates > 0)
        sq_lodx_guard_learn(lod, &lod->guard.cost_update, &lod->guard.tr_update, fr->c_ticks / (double)fr->tc.updates);
    if (fr->in->budget_s > 0 && lod->guard.cost_update > 0 && lod->guard.cost_calibrated)
        fr->guard_on = 1;
    if (!fr->guard_on) {
        for (int k = 0; k + 1 < L && k < lod->top && pairs; k++)
            sq_lodx_adapt_pair(lod, k, !fr->over_budget, &fr->projected, &fr->ao);
        sq_lodx_enforce_cap(lod, &fr->projected, &fr->ao);
        return;
    }
    double B = fr->fr_budget;
    /* what is left of this frame once the rest of it (push, feedback: within the fixed cost)
     * is paid */
    double used = lod->guard.cost_given ? lod->guard.cost_update * (double)fr->tc.updates + fr->modeled_pass : now - fr->c_start;
    double left = B - used - lod->guard.cost_fixed;
    long keep = sq_lodx_guard_updates_fitting(lod, B);
    long split_cap = sq_lodx_guard_updates_fitting(lod, SQ_GUARD_SPLIT_HEADROOM * B - SQ_GUARD_PASS_MARGIN * sq_lodx_guard_pass_cost(lod, sq_lodx_guard_all_levels(lod), 0));
    if (fr->cap_user > 0) {
        keep = SQ_MIN(keep, fr->cap_user);
        split_cap = SQ_MIN(split_cap, fr->cap_user);
    }
    unsigned sched = 0;
    for (int k = 0; k + 1 < L && k < lod->top && pairs; k++) {
        double pc = SQ_GUARD_PASS_MARGIN * sq_lodx_guard_pass_cost(lod, 3u << k, sched);
        if (pc > left) {
            fr->ao.refused = 1; /* deferred: this pair's splits and merges wait for a frame with room */
            continue;
        }
        /* the regions this pass can change; when the criterion wants more, the merges it
         * wants (least needed first), then the splits (most needed first) up to that count,
         * the others held out of this pass */
        double rc = SQ_GUARD_PASS_MARGIN * sq_lodx_guard_region_cost(lod, k);
        long afford = rc > 0 ? (long)fmin(1e9, fmax(0.0, (left - pc) / rc)) : 1000000000L;
        int allow = !fr->over_budget && split_cap > 0 && fr->projected < split_cap;
        int s0 = fr->ao.splits, m0 = fr->ao.merges;
        lod->def.max_node_updates = split_cap;
        sq_lodx_guard_rest_mask(lod, k, 1);
        long held = sq_lodx_guard_limit(lod, k, allow, afford);
        sq_lodx_adapt_pair(lod, k, allow, &fr->projected, &fr->ao);
        if (held > 0) {
            sq_lodx_guard_limit_undo(lod, k);
            fr->ao.refused = 1;
        }
        sq_lodx_guard_rest_mask(lod, k, 0);
        unsigned now_sched = 0;
        for (int m = 0; m < L; m++)
            now_sched |= fr->ao.changed[m] ? 1u << m : 0u;
        left -= SQ_GUARD_PASS_MARGIN * sq_lodx_guard_pass_cost(lod, now_sched, sched) + rc * (double)(fr->ao.splits - s0 + fr->ao.merges - m0);
        sched = now_sched;
    }
    lod->def.max_node_updates = fr->cap_user;
    if (fr->projected > keep) {
        /* the next frame would not fit even without a pass: merge the least needed regions,
         * as many as this frame can rebuild (the next frame's layout stage merges the rest) */
        double pc = SQ_GUARD_PASS_MARGIN * sq_lodx_guard_pass_cost(lod, sq_lodx_guard_all_levels(lod), sched), rc = 0;
        for (int k = 0; k + 1 < L; k++)
            rc = fmax(rc, SQ_GUARD_PASS_MARGIN * sq_lodx_guard_region_cost(lod, k));
        long most = rc > 0 ? (long)fmin(1e9, (left - pc) / rc) : 1000000000L;
        if (most > 0)
            fr->guard_merges += sq_lodx_guard_merge(lod, keep, &fr->projected, &fr->ao, SQ_GUARD_REST_FRAMES, most);
    }
}

/* the levels whose layout changed rebuilt, then the coupling over the new layout */
static void stage_adapt(lod_frame *fr)
{
    rebuild_pass(fr, 1, 0);
}

/* (3) every ghost from the active nodes at the end of the frame: the rendered finest level,
 * probes and the next frame start from consistent values */
static void stage_push(lod_frame *fr)
{
    sq_lodx_cascade_needed(fr->lod);
}

/* feedback: mean internal force on the held nodes, shared among the holds mapped there */
static void stage_feedback(lod_frame *fr)
{
    sq_lodx_hold_end(fr->lod, fr->in->holds, fr->in->nholds, fr->force);
}

/* the sharp estimates a pass could not make by its deadline (their levels on Gershgorin
 * substeps meanwhile), made in what is left of this frame: with a budget up to 90 % of it
 * less what the frame used, each only when its predicted cost fits (bound.c); without one,
 * all (a budget gone) */
static void sharp_owed(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    if (!sq_lodx_sharp_owes(lod, -1))
        return;
    double c = sq_thread_cpu();
    double room = fr->in->budget_s > 0 ? 0.9 * fr->fr_budget - (c - fr->c_start) : INFINITY;
    if (room > 0)
        fr->sharp_made = sq_lodx_sharp_owed(lod, room);
    fr->c_owed = sq_thread_cpu() - c;
}

/* with a budget, the coupling arrays grown ahead of need and their pages mapped
 * (sq_lodx_reserve_blocks) in what is left of this frame (90 % of the budget less what the
 * frame used, at most a quarter of the budget), so that no pass pays first-touch page faults; the rest waits for a later frame */
static void reserve_ahead(lod_frame *fr)
{
    if (fr->in->budget_s <= 0 || !fr->lod->cpl.have_mat || !fr->lod->reserve.reserve_live)
        return;
    double c = sq_thread_cpu();
    double room = fmin(0.9 * fr->fr_budget - (c - fr->c_start), 0.25 * fr->fr_budget);
    if (room > 0)
        fr->reserved_pages += sq_lodx_reserve_blocks(fr->lod, room, 1);
    fr->c_reserve += sq_thread_cpu() - c;
}

/* the cost model of the guard, then the profile and the frame's event */
static void frame_profile(lod_frame *fr, sq_frame_profile *prof)
{
    sq_lod *lod = fr->lod;
    int L = lod->L;
    double budget_s = fr->in->budget_s;
    double t_pull = fr->t[SQ_LOD_STAGE_PULL], t_int = fr->t[SQ_LOD_STAGE_STEP];
    long updates = fr->tc.updates, cap_user = fr->cap_user, cap_guard = fr->cap_guard;
    const adapt_out ao = fr->ao;
    double t_end = sq_now(), c_end = sq_thread_cpu();
    double cpu = c_end - fr->c_start;
    lod->guard.last_c_end = c_end;
    if (fr->c_ticks == 0 && updates > 0) { /* a frame abandoned before its criterion stage */
        fr->c_ticks = fmax(0.0, cpu - fr->c_pass);
        sq_lodx_guard_learn(lod, &lod->guard.cost_update, &lod->guard.tr_update, fr->c_ticks / (double)updates);
    }
    /* what is neither ticks nor passes (nor the reserve and owed estimates, done only with room left):
     * criterion, push, feedback, guard, layout, holds */
    sq_lodx_guard_learn(lod, &lod->guard.cost_fixed, &lod->guard.tr_fixed, fmax(0.0, cpu - fr->c_ticks - fr->c_pass - fr->c_reserve - fr->c_owed));

    lod->guard.guard_modeled = lod->guard.cost_fixed + lod->guard.cost_update * (double)updates + fr->modeled_pass;
    lod->guard.last_time = lod->guard.cost_given ? lod->guard.guard_modeled : cpu; /* given costs: deterministic */
    long next = sq_lod_projected_updates(lod);
    lod->guard.guard_predicted = lod->guard.cost_fixed + lod->guard.cost_update * (double)next;
    double coarse_ms = 1e3 * (lod->guard.cost_fixed + lod->guard.cost_update *
                                                    (double)((long)lod->lv[0].model.nfree << sub_log2(lod, 0)));
    if (sq_debug()->guard_trace && budget_s > 0)
        fprintf(stderr,
                "guard %ld: cpu %.2f ms (ticks %.2f, passes %d %.2f, rest %.2f; outside %.2f, before this frame %.2f), "
                "%ld updates, modeled %.2f ms, rebuilt %#x, "
                "splits %d merges %d (guard %ld), next %ld updates predicted %.2f ms; model %.1f ns/update, "
                "fixed %.2f ms, couple %.2f, bound %.2f, per change %.0f/%.0f/%.0f/%.0f us; "
                "reserve %.2f ms %ld pages (%ld pending, %.1f MB held); owed estimates %.2f ms, %d made, %d owed\n",
                lod->guard.guard_clock, 1e3 * cpu, 1e3 * fr->c_ticks, fr->passes, 1e3 * fr->c_pass,
                1e3 * (cpu - fr->c_ticks - fr->c_pass), 1e3 * lod->guard.cost_outside, 1e3 * fr->outside_raw, updates, 1e3 * lod->guard.guard_modeled, fr->rebuilt, ao.splits, ao.merges,
                fr->guard_merges, next, 1e3 * lod->guard.guard_predicted, 1e9 * lod->guard.cost_update,
                1e3 * lod->guard.cost_fixed, 1e3 * lod->guard.cost_couple, 1e3 * lod->guard.cost_bound,
                1e6 * lod->guard.cost_block_change[0], 1e6 * lod->guard.cost_block_change[1], 1e6 * lod->guard.cost_block_change[2],
                1e6 * lod->guard.cost_block_change[3], 1e3 * fr->c_reserve, fr->reserved_pages, lod->reserve.reserve_pending,
                1e-6 * (double)lod->reserve.reserve_bytes, 1e3 * fr->c_owed, fr->sharp_made, sq_lodx_sharp_owes(lod, -1));
    if (sq_debug()->guard_trace && budget_s > 0) {
        /* where a frame's thread CPU time went (a frame far over its model: user or system
         * time, page faults, the thread preempted) */
        double u, sy;
        long flt, cs;
        sq_thread_usage(&u, &sy, &flt, &cs);
        fprintf(stderr, "usage %ld: user %.2f ms, system %.2f ms, minor faults %ld, involuntary switches %ld\n",
                lod->guard.guard_clock, 1e3 * (u - fr->u0_user), 1e3 * (sy - fr->u0_sys), flt - fr->u0_flt, cs - fr->u0_ivcsw);
    }
    long cap_used = cap_guard;
    lod->def.max_node_updates = cap_user;
    if (prof) {
        prof->t_pull = t_pull;
        prof->t_integrate = t_int;
        prof->t_push = fr->t[SQ_LOD_STAGE_PUSH];
        prof->t_adapt = fr->t[SQ_LOD_STAGE_CRITERION] + fr->t[SQ_LOD_STAGE_ADAPT];
        prof->t_total = t_end - fr->t_start;
        memcpy(prof->t_stage, fr->t, sizeof prof->t_stage);
        prof->node_updates = updates;
        prof->ring_values = fr->tc.ring_values;
        prof->ring_rows = fr->tc.ring_rows;
        prof->frontier_rows = fr->tc.frontier_rows;
        for (int k = 0; k < SQ_MAX_LEVELS; k++) {
            prof->active[k] = k < L ? lod->lev[k].lay.nactive : 0;
            prof->substeps[k] = k < L ? 1 << sub_log2(lod, k) : 0;
        }
        prof->splits = ao.splits;
        prof->merges = ao.merges;
        prof->splits_refused = fr->over_budget || ao.refused;
        if (budget_s > 0 && lod->guard.cost_update > 0 && coarse_ms > fr->fr_budget * 1e3) {
            prof->splits_refused = 1;
            sq_frame_event(prof, SQ_HEALTH_BUDGET_COARSE, coarse_ms, lod->lv[0].model.nfree,
                           1 << sub_log2(lod, 0), fr->fr_budget * 1e3, NULL);
        } else if (fr->over_budget)
            sq_frame_event(prof, SQ_HEALTH_BUDGET_OVER, fr->prev_time * 1e3, lod->def.budget * 100,
                           budget_s * 1e3, 0, NULL);
        else if (fr->guard_merges > 0)
            sq_frame_event(prof, SQ_HEALTH_BUDGET_PREDICTED, lod->def.budget * 100, budget_s * 1e3,
                           (double)cap_used, 0, NULL);
        else if (ao.refused && cap_user > 0)
            sq_frame_event(prof, SQ_HEALTH_NODE_CAP, (double)cap_user, 0, 0, 0, NULL);
    }
}

/* ---------------------------------------------------------------- the frame */

const char *sq_lod_stage_name(int stage)
{
    static const char *const names[SQ_LOD_STAGES] = {"guard", "layout", "holds", "pull", "step",
                                                     "criterion", "adapt", "push", "feedback"};
    return stage >= 0 && stage < SQ_LOD_STAGES ? names[stage] : "?";
}

void sq_lod_frame(sq_lod *lod, const sq_lod_frame_in *in, double (*force)[3], sq_frame_profile *prof)
{
    lod_frame fr;
    memset(&fr, 0, sizeof(fr));
    fr.lod = lod;
    fr.in = in;
    fr.force = force;
    fr.t_start = sq_now();
    fr.c_start = sq_thread_cpu();
    fr.mark = fr.t_start;
    fr.c_mark = fr.c_start;
    if (sq_debug()->guard_trace && in->budget_s > 0)
        sq_thread_usage(&fr.u0_user, &fr.u0_sys, &fr.u0_flt, &fr.u0_ivcsw);
    for (int t = 0; force && t < in->ntools; t++)
        force[t][0] = force[t][1] = force[t][2] = 0;

    run_once(&fr, stage_guard, SQ_LOD_STAGE_GUARD);   /* splits allowed? the cap that fits */
    run_once(&fr, stage_layout, SQ_LOD_STAGE_LAYOUT); /* coupling, cap merges, substep clock */
    run_once(&fr, stage_holds, SQ_LOD_STAGE_HOLDS);   /* tool holds onto active nodes */
    for (fr.tick = 0; fr.tick < fr.nticks; fr.tick++) {
        if ((fr.tick & 15) == 15 && sq_cancelled())
            break; /* the server is stopping: the frame is abandoned */
        if (in->live)
            sq_lodx_hold_live(lod, in, (fr.tick + 1.0) / fr.nticks); /* the newest haptic poses, at every tick (holds.c) */
        run(&fr, tick_pull, SQ_LOD_STAGE_PULL);    /* ring ghosts of the due levels */
        run(&fr, tick_step, SQ_LOD_STAGE_STEP);    /* forces, coupling, integration */
    }
    if (fr.tick == fr.nticks) {                    /* every level at the frame's end */
        run_once(&fr, stage_criterion, SQ_LOD_STAGE_CRITERION); /* split/merge decisions */
        run_once(&fr, stage_adapt, SQ_LOD_STAGE_ADAPT);         /* changed levels rebuilt */
    }
    run_once(&fr, stage_push, SQ_LOD_STAGE_PUSH);       /* ghosts for the viewer, next frame */
    run_once(&fr, stage_feedback, SQ_LOD_STAGE_FEEDBACK); /* tool forces, holds released */
    sharp_owed(&fr);                               /* step estimates a pass left owed */
    reserve_ahead(&fr);                            /* coupling arrays mapped ahead of need */
    frame_profile(&fr, prof);                      /* cost model, profile, events */
    lod->frames++;
}
