/* dispatch.c - request dispatch: one complete text message of a client, on the lws thread.
 *
 * Rate limit (token bucket), decode and state checks (request.c), then: hello, list_scenes,
 * open/join, leave, stats, subscribe, take_control and ping are answered here; tool, set,
 * pause, resume, reset, step and nodes become jobs of the client's session thread (jobs.c).
 */
#include "net/server.h"
#include "net/haptic_ws.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

static int token_matches(const server *srv, const char *t)
{
    const char *want = srv->opt->token;
    if (!want)
        return 1;
    size_t a = strlen(want), b = strlen(t);
    unsigned diff = (unsigned)(a != b);
    for (size_t i = 0; i < a; i++)
        diff |= (unsigned)(want[i] ^ (i < b ? t[i] : 0));
    return diff == 0;
}

static void do_open_or_join(client *c, const sq_request *req)
{
    server *srv = c->srv;
    char m[240];
    if (srv->stopping) {
        net_send_error(c, req, SQ_CODE_SHUTTING_DOWN, "the server is stopping; reconnect later");
        return;
    }
    srec *r = NULL;
    sq_role role = c->role;
    if (req->type == SQ_REQ_OPEN) {
        int sc = sq_scene_list_find(&srv->scenes, req->open.scene);
        if (sc < 0) {
            snprintf(m, sizeof m, "open.scene: no scene \"%.60s\"; list_scenes gives the names",
                     req->open.scene);
            net_send_error(c, req, SQ_CODE_UNKNOWN_SCENE, m);
            return;
        }
        /* a free slot (the one the client leaves may be reused) */
        net_leave_session(c);
        int idx = -1, limit = srv->opt->max_sessions - (c->token_ok ? 0 : net_reserved_sessions(srv));
        if (net_live_sessions(srv) < limit)
            for (int i = 0; i < srv->nslots && idx < 0; i++)
                if (!srv->slots[i].s)
                    idx = i;
        int mine = c->token_ok ? 0 : net_sessions_opened_from(srv, c->addr);
        if (idx >= 0 && srv->opt->max_sessions_per_addr > 0 && mine >= srv->opt->max_sessions_per_addr) {
            snprintf(m, sizeof m, "%d sessions opened from %s are running (--max-sessions-per-addr "
                     "%d); join one, or wait until an empty one ends (--grace)", mine, c->addr,
                     srv->opt->max_sessions_per_addr);
            net_send_error(c, req, SQ_CODE_SERVER_FULL, m);
            return;
        }
        if (idx < 0) {
            if (limit < srv->opt->max_sessions)
                snprintf(m, sizeof m, "%d sessions are running; the other %d of --max-sessions are "
                         "kept for clients with the control token (--token); join one or retry "
                         "later", net_live_sessions(srv), net_reserved_sessions(srv));
            else
                snprintf(m, sizeof m, "%d sessions are running (--max-sessions); join one or retry "
                         "later", net_live_sessions(srv));
            net_send_error(c, req, SQ_CODE_SERVER_FULL, m);
            return;
        }
        r = &srv->slots[idx];
        r->gen = net_new_generation(r->gen, sq_session_gen_mask(srv->opt->instance, SLOT_BITS));
        r->scene = sc;
        r->controller = 0;
        r->bytes_sent = 0;
        r->empty_since = 0;
        uint64_t id = sq_session_id_public(r->gen << SLOT_BITS | (uint64_t)idx, srv->opt->instance);
        r->s = sq_session_start(srv->scenes.scenes[sc], srv->scenes.names[sc], id, srv->opt->lockstep,
                                srv->opt->precision, net_wake, srv);
        r->s->snapshotter = srv->snapshotter;
        __atomic_store(&r->s->budget.frac, &srv->opt->frame_budget, __ATOMIC_RELAXED);
        r->last_snapshot = 0;
        snprintf(r->opener, sizeof r->opener, "%s", c->token_ok ? "" : c->addr);
        if (srv->opt->verbose)
            fprintf(stderr, "squish serve: session %llu opened (scene %s)\n",
                    (unsigned long long)id, srv->scenes.names[sc]);
    } else {
        r = net_find_session(srv, req->join.session);
        if (!r) {
            snprintf(m, sizeof m, "join.session: no session %llu (it ended, or never existed); open "
                     "a scene instead", (unsigned long long)req->join.session);
            net_send_error(c, req, SQ_CODE_UNKNOWN_SESSION, m);
            return;
        }
        if (req->join.has_role)
            role = req->join.role;
        if (role == SQ_ROLE_CONTROL && !c->token_ok) {
            net_send_error(c, req, SQ_CODE_BAD_TOKEN, "join.role: control needs the server's token; send it "
                       "in hello.token or join as \"view\"");
            return;
        }
        if (c->sess == r) {
            /* already here: answer again with the current state; the controller joining
             * as a viewer gives control up */
            if (role == SQ_ROLE_VIEW && r->controller == c->serial) {
                r->controller = 0;
                net_release_tools(c, r);
                net_control_event(r, "demoted");
            }
            c->pending_req = *req;
            net_send_session_info(c);
            return;
        }
        net_leave_session(c);
    }
    c->pending_req = *req;
    uint64_t had = r->controller;
    if (net_add_member(c, r, role)) {
        if (r->nmembers == 0 && !r->empty_since)
            r->empty_since = sq_now();
        return;
    }
    if (req->type == SQ_REQ_JOIN && r->controller != had)
        net_control_event(r, "taken"); /* a control client joined a session without one */
    c->pending = 1;
    pthread_mutex_lock(&r->s->mu);
    int state = r->s->state;
    pthread_mutex_unlock(&r->s->mu);
    if (state == SQ_SESSION_READY)
        net_send_session_info(c);
    /* STARTING: answered when the session posts READY; FAILED: by its FAILED item */
}

/* hello: the role, and the token when the server has one (guessing throttled per address) */
static void do_hello(client *c, const sq_request *req, double now)
{
    server *srv = c->srv;
    const sq_serve_options *opt = srv->opt;
    if (opt->token && req->hello.has_token) {
        /* token guessing is throttled per address */
        double wait = sq_guard_wait(srv->guard, c->addr, now);
        if (wait > 0) {
            char m[200];
            snprintf(m, sizeof m, "hello.token: %d wrong tokens from %s; wait %.0f s before "
                     "trying again", SQ_GUARD_FAILS, c->addr, ceil(wait));
            net_send_error(c, req, SQ_CODE_THROTTLED, m);
            return;
        }
        if (!token_matches(srv, req->hello.token))
            sq_guard_fail(srv->guard, c->addr, now);
    }
    if (req->hello.role == SQ_ROLE_CONTROL && opt->token &&
        (!req->hello.has_token || !token_matches(srv, req->hello.token))) {
        net_send_error(c, req, SQ_CODE_BAD_TOKEN, req->hello.has_token
                   ? "hello.token: wrong token for role control; ask the server's operator"
                   : "hello.token: the server needs a token for role control; send it or use "
                     "role \"view\"");
        return;
    }
    c->greeted = 1;
    c->role = req->hello.role;
    c->token_ok = !opt->token || (req->hello.has_token && token_matches(srv, req->hello.token));
    snprintf(c->name, sizeof c->name, "%s", req->hello.client);
    net_send_json(c, net_welcome_json(srv, c, req));
}

/* subscribe: stats pushes and frames on or off, the stats rate */
static void do_subscribe(client *c, const sq_request *req)
{
    srec *r = c->sess;
    /* the first push comes at once when stats are turned on; a subscribe that only
     * changes the rate (or repeats stats: true) keeps the schedule: next push one new
     * period after the last one, never an extra push */
    int was_on = c->sub_stats;
    if (req->subscribe.stats >= 0)
        c->sub_stats = req->subscribe.stats;
    if (req->subscribe.frames >= 0) {
        c->sub_frames = req->subscribe.frames;
        if (!c->sub_frames)
            net_clear_slots(c);
    }
    if (req->subscribe.has_hz)
        c->stats_hz = req->subscribe.stats_hz;
    if (!was_on)
        c->next_stats = 0;
    else if (c->last_stats > 0)
        c->next_stats = c->last_stats + 1.0 / c->stats_hz;
    cJSON *o = sq_reply_new("ack", req);
    cJSON_AddStringToObject(o, "request", "subscribe");
    long frame = 0;
    if (r) {
        pthread_mutex_lock(&r->s->mu);
        frame = r->s->snap.frame;
        pthread_mutex_unlock(&r->s->mu);
    }
    cJSON_AddNumberToObject(o, "frame", (double)frame);
    net_send_json(c, o);
}

/* take_control: this client becomes the session's controller (the token when needed) */
static void do_take_control(client *c, const sq_request *req)
{
    server *srv = c->srv;
    const sq_serve_options *opt = srv->opt;
    srec *r = c->sess;
    if (r->controller && r->controller != c->serial) {
        net_send_error(c, req, SQ_CODE_CONTROLLER_PRESENT, "take_control: another client controls "
                   "this session; wait for an event of kind \"control\" saying nobody does");
        return;
    }
    if (opt->token && !c->token_ok &&
        !(req->take_control.has_token && token_matches(srv, req->take_control.token))) {
        net_send_error(c, req, SQ_CODE_BAD_TOKEN, req->take_control.has_token
                   ? "take_control.token: wrong token; ask the server's operator"
                   : "take_control.token: the server needs a token for control; send it "
                     "here or in hello.token");
        return;
    }
    c->token_ok = 1;
    int changed = r->controller != c->serial;
    r->controller = c->serial;
    c->demoted = 0;
    cJSON *o = sq_reply_new("ack", req);
    cJSON_AddStringToObject(o, "request", "take_control");
    cJSON_AddStringToObject(o, "role", "control");
    pthread_mutex_lock(&r->s->mu);
    long frame = r->s->snap.frame;
    pthread_mutex_unlock(&r->s->mu);
    cJSON_AddNumberToObject(o, "frame", (double)frame);
    net_send_json(c, o);
    if (changed)
        net_control_event(r, "taken");
}

/* a request the session thread applies: queued (a client's nodes requests one at a time, at
 * most CLIENT_MAX_JOBS waiting per client) */
static void queue_job(client *c, const sq_request *req)
{
    srec *r = c->sess;
    if (req->type == SQ_REQ_TOOL) {
        /* remembered, to be released when this controller leaves */
        int known = 0;
        for (int i = 0; i < c->ntool_ids; i++)
            known |= c->tool_ids[i] == req->tool.id;
        if (!known && c->ntool_ids < SQ_MAX_TOOLS)
            c->tool_ids[c->ntool_ids++] = req->tool.id;
    }
    if (req->type == SQ_REQ_NODES && c->nodes_busy) {
        /* one nodes request runs at a time per client; the newest waits, older waiting
         * ones are answered as replaced */
        if (c->nodes_deferred)
            net_send_error(c, &c->nodes_req, SQ_CODE_SUPERSEDED, "nodes: replaced by a newer nodes "
                       "request of this client (one runs at a time; wait for the reply)");
        c->nodes_req = *req;
        c->nodes_deferred = 1;
        return;
    }
    if (sq_session_pending_jobs(r->s, c->serial) >= CLIENT_MAX_JOBS) {
        char m[200];
        snprintf(m, sizeof m, "%d requests of this client wait for session %llu; wait for "
                 "their replies before sending more", CLIENT_MAX_JOBS,
                 (unsigned long long)r->s->id);
        net_send_error(c, req, SQ_CODE_BUSY, m);
        return;
    }
    sq_session_push_job(r->s, c->serial, req);
    if (req->type == SQ_REQ_NODES)
        c->nodes_busy = 1;
}

void net_handle_request(client *c, const char *text, size_t len)
{
    server *srv = c->srv;
    const sq_serve_options *opt = srv->opt;
    sq_request req;
    sq_net_error err;

    /* rate limit: token bucket of `rate` tokens per second, burst `rate` */
    double now = sq_now();
    c->tokens = fmin(opt->rate, c->tokens + (now - c->last_refill) * opt->rate);
    c->last_refill = now;
    if (c->tokens < 1) {
        char m[160];
        if (sq_request_decode(text, len, (size_t)opt->max_message, &req, &err))
            memset(&req, 0, sizeof req);
        snprintf(m, sizeof m, "more than %g requests per second (--rate); slow down", opt->rate);
        net_send_error(c, &req, SQ_CODE_RATE_LIMITED, m);
        return;
    }
    c->tokens -= 1;

    if (net_haptic_request(c, text, len)) /* the haptic channel's own request (haptic_ws.c) */
        return;
    if (sq_request_decode(text, len, (size_t)opt->max_message, &req, &err)) {
        net_send_error(c, &req, sq_net_code_of(err.code), err.message);
        return;
    }
    srec *r = c->sess;
    sq_client_ctx ctx = {
        .greeted = c->greeted,
        .in_session = r != NULL && c->ready,
        .is_controller = r && r->controller == c->serial,
        .lockstep = opt->lockstep,
        .max_tools = SQ_MAX_TOOLS,
    };
    int ids[SQ_MAX_TOOLS];
    if (r && c->ready) {
        pthread_mutex_lock(&r->s->mu);
        ctx.nbodies = r->s->nbodies;
        ctx.ntools = r->s->ntool_ids;
        memcpy(ids, r->s->tool_ids, sizeof ids);
        pthread_mutex_unlock(&r->s->mu);
        ctx.tool_ids = ids;
    }
    if (sq_request_check(&req, &ctx, &err)) {
        net_send_error(c, &req, sq_net_code_of(err.code), err.message);
        return;
    }

    switch (req.type) {
    case SQ_REQ_HELLO:
        do_hello(c, &req, now);
        break;
    case SQ_REQ_LIST_SCENES:
        net_send_json(c, net_scenes_json(srv, &req));
        break;
    case SQ_REQ_OPEN:
    case SQ_REQ_JOIN:
        do_open_or_join(c, &req);
        break;
    case SQ_REQ_LEAVE: {
        cJSON *o = sq_reply_new("left", &req);
        cJSON_AddNumberToObject(o, "session", r->s->id);
        net_leave_session(c);
        net_send_json(c, o);
        break;
    }
    case SQ_REQ_STATS:
        net_send_json(c, net_stats_json(srv, r, c, &req));
        break;
    case SQ_REQ_SUBSCRIBE:
        do_subscribe(c, &req);
        break;
    case SQ_REQ_TAKE_CONTROL:
        do_take_control(c, &req);
        break;
    case SQ_REQ_PING: {
        cJSON *o = sq_reply_new("pong", &req);
        cJSON_AddNumberToObject(o, "t", req.ping.t);
        cJSON_AddNumberToObject(o, "server_time", now);
        net_send_json(c, o);
        break;
    }
    default:
        /* tool, set, pause, resume, reset, step, nodes: applied by the session thread */
        queue_job(c, &req);
        break;
    }
}
