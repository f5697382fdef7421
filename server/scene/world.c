/* world.c - one running instance of a scene: bodies, tool poses, frame clock, profiles.
 *
 * Deterministic: with budget_s == 0 nothing depends on wall-clock time, so the same scene
 * stepped the same number of frames gives bit-identical body states.
 */
#include "scene/scene.h"
#include "body/body.h" /* sq_body_sim_level */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* simulated time of frame k, computed from the count (no accumulated rounding) */
static double frame_time(const sq_world *w, long k)
{
    return (double)k / w->scene->frame_rate;
}

/* scripted tools take their pose at time t; live tools keep theirs */
static void pose_scripted_tools(sq_world *w, double t)
{
    for (int i = 0; i < w->ntools; i++) {
        if (!w->tool_scripted[i])
            continue;
        for (int j = 0; j < w->scene->ntools; j++)
            if (w->scene->tools[j].tool.id == w->tools[i].id)
                sq_tool_script_pose(&w->scene->tools[j], t, &w->tools[i]);
    }
}

/* the scene's tool table at t = 0 */
static void restore_tools(sq_world *w)
{
    w->ntools = w->scene->ntools;
    for (int i = 0; i < w->ntools; i++) {
        w->tool_scripted[i] = 1;
        sq_tool_script_pose(&w->scene->tools[i], 0, &w->tools[i]);
    }
    memset(w->feedback, 0, sizeof w->feedback);
    memset(w->grab_known, 0, sizeof w->grab_known);
}

/* a grab's capture fallback (nearest node within 3 radii when no node is within the radius)
 * takes only the body the tool hit: none when some body has a node within the radius (those
 * direct captures are what the tool hit), else the body whose surface is nearest to the
 * capture point. Decided once per capture point; the bodies capture in the same frame. */
static void grab_fallbacks(sq_world *w)
{
    for (int i = 0; i < w->ntools; i++) {
        const sq_tool *t = &w->tools[i];
        if (t->shape != SQ_TOOL_GRAB || !t->active) {
            w->grab_known[i] = 0;
            continue;
        }
        const double *at = t->has_origin ? t->origin : t->pos;
        if (w->grab_known[i] && !memcmp(w->grab_at[i], at, sizeof w->grab_at[i]))
            continue;
        int direct = 0, nearest_body = -1;
        double nearest = INFINITY;
        for (int b = 0; b < w->nbodies; b++) {
            double d;
            direct += sq_body_grab_reach(w->bodies[b], at, t->radius, &d);
            if (d < nearest) {
                nearest = d;
                nearest_body = b;
            }
        }
        w->grab_fallback[i] = direct ? -1 : nearest_body;
        memcpy(w->grab_at[i], at, sizeof w->grab_at[i]);
        w->grab_known[i] = 1;
    }
}

/* before any frame, the profiles already say which nodes are active and the steps per frame
 * of each level (stats read them) */
static void profile_at_rest(sq_world *w)
{
    for (int b = 0; b < w->nbodies; b++) {
        sq_body_active_nodes(w->bodies[b], w->profile[b].active);
        sq_body_substeps(w->bodies[b], w->profile[b].substeps);
    }
}

/* the scene's obstacles at time t, and every body meeting them */
static void pose_obstacles(sq_world *w, double t)
{
    const sq_scene *s = w->scene;
    w->nobstacles = s->nobstacles;
    for (int o = 0; o < s->nobstacles; o++)
        sq_obstacle_script_pose(&s->obstacles[o], t, 1.0 / s->frame_rate, &w->obstacles[o]);
    for (int b = 0; b < w->nbodies; b++)
        sq_body_set_obstacles(w->bodies[b], w->obstacles, w->nobstacles);
}

int sq_scene_check(const sq_scene *s, sq_err *err)
{
    for (int b = 0; b < s->nbodies; b++) {
        sq_err e = {{0}};
        sq_body *body = sq_body_create(&s->bodies[b], &e);
        if (!body)
            return sq_err_set(err, "%s: bodies[%d] (\"%s\"): %s", s->path, b, s->body_names[b], e.msg);
        sq_body_destroy(body);
    }
    return 0;
}

sq_world *sq_world_create(const sq_scene *scene, sq_err *err)
{
    if (!scene) {
        sq_err_set(err, "no scene given; load one with sq_scene_load or sq_scene_default");
        return NULL;
    }
    sq_world *w = sq_calloc(1, sizeof *w);
    w->scene = scene;
    for (int b = 0; b < scene->nbodies; b++) {
        sq_err e = {{0}};
        w->bodies[b] = sq_body_create(&scene->bodies[b], &e);
        if (!w->bodies[b]) {
            sq_err_set(err, "%s: bodies[%d] (\"%s\"): %s", scene->path, b, scene->body_names[b], e.msg);
            sq_world_destroy(w);
            return NULL;
        }
        w->nbodies = b + 1;
    }
    pose_obstacles(w, 0);
    restore_tools(w);
    profile_at_rest(w);
    return w;
}

void sq_world_destroy(sq_world *w)
{
    if (!w)
        return;
    for (int b = 0; b < w->nbodies; b++)
        sq_body_destroy(w->bodies[b]);
    free(w);
}

/* a scratch copy of body b's definition forced fully coarse: an adaptive body never splits
 * (split inf, merge everything) and starts at its level 0; a fixed body stays at its level */
static sq_body_def coarse_def(const sq_body *body)
{
    sq_body_def d = *sq_body_get_def(body);
    if (d.lod.mode == SQ_LOD_ADAPTIVE) {
        d.lod.split = INFINITY;
        d.lod.merge = 1e300;
        d.lod.level = 0;
        d.lod.max_node_updates = 0;
    }
    return d;
}

/* thread CPU s of one all-node force pass of the world's body at its coarsest simulated level
 * (read only; the part of a step that grows with the nodes), and that level, its nodes and steps */
static double force_pass_cpu(sq_body *body, int *level, int *nodes, int *steps)
{
    const sq_body_def *def = sq_body_get_def(body);
    int k = sq_body_sim_level(body);
    if (def->lod.mode == SQ_LOD_ADAPTIVE)
        for (k = 0; k < SQ_MAX_LEVELS - 1 && !sq_body_level(body, k); k++)
            ;
    sq_level *L = sq_body_level(body, k);
    if (!L)
        return -1;
    int sub[SQ_MAX_LEVELS];
    sq_body_substeps(body, sub);
    *level = k;
    *nodes = L->model.n;
    *steps = sub[k] > 0 ? sub[k] : 1 << L->substeps_log2;
    size_t nn = (size_t)L->model.n;
    double *f = sq_malloc(sizeof(double) * 3 * nn), *acc = sq_calloc(3 * nn + 1, sizeof(double));
    sq_level_forces_to(&L->model, &L->state, &def->material, def->gravity, NULL, f, acc); /* warm */
    double c0 = sq_thread_cpu(), c = c0;
    int reps = 0;
    while (reps < 3 || (c - c0 < 2e-3 && reps < 200)) {
        sq_level_forces_to(&L->model, &L->state, &def->material, def->gravity, NULL, f, acc);
        reps++;
        c = sq_thread_cpu();
    }
    free(f);
    free(acc);
    return (c - c0) / reps;
}

/* frames of the scratch copy: one warm-up (first-use costs), then at least RT_FRAMES timed ones,
 * more (up to RT_MAX_FRAMES) while they total under RT_MIN_CPU of thread CPU */
#define RT_FRAMES 3
#define RT_MAX_FRAMES 20
#define RT_MIN_CPU 5e-3

int sq_world_realtime_check(sq_world *w, double period_s, char *msg, size_t n)
{
    double frac = 0.95, passes = 0, worst_pass = 0, worst_steps_cpu = -1;
    int wb = 0, wk = 0, wn = 0, ws = 0, nb = 0;
    double load0 = sq_thread_cpu();
    /* a scratch world: the same scene, tools and frame count, its bodies fresh copies forced fully
     * coarse; the world checked is only read (its tools copied, one force pass timed per body).
     * The copies borrow each body's operators, lod hierarchy and mesh tables (read only by the
     * frames: sq_body_create_like) and are destroyed before w can change */
    sq_world *s = sq_calloc(1, sizeof *s);
    *s = *w;
    s->nbodies = 0;
    memset(s->bodies, 0, sizeof s->bodies);
    const char *failed = NULL;
    char why[256] = "";
    for (int b = 0; b < w->nbodies; b++) {
        sq_body *body = w->bodies[b];
        const sq_body_def *def = sq_body_get_def(body);
        if (def->lod.budget > 0)
            frac = fmin(frac, def->lod.budget);
        int k = 0, nodes = 0, steps = 1;
        double pass = force_pass_cpu(body, &k, &nodes, &steps);
        if (pass < 0)
            continue;
        passes += pass * steps;
        if (pass * steps > worst_steps_cpu) {
            worst_steps_cpu = pass * steps;
            worst_pass = pass;
            wb = b, wk = k, wn = nodes, ws = steps;
        }
        sq_body_def d = coarse_def(body);
        sq_err e = {{0}};
        sq_body *copy = sq_body_create_like(body, &d, &e);
        if (!copy) {
            failed = w->scene->body_names[b];
            snprintf(why, sizeof why, "%.200s", e.msg);
            break;
        }
        s->bodies[nb++] = copy;
        s->nbodies = nb;
    }
    double frame = 0, frame_max = 0;
    int timed = 0;
    if (!failed && nb > 0) {
        if (nb == w->nbodies) {
            sq_world_step(s, 0); /* warm-up: first-use allocations, the first step estimate */
            double c0 = sq_thread_cpu(), c = c0;
            while (timed < RT_FRAMES || (c - c0 < RT_MIN_CPU && timed < RT_MAX_FRAMES)) {
                double f0 = sq_thread_cpu();
                sq_world_step(s, 0);
                c = sq_thread_cpu();
                frame_max = fmax(frame_max, c - f0);
                timed++;
            }
            frame = (c - c0) / timed;
        }
    }
    for (int b = 0; b < s->nbodies; b++)
        sq_body_destroy(s->bodies[b]);
    free(s);
    double load = sq_thread_cpu() - load0;
    double budget = frac * period_s;
    if (worst_steps_cpu < 0 || period_s <= 0) {
        snprintf(msg, n, "realtime: no body to check");
        return 0;
    }
    if (failed || timed == 0) {
        /* no scratch copy (it cannot fail where the body itself was made, but say so): the
         * force passes alone, a lower bound */
        frame = passes;
        frame_max = passes;
    }
    /* what grows with the steps (the force passes) against the rest of the frame (integration,
     * coupling, ghosts and the frame's fixed cost) */
    double rest = fmax(0, frame - passes);
    char src[200];
    if (failed || timed == 0)
        snprintf(src, sizeof src, "force passes only, a lower bound: no scratch copy of body \"%.40s\" (%.90s)",
                 failed ? failed : "?", why);
    else
        snprintf(src, sizeof src, "mean of %d real frames of a fully coarse copy, slowest %.2f ms; check took %.0f ms",
                 timed, 1e3 * frame_max, 1e3 * load);
    if (frame > budget) {
        const char *todo =
            rest > passes
                ? "most of it is the frame's cost beside the force passes (integration, ghost levels, the frame's "
                  "fixed cost), paid once per frame: lower the frame rate (\"frame_rate\" in the scene), or give "
                  "the body fewer levels or a coarser level 0 (fewer nodes)"
            : ws > 1 ? "a lower frame rate does not help (the steps per frame grow with the period): "
                       "give the body a coarser level 0 (fewer nodes) or a material that allows a "
                       "longer stable step"
                     : "lower the frame rate (\"frame_rate\" in the scene: a frame already has one "
                       "step), or give the body a coarser level 0 (fewer nodes)";
        snprintf(msg, n,
                 "warning: the scene cannot run in real time even fully coarse: one frame with every body at "
                 "its coarsest level takes %.2f ms of CPU (%s%s), of which %.2f ms force passes (body %d, "
                 "level %d: %d nodes x %d steps x %.3f ms), budget %.2f ms (%.0f%% of the %.2f ms period); %s",
                 1e3 * frame, src, w->nbodies > 1 ? "; all bodies" : "", 1e3 * passes, wb, wk, wn, ws,
                 1e3 * worst_pass, 1e3 * budget, 100 * frac, 1e3 * period_s, todo);
        return 1;
    }
    snprintf(msg, n,
             "realtime: fully coarse frame predicted %.2f ms of CPU (%s), of which %.2f ms force passes (body %d, "
             "level %d: %d nodes x %d steps), budget %.1f ms",
             1e3 * frame, src, 1e3 * passes, wb, wk, wn, ws, 1e3 * budget);
    return 0;
}

void sq_world_reset(sq_world *w)
{
    for (int b = 0; b < w->nbodies; b++)
        sq_body_reset(w->bodies[b]);
    w->frame = 0;
    w->time = 0;
    w->deadline_misses = 0;
    w->resets = 0;
    w->last_frame_s = 0;
    memset(w->profile, 0, sizeof w->profile);
    pose_obstacles(w, 0);
    restore_tools(w);
    profile_at_rest(w);
}

void sq_world_untimed(sq_world *w, double cpu_s)
{
    for (int b = 0; b < w->nbodies; b++)
        sq_body_untimed(w->bodies[b], cpu_s);
}

void sq_world_prepare_budget(sq_world *w)
{
    for (int b = 0; b < w->nbodies; b++)
        sq_body_prepare_budget(w->bodies[b]);
}

void sq_world_set_pose_source(sq_world *w, sq_pose_source_fn fn, void *arg)
{
    w->pose_fn = fn;
    w->pose_arg = arg;
}

void sq_world_step(sq_world *w, double budget_s)
{
    double t0 = sq_now();
    long next = w->frame + 1;
    double t = frame_time(w, next);
    pose_scripted_tools(w, t);
    pose_obstacles(w, t);

    /* each body gets an equal share of the compute budget for its splitting decisions */
    double share = budget_s > 0 ? budget_s / w->nbodies : 0;
    grab_fallbacks(w);
    sq_tool tools[SQ_MAX_TOOLS];
    const int pairs = w->scene->body_contact && w->nbodies > 1;
    for (int b = 0; b < w->nbodies; b++) {
        sq_frame_profile *prof = &w->profile[b];
        memset(prof, 0, sizeof *prof);
        memcpy(tools, w->tools, sizeof(sq_tool) * (size_t)w->ntools);
        for (int i = 0; i < w->ntools; i++)
            tools[i].no_fallback = w->grab_known[i] && w->grab_fallback[i] != b;
        sq_contact_target tg[SQ_MAX_BODIES];
        int ntg = 0;
        if (pairs) /* the others' surfaces where they stand now (docs/physics.md section 13) */
            for (int j = 0; j < w->nbodies; j++)
                if (j != b && sq_body_contact_target(w->bodies[j], w->scene->body_friction, &tg[ntg]) == 0)
                    ntg++;
        sq_body_set_targets(w->bodies[b], tg, ntg);
        sq_body_set_pose_source(w->bodies[b], w->pose_fn, w->pose_arg);
        sq_body_frame(w->bodies[b], tools, w->ntools, w->feedback[b], prof, share);
        sq_body_set_targets(w->bodies[b], NULL, 0);
        for (int j = 0; pairs && j < w->nbodies; j++) /* the reactions: now on the bodies done, */
            if (j != b)                               /* at their frame's start on the others */
                sq_body_contact_apply(w->bodies[j], j > b);
        if (prof->reset)
            w->resets++;
    }
    w->frame = next;
    w->time = t;
    w->last_frame_s = sq_now() - t0;
    if (budget_s > 0 && w->last_frame_s > budget_s)
        w->deadline_misses++;
}

static int tool_valid(const sq_tool *t, sq_err *err)
{
    if (t->id < 0)
        return sq_err_set(err, "tool id %d is negative; use an id >= 0", t->id);
    if (t->shape != SQ_TOOL_SPHERE && t->shape != SQ_TOOL_BOX && t->shape != SQ_TOOL_GRAB)
        return sq_err_set(err, "tool %d: shape %d is unknown; use sphere (0), box (1) or grab (2)", t->id,
                          (int)t->shape);
    for (int i = 0; i < 3; i++)
        if (!isfinite(t->pos[i]) || fabs(t->pos[i]) > 1e6)
            return sq_err_set(err, "tool %d: position component %c = %g is not a finite coordinate "
                                   "below 1e6 m; send a position near the bodies",
                              t->id, "xyz"[i], t->pos[i]);
    if (t->shape == SQ_TOOL_BOX) {
        for (int i = 0; i < 3; i++)
            if (!(t->half[i] > 0) || !isfinite(t->half[i]))
                return sq_err_set(err, "tool %d: box half extent %c = %g; use a finite value > 0 (m)", t->id,
                                  "xyz"[i], t->half[i]);
    } else if (!(t->radius > 0) || !isfinite(t->radius)) {
        return sq_err_set(err, "tool %d: radius %g; use a finite radius > 0 (m)", t->id, t->radius);
    }
    return 0;
}

/* the activation point of nt replacing old (NULL for a new tool): set on an inactive ->
 * active change (or a change of shape), kept while it stays active, cleared when inactive */
static void tool_origin(sq_tool *nt, const sq_tool *old)
{
    if (!nt->active) {
        nt->has_origin = 0;
        return;
    }
    if (old && old->active && old->shape == nt->shape) {
        memcpy(nt->origin, old->origin, sizeof nt->origin);
        nt->has_origin = old->has_origin;
        return;
    }
    memcpy(nt->origin, nt->pos, sizeof nt->origin);
    nt->has_origin = 1;
}

int sq_world_set_tool(sq_world *w, const sq_tool *t, sq_err *err)
{
    if (tool_valid(t, err))
        return -1;
    for (int i = 0; i < w->ntools; i++)
        if (w->tools[i].id == t->id) {
            sq_tool nt = *t;
            tool_origin(&nt, &w->tools[i]);
            w->tools[i] = nt;
            w->tool_scripted[i] = 0;
            return 0;
        }
    if (w->ntools >= SQ_MAX_TOOLS)
        return sq_err_set(err, "tool %d: the world already has %d tools, the maximum; reuse an id", t->id,
                          SQ_MAX_TOOLS);
    w->tools[w->ntools] = *t;
    tool_origin(&w->tools[w->ntools], NULL);
    w->tool_scripted[w->ntools] = 0;
    memset(w->feedback, 0, sizeof w->feedback);
    w->ntools++;
    return 0;
}

int sq_world_probe(const sq_world *w, int probe, double u[3])
{
    if (probe < 0 || probe >= w->scene->nprobes)
        return -1;
    const sq_probe *p = &w->scene->probes[probe];
    if (p->body < 0 || p->body >= w->nbodies)
        return -1;
    return sq_body_probe(w->bodies[p->body], p->point, u);
}

int sq_world_find_body(const sq_world *w, const char *name)
{
    for (int b = 0; b < w->nbodies; b++)
        if (!strcmp(w->scene->body_names[b], name))
            return b;
    return -1;
}

int sq_world_listed_level(const sq_world *w, int body, int k)
{
    if (!w->scene || body < 0 || body >= w->nbodies || k < 0 || k >= sq_body_nlevels(w->bodies[body]))
        return k;
    return w->scene->level_index[body][k];
}

void sq_world_surface_state(const sq_world *w, int body, float *xyz, unsigned char *level)
{
    const sq_body *b = w->bodies[body];
    sq_body_surface_state(b, xyz, level);
    if (!level || !w->scene)
        return;
    /* loaded index -> listed index (identity when every listed level is loaded) */
    int nl = sq_body_nlevels(b), n = sq_body_surface_mesh(b)->nsurf;
    unsigned char map[256];
    for (int k = 0; k < 256; k++)
        map[k] = (unsigned char)k;
    for (int k = 0; k < nl; k++)
        map[k] = (unsigned char)w->scene->level_index[body][k];
    for (int i = 0; i < n; i++)
        level[i] = map[level[i]];
}

int sq_world_write_vtk(const sq_world *w, int body, const char *path, sq_err *err)
{
    if (body < 0 || body >= w->nbodies)
        return sq_err_set(err, "%s: no body %d in this world", path, body);
    const sq_body *b = w->bodies[body];
    int adaptive = sq_body_get_def(b)->lod.mode == SQ_LOD_ADAPTIVE;
    int k = sq_body_sim_level(b);
    const sq_mesh *m = sq_body_mesh(b, k);
    const unsigned char *nl = sq_body_node_level(b);
    int *lev = sq_malloc(sizeof(int) * (size_t)m->nnodes);
    for (int i = 0; i < m->nnodes; i++)
        lev[i] = sq_world_listed_level(w, body, adaptive && nl ? nl[i] : k);
    int rc = sq_mesh_write_vtk(m, path, sq_body_displacement(b, k), sq_body_velocity(b, k), lev, err);
    free(lev);
    return rc;
}
