/* clients.c - client queues: what the service thread sends to one WebSocket client.
 *
 * A realtime frame goes into a one-slot-per-body mailbox of the client (a newer frame
 * replaces an unsent one: the client skips it, counted), everything else into its bounded
 * FIFO (a client that stops reading is dropped). Writes happen only in SERVER_WRITEABLE, one
 * message per callback (net_write_one), at most PASS_WRITES per service pass to clients
 * without a haptic channel (the others are asked again for the next pass): a frame's fan-out
 * to many viewers is spread over a few passes, and a haptic pose that arrives meanwhile is
 * read after at most PASS_WRITES writes instead of after all of them. Refused requests are
 * counted here for /metrics.
 */
#include "net/server.h"
#include "net/haptic_ws.h"

#include <stdlib.h>
#include <string.h>

/* count n refused requests of a code (a protocol error code or an HTTP status) */
void net_count_refused_n(server *srv, const char *code, long n)
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

void net_count_refused(server *srv, const char *code)
{
    net_count_refused_n(srv, code, 1);
}

/* ---------------------------------------------------------------- sending */

void net_fifo_push(client *c, sq_blob *b)
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

void net_send_json(client *c, cJSON *o)
{
    net_fifo_push(c, sq_reply_blob(o));
}

void net_send_error(client *c, const sq_request *req, sq_net_code code, const char *msg)
{
    net_count_refused(c->srv, sq_net_code_name(code));
    net_fifo_push(c, sq_error_blob(code, msg, req));
}

/* a realtime frame: latest wins */
void net_slot_put(client *c, int body, sq_blob *b)
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

void net_clear_slots(client *c)
{
    for (int b = 0; b < SQ_MAX_BODIES; b++) {
        sq_blob_unref(c->slot[b]);
        c->slot[b] = NULL;
    }
}

/* the client's nodes reply is written: run its waiting nodes request, if any. A client
 * that does not read its replies thus never has more than one nodes job and one nodes
 * message on the server. */
void net_nodes_check(client *c)
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
int net_write_one(client *c)
{
    if (c->closing)
        return -1;
    if (!c->haptic && c->srv->pass_writes >= PASS_WRITES) {
        lws_callback_on_writable(c->wsi); /* this pass has written its share: the next one */
        return 0;
    }
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
    if (c->haptic && b->binary && len == SQ_HAPTIC_FORCE_BYTES && sq_haptic_is_message(b->msg, len))
        net_haptic_written(c, b);
    else if (!c->haptic)
        c->srv->pass_writes++;
    sq_blob_unref(b);
    if (n < (int)len)
        return -1;
    net_nodes_check(c);
    int more = c->fcount > 0;
    for (int i = 0; i < SQ_MAX_BODIES && !more; i++)
        more = c->slot[i] != NULL;
    if (more)
        lws_callback_on_writable(c->wsi);
    return 0;
}
