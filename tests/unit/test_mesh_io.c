/* test_mesh_io.c - mesh readers and writers: round trips, real Gmsh files, broken files. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh/mesh.h"
#include "sq_test.h"
#include "test_sim_helpers.h"

static sq_mesh *load_data(const char *name, sq_err *err)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/mesh/%s", sq_test_data(), name);
    return sq_mesh_load(path, err);
}

static double volume_of(const sq_mesh *m)
{
    sq_mesh_info in;
    sq_mesh_measure(m, &in);
    return in.volume;
}

/* write m with the writer for ext, read back, compare */
static void roundtrip(const sq_mesh *m, const char *ext)
{
    char path[1024];
    sq_err err = {0};
    snprintf(path, sizeof path, "%s/rt_%p%s", sq_test_tmpdir(), (const void *)m, ext);
    CHECK(sq_mesh_save(m, path, &err) == 0);
    sq_mesh *r = sq_mesh_load(path, &err);
    CHECK(r != NULL);
    if (!r) {
        printf("    %s: %s\n", ext, err.msg);
        return;
    }
    CHECK(r->nnodes == m->nnodes);
    CHECK(r->ntets == m->ntets);
    CHECK(r->ntris == m->ntris);
    /* writers print the shortest exact decimal: coordinates come back bit for bit */
    int same = r->nnodes == m->nnodes;
    for (int i = 0; same && i < 3 * m->nnodes; i++)
        same = r->x[i] == m->x[i];
    CHECK(same);
    same = r->ntets == m->ntets;
    for (int i = 0; same && i < 4 * m->ntets; i++)
        same = r->tets[i] == m->tets[i];
    CHECK(same);
    CHECK_NEAR(volume_of(r), volume_of(m), 1e-14);
    sq_mesh_free(r);
}

SQ_TEST(mesh_io_roundtrip_all_formats)
{
    sq_err err = {0};
    const double size[3] = {0.3, 0.7, 1.1}, origin[3] = {-0.1, 1.0 / 3, 2e-7};
    sq_mesh *m = sq_mesh_box(3, 2, 4, size, origin, &err);
    CHECK(m != NULL);
    if (!m)
        return;
    roundtrip(m, ".msh");
    roundtrip(m, ".mesh");
    roundtrip(m, ".node");
    roundtrip(m, ".ele");
    sq_mesh_free(m);
    /* a real Gmsh mesh too */
    m = load_data("cube_h05_v41.msh", &err);
    CHECK(m != NULL);
    if (m) {
        roundtrip(m, ".msh");
        roundtrip(m, ".mesh");
        roundtrip(m, ".node");
        sq_mesh_free(m);
    }
}

/* the same cube written by Gmsh as 2.2, 4.1 and Medit, by hand as TetGen and with sparse
 * shuffled node tags: all read to the same 14 nodes, 24 tets, unit volume */
SQ_TEST(mesh_io_gmsh_medit_tetgen_same_cube)
{
    const char *files[] = {"cube_h1.msh", "cube_h1_v41.msh", "cube_h1.mesh", "cube_tetgen.node",
                           "cube_tetgen.ele", "sparse_tags.msh", "all_negative.msh",
                           "cube_h1_v41_param.msh"};
    sq_mesh *ref = NULL;
    for (size_t f = 0; f < SQ_COUNTOF(files); f++) {
        sq_err err = {0};
        sq_mesh *m = load_data(files[f], &err);
        CHECK(m != NULL);
        if (!m) {
            printf("    %s: %s\n", files[f], err.msg);
            continue;
        }
        CHECK(m->nnodes == 14);
        CHECK(m->ntets == 24);
        CHECK(m->ntris == 24);
        /* exact cube: volume and area are sums of dyadic values (1e-14) */
        CHECK_NEAR(volume_of(m), 1.0, 1e-14);
        for (int t = 0; t < m->ntets; t++)
            CHECK(sq_tet_volume(m, t) > 0);
        if (!ref) {
            ref = m;
            continue;
        }
        /* same node coordinates as a set: compare the sums of x, x^2 */
        double s1 = 0, s2 = 0, r1 = 0, r2 = 0;
        for (int i = 0; i < 3 * m->nnodes; i++) {
            s1 += m->x[i];
            s2 += m->x[i] * m->x[i] * (1 + i % 3);
            r1 += ref->x[i];
            r2 += ref->x[i] * ref->x[i] * (1 + i % 3);
        }
        CHECK_NEAR(s1, r1, 1e-12);
        CHECK_NEAR(s2, r2, 1e-12);
        sq_mesh_free(m);
    }
    sq_mesh_free(ref);
}

/* each broken file: the message names file, line and problem */
SQ_TEST(mesh_io_broken_files)
{
    static const struct {
        const char *file, *where, *what;
    } cases[] = {
        {"truncated.msh", "truncated.msh:13:", "the file is truncated"},
        {"truncated_elements.msh", "truncated_elements.msh:83:", "fewer than 4 nodes"},
        {"truncated.mesh", "truncated.mesh:81:", "the file is truncated"},
        {"bad_index.msh", "bad_index.msh:26:", "refers to node 99"},
        {"bad_ref.ele", "bad_ref.ele:12:", "refers to node 0"},
        {"nan_coord.msh", "nan_coord.msh:10:", "coordinate y is not finite"},
        {"bad_number.msh", "bad_number.msh:8:", "expected a number for coordinate x, found '0.5x'"},
        {"inverted.msh", "inverted.msh:28:", "inverted"},
        {"degenerate.msh", "degenerate.msh:47:", "degenerate"},
        {"unreferenced.msh", "unreferenced.msh:20:", "not used by any tetrahedron"},
        {"no_tets.msh", "no_tets.msh", "no tetrahedra"},
        {"huge_count.msh", "huge_count.msh:5:", "impossible node count: 1000000000000"},
        {"binary.msh", "binary.msh:2:", "binary .msh is not supported"},
        {"does_not_exist.msh", "does_not_exist.msh", "cannot open"},
        {"cube.geo", "cube.geo", "unknown mesh format"},
        {"truncated_v41.msh", "truncated_v41.msh:170:", "the file is truncated"},
        {"lonely.node", "lonely.ele: cannot open", "needs both NAME.node and NAME.ele"},
        {"unknown_keyword.mesh", "unknown_keyword.mesh:6:", "unknown keyword 'BogusSection'"},
        {"cube_order2.msh", "cube_order2.msh", "only higher-order tetrahedra (24 of them)"},
    };
    for (size_t i = 0; i < SQ_COUNTOF(cases); i++) {
        sq_err err = {0};
        sq_mesh *m = load_data(cases[i].file, &err);
        CHECK(m == NULL);
        sq_mesh_free(m);
        CHECK_CONTAINS(err.msg, cases[i].where);
        CHECK_CONTAINS(err.msg, cases[i].what);
    }
}

/* every prefix of a valid file either loads or fails with a message: never a crash */
SQ_TEST(mesh_io_every_truncation)
{
    const char *files[] = {"cube_h1.msh", "cube_h1_v41.msh", "cube_h1.mesh"};
    for (size_t f = 0; f < SQ_COUNTOF(files); f++) {
        char src[1024], dst[1024];
        snprintf(src, sizeof src, "%s/mesh/%s", sq_test_data(), files[f]);
        snprintf(dst, sizeof dst, "%s/cut_%s", sq_test_tmpdir(), files[f]);
        sq_err err = {0};
        size_t len;
        char *buf = sq_read_file(src, &len, 1 << 20, &err);
        CHECK(buf != NULL);
        if (!buf)
            continue;
        int bad = 0, loaded = 0;
        /* every 7th cut keeps the test fast under ASan */
        for (size_t cut = 0; cut < len; cut += 7) {
            FILE *o = fopen(dst, "wb");
            fwrite(buf, 1, cut, o);
            fclose(o);
            err.msg[0] = 0;
            sq_mesh *m = sq_mesh_load(dst, &err);
            if (m) {
                loaded++;
                sq_mesh_free(m);
            } else if (!strstr(err.msg, dst)) {
                bad++;
            }
        }
        CHECK(bad == 0);
        /* only cuts in the trailing end markers may still load */
        CHECK(loaded <= 4);
        free(buf);
    }
}

SQ_TEST(mesh_io_vtk_deterministic_with_fields)
{
    sq_err err = {0};
    sq_mesh *m = sq_mesh_box(2, 1, 1, NULL, NULL, &err);
    CHECK(m != NULL);
    if (!m)
        return;
    double *d = calloc(3 * (size_t)m->nnodes, sizeof *d), *v = calloc(3 * (size_t)m->nnodes, sizeof *v);
    int *lev = calloc((size_t)m->nnodes, sizeof *lev);
    for (int i = 0; i < m->nnodes; i++) {
        d[3 * i + 2] = -0.001 * i;
        v[3 * i] = i == 0 ? -0.0 : 1.0 / 3 * i;
        lev[i] = i % 3;
    }
    char p1[1024], p2[1024];
    snprintf(p1, sizeof p1, "%s/a.vtk", sq_test_tmpdir());
    snprintf(p2, sizeof p2, "%s/b.vtk", sq_test_tmpdir());
    CHECK(sq_mesh_write_vtk(m, p1, d, v, lev, &err) == 0);
    CHECK(sq_mesh_write_vtk(m, p2, d, v, lev, &err) == 0);
    size_t n1, n2;
    char *a = sq_read_file(p1, &n1, 1 << 20, &err), *b = sq_read_file(p2, &n2, 1 << 20, &err);
    CHECK(a && b && n1 == n2 && !memcmp(a, b, n1));
    if (a) {
        CHECK_CONTAINS(a, "# vtk DataFile Version 3.0\n");
        CHECK_CONTAINS(a, "DATASET UNSTRUCTURED_GRID\nPOINTS 12 double\n");
        CHECK_CONTAINS(a, "CELLS 12 60\n4 ");
        CHECK_CONTAINS(a, "CELL_TYPES 12\n10\n");
        CHECK_CONTAINS(a, "POINT_DATA 12\nVECTORS displacement double\n0 0 0\n0 0 -0.001\n");
        CHECK_CONTAINS(a, "VECTORS velocity double\n0 0 0\n0.333333333 0 0\n");
        CHECK_CONTAINS(a, "SCALARS level int 1\nLOOKUP_TABLE default\n0\n1\n2\n0\n");
        /* -0 prints as 0 */
        CHECK(!strstr(a, "-0 "));
    }
    free(a);
    free(b);
    /* VTK's own reader (ParaView's) reads it: counts, tet cells, the three arrays */
    char cmd[2200], out[1024] = "";
    snprintf(cmd, sizeof cmd, "/usr/bin/python3 %s/mesh/vtk_read.py %s 2>&1", sq_test_data(), p1);
    FILE *pp = popen(cmd, "r");
    CHECK(pp != NULL);
    if (pp) {
        size_t got = fread(out, 1, sizeof out - 1, pp);
        out[got] = 0;
        CHECK(pclose(pp) == 0);
        CHECK_CONTAINS(out, "points 12 cells 12 type 10 error 0\n");
        CHECK_CONTAINS(out, "displacement 3 0 0 -0.001\n");
        CHECK_CONTAINS(out, "velocity 3 0.333333333 0 0\n");
        CHECK_CONTAINS(out, "level 1 1\n");
    }
    /* without fields there is no POINT_DATA */
    CHECK(sq_mesh_write_vtk(m, p1, NULL, NULL, NULL, &err) == 0);
    a = sq_read_file(p1, &n1, 1 << 20, &err);
    CHECK(a && !strstr(a, "POINT_DATA"));
    free(a);
    /* an unwritable path names the file */
    CHECK(sq_mesh_write_vtk(m, "/nonexistent-dir/x.vtk", NULL, NULL, NULL, &err) < 0);
    CHECK_CONTAINS(err.msg, "/nonexistent-dir/x.vtk: cannot write");
    CHECK(sq_mesh_save(m, "x.obj", &err) < 0);
    CHECK_CONTAINS(err.msg, "unknown output format");
    free(d);
    free(v);
    free(lev);
    sq_mesh_free(m);
}

/* the shipped level-of-detail families: every level loads and validates, has the shape's
 * volume, and the mean edge length roughly halves per level */
SQ_TEST(mesh_shipped_meshes)
{
    static const struct {
        const char *shape;
        double volume;  /* exact volume of the shape (0: unknown, compare with the finest) */
        double tol[4];  /* relative volume tolerance per level */
    } shapes[] = {
        /* boxes are meshed exactly: roundoff only */
        {"cube", 1.0, {1e-12, 1e-12, 1e-12, 1e-12}},
        {"beam", 0.01, {1e-12, 1e-12, 1e-12, 1e-12}},
        /* an inscribed polyhedron loses volume ~ (h/R)^2: 10% at h = R/2, 0.5% at h = R/16 */
        {"sphere", 4.0 / 3.0 * M_PI * 0.125, {0.10, 0.03, 0.01, 0.005}},
        /* no closed form: within the same bounds of the finest level */
        {"organ", 0, {0.12, 0.05, 0.02, 1e-12}},
    };
    for (size_t s = 0; s < SQ_COUNTOF(shapes); s++) {
        sq_mesh_info info[4];
        int ok = 1;
        for (int k = 0; k < 4; k++) {
            sq_mesh *m = th_shipped_mesh("%s/%s_l%d.msh", shapes[s].shape, shapes[s].shape, k);
            CHECK(m != NULL);
            if (!m) {
                ok = 0;
                break;
            }
            sq_mesh_measure(m, &info[k]);
            /* closed outward surface: (1/3) sum x.n A over boundary triangles = volume (1e-9 rel:
             * roundoff over up to ~8k triangles) */
            double dv = 0;
            for (int t = 0; t < m->ntris; t++) {
                const double *a = m->x + 3 * m->tris[3 * t], *b = m->x + 3 * m->tris[3 * t + 1],
                             *c = m->x + 3 * m->tris[3 * t + 2];
                double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, w[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
                double n2[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
                dv += (a[0] * n2[0] + a[1] * n2[1] + a[2] * n2[2]) / 6;
            }
            CHECK_NEAR(dv / info[k].volume, 1.0, 1e-9);
            /* real time: the finest level stays at most ~15k nodes */
            CHECK(m->nnodes <= 15000);
            CHECK(info[k].volume > 0);
            CHECK(info[k].dihedral_min_deg > 5);
            sq_mesh_free(m);
        }
        if (!ok)
            continue;
        double ref = shapes[s].volume > 0 ? shapes[s].volume : info[3].volume;
        for (int k = 0; k < 4; k++) {
            CHECK_NEAR(info[k].volume / ref, 1.0, shapes[s].tol[k]);
            if (k > 0) {
                /* mean edge ratio between levels: 0.5 in the bulk, more where the coarse level
                 * is all surface */
                double r = info[k].edge_mean / info[k - 1].edge_mean;
                CHECK(r > 0.4 && r < 0.75);
                CHECK(info[k].nnodes > 2 * info[k - 1].nnodes);
            }
        }
    }
}

/* random byte edits of valid files (deterministic): each either loads a valid mesh or fails
 * with a message naming the file; under ASan this also shows no out-of-bounds access */
SQ_TEST(mesh_io_mutated_files)
{
    const char *files[] = {"cube_h1.msh", "cube_h1_v41.msh", "cube_h1.mesh", "cube_tetgen.ele"};
    static const char junk[] = "0123456789 \n-.e$#xX9";
    unsigned s = 2024;
    for (size_t f = 0; f < SQ_COUNTOF(files); f++) {
        char src[1024], dst[1024];
        snprintf(src, sizeof src, "%s/mesh/%s", sq_test_data(), files[f]);
        const char *ext = strrchr(files[f], '.');
        snprintf(dst, sizeof dst, "%s/mut%s", sq_test_tmpdir(), ext);
        if (!strcmp(ext, ".ele")) {
            /* the .node beside it stays valid */
            char nsrc[1024], ndst[1024];
            snprintf(nsrc, sizeof nsrc, "%s/mesh/cube_tetgen.node", sq_test_data());
            snprintf(ndst, sizeof ndst, "%s/mut.node", sq_test_tmpdir());
            sq_err e2 = {0};
            size_t nl;
            char *nb = sq_read_file(nsrc, &nl, 1 << 20, &e2);
            FILE *o = fopen(ndst, "wb");
            fwrite(nb, 1, nl, o);
            fclose(o);
            free(nb);
        }
        sq_err err = {0};
        size_t len;
        char *buf = sq_read_file(src, &len, 1 << 20, &err);
        CHECK(buf != NULL);
        if (!buf)
            continue;
        char *mut = malloc(len + 1);
        int bad = 0;
        for (int trial = 0; trial < 150; trial++) {
            memcpy(mut, buf, len);
            int edits = 1 + trial % 3;
            for (int e = 0; e < edits; e++) {
                s = s * 1103515245u + 12345u;
                size_t at = (s >> 8) % len;
                s = s * 1103515245u + 12345u;
                mut[at] = junk[(s >> 8) % (sizeof junk - 1)];
            }
            FILE *o = fopen(dst, "wb");
            fwrite(mut, 1, len, o);
            fclose(o);
            err.msg[0] = 0;
            sq_mesh *m = sq_mesh_load(dst, &err);
            if (m) {
                /* whatever loaded is a valid mesh */
                for (int t = 0; t < m->ntets; t++)
                    if (!(sq_tet_volume(m, t) > 0))
                        bad++;
                sq_mesh_free(m);
            } else if (!strstr(err.msg, "/mut.")) {
                bad++;
                printf("    unnamed error: %s\n", err.msg);
            }
        }
        CHECK(bad == 0);
        free(mut);
        free(buf);
    }
}

/* locate on a real unstructured mesh: points inside the sphere are found in a tet that
 * contains them; points outside get the tet under the nearest surface point */
SQ_TEST(mesh_locate_sphere)
{
    sq_mesh *m = th_shipped_mesh("sphere/sphere_l2.msh");
    CHECK(m != NULL);
    if (!m)
        return;
    unsigned s = 99;
    int bad_in = 0, bad_out = 0, nin = 0, nout = 0;
    for (int q = 0; q < 4000; q++) {
        double p[3], r2 = 0, b[4];
        for (int c = 0; c < 3; c++) {
            s = s * 1103515245u + 12345u;
            p[c] = 1.4 * (((s >> 8) & 0xffff) / 65536.0 - 0.5);
            r2 += p[c] * p[c];
        }
        int t = sq_mesh_locate(m, p, b);
        if (t < 0) {
            bad_in++;
            continue;
        }
        double mn = 1, x[3] = {0, 0, 0};
        for (int k = 0; k < 4; k++) {
            mn = b[k] < mn ? b[k] : mn;
            for (int c = 0; c < 3; c++)
                x[c] += b[k] * m->x[3 * m->tets[4 * t + k] + c];
        }
        /* the barycentric coordinates always reproduce p (1e-12: roundoff) */
        for (int c = 0; c < 3; c++)
            if (fabs(x[c] - p[c]) > 1e-12)
                bad_in++;
        /* well inside the inscribed polyhedron (r < 0.45 < its inradius) must be contained */
        if (sqrt(r2) < 0.45) {
            nin++;
            if (mn < -1e-12)
                bad_in++;
        } else if (sqrt(r2) > 0.5) {
            /* outside the sphere: not contained, and the tet touches the boundary */
            nout++;
            int on = 0;
            for (int k = 0; k < 4; k++)
                on |= m->on_boundary[m->tets[4 * t + k]];
            if (mn >= 0 || !on)
                bad_out++;
        }
    }
    CHECK(nin > 400 && nout > 400);
    CHECK(bad_in == 0);
    CHECK(bad_out == 0);
    /* every node is located in a tet that has it as a vertex or contains it */
    int bad_node = 0;
    for (int i = 0; i < m->nnodes; i += 7) {
        double b[4];
        int t = sq_mesh_locate(m, m->x + 3 * i, b);
        double mn = 1;
        for (int k = 0; k < 4; k++)
            mn = b[k] < mn ? b[k] : mn;
        if (t < 0 || mn < -1e-12)
            bad_node++;
    }
    CHECK(bad_node == 0);
    sq_mesh_free(m);
}
