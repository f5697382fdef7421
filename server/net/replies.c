/* replies.c - replies: the JSON builders of the protocol's text messages.
 *
 * Shared by both threads: a reply with its ref, error replies, the tools array, the bodies
 * array of opened/joined and a body's settings (session thread), then stats, welcome and
 * scenes (lws thread). Field by field as in docs/protocol.md.
 */
#include "net/server.h"
#include "net/haptic_ws.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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
    if (!s) {
        char oom[96];
        snprintf(oom, sizeof oom, "{\"type\":\"error\",\"code\":\"%s\",\"message\":\"out of memory\"}",
                 sq_net_code_name(SQ_CODE_INTERNAL));
        return sq_blob_text(oom);
    }
    sq_blob *b = sq_blob_text(s);
    cJSON_free(s);
    return b;
}

sq_blob *sq_error_blob(sq_net_code code, const char *message, const sq_request *req)
{
    /* messages quote client input, possibly cut in the middle of a UTF-8 sequence or not
     * UTF-8 at all: keep them ASCII so the text frame is always valid UTF-8 */
    char clean[512];
    size_t n = 0;
    for (const unsigned char *p = (const unsigned char *)message; *p && n < sizeof clean - 1; p++)
        clean[n++] = *p < 0x80 ? (char)*p : '?';
    clean[n] = 0;
    cJSON *o = sq_reply_new("error", req);
    cJSON_AddStringToObject(o, "code", sq_net_code_name(code));
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
cJSON *sq_settings_json(const sq_world *w, int bi)
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
    cJSON_AddStringToObject(o, "pressure", d->nodal_pressure == SQ_PRESSURE_SMOOTHED ? "smoothed"
                                            : d->nodal_pressure                      ? "nodal"
                                                                                     : "element");
    cJSON_AddStringToObject(o, "integrator", d->integrator == SQ_INTEGRATOR_IMPLICIT ? "implicit" : "explicit");
    cJSON *im = cJSON_AddObjectToObject(o, "implicit");
    cJSON_AddNumberToObject(im, "substeps", d->implicit.substeps);
    cJSON_AddNumberToObject(im, "cg_tolerance", d->implicit.tol);
    cJSON_AddNumberToObject(im, "cg_max_iterations", d->implicit.max_iter);
    cJSON_AddStringToObject(im, "preconditioner", d->implicit.precond == SQ_PRECOND_JACOBI      ? "jacobi"
                                                  : d->implicit.precond == SQ_PRECOND_MULTIGRID ? "multigrid"
                                                                                                : "block_jacobi");
    cJSON_AddNumberToObject(im, "newton_iterations", d->implicit.newton);
    cJSON *l = cJSON_AddObjectToObject(o, "lod");
    cJSON_AddStringToObject(l, "mode", d->lod.mode == SQ_LOD_ADAPTIVE ? "adaptive" : "fixed");
    cJSON_AddNumberToObject(l, "level", sq_world_listed_level(w, bi, d->lod.level));
    cJSON_AddNumberToObject(l, "split", d->lod.split);
    cJSON_AddNumberToObject(l, "merge", d->lod.merge);
    cJSON_AddNumberToObject(l, "max_level", sq_world_listed_level(w, bi, d->lod.max_level));
    cJSON_AddNumberToObject(l, "budget", d->lod.budget);
    cJSON_AddNumberToObject(l, "adapt_every", SQ_MAX(d->lod.adapt_every, 1));
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
char *sq_bodies_json(const sq_session *s)
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
        cJSON_AddItemToObject(o, "settings", sq_settings_json(w, i));
        cJSON_AddItemToObject(o, "probes", probes_json(s->scene, i, sm));
        cJSON_AddItemToArray(a, o);
    }
    char *txt = cJSON_PrintUnformatted(a);
    cJSON_Delete(a);
    char *out = sq_strdup(txt ? txt : "[]");
    cJSON_free(txt);
    return out;
}

cJSON *net_stats_json(server *srv, srec *r, client *c, const sq_request *req)
{
    sq_session *s = r->s;
    cJSON *o = sq_reply_new("stats", req);
    pthread_mutex_lock(&s->mu);
    const sq_snapshot *p = &s->snap;
    cJSON_AddNumberToObject(o, "session", s->id);
    cJSON_AddNumberToObject(o, "frame", (double)p->frame);
    cJSON_AddNumberToObject(o, "time", p->time);
    cJSON_AddNumberToObject(o, "frame_rate", 1.0 / s->period);
    cJSON_AddBoolToObject(o, "paused", p->paused);
    cJSON_AddNumberToObject(o, "budget_used", p->budget_used);
    cJSON_AddNumberToObject(o, "frame_ms", 1e3 * p->frame_s);
    cJSON_AddNumberToObject(o, "frame_cpu_ms", 1e3 * p->frame_cpu_s);
    cJSON_AddNumberToObject(o, "deadline_misses", (double)p->deadline_misses);
    cJSON_AddNumberToObject(o, "overruns", (double)p->overruns);
    cJSON_AddNumberToObject(o, "resets", (double)p->resets);
    /* per-level arrays are indexed by the level's number in the scene file (as the level
     * bytes of frames): zeros for levels a body did not load */
    int maxl = 0, sleeping = 0;
    int bact[SQ_MAX_BODIES][SQ_MAX_LEVELS] = {{0}}, bsub[SQ_MAX_BODIES][SQ_MAX_LEVELS] = {{0}};
    int blen[SQ_MAX_BODIES] = {0};
    double updates = 0, cg_it = 0, cg_res = 0;
    for (int b = 0; b < p->nbodies; b++) {
        for (int k = 0; k < p->nlevels[b]; k++) {
            int li = s->scene ? s->scene->level_index[b][k] : k;
            if (li < 0 || li >= SQ_MAX_LEVELS)
                continue;
            bact[b][li] = p->active[b][k];
            bsub[b][li] = p->substeps[b][k];
            blen[b] = SQ_MAX(blen[b], li + 1);
        }
        maxl = SQ_MAX(maxl, blen[b]);
        sleeping += p->sleeping[b] != 0;
        updates += (double)p->node_updates[b];
        cg_it += p->cg_iterations[b];
        cg_res = SQ_MAX(cg_res, p->cg_residual[b]);
    }
    double act[SQ_MAX_LEVELS] = {0};
    for (int b = 0; b < p->nbodies; b++)
        for (int l = 0; l < maxl; l++)
            act[l] += bact[b][l];
    cJSON_AddItemToObject(o, "active_nodes", cJSON_CreateDoubleArray(act, maxl));
    cJSON_AddNumberToObject(o, "node_updates", updates);
    cJSON_AddNumberToObject(o, "cg_iterations", cg_it);
    cJSON_AddNumberToObject(o, "cg_residual", cg_res);
    cJSON_AddNumberToObject(o, "sleeping", sleeping);
    cJSON *fb = cJSON_AddArrayToObject(o, "feedback");
    for (int b = 0; b < p->nbodies; b++)
        for (int t = 0; t < p->ntools; t++) {
            cJSON *e = cJSON_CreateObject();
            cJSON_AddNumberToObject(e, "tool", p->tools[t].id);
            cJSON_AddNumberToObject(e, "body", b);
            cJSON_AddItemToObject(e, "force", cJSON_CreateDoubleArray(p->feedback[b][t].force, 3));
            cJSON_AddNumberToObject(e, "nodes", p->feedback[b][t].nnodes);
            cJSON_AddItemToArray(fb, e);
        }
    cJSON_AddItemToObject(o, "tools", sq_tools_json(p->tools, p->ntools));
    cJSON_AddItemToObject(o, "obstacles", sq_obstacle_offsets_json(s->scene, (const double (*)[3])p->obstacle_pos,
                                                                   p->nobstacles));
    cJSON *ba = cJSON_AddArrayToObject(o, "bodies");
    for (int b = 0; b < p->nbodies; b++) {
        cJSON *e = cJSON_CreateObject();
        cJSON_AddNumberToObject(e, "id", b);
        cJSON_AddItemToObject(e, "active_nodes", cJSON_CreateIntArray(bact[b], blen[b]));
        cJSON_AddNumberToObject(e, "node_updates", (double)p->node_updates[b]);
        cJSON_AddNumberToObject(e, "cg_iterations", p->cg_iterations[b]);
        cJSON_AddNumberToObject(e, "cg_residual", p->cg_residual[b]);
        cJSON_AddItemToObject(e, "substeps", cJSON_CreateIntArray(bsub[b], blen[b]));
        cJSON_AddBoolToObject(e, "sleeping", p->sleeping[b]);
        cJSON_AddNumberToObject(e, "splits", p->splits[b]);
        cJSON_AddNumberToObject(e, "merges", p->merges[b]);
        /* contact: the sum of the body's contact forces over the last frame (obstacles and
         * other bodies), the nodes in contact, the deepest penetration into an obstacle */
        cJSON *ct = cJSON_AddObjectToObject(e, "contact");
        cJSON_AddItemToObject(ct, "force", cJSON_CreateDoubleArray(p->contact_force[b], 3));
        cJSON_AddNumberToObject(ct, "nodes", p->contact_nodes[b]);
        cJSON_AddNumberToObject(ct, "depth", p->contact_depth[b]);
        /* health warnings since the body was created, by kind (only kinds that occurred) */
        cJSON *hw = cJSON_AddObjectToObject(e, "health");
        for (int k = SQ_HEALTH_NONE + 1; k < SQ_HEALTH_NKINDS; k++)
            if (p->health[b][k].count > 0) {
                cJSON *hk = cJSON_AddObjectToObject(hw, sq_health_kind_name((sq_health_kind)k));
                cJSON_AddNumberToObject(hk, "count", (double)p->health[b][k].count);
                cJSON_AddNumberToObject(hk, "last_value", p->health[b][k].last_value);
                cJSON_AddNumberToObject(hk, "last_frame", (double)p->health[b][k].last_frame);
            }
        cJSON_AddItemToArray(ba, e);
    }
    pthread_mutex_unlock(&s->mu);
    (void)srv;
    cJSON_AddNumberToObject(o, "clients", r->nmembers);
    cJSON_AddNumberToObject(o, "viewers", r->nmembers - (r->controller ? 1 : 0));
    cJSON_AddBoolToObject(o, "controller", r->controller != 0);
    cJSON_AddNumberToObject(o, "bytes_sent", (double)r->bytes_sent);
    cJSON_AddNumberToObject(o, "skipped", (double)c->skipped);
    cJSON_AddItemToObject(o, "haptic", net_haptic_stats_json(s));
    return o;
}

cJSON *net_welcome_json(server *srv, client *c, const sq_request *req)
{
    const sq_serve_options *opt = srv->opt;
    cJSON *o = sq_reply_new("welcome", req);
    cJSON_AddNumberToObject(o, "version", SQ_PROTOCOL_VERSION);
    cJSON_AddStringToObject(o, "server", SQ_SERVER_NAME);
    cJSON_AddStringToObject(o, "role", c->role == SQ_ROLE_CONTROL ? "control" : "view");
    cJSON *sc = cJSON_AddArrayToObject(o, "scenes");
    for (int i = 0; i < srv->scenes.n; i++)
        cJSON_AddItemToArray(sc, cJSON_CreateString(srv->scenes.names[i]));
    cJSON_AddBoolToObject(o, "lockstep", opt->lockstep);
    cJSON *l = cJSON_AddObjectToObject(o, "limits");
    cJSON_AddNumberToObject(l, "max_sessions", opt->max_sessions);
    cJSON_AddNumberToObject(l, "max_clients", opt->max_clients);
    cJSON_AddNumberToObject(l, "max_message", opt->max_message);
    cJSON_AddNumberToObject(l, "rate", opt->rate);
    cJSON_AddNumberToObject(l, "grace", opt->grace);
    cJSON_AddNumberToObject(l, "max_step", SQ_NET_MAX_STEP);
    return o;
}

cJSON *net_scenes_json(server *srv, const sq_request *req)
{
    cJSON *o = sq_reply_new("scenes", req);
    cJSON *a = cJSON_AddArrayToObject(o, "scenes");
    for (int i = 0; i < srv->scenes.n; i++) {
        const sq_scene *sc = srv->scenes.scenes[i];
        cJSON *e = cJSON_CreateObject();
        cJSON_AddStringToObject(e, "name", srv->scenes.names[i]);
        cJSON_AddStringToObject(e, "description", sc->description);
        cJSON *b = cJSON_AddArrayToObject(e, "bodies");
        cJSON *lv = cJSON_AddArrayToObject(e, "levels");
        for (int k = 0; k < sc->nbodies; k++) {
            cJSON_AddItemToArray(b, cJSON_CreateString(sc->body_names[k]));
            cJSON_AddItemToArray(lv, cJSON_CreateNumber(sc->bodies[k].nlevels));
        }
        cJSON_AddNumberToObject(e, "frame_rate", sc->frame_rate);
        cJSON_AddItemToArray(a, e);
    }
    return o;
}
