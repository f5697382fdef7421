/* frame.c - one frame of a body: tools to holds, then the fixed-level step (holds mapped to
 * the simulated level, substeps, tool feedback) or the lod module's adaptive frame, then
 * health and sleep (body/health.c). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lod/lod.h"
#include "body/body_internal.h"

/* the nodes of level k held in the frame just done (hold list of that level) */
static void mark_held(sq_body *b, int k, const sq_hold *holds, int nholds)
{
    sq_body_clear_held(b, k);
    for (int h = 0; h < nholds; h++) {
        int i = holds[h].node;
        if (!b->held[k][i]) {
            b->held[k][i] = 1;
            b->held_list[k][b->nheld[k]++] = i;
        }
    }
}

/* tool feedback: weight w of the force on each held node, less its weight, onto its tool */
static void add_feedback(const sq_body *b, const sq_level *L, int nk, int ntools, double (*force)[3], double w)
{
    const double *g = b->def.gravity;
    for (int h = 0; h < nk; h++) {
        int i = b->khold[h].node, t = b->khold[h].tool;
        if (force && t >= 0 && t < ntools)
            for (int c = 0; c < 3; c++)
                force[t][c] += w * (L->state.f[3 * i + c] - L->model.mass[i] * g[c]);
    }
}

/* the newest haptic poses (sq_body_set_pose_source) at fraction frac of the frame: live_shift of
 * each khold a live hold feeds, the summed change of its holds' targets since the frame's start
 * (zero from sq_body_live_begin until a pose changes); 0 when no pose changed */
static int live_shifts(sq_body *b, double frac)
{
    if (!sq_body_live_refresh(b, frac))
        return 0;
    for (int h = 0; h < b->nholds; h++)
        if (b->live_on[h])
            memset(b->live_shift + 3 * (size_t)b->khold_of[h], 0, 3 * sizeof(double));
    for (int h = 0; h < b->nholds; h++)
        if (b->live_on[h])
            for (int c = 0; c < 3; c++)
                b->live_shift[3 * (size_t)b->khold_of[h] + c] += b->live_target[3 * (size_t)h + c] - b->holds[h].target[c];
    return 1;
}

/* khold k's target with the newest poses: its frame-start target plus the mean change */
static double live_target_of(const sq_body *b, int k, int c)
{
    return b->khold[k].target[c] + (b->live ? b->live_shift[3 * (size_t)k + c] / b->kcount[k] : 0);
}

/* an explicit substep with live tools: the nodes they hold moved to the newest poses
 * (constrained axes stay) */
static void live_holds_fixed(sq_body *b, sq_level *L, double frac)
{
    if (!live_shifts(b, frac))
        return;
    for (int h = 0; h < b->nholds; h++) {
        if (!b->live_on[h])
            continue;
        int k = b->khold_of[h], i = b->khold[k].node;
        for (int c = 0; c < 3; c++)
            if (!(L->model.fixed[i] & (1u << c)))
                L->state.d[3 * (size_t)i + c] = live_target_of(b, k, c);
    }
}

/* an implicit frame's step s of nsub with live tools: the held nodes' velocity re-aimed at
 * the newest targets, reached at the frame's end (the steps move held nodes by h v) */
static void live_holds_implicit(sq_body *b, sq_level *L, int nk, int s, int nsub)
{
    if (!live_shifts(b, (double)s / nsub))
        return;
    const double left = b->def.frame_dt * (nsub - s) / nsub;
    for (int k = 0; k < nk; k++) {
        const int i = b->khold[k].node;
        for (int c = 0; c < 3; c++)
            if (!(L->model.fixed[i] & (1u << c)))
                L->state.v[3 * (size_t)i + c] = (live_target_of(b, k, c) - L->state.d[3 * (size_t)i + c]) / left;
    }
}

/* the implicit frame's steps (level/implicit.c): substeps backward Euler steps of
 * frame_dt / substeps, held nodes projected out; feedback from the force at each step's end
 * state; CG stopped by the frame budget when there is one (budget_s > 0); the held nodes put
 * at their targets at the end. Returns the substeps stepped */
static int implicit_steps(sq_body *b, sq_level *L, int nk, int ntools, double (*force)[3], double budget_s,
                          sq_frame_profile *prof)
{
    const sq_material *mat = &b->def.material;
    const double *g = b->def.gravity;
    const sq_implicit_def *def = &b->def.implicit;
    const int nsub = def->substeps;
    const double h = b->def.frame_dt / nsub, inv = 1.0 / nsub;
    const double deadline = budget_s > 0 ? sq_thread_cpu() + budget_s : 0;
    if (def->precond == SQ_PRECOND_MULTIGRID) {
        /* the body's coarser levels are the hierarchy (built once; block Jacobi without any) */
        const sq_level_model *coarse[SQ_MAX_LEVELS];
        int nc = 0;
        for (int k = b->cur - 1; k >= 0; k--) {
            sq_err ignore = {{0}};
            if (sq_body_ensure_level(b, k, &ignore) < 0)
                break;
            coarse[nc++] = &b->level[k].model;
        }
        sq_level_implicit_set_coarse(&L->model, &L->state, coarse, nc);
    }
    sq_implicit_stats st, tot;
    memset(&tot, 0, sizeof tot);
    for (int s = 0; s < nsub; s++) {
        if (b->live && nk) /* the newest poses before each step (a haptic channel) */
            live_holds_implicit(b, L, nk, s, nsub);
        sq_body_contact_constraints(b, L, h);
        sq_level_implicit_step(&L->model, &L->state, mat, g, h, nk ? b->mask[b->cur] : NULL, def, deadline, &st);
        sq_level_implicit_set_contacts(&L->model, &L->state, NULL);
        sq_body_contact_constrained(b, L, h);
        sq_body_contact_step(b, L, nk ? b->mask[b->cur] : NULL, h);
        tot.iterations += st.iterations;
        tot.residual = SQ_MAX(tot.residual, st.residual);
        tot.unconverged |= st.unconverged;
        tot.newton += st.newton;
        tot.newton_residual = SQ_MAX(tot.newton_residual, st.newton_residual);
        if (nk && force) {
            sq_level_forces(&L->model, &L->state, mat, g, NULL); /* the end state's force */
            add_feedback(b, L, nk, ntools, force, inv);
        }
    }
    if (prof) {
        prof->cg_iterations = tot.iterations;
        prof->cg_residual = tot.residual;
        prof->newton_iterations = tot.newton;
        prof->newton_residual = tot.newton_residual;
        if (tot.unconverged) {
            sq_frame_event(prof, SQ_HEALTH_SOLVE_UNCONVERGED, tot.residual, tot.iterations, def->tol,
                           def->max_iter, b->name);
            sq_body_count_health(b, SQ_HEALTH_SOLVE_UNCONVERGED, tot.residual);
        }
    }
    for (int k = 0; k < nk; k++) { /* at the target exactly (the steps' sum of h u, to round-off) */
        int i = b->khold[k].node;
        for (int c = 0; c < 3; c++)
            if (!(L->model.fixed[i] & (1u << c)))
                L->state.d[3 * (size_t)i + c] = live_target_of(b, k, c);
    }
    return nsub;
}

/* the explicit frame's start state (after the holds): d, v and the corotational rotations */
static void save_frame_start(sq_body *b, const sq_level *L)
{
    size_t n3 = 3 * (size_t)L->model.n, nq = sq_level_corot_state_len(&L->state);
    if (b->save_n3 != n3 || b->save_nq != nq) {
        b->save_d = sq_realloc(b->save_d, sizeof(double) * n3);
        b->save_v = sq_realloc(b->save_v, sizeof(double) * n3);
        b->save_q = sq_realloc(b->save_q, sizeof(double) * (nq ? nq : 1));
        b->save_n3 = n3;
        b->save_nq = nq;
    }
    memcpy(b->save_d, L->state.d, sizeof(double) * n3);
    memcpy(b->save_v, L->state.v, sizeof(double) * n3);
    sq_level_corot_save(&L->state, b->save_q);
}

static void load_frame_start(sq_body *b, sq_level *L)
{
    memcpy(L->state.d, b->save_d, sizeof(double) * b->save_n3);
    memcpy(L->state.v, b->save_v, sizeof(double) * b->save_n3);
    sq_level_corot_load(&L->state, b->save_q);
}

/* the explicit frame's substeps: forces on all nodes, feedback on held nodes, integrate the
 * others; a frame that diverges is re-run from its start with twice the substeps (up to
 * SQ_RETRY_MAX times; docs/physics.md section 11). Returns the substeps stepped */
static int explicit_steps(sq_body *b, sq_level *L, int nk, int ntools, double (*force)[3], double budget_s,
                          sq_frame_profile *prof)
{
    (void)budget_s; /* the explicit substeps are not cut by the budget */
    const sq_material *mat = &b->def.material;
    const double *g = b->def.gravity;
    unsigned char *mask = b->mask[b->cur];
    const double sdt0 = b->def.sharp_step ? L->dt_fixed : L->dt;
    int factor = b->boost > 1 ? b->boost : 1, nsub = sq_body_fixed_nsub(b, L) * factor, retried = 0;
    save_frame_start(b, L);
    for (int attempt = 0;; attempt++) {
        const double sdt = sdt0 / factor, inv = 1.0 / nsub;
        int s;
        for (s = 0; s < nsub; s++) {
            if ((s & 15) == 15 && sq_cancelled())
                break; /* the server is stopping: the frame is abandoned */
            if (b->live)
                live_holds_fixed(b, L, (s + 1.0) / nsub); /* the newest haptic poses (sq_body_set_pose_source) */
            sq_level_step(&L->model, &L->state, mat, g, sdt, nk ? mask : NULL); /* L->f: forces before the update */
            sq_body_contact_step(b, L, nk ? mask : NULL, sdt);
            add_feedback(b, L, nk, ntools, force, inv);
        }
        double value;
        b->div_frame = -1; /* this attempt's end state is new: test it afresh */
        if (s < nsub || attempt >= SQ_RETRY_MAX || (long)nsub * 2 > (1L << 22) ||
            sq_body_diverged_now(b, &value) == SQ_HEALTH_NONE)
            break;
        /* diverged: back to the frame's start, twice the substeps */
        load_frame_start(b, L);
        memset(&b->contact, 0, sizeof b->contact);
        memcpy(b->contact.impulse, b->carry, sizeof b->carry);
        sq_contact_cache_reset(b->ccache);
        sq_body_contact_retry(b);
        if (force)
            memset(force, 0, sizeof(double) * 3 * (size_t)SQ_MAX(ntools, 0));
        if (prof)
            sq_frame_event(prof, SQ_HEALTH_STEP_REFINED, 2.0 * nsub, nsub, 0, 0, b->name);
        factor *= 2;
        nsub *= 2;
        retried = 1;
    }
    if (retried) {
        sq_body_count_health(b, SQ_HEALTH_STEP_REFINED, nsub);
        b->boost = factor;
        b->boost_calm = 0;
    } else if (b->boost > 1 && ++b->boost_calm >= SQ_RETRY_CALM) {
        b->boost /= 2; /* try half the raise again */
        b->boost_calm = 0;
    }
    return nsub;
}

/* the integrators of the fixed-level frame, one row per sq_integrator_kind: the body's
 * def.integrator, chosen at creation (or by sq_body_set_integrator), picks the row, and the
 * frame runs it without asking which it is */
typedef struct frame_integrator {
    const char *name;
    int hold_velocity; /* 1: a hold prescribes the velocity only, the steps bring d to the target */
    /* the frame's substeps after the holds; returns the substeps stepped */
    int (*steps)(sq_body *b, sq_level *L, int nk, int ntools, double (*force)[3], double budget_s,
                 sq_frame_profile *prof);
} frame_integrator;

static const frame_integrator integrators[] = {
    [SQ_INTEGRATOR_EXPLICIT] = {"explicit", 0, explicit_steps}, /* symplectic Euler substeps */
    [SQ_INTEGRATOR_IMPLICIT] = {"implicit", 1, implicit_steps}, /* backward Euler by CG */
};

static void frame_fixed(sq_body *b, const sq_hold *holds, int nholds, int ntools, double (*force)[3],
                        sq_frame_profile *prof, double budget_s)
{
    sq_level *L = &b->level[b->cur];
    int *hold_of = b->hold_of[b->cur];
    unsigned char *mask = b->mask[b->cur];

    /* map holds to nodes of the simulated level: same node at the finest level, else the
     * nearest level-k node gets the hold's translation (averaged when several map there) */
    if (b->cap_khold < nholds) {
        b->cap_khold = nholds;
        b->khold = sq_realloc(b->khold, sizeof(sq_hold) * (size_t)nholds);
        b->kcount = sq_realloc(b->kcount, sizeof(int) * (size_t)nholds);
        b->khold_of = sq_realloc(b->khold_of, sizeof(int) * (size_t)nholds);
    }
    int nk = 0;
    const sq_mesh *fm = b->def.levels[b->fine];
    int *count = b->kcount;
    for (int h = 0; h < nholds; h++) {
        int node = holds[h].node, knode;
        double t[3];
        if (b->cur == b->fine) {
            knode = node;
            memcpy(t, holds[h].target, sizeof t);
        } else {
            int s = fm->surf_of_node[node];
            double u[3];
            sq_body_surface_disp(b, s, u);
            knode = b->surf_near[s];
            for (int c = 0; c < 3; c++)
                t[c] = L->state.d[3 * knode + c] + holds[h].target[c] - u[c];
        }
        int idx = hold_of[knode];
        if (idx < 0) {
            idx = nk++;
            hold_of[knode] = idx;
            b->khold[idx].node = knode;
            b->khold[idx].tool = holds[h].tool;
            memset(b->khold[idx].target, 0, sizeof b->khold[idx].target);
            count[idx] = 0;
        }
        for (int c = 0; c < 3; c++)
            b->khold[idx].target[c] += t[c];
        count[idx]++;
        b->khold_of[h] = idx;
    }
    /* held nodes: displacement set to the target, velocity to (target - old) / frame_dt, on the
     * free axes (the one hold rule of both modes: sq_level_apply_hold); implicit: the velocity
     * only, the displacement reaching the target through the frame's steps */
    const frame_integrator *in = &integrators[b->def.integrator];
    for (int h = 0; h < nk; h++) {
        sq_hold *kh = &b->khold[h];
        int i = kh->node;
        for (int c = 0; c < 3; c++)
            kh->target[c] /= count[h];
        double keep[3];
        memcpy(keep, L->state.d + 3 * (size_t)i, sizeof keep);
        sq_level_apply_hold(&L->model, &L->state, i, kh->target, L->state.d + 3 * (size_t)i, b->def.frame_dt); /* clamped axes stay */
        if (in->hold_velocity)
            memcpy(L->state.d + 3 * (size_t)i, keep, sizeof keep);
        mask[i] = 0;
        hold_of[i] = -1;
    }

    int nsub = in->steps(b, L, nk, ntools, force, budget_s, prof);
    for (int h = 0; h < nk; h++)
        mask[b->khold[h].node] = 1;
    mark_held(b, b->cur, b->khold, nk);

    if (prof) {
        prof->node_updates = (long)(L->model.n - nk) * nsub;
        prof->active[b->cur] = L->model.n;
        prof->substeps[b->cur] = nsub;
        prof->awake_nodes = L->model.n;
    }
}

/* the adaptive frame's live holds: the newest targets when they changed (sq_lod_frame_in) */
static int live_lod(void *arg, double frac, const unsigned char **on, const double **target)
{
    sq_body *b = arg;
    if (!sq_body_live_refresh(b, frac))
        return 0;
    *on = b->live_on;
    *target = b->live_target;
    return 1;
}

void sq_body_untimed(sq_body *b, double cpu_s)
{
    if (b->lod)
        sq_lod_untimed(b->lod, cpu_s);
}

void sq_body_prepare_budget(sq_body *b)
{
    if (b->lod)
        sq_lod_prepare_budget(b->lod);
}

/* the spheres an adaptive frame keeps at the finest level: each active tool with a focus
 * (sq_tool.focus), centre its pos, radius focus times its size (sphere radius, box
 * half-diagonal, grab capture radius); returns how many */
static int focus_spheres(const sq_tool *tools, int ntools, double out[][4])
{
    int n = 0;
    for (int t = 0; t < ntools && n < SQ_MAX_TOOLS; t++) {
        const sq_tool *tl = &tools[t];
        if (!tl->active || !(tl->focus > 0))
            continue;
        const double size = tl->shape == SQ_TOOL_BOX
                                ? sqrt(tl->half[0] * tl->half[0] + tl->half[1] * tl->half[1] + tl->half[2] * tl->half[2])
                                : tl->radius;
        memcpy(out[n], tl->pos, 3 * sizeof(double));
        out[n++][3] = tl->focus * size;
    }
    return n;
}

int sq_body_frame(sq_body *b, const sq_tool *tools, int ntools, sq_tool_feedback *feedback,
                  sq_frame_profile *prof, double frame_budget_s)
{
    double t0 = sq_now();
    sq_frame_profile local;
    if (!prof)
        prof = &local;
    memset(prof, 0, sizeof *prof);
    if (ntools < 0 || !tools)
        ntools = 0;
    if (ntools > SQ_MAX_TOOLS)
        ntools = SQ_MAX_TOOLS;
    double force[SQ_MAX_TOOLS][3];
    memset(force, 0, sizeof force);
    const sq_contact_sum last_contact = b->contact; /* kept while asleep */
    memset(&b->contact, 0, sizeof b->contact); /* this frame's contact impulses */
    memcpy(b->contact.impulse, b->carry, sizeof b->carry); /* and those others gave it just before */
    memset(b->carry, 0, sizeof b->carry);
    b->contact_cpu = 0;
    sq_contact_cache_reset(b->ccache); /* positions moved (holds, another body): measure afresh */
    sq_body_contact_begin(b);
    for (int o = 0; b->sleeping && o < b->nobstacles; o++) { /* a moving obstacle wakes the body */
        const double *u = b->obstacles[o].velocity;
        if (u[0] != 0 || u[1] != 0 || u[2] != 0)
            b->sleeping = b->calm = 0;
    }

    /* tools -> holds on finest surface nodes */
    int tool_nodes[SQ_MAX_TOOLS];
    int nholds = sq_body_tool_holds(b, tools, ntools, tool_nodes);
    b->nholds = nholds; /* kept for the haptic model (haptic.c) */
    sq_body_live_begin(b, tools, ntools); /* tools whose poses change within the frame */
    double t1 = sq_now();
    b->frames++;
    if (b->sleeping && nholds > 0)
        sq_body_count_health(b, SQ_HEALTH_WAKE, nholds);
    prof->t_tools = t1 - t0;

    if (b->sleeping && nholds == 0) {
        prof->sleeping = 1;
        b->contact = last_contact; /* asleep where it rests: the same support */
        prof->sleeping_nodes = b->level[b->cur].model.n;
        /* asleep, the resolution stays what it was: active nodes are reported as they stand
         * (nothing is updated: node_updates stays 0) */
        sq_body_active_nodes(b, prof->active);
    } else {
        b->sleeping = 0;
        if (b->def.lod.mode == SQ_LOD_ADAPTIVE) {
            double focus[SQ_MAX_TOOLS][4];
            const int nfocus = focus_spheres(tools, ntools, focus);
            sq_lod_frame_in in = {.mat = &b->def.material, .frame_dt = b->def.frame_dt, .holds = b->holds,
                                  .nholds = nholds, .ntools = ntools, .budget_s = frame_budget_s,
                                  .obstacles = b->obstacles, .nobstacles = b->nobstacles, .targets = b->targets,
                                  .ntargets = b->ntargets, .contact = &b->contact,
                                  .touched = b->touched, .live = b->live ? live_lod : NULL, .live_arg = b,
                                  .focus = nfocus ? (const double(*)[4])focus : NULL, .nfocus = nfocus};
            memcpy(in.gravity, b->def.gravity, sizeof in.gravity);
            sq_lod_frame(b->lod, &in, force, prof);
            sq_body_count_health(b, prof->event_kind, prof->event_value[0]); /* budget warnings */
            mark_held(b, b->fine, b->holds, nholds);
            sq_lod_node_levels(b->lod, b->node_level);
        } else {
            frame_fixed(b, b->holds, nholds, ntools, force, prof, frame_budget_s);
        }
    }
    double t2 = sq_now();
    prof->t_integrate = SQ_MAX(0.0, t2 - t1 - prof->t_pull - prof->t_push - prof->t_adapt);

    /* health: a blow-up resets the body (no feedback then), else the sleep test */
    if (sq_body_check_health(b, prof, nholds)) {
        memset(force, 0, sizeof force);
        memset(&b->contact, 0, sizeof b->contact);
    }
    prof->t_health = sq_now() - t2;

    if (feedback)
        for (int t = 0; t < ntools; t++) {
            feedback[t].id = tools[t].id;
            feedback[t].force[0] = force[t][0];
            feedback[t].force[1] = force[t][1];
            feedback[t].force[2] = force[t][2];
            feedback[t].nnodes = tool_nodes[t];
        }
    if (prof->sleeping) {
        prof->awake_nodes = 0;
        prof->node_updates = 0;
    }
    prof->t_total = sq_now() - t0;
    return 0;
}
