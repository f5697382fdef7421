/* registry.c - the session registry: slots, ids, members, control, outboxes, housekeeping.
 *
 * A session slot (srec) holds the running sq_session, its members and its controller. Ids
 * are random generation << SLOT_BITS | slot (net_find_session refuses stale ones). The
 * outbox of a session thread is distributed to its members here (net_drain_session); the
 * 50 ms tick pushes stats, ends sessions empty past --grace and watches progress (/healthz).
 */
#include "net/server.h"
#include "net/haptic_ws.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/random.h>

/* ---------------------------------------------------------------- sessions */

srec *net_find_session(server *srv, uint64_t id)
{
    if (sq_session_id_local(id, srv->opt->instance, &id))
        return NULL;
    uint64_t idx = id & ((1u << SLOT_BITS) - 1), gen = id >> SLOT_BITS;
    if (idx >= (uint64_t)srv->nslots)
        return NULL;
    srec *r = &srv->slots[idx];
    return (r->s && r->gen == gen && gen) ? r : NULL;
}

/* a random session generation (the bits of mask, sq_session_gen_mask: ids stay below 2^49,
 * at most 15 decimal digits, which JSON and cJSON keep exact; not 0, not old): ids cannot be guessed from
 * one another */
uint64_t net_new_generation(uint64_t old, uint64_t mask)
{
    uint64_t g = 0;
    while (g == 0 || g == old) {
        if (getrandom(&g, sizeof g, 0) != (ssize_t)sizeof g) {
            /* no entropy source: fall back on time and address bits (guessable; logged) */
            lwsl_warn("squish: getrandom failed; session ids are less random\n");
            g = (uint64_t)(sq_now() * 1e9) ^ ((uint64_t)(uintptr_t)&g << 7) ^ old * 0x9e3779b97f4a7c15ull;
        }
        g &= mask;
    }
    return g;
}

/* session slots kept for token holders when the server has a token: a quarter, at least 1 */
int net_reserved_sessions(const server *srv)
{
    return srv->opt->token ? SQ_MAX(1, srv->opt->max_sessions / 4) : 0;
}

int net_sessions_opened_from(const server *srv, const char *addr)
{
    int n = 0;
    for (int i = 0; i < srv->nslots; i++)
        n += srv->slots[i].s != NULL && srv->slots[i].opener[0] && !strcmp(srv->slots[i].opener, addr);
    return n;
}

int net_live_sessions(const server *srv)
{
    int n = 0;
    for (int i = 0; i < srv->nslots; i++)
        n += srv->slots[i].s != NULL;
    return n;
}

void net_end_session(server *srv, srec *r)
{
    if (!r->s)
        return;
    if (srv->opt->verbose)
        fprintf(stderr, "squish serve: session %llu ends\n", (unsigned long long)r->s->id);
    pthread_mutex_lock(&r->s->mu);
    srv->frames_ended += r->s->snap.frame;
    srv->misses_ended += r->s->snap.deadline_misses;
    srv->resets_ended += r->s->snap.resets;
    for (int i = 0; i < r->s->nrefused; i++)
        net_count_refused_n(srv, r->s->refused[i].code, r->s->refused[i].n);
    pthread_mutex_unlock(&r->s->mu);
    for (int i = 0; i < r->nmembers; i++) {
        client *c = r->members[i];
        c->sess = NULL;
        c->ready = c->pending = 0;
        c->nodes_busy = c->nodes_deferred = 0;
        net_clear_slots(c);
    }
    free(r->members);
    r->members = NULL;
    r->nmembers = r->cap = 0;
    sq_session_stop(r->s);
    r->s = NULL;
    r->controller = 0;
}

/* a departing controller's tools go inactive: a tool job per tool it set, answered to its
 * own serial (no member has it any more, so the acks go nowhere) */
void net_release_tools(client *c, srec *r)
{
    for (int i = 0; i < c->ntool_ids; i++) {
        sq_request q;
        memset(&q, 0, sizeof q);
        q.type = SQ_REQ_TOOL;
        q.tool.id = c->tool_ids[i];
        q.tool.has_active = 1;
        q.tool.active = 0;
        sq_session_push_job(r->s, c->serial, &q);
    }
    c->ntool_ids = 0;
}

/* tell every client of r who controls it now (event "control"): sent on every change */
void net_control_event(srec *r, const char *reason)
{
    for (int i = 0; i < r->nmembers; i++) {
        client *m = r->members[i];
        if (!m->ready)
            continue; /* a client still joining learns its role from joined */
        cJSON *e = sq_reply_new("event", NULL);
        cJSON_AddStringToObject(e, "kind", "control");
        cJSON_AddNumberToObject(e, "session", r->s->id);
        cJSON_AddBoolToObject(e, "controller", r->controller != 0);
        cJSON_AddBoolToObject(e, "you", r->controller == m->serial);
        cJSON_AddStringToObject(e, "reason", reason);
        net_send_json(m, e);
    }
}

void net_leave_session(client *c)
{
    srec *r = c->sess;
    if (!r)
        return;
    /* its nodes requests are dropped: their replies would go nowhere */
    if (c->nodes_busy || c->nodes_deferred)
        sq_session_drop_jobs(r->s, c->serial, SQ_REQ_NODES);
    c->nodes_busy = c->nodes_deferred = 0;
    for (int i = 0; i < r->nmembers; i++)
        if (r->members[i] == c) {
            r->members[i] = r->members[--r->nmembers];
            break;
        }
    if (r->controller == c->serial) {
        r->controller = 0;
        net_release_tools(c, r);
        net_control_event(r, "left");
    }
    c->ntool_ids = 0;
    net_haptic_close_owner(r->s, c->serial);
    if (r->nmembers == 0) {
        /* nobody watches: the session keeps its state but stops stepping until someone
         * joins again or the grace period ends it */
        r->empty_since = sq_now();
        __atomic_store_n(&r->s->idle, 1, __ATOMIC_RELAXED);
    }
    c->sess = NULL;
    c->ready = c->pending = c->demoted = 0;
    net_clear_slots(c);
}

/* add c to r with the requested role; returns 0 or -1 after an error reply */
int net_add_member(client *c, srec *r, sq_role role)
{
    if (r->nmembers >= c->srv->opt->max_clients) {
        char m[160];
        snprintf(m, sizeof m, "session %llu already has %d clients (--max-clients); open another "
                 "session", (unsigned long long)r->s->id, r->nmembers);
        net_send_error(c, &c->pending_req, SQ_CODE_SESSION_FULL, m);
        return -1;
    }
    if (r->nmembers == r->cap) {
        r->cap = r->cap ? 2 * r->cap : 8;
        r->members = sq_realloc(r->members, sizeof *r->members * (size_t)r->cap);
    }
    r->members[r->nmembers++] = c;
    __atomic_store_n(&r->s->idle, 0, __ATOMIC_RELAXED);
    c->sess = r;
    c->demoted = 0;
    if (role == SQ_ROLE_CONTROL) {
        if (!r->controller)
            r->controller = c->serial;
        else
            c->demoted = 1;
    }
    c->sub_frames = 1;
    return 0;
}

/* topology, then opened/joined, then the newest frames */
void net_send_session_info(client *c)
{
    srec *r = c->sess;
    sq_session *s = r->s;
    const sq_request *req = &c->pending_req;
    cJSON *o = sq_reply_new(req->type == SQ_REQ_OPEN ? "opened" : "joined", req);
    pthread_mutex_lock(&s->mu);
    for (int b = 0; b < s->nbodies; b++)
        net_fifo_push(c, sq_blob_ref(s->topology[b]));
    cJSON_AddNumberToObject(o, "session", s->id);
    cJSON_AddStringToObject(o, "scene", s->scene_name);
    cJSON_AddStringToObject(o, "role", r->controller == c->serial ? "control" : "view");
    cJSON_AddBoolToObject(o, "demoted", c->demoted);
    cJSON_AddNumberToObject(o, "frame", (double)s->snap.frame);
    cJSON_AddNumberToObject(o, "time", s->snap.time);
    cJSON_AddNumberToObject(o, "frame_rate", 1.0 / s->period);
    cJSON_AddBoolToObject(o, "lockstep", s->lockstep);
    cJSON_AddBoolToObject(o, "paused", s->snap.paused);
    cJSON *bodies = cJSON_Parse(s->bodies_json ? s->bodies_json : "[]");
    cJSON_AddItemToObject(o, "bodies", bodies ? bodies : cJSON_CreateArray());
    cJSON_AddItemToObject(o, "tools", sq_tools_json(s->snap.tools, s->snap.ntools));
    cJSON_AddItemToObject(o, "obstacles", sq_obstacles_json(s->scene));
    sq_blob *last[SQ_MAX_BODIES] = {0};
    for (int b = 0; b < s->nbodies; b++)
        last[b] = sq_blob_ref(s->last_frame[b]);
    pthread_mutex_unlock(&s->mu);
    net_send_json(c, o);
    c->pending = 0;
    c->ready = 1;
    /* the newest frames; in lockstep mode in order with the stepped ones */
    for (int b = 0; b < SQ_MAX_BODIES; b++)
        if (last[b]) {
            if (!c->sub_frames)
                sq_blob_unref(last[b]);
            else if (c->srv->opt->lockstep)
                net_fifo_push(c, last[b]);
            else
                net_slot_put(c, b, last[b]);
        }
}

/* distribute one session's outbox */
void net_drain_session(server *srv, srec *r)
{
    int n;
    sq_out *outs = sq_session_take_outbox(r->s, &n);
    int failed = 0;
    for (int i = 0; i < n; i++) {
        sq_out *o = &outs[i];
        switch (o->kind) {
        case SQ_OUT_READY:
            for (int k = 0; k < r->nmembers; k++)
                if (r->members[k]->pending)
                    net_send_session_info(r->members[k]);
            break;
        case SQ_OUT_FAILED:
            failed = 1;
            for (int k = 0; k < r->nmembers; k++)
                net_send_error(r->members[k], &r->members[k]->pending_req, SQ_CODE_SCENE_FAILED,
                           r->s->fail_msg);
            break;
        case SQ_OUT_FRAME:
            for (int k = 0; k < r->nmembers; k++)
                if (r->members[k]->ready && r->members[k]->sub_frames)
                    net_slot_put(r->members[k], o->body, sq_blob_ref(o->blob));
            break;
        case SQ_OUT_STEP_FRAME:
            for (int k = 0; k < r->nmembers; k++)
                if (r->members[k]->ready && r->members[k]->sub_frames)
                    net_fifo_push(r->members[k], sq_blob_ref(o->blob));
            break;
        case SQ_OUT_NODES_DONE:
            for (int k = 0; k < r->nmembers; k++) {
                client *m = r->members[k];
                if (m->serial == o->client && m->nodes_busy == 1) {
                    m->nodes_busy = 2;
                    m->nodes_mark = m->pushed;
                    net_nodes_check(m);
                }
            }
            break;
        case SQ_OUT_TEXT:
        case SQ_OUT_BINARY:
            for (int k = 0; k < r->nmembers; k++)
                if (r->members[k]->ready && (!o->client || o->client == r->members[k]->serial))
                    net_fifo_push(r->members[k], sq_blob_ref(o->blob));
            break;
        }
        sq_blob_unref(o->blob);
    }
    free(outs);
    if (failed)
        net_end_session(srv, r);
}

/* ---------------------------------------------------------------- housekeeping */

void net_tick(lws_sorted_usec_list_t *sul)
{
    server *srv = lws_container_of(sul, server, sul);
    double now = sq_now();
    for (int i = 0; i < srv->nslots; i++) {
        srec *r = &srv->slots[i];
        if (!r->s)
            continue;
        net_drain_session(srv, r);
        if (!r->s)
            continue;
        {
            /* progress: a stepping session that finishes no frame for long is frozen */
            pthread_mutex_lock(&r->s->mu);
            long frame = r->s->snap.frame;
            int waiting = r->s->state != SQ_SESSION_READY || r->s->snap.paused || r->s->lockstep;
            pthread_mutex_unlock(&r->s->mu);
            if (waiting || frame != r->seen_frame || __atomic_load_n(&r->s->idle, __ATOMIC_RELAXED) ||
                !r->progress_at) {
                r->seen_frame = frame;
                r->progress_at = now;
            }
        }
        if (r->nmembers == 0) {
            if (!r->empty_since)
                r->empty_since = now;
            if (now - r->empty_since >= srv->opt->grace) {
                net_end_session(srv, r);
                continue;
            }
        }
        for (int k = 0; k < r->nmembers; k++) {
            client *c = r->members[k];
            if (!c->ready || !c->sub_stats || c->stats_queued || now < c->next_stats)
                continue;
            /* on a fixed grid (no drift from the 50 ms tick), restarted after a gap; a late
             * push delays the next one to at least half a period */
            double period = 1.0 / (c->stats_hz > 0 ? c->stats_hz : 4);
            c->next_stats = c->next_stats > 0 && now - c->next_stats < period
                            ? fmax(c->next_stats + period, now + 0.5 * period) : now + period;
            c->last_stats = now;
            sq_blob *b = sq_reply_blob(net_stats_json(srv, r, c, NULL));
            c->stats_queued = b;
            net_fifo_push(c, b);
        }
    }
    lws_sul_schedule(srv->ctx, 0, sul, net_tick, TICK_US);
}
