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

static void frame_fixed(sq_body *b, const sq_hold *holds, int nholds, int ntools, double (*force)[3],
                        sq_frame_profile *prof)
{
    sq_level *L = &b->level[b->cur];
    const sq_material *mat = &b->def.material;
    const double *g = b->def.gravity;
    int *hold_of = b->hold_of[b->cur];
    unsigned char *mask = b->mask[b->cur];

    /* map holds to nodes of the simulated level: same node at the finest level, else the
     * nearest level-k node gets the hold's translation (averaged when several map there) */
    if (b->cap_khold < nholds) {
        b->cap_khold = nholds;
        b->khold = sq_realloc(b->khold, sizeof(sq_hold) * (size_t)nholds);
        b->kcount = sq_realloc(b->kcount, sizeof(int) * (size_t)nholds);
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
                t[c] = L->d[3 * knode + c] + holds[h].target[c] - u[c];
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
    }
    /* held nodes: displacement set to the target, velocity to (target - old) / frame_dt, on the
     * free axes (the one hold rule of both modes: sq_level_apply_hold) */
    for (int h = 0; h < nk; h++) {
        sq_hold *kh = &b->khold[h];
        int i = kh->node;
        for (int c = 0; c < 3; c++)
            kh->target[c] /= count[h];
        sq_level_apply_hold(L, i, kh->target, L->d + 3 * (size_t)i, b->def.frame_dt); /* clamped axes stay */
        mask[i] = 0;
        hold_of[i] = -1;
    }

    /* substeps: forces on all nodes, feedback on held nodes, integrate the others */
    int nsub = sq_body_fixed_nsub(b, L);
    double sdt = b->def.sharp_step ? L->dt_fixed : L->dt;
    double inv = 1.0 / nsub;
    for (int s = 0; s < nsub; s++) {
        if ((s & 15) == 15 && sq_cancelled())
            break; /* the server is stopping: the frame is abandoned */
        sq_level_step(L, mat, g, sdt, nk ? mask : NULL); /* L->f: forces before the update */
        for (int h = 0; h < nk; h++) {
            int i = b->khold[h].node, t = b->khold[h].tool;
            if (force && t >= 0 && t < ntools)
                for (int c = 0; c < 3; c++)
                    force[t][c] += inv * (L->f[3 * i + c] - L->model.mass[i] * g[c]);
        }
    }
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

    /* tools -> holds on finest surface nodes */
    int tool_nodes[SQ_MAX_TOOLS];
    int nholds = sq_body_tool_holds(b, tools, ntools, tool_nodes);
    b->nholds = nholds; /* kept for the haptic model (haptic.c) */
    double t1 = sq_now();
    b->frames++;
    if (b->sleeping && nholds > 0)
        sq_body_count_health(b, SQ_HEALTH_WAKE, nholds);
    prof->t_tools = t1 - t0;

    if (b->sleeping && nholds == 0) {
        prof->sleeping = 1;
        prof->sleeping_nodes = b->level[b->cur].model.n;
        /* asleep, the resolution stays what it was: active nodes are reported as they stand
         * (nothing is updated: node_updates stays 0) */
        sq_body_active_nodes(b, prof->active);
    } else {
        b->sleeping = 0;
        if (b->def.lod.mode == SQ_LOD_ADAPTIVE) {
            sq_lod_frame_in in = {.mat = &b->def.material, .frame_dt = b->def.frame_dt, .holds = b->holds,
                                  .nholds = nholds, .ntools = ntools, .budget_s = frame_budget_s};
            memcpy(in.gravity, b->def.gravity, sizeof in.gravity);
            sq_lod_frame(b->lod, &in, force, prof);
            sq_body_count_health(b, prof->event_kind, prof->event_value[0]); /* budget warnings */
            mark_held(b, b->fine, b->holds, nholds);
            sq_lod_node_levels(b->lod, b->node_level);
        } else {
            frame_fixed(b, b->holds, nholds, ntools, force, prof);
        }
    }
    double t2 = sq_now();
    prof->t_integrate = SQ_MAX(0.0, t2 - t1 - prof->t_pull - prof->t_push - prof->t_adapt);

    /* health: a blow-up resets the body (no feedback then), else the sleep test */
    if (sq_body_check_health(b, prof, nholds))
        memset(force, 0, sizeof force);
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
