/* snapshot_http.c - GET /snapshot.png: requests waiting for their PNG (lws thread).
 *
 * A request is validated (query.c) and rate-limited, handed to its session thread, which
 * captures the world for the render worker (snapshot.c); the rendered PNG wakes the waiting
 * HTTP connection. Waits are found by connection, and survive a connection that closes.
 */
#include "net/server.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* GET /snapshot.png?session=ID[&size=WxH]: validate, rate-limit, hand to the session */
int net_snapshot_request(server *srv, struct lws *wsi, conn *pss)
{
    char buf[8][128], msg[400];
    const char *args[8];
    int nargs = 0;
    for (; nargs < 8 && lws_hdr_copy_fragment(wsi, buf[nargs], sizeof buf[nargs], WSI_TOKEN_HTTP_URI_ARGS,
                                              nargs) > 0; nargs++)
        args[nargs] = buf[nargs];
    sq_snapshot_query q;
    int status = sq_snapshot_query_parse(args, nargs, SQ_SNAPSHOT_MAX_SIZE, &q, msg, sizeof msg);
    srec *r = status ? NULL : net_find_session(srv, q.session);
    if (!status && !r) {
        snprintf(msg, sizeof msg, "no session %llu; use /snapshot.png?session=ID with the id of "
                 "'opened'\n", (unsigned long long)q.session);
        status = HTTP_STATUS_NOT_FOUND;
    }
    if (status)
        return net_http_reply(wsi, (unsigned)status, "text/plain", msg, strlen(msg));
    if (!srv->snapshotter) {
        snprintf(msg, sizeof msg, "snapshots are not available in this server\n");
        return net_http_reply(wsi, 503, "text/plain", msg, strlen(msg));
    }
    int width = q.width, height = q.height;
    double now = sq_now();
    if (now - r->last_snapshot < SNAP_MIN_INTERVAL || srv->nwaits >= SNAP_MAX_WAITING) {
        snprintf(msg, sizeof msg, "too many snapshots: at most one per %.2f s per session; retry "
                 "later\n", SNAP_MIN_INTERVAL);
        return net_http_reply(wsi, 429, "text/plain", msg, strlen(msg));
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
snap_wait *net_snapshot_wait_of(server *srv, struct lws *wsi)
{
    for (snap_wait *w = srv->waits; w; w = w->next)
        if (w->wsi == wsi)
            return w;
    return NULL;
}

/* rendered snapshots: wake their HTTP connections (by handle: a result whose connection
 * closed meanwhile only frees its render place) */
void net_snapshot_results(server *srv)
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
void net_snapshot_closed(server *srv, struct lws *wsi)
{
    for (snap_wait *w = srv->waits; w; w = w->next)
        if (w->wsi == wsi)
            w->wsi = NULL;
}

int net_snapshot_write(server *srv, struct lws *wsi)
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
        rc = net_http_reply(wsi, HTTP_STATUS_OK, "image/png", j->png, j->png_len);
    } else {
        char msg[300];
        snprintf(msg, sizeof msg, "snapshot failed: %.250s\n", j->error);
        rc = net_http_reply(wsi, HTTP_STATUS_INTERNAL_SERVER_ERROR, "text/plain", msg, strlen(msg));
    }
    sq_snap_job_free(j);
    return rc;
}

