/* callback.c - the lws protocol callback: every event of every connection.
 *
 * Connection caps at accept, the WebSocket upgrade (only /ws, only allowed Origins), client
 * creation, message assembly (fragments, --max-message) handed to dispatch.c, one write per
 * SERVER_WRITEABLE (clients.c), the HTTP filters (GET and HEAD only, long URIs, the web
 * root) and routes (/healthz, /metrics, /snapshot.png), and the wake-ups of the session
 * threads (EVENT_WAIT_CANCELLED: drain every outbox, collect rendered snapshots).
 */
#include "net/server.h"
#include "net/haptic_ws.h"

#include <arpa/inet.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>

/* a fragment of a WebSocket message: gathered up to --max-message; a complete one is handled
 * (JSON text, or a haptic binary message) or refused */
static int on_receive(server *srv, struct lws *wsi, client *c, const void *in, size_t len)
{
    if (!c)
        return -1;
    double t_read = sq_now(); /* a pose's read time: its channel's latency starts here */
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
    if (c->rx_binary && !c->rx_oversize && sq_haptic_is_message((unsigned char *)c->rx, c->rx_len)) {
        net_haptic_binary(c, (unsigned char *)c->rx, c->rx_len, t_read);
    } else if (c->rx_binary) {
        net_send_error(c, &unread, SQ_CODE_BAD_JSON, "binary messages are not accepted; send JSON text");
    } else if (c->rx_oversize) {
        char m[160];
        snprintf(m, sizeof m, "text message larger than %zu bytes (--max-message) dropped; "
                 "send smaller messages", max);
        net_send_error(c, &unread, SQ_CODE_TOO_LARGE, m);
    } else {
        net_handle_request(c, c->rx, c->rx_len);
    }
    c->rx_len = 0;
    if (c->rx_cap > 65536) { /* do not keep a large buffer around */
        free(c->rx);
        c->rx = NULL;
        c->rx_cap = 0;
    }
    return 0;
}

/* an HTTP request before it is served: only GET and HEAD, a bounded request line, files only
 * inside the web root; 0: go on, else lws's answer (close) */
static int filter_http(server *srv, struct lws *wsi)
{
    /* a file request pipelined behind a waiting snapshot would be served before it
     * by lws: close too */
    if (net_snapshot_wait_of(srv, wsi))
        return -1;
    /* only GET and HEAD; files only inside the web root */
    if (lws_hdr_total_length(wsi, WSI_TOKEN_POST_URI) || lws_hdr_total_length(wsi, WSI_TOKEN_PUT_URI) ||
        lws_hdr_total_length(wsi, WSI_TOKEN_DELETE_URI) || lws_hdr_total_length(wsi, WSI_TOKEN_PATCH_URI) ||
        lws_hdr_total_length(wsi, WSI_TOKEN_OPTIONS_URI)) {
        net_count_refused(srv, "405");
        lws_return_http_status(wsi, HTTP_STATUS_METHOD_NOT_ALLOWED,
                               "method not allowed: this server answers GET and HEAD only");
        return 1;
    }
    if (lws_hdr_total_length(wsi, WSI_TOKEN_GET_URI) > MAX_URI ||
        lws_hdr_total_length(wsi, WSI_TOKEN_HEAD_URI) > MAX_URI) {
        net_count_refused(srv, "414");
        lws_return_http_status(wsi, HTTP_STATUS_REQ_URI_TOO_LONG,
                               "request line too long: the path and query may have 2048 bytes");
        return 1;
    }
    char uri[1024] = "";
    if (lws_hdr_copy(wsi, uri, sizeof uri, WSI_TOKEN_GET_URI) <= 0)
        lws_hdr_copy(wsi, uri, sizeof uri, WSI_TOKEN_HEAD_URI);
    if (uri[0] == '/' && strcmp(uri, "/ws") && net_outside_web_root(srv, uri)) {
        lwsl_notice("squish: %s leads outside the web root (a symlink): refused\n", uri);
        net_count_refused(srv, "404");
        lws_return_http_status(wsi, HTTP_STATUS_NOT_FOUND, "not found");
        return 1;
    }
    return 0;
}

/* connection caps, at accept: over them the socket (fd) is closed at once */
static int filter_network(server *srv, int fd)
{
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

int net_callback(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in,
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
        if (!net_origin_allowed(srv, wsi)) {
            lwsl_notice("squish: WebSocket upgrade refused: Origin not in --origin list\n");
            net_count_refused(srv, "403");
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

    case LWS_CALLBACK_RECEIVE:
        return on_receive(srv, wsi, c, in, len);
    case LWS_CALLBACK_SERVER_WRITEABLE:
        return c ? net_write_one(c) : 0;

    case LWS_CALLBACK_CLOSED:
        if (c) {
            net_leave_session(c);
            for (int i = 0; i < c->fcount; i++)
                sq_blob_unref(c->fifo[(c->fhead + i) % c->fcap]);
            free(c->fifo);
            free(c->rx);
            free(c);
            pss->c = NULL;
        }
        return 0;

    case LWS_CALLBACK_CLOSED_HTTP:
        net_snapshot_closed(srv, wsi);
        break;

    case LWS_CALLBACK_HTTP_WRITEABLE: 
        if (net_snapshot_wait_of(srv, wsi))
            return net_snapshot_write(srv, wsi);
        break;

    case LWS_CALLBACK_EVENT_WAIT_CANCELLED:
        if (srv) {
            for (int i = 0; i < srv->nslots; i++)
                if (srv->slots[i].s)
                    net_drain_session(srv, &srv->slots[i]);
            net_snapshot_results(srv);
        }
        return 0;

    case LWS_CALLBACK_FILTER_HTTP_CONNECTION: {
        int rc = filter_http(srv, wsi);
        if (rc)
            return rc;
        break;
    }
    case LWS_CALLBACK_FILTER_NETWORK_CONNECTION:
        return filter_network(srv, (int)(intptr_t)in);
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
                return net_healthz(srv, wsi, 1);
        }
        if (net_snapshot_wait_of(srv, wsi)) {
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
            return net_snapshot_request(srv, wsi, pss);
        if (!strcmp(uri, "/healthz"))
            return net_healthz(srv, wsi, 0);
        if (!strcmp(uri, "/metrics"))
            return net_metrics_reply(srv, wsi);
        if (!srv->opt->web_dir && (!strcmp(uri, "/") || !strcmp(uri, "/index.html")))
            return net_http_reply(wsi, HTTP_STATUS_OK, "text/html; charset=utf-8", net_no_viewer_page,
                              strlen(net_no_viewer_page));
        return net_http_reply(wsi, HTTP_STATUS_NOT_FOUND, "text/plain", "not found\n", 10);
    }
    default:
        break;
    }
    return lws_callback_http_dummy(wsi, reason, user, in, len);
}
