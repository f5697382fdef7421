/* jobs.c - session jobs: the requests a session thread applies to its world.
 *
 * tool, set, pause, resume, reset, step, nodes and snapshot captures, in the order they were
 * queued, between frames (session.c runs them). Each answers its client through the outbox:
 * an ack, a reply, or an error with the refusal of the engine.
 */
#include "net/session.h"

#include <cJSON.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static cJSON *ack(const char *request, const sq_request *req, long frame)
{
    cJSON *o = sq_reply_new("ack", req);
    cJSON_AddStringToObject(o, "request", request);
    cJSON_AddNumberToObject(o, "frame", (double)frame);
    return o;
}

static void do_tool(sq_session *s, const sq_job *j)
{
    const sq_request *r = &j->req;
    sq_world *w = s->world;
    sq_tool t;
    int idx = -1;
    for (int i = 0; i < w->ntools; i++)
        if (w->tools[i].id == r->tool.id)
            idx = i;
    char msg[320];
    if (idx >= 0) {
        t = w->tools[idx];
    } else {
        if (!r->tool.has_shape || !r->tool.has_pos) {
            snprintf(msg, sizeof msg, "tool.id: %d is not a tool of this session; a new tool needs "
                     "shape and pos", r->tool.id);
            sq_session_reply_error(s, j->client, r, SQ_CODE_UNKNOWN_TOOL, msg);
            sq_session_sync_tool_ids(s);
            return;
        }
        memset(&t, 0, sizeof t);
        t.id = r->tool.id;
        t.radius = 0.05;
        t.half[0] = t.half[1] = t.half[2] = 0.05;
        t.active = 1;
    }
    if (r->tool.has_shape) t.shape = r->tool.shape;
    if (r->tool.has_pos) memcpy(t.pos, r->tool.pos, sizeof t.pos);
    if (r->tool.has_radius) t.radius = r->tool.radius;
    if (r->tool.has_size)
        for (int k = 0; k < 3; k++)
            t.half[k] = 0.5 * r->tool.size[k];
    if (r->tool.has_active) t.active = r->tool.active;
    sq_err err = {{0}};
    if (sq_world_set_tool(w, &t, &err)) {
        sq_session_reply_error(s, j->client, r, w->ntools >= SQ_MAX_TOOLS ? SQ_CODE_TOO_MANY_TOOLS : SQ_CODE_REFUSED,
                    err.msg);
        sq_session_sync_tool_ids(s);
        return;
    }
    sq_session_sync_tool_ids(s); /* before the ack, so that the next update of this id passes */
    sq_session_reply(s, j->client, ack("tool", r, w->frame + 1));
}

/* the loaded index of body b's level listed as `listed` in the scene file; -1 (and msg
 * naming the loaded ones) if the body did not load it */
static int loaded_level(const sq_world *w, int b, int listed, const char *key, char *msg, size_t cap)
{
    int nl = sq_body_nlevels(w->bodies[b]);
    for (int k = 0; k < nl; k++)
        if (sq_world_listed_level(w, b, k) == listed)
            return k;
    snprintf(msg, cap, "lod.%s: level %d is not loaded by this body (it loaded levels %d..%d of its "
             "scene file; a fixed body loads only its own); use one of those or list the body as adaptive "
             "in the scene", key, listed, sq_world_listed_level(w, b, 0), sq_world_listed_level(w, b, nl - 1));
    return -1;
}

/* set: body's material and operator with the request's changes merged into d's; 0 or -1 (err) */
static int set_material(sq_body *body, const sq_body_def *d, const sq_request *r, sq_err *err)
{
    int rc = 0;
    sq_material m = d->material;
    if (r->set.has_E || r->set.has_nu) {
        double E, nu;
        sq_material_E_nu(&m, &E, &nu);
        if (r->set.has_E) E = r->set.E;
        if (r->set.has_nu) nu = r->set.nu;
        sq_material tmp = m;
        rc = sq_material_from_E_nu(&tmp, E, nu, err);
        m.mu = tmp.mu;
        m.lambda = tmp.lambda;
    }
    if (r->set.has_density) m.density = r->set.density;
    if (r->set.has_mass) m.rayleigh_mass = r->set.mass;
    if (r->set.has_stiffness) m.rayleigh_stiffness = r->set.stiffness;
    if (!rc)
        rc = sq_body_set_material(body, &m, r->set.has_operator ? r->set.op : d->op, err);
    return rc;
}

/* set: body b's lod with the request's changes merged into d's (levels as listed in the scene
 * file); 0 or -1 (err) */
static int set_lod(sq_world *w, int b, const sq_body_def *d, const sq_request *r, sq_err *err)
{
    int rc = 0;
    sq_body *body = w->bodies[b];
    sq_lod_def l = d->lod;
    if (r->set.has_mode) l.mode = r->set.mode;
    if (r->set.has_level && (l.level = loaded_level(w, b, r->set.level, "level", err->msg,
                                                    sizeof err->msg)) < 0)
        rc = -1;
    if (r->set.has_split) l.split = r->set.split;
    if (r->set.has_merge) l.merge = r->set.merge;
    if (!rc && r->set.has_max_level &&
        (l.max_level = loaded_level(w, b, r->set.max_level, "max_level", err->msg, sizeof err->msg)) < 0)
        rc = -1;
    if (r->set.has_budget) l.budget = r->set.budget;
    if (r->set.has_adapt_every) l.adapt_every = r->set.adapt_every;
    if (!rc)
        rc = sq_body_set_lod(body, &l, err);
    return rc;
}

static void do_set(sq_session *s, const sq_job *j)
{
    const sq_request *r = &j->req;
    sq_world *w = s->world;
    int b0 = r->set.body < 0 ? 0 : r->set.body, b1 = r->set.body < 0 ? w->nbodies : r->set.body + 1;
    sq_material old_m[SQ_MAX_BODIES];
    sq_operator_kind old_op[SQ_MAX_BODIES];
    sq_lod_def old_lod[SQ_MAX_BODIES];
    sq_elasticity_kind old_el[SQ_MAX_BODIES];
    int old_np[SQ_MAX_BODIES];
    sq_integrator_kind old_in[SQ_MAX_BODIES];
    sq_implicit_def old_imp[SQ_MAX_BODIES];
    int changed_int = r->set.has_integrator || r->set.has_substeps || r->set.has_tol || r->set.has_max_iter ||
                      r->set.has_precond || r->set.has_newton;
    int changed_mat = r->set.has_E || r->set.has_nu || r->set.has_density || r->set.has_operator ||
                      r->set.has_mass || r->set.has_stiffness;
    int changed_lod = r->set.has_mode || r->set.has_level || r->set.has_split || r->set.has_merge ||
                      r->set.has_max_level || r->set.has_budget || r->set.has_adapt_every;
    for (int b = b0; b < b1; b++) {
        sq_body *body = w->bodies[b];
        const sq_body_def *d = sq_body_get_def(body);
        old_m[b] = d->material;
        old_op[b] = d->op;
        old_lod[b] = d->lod;
        old_el[b] = d->elasticity;
        old_np[b] = d->nodal_pressure;
        old_in[b] = d->integrator;
        old_imp[b] = d->implicit;
        sq_err err = {{0}};
        int rc = 0;
        /* integrator: the implicit settings merged into the body's; explicit first (before a
         * change to adaptive lod), implicit last (it needs fixed lod, which this request may set) */
        sq_implicit_def imp = d->implicit;
        if (r->set.has_substeps) imp.substeps = r->set.implicit.substeps;
        if (r->set.has_tol) imp.tol = r->set.implicit.tol;
        if (r->set.has_max_iter) imp.max_iter = r->set.implicit.max_iter;
        if (r->set.has_precond) imp.precond = r->set.implicit.precond;
        if (r->set.has_newton) imp.newton = r->set.implicit.newton;
        sq_integrator_kind ik = r->set.has_integrator ? r->set.integrator : d->integrator;
        if (changed_int && ik == SQ_INTEGRATOR_EXPLICIT)
            rc = sq_body_set_integrator(body, ik, &imp, &err);
        /* pressure: element first, nodal or smoothed last (they need fem, linear and fixed lod) */
        if (r->set.has_pressure && !r->set.nodal_pressure)
            rc = sq_body_set_pressure(body, 0, &err);
        /* elasticity: linear before the other changes, corotational after them (it needs fem and
         * fixed lod, which this same request may set) */
        if (!rc && r->set.has_elasticity && r->set.elasticity == SQ_ELASTICITY_LINEAR)
            rc = sq_body_set_elasticity(body, SQ_ELASTICITY_LINEAR, &err);
        if (!rc && changed_mat)
            rc = set_material(body, d, r, &err);
        if (!rc && changed_lod) {
            rc = set_lod(w, b, d, r, &err);
            if (rc && changed_mat) /* all or nothing for this body */
                sq_body_set_material(body, &old_m[b], old_op[b], NULL);
        }
        if (!rc && r->set.has_elasticity && r->set.elasticity == SQ_ELASTICITY_COROTATIONAL &&
            (rc = sq_body_set_elasticity(body, SQ_ELASTICITY_COROTATIONAL, &err)) < 0) {
            if (changed_lod) /* all or nothing for this body */
                sq_body_set_lod(body, &old_lod[b], NULL);
            if (changed_mat)
                sq_body_set_material(body, &old_m[b], old_op[b], NULL);
        }
        if (!rc && r->set.has_pressure && r->set.nodal_pressure &&
            (rc = sq_body_set_pressure(body, r->set.nodal_pressure, &err)) < 0) {
            if (r->set.has_elasticity && old_el[b] == SQ_ELASTICITY_LINEAR)
                sq_body_set_elasticity(body, old_el[b], NULL);
            if (changed_lod)
                sq_body_set_lod(body, &old_lod[b], NULL);
            if (changed_mat)
                sq_body_set_material(body, &old_m[b], old_op[b], NULL);
        }
        if (!rc && changed_int && ik == SQ_INTEGRATOR_IMPLICIT &&
            (rc = sq_body_set_integrator(body, ik, &imp, &err)) < 0) {
            if (changed_lod)
                sq_body_set_lod(body, &old_lod[b], NULL);
            if (changed_mat)
                sq_body_set_material(body, &old_m[b], old_op[b], NULL);
        }
        if (rc && r->set.has_elasticity)
            sq_body_set_elasticity(body, old_el[b], NULL);
        if (rc && r->set.has_pressure)
            sq_body_set_pressure(body, old_np[b], NULL);
        if (rc && changed_int) /* back as it was */
            sq_body_set_integrator(body, old_in[b], &old_imp[b], NULL);
        if (rc) {
            /* undo the bodies already changed, then refuse */
            for (int k = b0; k < b; k++) {
                if (r->set.has_pressure && !old_np[k])
                    sq_body_set_pressure(w->bodies[k], 0, NULL);
                if (r->set.has_elasticity && old_el[k] == SQ_ELASTICITY_LINEAR)
                    sq_body_set_elasticity(w->bodies[k], old_el[k], NULL);
                if (changed_lod)
                    sq_body_set_lod(w->bodies[k], &old_lod[k], NULL);
                if (changed_mat)
                    sq_body_set_material(w->bodies[k], &old_m[k], old_op[k], NULL);
                if (r->set.has_elasticity && old_el[k] == SQ_ELASTICITY_COROTATIONAL)
                    sq_body_set_elasticity(w->bodies[k], old_el[k], NULL);
                if (r->set.has_pressure && old_np[k])
                    sq_body_set_pressure(w->bodies[k], old_np[k], NULL);
                if (changed_int)
                    sq_body_set_integrator(w->bodies[k], old_in[k], &old_imp[k], NULL);
            }
            char msg[400];
            snprintf(msg, sizeof msg, "body %d (\"%.40s\"): %.260s", b, s->scene->body_names[b], err.msg);
            sq_session_reply_error(s, j->client, r, SQ_CODE_REFUSED, msg);
            return;
        }
    }
    /* the compute budget: settings predictably over it are refused (docs/security.md) */
    sq_budget_prediction p;
    double frac = sq_session_budget_frac(s);
    sq_budget_predict(&s->budget, w, s->period, &p);
    double budget = frac * s->period;
    if (p.seconds > budget) {
        for (int k = b0; k < b1; k++) {
            if (changed_int)
                sq_body_set_integrator(w->bodies[k], old_in[k], &old_imp[k], NULL);
            if (changed_lod)
                sq_body_set_lod(w->bodies[k], &old_lod[k], NULL);
            if (changed_mat)
                sq_body_set_material(w->bodies[k], &old_m[k], old_op[k], NULL);
        }
        char msg[480];
        snprintf(msg, sizeof msg, "predicted cost %.1f ms of CPU per frame (%.3g node updates; body "
                 "%d: %d substeps x %d nodes; %.3g us per node update) is over the frame budget "
                 "of %.1f ms (--frame-budget %.3g x the %.1f ms period); settings unchanged: use a "
                 "softer or denser material, less stiffness damping or a coarser level",
                 1e3 * p.seconds, p.updates, p.body, p.substeps, p.nodes,
                 1e6 * p.seconds / (p.updates > 0 ? p.updates : 1), 1e3 * budget,
                 frac, 1e3 * s->period);
        sq_session_reply_error(s, j->client, r, SQ_CODE_OVER_BUDGET, msg);
        return;
    }
    cJSON *o = ack("set", r, w->frame + 1);
    cJSON *a = cJSON_AddArrayToObject(o, "bodies");
    for (int b = b0; b < b1; b++) {
        cJSON *e = cJSON_CreateObject();
        cJSON_AddNumberToObject(e, "id", b);
        cJSON_AddItemToObject(e, "settings", sq_settings_json(w, b));
        cJSON_AddItemToArray(a, e);
    }
    char *bj = sq_bodies_json(s);
    pthread_mutex_lock(&s->mu);
    free(s->bodies_json);
    s->bodies_json = bj;
    pthread_mutex_unlock(&s->mu);
    sq_session_reply(s, j->client, o);
}

static void do_nodes(sq_session *s, const sq_job *j)
{
    const sq_request *r = &j->req;
    sq_world *w = s->world;
    const sq_body *b = w->bodies[r->nodes.body];
    const sq_body_def *d = sq_body_get_def(b);
    int nl = sq_body_nlevels(b);
    int fixed = d->lod.mode == SQ_LOD_FIXED || nl == 1;
    int L = sq_body_sim_level(b);
    const sq_mesh *m = sq_body_mesh(b, L);
    const double *u = sq_body_displacement(b, L);
    const unsigned char *nlev = fixed ? NULL : sq_body_node_level(b);
    float *xyz = sq_malloc(sizeof(float) * 3 * (size_t)m->nnodes);
    unsigned char *lev = sq_malloc((size_t)m->nnodes + 1);
    for (int i = 0; i < m->nnodes; i++) {
        for (int k = 0; k < 3; k++)
            xyz[3 * i + k] = (float)(m->x[3 * i + k] + (u ? u[3 * i + k] : 0));
        lev[i] = (unsigned char)sq_world_listed_level(w, r->nodes.body, nlev ? nlev[i] : L);
    }
    sq_blob *blob = sq_encode_nodes((uint32_t)r->nodes.body, (uint32_t)w->frame, w->time, xyz, lev,
                                    m->nnodes);
    free(xyz);
    free(lev);
    sq_session_post(s, SQ_OUT_BINARY, j->client, r->nodes.body, blob);
    cJSON *o = sq_reply_new("nodes", r);
    cJSON_AddNumberToObject(o, "body", r->nodes.body);
    cJSON_AddNumberToObject(o, "count", m->nnodes);
    cJSON_AddNumberToObject(o, "level", sq_world_listed_level(w, r->nodes.body, L));
    cJSON_AddNumberToObject(o, "frame", (double)w->frame);
    sq_session_reply(s, j->client, o);
    sq_session_post(s, SQ_OUT_NODES_DONE, j->client, 0, NULL);
}

/* apply one job; returns 1 if the visible state changed without a step */
int sq_session_do_job(sq_session *s, const sq_job *j)
{
    const sq_request *r = &j->req;
    sq_world *w = s->world;
    if (j->snap) {
        /* a cheap copy of what to draw; the worker renders it off this thread */
        sq_snap_job *sj = j->snap;
        sq_err err = {{0}};
        sj->state = sq_calloc(1, sizeof *sj->state);
        sq_render_state_init(sj->state);
        if (sq_render_state_capture(sj->state, w, &err)) {
            sq_render_state_free(sj->state);
            free(sj->state);
            sj->state = NULL;
            snprintf(sj->error, sizeof sj->error, "capture: %.200s", err.msg);
        }
        sq_snapshotter_submit(s->snapshotter, sj);
        return 0;
    }
    /* a client's view of the bodies may be stale: check ids again here */
    int body = r->type == SQ_REQ_SET ? r->set.body : r->type == SQ_REQ_RESET ? r->reset.body
             : r->type == SQ_REQ_NODES ? r->nodes.body : -1;
    if (body >= w->nbodies) {
        sq_session_reply_error(s, j->client, r, SQ_CODE_UNKNOWN_BODY, "body id out of range");
        if (r->type == SQ_REQ_NODES)
            sq_session_post(s, SQ_OUT_NODES_DONE, j->client, 0, NULL);
        return 0;
    }
    switch (r->type) {
    case SQ_REQ_TOOL:
        do_tool(s, j);
        return 1;
    case SQ_REQ_SET:
        do_set(s, j);
        return 1;
    case SQ_REQ_PAUSE:
    case SQ_REQ_RESUME:
        s->paused = r->type == SQ_REQ_PAUSE;
        sq_session_reply(s, j->client, ack(sq_req_name(r->type), r, w->frame));
        return 1;
    case SQ_REQ_RESET:
        if (r->reset.body < 0)
            sq_world_reset(w);
        else
            sq_body_reset(w->bodies[r->reset.body]);
        sq_session_sync_tool_ids(s);
        sq_session_reply(s, j->client, ack("reset", r, w->frame));
        return 1;
    case SQ_REQ_STEP: {
        /* a long step ends early when the server stops */
        for (int i = 0; i < r->step.frames && !__atomic_load_n(&s->stop, __ATOMIC_RELAXED); i++)
            sq_session_step_frame(s, SQ_OUT_STEP_FRAME);
        cJSON *o = sq_reply_new("stepped", r);
        cJSON_AddNumberToObject(o, "frame", (double)w->frame);
        cJSON_AddNumberToObject(o, "time", w->time);
        cJSON_AddNumberToObject(o, "frames", r->step.frames);
        sq_session_reply(s, j->client, o);
        return 0;
    }
    case SQ_REQ_NODES:
        do_nodes(s, j);
        return 0;
    default:
        sq_session_reply_error(s, j->client, r, SQ_CODE_INTERNAL, "request not handled by the session");
        return 0;
    }
}
