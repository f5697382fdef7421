/* session.c - a session's simulation thread: world, frame clock, jobs, frame encoding.
 *
 * The thread builds the world, then loops: sleep until the next frame time (real-time mode)
 * or until a job arrives (lockstep), apply the queued jobs in order, step one frame, encode
 * one frame message per body and post it to the outbox. Nothing here waits for a client.
 */
#include "net/session.h"

#include <cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

/* ---------------------------------------------------------------- JSON helpers */

cJSON *sq_reply_new(const char *type, const sq_request *req)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "type", type);
    if (req && req->ref_kind == SQ_REF_STRING)
        cJSON_AddStringToObject(o, "ref", req->ref_str);
    else if (req && req->ref_kind == SQ_REF_NUMBER)
        cJSON_AddNumberToObject(o, "ref", req->ref_num);
    else if (req && req->ref_kind == SQ_REF_NULL)
        cJSON_AddNullToObject(o, "ref");
    return o;
}

sq_blob *sq_reply_blob(cJSON *o)
{
    char *s = cJSON_PrintUnformatted(o);
    cJSON_Delete(o);
    if (!s)
        return sq_blob_text("{\"type\":\"error\",\"code\":\"internal\",\"message\":\"out of memory\"}");
    sq_blob *b = sq_blob_text(s);
    cJSON_free(s);
    return b;
}

sq_blob *sq_error_blob(const char *code, const char *message, const sq_request *req)
{
    /* messages quote client input, possibly cut in the middle of a UTF-8 sequence or not
     * UTF-8 at all: keep them ASCII so the text frame is always valid UTF-8 */
    char clean[512];
    size_t n = 0;
    for (const unsigned char *p = (const unsigned char *)message; *p && n < sizeof clean - 1; p++)
        clean[n++] = *p < 0x80 ? (char)*p : '?';
    clean[n] = 0;
    cJSON *o = sq_reply_new("error", req);
    cJSON_AddStringToObject(o, "code", code);
    cJSON_AddStringToObject(o, "message", clean);
    if (req && req->type != SQ_REQ_NONE)
        cJSON_AddStringToObject(o, "request", sq_req_name(req->type));
    return sq_reply_blob(o);
}

static cJSON *vec3(const double v[3])
{
    return cJSON_CreateDoubleArray(v, 3);
}

static const char *const shape_names[] = {"sphere", "box", "grab"};

cJSON *sq_tools_json(const sq_tool *tools, int ntools)
{
    cJSON *a = cJSON_CreateArray();
    for (int i = 0; i < ntools; i++) {
        const sq_tool *t = &tools[i];
        cJSON *o = cJSON_CreateObject();
        cJSON_AddNumberToObject(o, "id", t->id);
        cJSON_AddStringToObject(o, "shape", shape_names[(unsigned)t->shape % 3]);
        cJSON_AddBoolToObject(o, "active", t->active != 0);
        cJSON_AddItemToObject(o, "pos", vec3(t->pos));
        if (t->shape == SQ_TOOL_BOX) {
            double size[3] = {2 * t->half[0], 2 * t->half[1], 2 * t->half[2]};
            cJSON_AddItemToObject(o, "size", vec3(size));
        } else {
            cJSON_AddNumberToObject(o, "radius", t->radius);
        }
        cJSON_AddItemToArray(a, o);
    }
    return a;
}

/* settings of body bi, as in docs/protocol.md; levels numbered as listed in the scene file */
static cJSON *settings_json(const sq_world *w, int bi)
{
    const sq_body *b = w->bodies[bi];
    const sq_body_def *d = sq_body_get_def(b);
    double E = 0, nu = 0;
    sq_material_E_nu(&d->material, &E, &nu);
    cJSON *o = cJSON_CreateObject();
    cJSON *m = cJSON_AddObjectToObject(o, "material");
    cJSON_AddNumberToObject(m, "E", E);
    cJSON_AddNumberToObject(m, "nu", nu);
    cJSON_AddNumberToObject(m, "density", d->material.density);
    cJSON_AddNumberToObject(m, "mu", d->material.mu);
    cJSON_AddNumberToObject(m, "lambda", d->material.lambda);
    cJSON *dm = cJSON_AddObjectToObject(o, "damping");
    cJSON_AddNumberToObject(dm, "mass", d->material.rayleigh_mass);
    cJSON_AddNumberToObject(dm, "stiffness", d->material.rayleigh_stiffness);
    cJSON_AddStringToObject(o, "operator", d->op == SQ_OPERATOR_PAPER ? "paper" : "fem");
    cJSON_AddStringToObject(o, "elasticity", d->elasticity == SQ_ELASTICITY_COROTATIONAL ? "corotational" : "linear");
    cJSON_AddStringToObject(o, "pressure", d->nodal_pressure ? "nodal" : "element");
    cJSON *l = cJSON_AddObjectToObject(o, "lod");
    cJSON_AddStringToObject(l, "mode", d->lod.mode == SQ_LOD_ADAPTIVE ? "adaptive" : "fixed");
    cJSON_AddNumberToObject(l, "level", sq_world_listed_level(w, bi, d->lod.level));
    cJSON_AddNumberToObject(l, "split", d->lod.split);
    cJSON_AddNumberToObject(l, "merge", d->lod.merge);
    cJSON_AddNumberToObject(l, "max_level", sq_world_listed_level(w, bi, d->lod.max_level));
    cJSON_AddNumberToObject(l, "budget", d->lod.budget);
    cJSON *lv = cJSON_AddArrayToObject(o, "levels");
    for (int k = 0; k < sq_body_nlevels(b); k++) {
        cJSON *e = cJSON_CreateObject();
        cJSON_AddNumberToObject(e, "index", sq_world_listed_level(w, bi, k));
        cJSON_AddNumberToObject(e, "dt", sq_body_level_dt(b, k));
        cJSON_AddNumberToObject(e, "bound", sq_body_level_bound(b, k));
        cJSON_AddItemToArray(lv, e);
    }
    return o;
}

/* the scene's probes on body bi: name, nearest surface vertex (topology order), rest point */
static cJSON *probes_json(const sq_scene *sc, int bi, const sq_mesh *sm)
{
    cJSON *a = cJSON_CreateArray();
    for (int p = 0; p < sc->nprobes; p++) {
        const sq_probe *pr = &sc->probes[p];
        if (pr->body != bi)
            continue;
        int best = -1;
        double bd = INFINITY;
        for (int v = 0; v < sm->nsurf; v++) {
            const double *x = sm->x + 3 * (size_t)sm->surf_nodes[v];
            double d = 0;
            for (int k = 0; k < 3; k++)
                d += (x[k] - pr->point[k]) * (x[k] - pr->point[k]);
            if (d < bd) {
                bd = d;
                best = v;
            }
        }
        cJSON *e = cJSON_CreateObject();
        cJSON_AddStringToObject(e, "name", pr->name);
        cJSON_AddNumberToObject(e, "vertex", best);
        cJSON_AddItemToObject(e, "point", vec3(pr->point));
        cJSON_AddItemToArray(a, e);
    }
    return a;
}

/* the "bodies" array of opened/joined */
static char *bodies_json(const sq_session *s)
{
    const sq_world *w = s->world;
    cJSON *a = cJSON_CreateArray();
    for (int i = 0; i < w->nbodies; i++) {
        const sq_body *b = w->bodies[i];
        cJSON *o = cJSON_CreateObject();
        cJSON_AddNumberToObject(o, "id", i);
        cJSON_AddStringToObject(o, "name", s->scene->body_names[i]);
        cJSON *lv = cJSON_AddArrayToObject(o, "levels");
        for (int k = 0; k < sq_body_nlevels(b); k++) {
            const sq_mesh *m = sq_body_mesh(b, k);
            cJSON *e = cJSON_CreateObject();
            /* the level's number in the scene file: the one frames, stats and renders use */
            cJSON_AddNumberToObject(e, "index", sq_world_listed_level(w, i, k));
            cJSON_AddNumberToObject(e, "nodes", m->nnodes);
            cJSON_AddNumberToObject(e, "tets", m->ntets);
            cJSON_AddNumberToObject(e, "dt", sq_body_level_dt(b, k));
            cJSON_AddItemToArray(lv, e);
        }
        const sq_mesh *sm = sq_body_surface_mesh(b);
        cJSON *sf = cJSON_AddObjectToObject(o, "surface");
        cJSON_AddNumberToObject(sf, "vertices", sm->nsurf);
        cJSON_AddNumberToObject(sf, "triangles", sm->ntris);
        cJSON_AddNumberToObject(o, "listed_levels", s->scene->nlisted[i]);
        cJSON_AddItemToObject(o, "settings", settings_json(w, i));
        cJSON_AddItemToObject(o, "probes", probes_json(s->scene, i, sm));
        cJSON_AddItemToArray(a, o);
    }
    char *txt = cJSON_PrintUnformatted(a);
    cJSON_Delete(a);
    char *out = sq_strdup(txt ? txt : "[]");
    cJSON_free(txt);
    return out;
}

/* ---------------------------------------------------------------- queues */

/* append an outbox item (caller holds mu); realtime frames replace an unsent one */
static void post_locked(sq_session *s, sq_out_kind kind, uint64_t client, int body, sq_blob *blob)
{
    if (kind == SQ_OUT_FRAME)
        for (int i = 0; i < s->nouts; i++)
            if (s->outs[i].kind == SQ_OUT_FRAME && s->outs[i].body == body) {
                sq_blob_unref(s->outs[i].blob);
                s->outs[i].blob = blob;
                return;
            }
    if (s->nouts == s->cap_outs) {
        s->cap_outs = s->cap_outs ? 2 * s->cap_outs : 16;
        s->outs = sq_realloc(s->outs, sizeof *s->outs * (size_t)s->cap_outs);
    }
    s->outs[s->nouts++] = (sq_out){kind, client, body, blob};
}

static void post(sq_session *s, sq_out_kind kind, uint64_t client, int body, sq_blob *blob)
{
    pthread_mutex_lock(&s->mu);
    post_locked(s, kind, client, body, blob);
    pthread_mutex_unlock(&s->mu);
}

static void reply(sq_session *s, uint64_t client, cJSON *o)
{
    post(s, SQ_OUT_TEXT, client, 0, sq_reply_blob(o));
}

static void reply_error(sq_session *s, uint64_t client, const sq_request *req, const char *code,
                        const char *msg)
{
    sq_blob *b = sq_error_blob(code, msg, req);
    pthread_mutex_lock(&s->mu);
    /* counted by code for /metrics (code: a static string) */
    int i = 0;
    while (i < s->nrefused && strcmp(s->refused[i].code, code))
        i++;
    if (i < (int)(sizeof s->refused / sizeof s->refused[0])) {
        if (i == s->nrefused) {
            s->refused[i].code = code;
            s->refused[i].n = 0;
            s->nrefused++;
        }
        s->refused[i].n++;
    }
    post_locked(s, SQ_OUT_TEXT, client, 0, b);
    pthread_mutex_unlock(&s->mu);
}

void sq_session_push_job(sq_session *s, uint64_t client, const sq_request *req)
{
    pthread_mutex_lock(&s->mu);
    if (s->njobs == s->cap_jobs) {
        s->cap_jobs = s->cap_jobs ? 2 * s->cap_jobs : 16;
        s->jobs = sq_realloc(s->jobs, sizeof *s->jobs * (size_t)s->cap_jobs);
    }
    s->jobs[s->njobs].client = client;
    s->jobs[s->njobs].req = *req;
    s->jobs[s->njobs].snap = NULL;
    s->njobs++;
    /* a new tool id is known at once, so that a quick update of it passes the checks */
    if (req->type == SQ_REQ_TOOL && s->ntool_ids < SQ_MAX_TOOLS) {
        int known = 0;
        for (int i = 0; i < s->ntool_ids; i++)
            known |= s->tool_ids[i] == req->tool.id;
        if (!known)
            s->tool_ids[s->ntool_ids++] = req->tool.id;
    }
    pthread_cond_signal(&s->cv);
    pthread_mutex_unlock(&s->mu);
}

void sq_session_push_snapshot(sq_session *s, sq_snap_job *j)
{
    pthread_mutex_lock(&s->mu);
    if (s->njobs == s->cap_jobs) {
        s->cap_jobs = s->cap_jobs ? 2 * s->cap_jobs : 16;
        s->jobs = sq_realloc(s->jobs, sizeof *s->jobs * (size_t)s->cap_jobs);
    }
    memset(&s->jobs[s->njobs], 0, sizeof s->jobs[s->njobs]);
    s->jobs[s->njobs].snap = j;
    s->njobs++;
    pthread_cond_signal(&s->cv);
    pthread_mutex_unlock(&s->mu);
}

int sq_session_pending_jobs(sq_session *s, uint64_t client)
{
    int n = 0;
    pthread_mutex_lock(&s->mu);
    for (int i = 0; i < s->njobs; i++)
        n += s->jobs[i].client == client && !s->jobs[i].snap;
    pthread_mutex_unlock(&s->mu);
    return n;
}

void sq_session_drop_jobs(sq_session *s, uint64_t client, sq_req_type type)
{
    pthread_mutex_lock(&s->mu);
    int k = 0;
    for (int i = 0; i < s->njobs; i++)
        if (s->jobs[i].snap || s->jobs[i].client != client || s->jobs[i].req.type != type)
            s->jobs[k++] = s->jobs[i];
    s->njobs = k;
    pthread_mutex_unlock(&s->mu);
}

sq_out *sq_session_take_outbox(sq_session *s, int *n)
{
    pthread_mutex_lock(&s->mu);
    sq_out *o = s->outs;
    *n = s->nouts;
    s->outs = NULL;
    s->nouts = s->cap_outs = 0;
    pthread_mutex_unlock(&s->mu);
    return o;
}

/* ---------------------------------------------------------------- the simulation side */

/* copy what clients see (caller holds mu) */
static void snapshot_locked(sq_session *s, double frame_s)
{
    const sq_world *w = s->world;
    sq_snapshot *p = &s->snap;
    p->frame = w->frame;
    p->time = w->time;
    p->paused = s->paused;
    if (frame_s >= 0) {
        p->frame_s = frame_s;
        p->budget_used = frame_s / s->period;
    }
    p->deadline_misses = s->deadline_misses;
    p->overruns = w->deadline_misses;
    p->resets = w->resets;
    p->nbodies = w->nbodies;
    for (int b = 0; b < w->nbodies; b++) {
        const sq_frame_profile *f = &w->profile[b];
        p->nlevels[b] = sq_body_nlevels(w->bodies[b]);
        memcpy(p->active[b], f->active, sizeof p->active[b]);
        memcpy(p->substeps[b], f->substeps, sizeof p->substeps[b]);
        p->node_updates[b] = f->node_updates;
        p->sleeping[b] = sq_body_is_sleeping(w->bodies[b]);
        p->splits[b] = f->splits;
        p->merges[b] = f->merges;
        memcpy(p->feedback[b], w->feedback[b], sizeof p->feedback[b]);
        memcpy(p->health[b], sq_body_health(w->bodies[b]), sizeof p->health[b]);
    }
    p->ntools = w->ntools;
    memcpy(p->tools, w->tools, sizeof p->tools);
}

/* the tool ids requests are checked against: the world's tools plus those of tool jobs not
 * yet applied (caller holds mu) */
static void sync_tool_ids_locked(sq_session *s)
{
    const sq_world *w = s->world;
    s->ntool_ids = w->ntools;
    for (int i = 0; i < w->ntools; i++)
        s->tool_ids[i] = w->tools[i].id;
    for (int j = 0; j < s->njobs && s->ntool_ids < SQ_MAX_TOOLS; j++) {
        if (s->jobs[j].req.type != SQ_REQ_TOOL)
            continue;
        int known = 0;
        for (int i = 0; i < s->ntool_ids; i++)
            known |= s->tool_ids[i] == s->jobs[j].req.tool.id;
        if (!known)
            s->tool_ids[s->ntool_ids++] = s->jobs[j].req.tool.id;
    }
}

static void sync_tool_ids(sq_session *s)
{
    pthread_mutex_lock(&s->mu);
    sync_tool_ids_locked(s);
    pthread_mutex_unlock(&s->mu);
}

/* encode the current state of every body and post it (kind < 0: only keep it as the newest
 * frame, for clients that join) */
static void publish(sq_session *s, int kind, double frame_s)
{
    sq_world *w = s->world;
    sq_blob *frames[SQ_MAX_BODIES];
    for (int b = 0; b < w->nbodies; b++) {
        unsigned flags = w->profile[b].reset ? SQ_MSG_FLAG_RESET : 0;
        sq_world_surface_state(w, b, s->cur, s->lev); /* levels numbered as listed */
        frames[b] = sq_encode_frame(&s->codec[b], (uint32_t)b, (uint32_t)w->frame, w->time, flags,
                                    s->cur, s->lev, w->tools, w->feedback[b], w->ntools);
    }
    pthread_mutex_lock(&s->mu);
    for (int b = 0; b < w->nbodies; b++) {
        sq_blob_unref(s->last_frame[b]);
        s->last_frame[b] = sq_blob_ref(frames[b]);
        if (kind >= 0)
            post_locked(s, (sq_out_kind)kind, 0, b, frames[b]);
        else
            sq_blob_unref(frames[b]);
        if (w->profile[b].reset) {
            cJSON *e = sq_reply_new("event", NULL);
            cJSON_AddStringToObject(e, "kind", "reset");
            cJSON_AddNumberToObject(e, "session", s->id);
            cJSON_AddNumberToObject(e, "body", b);
            cJSON_AddNumberToObject(e, "frame", (double)w->frame);
            cJSON_AddStringToObject(e, "message", w->profile[b].event[0] ? w->profile[b].event
                                                                         : "numerical blow-up: body reset to rest");
            post_locked(s, SQ_OUT_TEXT, 0, 0, sq_reply_blob(e));
        }
    }
    snapshot_locked(s, frame_s);
    pthread_mutex_unlock(&s->mu);
}

/* one frame: step and publish */
static double budget_frac(sq_session *s)
{
    double f;
    __atomic_load(&s->budget.frac, &f, __ATOMIC_RELAXED);
    return f > 0 ? f : 1.0;
}

/* account a stepped frame of cpu seconds; a realtime session far over its budget pauses */
static void budget_account(sq_session *s, double cpu)
{
    if (__atomic_load_n(&s->stop, __ATOMIC_RELAXED))
        return; /* the frame was abandoned */
    const sq_world *w = s->world;
    double updates = 0;
    for (int b = 0; b < w->nbodies; b++)
        updates += (double)w->profile[b].node_updates;
    double frac = budget_frac(s);
    char msg[400];
    if (!sq_budget_frame(&s->budget, frac, s->period, cpu, updates, msg, sizeof msg) || s->lockstep)
        return;
    s->paused = 1;
    cJSON *e = sq_reply_new("event", NULL);
    cJSON_AddStringToObject(e, "kind", "over_budget");
    cJSON_AddNumberToObject(e, "session", s->id);
    cJSON_AddNumberToObject(e, "frame", (double)w->frame);
    cJSON_AddNumberToObject(e, "frame_ms", 1e3 * cpu);
    cJSON_AddNumberToObject(e, "budget_ms", 1e3 * frac * s->period);
    cJSON_AddStringToObject(e, "message", msg);
    post(s, SQ_OUT_TEXT, 0, 0, sq_reply_blob(e));
}

static void step_frame(sq_session *s, sq_out_kind kind)
{
    double t0 = sq_now(), c0 = sq_thread_cpu();
    sq_world_step(s->world, s->lockstep ? 0 : s->period);
    budget_account(s, sq_thread_cpu() - c0);
    publish(s, kind, sq_now() - t0);
}

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
            reply_error(s, j->client, r, "unknown_tool", msg);
            sync_tool_ids(s);
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
        reply_error(s, j->client, r, w->ntools >= SQ_MAX_TOOLS ? "too_many_tools" : "refused",
                    err.msg);
        sync_tool_ids(s);
        return;
    }
    sync_tool_ids(s); /* before the ack, so that the next update of this id passes */
    reply(s, j->client, ack("tool", r, w->frame + 1));
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
    int changed_mat = r->set.has_E || r->set.has_nu || r->set.has_density || r->set.has_operator ||
                      r->set.has_mass || r->set.has_stiffness;
    int changed_lod = r->set.has_mode || r->set.has_level || r->set.has_split || r->set.has_merge ||
                      r->set.has_max_level || r->set.has_budget;
    for (int b = b0; b < b1; b++) {
        sq_body *body = w->bodies[b];
        const sq_body_def *d = sq_body_get_def(body);
        old_m[b] = d->material;
        old_op[b] = d->op;
        old_lod[b] = d->lod;
        old_el[b] = d->elasticity;
        old_np[b] = d->nodal_pressure;
        sq_err err = {{0}};
        int rc = 0;
        /* pressure: element first, nodal last (it needs fem, linear and fixed lod) */
        if (r->set.has_pressure && !r->set.nodal_pressure)
            rc = sq_body_set_pressure(body, 0, &err);
        /* elasticity: linear before the other changes, corotational after them (it needs fem and
         * fixed lod, which this same request may set) */
        if (!rc && r->set.has_elasticity && r->set.elasticity == SQ_ELASTICITY_LINEAR)
            rc = sq_body_set_elasticity(body, SQ_ELASTICITY_LINEAR, &err);
        if (!rc && changed_mat) {
            sq_material m = d->material;
            if (r->set.has_E || r->set.has_nu) {
                double E, nu;
                sq_material_E_nu(&m, &E, &nu);
                if (r->set.has_E) E = r->set.E;
                if (r->set.has_nu) nu = r->set.nu;
                sq_material tmp = m;
                rc = sq_material_from_E_nu(&tmp, E, nu, &err);
                m.mu = tmp.mu;
                m.lambda = tmp.lambda;
            }
            if (r->set.has_density) m.density = r->set.density;
            if (r->set.has_mass) m.rayleigh_mass = r->set.mass;
            if (r->set.has_stiffness) m.rayleigh_stiffness = r->set.stiffness;
            if (!rc)
                rc = sq_body_set_material(body, &m, r->set.has_operator ? r->set.op : d->op, &err);
        }
        if (!rc && changed_lod) {
            sq_lod_def l = d->lod;
            if (r->set.has_mode) l.mode = r->set.mode;
            /* levels are given as listed in the scene file */
            if (r->set.has_level && (l.level = loaded_level(w, b, r->set.level, "level", err.msg,
                                                            sizeof err.msg)) < 0)
                rc = -1;
            if (r->set.has_split) l.split = r->set.split;
            if (r->set.has_merge) l.merge = r->set.merge;
            if (!rc && r->set.has_max_level &&
                (l.max_level = loaded_level(w, b, r->set.max_level, "max_level", err.msg, sizeof err.msg)) < 0)
                rc = -1;
            if (r->set.has_budget) l.budget = r->set.budget;
            if (!rc)
                rc = sq_body_set_lod(body, &l, &err);
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
        if (!rc && r->set.has_pressure && r->set.nodal_pressure && (rc = sq_body_set_pressure(body, 1, &err)) < 0) {
            if (r->set.has_elasticity && old_el[b] == SQ_ELASTICITY_LINEAR)
                sq_body_set_elasticity(body, old_el[b], NULL);
            if (changed_lod)
                sq_body_set_lod(body, &old_lod[b], NULL);
            if (changed_mat)
                sq_body_set_material(body, &old_m[b], old_op[b], NULL);
        }
        if (rc && r->set.has_elasticity)
            sq_body_set_elasticity(body, old_el[b], NULL);
        if (rc && r->set.has_pressure)
            sq_body_set_pressure(body, old_np[b], NULL);
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
                    sq_body_set_pressure(w->bodies[k], 1, NULL);
            }
            char msg[400];
            snprintf(msg, sizeof msg, "body %d (\"%.40s\"): %.260s", b, s->scene->body_names[b], err.msg);
            reply_error(s, j->client, r, "refused", msg);
            return;
        }
    }
    /* the compute budget: settings predictably over it are refused (docs/security.md) */
    sq_budget_prediction p;
    double frac = budget_frac(s);
    sq_budget_predict(&s->budget, w, s->period, &p);
    double budget = frac * s->period;
    if (p.seconds > budget) {
        for (int k = b0; k < b1; k++) {
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
        reply_error(s, j->client, r, "over_budget", msg);
        return;
    }
    cJSON *o = ack("set", r, w->frame + 1);
    cJSON *a = cJSON_AddArrayToObject(o, "bodies");
    for (int b = b0; b < b1; b++) {
        cJSON *e = cJSON_CreateObject();
        cJSON_AddNumberToObject(e, "id", b);
        cJSON_AddItemToObject(e, "settings", settings_json(w, b));
        cJSON_AddItemToArray(a, e);
    }
    char *bj = bodies_json(s);
    pthread_mutex_lock(&s->mu);
    free(s->bodies_json);
    s->bodies_json = bj;
    pthread_mutex_unlock(&s->mu);
    reply(s, j->client, o);
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
    post(s, SQ_OUT_BINARY, j->client, r->nodes.body, blob);
    cJSON *o = sq_reply_new("nodes", r);
    cJSON_AddNumberToObject(o, "body", r->nodes.body);
    cJSON_AddNumberToObject(o, "count", m->nnodes);
    cJSON_AddNumberToObject(o, "level", sq_world_listed_level(w, r->nodes.body, L));
    cJSON_AddNumberToObject(o, "frame", (double)w->frame);
    reply(s, j->client, o);
    post(s, SQ_OUT_NODES_DONE, j->client, 0, NULL);
}

/* apply one job; returns 1 if the visible state changed without a step */
static int do_job(sq_session *s, const sq_job *j)
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
        reply_error(s, j->client, r, "unknown_body", "body id out of range");
        if (r->type == SQ_REQ_NODES)
            post(s, SQ_OUT_NODES_DONE, j->client, 0, NULL);
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
        reply(s, j->client, ack(sq_req_name(r->type), r, w->frame));
        return 1;
    case SQ_REQ_RESET:
        if (r->reset.body < 0)
            sq_world_reset(w);
        else
            sq_body_reset(w->bodies[r->reset.body]);
        sync_tool_ids(s);
        reply(s, j->client, ack("reset", r, w->frame));
        return 1;
    case SQ_REQ_STEP: {
        /* a long step ends early when the server stops */
        for (int i = 0; i < r->step.frames && !__atomic_load_n(&s->stop, __ATOMIC_RELAXED); i++)
            step_frame(s, SQ_OUT_STEP_FRAME);
        cJSON *o = sq_reply_new("stepped", r);
        cJSON_AddNumberToObject(o, "frame", (double)w->frame);
        cJSON_AddNumberToObject(o, "time", w->time);
        cJSON_AddNumberToObject(o, "frames", r->step.frames);
        reply(s, j->client, o);
        return 0;
    }
    case SQ_REQ_NODES:
        do_nodes(s, j);
        return 0;
    default:
        reply_error(s, j->client, r, "internal", "request not handled by the session");
        return 0;
    }
}

static int setup(sq_session *s)
{
    sq_err err = {{0}};
    s->world = sq_world_create(s->scene, &err);
    if (!s->world) {
        pthread_mutex_lock(&s->mu);
        s->state = SQ_SESSION_FAILED;
        snprintf(s->fail_msg, sizeof s->fail_msg, "scene \"%.60s\": %.400s", s->scene_name, err.msg);
        post_locked(s, SQ_OUT_FAILED, 0, 0, NULL);
        pthread_mutex_unlock(&s->mu);
        s->wake(s->wake_arg);
        return -1;
    }
    sq_world *w = s->world;
    int maxs = 1;
    sq_blob *topo[SQ_MAX_BODIES];
    for (int b = 0; b < w->nbodies; b++) {
        const sq_mesh *m = sq_body_surface_mesh(w->bodies[b]);
        float *rest = sq_malloc(sizeof(float) * 3 * (size_t)(m->nsurf + 1));
        for (int i = 0; i < m->nsurf; i++)
            for (int k = 0; k < 3; k++)
                rest[3 * i + k] = (float)m->x[3 * m->surf_nodes[i] + k];
        sq_codec_init(&s->codec[b], m->nsurf, rest);
        s->codec[b].precision = (float)(s->precision * s->codec[b].diagonal);
        free(rest);
        topo[b] = sq_encode_topology(&s->codec[b], (uint32_t)b, 0, 0.0, m->surf_tris, m->ntris);
        maxs = SQ_MAX(maxs, m->nsurf);
    }
    s->cur = sq_malloc(sizeof(float) * 3 * (size_t)maxs);
    s->lev = sq_malloc((size_t)maxs);
    char *bj = bodies_json(s);
    pthread_mutex_lock(&s->mu);
    s->nbodies = w->nbodies;
    for (int b = 0; b < w->nbodies; b++)
        s->topology[b] = topo[b];
    s->bodies_json = bj;
    snapshot_locked(s, 0);
    sync_tool_ids_locked(s);
    s->state = SQ_SESSION_READY;
    post_locked(s, SQ_OUT_READY, 0, 0, NULL);
    pthread_mutex_unlock(&s->mu);
    publish(s, -1, 0); /* frame 0, sent to every client with opened/joined */
    s->wake(s->wake_arg);
    return 0;
}

/* put jobs not applied this frame back in front of the queue, in order */
static void requeue_front(sq_session *s, const sq_job *j, int m)
{
    pthread_mutex_lock(&s->mu);
    if (s->njobs + m > s->cap_jobs) {
        s->cap_jobs = SQ_MAX(s->njobs + m, 2 * s->cap_jobs);
        s->jobs = sq_realloc(s->jobs, sizeof *s->jobs * (size_t)s->cap_jobs);
    }
    memmove(s->jobs + m, s->jobs, sizeof *s->jobs * (size_t)s->njobs);
    memcpy(s->jobs, j, sizeof *j * (size_t)m);
    s->njobs += m;
    pthread_mutex_unlock(&s->mu);
}

static void *session_main(void *arg)
{
    sq_session *s = arg;
    sq_cancel_flag = &s->stop; /* a frame in progress is abandoned when the session stops */
    if (setup(s))
        return NULL;
    double next = sq_now() + s->period;
    sq_job *jobs = NULL;
    int cap = 0;
    pthread_mutex_lock(&s->mu);
    while (!s->stop) {
        if (s->lockstep) {
            while (!s->stop && s->njobs == 0)
                pthread_cond_wait(&s->cv, &s->mu);
        } else {
            /* sleep until the frame time; jobs wait for it (they take effect on a frame) */
            for (;;) {
                double now = sq_now();
                if (s->stop || now >= next)
                    break;
                struct timespec ts;
                clock_gettime(CLOCK_MONOTONIC, &ts);
                double wait = next - now;
                long sec = (long)wait;
                ts.tv_sec += sec;
                ts.tv_nsec += (long)((wait - (double)sec) * 1e9);
                if (ts.tv_nsec >= 1000000000L) {
                    ts.tv_sec++;
                    ts.tv_nsec -= 1000000000L;
                }
                pthread_cond_timedwait(&s->cv, &s->mu, &ts);
            }
        }
        if (s->stop)
            break;
        /* take the jobs queued so far */
        sq_job *tmp = s->jobs;
        int n = s->njobs;
        s->jobs = jobs;
        int tcap = s->cap_jobs;
        s->cap_jobs = cap;
        s->njobs = 0;
        jobs = tmp;
        cap = tcap;
        pthread_mutex_unlock(&s->mu);

        int changed = 0, done = 0;
        double jobs_t0 = sq_now();
        while (done < n) {
            changed |= do_job(s, &jobs[done++]);
            /* requests get at most part of a frame period per frame; the rest wait for the
             * next frame, so that a flood of costly ones (set) cannot freeze the clock */
            if (!s->lockstep && sq_now() - jobs_t0 > SQ_SESSION_JOB_SHARE * s->period)
                break;
        }
        if (done < n)
            requeue_front(s, jobs + done, n - done);
        double frame_start = next;
        int idle = __atomic_load_n(&s->idle, __ATOMIC_RELAXED);
        if (!s->lockstep && !s->paused && !idle)
            step_frame(s, SQ_OUT_FRAME);
        else if (changed && !s->lockstep)
            publish(s, SQ_OUT_FRAME, -1); /* paused: show tool moves, resets, settings */
        s->wake(s->wake_arg);

        if (!s->lockstep) {
            /* the frame must be done before the next frame time; when late, count a miss
             * and restart the clock from now (no burst of catch-up frames) */
            double end = sq_now();
            next = frame_start + s->period;
            if (end > next) {
                if (!s->paused && !idle)
                    s->deadline_misses++;
                next = end + s->period;
            }
        }
        pthread_mutex_lock(&s->mu);
    }
    pthread_mutex_unlock(&s->mu);
    free(jobs);
    return NULL;
}

sq_session *sq_session_start(const sq_scene *scene, const char *name, uint64_t id, int lockstep,
                             double precision, void (*wake)(void *), void *wake_arg)
{
    sq_session *s = sq_calloc(1, sizeof *s);
    s->id = id;
    s->scene = scene;
    snprintf(s->scene_name, sizeof s->scene_name, "%s", name);
    s->period = 1.0 / (scene->frame_rate > 0 ? scene->frame_rate : 50.0);
    s->lockstep = lockstep;
    s->precision = precision > 0 ? precision : SQ_CODEC_PRECISION;
    s->budget.frac = 1.0;
    s->wake = wake;
    s->wake_arg = wake_arg;
    pthread_mutex_init(&s->mu, NULL);
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&s->cv, &ca);
    pthread_condattr_destroy(&ca);
    if (pthread_create(&s->thread, NULL, session_main, s) == 0)
        s->thread_started = 1;
    else {
        s->state = SQ_SESSION_FAILED;
        snprintf(s->fail_msg, sizeof s->fail_msg, "cannot start a thread: %s", strerror(errno));
        post_locked(s, SQ_OUT_FAILED, 0, 0, NULL);
    }
    return s;
}

void sq_session_cancel(sq_session *s)
{
    pthread_mutex_lock(&s->mu);
    __atomic_store_n(&s->stop, 1, __ATOMIC_RELAXED);
    pthread_cond_broadcast(&s->cv);
    pthread_mutex_unlock(&s->mu);
}

void sq_session_stop(sq_session *s)
{
    if (!s)
        return;
    pthread_mutex_lock(&s->mu);
    __atomic_store_n(&s->stop, 1, __ATOMIC_RELAXED);
    pthread_cond_broadcast(&s->cv);
    pthread_mutex_unlock(&s->mu);
    if (s->thread_started)
        pthread_join(s->thread, NULL);
    for (int i = 0; i < s->nouts; i++)
        sq_blob_unref(s->outs[i].blob);
    free(s->outs);
    /* snapshot requests still queued get an answer */
    for (int i = 0; i < s->njobs; i++)
        if (s->jobs[i].snap) {
            snprintf(s->jobs[i].snap->error, sizeof s->jobs[i].snap->error, "the session ended");
            if (s->snapshotter)
                sq_snapshotter_submit(s->snapshotter, s->jobs[i].snap);
            else
                sq_snap_job_free(s->jobs[i].snap);
        }
    free(s->jobs);
    for (int b = 0; b < SQ_MAX_BODIES; b++) {
        sq_blob_unref(s->topology[b]);
        sq_blob_unref(s->last_frame[b]);
    }
    if (s->world)
        for (int b = 0; b < s->world->nbodies; b++)
            sq_codec_free(&s->codec[b]);
    sq_world_destroy(s->world);
    free(s->bodies_json);
    free(s->cur);
    free(s->lev);
    pthread_mutex_destroy(&s->mu);
    pthread_cond_destroy(&s->cv);
    free(s);
}
