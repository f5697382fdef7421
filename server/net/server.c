/* server.c - the libwebsockets service: HTTP files, /ws, clients, sessions, limits.
 *
 * One lws service thread does all I/O. Sessions run on their own threads (session.c) and
 * hand frames over through their outbox plus lws_cancel_service(); this thread distributes
 * them: a realtime frame goes into a one-slot-per-body mailbox of each client (a newer frame
 * replaces an unsent one: the client skips it, counted), everything else into the client's
 * bounded FIFO. Writes happen only in SERVER_WRITEABLE, one message per callback.
 */
#include "net/limits.h"
#include "net/metrics.h"
#include "net/session.h"
#include "net/query.h"

#include <arpa/inet.h>
#include <cJSON.h>
#include <dirent.h>
#include <libwebsockets.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <sys/random.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <stdlib.h>
#include <string.h>

_Static_assert(LWS_PRE <= SQ_BLOB_PRE, "blob headroom must hold LWS_PRE");

#define FIFO_MAX 4096            /* queued messages per client before it is dropped */
#define FIFO_MAX_BYTES (32u << 20) /* queued bytes per client before it is dropped */
#define CLIENT_MAX_JOBS 64       /* requests of one client waiting for its session thread */
#define SLOT_BITS 10             /* session id = generation << SLOT_BITS | slot */
#define TICK_US 50000            /* housekeeping period (stats pushes, grace), us */
#define SNDBUF_BYTES (128 << 10) /* kernel send buffer per client: bounds how stale a slow
                                    client's frames get (the kernel doubles it) */

struct server;
struct srec;

/* one WebSocket connection (lws thread only) */
typedef struct client {
    uint64_t serial;
    struct lws *wsi;
    struct server *srv;
    int greeted, token_ok;
    sq_role role;
    char name[SQ_NET_NAME_MAX];
    struct srec *sess;               /* session, or NULL */
    int ready;                       /* topology sent: receives frames */
    int pending;                     /* waiting for the session to start */
    sq_request pending_req;          /* the open/join to answer */
    int demoted;
    int sub_frames, sub_stats;
    double stats_hz, next_stats, last_stats;
    sq_blob *stats_queued;           /* a stats push not yet written */
    double tokens, last_refill;      /* rate limit */
    char *rx;                        /* message being assembled */
    size_t rx_len, rx_cap;
    int rx_oversize, rx_binary;
    sq_blob *slot[SQ_MAX_BODIES];    /* newest unsent realtime frame per body */
    sq_blob **fifo;                  /* ring of queued messages */
    int fhead, fcount, fcap;
    size_t fbytes;                   /* bytes queued in the ring */
    long skipped;
    int closing;
    int tool_ids[SQ_MAX_TOOLS];      /* tools this client set as controller of its session */
    int ntool_ids;
    /* nodes: one request at a time per client, the newest waiting (docs/security.md) */
    int nodes_busy;                  /* 1: job queued or running; 2: reply in the FIFO; 0 */
    int nodes_deferred;              /* nodes_req waits for the current one */
    sq_request nodes_req;
    uint64_t pushed, written;        /* FIFO messages queued / written so far */
    uint64_t nodes_mark;             /* `pushed` when the whole nodes reply was queued */
    char addr[SQ_ADDR_MAX];          /* peer address */
} client;

/* per-connection data lws allocates: a WebSocket client, or a waiting snapshot request */
typedef struct conn {
    client *c;
} conn;

/* a snapshot request waiting for its PNG (lws thread only) */
typedef struct snap_wait {
    uint64_t id;
    struct lws *wsi;                 /* NULL once the HTTP connection closed */
    sq_snap_job *result;             /* set when rendered */
    struct snap_wait *next;
} snap_wait;

#define SNAP_MIN_INTERVAL 0.25       /* s between snapshots of one session */
#define SNAP_MAX_WAITING 8           /* snapshot requests waiting, server-wide */
#define SNAP_TIMEOUT_S 60            /* s a snapshot request may wait for its PNG */

/* the server's record of a session (lws thread only, except s) */
typedef struct srec {
    sq_session *s;                   /* NULL: free slot */
    uint64_t gen;                    /* random, never 0, new at every open */
    int scene;
    client **members;
    int nmembers, cap;
    uint64_t controller;             /* serial of the controller, 0 = none */
    double empty_since;
    uint64_t bytes_sent;
    double last_snapshot;            /* when the last snapshot was asked for */
    long seen_frame;                 /* frame number at progress_at */
    double progress_at;              /* when the session last finished a frame (or had no
                                        reason to: paused, idle, starting) */
} srec;

typedef struct server {
    const sq_serve_options *opt;
    struct lws_context *ctx;
    struct lws_vhost *vhost;
    int nscenes;
    sq_scene **scenes;
    char (*names)[SQ_NET_NAME_MAX];
    srec *slots;
    int nslots;
    uint64_t next_serial;
    lws_sorted_usec_list_t sul;
    int stopping;
    sq_snapshotter *snapshotter;
    snap_wait *waits;
    int nwaits;
    uint64_t next_snap;
    sq_conns *conns;                 /* open connections per address (limits.c) */
    sq_guard *guard;                 /* wrong tokens per address */
    /* counters for /metrics */
    uint64_t bytes_out;              /* WebSocket message bytes written */
    long frames_ended, misses_ended, resets_ended; /* of sessions that ended */
    int nrefused;
    struct { const char *code; long n; } refused[48]; /* error replies and HTTP statuses */
} server;

#define MAX_URI 2048                 /* longer request paths get 414 */
#define HEADER_BYTES 16384           /* lws header space per request (longer: closed) */
#define FROZEN_MIN_S 2.0             /* a session is frozen after max(2 s, 50 periods) */
#define FROZEN_PERIODS 50

/* count n refused requests of a code (a protocol error code or an HTTP status) */
static void count_refused_n(server *srv, const char *code, long n)
{
    for (int i = 0; i < srv->nrefused; i++)
        if (!strcmp(srv->refused[i].code, code)) {
            srv->refused[i].n += n;
            return;
        }
    if (srv->nrefused < (int)(sizeof srv->refused / sizeof srv->refused[0])) {
        srv->refused[srv->nrefused].code = code;
        srv->refused[srv->nrefused++].n = n;
    }
}

static void count_refused(server *srv, const char *code)
{
    count_refused_n(srv, code, 1);
}

static volatile sig_atomic_t interrupted; /* set by SIGINT/SIGTERM */

static void on_signal(int sig)
{
    (void)sig;
    interrupted = 1;
}

static void wake(void *arg)
{
    server *srv = arg;
    if (srv->ctx)
        lws_cancel_service(srv->ctx);
}

/* ---------------------------------------------------------------- sending */

static void fifo_push(client *c, sq_blob *b)
{
    if (c->closing) {
        sq_blob_unref(b);
        return;
    }
    if (c->fcount >= FIFO_MAX || c->fbytes + b->len > FIFO_MAX_BYTES) {
        /* a client that stops reading while asking for more: drop it */
        lwsl_warn("squish: client %llu does not read; closing it\n", (unsigned long long)c->serial);
        sq_blob_unref(b);
        c->closing = 1;
        lws_callback_on_writable(c->wsi);
        return;
    }
    if (c->fcount == c->fcap) {
        int ncap = c->fcap ? 2 * c->fcap : 16;
        sq_blob **n = sq_malloc(sizeof *n * (size_t)ncap);
        for (int i = 0; i < c->fcount; i++)
            n[i] = c->fifo[(c->fhead + i) % c->fcap];
        free(c->fifo);
        c->fifo = n;
        c->fhead = 0;
        c->fcap = ncap;
    }
    c->fifo[(c->fhead + c->fcount) % c->fcap] = b;
    c->fcount++;
    c->pushed++;
    c->fbytes += b->len;
    lws_callback_on_writable(c->wsi);
}

static void send_json(client *c, cJSON *o)
{
    fifo_push(c, sq_reply_blob(o));
}

static void send_error(client *c, const sq_request *req, const char *code, const char *msg)
{
    count_refused(c->srv, code);
    fifo_push(c, sq_error_blob(code, msg, req));
}

/* a realtime frame: latest wins */
static void slot_put(client *c, int body, sq_blob *b)
{
    if (body < 0 || body >= SQ_MAX_BODIES || c->closing) {
        sq_blob_unref(b);
        return;
    }
    if (c->slot[body]) {
        sq_blob_unref(c->slot[body]);
        c->skipped++;
    }
    c->slot[body] = b;
    lws_callback_on_writable(c->wsi);
}

static void clear_slots(client *c)
{
    for (int b = 0; b < SQ_MAX_BODIES; b++) {
        sq_blob_unref(c->slot[b]);
        c->slot[b] = NULL;
    }
}

/* the client's nodes reply is written: run its waiting nodes request, if any. A client
 * that does not read its replies thus never has more than one nodes job and one nodes
 * message on the server. */
static void nodes_check(client *c)
{
    if (c->nodes_busy != 2 || c->written < c->nodes_mark)
        return;
    c->nodes_busy = 0;
    if (c->nodes_deferred && c->sess && c->ready && !c->closing) {
        c->nodes_deferred = 0;
        c->nodes_busy = 1;
        sq_session_push_job(c->sess->s, c->serial, &c->nodes_req);
    }
}

/* write one queued message; -1 closes the connection */
static int write_one(client *c)
{
    if (c->closing)
        return -1;
    sq_blob *b = NULL;
    if (c->fcount) {
        b = c->fifo[c->fhead];
        c->fhead = (c->fhead + 1) % c->fcap;
        c->fcount--;
        c->written++;
        c->fbytes -= b->len;
    } else {
        /* then the newest frame of each body, in body order */
        int best = -1;
        for (int i = 0; i < SQ_MAX_BODIES; i++)
            if (c->slot[i] && best < 0)
                best = i;
        if (best >= 0) {
            b = c->slot[best];
            c->slot[best] = NULL;
        }
    }
    if (!b)
        return 0;
    if (b == c->stats_queued)
        c->stats_queued = NULL;
    int n = lws_write(c->wsi, b->msg, b->len, b->binary ? LWS_WRITE_BINARY : LWS_WRITE_TEXT);
    if (c->sess)
        c->sess->bytes_sent += b->len;
    c->srv->bytes_out += b->len;
    size_t len = b->len;
    sq_blob_unref(b);
    if (n < (int)len)
        return -1;
    nodes_check(c);
    int more = c->fcount > 0;
    for (int i = 0; i < SQ_MAX_BODIES && !more; i++)
        more = c->slot[i] != NULL;
    if (more)
        lws_callback_on_writable(c->wsi);
    return 0;
}

/* ---------------------------------------------------------------- sessions */

static srec *find_session(server *srv, uint64_t id)
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
static uint64_t new_generation(uint64_t old, uint64_t mask)
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
static int reserved_sessions(const server *srv)
{
    return srv->opt->token ? SQ_MAX(1, srv->opt->max_sessions / 4) : 0;
}

static int live_sessions(const server *srv)
{
    int n = 0;
    for (int i = 0; i < srv->nslots; i++)
        n += srv->slots[i].s != NULL;
    return n;
}

static void end_session(server *srv, srec *r)
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
        count_refused_n(srv, r->s->refused[i].code, r->s->refused[i].n);
    pthread_mutex_unlock(&r->s->mu);
    for (int i = 0; i < r->nmembers; i++) {
        client *c = r->members[i];
        c->sess = NULL;
        c->ready = c->pending = 0;
        c->nodes_busy = c->nodes_deferred = 0;
        clear_slots(c);
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
static void release_tools(client *c, srec *r)
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
static void control_event(srec *r, const char *reason)
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
        send_json(m, e);
    }
}

static void leave_session(client *c)
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
        release_tools(c, r);
        control_event(r, "left");
    }
    c->ntool_ids = 0;
    if (r->nmembers == 0) {
        /* nobody watches: the session keeps its state but stops stepping until someone
         * joins again or the grace period ends it */
        r->empty_since = sq_now();
        __atomic_store_n(&r->s->idle, 1, __ATOMIC_RELAXED);
    }
    c->sess = NULL;
    c->ready = c->pending = c->demoted = 0;
    clear_slots(c);
}

/* add c to r with the requested role; returns 0 or -1 after an error reply */
static int add_member(client *c, srec *r, sq_role role)
{
    if (r->nmembers >= c->srv->opt->max_clients) {
        char m[160];
        snprintf(m, sizeof m, "session %llu already has %d clients (--max-clients); open another "
                 "session", (unsigned long long)r->s->id, r->nmembers);
        send_error(c, &c->pending_req, "session_full", m);
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
static void send_session_info(client *c)
{
    srec *r = c->sess;
    sq_session *s = r->s;
    const sq_request *req = &c->pending_req;
    cJSON *o = sq_reply_new(req->type == SQ_REQ_OPEN ? "opened" : "joined", req);
    pthread_mutex_lock(&s->mu);
    for (int b = 0; b < s->nbodies; b++)
        fifo_push(c, sq_blob_ref(s->topology[b]));
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
    sq_blob *last[SQ_MAX_BODIES] = {0};
    for (int b = 0; b < s->nbodies; b++)
        last[b] = sq_blob_ref(s->last_frame[b]);
    pthread_mutex_unlock(&s->mu);
    send_json(c, o);
    c->pending = 0;
    c->ready = 1;
    /* the newest frames; in lockstep mode in order with the stepped ones */
    for (int b = 0; b < SQ_MAX_BODIES; b++)
        if (last[b]) {
            if (!c->sub_frames)
                sq_blob_unref(last[b]);
            else if (c->srv->opt->lockstep)
                fifo_push(c, last[b]);
            else
                slot_put(c, b, last[b]);
        }
}

/* distribute one session's outbox */
static void drain_session(server *srv, srec *r)
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
                    send_session_info(r->members[k]);
            break;
        case SQ_OUT_FAILED:
            failed = 1;
            for (int k = 0; k < r->nmembers; k++)
                send_error(r->members[k], &r->members[k]->pending_req, "scene_failed",
                           r->s->fail_msg);
            break;
        case SQ_OUT_FRAME:
            for (int k = 0; k < r->nmembers; k++)
                if (r->members[k]->ready && r->members[k]->sub_frames)
                    slot_put(r->members[k], o->body, sq_blob_ref(o->blob));
            break;
        case SQ_OUT_STEP_FRAME:
            for (int k = 0; k < r->nmembers; k++)
                if (r->members[k]->ready && r->members[k]->sub_frames)
                    fifo_push(r->members[k], sq_blob_ref(o->blob));
            break;
        case SQ_OUT_NODES_DONE:
            for (int k = 0; k < r->nmembers; k++) {
                client *m = r->members[k];
                if (m->serial == o->client && m->nodes_busy == 1) {
                    m->nodes_busy = 2;
                    m->nodes_mark = m->pushed;
                    nodes_check(m);
                }
            }
            break;
        case SQ_OUT_TEXT:
        case SQ_OUT_BINARY:
            for (int k = 0; k < r->nmembers; k++)
                if (r->members[k]->ready && (!o->client || o->client == r->members[k]->serial))
                    fifo_push(r->members[k], sq_blob_ref(o->blob));
            break;
        }
        sq_blob_unref(o->blob);
    }
    free(outs);
    if (failed)
        end_session(srv, r);
}

/* ---------------------------------------------------------------- requests */

static cJSON *stats_json(server *srv, srec *r, client *c, const sq_request *req)
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
    cJSON_AddNumberToObject(o, "deadline_misses", (double)p->deadline_misses);
    cJSON_AddNumberToObject(o, "overruns", (double)p->overruns);
    cJSON_AddNumberToObject(o, "resets", (double)p->resets);
    /* per-level arrays are indexed by the level's number in the scene file (as the level
     * bytes of frames): zeros for levels a body did not load */
    int maxl = 0, sleeping = 0;
    int bact[SQ_MAX_BODIES][SQ_MAX_LEVELS] = {{0}}, bsub[SQ_MAX_BODIES][SQ_MAX_LEVELS] = {{0}};
    int blen[SQ_MAX_BODIES] = {0};
    double updates = 0;
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
    }
    double act[SQ_MAX_LEVELS] = {0};
    for (int b = 0; b < p->nbodies; b++)
        for (int l = 0; l < maxl; l++)
            act[l] += bact[b][l];
    cJSON_AddItemToObject(o, "active_nodes", cJSON_CreateDoubleArray(act, maxl));
    cJSON_AddNumberToObject(o, "node_updates", updates);
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
    cJSON *ba = cJSON_AddArrayToObject(o, "bodies");
    for (int b = 0; b < p->nbodies; b++) {
        cJSON *e = cJSON_CreateObject();
        cJSON_AddNumberToObject(e, "id", b);
        cJSON_AddItemToObject(e, "active_nodes", cJSON_CreateIntArray(bact[b], blen[b]));
        cJSON_AddNumberToObject(e, "node_updates", (double)p->node_updates[b]);
        cJSON_AddItemToObject(e, "substeps", cJSON_CreateIntArray(bsub[b], blen[b]));
        cJSON_AddBoolToObject(e, "sleeping", p->sleeping[b]);
        cJSON_AddNumberToObject(e, "splits", p->splits[b]);
        cJSON_AddNumberToObject(e, "merges", p->merges[b]);
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
    return o;
}

static cJSON *welcome_json(server *srv, client *c, const sq_request *req)
{
    const sq_serve_options *opt = srv->opt;
    cJSON *o = sq_reply_new("welcome", req);
    cJSON_AddNumberToObject(o, "version", SQ_PROTOCOL_VERSION);
    cJSON_AddStringToObject(o, "server", SQ_SERVER_NAME);
    cJSON_AddStringToObject(o, "role", c->role == SQ_ROLE_CONTROL ? "control" : "view");
    cJSON *sc = cJSON_AddArrayToObject(o, "scenes");
    for (int i = 0; i < srv->nscenes; i++)
        cJSON_AddItemToArray(sc, cJSON_CreateString(srv->names[i]));
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

static cJSON *scenes_json(server *srv, const sq_request *req)
{
    cJSON *o = sq_reply_new("scenes", req);
    cJSON *a = cJSON_AddArrayToObject(o, "scenes");
    for (int i = 0; i < srv->nscenes; i++) {
        const sq_scene *sc = srv->scenes[i];
        cJSON *e = cJSON_CreateObject();
        cJSON_AddStringToObject(e, "name", srv->names[i]);
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
        send_error(c, req, "shutting_down", "the server is stopping; reconnect later");
        return;
    }
    srec *r = NULL;
    sq_role role = c->role;
    if (req->type == SQ_REQ_OPEN) {
        int sc = -1;
        for (int i = 0; i < srv->nscenes; i++)
            if (!strcmp(srv->names[i], req->open.scene))
                sc = i;
        if (sc < 0) {
            snprintf(m, sizeof m, "open.scene: no scene \"%.60s\"; list_scenes gives the names",
                     req->open.scene);
            send_error(c, req, "unknown_scene", m);
            return;
        }
        /* a free slot (the one the client leaves may be reused) */
        leave_session(c);
        int idx = -1, limit = srv->opt->max_sessions - (c->token_ok ? 0 : reserved_sessions(srv));
        if (live_sessions(srv) < limit)
            for (int i = 0; i < srv->nslots && idx < 0; i++)
                if (!srv->slots[i].s)
                    idx = i;
        if (idx < 0) {
            if (limit < srv->opt->max_sessions)
                snprintf(m, sizeof m, "%d sessions are running; the other %d of --max-sessions are "
                         "kept for clients with the control token (--token); join one or retry "
                         "later", live_sessions(srv), reserved_sessions(srv));
            else
                snprintf(m, sizeof m, "%d sessions are running (--max-sessions); join one or retry "
                         "later", live_sessions(srv));
            send_error(c, req, "server_full", m);
            return;
        }
        r = &srv->slots[idx];
        r->gen = new_generation(r->gen, sq_session_gen_mask(srv->opt->instance, SLOT_BITS));
        r->scene = sc;
        r->controller = 0;
        r->bytes_sent = 0;
        r->empty_since = 0;
        uint64_t id = sq_session_id_public(r->gen << SLOT_BITS | (uint64_t)idx, srv->opt->instance);
        r->s = sq_session_start(srv->scenes[sc], srv->names[sc], id, srv->opt->lockstep,
                                srv->opt->precision, wake, srv);
        r->s->snapshotter = srv->snapshotter;
        __atomic_store(&r->s->budget.frac, &srv->opt->frame_budget, __ATOMIC_RELAXED);
        r->last_snapshot = 0;
        if (srv->opt->verbose)
            fprintf(stderr, "squish serve: session %llu opened (scene %s)\n",
                    (unsigned long long)id, srv->names[sc]);
    } else {
        r = find_session(srv, req->join.session);
        if (!r) {
            snprintf(m, sizeof m, "join.session: no session %llu (it ended, or never existed); open "
                     "a scene instead", (unsigned long long)req->join.session);
            send_error(c, req, "unknown_session", m);
            return;
        }
        if (req->join.has_role)
            role = req->join.role;
        if (role == SQ_ROLE_CONTROL && !c->token_ok) {
            send_error(c, req, "bad_token", "join.role: control needs the server's token; send it "
                       "in hello.token or join as \"view\"");
            return;
        }
        if (c->sess == r) {
            /* already here: answer again with the current state; the controller joining
             * as a viewer gives control up */
            if (role == SQ_ROLE_VIEW && r->controller == c->serial) {
                r->controller = 0;
                release_tools(c, r);
                control_event(r, "demoted");
            }
            c->pending_req = *req;
            send_session_info(c);
            return;
        }
        leave_session(c);
    }
    c->pending_req = *req;
    uint64_t had = r->controller;
    if (add_member(c, r, role)) {
        if (r->nmembers == 0 && !r->empty_since)
            r->empty_since = sq_now();
        return;
    }
    if (req->type == SQ_REQ_JOIN && r->controller != had)
        control_event(r, "taken"); /* a control client joined a session without one */
    c->pending = 1;
    pthread_mutex_lock(&r->s->mu);
    int state = r->s->state;
    pthread_mutex_unlock(&r->s->mu);
    if (state == SQ_SESSION_READY)
        send_session_info(c);
    /* STARTING: answered when the session posts READY; FAILED: by its FAILED item */
}

static void handle_request(client *c, const char *text, size_t len)
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
        send_error(c, &req, "rate_limited", m);
        return;
    }
    c->tokens -= 1;

    if (sq_request_decode(text, len, (size_t)opt->max_message, &req, &err)) {
        send_error(c, &req, err.code, err.message);
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
        send_error(c, &req, err.code, err.message);
        return;
    }

    switch (req.type) {
    case SQ_REQ_HELLO:
        if (opt->token && req.hello.has_token) {
            /* token guessing is throttled per address */
            double wait = sq_guard_wait(srv->guard, c->addr, now);
            if (wait > 0) {
                char m[200];
                snprintf(m, sizeof m, "hello.token: %d wrong tokens from %s; wait %.0f s before "
                         "trying again", SQ_GUARD_FAILS, c->addr, ceil(wait));
                send_error(c, &req, "throttled", m);
                return;
            }
            if (!token_matches(srv, req.hello.token))
                sq_guard_fail(srv->guard, c->addr, now);
        }
        if (req.hello.role == SQ_ROLE_CONTROL && opt->token &&
            (!req.hello.has_token || !token_matches(srv, req.hello.token))) {
            send_error(c, &req, "bad_token", req.hello.has_token
                       ? "hello.token: wrong token for role control; ask the server's operator"
                       : "hello.token: the server needs a token for role control; send it or use "
                         "role \"view\"");
            return;
        }
        c->greeted = 1;
        c->role = req.hello.role;
        c->token_ok = !opt->token || (req.hello.has_token && token_matches(srv, req.hello.token));
        snprintf(c->name, sizeof c->name, "%s", req.hello.client);
        send_json(c, welcome_json(srv, c, &req));
        break;
    case SQ_REQ_LIST_SCENES:
        send_json(c, scenes_json(srv, &req));
        break;
    case SQ_REQ_OPEN:
    case SQ_REQ_JOIN:
        do_open_or_join(c, &req);
        break;
    case SQ_REQ_LEAVE: {
        cJSON *o = sq_reply_new("left", &req);
        cJSON_AddNumberToObject(o, "session", r->s->id);
        leave_session(c);
        send_json(c, o);
        break;
    }
    case SQ_REQ_STATS:
        send_json(c, stats_json(srv, r, c, &req));
        break;
    case SQ_REQ_SUBSCRIBE: {
        /* the first push comes at once when stats are turned on; a subscribe that only
         * changes the rate (or repeats stats: true) keeps the schedule: next push one new
         * period after the last one, never an extra push */
        int was_on = c->sub_stats;
        if (req.subscribe.stats >= 0)
            c->sub_stats = req.subscribe.stats;
        if (req.subscribe.frames >= 0) {
            c->sub_frames = req.subscribe.frames;
            if (!c->sub_frames)
                clear_slots(c);
        }
        if (req.subscribe.has_hz)
            c->stats_hz = req.subscribe.stats_hz;
        if (!was_on)
            c->next_stats = 0;
        else if (c->last_stats > 0)
            c->next_stats = c->last_stats + 1.0 / c->stats_hz;
        cJSON *o = sq_reply_new("ack", &req);
        cJSON_AddStringToObject(o, "request", "subscribe");
        long frame = 0;
        if (r) {
            pthread_mutex_lock(&r->s->mu);
            frame = r->s->snap.frame;
            pthread_mutex_unlock(&r->s->mu);
        }
        cJSON_AddNumberToObject(o, "frame", (double)frame);
        send_json(c, o);
        break;
    }
    case SQ_REQ_TAKE_CONTROL: {
        if (r->controller && r->controller != c->serial) {
            send_error(c, &req, "controller_present", "take_control: another client controls "
                       "this session; wait for an event of kind \"control\" saying nobody does");
            return;
        }
        if (opt->token && !c->token_ok &&
            !(req.take_control.has_token && token_matches(srv, req.take_control.token))) {
            send_error(c, &req, "bad_token", req.take_control.has_token
                       ? "take_control.token: wrong token; ask the server's operator"
                       : "take_control.token: the server needs a token for control; send it "
                         "here or in hello.token");
            return;
        }
        c->token_ok = 1;
        int changed = r->controller != c->serial;
        r->controller = c->serial;
        c->demoted = 0;
        cJSON *o = sq_reply_new("ack", &req);
        cJSON_AddStringToObject(o, "request", "take_control");
        cJSON_AddStringToObject(o, "role", "control");
        pthread_mutex_lock(&r->s->mu);
        long frame = r->s->snap.frame;
        pthread_mutex_unlock(&r->s->mu);
        cJSON_AddNumberToObject(o, "frame", (double)frame);
        send_json(c, o);
        if (changed)
            control_event(r, "taken");
        break;
    }
    case SQ_REQ_PING: {
        cJSON *o = sq_reply_new("pong", &req);
        cJSON_AddNumberToObject(o, "t", req.ping.t);
        cJSON_AddNumberToObject(o, "server_time", now);
        send_json(c, o);
        break;
    }
    default:
        /* tool, set, pause, resume, reset, step, nodes: applied by the session thread */
        if (req.type == SQ_REQ_TOOL) {
            /* remembered, to be released when this controller leaves */
            int known = 0;
            for (int i = 0; i < c->ntool_ids; i++)
                known |= c->tool_ids[i] == req.tool.id;
            if (!known && c->ntool_ids < SQ_MAX_TOOLS)
                c->tool_ids[c->ntool_ids++] = req.tool.id;
        }
        if (req.type == SQ_REQ_NODES && c->nodes_busy) {
            /* one nodes request runs at a time per client; the newest waits, older waiting
             * ones are answered as replaced */
            if (c->nodes_deferred)
                send_error(c, &c->nodes_req, "superseded", "nodes: replaced by a newer nodes "
                           "request of this client (one runs at a time; wait for the reply)");
            c->nodes_req = req;
            c->nodes_deferred = 1;
            break;
        }
        if (sq_session_pending_jobs(r->s, c->serial) >= CLIENT_MAX_JOBS) {
            char m[200];
            snprintf(m, sizeof m, "%d requests of this client wait for session %llu; wait for "
                     "their replies before sending more", CLIENT_MAX_JOBS,
                     (unsigned long long)r->s->id);
            send_error(c, &req, "busy", m);
            break;
        }
        sq_session_push_job(r->s, c->serial, &req);
        if (req.type == SQ_REQ_NODES)
            c->nodes_busy = 1;
        break;
    }
}

/* ---------------------------------------------------------------- housekeeping */

static void tick(lws_sorted_usec_list_t *sul)
{
    server *srv = lws_container_of(sul, server, sul);
    double now = sq_now();
    for (int i = 0; i < srv->nslots; i++) {
        srec *r = &srv->slots[i];
        if (!r->s)
            continue;
        drain_session(srv, r);
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
                end_session(srv, r);
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
            sq_blob *b = sq_reply_blob(stats_json(srv, r, c, NULL));
            c->stats_queued = b;
            fifo_push(c, b);
        }
    }
    lws_sul_schedule(srv->ctx, 0, sul, tick, TICK_US);
}

/* ---------------------------------------------------------------- lws callback */

static const char *status_code(unsigned status)
{
    switch (status) {
    case 400: return "400";
    case 403: return "403";
    case 404: return "404";
    case 405: return "405";
    case 414: return "414";
    case 429: return "429";
    case 500: return "500";
    case 503: return "503";
    default: return "other";
    }
}

static int http_reply(struct lws *wsi, unsigned status, const char *type, const void *body,
                      size_t len)
{
    if (status >= 400) {
        server *srv = lws_context_user(lws_get_context(wsi));
        count_refused(srv, status_code(status));
    }
    unsigned char buf[LWS_PRE + 512], *start = buf + LWS_PRE, *p = start, *end = buf + sizeof buf;
    if (lws_add_http_common_headers(wsi, status, type, (lws_filepos_t)len, &p, end) ||
        lws_finalize_write_http_header(wsi, start, &p, end))
        return -1;
    unsigned char *out = sq_malloc(LWS_PRE + len + 1);
    memcpy(out + LWS_PRE, body, len);
    int n = lws_write(wsi, out + LWS_PRE, len, LWS_WRITE_HTTP_FINAL);
    free(out);
    if (n < (int)len)
        return -1;
    return lws_http_transaction_completed(wsi) ? -1 : 0;
}

/* GET /snapshot.png?session=ID[&size=WxH]: validate, rate-limit, hand to the session */
static int snapshot_request(server *srv, struct lws *wsi, conn *pss)
{
    char buf[8][128], msg[400];
    const char *args[8];
    int nargs = 0;
    for (; nargs < 8 && lws_hdr_copy_fragment(wsi, buf[nargs], sizeof buf[nargs], WSI_TOKEN_HTTP_URI_ARGS,
                                              nargs) > 0; nargs++)
        args[nargs] = buf[nargs];
    sq_snapshot_query q;
    int status = sq_snapshot_query_parse(args, nargs, SQ_SNAPSHOT_MAX_SIZE, &q, msg, sizeof msg);
    srec *r = status ? NULL : find_session(srv, q.session);
    if (!status && !r) {
        snprintf(msg, sizeof msg, "no session %llu; use /snapshot.png?session=ID with the id of "
                 "'opened'\n", (unsigned long long)q.session);
        status = HTTP_STATUS_NOT_FOUND;
    }
    if (status)
        return http_reply(wsi, (unsigned)status, "text/plain", msg, strlen(msg));
    if (!srv->snapshotter) {
        snprintf(msg, sizeof msg, "snapshots are not available in this server\n");
        return http_reply(wsi, 503, "text/plain", msg, strlen(msg));
    }
    int width = q.width, height = q.height;
    double now = sq_now();
    if (now - r->last_snapshot < SNAP_MIN_INTERVAL || srv->nwaits >= SNAP_MAX_WAITING) {
        snprintf(msg, sizeof msg, "too many snapshots: at most one per %.2f s per session; retry "
                 "later\n", SNAP_MIN_INTERVAL);
        return http_reply(wsi, 429, "text/plain", msg, strlen(msg));
    }
    (void)pss;
    r->last_snapshot = now;
    snap_wait *w = sq_calloc(1, sizeof *w);
    w->id = ++srv->next_snap;
    w->wsi = wsi;
    w->next = srv->waits;
    srv->waits = w;
    srv->nwaits++;
    sq_snap_job *j = sq_calloc(1, sizeof *j);
    j->id = w->id;
    j->width = width;
    j->height = height;
    sq_session_push_snapshot(r->s, j);
    /* rendering may take longer than lws' default wait for a reply (5 s): the render queue
     * is bounded (SNAP_MAX_WAITING), so each request gets time for the whole queue */
    lws_set_timeout(wsi, PENDING_TIMEOUT_HTTP_CONTENT, SNAP_TIMEOUT_S);
    return 0; /* answered from HTTP_WRITEABLE when the PNG is ready */
}

/* the snapshot a connection waits for, or NULL. Waits are found by connection, never
 * through the per-request user data: lws frees and re-zeroes that at every completed
 * transaction, including one pipelined behind a waiting snapshot. */
static snap_wait *snapshot_wait_of(server *srv, struct lws *wsi)
{
    for (snap_wait *w = srv->waits; w; w = w->next)
        if (w->wsi == wsi)
            return w;
    return NULL;
}

/* rendered snapshots: wake their HTTP connections (by handle: a result whose connection
 * closed meanwhile only frees its render place) */
static void snapshot_results(server *srv)
{
    if (!srv->snapshotter)
        return;
    for (sq_snap_job *j = sq_snapshotter_take(srv->snapshotter), *n; j; j = n) {
        n = j->next;
        j->next = NULL;
        snap_wait *w = srv->waits;
        while (w && w->id != j->id)
            w = w->next;
        if (w && !w->result) {
            w->result = j;
            if (w->wsi)
                lws_callback_on_writable(w->wsi);
        } else {
            sq_snap_job_free(j);
        }
    }
    /* forget rendered waits whose connection closed; unrendered ones keep their place in
     * SNAP_MAX_WAITING until the render is done, so closing connections cannot queue
     * unbounded renders */
    for (snap_wait **p = &srv->waits; *p;) {
        if (!(*p)->wsi && (*p)->result) {
            snap_wait *d = *p;
            *p = d->next;
            sq_snap_job_free(d->result);
            free(d);
            srv->nwaits--;
        } else {
            p = &(*p)->next;
        }
    }
}

/* the connection closed: its waits lose their connection (freed when rendered) */
static void snapshot_closed(server *srv, struct lws *wsi)
{
    for (snap_wait *w = srv->waits; w; w = w->next)
        if (w->wsi == wsi)
            w->wsi = NULL;
}

static int snapshot_write(server *srv, struct lws *wsi)
{
    snap_wait **p = &srv->waits;
    while (*p && (*p)->wsi != wsi)
        p = &(*p)->next;
    if (!*p || !(*p)->result)
        return 0;
    snap_wait *w = *p;
    *p = w->next;
    srv->nwaits--;
    sq_snap_job *j = w->result;
    free(w);
    int rc;
    if (j->png) {
        rc = http_reply(wsi, HTTP_STATUS_OK, "image/png", j->png, j->png_len);
    } else {
        char msg[300];
        snprintf(msg, sizeof msg, "snapshot failed: %.250s\n", j->error);
        rc = http_reply(wsi, HTTP_STATUS_INTERNAL_SERVER_ERROR, "text/plain", msg, strlen(msg));
    }
    sq_snap_job_free(j);
    return rc;
}

/* "/" when the server has no viewer to serve (no --web and none found) */
static const char no_viewer_page[] =
    "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>squish serve: "
    "no viewer</title></head>\n<body>\n<h1>squish serve is running, without its viewer</h1>\n"
    "<p>This server found no viewer to serve. Start it with <code>squish serve --web DIR</code>, "
    "DIR being the viewer's directory: <code>web/</code> in the source tree, "
    "<code>PREFIX/share/squish/web</code> after <code>make install</code>.</p>\n"
    "<p>The simulation itself is up: WebSocket clients connect to <code>/ws</code> "
    "(docs/protocol.md), <code>/healthz</code> answers <code>ok</code> and "
    "<code>/snapshot.png?session=ID</code> renders a session.</p>\n</body></html>\n";
/* the first session that should be stepping but has finished no frame for max(2 s, 50
 * periods), or NULL; *stalled its seconds without a frame */
static srec *frozen_session(server *srv, double *stalled)
{
    double now = sq_now();
    for (int i = 0; i < srv->nslots; i++) {
        srec *r = &srv->slots[i];
        if (!r->s || !r->progress_at)
            continue;
        double lim = SQ_MAX(FROZEN_MIN_S, FROZEN_PERIODS * r->s->period);
        if (now - r->progress_at > lim) {
            *stalled = now - r->progress_at;
            return r;
        }
    }
    return NULL;
}

/* GET or HEAD /healthz: 200 "ok", or 503 naming a frozen session */
static int healthz(server *srv, struct lws *wsi, int head)
{
    char msg[300];
    double stalled = 0;
    srec *r = frozen_session(srv, &stalled);
    unsigned status = HTTP_STATUS_OK;
    if (r) {
        snprintf(msg, sizeof msg, "unhealthy: session %llu has not finished a frame for %.1f s "
                 "(frame %ld; its thread is stuck or far over its budget)\n",
                 (unsigned long long)r->s->id, stalled, r->seen_frame);
        status = HTTP_STATUS_SERVICE_UNAVAILABLE;
    } else {
        snprintf(msg, sizeof msg, "ok\n");
    }
    if (!head)
        return http_reply(wsi, status, "text/plain", msg, strlen(msg));
    /* HEAD: the headers of the GET reply, no body */
    unsigned char buf[LWS_PRE + 512], *start = buf + LWS_PRE, *p = start, *end = buf + sizeof buf;
    if (lws_add_http_common_headers(wsi, status, "text/plain", (lws_filepos_t)strlen(msg), &p, end) ||
        lws_finalize_write_http_header(wsi, start, &p, end))
        return -1;
    return lws_http_transaction_completed(wsi) ? -1 : 0;
}

/* GET /metrics: Prometheus text format (docs/deploy.md lists the series) */
static int metrics_reply(server *srv, struct lws *wsi)
{
    sq_metrics m = {0};
    long frames = srv->frames_ended, misses = srv->misses_ended, resets = srv->resets_ended;
    int sessions = 0, clients = 0;
    sq_metrics_family(&m, "squish_session_frame_seconds", "gauge",
                      "compute time of the session's last frame");
    for (int i = 0; i < srv->nslots; i++) {
        srec *r = &srv->slots[i];
        if (!r->s)
            continue;
        sessions++;
        clients += r->nmembers;
        pthread_mutex_lock(&r->s->mu);
        frames += r->s->snap.frame;
        misses += r->s->snap.deadline_misses;
        resets += r->s->snap.resets;
        double fs = r->s->snap.frame_s;
        pthread_mutex_unlock(&r->s->mu);
        char l[64];
        snprintf(l, sizeof l, "session=\"%llu\"", (unsigned long long)r->s->id);
        sq_metrics_sample(&m, "squish_session_frame_seconds", l, fs);
    }
    sq_metrics_family(&m, "squish_sessions", "gauge", "running sessions");
    sq_metrics_sample(&m, "squish_sessions", NULL, sessions);
    sq_metrics_family(&m, "squish_clients", "gauge", "WebSocket clients in sessions");
    sq_metrics_sample(&m, "squish_clients", NULL, clients);
    sq_metrics_family(&m, "squish_connections", "gauge", "open TCP connections");
    sq_metrics_sample(&m, "squish_connections", NULL, sq_conns_open(srv->conns));
    sq_metrics_family(&m, "squish_frames_total", "counter", "frames stepped, every session");
    sq_metrics_sample(&m, "squish_frames_total", NULL, (double)frames);
    sq_metrics_family(&m, "squish_deadline_misses_total", "counter",
                      "frames finished after their frame time");
    sq_metrics_sample(&m, "squish_deadline_misses_total", NULL, (double)misses);
    sq_metrics_family(&m, "squish_resets_total", "counter", "bodies reset after a blow-up");
    sq_metrics_sample(&m, "squish_resets_total", NULL, (double)resets);
    sq_metrics_family(&m, "squish_bytes_out_total", "counter", "WebSocket message bytes written");
    sq_metrics_sample(&m, "squish_bytes_out_total", NULL, (double)srv->bytes_out);
    sq_metrics_family(&m, "squish_connections_refused_total", "counter",
                      "connections closed at accept (--max-conns, --max-conns-per-addr)");
    sq_metrics_sample(&m, "squish_connections_refused_total", NULL,
                      (double)sq_conns_refused(srv->conns));
    sq_metrics_family(&m, "squish_refused_total", "counter",
                      "refused requests by code (protocol error codes and HTTP statuses)");
    /* the I/O thread's refusals, plus those of the running sessions' threads */
    server tmp;
    tmp.nrefused = srv->nrefused;
    memcpy(tmp.refused, srv->refused, sizeof tmp.refused);
    for (int i = 0; i < srv->nslots; i++) {
        srec *r = &srv->slots[i];
        if (!r->s)
            continue;
        pthread_mutex_lock(&r->s->mu);
        for (int k = 0; k < r->s->nrefused; k++)
            count_refused_n(&tmp, r->s->refused[k].code, r->s->refused[k].n);
        pthread_mutex_unlock(&r->s->mu);
    }
    for (int i = 0; i < tmp.nrefused; i++) {
        char l[80];
        snprintf(l, sizeof l, "code=\"%.60s\"", tmp.refused[i].code);
        sq_metrics_sample(&m, "squish_refused_total", l, (double)tmp.refused[i].n);
    }
    int rc = http_reply(wsi, HTTP_STATUS_OK, "text/plain; version=0.0.4", m.text, m.len);
    sq_metrics_free(&m);
    return rc;
}

/* a file of the web root whose real path leaves the root (a symlink out of it)? */
static int outside_web_root(server *srv, const char *uri)
{
    if (!srv->opt->web_dir)
        return 0;
    char root[PATH_MAX], path[PATH_MAX + 160], real[PATH_MAX];
    if (!realpath(srv->opt->web_dir, root))
        return 1;
    size_t n = strlen(uri);
    snprintf(path, sizeof path, "%s%s%s", srv->opt->web_dir, uri,
             n && uri[n - 1] == '/' ? "index.html" : "");
    if (!realpath(path, real))
        return 0; /* missing: lws answers 404 */
    size_t rl = strlen(root);
    return !(strncmp(real, root, rl) == 0 && (real[rl] == '/' || real[rl] == 0));
}

static int origin_allowed(server *srv, struct lws *wsi)
{
    if (!srv->opt->norigins)
        return 1;
    char origin[256] = "";
    if (lws_hdr_copy(wsi, origin, sizeof origin, WSI_TOKEN_ORIGIN) <= 0)
        return 0;
    for (int i = 0; i < srv->opt->norigins; i++)
        if (!strcmp(origin, srv->opt->origins[i]))
            return 1;
    return 0;
}

static int callback(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in,
                    size_t len)
{
    server *srv = lws_context_user(lws_get_context(wsi));
    conn *pss = user;
    client *c = pss ? pss->c : NULL;

    switch (reason) {
    case LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION: {
        char uri[64] = "";
        lws_hdr_copy(wsi, uri, sizeof uri, WSI_TOKEN_GET_URI);
        if (strcmp(uri, "/ws")) {
            lwsl_notice("squish: WebSocket upgrade on %s refused (the endpoint is /ws)\n", uri);
            return 1;
        }
        if (!origin_allowed(srv, wsi)) {
            lwsl_notice("squish: WebSocket upgrade refused: Origin not in --origin list\n");
            count_refused(srv, "403");
            lws_return_http_status(wsi, HTTP_STATUS_FORBIDDEN,
                                   "WebSocket upgrade refused: this Origin is not allowed (--origin)");
            return 1;
        }
        return 0;
    }
    case LWS_CALLBACK_ESTABLISHED:
        c = sq_calloc(1, sizeof *c);
        c->serial = ++srv->next_serial;
        c->wsi = wsi;
        c->srv = srv;
        c->role = SQ_ROLE_CONTROL;
        c->tokens = srv->opt->rate;
        c->last_refill = sq_now();
        c->stats_hz = 4;
        c->sub_frames = 1;
        lws_get_peer_simple(wsi, c->addr, sizeof c->addr);
        pss->c = c;
        {
            /* a fixed send buffer: a slow reader fills it quickly, and from then on the
             * latest-wins slots decide what it gets, instead of megabytes of old frames */
            int fd = (int)lws_get_socket_fd(wsi), sz = SNDBUF_BYTES;
            if (fd >= 0)
                setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &sz, sizeof sz);
        }
        if (srv->stopping)
            return -1;
        return 0;

    case LWS_CALLBACK_RECEIVE: {
        if (!c)
            return -1;
        if (lws_is_first_fragment(wsi)) {
            c->rx_len = 0;
            c->rx_oversize = 0;
            c->rx_binary = lws_frame_is_binary(wsi);
        }
        size_t max = (size_t)srv->opt->max_message;
        if (!c->rx_oversize) {
            if (c->rx_len + len > max) {
                c->rx_oversize = 1;
            } else {
                if (c->rx_len + len + 1 > c->rx_cap) {
                    c->rx_cap = SQ_MAX(c->rx_len + len + 1, 2 * c->rx_cap);
                    c->rx = sq_realloc(c->rx, c->rx_cap);
                }
                memcpy(c->rx + c->rx_len, in, len);
                c->rx_len += len;
            }
        }
        if (!lws_is_final_fragment(wsi) || lws_remaining_packet_payload(wsi))
            return 0;
        /* messages not read as JSON: their errors say "ref": null */
        static const sq_request unread = {.ref_kind = SQ_REF_NULL};
        if (c->rx_binary) {
            send_error(c, &unread, "bad_json", "binary messages are not accepted; send JSON text");
        } else if (c->rx_oversize) {
            char m[160];
            snprintf(m, sizeof m, "text message larger than %zu bytes (--max-message) dropped; "
                     "send smaller messages", max);
            send_error(c, &unread, "too_large", m);
        } else {
            handle_request(c, c->rx, c->rx_len);
        }
        c->rx_len = 0;
        if (c->rx_cap > 65536) { /* do not keep a large buffer around */
            free(c->rx);
            c->rx = NULL;
            c->rx_cap = 0;
        }
        return 0;
    }
    case LWS_CALLBACK_SERVER_WRITEABLE:
        return c ? write_one(c) : 0;

    case LWS_CALLBACK_CLOSED:
        if (c) {
            leave_session(c);
            for (int i = 0; i < c->fcount; i++)
                sq_blob_unref(c->fifo[(c->fhead + i) % c->fcap]);
            free(c->fifo);
            free(c->rx);
            free(c);
            pss->c = NULL;
        }
        return 0;

    case LWS_CALLBACK_CLOSED_HTTP:
        snapshot_closed(srv, wsi);
        break;

    case LWS_CALLBACK_HTTP_WRITEABLE: 
        if (snapshot_wait_of(srv, wsi))
            return snapshot_write(srv, wsi);
        break;

    case LWS_CALLBACK_EVENT_WAIT_CANCELLED:
        if (srv) {
            for (int i = 0; i < srv->nslots; i++)
                if (srv->slots[i].s)
                    drain_session(srv, &srv->slots[i]);
            snapshot_results(srv);
        }
        return 0;

    case LWS_CALLBACK_FILTER_HTTP_CONNECTION: {
        /* a file request pipelined behind a waiting snapshot would be served before it
         * by lws: close too */
        if (snapshot_wait_of(srv, wsi))
            return -1;
        /* only GET and HEAD; files only inside the web root */
        if (lws_hdr_total_length(wsi, WSI_TOKEN_POST_URI) || lws_hdr_total_length(wsi, WSI_TOKEN_PUT_URI) ||
            lws_hdr_total_length(wsi, WSI_TOKEN_DELETE_URI) || lws_hdr_total_length(wsi, WSI_TOKEN_PATCH_URI) ||
            lws_hdr_total_length(wsi, WSI_TOKEN_OPTIONS_URI)) {
            count_refused(srv, "405");
            lws_return_http_status(wsi, HTTP_STATUS_METHOD_NOT_ALLOWED,
                                   "method not allowed: this server answers GET and HEAD only");
            return 1;
        }
        if (lws_hdr_total_length(wsi, WSI_TOKEN_GET_URI) > MAX_URI ||
            lws_hdr_total_length(wsi, WSI_TOKEN_HEAD_URI) > MAX_URI) {
            count_refused(srv, "414");
            lws_return_http_status(wsi, HTTP_STATUS_REQ_URI_TOO_LONG,
                                   "request line too long: the path and query may have 2048 bytes");
            return 1;
        }
        char uri[1024] = "";
        if (lws_hdr_copy(wsi, uri, sizeof uri, WSI_TOKEN_GET_URI) <= 0)
            lws_hdr_copy(wsi, uri, sizeof uri, WSI_TOKEN_HEAD_URI);
        if (uri[0] == '/' && strcmp(uri, "/ws") && outside_web_root(srv, uri)) {
            lwsl_notice("squish: %s leads outside the web root (a symlink): refused\n", uri);
            count_refused(srv, "404");
            lws_return_http_status(wsi, HTTP_STATUS_NOT_FOUND, "not found");
            return 1;
        }
        break;
    }
    case LWS_CALLBACK_FILTER_NETWORK_CONNECTION: {
        /* connection caps, at accept: over them the socket is closed at once */
        int fd = (int)(intptr_t)in;
        struct sockaddr_storage sa;
        socklen_t sl = sizeof sa;
        char addr[SQ_ADDR_MAX] = "?", why[160];
        if (!getpeername(fd, (struct sockaddr *)&sa, &sl)) {
            if (sa.ss_family == AF_INET)
                inet_ntop(AF_INET, &((struct sockaddr_in *)&sa)->sin_addr, addr, sizeof addr);
            else if (sa.ss_family == AF_INET6)
                inet_ntop(AF_INET6, &((struct sockaddr_in6 *)&sa)->sin6_addr, addr, sizeof addr);
        }
        if (srv->conns && sq_conns_accept(srv->conns, fd, addr, why, sizeof why)) {
            lwsl_warn("squish: connection from %s refused: %s\n", addr, why);
            return 1;
        }
        return 0;
    }
    case LWS_CALLBACK_SERVER_NEW_CLIENT_INSTANTIATED:
        if (srv->conns)
            sq_conns_bind(srv->conns, (int)lws_get_socket_fd(wsi), wsi);
        break;
    case LWS_CALLBACK_WSI_DESTROY:
        if (srv && srv->conns)
            sq_conns_close(srv->conns, wsi);
        break;
    case LWS_CALLBACK_HTTP: {
        {
            char head[64] = "";
            if (lws_hdr_copy(wsi, head, sizeof head, WSI_TOKEN_HEAD_URI) > 0 && !strcmp(head, "/healthz"))
                return healthz(srv, wsi, 1);
        }
        if (snapshot_wait_of(srv, wsi)) {
            /* pipelined behind a snapshot still rendering: lws 4.1 no longer makes the
             * connection writeable for the earlier reply, and replies must keep the order
             * of the requests; close (the client sends both again on a new connection,
             * as HTTP/1.1 allows). The waiting snapshot loses its connection and frees its
             * render place when rendered. */
            lwsl_notice("squish: HTTP request pipelined behind a snapshot: closing\n");
            return -1;
        }
        char uri[128] = "";
        lws_hdr_copy(wsi, uri, sizeof uri, WSI_TOKEN_GET_URI);
        if (!strcmp(uri, "/snapshot.png"))
            return snapshot_request(srv, wsi, pss);
        if (!strcmp(uri, "/healthz"))
            return healthz(srv, wsi, 0);
        if (!strcmp(uri, "/metrics"))
            return metrics_reply(srv, wsi);
        if (!srv->opt->web_dir && (!strcmp(uri, "/") || !strcmp(uri, "/index.html")))
            return http_reply(wsi, HTTP_STATUS_OK, "text/html; charset=utf-8", no_viewer_page,
                              strlen(no_viewer_page));
        return http_reply(wsi, HTTP_STATUS_NOT_FOUND, "text/plain", "not found\n", 10);
    }
    default:
        break;
    }
    return lws_callback_http_dummy(wsi, reason, user, in, len);
}

/* ---------------------------------------------------------------- setup */

sq_serve_options sq_serve_options_default(void)
{
    sq_serve_options o;
    memset(&o, 0, sizeof o);
    o.host = "127.0.0.1";
    o.port = 8080;
    o.max_sessions = 16;
    o.max_clients = 256;
    o.max_message = 65536;
    o.rate = 200;
    o.grace = 30;
    o.precision = SQ_CODEC_PRECISION;
    o.frame_budget = 1.0;
    o.max_conns = 2000;
    o.max_conns_per_addr = 500;
    o.idle_timeout = 300;
    return o;
}

static int has_suffix(const char *s, const char *suf)
{
    size_t a = strlen(s), b = strlen(suf);
    return a >= b && !strcmp(s + a - b, suf);
}

static int cmp_str(const void *a, const void *b)
{
    return strcmp(*(char *const *)a, *(char *const *)b);
}

/* load every *.json of dir (sorted); bad files are reported and skipped */
static void load_scenes(server *srv, const char *dir)
{
    DIR *d = opendir(dir);
    if (!d) {
        fprintf(stderr, "squish serve: cannot read scene directory %s; serving the default scene\n",
                dir);
        return;
    }
    char **files = NULL;
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d)))
        if (e->d_name[0] != '.' && has_suffix(e->d_name, ".json")) {
            files = sq_realloc(files, sizeof *files * (size_t)(n + 1));
            files[n++] = sq_strdup(e->d_name);
        }
    closedir(d);
    if (n)
        qsort(files, (size_t)n, sizeof *files, cmp_str);
    for (int i = 0; i < n; i++) {
        char path[1024];
        snprintf(path, sizeof path, "%s/%s", dir, files[i]);
        sq_err err = {{0}};
        sq_scene *sc = sq_scene_load(path, &err);
        /* what only the engine can tell (every node fixed, a step bound needing more than
         * 2^20 substeps, ...): a scene that cannot start is not offered */
        if (sc && sq_scene_check(sc, &err)) {
            sq_scene_free(sc);
            sc = NULL;
        }
        int dup = -1;
        for (int k = 0; sc && k < srv->nscenes; k++)
            if (!strcmp(srv->names[k], sc->name))
                dup = k;
        if (!sc) {
            fprintf(stderr, "squish serve: skipping scene %s\n", err.msg);
        } else if (dup >= 0) {
            /* clients open scenes by their "name": two files may not share one */
            fprintf(stderr, "squish serve: skipping scene %s: its name \"%s\" is already the name "
                    "of %s; give each scene file its own \"name\"\n", path, sc->name,
                    srv->scenes[dup]->path);
            sq_scene_free(sc);
        } else {
            srv->scenes = sq_realloc(srv->scenes, sizeof *srv->scenes * (size_t)(srv->nscenes + 1));
            srv->names = sq_realloc(srv->names, sizeof *srv->names * (size_t)(srv->nscenes + 1));
            srv->scenes[srv->nscenes] = sc;
            /* the scene's "name" (sq_scene_load gives the file's base name without one) */
            snprintf(srv->names[srv->nscenes], sizeof srv->names[srv->nscenes], "%s", sc->name);
            srv->nscenes++;
        }
        free(files[i]);
    }
    free(files);
}

static const struct lws_protocol_vhost_options mime_json = {NULL, NULL, ".map", "application/json"};
static const struct lws_protocol_vhost_options mime_wasm = {&mime_json, NULL, ".wasm", "application/wasm"};
static const struct lws_protocol_vhost_options mime_mjs = {&mime_wasm, NULL, ".mjs", "text/javascript"};

int sq_serve(const sq_serve_options *opt, sq_err *err)
{
    server srv;
    int rc = 0;
    memset(&srv, 0, sizeof srv);
    srv.opt = opt;
    if (opt->max_sessions < 1 || opt->max_sessions > (1 << SLOT_BITS))
        return sq_err_set(err, "--max-sessions %d: use 1..%d", opt->max_sessions, 1 << SLOT_BITS);

    if (opt->web_dir) {
        DIR *d = opendir(opt->web_dir);
        if (!d)
            return sq_err_set(err, "--web %s: not a readable directory; give the viewer's "
                              "directory (web/ in the repository)", opt->web_dir);
        closedir(d);
    }
    if (opt->scenes_dir)
        load_scenes(&srv, opt->scenes_dir);
    int builtin = srv.nscenes == 0;
    if (srv.nscenes == 0) {
        sq_scene *sc = sq_scene_default(err);
        if (!sc)
            return sq_err_prefix(err, "default scene");
        srv.scenes = sq_malloc(sizeof *srv.scenes);
        srv.names = sq_malloc(sizeof *srv.names);
        srv.scenes[0] = sc;
        snprintf(srv.names[0], sizeof srv.names[0], "default");
        srv.nscenes = 1;
    }
    srv.nslots = opt->max_sessions;
    srv.slots = sq_calloc((size_t)srv.nslots, sizeof *srv.slots);

    static struct lws_protocols protocols[2];
    memset(protocols, 0, sizeof protocols);
    protocols[0].name = "squish";
    protocols[0].callback = callback;
    protocols[0].per_session_data_size = sizeof(conn);
    protocols[0].rx_buffer_size = 16384;

    struct lws_http_mount health, files;
    memset(&health, 0, sizeof health);
    memset(&files, 0, sizeof files);
    health.mountpoint = "/healthz";
    health.mountpoint_len = (unsigned char)strlen(health.mountpoint);
    health.origin = "squish";
    health.origin_protocol = LWSMPRO_CALLBACK;
    files.mountpoint = "/";
    files.mountpoint_len = 1;
    files.origin = opt->web_dir;
    files.def = "index.html";
    files.origin_protocol = LWSMPRO_FILE;
    files.extra_mimetypes = &mime_mjs;
    struct lws_http_mount snap;
    memset(&snap, 0, sizeof snap);
    snap.mountpoint = "/snapshot.png";
    snap.mountpoint_len = (unsigned char)strlen(snap.mountpoint);
    snap.origin = "squish";
    snap.origin_protocol = LWSMPRO_CALLBACK;
    struct lws_http_mount metrics;
    memset(&metrics, 0, sizeof metrics);
    metrics.mountpoint = "/metrics";
    metrics.mountpoint_len = (unsigned char)strlen(metrics.mountpoint);
    metrics.origin = "squish";
    metrics.origin_protocol = LWSMPRO_CALLBACK;
    health.mount_next = &metrics;
    metrics.mount_next = &snap;
    if (opt->web_dir)
        snap.mount_next = &files;

    struct lws_context_creation_info info;
    memset(&info, 0, sizeof info);
    info.port = opt->port;
    info.iface = opt->host;
    info.protocols = protocols;
    info.user = &srv; /* the callbacks find the server with lws_context_user() */
    info.mounts = &health;
    info.options = LWS_SERVER_OPTION_HTTP_HEADERS_SECURITY_BEST_PRACTICES_ENFORCE |
                   LWS_SERVER_OPTION_DISABLE_IPV6;
    lws_set_log_level(opt->verbose ? (LLL_ERR | LLL_WARN | LLL_NOTICE) : (LLL_ERR | LLL_WARN),
                      sq_log_emit);
    /* a WebSocket silent for idle_timeout / 2 gets a ping; one that has not answered (or
     * sent anything) within idle_timeout is closed */
    static lws_retry_bo_t idle;
    memset(&idle, 0, sizeof idle);
    idle.secs_since_valid_ping = (uint16_t)SQ_MAX(1.0, opt->idle_timeout / 2);
    idle.secs_since_valid_hangup = (uint16_t)SQ_MAX(idle.secs_since_valid_ping + 1.0, opt->idle_timeout);
    info.retry_and_idle_policy = &idle;
    info.max_http_header_data = HEADER_BYTES;
    /* the fd limit: raised to its hard maximum; the connection cap stays below it (two fds
     * per connection serving a file, plus a margin), so that accept never fails with EMFILE
     * (lws would retry it in a busy loop) */
    int max_conns = opt->max_conns;
    struct rlimit rl;
    if (!getrlimit(RLIMIT_NOFILE, &rl)) {
        if (rl.rlim_cur < rl.rlim_max) {
            rl.rlim_cur = rl.rlim_max;
            setrlimit(RLIMIT_NOFILE, &rl);
            getrlimit(RLIMIT_NOFILE, &rl);
        }
        long fit = ((long)rl.rlim_cur - 64) / 2;
        if (fit < max_conns) {
            fprintf(stderr, "squish serve: --max-conns %d lowered to %ld (file descriptor limit %ld)\n",
                    max_conns, SQ_MAX(fit, 1L), (long)rl.rlim_cur);
            max_conns = (int)SQ_MAX(fit, 1L);
        }
    }
    srv.conns = sq_conns_new(max_conns, opt->max_conns_per_addr);
    srv.guard = sq_guard_new();

    srv.snapshotter = sq_snapshotter_start(wake, &srv);
    srv.ctx = lws_create_context(&info);
    if (!srv.ctx) {
        sq_err_set(err, "cannot listen on %s:%d (port in use, or the address is not local?); "
                   "choose another --port or --host", opt->host, opt->port);
        goto fail;
    }
    srv.vhost = lws_get_vhost_by_name(srv.ctx, "default");
    int port = srv.vhost ? lws_get_vhost_listen_port(srv.vhost) : opt->port;
    printf("squish serve: listening on http://%s:%d/ (WebSocket /ws; ", opt->host, port);
    if (opt->web_dir)
        printf("viewer from %s; ", opt->web_dir);
    else
        printf("no viewer: / says to pass --web DIR; ");
    if (builtin) {
        printf("only the built-in cube is offered, as scene \"default\": %s)",
               opt->scenes_dir ? "no scene loaded from --scenes" : "pass --scenes DIR for more");
    } else {
        printf("%d scene%s from %s:", srv.nscenes, srv.nscenes == 1 ? "" : "s", opt->scenes_dir);
        for (int i = 0; i < srv.nscenes; i++)
            printf(" %s", srv.names[i]);
        printf(")");
    }
    printf("%s\n", opt->lockstep ? " lockstep" : "");
    fflush(stdout);

    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);

    lws_sul_schedule(srv.ctx, 0, &srv.sul, tick, TICK_US);
    while (!interrupted)
        if (lws_service(srv.ctx, 0) < 0)
            break;

    /* clean shutdown: tell the clients, flush for a moment, then close everything; every
     * session thread is told to stop first, so that frames in progress end together */
    srv.stopping = 1;
    for (int i = 0; i < srv.nslots; i++)
        if (srv.slots[i].s)
            sq_session_cancel(srv.slots[i].s);
    for (int i = 0; i < srv.nslots; i++) {
        srec *r = &srv.slots[i];
        for (int k = 0; r->s && k < r->nmembers; k++) {
            cJSON *e = sq_reply_new("event", NULL);
            cJSON_AddStringToObject(e, "kind", "shutdown");
            cJSON_AddNumberToObject(e, "session", r->s->id);
            cJSON_AddStringToObject(e, "message", "the server is stopping");
            send_json(r->members[k], e);
        }
    }
    double until = sq_now() + 0.3;
    while (sq_now() < until) {
        lws_service(srv.ctx, 0);
        int busy = 0;
        for (int i = 0; i < srv.nslots; i++)
            for (int k = 0; srv.slots[i].s && k < srv.slots[i].nmembers; k++)
                busy |= srv.slots[i].members[k]->fcount > 0;
        if (!busy)
            break;
    }
    /* the simulation and render threads stop first, so that nothing wakes the context
     * while it is destroyed; then the connections close */
    for (int i = 0; i < srv.nslots; i++)
        end_session(&srv, &srv.slots[i]);
    sq_snapshotter_stop(srv.snapshotter);
    srv.snapshotter = NULL;
    lws_context_destroy(srv.ctx);
    srv.ctx = NULL;
    fprintf(stderr, "squish serve: stopped\n");
    goto done;
fail:
    rc = -1;
done:
    sq_snapshotter_stop(srv.snapshotter);
    for (snap_wait *w = srv.waits, *n; w; w = n) {
        n = w->next;
        sq_snap_job_free(w->result);
        free(w);
    }
    for (int i = 0; i < srv.nscenes; i++)
        sq_scene_free(srv.scenes[i]);
    free(srv.scenes);
    free(srv.names);
    free(srv.slots);
    sq_conns_free(srv.conns);
    sq_guard_free(srv.guard);
    return rc;
}
