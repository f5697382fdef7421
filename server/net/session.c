/* session.c - a session's simulation thread: world, frame clock, job queue, frame encoding.
 *
 * The thread builds the world, then loops: sleep until the next frame time (real-time mode)
 * or until a job arrives (lockstep), apply the queued jobs in order, step one frame, encode
 * one frame message per body and post it to the outbox. Nothing here waits for a client.
 * The jobs themselves are applied in jobs.c, the JSON of the replies is built in replies.c.
 */
#include "net/session.h"

#include <cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

/* ---------------------------------------------------------------- queues */

/* append an outbox item (caller holds mu); realtime frames replace an unsent one */
static void sq_session_post_locked(sq_session *s, sq_out_kind kind, uint64_t client, int body, sq_blob *blob)
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

void sq_session_post(sq_session *s, sq_out_kind kind, uint64_t client, int body, sq_blob *blob)
{
    pthread_mutex_lock(&s->mu);
    sq_session_post_locked(s, kind, client, body, blob);
    pthread_mutex_unlock(&s->mu);
}

void sq_session_reply(sq_session *s, uint64_t client, cJSON *o)
{
    sq_session_post(s, SQ_OUT_TEXT, client, 0, sq_reply_blob(o));
}

void sq_session_reply_error(sq_session *s, uint64_t client, const sq_request *req, sq_net_code ec,
                        const char *msg)
{
    sq_blob *b = sq_error_blob(ec, msg, req);
    const char *code = sq_net_code_name(ec);
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
    sq_session_post_locked(s, SQ_OUT_TEXT, client, 0, b);
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
        p->cg_iterations[b] = f->cg_iterations;
        p->cg_residual[b] = f->cg_residual;
        p->sleeping[b] = sq_body_is_sleeping(w->bodies[b]);
        p->splits[b] = f->splits;
        p->merges[b] = f->merges;
        memcpy(p->feedback[b], w->feedback[b], sizeof p->feedback[b]);
        memcpy(p->health[b], sq_body_health(w->bodies[b]), sizeof p->health[b]);
        sq_body_contact_force(w->bodies[b], p->contact_force[b], &p->contact_nodes[b], &p->contact_depth[b]);
    }
    p->nobstacles = w->nobstacles;
    for (int o = 0; o < w->nobstacles; o++)
        memcpy(p->obstacle_pos[o], w->obstacles[o].point, sizeof p->obstacle_pos[o]);
    p->ntools = w->ntools;
    memcpy(p->tools, w->tools, sizeof p->tools);
}

/* the tool ids requests are checked against: the world's tools plus those of tool jobs not
 * yet applied (caller holds mu) */
static void sq_session_sync_tool_ids_locked(sq_session *s)
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

void sq_session_sync_tool_ids(sq_session *s)
{
    pthread_mutex_lock(&s->mu);
    sq_session_sync_tool_ids_locked(s);
    pthread_mutex_unlock(&s->mu);
}

/* encode the current state of every body and post it (kind < 0: only keep it as the newest
 * frame, for clients that join) */
static void publish(sq_session *s, int kind, double frame_s, double cpu_s)
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
            sq_session_post_locked(s, (sq_out_kind)kind, 0, b, frames[b]);
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
            sq_session_post_locked(s, SQ_OUT_TEXT, 0, 0, sq_reply_blob(e));
        }
    }
    if (kind >= 0 && sq_net_obstacles_move(s->scene))
        sq_session_post_locked(s, SQ_OUT_TEXT, 0, 0, sq_reply_blob(sq_obstacles_frame_json(w)));
    snapshot_locked(s, frame_s);
    if (frame_s >= 0)
        s->snap.frame_cpu_s = cpu_s;
    pthread_mutex_unlock(&s->mu);
}

/* one frame: step and publish */
double sq_session_budget_frac(sq_session *s)
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
    double frac = sq_session_budget_frac(s);
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
    sq_session_post(s, SQ_OUT_TEXT, 0, 0, sq_reply_blob(e));
}

void sq_session_step_frame(sq_session *s, sq_out_kind kind)
{
    double t0 = sq_now(), c0 = sq_thread_cpu();
    sq_haptic_before_frame(&s->haptic, s->world); /* the newest haptic poses (none: nothing) */
    /* real time: the haptic tools' newest poses at every substep too; lockstep: at frame
     * starts, or a channel's ramp between its frames' poses */
    sq_world_set_pose_source(s->world, sq_haptic_pose_source(&s->haptic, s->lockstep), &s->haptic);
    sq_world_step(s->world, s->lockstep ? 0 : s->period);
    budget_account(s, sq_thread_cpu() - c0);
    /* the channels' models, outside the budget. Real time: after the frame is published, so
     * that the channel delays no frame (the poses meanwhile get the last frame's model, as
     * between any two frames); lockstep: before it, so that the poses a client sends once it
     * has the step's frames get that frame's model (deterministic) */
    if (s->lockstep)
        sq_haptic_after_frame(&s->haptic, s->world);
    publish(s, kind, sq_now() - t0, sq_thread_cpu() - c0);
    if (!s->lockstep)
        sq_haptic_after_frame(&s->haptic, s->world);
}


static int setup(sq_session *s)
{
    sq_err err = {{0}};
    s->world = sq_world_create(s->scene, &err);
    if (!s->world) {
        pthread_mutex_lock(&s->mu);
        s->state = SQ_SESSION_FAILED;
        snprintf(s->fail_msg, sizeof s->fail_msg, "scene \"%.60s\": %.400s", s->scene_name, err.msg);
        sq_session_post_locked(s, SQ_OUT_FAILED, 0, 0, NULL);
        pthread_mutex_unlock(&s->mu);
        s->wake(s->wake_arg);
        return -1;
    }
    sq_world *w = s->world;
    if (!s->lockstep) { /* real time: say at load when the scene cannot hold its frame */
        char msg[1024];
        if (sq_world_realtime_check(w, s->period, msg, sizeof msg))
            fprintf(stderr, "squish serve: session %llu, scene \"%.60s\": %s\n", (unsigned long long)s->id,
                    s->scene_name, msg);
        sq_world_prepare_budget(w); /* the first budgeted frame's set-up, at load */
    }
    int maxs = 1;
    sq_blob *topo[SQ_MAX_BODIES];
    for (int b = 0; b < w->nbodies; b++) {
        const sq_mesh *m = sq_body_surface_mesh(w->bodies[b]);
        sq_codec_init_surface(&s->codec[b], m, s->precision);
        topo[b] = sq_encode_topology(&s->codec[b], (uint32_t)b, 0, 0.0, m->surf_tris, m->ntris);
        maxs = SQ_MAX(maxs, m->nsurf);
    }
    s->cur = sq_malloc(sizeof(float) * 3 * (size_t)maxs);
    s->lev = sq_malloc((size_t)maxs);
    char *bj = sq_bodies_json(s);
    /* frame 0 is kept before the session says it is ready: every client gets it with its
     * opened/joined (published after READY, a client served in between had no frame 0) */
    publish(s, -1, 0, 0);
    pthread_mutex_lock(&s->mu);
    s->nbodies = w->nbodies;
    for (int b = 0; b < w->nbodies; b++)
        s->topology[b] = topo[b];
    s->bodies_json = bj;
    snapshot_locked(s, 0);
    sq_session_sync_tool_ids_locked(s);
    s->state = SQ_SESSION_READY;
    sq_session_post_locked(s, SQ_OUT_READY, 0, 0, NULL);
    pthread_mutex_unlock(&s->mu);
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
            changed |= sq_session_do_job(s, &jobs[done++]);
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
            sq_session_step_frame(s, SQ_OUT_FRAME);
        else if (changed && !s->lockstep)
            publish(s, SQ_OUT_FRAME, -1, 0); /* paused: show tool moves, resets, settings */
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
    sq_haptic_hub_init(&s->haptic);
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
        sq_session_post_locked(s, SQ_OUT_FAILED, 0, 0, NULL);
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
    sq_haptic_hub_free(&s->haptic);
    pthread_cond_destroy(&s->cv);
    free(s);
}
