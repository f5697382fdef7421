/* test_mesh.c - box mesh, topology (boundary, adjacency), geometry (volume, gradients),
 * point location and measurements. */
#include <stdlib.h>
#include <string.h>

#include "mesh/mesh.h"
#include "sq_test.h"

static int cmp(const void *pa, const void *pb)
{
    long long a = *(const long long *)pa, b = *(const long long *)pb;
    return (a > b) - (a < b);
}

/* every boundary edge is shared by exactly two boundary triangles, in opposite directions
 * (closed, consistently oriented surface); returns the number of bad edges */
static int open_edges(const sq_mesh *m)
{
    /* directed edges sorted; each (a,b) must have exactly one (b,a) and no duplicate */
    int ne = 3 * m->ntris, bad = 0;
    long long *e = malloc(sizeof *e * (size_t)(ne ? ne : 1));
    for (int t = 0; t < m->ntris; t++)
        for (int k = 0; k < 3; k++) {
            long long a = m->tris[3 * t + k], b = m->tris[3 * t + (k + 1) % 3];
            e[3 * t + k] = a * m->nnodes + b;
        }
    qsort(e, (size_t)ne, sizeof *e, cmp);
    for (int i = 0; i < ne; i++) {
        if (i && e[i] == e[i - 1])
            bad++;
        long long a = e[i] / m->nnodes, b = e[i] % m->nnodes, rev = b * m->nnodes + a;
        if (!bsearch(&rev, e, (size_t)ne, sizeof *e, cmp))
            bad++;
    }
    free(e);
    return bad;
}

/* (1/3) sum over boundary triangles of x . n A: equals the volume for an outward surface */
static double divergence_volume(const sq_mesh *m)
{
    double s = 0;
    for (int t = 0; t < m->ntris; t++) {
        const double *a = m->x + 3 * m->tris[3 * t], *b = m->x + 3 * m->tris[3 * t + 1],
                     *c = m->x + 3 * m->tris[3 * t + 2];
        double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, w[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double n2[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
        double cen[3] = {(a[0] + b[0] + c[0]) / 3, (a[1] + b[1] + c[1]) / 3, (a[2] + b[2] + c[2]) / 3};
        s += (cen[0] * n2[0] + cen[1] * n2[1] + cen[2] * n2[2]) / 2;
    }
    return s / 3;
}

SQ_TEST(mesh_box_counts_volume_area)
{
    sq_err err = {0};
    const double size[3] = {2, 3, 0.5}, origin[3] = {-1, 0.5, 2};
    sq_mesh *m = sq_mesh_box(4, 5, 3, size, origin, &err);
    CHECK(m != NULL);
    if (!m)
        return;
    CHECK(m->nnodes == 5 * 6 * 4);
    CHECK(m->ntets == 6 * 4 * 5 * 3);
    /* each face of the box: 2 triangles per cell face */
    CHECK(m->ntris == 2 * 2 * (4 * 5 + 5 * 3 + 4 * 3));
    /* boundary nodes: all minus interior (3*4*2) */
    CHECK(m->nsurf == 5 * 6 * 4 - 3 * 4 * 2);
    sq_mesh_info info;
    sq_mesh_measure(m, &info);
    /* sums of ~360 exact-ish products: 1e-12 relative */
    CHECK_NEAR(info.volume, 2 * 3 * 0.5, 1e-12);
    CHECK_NEAR(info.surface_area, 2 * (2 * 3 + 3 * 0.5 + 2 * 0.5), 1e-12);
    CHECK_NEAR(m->bbox_min[0], -1, 0);
    CHECK_NEAR(m->bbox_max[1], 3.5, 0);
    CHECK_NEAR(m->bbox_max[2], 2.5, 0);
    for (int t = 0; t < m->ntets; t++)
        CHECK(sq_tet_volume(m, t) > 0);
    CHECK(open_edges(m) == 0);
    CHECK_NEAR(divergence_volume(m), 3.0, 1e-12);
    /* Kuhn cells: every tet has the same volume */
    CHECK_NEAR(sq_tet_volume(m, 7), 3.0 / m->ntets, 1e-15);
    sq_mesh_free(m);
}

SQ_TEST(mesh_box_bad_sizes)
{
    sq_err err = {0};
    const double size[3] = {1, -1, 1};
    CHECK(sq_mesh_box(0, 1, 1, NULL, NULL, &err) == NULL);
    CHECK_CONTAINS(err.msg, ">= 1");
    CHECK(sq_mesh_box(1, 1, 1, size, NULL, &err) == NULL);
    CHECK_CONTAINS(err.msg, "size must be positive");
    CHECK(sq_mesh_box(100000, 100000, 100000, NULL, NULL, &err) == NULL);
    CHECK_CONTAINS(err.msg, "too large");
}

SQ_TEST(mesh_adjacency_csr)
{
    sq_err err = {0};
    sq_mesh *m = sq_mesh_box(3, 2, 2, NULL, NULL, &err);
    CHECK(m != NULL);
    if (!m)
        return;
    /* sorted, unique, includes self, symmetric, and each tet's edges are present */
    int ok = 1;
    for (int i = 0; i < m->nnodes && ok; i++) {
        int self = 0;
        for (int e = m->adj_start[i]; e < m->adj_start[i + 1]; e++) {
            if (e > m->adj_start[i] && m->adj[e] <= m->adj[e - 1])
                ok = 0;
            if (m->adj[e] == i)
                self = 1;
            int j = m->adj[e], found = 0;
            for (int f = m->adj_start[j]; f < m->adj_start[j + 1]; f++)
                found |= m->adj[f] == i;
            if (!found)
                ok = 0;
        }
        if (!self)
            ok = 0;
    }
    CHECK(ok);
    for (int t = 0; t < m->ntets; t++)
        for (int a = 0; a < 4; a++)
            for (int b = 0; b < 4; b++) {
                int i = m->tets[4 * t + a], j = m->tets[4 * t + b], found = 0;
                for (int e = m->adj_start[i]; e < m->adj_start[i + 1]; e++)
                    found |= m->adj[e] == j;
                CHECK(found);
            }
    /* the box's corner 0 (on the Kuhn diagonal start) has neighbours 1, +x, +y, +z, and the
     * three face diagonals and the cell diagonal: 8 with itself */
    CHECK(m->adj_start[1] - m->adj_start[0] == 8);
    /* surface numbering is consistent */
    for (int s = 0; s < m->nsurf; s++)
        CHECK(m->surf_of_node[m->surf_nodes[s]] == s);
    for (int k = 0; k < 3 * m->ntris; k++)
        CHECK(m->surf_nodes[m->surf_tris[k]] == m->tris[k]);
    sq_mesh_free(m);
}

SQ_TEST(mesh_gradients)
{
    sq_err err = {0};
    /* one irregular tet plus a box */
    const double x[12] = {0.1, 0.2, 0.3, 1.3, 0.1, 0.2, 0.2, 1.1, 0.1, 0.4, 0.3, 0.9};
    const int tet[4] = {0, 1, 2, 3};
    sq_mesh *m = sq_mesh_from_arrays(4, x, 1, tet, "one tet", &err);
    CHECK(m != NULL);
    if (!m)
        return;
    double g[4][3];
    double vol = sq_tet_gradients(m, 0, g);
    CHECK(vol > 0);
    CHECK_NEAR(vol, sq_tet_volume(m, 0), 1e-15);
    /* sums to zero (1e-12: roundoff on gradients of size ~1/h ~ 2) */
    for (int c = 0; c < 3; c++)
        CHECK_NEAR(g[0][c] + g[1][c] + g[2][c] + g[3][c], 0, 1e-12);
    /* a_i . (x_j - x_k) = delta_ij - delta_ik: W_i is 1 at node i and 0 at the others */
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++) {
            const double *xj = m->x + 3 * m->tets[j], *x0 = m->x + 3 * m->tets[(j + 1) % 4];
            double d = 0;
            for (int c = 0; c < 3; c++)
                d += g[i][c] * (xj[c] - x0[c]);
            CHECK_NEAR(d, (i == j) - (i == (j + 1) % 4), 1e-12);
        }
    /* a linear field f = c0 + k.x: sum_i f(x_i) a_i = k exactly (1e-12 roundoff) */
    const double k[3] = {0.7, -1.9, 3.25};
    double rec[3] = {0, 0, 0};
    for (int i = 0; i < 4; i++) {
        const double *xi = m->x + 3 * m->tets[i];
        double f = 2.5 + k[0] * xi[0] + k[1] * xi[1] + k[2] * xi[2];
        for (int c = 0; c < 3; c++)
            rec[c] += f * g[i][c];
    }
    for (int c = 0; c < 3; c++)
        CHECK_NEAR(rec[c], k[c], 1e-12);
    /* height: 1/|a_i| equals 3V / area of the opposite face */
    sq_mesh_info info;
    sq_mesh_measure(m, &info);
    CHECK(info.height_min > 0);
    CHECK(info.dihedral_min_deg > 0 && info.dihedral_max_deg < 180);
    CHECK(m->ntris == 4 && m->nsurf == 4);
    CHECK_NEAR(divergence_volume(m), vol, 1e-14);
    sq_mesh_free(m);
}

SQ_TEST(mesh_measure_regular_tet)
{
    /* regular tet of edge 1: dihedral acos(1/3) = 70.5288 deg, height sqrt(2/3) */
    const double s = 1 / sqrt(2.0);
    const double x[12] = {0, 0, 0, s, s, 0, s, 0, s, 0, s, s};
    const int tet[4] = {0, 1, 2, 3};
    sq_err err = {0};
    sq_mesh *m = sq_mesh_from_arrays(4, x, 1, tet, "regular", &err);
    CHECK(m != NULL);
    if (!m)
        return;
    sq_mesh_info info;
    sq_mesh_measure(m, &info);
    CHECK(info.nedges == 6);
    CHECK_NEAR(info.edge_min, 1, 1e-12);
    CHECK_NEAR(info.edge_max, 1, 1e-12);
    CHECK_NEAR(info.dihedral_min_deg, acos(1.0 / 3) * 180 / M_PI, 1e-9);
    CHECK_NEAR(info.dihedral_max_deg, acos(1.0 / 3) * 180 / M_PI, 1e-9);
    CHECK_NEAR(info.height_min, sqrt(2.0 / 3), 1e-12);
    CHECK_NEAR(info.aspect_max, 1 / sqrt(2.0 / 3), 1e-12);
    CHECK_NEAR(info.volume, 1 / (6 * sqrt(2.0)), 1e-12);
    CHECK_NEAR(info.surface_area, sqrt(3.0), 1e-12);
    sq_mesh_free(m);
}

SQ_TEST(mesh_from_arrays_flips_all_negative)
{
    /* every tet negatively oriented: the file's convention, flipped silently */
    sq_err err = {0};
    sq_mesh *b = sq_mesh_box(2, 2, 2, NULL, NULL, &err);
    CHECK(b != NULL);
    if (!b)
        return;
    int *t = malloc(sizeof *t * 4 * (size_t)b->ntets);
    for (int i = 0; i < b->ntets; i++) {
        t[4 * i] = b->tets[4 * i + 1];
        t[4 * i + 1] = b->tets[4 * i];
        t[4 * i + 2] = b->tets[4 * i + 2];
        t[4 * i + 3] = b->tets[4 * i + 3];
    }
    sq_mesh *m = sq_mesh_from_arrays(b->nnodes, b->x, b->ntets, t, "flipped", &err);
    CHECK(m != NULL);
    if (m) {
        for (int i = 0; i < m->ntets; i++)
            CHECK(sq_tet_volume(m, i) > 0);
        sq_mesh_free(m);
    }
    /* a mix is an error naming the odd tet */
    t[4 * 5] = b->tets[4 * 5];
    t[4 * 5 + 1] = b->tets[4 * 5 + 1];
    m = sq_mesh_from_arrays(b->nnodes, b->x, b->ntets, t, "mixed", &err);
    CHECK(m == NULL);
    CHECK_CONTAINS(err.msg, "mixed: tet 5 (nodes");
    CHECK_CONTAINS(err.msg, "inverted");
    free(t);
    sq_mesh_free(b);
}

SQ_TEST(mesh_from_arrays_errors)
{
    sq_err err = {0};
    const double x[15] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 5, 5, 5};
    const int good[4] = {0, 1, 2, 3}, badidx[4] = {0, 1, 2, 7}, flat[4] = {0, 1, 2, 2};
    CHECK(sq_mesh_from_arrays(5, x, 1, good, "extra", &err) == NULL);
    CHECK_CONTAINS(err.msg, "extra: node 4: not used");
    CHECK(sq_mesh_from_arrays(4, x, 1, badidx, "idx", &err) == NULL);
    CHECK_CONTAINS(err.msg, "idx: tet 0 (nodes 0 1 2 7): node index 7 out of range");
    CHECK(sq_mesh_from_arrays(4, x, 1, flat, "flat", &err) == NULL);
    CHECK_CONTAINS(err.msg, "degenerate");
    CHECK(sq_mesh_from_arrays(4, x, 0, good, "none", &err) == NULL);
    CHECK_CONTAINS(err.msg, "no tetrahedra");
    double nan_x[12];
    memcpy(nan_x, x, sizeof nan_x);
    nan_x[7] = NAN;
    CHECK(sq_mesh_from_arrays(4, nan_x, 1, good, "nan", &err) == NULL);
    CHECK_CONTAINS(err.msg, "nan: node 2: coordinate y is not finite");
    /* coplanar but distinct points: degenerate too */
    const double planar[12] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 1e-14};
    CHECK(sq_mesh_from_arrays(4, planar, 1, good, "planar", &err) == NULL);
    CHECK_CONTAINS(err.msg, "degenerate");
    /* two tets on the same face and a third on it too: non-manifold */
    const double x5[18] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, -1, 0.2, 0.2, 0.5};
    const int three[12] = {0, 1, 2, 3, 0, 2, 1, 4, 0, 1, 2, 5};
    CHECK(sq_mesh_from_arrays(6, x5, 3, three, "nonmanifold", &err) == NULL);
    CHECK_CONTAINS(err.msg, "shared by more than two tets");
}

SQ_TEST(mesh_locate_inside_outside)
{
    sq_err err = {0};
    const double size[3] = {1, 2, 1}, origin[3] = {0, 0, 0};
    sq_mesh *m = sq_mesh_box(5, 6, 4, size, origin, &err);
    CHECK(m != NULL);
    if (!m)
        return;
    /* inside points: found tet contains them, bary interpolates x exactly (1e-12) */
    unsigned s = 12345;
    int ok_inside = 1, ok_interp = 1;
    for (int q = 0; q < 500; q++) {
        double p[3];
        for (int c = 0; c < 3; c++) {
            s = s * 1103515245u + 12345u;
            p[c] = size[c] * ((s >> 8) & 0xffff) / 65536.0;
        }
        double b[4];
        int t = sq_mesh_locate(m, p, b);
        if (t < 0) {
            ok_inside = 0;
            continue;
        }
        double sum = 0, mn = 1;
        for (int k = 0; k < 4; k++) {
            sum += b[k];
            mn = b[k] < mn ? b[k] : mn;
        }
        if (mn < -1e-12 || fabs(sum - 1) > 1e-12)
            ok_inside = 0;
        for (int c = 0; c < 3; c++) {
            double xi = 0;
            for (int k = 0; k < 4; k++)
                xi += b[k] * m->x[3 * m->tets[4 * t + k] + c];
            if (fabs(xi - p[c]) > 1e-12)
                ok_interp = 0;
        }
    }
    CHECK(ok_inside);
    CHECK(ok_interp);
    /* outside: the nearest tet touches the nearest boundary point; bary still reproduces p */
    const double out[3] = {1.5, 1.0, 0.5};
    double b[4];
    int t = sq_mesh_locate(m, out, b);
    CHECK(t >= 0);
    if (t >= 0) {
        double mn = 1, xi = 0, maxx = 0;
        for (int k = 0; k < 4; k++) {
            mn = b[k] < mn ? b[k] : mn;
            xi += b[k] * m->x[3 * m->tets[4 * t + k]];
            double xx = m->x[3 * m->tets[4 * t + k]];
            maxx = xx > maxx ? xx : maxx;
        }
        CHECK(mn < 0);
        CHECK_NEAR(xi, 1.5, 1e-12);
        /* the tet lies on the x = 1 face */
        CHECK_NEAR(maxx, 1.0, 1e-15);
    }
    /* far away below a corner */
    const double far[3] = {-3, -3, -3};
    t = sq_mesh_locate(m, far, b);
    CHECK(t >= 0);
    if (t >= 0) {
        int has_origin = 0;
        for (int k = 0; k < 4; k++)
            has_origin |= m->tets[4 * t + k] == 0;
        CHECK(has_origin);
    }
    sq_mesh_free(m);
}

SQ_TEST(mesh_box_large_finalize)
{
    /* 40^3 cells = 68921 nodes, 384000 tets: exercises the sort-based face matching */
    sq_err err = {0};
    sq_mesh *m = sq_mesh_box(40, 40, 40, NULL, NULL, &err);
    CHECK(m != NULL);
    if (!m)
        return;
    CHECK(m->ntris == 2 * 6 * 40 * 40);
    CHECK(m->nsurf == 41 * 41 * 41 - 39 * 39 * 39);
    /* interior node of a Kuhn mesh has 14 neighbours + itself */
    int mid = (20 * 41 + 20) * 41 + 20;
    CHECK(m->adj_start[mid + 1] - m->adj_start[mid] == 15);
    sq_mesh_free(m);
}

/* RCM renumbering: a box with its nodes shuffled gets a bandwidth near the lexicographic one
 * back; the mesh is the same (positions, tets as sets of positions, volume), and the result is
 * deterministic */
SQ_TEST(mesh_renumber_rcm)
{
    sq_err err = {{0}};
    sq_mesh *b = sq_mesh_box(8, 6, 5, NULL, NULL, &err);
    CHECK(b != NULL);
    if (!b)
        return;
    int n = b->nnodes;
    /* a fixed pseudo-random permutation */
    int *perm = malloc(sizeof *perm * (size_t)n);
    for (int i = 0; i < n; i++)
        perm[i] = i;
    unsigned s = 12345;
    for (int i = n - 1; i > 0; i--) {
        s = s * 1103515245u + 12345u;
        int j = (int)((s >> 8) % (unsigned)(i + 1)), t = perm[i];
        perm[i] = perm[j];
        perm[j] = t;
    }
    double *x = malloc(sizeof *x * 3 * (size_t)n);
    int *tets = malloc(sizeof *tets * 4 * (size_t)b->ntets);
    for (int i = 0; i < n; i++)
        memcpy(x + 3 * perm[i], b->x + 3 * i, 3 * sizeof *x);
    for (int t = 0; t < 4 * b->ntets; t++)
        tets[t] = perm[b->tets[t]];
    sq_mesh *sh = sq_mesh_from_arrays(n, x, b->ntets, tets, "shuffled", &err);
    CHECK(sh != NULL);
    sq_mesh *r = sh ? sq_mesh_renumber(sh, &err) : NULL;
    CHECK(r != NULL);
    if (r) {
        int bw_box = sq_mesh_bandwidth(b), bw_sh = sq_mesh_bandwidth(sh), bw_r = sq_mesh_bandwidth(r);
        /* lexicographic: (nx+1)(ny+1) + (nx+1) + 1 = 73; shuffled: most of n = 378 */
        CHECK(bw_sh > 4 * bw_box);
        CHECK(bw_r <= 2 * bw_box);
        CHECK(r->nnodes == n && r->ntets == b->ntets && r->ntris == b->ntris);
        sq_mesh_info ib, ir;
        sq_mesh_measure(b, &ib);
        sq_mesh_measure(r, &ir);
        CHECK_NEAR(ir.volume, ib.volume, 1e-12);
        /* the same positions (a permutation of them): sums of coordinates and of squares */
        double s1[2] = {0, 0}, s2[2] = {0, 0};
        for (int i = 0; i < 3 * n; i++) {
            s1[0] += b->x[i];
            s1[1] += r->x[i];
            s2[0] += b->x[i] * b->x[i] * (1 + i % 3);
            s2[1] += r->x[i] * r->x[i] * (1 + i % 3);
        }
        CHECK_NEAR(s1[1], s1[0], 1e-9);
        CHECK_NEAR(s2[1], s2[0], 1e-9);
        /* tets sorted by their smallest node */
        int sorted = 1;
        for (int t = 1; t < r->ntets && sorted; t++) {
            int a = n, c = n;
            for (int k = 0; k < 4; k++) {
                a = SQ_MIN(a, r->tets[4 * (t - 1) + k]);
                c = SQ_MIN(c, r->tets[4 * t + k]);
            }
            sorted = a <= c;
        }
        CHECK(sorted);
        /* deterministic */
        sq_mesh *r2 = sq_mesh_renumber(sh, &err);
        CHECK(r2 && !memcmp(r2->x, r->x, sizeof(double) * 3 * (size_t)n) &&
              !memcmp(r2->tets, r->tets, sizeof(int) * 4 * (size_t)r->ntets));
        sq_mesh_free(r2);
    }
    sq_mesh_free(r);
    sq_mesh_free(sh);
    sq_mesh_free(b);
    free(perm);
    free(x);
    free(tets);
}
