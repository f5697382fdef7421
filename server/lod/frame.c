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
#include "lod/frame.h"
#include "lod/guard.h"
#include "lod/holds.h"
#include "lod/pass.h"
#include "lod/reserve.h"
#include "lod/ring.h"
#include "lod/state.h"
#include "lod/statics.h"
#include "lod/tick.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>


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

/* ---------------------------------------------------------------- the stages */

/* guaranteed frame rate (guard.c): splits allowed? the frame's budget; with a budget, the
 * pass's reserve and calibration the first time (pass.c), then the node-update cap that fits */
static void stage_guard(lod_frame *fr)
{
    sq_lodx_static_loads(fr->lod, fr->in->gravity); /* no-op unless gravity or material changed */
    if (sq_lodx_guard_open(fr)) {
        sq_lodx_pass_prepare(fr);
        sq_lodx_guard_cap(fr);
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
        sq_lodx_pass(fr, 0, lod->guard.cost_update * (double)fr->projected);
        fr->projected = sq_lod_projected_updates(lod);
    }
    int nmax = 0;
    for (int k = 0; k < L; k++)
        nmax = SQ_MAX(nmax, sub_log2(lod, k));
    fr->nticks = 1L << nmax;
    for (int k = 0; k < L; k++)
        fr->stride[k] = 1L << (nmax - sub_log2(lod, k));
    sq_lodx_tick_clock(lod, fr->stride); /* the previous frame's last step ended at tick 0 */
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
    sq_lodx_guard_ticks_measured(fr); /* the cost per update; the guard on once it is known */
    if (!fr->guard_on) {
        for (int k = 0; k + 1 < L && k < lod->top && pairs; k++)
            sq_lodx_adapt_pair(lod, k, !fr->over_budget, &fr->projected, &fr->ao);
        sq_lodx_enforce_cap(lod, &fr->projected, &fr->ao);
        return;
    }
    sq_lodx_guard_adapt(fr, now, pairs); /* the pairs within the budget, the guard's merges */
}

/* the levels whose layout changed rebuilt, then the coupling over the new layout */
static void stage_adapt(lod_frame *fr)
{
    sq_lodx_pass(fr, 1, 0);
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
    long next = sq_lodx_guard_frame_end(fr, c_end, cpu); /* the cost model (guard.c) */
    double coarse_ms = 1e3 * sq_lodx_guard_coarse_cost(lod); /* the model just learned */
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
    lod->focus = in->focus;
    lod->nfocus = in->focus ? in->nfocus : 0;

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
    lod->focus = NULL;
    lod->nfocus = 0;
}
