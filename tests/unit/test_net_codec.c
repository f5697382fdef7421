/* test_net_codec.c - binary messages (server/net/codec.c): header layout, quantisation
 * error bound, round trips. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "net/net.h"
#include "sq_test.h"

/* a small grid of surface points with a smooth displacement */
static void make_surface(int n, float *rest, float *cur, double amp)
{
    for (int i = 0; i < n; i++) {
        float x = (float)(i % 10) * 0.1f, y = (float)((i / 10) % 10) * 0.1f, z = (float)(i / 100) * 0.1f;
        rest[3 * i] = x, rest[3 * i + 1] = y, rest[3 * i + 2] = z;
        cur[3 * i] = x + (float)(amp * sin(3 * y));
        cur[3 * i + 1] = y - (float)(0.5 * amp * cos(2 * x));
        cur[3 * i + 2] = z + (float)(amp * x * y);
    }
}

SQ_TEST(net_codec_frame_roundtrip)
{
    enum { N = 300 };
    float rest[3 * N], cur[3 * N];
    unsigned char lev[N];
    make_surface(N, rest, cur, 0.05);
    for (int i = 0; i < N; i++)
        lev[i] = (unsigned char)(i % 3);
    sq_codec c;
    sq_codec_init(&c, N, rest);
    sq_tool tools[2] = {{.id = 7, .shape = SQ_TOOL_GRAB, .active = 1, .pos = {0.1, 0.2, 0.3}, .radius = 0.05},
                        {.id = 9, .shape = SQ_TOOL_BOX, .active = 0, .half = {0.1, 0.4, 0.2}}};
    sq_tool_feedback fb[2] = {{.id = 7, .force = {1.5, -2, 3}}, {.id = 9}};
    sq_blob *b = sq_encode_frame(&c, 2, 41, 0.82, SQ_MSG_FLAG_RESET, cur, lev, tools, fb, 2);
    CHECK(b && b->binary);

    /* fixed header offsets of docs/protocol.md */
    CHECK(!memcmp(b->msg, "SQSH", 4));
    CHECK(b->msg[4] == 1 && b->msg[5] == 0 && b->msg[6] == 2 && b->msg[7] == 1);
    sq_msg_header h;
    sq_err err;
    CHECK(sq_msg_parse_header(b->msg, b->len, &h, &err) == 0);
    CHECK(h.body == 2 && h.frame == 41 && h.time == 0.82 && h.count0 == N && h.count1 == 2);
    CHECK(h.raw_bytes == 7 * N + 72);
    CHECK(h.zbytes + 64 == b->len);

    unsigned char *raw = malloc(h.raw_bytes);
    CHECK(sq_msg_payload(b->msg, b->len, &h, raw, &err) == 0);
    /* reconstruction error within half a quantisation step (plus float rounding of a few
     * ulps of the 1 m coordinates, 1e-6) */
    double worst = 0;
    for (int k = 0; k < 3; k++)
        for (int i = 0; i < N; i++) {
            unsigned q = raw[2 * (k * N + i)] | raw[2 * (k * N + i) + 1] << 8;
            double d = h.offset[k] + q * (double)h.scale[k];
            double want = (double)cur[3 * i + k] - rest[3 * i + k];
            double e = fabs(d - want) - 0.5 * h.scale[k];
            if (e > worst)
                worst = e;
        }
    CHECK(worst < 1e-6);
    /* the precision floor: 1e-4 of the diagonal of the 0.9 x 0.9 x 0.2 box */
    CHECK(h.scale[0] >= c.precision * 0.999f);
    CHECK(!memcmp(raw + 6 * N, lev, N));
    const unsigned char *t = raw + 7 * N;
    CHECK(t[0] == 7 && t[4] == 2 && t[5] == 1);
    float f;
    memcpy(&f, t + 24, 4);
    CHECK(f == 1.5f);
    memcpy(&f, t + 36 + 20, 4);
    CHECK(f == 0.4f); /* box: radius field = largest half extent */
    free(raw);
    sq_blob_unref(b);
    sq_codec_free(&c);
}

SQ_TEST(net_codec_rest_frame_is_tiny)
{
    enum { N = 1000 };
    float *rest = malloc(sizeof(float) * 3 * N), *cur = malloc(sizeof(float) * 3 * N);
    make_surface(N, rest, cur, 0.0);
    sq_codec c;
    sq_codec_init(&c, N, rest);
    sq_blob *b = sq_encode_frame(&c, 0, 1, 0.0, 0, rest, NULL, NULL, NULL, 0);
    sq_msg_header h;
    sq_err err;
    CHECK(sq_msg_parse_header(b->msg, b->len, &h, &err) == 0);
    CHECK(h.scale[0] == 0 && h.scale[1] == 0);
    /* a body at rest: all-zero planes compress to almost nothing (< 0.1 byte per vertex) */
    CHECK(b->len < 64 + N / 10);
    sq_blob_unref(b);
    sq_codec_free(&c);
    free(rest);
    free(cur);
}

SQ_TEST(net_codec_topology_and_nodes)
{
    float rest[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    int tris[3] = {0, 1, 2};
    sq_codec c;
    sq_codec_init(&c, 3, rest);
    sq_blob *b = sq_encode_topology(&c, 1, 0, 0.0, tris, 1);
    sq_msg_header h;
    sq_err err;
    CHECK(sq_msg_parse_header(b->msg, b->len, &h, &err) == 0);
    CHECK(h.kind == 1 && h.count0 == 3 && h.count1 == 1 && h.raw_bytes == 48);
    unsigned char raw[48];
    CHECK(sq_msg_payload(b->msg, b->len, &h, raw, &err) == 0);
    float x;
    memcpy(&x, raw + 12, 4);
    CHECK(x == 1.0f);
    CHECK(raw[36] == 0 && raw[40] == 1 && raw[44] == 2);
    sq_blob_unref(b);

    unsigned char lev[3] = {0, 1, 2};
    b = sq_encode_nodes(0, 5, 0.1, rest, lev, 3);
    CHECK(sq_msg_parse_header(b->msg, b->len, &h, &err) == 0);
    CHECK(h.kind == 3 && h.count0 == 3 && h.raw_bytes == 39);
    unsigned char rn[39];
    CHECK(sq_msg_payload(b->msg, b->len, &h, rn, &err) == 0);
    CHECK(rn[12] == 0 && rn[25] == 1 && rn[38] == 2);
    sq_blob_unref(b);

    /* bad headers are named */
    unsigned char bad[64] = "SQSX";
    CHECK(sq_msg_parse_header(bad, 64, &h, &err) == -1);
    CHECK_CONTAINS(err.msg, "magic");
    CHECK(sq_msg_parse_header(bad, 10, &h, &err) == -1);
    sq_codec_free(&c);
}
