/* test_parsers.c - regressions from fuzzing the parsers a user or client can reach (mesh
 * readers, scene loader, request decoder, snapshot query): each input here once crashed,
 * hit undefined behaviour or used unbounded memory. See docs/security.md, "parsers". */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh/mesh.h"
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
