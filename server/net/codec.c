/* codec.c - the binary messages of docs/protocol.md: topology, frame, nodes.
 *
 * A 64-byte little-endian header then a zlib stream. Frames carry surface displacements
 * from rest quantised to 16 bits per axis (planar x, y, z), a level byte per vertex and the
 * tool records; the quantisation step never goes below a precision floor, so that noise
 * below what anyone can see does not reach the compressor.
 */
#include "net/net.h"
#include "net/le.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

_Static_assert(SQ_BLOB_PRE >= 16, "LWS_PRE headroom");

sq_blob *sq_blob_new(size_t len, int binary)
{
    sq_blob *b = sq_malloc(sizeof *b + SQ_BLOB_PRE + len + 1);
    b->refs = 1;
    b->binary = binary;
    b->len = len;
    b->msg = b->buf + SQ_BLOB_PRE;
    b->msg[len] = 0;
    return b;
}

sq_blob *sq_blob_text(const char *s)
{
    size_t n = strlen(s);
    sq_blob *b = sq_blob_new(n, 0);
    memcpy(b->msg, s, n);
    return b;
}

sq_blob *sq_blob_ref(sq_blob *b)
{
    if (b)
        __atomic_add_fetch(&b->refs, 1, __ATOMIC_RELAXED);
    return b;
}

void sq_blob_unref(sq_blob *b)
{
    if (b && __atomic_sub_fetch(&b->refs, 1, __ATOMIC_ACQ_REL) == 0)
        free(b);
}

void sq_codec_init(sq_codec *c, int nsurf, const float *rest_xyz)
{
    memset(c, 0, sizeof *c);
    c->nsurf = nsurf;
    c->rest = sq_malloc(sizeof(float) * 3 * (size_t)(nsurf > 0 ? nsurf : 1));
    c->cur = sq_malloc(sizeof(float) * 3 * (size_t)(nsurf > 0 ? nsurf : 1));
    c->level = sq_calloc((size_t)(nsurf > 0 ? nsurf : 1), 1);
    if (nsurf > 0)
        memcpy(c->rest, rest_xyz, sizeof(float) * 3 * (size_t)nsurf);
    /* precision floor: a fraction of the rest bounding-box diagonal */
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int i = 0; i < nsurf; i++)
        for (int k = 0; k < 3; k++) {
            lo[k] = fminf(lo[k], rest_xyz[3 * i + k]);
            hi[k] = fmaxf(hi[k], rest_xyz[3 * i + k]);
        }
    double diag2 = 0;
    for (int k = 0; k < 3 && nsurf > 0; k++)
        diag2 += (double)(hi[k] - lo[k]) * (hi[k] - lo[k]);
    c->diagonal = (float)sqrt(diag2);
    c->precision = (float)(SQ_CODEC_PRECISION * sqrt(diag2));
}

void sq_codec_init_surface(sq_codec *c, const sq_mesh *m, double precision_rel)
{
    float *rest = sq_malloc(sizeof(float) * 3 * (size_t)(m->nsurf + 1));
    for (int i = 0; i < m->nsurf; i++)
        for (int k = 0; k < 3; k++)
            rest[3 * i + k] = (float)m->x[3 * m->surf_nodes[i] + k];
    sq_codec_init(c, m->nsurf, rest);
    c->precision = (float)(precision_rel * c->diagonal);
    free(rest);
}

void sq_codec_free(sq_codec *c)
{
    free(c->rest);
    free(c->cur);
    free(c->level);
    free(c->raw);
    free(c->z);
    memset(c, 0, sizeof *c);
}

static void grow(unsigned char **p, size_t *cap, size_t need)
{
    if (*cap < need) {
        *p = sq_realloc(*p, need);
        *cap = need;
    }
}

/* header + compressed payload into a new blob; raw is the uncompressed payload */
static sq_blob *pack(int kind, unsigned flags, uint32_t body, uint32_t frame, double time,
                     uint32_t count0, uint32_t count1, const float offset[3], const float scale[3],
                     const unsigned char *raw, size_t raw_len, unsigned char **zbuf, size_t *zcap)
{
    uLongf zlen = compressBound((uLong)raw_len);
    grow(zbuf, zcap, zlen);
    if (compress2(*zbuf, &zlen, raw, (uLong)raw_len, 6) != Z_OK)
        zlen = 0; /* cannot happen with compressBound space; an empty payload is then sent */
    sq_blob *b = sq_blob_new(SQ_MSG_HEADER + zlen, 1);
    unsigned char *h = b->msg;
    memset(h, 0, SQ_MSG_HEADER);
    memcpy(h, "SQSH", 4);
    put_u16(h + 4, SQ_PROTOCOL_VERSION);
    h[6] = (unsigned char)kind;
    h[7] = (unsigned char)flags;
    put_u32(h + 8, body);
    put_u32(h + 12, frame);
    put_f64(h + 16, time);
    put_u32(h + 24, count0);
    put_u32(h + 28, count1);
    for (int k = 0; k < 3; k++) {
        put_f32(h + 32 + 4 * k, offset ? offset[k] : 0.f);
        put_f32(h + 44 + 4 * k, scale ? scale[k] : 0.f);
    }
    put_u32(h + 56, (uint32_t)raw_len);
    put_u32(h + 60, (uint32_t)zlen);
    memcpy(h + SQ_MSG_HEADER, *zbuf, zlen);
    return b;
}

sq_blob *sq_encode_topology(sq_codec *c, uint32_t body, uint32_t frame, double time,
                            const int *tris, int ntris)
{
    size_t n = (size_t)c->nsurf, raw_len = 12 * n + 12 * (size_t)ntris;
    grow(&c->raw, &c->raw_cap, raw_len + 1);
    unsigned char *p = c->raw;
    for (size_t i = 0; i < 3 * n; i++, p += 4)
        put_f32(p, c->rest[i]);
    for (size_t i = 0; i < 3 * (size_t)ntris; i++, p += 4)
        put_u32(p, (uint32_t)tris[i]);
    return pack(SQ_MSG_TOPOLOGY, 0, body, frame, time, (uint32_t)n, (uint32_t)ntris, NULL, NULL,
                c->raw, raw_len, &c->z, &c->z_cap);
}

sq_blob *sq_encode_frame(sq_codec *c, uint32_t body, uint32_t frame, double time,
                         unsigned flags, const float *cur, const unsigned char *level,
                         const sq_tool *tools, const sq_tool_feedback *feedback, int ntools)
{
    size_t n = (size_t)c->nsurf;
    size_t raw_len = 7 * n + SQ_TOOL_RECORD * (size_t)ntools;
    grow(&c->raw, &c->raw_cap, raw_len + 1);

    /* per-axis range of the displacement; non-finite values (a body about to be reset)
     * are sent as zero displacement */
    float lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0}, offset[3], scale[3];
    int first = 1;
    for (size_t i = 0; i < n; i++) {
        for (int k = 0; k < 3; k++) {
            float d = cur[3 * i + k] - c->rest[3 * i + k];
            if (!isfinite(d))
                d = 0;
            if (first || d < lo[k]) lo[k] = d;
            if (first || d > hi[k]) hi[k] = d;
        }
        first = 0;
    }
    for (int k = 0; k < 3; k++) {
        offset[k] = lo[k];
        float range = hi[k] - lo[k];
        scale[k] = fmaxf(range / 65535.0f, c->precision);
        if (range <= 0)
            scale[k] = 0;
        else if (range / scale[k] > 65535.0f) /* float rounding: keep q within 16 bits */
            scale[k] = nextafterf(range / 65535.0f, INFINITY);
    }

    /* planar quantised displacements, then levels, then tools */
    unsigned char *p = c->raw;
    for (int k = 0; k < 3; k++) {
        float inv = scale[k] > 0 ? 1.0f / scale[k] : 0.0f;
        for (size_t i = 0; i < n; i++, p += 2) {
            float d = cur[3 * i + k] - c->rest[3 * i + k];
            if (!isfinite(d))
                d = 0;
            long q = lrintf((d - offset[k]) * inv);
            if (q < 0) q = 0;
            if (q > 65535) q = 65535;
            put_u16(p, (unsigned)q);
        }
    }
    if (level)
        memcpy(p, level, n);
    else
        memset(p, 0, n);
    p += n;
    for (int t = 0; t < ntools; t++, p += SQ_TOOL_RECORD) {
        const sq_tool *tl = &tools[t];
        float radius = (float)tl->radius;
        if (tl->shape == SQ_TOOL_BOX)
            radius = (float)fmax(tl->half[0], fmax(tl->half[1], tl->half[2]));
        put_u32(p, (uint32_t)tl->id);
        p[4] = (unsigned char)tl->shape;
        p[5] = tl->active ? 1 : 0;
        put_u16(p + 6, 0);
        for (int k = 0; k < 3; k++)
            put_f32(p + 8 + 4 * k, (float)tl->pos[k]);
        put_f32(p + 20, radius);
        for (int k = 0; k < 3; k++)
            put_f32(p + 24 + 4 * k, feedback ? (float)feedback[t].force[k] : 0.f);
    }
    return pack(SQ_MSG_FRAME, flags, body, frame, time, (uint32_t)n, (uint32_t)ntools, offset,
                scale, c->raw, raw_len, &c->z, &c->z_cap);
}

sq_blob *sq_encode_nodes(uint32_t body, uint32_t frame, double time, const float *xyz,
                         const unsigned char *level, int n)
{
    size_t raw_len = 13 * (size_t)n;
    unsigned char *raw = sq_malloc(raw_len + 1), *p = raw;
    for (int i = 0; i < n; i++, p += 13) {
        for (int k = 0; k < 3; k++)
            put_f32(p + 4 * k, xyz[3 * i + k]);
        p[12] = level ? level[i] : 0;
    }
    unsigned char *z = NULL;
    size_t zcap = 0;
    sq_blob *b = pack(SQ_MSG_NODES, 0, body, frame, time, (uint32_t)n, 0, NULL, NULL, raw,
                      raw_len, &z, &zcap);
    free(raw);
    free(z);
    return b;
}

int sq_msg_parse_header(const unsigned char *m, size_t len, sq_msg_header *h, sq_err *err)
{
    if (len < SQ_MSG_HEADER)
        return sq_err_set(err, "binary message of %zu bytes is shorter than the %d-byte header",
                          len, SQ_MSG_HEADER);
    if (memcmp(m, "SQSH", 4))
        return sq_err_set(err, "binary message does not start with the magic SQSH");
    unsigned version = (unsigned)m[4] | (unsigned)m[5] << 8;
    if (version != SQ_PROTOCOL_VERSION)
        return sq_err_set(err, "binary message version %u, expected %d", version,
                          SQ_PROTOCOL_VERSION);
    h->kind = m[6];
    h->flags = m[7];
    h->body = get_u32(m + 8);
    h->frame = get_u32(m + 12);
    h->time = get_f64(m + 16);
    h->count0 = get_u32(m + 24);
    h->count1 = get_u32(m + 28);
    for (int k = 0; k < 3; k++) {
        h->offset[k] = get_f32(m + 32 + 4 * k);
        h->scale[k] = get_f32(m + 44 + 4 * k);
    }
    h->raw_bytes = get_u32(m + 56);
    h->zbytes = get_u32(m + 60);
    if (h->kind < SQ_MSG_TOPOLOGY || h->kind > SQ_MSG_NODES)
        return sq_err_set(err, "binary message kind %d unknown (1..3)", h->kind);
    if ((size_t)h->zbytes != len - SQ_MSG_HEADER)
        return sq_err_set(err, "binary message: zbytes %u but %zu payload bytes", h->zbytes,
                          len - SQ_MSG_HEADER);
    return 0;
}

int sq_msg_payload(const unsigned char *m, size_t len, const sq_msg_header *h,
                   unsigned char *out, sq_err *err)
{
    uLongf n = h->raw_bytes;
    if (len < SQ_MSG_HEADER + (size_t)h->zbytes)
        return sq_err_set(err, "binary message truncated");
    int rc = uncompress(out, &n, m + SQ_MSG_HEADER, h->zbytes);
    if (rc != Z_OK || n != h->raw_bytes)
        return sq_err_set(err, "binary payload does not inflate to %u bytes (zlib %d)",
                          h->raw_bytes, rc);
    return 0;
}
