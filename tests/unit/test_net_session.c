/* test_net_session.c - a session's simulation thread without the network
 * (server/net/session.c, jobs.c): start-up, lockstep steps, job replies, latest-wins outbox. */
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "net/session.h"
#include "sq_test.h"

static void no_wake(void *arg)
{
    (void)arg;
}

static void nap(double s)
{
    struct timespec ts = {0, (long)(s * 1e9)};
    nanosleep(&ts, NULL);
}

/* collect outbox items until pred says stop or timeout_s passes; returns items (caller frees
 * with drop_items) */
typedef struct items {
    sq_out *v;
    int n, cap;
} items;

static void take(sq_session *s, items *it)
{
    int n;
    sq_out *o = sq_session_take_outbox(s, &n);
    for (int i = 0; i < n; i++) {
        if (it->n == it->cap) {
            it->cap = it->cap ? 2 * it->cap : 64;
            it->v = sq_realloc(it->v, sizeof *it->v * (size_t)it->cap);
        }
        it->v[it->n++] = o[i];
    }
    free(o);
}

static void drop_items(items *it)
{
    for (int i = 0; i < it->n; i++)
        sq_blob_unref(it->v[i].blob);
    free(it->v);
    memset(it, 0, sizeof *it);
}

static int has_text(const items *it, uint64_t client, const char *needle)
{
    for (int i = 0; i < it->n; i++)
        if (it->v[i].kind == SQ_OUT_TEXT && it->v[i].client == client &&
            strstr((const char *)it->v[i].blob->msg, needle))
            return 1;
    return 0;
}

static int wait_for(sq_session *s, items *it, uint64_t client, const char *needle, double timeout)
{
    double t0 = sq_now();
    while (sq_now() - t0 < timeout) {
        take(s, it);
        if (has_text(it, client, needle))
            return 1;
        nap(0.002);
    }
    return 0;
}

static int wait_ready(sq_session *s, items *it, double timeout)
{
    double t0 = sq_now();
    while (sq_now() - t0 < timeout) {
        take(s, it);
        for (int i = 0; i < it->n; i++)
            if (it->v[i].kind == SQ_OUT_READY)
                return 1;
        nap(0.002);
    }
    return 0;
}

SQ_TEST(net_session_lockstep_steps_in_order)
{
    sq_err err = {{0}};
    sq_scene *sc = sq_scene_default(&err);
    CHECK(sc != NULL);
    if (!sc)
        return;
    sq_session *s = sq_session_start(sc, "default", 1024, 1, 0, no_wake, NULL);
    items it = {0};
    /* the world is built on the session thread; generous timeout for sanitizer builds */
    CHECK(wait_ready(s, &it, 30));
    CHECK(s->nbodies == sc->nbodies && s->topology[0] != NULL);
    sq_msg_header h;
    CHECK(sq_msg_parse_header(s->topology[0]->msg, s->topology[0]->len, &h, &err) == 0);
    CHECK(h.kind == SQ_MSG_TOPOLOGY && h.count0 > 0 && h.count1 > 0);
    drop_items(&it);

    sq_request r;
    memset(&r, 0, sizeof r);
    r.type = SQ_REQ_STEP;
    r.step.frames = 3;
    r.ref_kind = SQ_REF_NUMBER;
    r.ref_num = 5;
    sq_session_push_job(s, 7, &r);
    CHECK(wait_for(s, &it, 7, "\"stepped\"", 30));
    /* every frame, in order, before the reply; nothing replaced */
    int frames = 0, last = 0, reply_at = -1;
    for (int i = 0; i < it.n; i++) {
        if (it.v[i].kind == SQ_OUT_STEP_FRAME) {
            CHECK(sq_msg_parse_header(it.v[i].blob->msg, it.v[i].blob->len, &h, &err) == 0);
            CHECK(h.kind == SQ_MSG_FRAME && (int)h.frame >= last);
            last = (int)h.frame;
            frames++;
            CHECK(reply_at < 0);
        } else if (it.v[i].kind == SQ_OUT_TEXT) {
            reply_at = i;
            CHECK_CONTAINS((const char *)it.v[i].blob->msg, "\"ref\":5");
        }
    }
    CHECK(frames == 3 * sc->nbodies);
    CHECK(last == 3);
    drop_items(&it);

    /* an update of a tool the world does not have: refused with its code, to that client */
    memset(&r, 0, sizeof r);
    r.type = SQ_REQ_TOOL;
    r.tool.id = 77;
    r.tool.has_pos = 1;
    sq_session_push_job(s, 9, &r);
    CHECK(wait_for(s, &it, 9, "unknown_tool", 30));
    drop_items(&it);
    sq_session_stop(s);
    sq_scene_free(sc);
}

SQ_TEST(net_session_realtime_latest_frame_wins)
{
    sq_err err = {{0}};
    sq_scene *sc = sq_scene_default(&err);
    CHECK(sc != NULL);
    if (!sc)
        return;
    sq_session *s = sq_session_start(sc, "default", 2048, 0, 0, no_wake, NULL);
    items it = {0};
    CHECK(wait_ready(s, &it, 30));
    drop_items(&it);
    /* nobody drains for several frame periods: the outbox still holds one frame per body */
    nap(0.3);
    take(s, &it);
    int frames = 0;
    for (int i = 0; i < it.n; i++)
        frames += it.v[i].kind == SQ_OUT_FRAME;
    CHECK(frames >= 1 && frames <= sc->nbodies);
    pthread_mutex_lock(&s->mu);
    long f = s->snap.frame;
    pthread_mutex_unlock(&s->mu);
    CHECK(f >= 2); /* the clock ran meanwhile (50 Hz for 0.3 s; slow builds still pass) */
    drop_items(&it);
    sq_session_stop(s);
    sq_scene_free(sc);
}
