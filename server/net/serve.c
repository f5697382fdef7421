/* serve.c - transport and mounts: the lws context, the HTTP mounts, /healthz, /metrics.
 *
 * sq_serve sets up the listening socket, the mounts (/healthz, /metrics, /snapshot.png on the
 * protocol callback; the viewer's files from --web), the connection caps and the fd limit,
 * then runs the one lws service thread until SIGINT/SIGTERM and shuts down cleanly. Sessions
 * run on their own threads (session.c) and hand frames over through their outbox plus
 * lws_cancel_service() (net_wake); callback.c distributes them.
 */
#include "net/server.h"

#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <sched.h>
#include <signal.h>
#include <stdio.h>
#include <sys/resource.h>
#include <stdlib.h>
#include <string.h>

static volatile sig_atomic_t interrupted; /* set by SIGINT/SIGTERM */

static void on_signal(int sig)
{
    (void)sig;
    interrupted = 1;
}

void net_wake(void *arg)
{
    server *srv = arg;
    if (srv->ctx)
        lws_cancel_service(srv->ctx);
}

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

int net_http_reply(struct lws *wsi, unsigned status, const char *type, const void *body,
                      size_t len)
{
    if (status >= 400) {
        server *srv = lws_context_user(lws_get_context(wsi));
        net_count_refused(srv, status_code(status));
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

/* "/" when the server has no viewer to serve (no --web and none found) */
const char net_no_viewer_page[] =
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
int net_healthz(server *srv, struct lws *wsi, int head)
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
        return net_http_reply(wsi, status, "text/plain", msg, strlen(msg));
    /* HEAD: the headers of the GET reply, no body */
    unsigned char buf[LWS_PRE + 512], *start = buf + LWS_PRE, *p = start, *end = buf + sizeof buf;
    if (lws_add_http_common_headers(wsi, status, "text/plain", (lws_filepos_t)strlen(msg), &p, end) ||
        lws_finalize_write_http_header(wsi, start, &p, end))
        return -1;
    return lws_http_transaction_completed(wsi) ? -1 : 0;
}

/* GET /metrics: Prometheus text format (docs/deploy.md lists the series) */
int net_metrics_reply(server *srv, struct lws *wsi)
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
            net_count_refused_n(&tmp, r->s->refused[k].code, r->s->refused[k].n);
        pthread_mutex_unlock(&r->s->mu);
    }
    for (int i = 0; i < tmp.nrefused; i++) {
        char l[80];
        snprintf(l, sizeof l, "code=\"%.60s\"", tmp.refused[i].code);
        sq_metrics_sample(&m, "squish_refused_total", l, (double)tmp.refused[i].n);
    }
    int rc = net_http_reply(wsi, HTTP_STATUS_OK, "text/plain; version=0.0.4", m.text, m.len);
    sq_metrics_free(&m);
    return rc;
}

/* a file of the web root whose real path leaves the root (a symlink out of it)? */
int net_outside_web_root(server *srv, const char *uri)
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

int net_origin_allowed(server *srv, struct lws *wsi)
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


static const struct lws_protocol_vhost_options mime_json = {NULL, NULL, ".map", "application/json"};
static const struct lws_protocol_vhost_options mime_wasm = {&mime_json, NULL, ".wasm", "application/wasm"};
static const struct lws_protocol_vhost_options mime_mjs = {&mime_wasm, NULL, ".mjs", "text/javascript"};

/* the fd limit: raised to its hard maximum; the connection cap stays below it (two fds per
 * connection serving a file, plus a margin), so that accept never fails with EMFILE (lws
 * would retry it in a busy loop); returns the cap to use */
static int fit_fd_limit(int max_conns)
{
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
    return max_conns;
}

/* --io-priority: the calling (service) thread SCHED_FIFO at prio, with SCHED_RESET_ON_FORK,
 * so that the session threads it starts later run at normal priority. Only the service
 * thread, whose work per wake-up is bounded (PASS_WRITES), preempts the rest of the machine:
 * a pose is read when it arrives, not when the scheduler gets round to it. */
static void raise_io_priority(int prio)
{
    if (prio <= 0)
        return;
    struct sched_param sp = {.sched_priority = prio};
    if (sched_setscheduler(0, SCHED_FIFO | SCHED_RESET_ON_FORK, &sp))
        fprintf(stderr, "squish serve: --io-priority %d: %s (needs CAP_SYS_NICE or an RLIMIT_RTPRIO "
                "of at least %d); the service thread keeps normal priority\n", prio, strerror(errno), prio);
}

/* the listening line on stdout: address, viewer, scenes */
static void print_listening(const server *srv, int port, int builtin)
{
    printf("squish serve: listening on http://%s:%d/ (WebSocket /ws; ", srv->opt->host, port);
    if (srv->opt->web_dir)
        printf("viewer from %s; ", srv->opt->web_dir);
    else
        printf("no viewer: / says to pass --web DIR; ");
    if (builtin) {
        printf("only the built-in cube is offered, as scene \"default\": %s)",
               srv->opt->scenes_dir ? "no scene loaded from --scenes" : "pass --scenes DIR for more");
    } else {
        printf("%d scene%s from %s:", srv->scenes.n, srv->scenes.n == 1 ? "" : "s", srv->opt->scenes_dir);
        for (int i = 0; i < srv->scenes.n; i++)
            printf(" %s", srv->scenes.names[i]);
        printf(")");
    }
    printf("%s\n", srv->opt->lockstep ? " lockstep" : "");
    fflush(stdout);

}

/* clean shutdown: tell the clients, flush for a moment, then end every session; every session
 * thread is told to stop first, so that frames in progress end together */
static void shutdown_sessions(server *srv)
{
    srv->stopping = 1;
    for (int i = 0; i < srv->nslots; i++)
        if (srv->slots[i].s)
            sq_session_cancel(srv->slots[i].s);
    for (int i = 0; i < srv->nslots; i++) {
        srec *r = &srv->slots[i];
        for (int k = 0; r->s && k < r->nmembers; k++) {
            cJSON *e = sq_reply_new("event", NULL);
            cJSON_AddStringToObject(e, "kind", "shutdown");
            cJSON_AddNumberToObject(e, "session", r->s->id);
            cJSON_AddStringToObject(e, "message", "the server is stopping");
            net_send_json(r->members[k], e);
        }
    }
    double until = sq_now() + 0.3;
    while (sq_now() < until) {
        srv->pass_writes = 0;
        lws_service(srv->ctx, 0);
        int busy = 0;
        for (int i = 0; i < srv->nslots; i++)
            for (int k = 0; srv->slots[i].s && k < srv->slots[i].nmembers; k++)
                busy |= srv->slots[i].members[k]->fcount > 0;
        if (!busy)
            break;
    }
    /* the simulation and render threads stop first, so that nothing wakes the context
     * while it is destroyed; then the connections close */
    for (int i = 0; i < srv->nslots; i++)
        net_end_session(srv, &srv->slots[i]);
}

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
    if (opt->scenes_dir && sq_scene_list_load_dir(&srv.scenes, opt->scenes_dir, "squish serve"))
        fprintf(stderr, "squish serve: cannot read scene directory %s; serving the default scene\n",
                opt->scenes_dir);
    int builtin = srv.scenes.n == 0;
    if (srv.scenes.n == 0) {
        sq_scene *sc = sq_scene_default(err);
        if (!sc)
            return sq_err_prefix(err, "default scene");
        sq_scene_list_add(&srv.scenes, sc, "default");
    }
    srv.nslots = opt->max_sessions;
    srv.slots = sq_calloc((size_t)srv.nslots, sizeof *srv.slots);

    static struct lws_protocols protocols[2];
    memset(protocols, 0, sizeof protocols);
    protocols[0].name = "squish";
    protocols[0].callback = net_callback;
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
    int max_conns = fit_fd_limit(opt->max_conns);
    srv.conns = sq_conns_new(max_conns, opt->max_conns_per_addr);
    srv.guard = sq_guard_new();

    raise_io_priority(opt->io_priority); /* before any thread is started */
    srv.snapshotter = sq_snapshotter_start(net_wake, &srv);
    srv.ctx = lws_create_context(&info);
    if (!srv.ctx) {
        sq_err_set(err, "cannot listen on %s:%d (port in use, or the address is not local?); "
                   "choose another --port or --host", opt->host, opt->port);
        goto fail;
    }
    srv.vhost = lws_get_vhost_by_name(srv.ctx, "default");
    int port = srv.vhost ? lws_get_vhost_listen_port(srv.vhost) : opt->port;
    print_listening(&srv, port, builtin);

    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);

    lws_sul_schedule(srv.ctx, 0, &srv.sul, net_tick, TICK_US);
    while (!interrupted) {
        srv.pass_writes = 0; /* the pass's budget of writes (PASS_WRITES, clients.c) */
        if (lws_service(srv.ctx, 0) < 0)
            break;
    }

    /* clean shutdown: tell the clients, flush for a moment, then close everything; every
     * session thread is told to stop first, so that frames in progress end together */
    shutdown_sessions(&srv);
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
    sq_scene_list_free(&srv.scenes);
    free(srv.slots);
    sq_conns_free(srv.conns);
    sq_guard_free(srv.guard);
    return rc;
}
