/* session.h - one running scene instance of the server and its simulation thread.
 *
 * Internal to server/net. A session owns a world (sq_world) stepped by its own thread on a
 * real-time frame clock (or only on `step` in lockstep mode). The lws service thread and the
 * session thread meet only in the fields marked "shared", under `mu`:
 *   lws thread -> session: jobs (decoded requests of the session's clients)
 *   session -> lws thread: outbox items (frames, replies, events), then lws_cancel_service()
 * Realtime frames in the outbox are "latest wins": a newer frame of a body replaces an
 * unsent one, so the simulation never waits for the network.
 */
#ifndef SQ_NET_SESSION_H
#define SQ_NET_SESSION_H

#include <pthread.h>

#include "net/budget.h"
#include "net/errors.h"
#include "net/haptic.h"
#include "net/net.h"
#include "net/snapshot.h"
#include "scene/scene.h"

/* fraction of the frame period a session spends on requests per frame (the rest waits) */
#define SQ_SESSION_JOB_SHARE 0.5

/* a request handed to the session thread, with the client it came from */
typedef struct sq_job {
    uint64_t client;         /* client serial, for the reply */
    sq_request req;
    sq_snap_job *snap;       /* internal: capture the world for a snapshot (req unused) */
} sq_job;

typedef enum sq_out_kind {
    SQ_OUT_TEXT = 0,         /* text (client 0: every member) */
    SQ_OUT_BINARY,           /* binary to one client, in order (nodes) */
    SQ_OUT_FRAME,            /* realtime frame of `body` for every member: latest wins */
    SQ_OUT_STEP_FRAME,       /* lockstep frame for every member: never dropped */
    SQ_OUT_READY,            /* the world exists: topology and info are set */
    SQ_OUT_FAILED,           /* the world could not be created: fail_msg */
    SQ_OUT_NODES_DONE        /* the client's nodes request is answered (no blob) */
} sq_out_kind;

typedef struct sq_out {
    sq_out_kind kind;
    uint64_t client;         /* 0 = every member */
    int body;
    sq_blob *blob;           /* owned reference (NULL for READY/FAILED) */
} sq_out;

/* what clients see of a session's last frame (copied under mu) */
typedef struct sq_snapshot {
    long frame;
    double time;
    int paused;
    double frame_s;                  /* compute time of the last frame, s (wall clock) */
    double frame_cpu_s;              /* its session thread's CPU time, s (step and haptic
                                        models: what the frame cost, whatever else ran) */
    double budget_used;              /* frame_s / period */
    long deadline_misses, resets;
    long overruns;                   /* frames whose compute alone exceeded the period */
    int nbodies;
    int nlevels[SQ_MAX_BODIES];
    int active[SQ_MAX_BODIES][SQ_MAX_LEVELS];
    int substeps[SQ_MAX_BODIES][SQ_MAX_LEVELS];
    long node_updates[SQ_MAX_BODIES];
    int cg_iterations[SQ_MAX_BODIES];    /* implicit bodies: the frame's CG iterations (0: explicit) */
    double cg_residual[SQ_MAX_BODIES];   /* and its largest final relative residual */
    int sleeping[SQ_MAX_BODIES], splits[SQ_MAX_BODIES], merges[SQ_MAX_BODIES];
    int ntools;
    sq_tool tools[SQ_MAX_TOOLS];
    sq_tool_feedback feedback[SQ_MAX_BODIES][SQ_MAX_TOOLS];
    sq_health_stat health[SQ_MAX_BODIES][SQ_HEALTH_NKINDS]; /* sq_body_health per body */
    double contact_force[SQ_MAX_BODIES][3];  /* sq_body_contact_force: N */
    int contact_nodes[SQ_MAX_BODIES];
    double contact_depth[SQ_MAX_BODIES];     /* m */
    int nobstacles;
    double obstacle_pos[SQ_MAX_OBSTACLES][3]; /* each obstacle's point (centre, end a) now, m */
} sq_snapshot;

typedef enum sq_session_state {
    SQ_SESSION_STARTING = 0,
    SQ_SESSION_READY,
    SQ_SESSION_FAILED
} sq_session_state;

typedef struct sq_session {
    /* fixed at creation */
    uint64_t id;                     /* handle: random generation << 10 | slot index (< 2^49) */
    const sq_scene *scene;
    char scene_name[SQ_NET_NAME_MAX];
    double period;                   /* frame period, s */
    int lockstep;
    double precision;                /* quantisation floor / body diagonal */
    void (*wake)(void *);            /* wakes the lws thread (lws_cancel_service) */
    void *wake_arg;
    sq_snapshotter *snapshotter;     /* set by the server right after start (may be NULL) */
    int idle;                        /* atomic: no client is connected; the clock waits */

    /* shared, under mu */
    pthread_mutex_t mu;
    pthread_cond_t cv;
    sq_job *jobs;
    int njobs, cap_jobs;
    sq_out *outs;
    int nouts, cap_outs;
    int state;                       /* sq_session_state */
    int stop;
    char fail_msg[512];
    int nbodies;
    sq_blob *topology[SQ_MAX_BODIES];
    sq_blob *last_frame[SQ_MAX_BODIES]; /* newest frame per body, for clients that join */
    char *bodies_json;               /* "bodies" of opened/joined, rebuilt after set */
    sq_snapshot snap;
    int ntool_ids;
    int tool_ids[SQ_MAX_TOOLS];      /* ids of the world's tools, for request checks */
    int nrefused;                    /* error replies of the session thread, by code */
    struct { const char *code; long n; } refused[16];

    /* haptic channels: their own lock, never held across a step (net/haptic.h) */
    sq_haptic_hub haptic;

    /* session thread only */
    pthread_t thread;
    int thread_started;
    sq_world *world;
    sq_codec codec[SQ_MAX_BODIES];
    float *cur;                      /* scratch surface positions */
    unsigned char *lev;              /* scratch levels */
    int paused;
    long deadline_misses;
    sq_budget budget;                /* compute budget; budget.frac set by the server right
                                        after start (read atomically) */
} sq_session;

/* create and start a session's thread for scene; the world is built on that thread, which
 * then posts SQ_OUT_READY or SQ_OUT_FAILED */
sq_session *sq_session_start(const sq_scene *scene, const char *name, uint64_t id, int lockstep,
                             double precision, void (*wake)(void *), void *wake_arg);
/* ask the thread to stop (a frame in progress is abandoned); sq_session_stop still needed */
void sq_session_cancel(sq_session *s);
/* stop the thread, free everything (pending outbox blobs included) */
void sq_session_stop(sq_session *s);
/* queue a request for the session thread (lws thread) */
void sq_session_push_job(sq_session *s, uint64_t client, const sq_request *req);
/* queue a snapshot capture: the session thread captures its world into j->state at its
 * next frame and submits j to s->snapshotter */
void sq_session_push_snapshot(sq_session *s, sq_snap_job *j);
/* jobs of `client` waiting in the queue (lws thread; bounds what one client may queue) */
int sq_session_pending_jobs(sq_session *s, uint64_t client);
/* drop the queued jobs of `client` of request type `type` (a departed client's nodes) */
void sq_session_drop_jobs(sq_session *s, uint64_t client, sq_req_type type);
/* take every outbox item (lws thread); *n items, caller frees the array and blob refs */
sq_out *sq_session_take_outbox(sq_session *s, int *n);

/* ---- the session thread's own (session.c, jobs.c) */

struct cJSON;

/* append an outbox item (takes mu); realtime frames replace an unsent one */
void sq_session_post(sq_session *s, sq_out_kind kind, uint64_t client, int body, sq_blob *blob);
/* a text reply to one client (0: every member) */
void sq_session_reply(sq_session *s, uint64_t client, struct cJSON *o);
/* an error reply, counted by code for /metrics (code: a static string) */
void sq_session_reply_error(sq_session *s, uint64_t client, const sq_request *req,
                            sq_net_code code, const char *msg);
/* refresh the tool ids requests are checked against (takes mu) */
void sq_session_sync_tool_ids(sq_session *s);
/* step one frame and post its messages as kind */
void sq_session_step_frame(sq_session *s, sq_out_kind kind);
/* the --frame-budget fraction (read atomically) */
double sq_session_budget_frac(sq_session *s);
/* jobs.c: apply one job; returns 1 if the visible state changed without a step */
int sq_session_do_job(sq_session *s, const sq_job *j);

/* ---- replies.c: JSON helpers of both threads */
/* a reply object {"type": type} with the request's ref copied */
struct cJSON *sq_reply_new(const char *type, const sq_request *req);
/* print and free a JSON object into a text blob */
sq_blob *sq_reply_blob(struct cJSON *o);
/* an error reply */
sq_blob *sq_error_blob(sq_net_code code, const char *message, const sq_request *req);
/* the tools array of a snapshot */
struct cJSON *sq_tools_json(const sq_tool *tools, int ntools);
/* settings of body bi, as in docs/protocol.md; levels numbered as listed in the scene file */
struct cJSON *sq_settings_json(const sq_world *w, int bi);
/* the scene's obstacles (net/obstacles.c): their shapes for opened/joined; does any move
 * (keyframes)? the offsets of each from its placement (stats, and the "obstacles" message
 * sent with every frame when one moves) */
struct cJSON *sq_obstacles_json(const sq_scene *sc);
int sq_net_obstacles_move(const sq_scene *sc);
struct cJSON *sq_obstacle_offsets_json(const sq_scene *sc, const double (*pos)[3], int n);
struct cJSON *sq_obstacles_frame_json(const sq_world *w);
/* the "bodies" array of opened/joined, printed (malloc) */
char *sq_bodies_json(const sq_session *s);

#endif
