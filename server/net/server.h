/* server.h - the service thread's state, shared by the files of server/net that run on it.
 *
 * Internal to server/net (app/ uses net/net.h only). One lws service thread does all I/O:
 * clients (one per WebSocket), the session registry (srec slots), the HTTP waits of
 * snapshots. Who does what:
 *   serve.c          transport and mounts: lws context, HTTP mounts, /healthz, /metrics, shutdown
 *   callback.c       the lws protocol callback: connections, messages in, writes out
 *   clients.c        client queues: the FIFO, the latest-wins frame slots, one write per callback
 *   registry.c       the session registry: slots, members, control, outboxes, housekeeping tick
 *   dispatch.c       request dispatch: rate limit, decode, checks, the lws-thread requests
 *   replies.c        replies: the JSON builders of both threads
 *   snapshot_http.c  GET /snapshot.png: requests waiting for their PNG
 * Session threads (session.c, jobs.c) meet this thread only through net/session.h. Pure
 * parts, without state: request.c and rawtext.c (decoding, checks), errors.c (the error
 * codes), query.c (URL queries, ids), codec.c (binary messages), limits.c, budget.c.
 */
#ifndef SQ_NET_SERVER_H
#define SQ_NET_SERVER_H

#include "net/errors.h"
#include "net/limits.h"
#include "net/metrics.h"
#include "net/session.h"
#include "net/query.h"

#include <cJSON.h>
#include <libwebsockets.h>

_Static_assert(LWS_PRE <= SQ_BLOB_PRE, "blob headroom must hold LWS_PRE");

#define HQ_MAX 64                /* queued haptic forces per client whose latency is timed */
#define PASS_WRITES 4            /* messages written per service pass to clients without a
                                    haptic channel: the rest wait for the next pass, so that
                                    a pose never waits behind a whole fan-out of frames */
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
    double haptic_last_error;        /* when this client last got a haptic pose error */
    int haptic;                      /* 1: it has opened a haptic channel: its writes are not
                                        held back by the per-pass budget (PASS_WRITES) */
    double hq_read[HQ_MAX];          /* read times of its forces waiting in the FIFO, oldest */
    uint32_t hq_seq[HQ_MAX];         /* first (a ring from hq_head), with their poses' seq */
    int hq_head, hq_n;               /* beyond HQ_MAX waiting forces are not timed */
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
    char opener[SQ_ADDR_MAX];        /* address of the client that opened it without the
                                        token ("" when the opener had it) */
} srec;

typedef struct server {
    const sq_serve_options *opt;
    struct lws_context *ctx;
    struct lws_vhost *vhost;
    sq_scene_list scenes;            /* what clients may open (scene/dir.c) */
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
    int pass_writes;                 /* messages written in this service pass (serve.c's loop
                                        clears it before each lws_service) */
    long frames_ended, misses_ended, resets_ended; /* of sessions that ended */
    int nrefused;
    struct { const char *code; long n; } refused[48]; /* error replies and HTTP statuses */
} server;

#define MAX_URI 2048                 /* longer request paths get 414 */
#define HEADER_BYTES 16384           /* lws header space per request (longer: closed) */
#define FROZEN_MIN_S 2.0             /* a session is frozen after max(2 s, 50 periods) */
#define FROZEN_PERIODS 50

/* clients.c: client queues */
void net_count_refused_n(server *srv, const char *code, long n);
void net_count_refused(server *srv, const char *code);
void net_fifo_push(client *c, sq_blob *b);
void net_send_json(client *c, cJSON *o);
void net_send_error(client *c, const sq_request *req, sq_net_code code, const char *msg);
void net_slot_put(client *c, int body, sq_blob *b);
void net_clear_slots(client *c);
void net_nodes_check(client *c);
int net_write_one(client *c);

/* registry.c: the session registry */
srec *net_find_session(server *srv, uint64_t id);
uint64_t net_new_generation(uint64_t old, uint64_t mask);
int net_reserved_sessions(const server *srv);
int net_live_sessions(const server *srv);
/* live sessions opened without the token by a client at addr */
int net_sessions_opened_from(const server *srv, const char *addr);
void net_end_session(server *srv, srec *r);
void net_release_tools(client *c, srec *r);
void net_control_event(srec *r, const char *reason);
void net_leave_session(client *c);
int net_add_member(client *c, srec *r, sq_role role);
void net_send_session_info(client *c);
void net_drain_session(server *srv, srec *r);
void net_tick(lws_sorted_usec_list_t *sul);

/* dispatch.c: one complete text message of a client */
void net_handle_request(client *c, const char *text, size_t len);

/* replies.c: the replies built on the lws thread */
cJSON *net_stats_json(server *srv, srec *r, client *c, const sq_request *req);
cJSON *net_welcome_json(server *srv, client *c, const sq_request *req);
cJSON *net_scenes_json(server *srv, const sq_request *req);

/* snapshot_http.c: GET /snapshot.png */
int net_snapshot_request(server *srv, struct lws *wsi, conn *pss);
snap_wait *net_snapshot_wait_of(server *srv, struct lws *wsi);
void net_snapshot_results(server *srv);
void net_snapshot_closed(server *srv, struct lws *wsi);
int net_snapshot_write(server *srv, struct lws *wsi);

/* serve.c: HTTP replies and checks, the wake-up of the service thread */
void net_wake(void *arg);
int net_http_reply(struct lws *wsi, unsigned status, const char *type, const void *body,
                   size_t len);
int net_healthz(server *srv, struct lws *wsi, int head);
int net_metrics_reply(server *srv, struct lws *wsi);
int net_outside_web_root(server *srv, const char *uri);
int net_origin_allowed(server *srv, struct lws *wsi);
extern const char net_no_viewer_page[];

/* callback.c: the lws protocol callback */
int net_callback(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in,
                 size_t len);

#endif
