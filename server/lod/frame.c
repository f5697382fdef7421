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

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lod/lod_internal.h"



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
    /* layout and clock */
    long projected;                  /* node updates one frame of the current layout costs */
    adapt_out ao;                    /* splits, merges, refusals, levels whose layout changed */
    long nticks, tick;               /* finest substeps of the frame; the current one */
    long stride[SQ_MAX_LEVELS];      /* level k steps every stride[k] ticks */
    long updates;                    /* node integrations so far */
    long ring_values, ring_rows, frontier_rows; /* the interface's work so far (profile) */
} lod_frame;

/* run one stage and add its wall time to its entry */
static inline void run(lod_frame *fr, void (*stage)(lod_frame *), int which)
{
    stage(fr);
    double now = sq_now();
    fr->t[which] += now - fr->mark;
    fr->mark = now;
}

/* ---------------------------------------------------------------- the stages */

/* guaranteed frame rate: no splitting after a frame over budget (merging still allowed) */
static void stage_guard(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    double budget_s = fr->in->budget_s;
    sq_lodx_static_loads(lod, fr->in->gravity); /* no-op unless gravity or material changed */
    fr->prev_time = lod->last_time;
    fr->over_budget = budget_s > 0 && fr->prev_time > lod->def.budget * budget_s;
    /* ... and the next frame predicted from its node updates times the CPU cost of one update
     * measured on the last frame that had any: above budget x period, the node-update cap of
     * this frame is what fits, so the finest mergeable regions merge first and splits that
     * would exceed it are refused (the user's cap, if lower, still holds) */
    fr->cap_user = lod->def.max_node_updates;
    fr->cap_guard = 0;
    fr->coarse_ms = 0;
    if (budget_s > 0 && lod->cost_update > 0) {
        double fit = (lod->def.budget * budget_s - lod->cost_fixed) / lod->cost_update;
        fr->cap_guard = fit > 1e15 ? (long)1e15 : SQ_MAX((long)fit, 1L);
        if (fr->cap_user <= 0 || fr->cap_guard < fr->cap_user)
            lod->def.max_node_updates = fr->cap_guard;
        else
            fr->cap_guard = 0;
        /* the cheapest layout: every region at level 0 */
        fr->coarse_ms = 1e3 * lod->cost_update * (double)((long)lod->lv[0].model.nfree << sub_log2(lod, 0));
    }
}

/* coupling blocks and the substeps they need (which may push the cost over the cap: merge
 * first then), then the substep clock of the finest step */
static void stage_layout(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    const sq_material *mat = fr->in->mat;
    int L = lod->L;
    sq_lodx_update_ring_blocks(lod, mat);
    fr->projected = sq_lod_projected_updates(lod);
    if (lod->def.max_node_updates > 0 && fr->projected > lod->def.max_node_updates) {
        sq_lodx_enforce_cap(lod, &fr->projected, &fr->ao);
        for (int k = 0; k < L; k++)
            if (fr->ao.changed[k]) {
                sq_lodx_rebuild_level(lod, k);
                fr->ao.changed[k] = 0;
            }
        sq_lodx_build_sources(lod);
        sq_lodx_update_ring_blocks(lod, mat);
        fr->projected = sq_lod_projected_updates(lod);
    }
    int nmax = 0;
    for (int k = 0; k < L; k++)
        nmax = SQ_MAX(nmax, sub_log2(lod, k));
    fr->nticks = 1L << nmax;
    for (int k = 0; k < L; k++)
        fr->stride[k] = 1L << (nmax - sub_log2(lod, k));
    for (int k = 0; k < L; k++) {
        lod->lev[k].step_start = -fr->stride[k]; /* the previous frame's last step ended at tick 0 */
        lod->lev[k].step_len = fr->stride[k];
    }
    if (sq_lodx_corot_on(lod))
        sq_lodx_corot_layout(lod, mat); /* corotational levels: tet lists of the layout */
}

/* tool holds onto active nodes (holds.c) */
static void stage_holds(lod_frame *fr)
{
    sq_lodx_hold_start(fr->lod, fr->in->holds, fr->in->nholds, fr->in->ntools, fr->in->frame_dt);
}

/* (1) ghost values of every due level at this tick (ring ghosts from the active nodes, finest
 * simulated level included) */
static void tick_pull(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    long t = fr->tick;
    for (int k = 0; k < lod->L; k++) {
        lod->lev[k].due = t % fr->stride[k] == 0;
        if (lod->lev[k].due && lod->lev[k].nactive > 0) {
            sq_lodx_eval_ring(lod, k, t);
            fr->ring_values += lod->lev[k].nring;
        }
    }
}

/* (2) forces of every due level from the state at this tick, the coupling reactions between
 * levels, then integration of the free active nodes */
static void tick_step(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    const sq_material *mat = fr->in->mat;
    const double *gravity = fr->in->gravity;
    double frame_dt = fr->in->frame_dt;
    int L = lod->L;
    long t = fr->tick;
    for (int k = 0; k < L; k++)
        if (lod->lev[k].due && lod->lev[k].nactive > 0 && lod->lv[k].corot) {
            sq_lodx_corot_forces(lod, mat, gravity, k); /* tet by tet (corotational.c) */
        } else if (lod->lev[k].due && lod->lev[k].nactive > 0) {
            fr->frontier_rows += lod->lev[k].nfrontier;
            /* the all-nodes force pass is vectorised, faster per node than the masked
             * one, but computes ghost rows nobody reads and needs the frontier correction
             * pass: use it once 60% of the level is active (with the frontier rows folded,
             * 60% beat 40% by 5-8% CPU on the organ and 3.6% instructions on cube-poke) */
            if (5 * lod->lev[k].nactive >= 3 * lod->lv[k].model.n) {
                sq_level_forces(&lod->lv[k], mat, gravity, NULL);
                sq_lodx_front_correct(lod, mat, k);
            } else if (mat->use_viscosity) {
                sq_level_forces(&lod->lv[k], mat, gravity, lod->lev[k].active);
                sq_lodx_front_correct(lod, mat, k);
            } else {
                /* interior rows by the level's pass, frontier rows with their
                 * correction folded in */
                sq_lodx_rows(lod, mat, gravity, k);
                sq_lodx_front_rows(lod, mat, gravity, k);
            }
        }
    for (int k = 0; k < L; k++)
        if (lod->lev[k].nactive > 0 && lod->lev[k].nring > 0) {
            if (!lod->lev[k].due && lod->lv[k].corot) {
                /* the tet-by-tet reactions read every ring ghost */
                sq_lodx_eval_ring(lod, k, t);
                fr->ring_values += lod->lev[k].nring;
            } else if (!lod->lev[k].due) {
                /* between two of its steps only the ring rows with a source on a level that
                 * steps more often are used (the reactions the finer levels need now): only
                 * the ghosts they read are evaluated (the others are not read before the
                 * level's next step or the frame's end, which evaluate every ghost) */
                unsigned faster = 0;
                for (int m = 0; m < L; m++)
                    faster |= fr->stride[m] < fr->stride[k] ? 1u << m : 0u;
                fr->ring_values += sq_lodx_eval_ring_hot(lod, k, t, faster);
            }
            if (lod->lv[k].corot)
                fr->ring_rows += sq_lodx_corot_couple_out(lod, mat, k, t);
            else
                fr->ring_rows += sq_lodx_couple_out(lod, mat, k, t);
        }
    for (int k = 0; k < L; k++) {
        if (!lod->lev[k].due)
            continue;
        sq_level *Lk = &lod->lv[k];
        lod->lev[k].step_start = t;
        if (lod->lev[k].nactive == 0)
            continue;
        /* feedback of the held nodes */
        sq_lodx_hold_sample(lod, k, gravity);
        /* finer levels read this level between its steps */
        sq_lodx_save_prev(lod, k);
        if (lod->lev[k].nintegrated > 0) {
            double dtk = lod->lev[k].extra_log2 ? frame_dt / (double)(1L << sub_log2(lod, k)) : Lk->dt;
            if (lod->lev[k].nintegrated == Lk->model.n)
                sq_level_integrate(Lk, dtk, NULL);
            else
                sq_lodx_integrate(lod, k, dtk);
        }
        fr->updates += lod->lev[k].nintegrated;
    }
}

/* (4) split/merge at the end of the frame, when every level is at the same time (see
 * docs/lod.md: a region changes level at most once per frame, and the coupling is rebuilt
 * once), on fresh ring values */
static void stage_criterion(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    int L = lod->L;
    for (int k = 0; k < L; k++)
        sq_lodx_eval_ring(lod, k, fr->nticks);
    for (int k = 0; k + 1 < L && k < lod->top; k++)
        sq_lodx_adapt_pair(lod, k, !fr->over_budget, &fr->projected, &fr->ao);
    sq_lodx_enforce_cap(lod, &fr->projected, &fr->ao);
}

/* the levels whose layout changed rebuilt, then the coupling over the new layout */
static void stage_adapt(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    int any = 0;
    for (int k = 0; k < lod->L; k++)
        if (fr->ao.changed[k]) {
            sq_lodx_rebuild_level(lod, k);
            fr->ao.changed[k] = 0;
            any = 1;
        }
    if (any) {
        /* (holds are mapped again onto the new active nodes at the next frame) */
        sq_lodx_build_sources(lod);
        sq_lodx_update_ring_blocks(lod, fr->in->mat);
        sq_lodx_refresh_lists(lod);
    }
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

/* the cost model of the guard, then the profile and the frame's event */
static void frame_profile(lod_frame *fr, sq_frame_profile *prof)
{
    sq_lod *lod = fr->lod;
    int L = lod->L;
    double budget_s = fr->in->budget_s;
    double t_pull = fr->t[SQ_LOD_STAGE_PULL], t_int = fr->t[SQ_LOD_STAGE_STEP];
    long updates = fr->updates, cap_user = fr->cap_user, cap_guard = fr->cap_guard;
    const adapt_out ao = fr->ao;
    double t_end = sq_now(), c_end = sq_thread_cpu();
    lod->last_time = c_end - fr->c_start;
    if (updates > 0) {
        /* a decaying maximum: a frame with a rebuild costs more per update than a quiet one,
         * and the next frame may have one */
        /* split the frame's CPU time into the part that scales with node updates (ghost
         * values, forces, integration) and the rest (split/merge and rebuilds, end-of-frame
         * ghosts), in the proportions of the stage wall times */
        double cpu = c_end - fr->c_start, wall = t_end - fr->t_start;
        double share = wall > 0 ? fmin(1.0, (t_pull + t_int) / wall) : 1.0;
        double c = cpu * share / (double)updates;
        lod->cost_update = fmax(c, 0.9 * lod->cost_update);
        lod->cost_fixed = fmax(cpu * (1 - share), 0.9 * lod->cost_fixed);
    }
    long cap_used = lod->def.max_node_updates;
    lod->def.max_node_updates = cap_user;
    if (prof) {
        prof->t_pull = t_pull;
        prof->t_integrate = t_int;
        prof->t_push = fr->t[SQ_LOD_STAGE_PUSH];
        prof->t_adapt = fr->t[SQ_LOD_STAGE_CRITERION] + fr->t[SQ_LOD_STAGE_ADAPT];
        prof->t_total = t_end - fr->t_start;
        memcpy(prof->t_stage, fr->t, sizeof prof->t_stage);
        prof->node_updates = updates;
        prof->ring_values = fr->ring_values;
        prof->ring_rows = fr->ring_rows;
        prof->frontier_rows = fr->frontier_rows;
        for (int k = 0; k < SQ_MAX_LEVELS; k++) {
            prof->active[k] = k < L ? lod->lev[k].nactive : 0;
            prof->substeps[k] = k < L ? 1 << sub_log2(lod, k) : 0;
        }
        prof->splits = ao.splits;
        prof->merges = ao.merges;
        prof->splits_refused = fr->over_budget || ao.refused;
        if (fr->coarse_ms > lod->def.budget * budget_s * 1e3)
            sq_frame_event(prof, SQ_HEALTH_BUDGET_COARSE, fr->coarse_ms, lod->lv[0].model.nfree,
                           1 << sub_log2(lod, 0), lod->def.budget * budget_s * 1e3, NULL);
        else if (fr->over_budget)
            sq_frame_event(prof, SQ_HEALTH_BUDGET_OVER, fr->prev_time * 1e3, lod->def.budget * 100,
                           budget_s * 1e3, 0, NULL);
        else if (ao.refused && cap_guard > 0 && cap_used == cap_guard)
            sq_frame_event(prof, SQ_HEALTH_BUDGET_PREDICTED, lod->def.budget * 100, budget_s * 1e3,
                           (double)cap_guard, 0, NULL);
        else if (ao.refused)
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
    for (int t = 0; force && t < in->ntools; t++)
        force[t][0] = force[t][1] = force[t][2] = 0;

    run(&fr, stage_guard, SQ_LOD_STAGE_GUARD);     /* splits allowed? the cap that fits */
    run(&fr, stage_layout, SQ_LOD_STAGE_LAYOUT);   /* coupling, cap merges, substep clock */
    run(&fr, stage_holds, SQ_LOD_STAGE_HOLDS);     /* tool holds onto active nodes */
    for (fr.tick = 0; fr.tick < fr.nticks; fr.tick++) {
        if ((fr.tick & 15) == 15 && sq_cancelled())
            break; /* the server is stopping: the frame is abandoned */
        run(&fr, tick_pull, SQ_LOD_STAGE_PULL);    /* ring ghosts of the due levels */
        run(&fr, tick_step, SQ_LOD_STAGE_STEP);    /* forces, coupling, integration */
    }
    if (fr.tick == fr.nticks) {                    /* every level at the frame's end */
        run(&fr, stage_criterion, SQ_LOD_STAGE_CRITERION); /* split/merge decisions */
        run(&fr, stage_adapt, SQ_LOD_STAGE_ADAPT);         /* changed levels rebuilt */
    }
    run(&fr, stage_push, SQ_LOD_STAGE_PUSH);       /* ghosts for the viewer, next frame */
    run(&fr, stage_feedback, SQ_LOD_STAGE_FEEDBACK); /* tool forces, holds released */
    frame_profile(&fr, prof);                      /* cost model, profile, events */
}
