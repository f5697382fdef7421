/* haptic_ws.c - the service thread's side of the haptic channel (docs/protocol.md, "Haptic
 * channel"): the "haptic" request that opens or closes a channel, pose messages in and one
 * force message out per pose, answered here from the tool's model of the last frame
 * (net/haptic.h) without waiting for the session thread. Bad poses are dropped and counted;
 * at most one error message per second per channel (or client) says why, so that a flood does
 * not turn into a flood of replies.
 */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "net/server.h"
#include "net/haptic_ws.h"
#include "net/le.h"

/* the ref of a raw request object, for the reply */
static void read_ref(const cJSON *o, sq_request *req)
{
    memset(req, 0, sizeof *req);
    req->type = SQ_REQ_NONE;
    const cJSON *ref = cJSON_GetObjectItemCaseSensitive(o, "ref");
    if (cJSON_IsString(ref) && strlen(ref->valuestring) < sizeof req->ref_str) {
        req->ref_kind = SQ_REF_STRING;
        snprintf(req->ref_str, sizeof req->ref_str, "%s", ref->valuestring);
    } else if (cJSON_IsNumber(ref) && isfinite(ref->valuedouble)) {
        req->ref_kind = SQ_REF_NUMBER;
        req->ref_num = ref->valuedouble;
    }
}

static int read_number(client *c, const sq_request *req, const cJSON *o, const char *key,
                       const char *path, double lo, double hi, int *has, double *v)
{
    const cJSON *it = cJSON_GetObjectItemCaseSensitive(o, key);
    *has = 0;
    if (!it)
        return 0;
    char m[240];
    if (!cJSON_IsNumber(it)) {
        snprintf(m, sizeof m, "%s: must be a number", path);
        net_send_error(c, req, SQ_CODE_BAD_FIELD, m);
        return -1;
    }
    if (!isfinite(it->valuedouble) || it->valuedouble < lo || it->valuedouble > hi) {
        snprintf(m, sizeof m, "%s: %g is outside [%g, %g]; send a value in range", path,
                 it->valuedouble, lo, hi);
        net_send_error(c, req, SQ_CODE_OUT_OF_RANGE, m);
        return -1;
    }
    *has = 1;
    *v = it->valuedouble;
    return 0;
}

static cJSON *channel_json(const sq_haptic_channel *ch)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "channel", ch->id);
    cJSON_AddNumberToObject(o, "tool", ch->tool);
    cJSON_AddNumberToObject(o, "poses", (double)ch->poses);
    cJSON_AddNumberToObject(o, "answered", (double)ch->answered);
    cJSON_AddNumberToObject(o, "dropped_rate", (double)ch->dropped_rate);
    cJSON_AddNumberToObject(o, "dropped_bad", (double)ch->dropped_bad);
    cJSON_AddNumberToObject(o, "model_frame", (double)ch->model_frame);
    cJSON_AddNumberToObject(o, "model_nodes", ch->model_valid ? ch->model.nnodes : 0);
    cJSON *l = cJSON_AddObjectToObject(o, "latency");
    cJSON_AddNumberToObject(l, "n", (double)ch->latency.n);
    cJSON_AddNumberToObject(l, "p50", 1e3 * sq_haptic_latency_quantile(&ch->latency, 0.5));
    cJSON_AddNumberToObject(l, "p99", 1e3 * sq_haptic_latency_quantile(&ch->latency, 0.99));
    cJSON_AddNumberToObject(l, "max", 1e3 * ch->latency.max);
    return o;
}

cJSON *net_haptic_stats_json(sq_session *s)
{
    cJSON *o = cJSON_CreateObject();
    cJSON *a = cJSON_AddArrayToObject(o, "channels");
    pthread_mutex_lock(&s->haptic.mu);
    for (int i = 0; i < SQ_MAX_TOOLS; i++)
        if (s->haptic.ch[i].id)
            cJSON_AddItemToArray(a, channel_json(&s->haptic.ch[i]));
    cJSON_AddNumberToObject(o, "bad_channel", (double)s->haptic.bad_channel);
    cJSON_AddNumberToObject(o, "bad_pose", (double)s->haptic.bad_pose);
    cJSON_AddNumberToObject(o, "model_ms", 1e3 * s->haptic.model_cpu_s);
    pthread_mutex_unlock(&s->haptic.mu);
    return o;
}

void net_haptic_close_owner(sq_session *s, uint64_t owner)
{
    sq_haptic_hub *h = &s->haptic;
    pthread_mutex_lock(&h->mu);
    for (int i = 0; i < SQ_MAX_TOOLS; i++)
        if (h->ch[i].id && h->ch[i].owner == owner) {
            h->ch[i].id = 0;
            sq_haptic_live_publish(h, i, -1, NULL);
            __atomic_sub_fetch(&h->nopen, 1, __ATOMIC_RELEASE);
        }
    pthread_mutex_unlock(&h->mu);
}

/* a field haptic does not take: an error naming it sent, 1 */
static int unknown_field(client *c, const sq_request *req, const cJSON *o)
{
    static const char *known[] = {"type", "ref", "tool", "open", "stiffness", "damping", "device_mass", "focus", "ramp"};
    const cJSON *it;
    cJSON_ArrayForEach(it, o) {
        int ok = 0;
        for (size_t k = 0; k < sizeof known / sizeof *known; k++)
            ok |= !strcmp(it->string, known[k]);
        if (!ok) {
            char m[160];
            snprintf(m, sizeof m, "haptic.%.60s: unknown field; haptic takes tool, open, stiffness, "
                     "damping, device_mass, focus, ramp, ref", it->string);
            net_send_error(c, req, SQ_CODE_BAD_FIELD, m);
            return 1;
        }
    }
    return 0;
}

/* the shape of the session's tool id (0 for one known only by its id so far), -1 if none */
static int tool_shape(sq_session *s, int id)
{
    int shape = -1;
    pthread_mutex_lock(&s->mu);
    for (int i = 0; i < s->ntool_ids; i++)
        if (s->tool_ids[i] == id)
            shape = 0;
    for (int i = 0; i < s->snap.ntools; i++)
        if (s->snap.tools[i].id == id)
            shape = (int)s->snap.tools[i].shape;
    pthread_mutex_unlock(&s->mu);
    return shape;
}

/* a free slot ch made channel of tool id, its settings the scene's "haptic" defaults, else the
 * channel's own (h->mu held) */
static void channel_new(sq_haptic_hub *h, sq_haptic_channel *ch, int id, const sq_scene_haptic *sh)
{
    memset(ch, 0, sizeof *ch);
    ch->id = h->next_id++;
    ch->tool = id;
    ch->tokens = SQ_HAPTIC_BURST;
    ch->last_refill = sq_now();
    ch->last_error = -1e9;
    ch->coupling.damping = sh->given & SQ_SCENE_HAPTIC_DAMPING ? sh->damping : SQ_HAPTIC_DAMPING;
    ch->coupling.device_mass = sh->given & SQ_SCENE_HAPTIC_DEVICE_MASS ? sh->device_mass : SQ_HAPTIC_DEVICE_MASS;
    ch->focus = sh->given & SQ_SCENE_HAPTIC_FOCUS ? sh->focus : SQ_HAPTIC_FOCUS;
    if (sh->given & SQ_SCENE_HAPTIC_STIFFNESS) {
        ch->coupling.stiffness = sh->stiffness;
        ch->stiffness_given = 1;
    }
}

int net_haptic_request(client *c, const char *text, size_t len)
{
    /* cheap test first: every other request goes on to the decoder untouched */
    if (!memmem(text, len, "haptic", 6))
        return 0;
    cJSON *o = cJSON_ParseWithLength(text, len);
    const cJSON *type = o ? cJSON_GetObjectItemCaseSensitive(o, "type") : NULL;
    if (!cJSON_IsString(type) || strcmp(type->valuestring, "haptic") != 0) {
        cJSON_Delete(o);
        return 0;
    }
    sq_request req;
    read_ref(o, &req);
    char m[320];
    if (unknown_field(c, &req, o)) {
        cJSON_Delete(o);
        return 1;
    }
    srec *r = c->sess;
    if (!c->greeted) {
        net_send_error(c, &req, SQ_CODE_HELLO_REQUIRED, "haptic: send hello first");
        goto done;
    }
    if (!r || !c->ready) {
        net_send_error(c, &req, SQ_CODE_NO_SESSION, "haptic: open or join a session first");
        goto done;
    }
    if (r->controller != c->serial) {
        net_send_error(c, &req, SQ_CODE_NOT_CONTROLLER, "haptic: only the session's controller may "
                       "open a haptic channel; take_control first");
        goto done;
    }
    const cJSON *tool = cJSON_GetObjectItemCaseSensitive(o, "tool");
    if (!cJSON_IsNumber(tool) || tool->valuedouble != floor(tool->valuedouble)) {
        net_send_error(c, &req, SQ_CODE_BAD_FIELD, "haptic.tool: missing or not an integer; send "
                       "the id of a tool of the session");
        goto done;
    }
    if (!(tool->valuedouble >= 0 && tool->valuedouble <= SQ_NET_MAX_TOOL_ID)) {
        snprintf(m, sizeof m, "haptic.tool: %g is outside [0, %d]; send the id of a tool of the "
                 "session", tool->valuedouble, SQ_NET_MAX_TOOL_ID);
        net_send_error(c, &req, SQ_CODE_OUT_OF_RANGE, m);
        goto done;
    }
    const cJSON *open = cJSON_GetObjectItemCaseSensitive(o, "open");
    if (open && !cJSON_IsBool(open)) {
        net_send_error(c, &req, SQ_CODE_BAD_FIELD, "haptic.open: must be true or false");
        goto done;
    }
    int want_open = !open || cJSON_IsTrue(open);
    const cJSON *ramp = cJSON_GetObjectItemCaseSensitive(o, "ramp");
    if (ramp && !cJSON_IsBool(ramp)) {
        net_send_error(c, &req, SQ_CODE_BAD_FIELD, "haptic.ramp: must be true or false");
        goto done;
    }
    int has_k, has_b, has_m, has_f;
    double k = 0, b = 0, mass = 0, focus = 0;
    if (read_number(c, &req, o, "stiffness", "haptic.stiffness", 0, SQ_HAPTIC_STIFFNESS_MAX, &has_k, &k) ||
        read_number(c, &req, o, "damping", "haptic.damping", 0, SQ_HAPTIC_DAMPING_MAX, &has_b, &b) ||
        read_number(c, &req, o, "device_mass", "haptic.device_mass", SQ_HAPTIC_DEVICE_MASS_MIN,
                    SQ_HAPTIC_DEVICE_MASS_MAX, &has_m, &mass) ||
        read_number(c, &req, o, "focus", "haptic.focus", 0, SQ_HAPTIC_FOCUS_MAX, &has_f, &focus))
        goto done;
    int id = (int)tool->valuedouble;
    sq_session *s = r->s;
    const int shape = tool_shape(s, id);
    if (shape < 0) {
        snprintf(m, sizeof m, "haptic.tool: %d is not a tool of this session; create it with a "
                 "tool request first", id);
        net_send_error(c, &req, SQ_CODE_UNKNOWN_TOOL, m);
        goto done;
    }
    sq_haptic_hub *h = &s->haptic;
    pthread_mutex_lock(&h->mu);
    sq_haptic_channel *ch = NULL;
    for (int i = 0; i < SQ_MAX_TOOLS; i++)
        if (h->ch[i].id && h->ch[i].tool == id)
            ch = &h->ch[i];
    cJSON *rep = sq_reply_new("haptic", &req);
    if (!want_open) {
        if (ch) {
            ch->id = 0;
            sq_haptic_live_publish(h, (int)(ch - h->ch), -1, NULL);
            __atomic_sub_fetch(&h->nopen, 1, __ATOMIC_RELEASE);
        }
        cJSON_AddNumberToObject(rep, "tool", id);
        cJSON_AddBoolToObject(rep, "open", 0);
        pthread_mutex_unlock(&h->mu);
        net_send_json(c, rep);
        goto done;
    }
    if (!ch) {
        for (int i = 0; i < SQ_MAX_TOOLS && !ch; i++)
            if (!h->ch[i].id)
                ch = &h->ch[i];
        if (!ch) { /* one slot per tool of at most SQ_MAX_TOOLS: cannot happen */
            pthread_mutex_unlock(&h->mu);
            cJSON_Delete(rep);
            net_send_error(c, &req, SQ_CODE_INTERNAL, "haptic: no free channel slot");
            goto done;
        }
        channel_new(h, ch, id, &s->scene->haptic);
        __atomic_add_fetch(&h->nopen, 1, __ATOMIC_RELEASE);
    }
    ch->owner = c->serial;
    c->haptic = 1;
    ch->shape = shape;
    if (ramp)
        ch->ramp = cJSON_IsTrue(ramp);
    if (has_b)
        ch->coupling.damping = b;
    if (has_m)
        ch->coupling.device_mass = mass;
    const double safe = sq_haptic_safe_stiffness(ch->coupling.device_mass, 1.0 / s->period);
    if (has_k)
        ch->coupling.stiffness = k, ch->stiffness_given = 1;
    else if (!ch->stiffness_given)
        ch->coupling.stiffness = safe; /* follows the device's mass */
    if (has_f)
        ch->focus = focus;
    cJSON_AddNumberToObject(rep, "channel", ch->id);
    cJSON_AddNumberToObject(rep, "tool", id);
    cJSON_AddBoolToObject(rep, "open", 1);
    cJSON_AddNumberToObject(rep, "version", SQ_HAPTIC_VERSION);
    cJSON_AddNumberToObject(rep, "max_rate", SQ_HAPTIC_MAX_RATE);
    cJSON_AddNumberToObject(rep, "burst", SQ_HAPTIC_BURST);
    cJSON_AddNumberToObject(rep, "pos_max", SQ_NET_POS_MAX);
    cJSON_AddNumberToObject(rep, "stiffness", ch->coupling.stiffness);
    cJSON_AddNumberToObject(rep, "stiffness_safe", safe);
    cJSON_AddNumberToObject(rep, "damping", ch->coupling.damping);
    cJSON_AddNumberToObject(rep, "device_mass", ch->coupling.device_mass);
    cJSON_AddNumberToObject(rep, "focus", ch->focus);
    cJSON_AddBoolToObject(rep, "ramp", ch->ramp);
    cJSON_AddNumberToObject(rep, "model_frame", (double)ch->model_frame);
    pthread_mutex_unlock(&h->mu);
    net_send_json(c, rep);
done:
    cJSON_Delete(o);
    return 1;
}

/* an error for a dropped pose, at most one per second per channel (ch NULL: per client) */
static void pose_error(client *c, double *last, sq_net_code code, const char *msg)
{
    static const sq_request none = {.ref_kind = SQ_REF_NULL};
    double now = sq_now();
    if (now - *last < 1.0)
        return;
    *last = now;
    net_send_error(c, &none, code, msg);
}

/* the read-to-written time of a force of channel id (slot of hub h) */
static void record_latency(sq_session *s, uint32_t id, double seconds)
{
    sq_haptic_hub *h = &s->haptic;
    pthread_mutex_lock(&h->mu);
    for (int i = 0; i < SQ_MAX_TOOLS; i++)
        if (h->ch[i].id && h->ch[i].id == id)
            sq_haptic_latency_add(&h->ch[i].latency, seconds);
    pthread_mutex_unlock(&h->mu);
}

/* a force out: written now, from the pose's receive callback, when nothing waits in the
 * client's queue and its socket takes it without blocking (lws_send_pipe_choked); else
 * queued like any reply (timed when written: net_haptic_written). The pose's receive
 * callback comes at most PASS_WRITES other clients' writes after the pass began (clients.c),
 * and the force does not wait for the next writeable pass behind the frames that pass writes
 * to every viewer (20 of them in tests/net/bench-haptic.mjs) */
static void send_force(client *c, sq_blob *b, uint32_t id, uint32_t seq, double t_read)
{
    if (c->closing || c->fcount > 0 || lws_send_pipe_choked(c->wsi)) {
        if (c->hq_n < HQ_MAX && !c->closing) {
            int k = (c->hq_head + c->hq_n++) % HQ_MAX;
            c->hq_read[k] = t_read;
            c->hq_seq[k] = seq;
        }
        net_fifo_push(c, b);
        return;
    }
    int n = lws_write(c->wsi, b->msg, b->len, LWS_WRITE_BINARY);
    if (c->sess) {
        c->sess->bytes_sent += b->len;
        record_latency(c->sess->s, id, sq_now() - t_read);
    }
    c->srv->bytes_out += b->len;
    if (n < (int)b->len) { /* a failed connection: closed from its next writeable callback */
        c->closing = 1;
        lws_callback_on_writable(c->wsi);
    }
    sq_blob_unref(b);
}

void net_haptic_written(client *c, const sq_blob *b)
{
    if (!c->hq_n || !c->sess)
        return;
    uint32_t id = get_u32(b->msg + 8), seq = get_u32(b->msg + 12);
    if (c->hq_seq[c->hq_head] != seq)
        return; /* queued while the ring was full: not timed */
    double t_read = c->hq_read[c->hq_head];
    c->hq_head = (c->hq_head + 1) % HQ_MAX;
    c->hq_n--;
    record_latency(c->sess->s, id, sq_now() - t_read);
}

void net_haptic_binary(client *c, const unsigned char *msg, size_t len, double t_read)
{
    sq_haptic_pose p;
    char why[200];
    srec *r = c->sess;
    if (sq_haptic_pose_decode(msg, len, &p, why, sizeof why)) {
        if (r) {
            pthread_mutex_lock(&r->s->haptic.mu);
            r->s->haptic.bad_pose++;
            pthread_mutex_unlock(&r->s->haptic.mu);
        }
        pose_error(c, &c->haptic_last_error, SQ_CODE_BAD_POSE, why);
        return;
    }
    if (!r || !c->ready) {
        pose_error(c, &c->haptic_last_error, SQ_CODE_BAD_CHANNEL,
                   "haptic pose: this client is in no session; open one and send a haptic request");
        return;
    }
    sq_haptic_hub *h = &r->s->haptic;
    pthread_mutex_lock(&h->mu);
    sq_haptic_channel *ch = NULL;
    for (int i = 0; i < SQ_MAX_TOOLS; i++)
        if (h->ch[i].id && h->ch[i].id == p.channel)
            ch = &h->ch[i];
    if (!ch || ch->owner != c->serial || r->controller != c->serial) {
        h->bad_channel++;
        pthread_mutex_unlock(&h->mu);
        snprintf(why, sizeof why, "haptic pose: channel %u is not open for this client%s; send a "
                 "haptic request for your tool", p.channel,
                 ch && r->controller != c->serial ? " (it no longer controls the session)" : "");
        pose_error(c, &c->haptic_last_error, SQ_CODE_BAD_CHANNEL, why);
        return;
    }
    ch->poses++;
    double now = sq_now();
    ch->tokens = fmin(SQ_HAPTIC_BURST, ch->tokens + (now - ch->last_refill) * SQ_HAPTIC_MAX_RATE);
    ch->last_refill = now;
    if (ch->tokens < 1) {
        ch->dropped_rate++;
        snprintf(why, sizeof why, "haptic pose: channel %u sends more than %g poses per second "
                 "(burst %g); poses dropped (stats.haptic.channels[].dropped_rate)", p.channel,
                 SQ_HAPTIC_MAX_RATE, SQ_HAPTIC_BURST);
        double *last = &ch->last_error;
        pthread_mutex_unlock(&h->mu);
        pose_error(c, last, SQ_CODE_RATE_LIMITED, why);
        return;
    }
    ch->tokens -= 1;
    int bad = !isfinite(p.t);
    for (int k = 0; k < 3; k++)
        bad |= !isfinite(p.pos[k]) || fabs(p.pos[k]) > SQ_NET_POS_MAX;
    if (bad) {
        ch->dropped_bad++;
        snprintf(why, sizeof why, "haptic pose: channel %u seq %u: time and position must be finite "
                 "and each coordinate within +-%g m (got %g %g %g at t %g); pose dropped",
                 p.channel, p.seq, SQ_NET_POS_MAX, p.pos[0], p.pos[1], p.pos[2], p.t);
        double *last = &ch->last_error;
        pthread_mutex_unlock(&h->mu);
        pose_error(c, last, SQ_CODE_BAD_POSE, why);
        return;
    }
    sq_haptic_out out;
    sq_haptic_eval(&ch->model, ch->model_valid, ch->model_frame, &ch->coupling, &ch->state, p.pos, p.t, &out);
    if (ch->shape != SQ_TOOL_BOX)
        memset(out.torque, 0, sizeof out.torque);
    memcpy(ch->pose, out.tool, sizeof ch->pose);
    ch->has_pose = 1;
    sq_haptic_live_publish(h, (int)(ch - h->ch), ch->tool, out.tool); /* the step's next substep */
    ch->answered++;
    uint32_t frame = (uint32_t)ch->model_frame;
    pthread_mutex_unlock(&h->mu);
    sq_blob *b = sq_blob_new(SQ_HAPTIC_FORCE_BYTES, 1);
    sq_haptic_force_encode(p.channel, p.seq, frame, p.t, &out, b->msg);
    send_force(c, b, p.channel, p.seq, t_read);
}
