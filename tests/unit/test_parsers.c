/* test_parsers.c - regressions from fuzzing the parsers a user or client can reach (mesh
 * readers, scene loader, request decoder, snapshot query): each input here once crashed,
 * hit undefined behaviour or used unbounded memory. See docs/security.md, "parsers". */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh/mesh.h"
#include "mesh/mesh_internal.h"
#include "net/query.h"
#include "sq_test.h"

/* write text to NAME in the test's temporary directory; returns the path (static buffer) */
static const char *put_file(const char *name, const char *text)
{
    static char path[2][1024];
    static int k;
    char *p = path[k++ & 1];
    snprintf(p, sizeof path[0], "%s/%s", sq_test_tmpdir(), name);
    FILE *f = fopen(p, "wb");
    if (f) {
        fputs(text, f);
        fclose(f);
    }
    return p;
}

#define MSH22_HEAD "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n"
#define TET_NODES "$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n%s 0 0 1\n$EndNodes\n"
#define TET_ELEMS "$Elements\n1\n1 4 0 1 2 3 %s\n$EndElements\n"

/* a Gmsh 2.2 file with one tet whose 4th node tag is `tag` */
static const char *msh22_with_tag(const char *tag)
{
    static char text[512], fmt[512];
    snprintf(fmt, sizeof fmt, "%s%s%s", MSH22_HEAD, TET_NODES, TET_ELEMS);
    snprintf(text, sizeof text, fmt, tag, tag);
    return text;
}

/* -9223372036854775808 made read_long negate LLONG_MIN (signed overflow, UBSan abort in every
 * reader); now any integer beyond +-LLONG_MAX is refused with its line and the token */
SQ_TEST(parsers_mesh_integer_out_of_range)
{
    static const struct {
        const char *name, *text, *want;
    } cases[] = {
        {"min.msh", NULL, "min.msh:9: node number out of range: '-9223372036854775808'"},
        {"big.msh", NULL, "big.msh:9: node number out of range: '9223372036854775808'"},
        {"long.msh", NULL, "long.msh:9: node number out of range: '123456789012345678901234567890'"},
        {"v41.msh",
         "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 4 1 4\n3 1 0 4\n1\n2\n3\n"
         "-9223372036854775808\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n$EndNodes\n",
         "v41.msh:10: node tag out of range: '-9223372036854775808'"},
        {"t.mesh",
         "MeshVersionFormatted 2\nDimension 3\nVertices\n4\n0 0 0 0\n1 0 0 0\n0 1 0 0\n0 0 1 0\n"
         "Tetrahedra\n1\n1 2 3 -9223372036854775808 0\nEnd\n",
         "t.mesh:11: tetrahedron vertex out of range: '-9223372036854775808'"},
        {"t.node", "4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n-9223372036854775808 0 0 1\n",
         "t.node:5: point number out of range: '-9223372036854775808'"},
    };
    for (size_t i = 0; i < SQ_COUNTOF(cases); i++) {
        const char *text = cases[i].text;
        if (!text)
            text = msh22_with_tag(i == 0 ? "-9223372036854775808" : i == 1 ? "9223372036854775808"
                                                                          : "123456789012345678901234567890");
        const char *path = put_file(cases[i].name, text);
        if (strstr(cases[i].name, ".node"))
            put_file("t.ele", "1 4 0\n1 1 2 3 4\n");
        sq_err err = {0};
        sq_mesh *m = sq_mesh_load(path, &err);
        CHECK(m == NULL);
        sq_mesh_free(m);
        CHECK_CONTAINS(err.msg, cases[i].want);
    }
    /* the extremes that fit still read: +-9223372036854775807 are valid (sparse) node tags */
    static const char *const ok[] = {"9223372036854775807", "-9223372036854775807"};
    for (int i = 0; i < 2; i++) {
        sq_err err = {0};
        sq_mesh *m = sq_mesh_load(put_file("edge.msh", msh22_with_tag(ok[i])), &err);
        CHECK(m != NULL);
        if (!m)
            printf("    %s: %s\n", ok[i], err.msg);
        else
            CHECK(m->nnodes == 4 && m->ntets == 1);
        sq_mesh_free(m);
    }
}

/* a 207-byte mesh of two unit tets 1000 m apart made the locator's grid 27.5 M cells
 * (~150 MB, allocated on the first locate, i.e. when a scene loads it); the cell count is now
 * bounded by the item count (4 n + 64 per grid), whatever the extent */
SQ_TEST(parsers_locator_bounded_by_mesh_size)
{
    const char *far = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n8\n1 0 0 0\n2 1 0 0\n3 0 1 0\n"
                      "4 0 0 1\n5 1000 1000 1000\n6 1001 1000 1000\n7 1000 1001 1000\n8 1000 1000 1001\n"
                      "$EndNodes\n$Elements\n2\n1 4 0 1 2 3 4\n2 4 0 5 6 7 8\n$EndElements\n";
    CHECK(strlen(far) == 207);
    sq_err err = {0};
    sq_mesh *m = sq_mesh_load(put_file("far.msh", far), &err);
    CHECK(m != NULL);
    if (!m) {
        printf("    %s\n", err.msg);
        return;
    }
    size_t items = 0, cells = sq_locator_cells(m, &items);
    /* 2 tets + 8 boundary triangles: at most (4*2+64) + (4*8+64) cells */
    CHECK(cells <= 4 * (size_t)(m->ntets + m->ntris) + 128);
    CHECK(items >= (size_t)(m->ntets + m->ntris));
    /* location still right: a point inside each tet, and one between them (nearest is a
     * boundary triangle of either tet, so the barycentrics are those of an outside point) */
    const double in0[3] = {0.1, 0.1, 0.1}, in1[3] = {1000.1, 1000.2, 1000.3}, mid[3] = {500, 500, 500};
    double b[4];
    CHECK(sq_mesh_locate(m, in0, b) == 0);
    CHECK(b[0] >= 0 && b[1] >= 0 && b[2] >= 0 && b[3] >= 0);
    CHECK(sq_mesh_locate(m, in1, b) == 1);
    CHECK(b[0] >= 0 && b[1] >= 0 && b[2] >= 0 && b[3] >= 0);
    int t = sq_mesh_locate(m, mid, b);
    CHECK(t == 0 || t == 1);
    CHECK(b[0] < 0 || b[1] < 0 || b[2] < 0 || b[3] < 0);
    sq_mesh_free(m);

    /* 64 tets scattered over a 1e6 m cube: still bounded by the count */
    char *text = malloc(1 << 16);
    size_t k = (size_t)snprintf(text, 1 << 16, "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n256\n");
    unsigned s = 7;
    for (int e = 0; e < 64; e++) {
        double o[3];
        for (int c = 0; c < 3; c++) {
            s = s * 1103515245u + 12345u;
            o[c] = 1e6 * ((s >> 8) & 0xffff) / 65536.0;
        }
        for (int v = 0; v < 4; v++)
            k += (size_t)snprintf(text + k, (1 << 16) - k, "%d %.17g %.17g %.17g\n", 4 * e + v + 1,
                                  o[0] + (v == 1), o[1] + (v == 2), o[2] + (v == 3));
    }
    k += (size_t)snprintf(text + k, (1 << 16) - k, "$EndNodes\n$Elements\n64\n");
    for (int e = 0; e < 64; e++)
        k += (size_t)snprintf(text + k, (1 << 16) - k, "%d 4 0 %d %d %d %d\n", e + 1, 4 * e + 1,
                              4 * e + 2, 4 * e + 3, 4 * e + 4);
    snprintf(text + k, (1 << 16) - k, "$EndElements\n");
    m = sq_mesh_load(put_file("scattered.msh", text), &err);
    free(text);
    CHECK(m != NULL);
    if (m) {
        cells = sq_locator_cells(m, &items);
        CHECK(cells <= 4 * (size_t)(m->ntets + m->ntris) + 128);
        /* each tet's own interior point is found in it */
        int bad = 0;
        for (int e = 0; e < m->ntets; e++) {
            double p[3] = {0, 0, 0};
            for (int v = 0; v < 4; v++)
                for (int c = 0; c < 3; c++)
                    p[c] += 0.25 * m->x[3 * m->tets[4 * e + v] + c];
            bad += sq_mesh_locate(m, p, b) != e;
        }
        CHECK(bad == 0);
        sq_mesh_free(m);
    }
}

/* GET /snapshot.png query arguments (server/net/query.c) */
SQ_TEST(parsers_snapshot_query)
{
    static const struct {
        const char *args[4];
        int nargs, status;
        uint64_t session;
        int w, h;
        const char *msg;
    } cases[] = {
        {{"session=1025"}, 1, 0, 1025, 800, 600, ""},
        {{"room=bio", "size=64x48", "session=4294967295"}, 3, 0, 4294967295u, 64, 48, ""},
        {{"size=64x48"}, 1, 404, 0, 0, 0, "no session (missing)"},
        {{"session="}, 1, 404, 0, 0, 0, "no session ;"},
        {{"session=9007199254740991"}, 1, 0, 9007199254740991ull, 800, 600, ""},
        {{"session=9007199254740992"}, 1, 404, 0, 0, 0, "no session 9007199254740992"},
        {{"session=-1"}, 1, 404, 0, 0, 0, "no session -1"},
        {{"session= 12"}, 1, 404, 0, 0, 0, "no session  12"},
        {{"session=0x10"}, 1, 404, 0, 0, 0, "no session 0x10"},
        {{"session=1", "session=2"}, 2, 400, 0, 0, 0, "session given twice"},
        {{"session=1", "size=1x1", "size=2x2"}, 3, 400, 0, 0, 0, "size given twice"},
        {{"session=1", "size=99999x1"}, 2, 400, 0, 0, 0, "each side must be in"},
        {{"session=1", "size=10"}, 2, 400, 0, 0, 0, "use WxH"},
        {{"sessions=1"}, 1, 404, 0, 0, 0, "(missing)"},
        /* found by fuzz_query: a newline in the echoed value made a two-line answer */
        {{"size=2048x24248", "session=4+29629496x\n1"}, 2, 404, 0, 0, 0, "no session 4+29629496x?1;"},
        {{"size=2048\n2048", "session=429496"}, 2, 400, 0, 0, 0, "size '2048?2048': use WxH"},
    };
    for (size_t i = 0; i < SQ_COUNTOF(cases); i++) {
        sq_snapshot_query q;
        char msg[400] = "";
        int st = sq_snapshot_query_parse(cases[i].args, cases[i].nargs, 2048, &q, msg, sizeof msg);
        CHECK(st == cases[i].status);
        if (st != cases[i].status)
            printf("    case %zu: status %d (%s)\n", i, st, msg);
        if (!st) {
            CHECK(q.session == cases[i].session && q.width == cases[i].w && q.height == cases[i].h);
        } else {
            CHECK_CONTAINS(msg, cases[i].msg);
            CHECK(strchr(msg, '\n') == msg + strlen(msg) - 1);
        }
    }
}

/* the instance rule of session ids: 100 * local + K, local's generation masked to fit */
SQ_TEST(parsers_session_id_instance)
{
    uint64_t local;
    CHECK(sq_session_id_public(1025, 0) == 1025);
    CHECK(sq_session_id_local(1025, 0, &local) == 0 && local == 1025);
    uint64_t mask = sq_session_gen_mask(7, 10);
    uint64_t top = mask << 10 | 1023;
    uint64_t id = sq_session_id_public(top, 7);
    CHECK(id % 100 == 7 && 100 * top + 7 == id); /* no wrap at the largest local id */
    CHECK(id < (1ull << 49));                     /* 15 decimal digits: JSON keeps it exact */
    CHECK(sq_session_id_local(id, 7, &local) == 0 && local == top);
    CHECK(sq_session_id_local(id, 8, &local) == -1);
    CHECK(sq_session_id_local(sq_session_id_public(1024, 12), 12, &local) == 0 && local == 1024);
    char s[32];
    snprintf(s, sizeof s, "%llu", (unsigned long long)sq_session_id_public(1024, 3));
    CHECK(!strcmp(s, "102403")); /* what docker/nginx.conf's map matches: ...03 */
    CHECK(sq_session_gen_mask(0, 10) == (1ull << 39) - 1);
    CHECK((sq_session_gen_mask(0, 10) << 10 | 1023) < (1ull << 49));
}

/* a sibling of read_long: `squish mesh box 2147483647 1 1` computed nx + 1 in int (signed
 * overflow) before the size check; now a message */
SQ_TEST(parsers_mesh_box_int_max)
{
    sq_err err = {{0}};
    sq_mesh *m = sq_mesh_box(2147483647, 1, 1, NULL, NULL, &err);
    CHECK(m == NULL);
    sq_mesh_free(m);
    CHECK_CONTAINS(err.msg, "box: 2147483647 x 1 x 1 cells is too large");
    m = sq_mesh_box(2147483647, 2147483647, 2147483647, NULL, NULL, &err);
    CHECK(m == NULL);
    sq_mesh_free(m);
}
