/* frame.c - stage: one adaptive frame (docs/lod.md, "The frame").
 *
 * A frame runs the finest substep clock (2^nmax ticks); level k is due every 2^(nmax - n_k)
 * ticks. At a tick, each due level's ring ghosts take their values, then each due level
 * computes its forces, receives the coupling reactions and integrates its free active nodes.
 * At the end of the frame, when every level is at the same time, the layout adapts
 * (split/merge) and the ghosts are brought up to date.
 */
#include "lod/lod.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lod/lod_internal.h"

#include <time.h>

/* CPU time of the calling thread (s): what the frame costs on an idle core */
static double thread_cpu(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ---------------------------------------------------------------- the frame */

void sq_lod_frame(sq_lod *lod, const sq_material *mat, const double gravity[3], double frame_dt,
                  const sq_hold *holds, int nholds, int ntools, double (*force)[3],
                  sq_frame_profile *prof, double budget_s)
{
    double t_start = sq_now(), c_start = thread_cpu();
    int L = lod->L, F = L - 1;
    double t_pull = 0, t_int = 0, t_push = 0, t_adapt = 0;
    long updates = 0;
    adapt_out ao;
    memset(&ao, 0, sizeof(ao));
    for (int t = 0; force && t < ntools; t++)
        force[t][0] = force[t][1] = force[t][2] = 0;

    sq_lodx_static_loads(lod, gravity); /* no-op unless gravity or material changed */
    /* guaranteed frame rate: no splitting after a frame over budget (merging still allowed) */
    double prev_time = lod->last_time;
    int over_budget = budget_s > 0 && prev_time > lod->def.budget * budget_s;
    /* ... and the next frame predicted from its node updates times the CPU cost of one update
     * measured on the last frame that had any: above budget x period, the node-update cap of
     * this frame is what fits, so the finest mergeable regions merge first and splits that
     * would exceed it are refused (the user's cap, if lower, still holds) */
    long cap_user = lod->def.max_node_updates, cap_guard = 0;
    double coarse_ms = 0;
    if (budget_s > 0 && lod->cost_update > 0) {
        double fit = (lod->def.budget * budget_s - lod->cost_fixed) / lod->cost_update;
        cap_guard = fit > 1e15 ? (long)1e15 : SQ_MAX((long)fit, 1L);
        if (cap_user <= 0 || cap_guard < cap_user)
            lod->def.max_node_updates = cap_guard;
        else
            cap_guard = 0;
        /* the cheapest layout: every region at level 0 */
        coarse_ms = 1e3 * lod->cost_update * (double)((long)lod->lv[0].nfree << sub_log2(lod, 0));
    }
    /* coupling blocks and the substeps they need (which may push the cost over the cap:
     * merge first then), then the substep clock of the finest step */
    sq_lodx_update_ring_blocks(lod, mat);
    long projected = sq_lod_projected_updates(lod);
    if (lod->def.max_node_updates > 0 && projected > lod->def.max_node_updates) {
        sq_lodx_enforce_cap(lod, &projected, &ao);
        for (int k = 0; k < L; k++)
            if (ao.changed[k]) {
                sq_lodx_rebuild_level(lod, k);
                ao.changed[k] = 0;
            }
        sq_lodx_build_sources(lod);
        sq_lodx_update_ring_blocks(lod, mat);
        projected = sq_lod_projected_updates(lod);
    }
    int nmax = 0;
    for (int k = 0; k < L; k++)
        nmax = SQ_MAX(nmax, sub_log2(lod, k));
    long nticks = 1L << nmax;
    long stride[SQ_MAX_LEVELS];
    for (int k = 0; k < L; k++)
        stride[k] = 1L << (nmax - sub_log2(lod, k));

    /* tool holds onto active nodes */
    sq_lodx_clear_holds(lod);
    if (nholds > lod->cap_holds) {
        lod->cap_holds = nholds;
        lod->hold_entry_of = sq_realloc(lod->hold_entry_of, sizeof(int) * (size_t)nholds);
    }
    for (int k = 0; k < L; k++) {
        lod->lev[k].nintegrated = lod->lev[k].nactive;
        memcpy(lod->lev[k].integrated, lod->lev[k].active, (size_t)lod->lv[k].n);
    }
    for (int h = 0; h < nholds; h++) {
        lod->hold_entry_of[h] = -1;
        if (holds[h].node < 0 || holds[h].node >= lod->lv[F].n || holds[h].tool < 0 ||
            holds[h].tool >= ntools)
            continue; /* the body validates holds; ignore any that are out of range */
        sq_lodx_map_hold(lod, &holds[h], h, 0.0);
    }
    sq_lodx_start_holds(lod, frame_dt);
    for (int k = 0; k < L; k++)
        sq_lodx_mask_list(lod, k);
    if (lod->lists_dirty)
        sq_lodx_refresh_lists(lod);

    for (int k = 0; k < L; k++) {
        lod->lev[k].step_start = -stride[k]; /* the previous frame's last step ended at tick 0 */
        lod->lev[k].step_len = stride[k];
    }
    for (long t = 0; t < nticks; t++) {
        if ((t & 15) == 15 && sq_cancelled())
            break; /* the server is stopping: the frame is abandoned */
        /* (1) ghost values of every due level at this tick (ring ghosts from the active
         * nodes, finest simulated level included) */
        double t0 = sq_now();
        for (int k = 0; k < L; k++) {
            lod->lev[k].due = t % stride[k] == 0;
            if (lod->lev[k].due && lod->lev[k].nactive > 0)
                sq_lodx_eval_ring(lod, k, t);
        }
        double t1 = sq_now();
        t_pull += t1 - t0;
        /* (2) forces of every due level from the state at this tick, the coupling reactions
         * between levels, then integration of the free active nodes */
        for (int k = 0; k < L; k++)
            if (lod->lev[k].due && lod->lev[k].nactive > 0) {
                /* the all-nodes force pass is vectorised, faster per node than the masked
                 * one, but computes ghost rows nobody reads and needs the frontier correction
                 * pass: use it once 60% of the level is active (with the frontier rows folded,
                 * 60% beat 40% by 5-8% CPU on the organ and 3.6% instructions on cube-poke) */
                if (5 * lod->lev[k].nactive >= 3 * lod->lv[k].n) {
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
                if (!lod->lev[k].due)
                    sq_lodx_eval_ring(lod, k, t);
                sq_lodx_couple_out(lod, mat, k, t);
            }
        for (int k = 0; k < L; k++) {
            if (!lod->lev[k].due)
                continue;
            sq_level *Lk = &lod->lv[k];
            lod->lev[k].step_start = t;
            if (lod->lev[k].nactive == 0)
                continue;
            /* feedback of the held nodes */
            for (int e = 0; e < lod->nhe; e++) {
                hold_entry *E = &lod->he[e];
                if (E->level != k || E->count == 0)
                    continue;
                int i = E->node;
                for (int c = 0; c < 3; c++)
                    E->fsum[c] += Lk->f[3 * i + c] - Lk->mass[i] * gravity[c];
                E->nf++;
            }
            /* finer levels read this level between its steps */
            sq_lodx_save_prev(lod, k);
            if (lod->lev[k].nintegrated > 0) {
                double dtk = lod->lev[k].extra_log2 ? frame_dt / (double)(1L << sub_log2(lod, k)) : Lk->dt;
                if (lod->lev[k].nintegrated == Lk->n)
                    sq_level_integrate(Lk, dtk, NULL);
                else
                    sq_lodx_integrate(lod, k, dtk);
            }
            updates += lod->lev[k].nintegrated;
        }
        double t2 = sq_now();
        t_int += t2 - t1;
        /* (4) split/merge at the end of the frame, when every level is at the same time
         * (see docs/lod.md: a region changes level at most once per frame, and the coupling
         * is rebuilt once), on fresh ring values */
        long next = t + 1;
        int any = 0;
        if (next == nticks) {
            for (int k = 0; k < L; k++)
                sq_lodx_eval_ring(lod, k, next);
            for (int k = 0; k + 1 < L && k < lod->top; k++)
                sq_lodx_adapt_pair(lod, k, !over_budget, &projected, &ao);
            sq_lodx_enforce_cap(lod, &projected, &ao);
        }
        for (int k = 0; k < L; k++)
            if (ao.changed[k]) {
                sq_lodx_rebuild_level(lod, k);
                ao.changed[k] = 0;
                any = 1;
            }
        if (any) {
            /* (holds are mapped again onto the new active nodes at the next frame) */
            sq_lodx_build_sources(lod);
            sq_lodx_update_ring_blocks(lod, mat);
            sq_lodx_refresh_lists(lod);
        }
        t_adapt += sq_now() - t2;
    }
    /* (3) every ghost from the active nodes at the end of the frame: the rendered finest
     * level, probes and the next frame start from consistent values */
    double t3 = sq_now();
    sq_lodx_cascade_needed(lod);
    t_push += sq_now() - t3;

    /* feedback: mean internal force on the held nodes, shared among the holds mapped there */
    for (int h = 0; force && h < nholds; h++) {
        int e = lod->hold_entry_of[h];
        if (e < 0 || lod->he[e].count == 0 || lod->he[e].nf == 0)
            continue;
        const hold_entry *E = &lod->he[e];
        for (int c = 0; c < 3; c++)
            force[holds[h].tool][c] += E->fsum[c] / E->nf / E->count;
    }
    sq_lodx_clear_holds(lod);
    for (int k = 0; k < L; k++)
        if (lod->lev[k].nintegrated != lod->lev[k].nactive) {
            memcpy(lod->lev[k].integrated, lod->lev[k].active, (size_t)lod->lv[k].n);
            lod->lev[k].nintegrated = lod->lev[k].nactive;
        }

    double t_end = sq_now(), c_end = thread_cpu();
    lod->last_time = c_end - c_start;
    if (updates > 0) {
        /* a decaying maximum: a frame with a rebuild costs more per update than a quiet one,
         * and the next frame may have one */
        /* split the frame's CPU time into the part that scales with node updates (ghost
         * values, forces, integration) and the rest (split/merge and rebuilds, end-of-frame
         * ghosts), in the proportions of the stage wall times */
        double cpu = c_end - c_start, wall = t_end - t_start;
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
        prof->t_push = t_push;
        prof->t_adapt = t_adapt;
        prof->t_total = t_end - t_start;
        prof->node_updates = updates;
        for (int k = 0; k < SQ_MAX_LEVELS; k++) {
            prof->active[k] = k < L ? lod->lev[k].nactive : 0;
            prof->substeps[k] = k < L ? 1 << sub_log2(lod, k) : 0;
        }
        prof->splits = ao.splits;
        prof->merges = ao.merges;
        prof->splits_refused = over_budget || ao.refused;
        if (coarse_ms > lod->def.budget * budget_s * 1e3)
            snprintf(prof->event, sizeof(prof->event),
                     "warning: cannot run in real time even fully coarse: level 0 needs %.2f ms "
                     "(%d nodes x %d steps), budget %.2f ms; splitting refused", coarse_ms,
                     lod->lv[0].nfree, 1 << sub_log2(lod, 0), lod->def.budget * budget_s * 1e3);
        else if (over_budget)
            snprintf(prof->event, sizeof(prof->event),
                     "warning: frame compute %.2f ms over %.0f%% of the %.2f ms budget: splitting "
                     "refused, merging allowed", prev_time * 1e3, lod->def.budget * 100,
                     budget_s * 1e3);
        else if (ao.refused && cap_guard > 0 && cap_used == cap_guard)
            snprintf(prof->event, sizeof(prof->event),
                     "warning: next frame predicted over %.0f%% of %.2f ms (%ld node updates fit): "
                     "finest regions merged, splitting refused", lod->def.budget * 100, budget_s * 1e3,
                     cap_guard);
        else if (ao.refused)
            snprintf(prof->event, sizeof(prof->event),
                     "warning: node-update cap %ld per frame reached: splitting refused", cap_user);
    }
}
