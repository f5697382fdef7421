/* test_sim_operator.c - identities of the two operators (PHYSICS.md section 2) on meshes. */
#include "sq_test.h"
#include "test_sim_helpers.h"

/* force tolerance: rounding in a sum of ~15 blocks of size kmax times |d| ~ 1, so 1e-11 kmax
 * is ~100x above double rounding and far below a real error (which is O(kmax |d|)) */
#define FTOL(L) (1e-11 * th_kmax(L))

static void check_translation(sq_operator_kind op)
{
    sq_mesh *m = th_box(3, 2, 4, 1.0, 0.7, 1.3);
    TH_REQUIRE(m);
    sq_material mat = th_material(40000, 100000, 1000);
    sq_level L;
    sq_err e = {{0}};
    CHECK(sq_level_init(&L, m, &mat, op, NULL, 0, &e) == 0);
    double *d = malloc(sizeof(double) * 3 * m->nnodes);
    for (int i = 0; i < m->nnodes; i++) {
        d[3 * i] = 0.3;
        d[3 * i + 1] = -0.2;
        d[3 * i + 2] = 0.5;
    }
    th_elastic_force(&L, &mat, d);
    double worst = 0;
    for (int i = 0; i < m->nnodes; i++)
        worst = th_max(worst, th_norm3(L.state.f + 3 * i));
    CHECK(worst <= FTOL(&L));
    free(d);
    sq_level_free(&L);
    sq_mesh_free(m);
}

SQ_TEST(sim_operator_translation_is_force_free_fem) { check_translation(SQ_OPERATOR_FEM); }
SQ_TEST(sim_operator_translation_is_force_free_paper) { check_translation(SQ_OPERATOR_PAPER); }

/* an infinitesimal rotation d = w x x: zero force under fem; under the paper operator zero at
 * interior nodes and non-zero at (some) free boundary nodes */
SQ_TEST(sim_operator_rotation_fem_zero_paper_boundary_only)
{
    sq_mesh *m = th_box(3, 3, 3, 1, 1, 1);
    TH_REQUIRE(m);
    sq_material mat = th_material(40000, 100000, 1000);
    double w[3] = {1e-3, -2e-3, 1.5e-3};
    double *d = malloc(sizeof(double) * 3 * m->nnodes);
    for (int i = 0; i < m->nnodes; i++) {
        const double *x = m->x + 3 * i;
        d[3 * i] = w[1] * x[2] - w[2] * x[1];
        d[3 * i + 1] = w[2] * x[0] - w[0] * x[2];
        d[3 * i + 2] = w[0] * x[1] - w[1] * x[0];
    }
    for (int op = 0; op < 2; op++) {
        sq_level L;
        sq_err e = {{0}};
        CHECK(sq_level_init(&L, m, &mat, (sq_operator_kind)op, NULL, 0, &e) == 0);
        th_elastic_force(&L, &mat, d);
        double tol = 1e-3 * FTOL(&L); /* |d| ~ 1e-3 here */
        double interior, boundary;
        th_force_split(m, &L, &interior, &boundary);
        CHECK(interior <= tol);
        if (op == SQ_OPERATOR_FEM)
            CHECK(boundary <= tol);
        else
            CHECK(boundary > 1e6 * tol); /* clearly non-zero: O(mu |w| h^2) */
        sq_level_free(&L);
    }
    free(d);
    sq_mesh_free(m);
}

/* paper - fem = mu sum_T V (a_i a_j^T - a_j a_i^T): vanishes unless both ends are on the boundary */
SQ_TEST(sim_operator_paper_fem_differ_only_on_boundary_edges)
{
    sq_mesh *m = th_box(3, 3, 4, 1, 1, 1.2);
    TH_REQUIRE(m);
    sq_material mat = th_material(40000, 100000, 1000);
    sq_level P, F;
    sq_err e = {{0}};
    CHECK(sq_level_init(&P, m, &mat, SQ_OPERATOR_PAPER, NULL, 0, &e) == 0);
    CHECK(sq_level_init(&F, m, &mat, SQ_OPERATOR_FEM, NULL, 0, &e) == 0);
    double tol = 1e-12 * th_kmax(&F), inner = 0, outer = 0;
    for (int i = 0; i < m->nnodes; i++)
        for (int p = m->adj_start[i]; p < m->adj_start[i + 1]; p++) {
            int j = m->adj[p];
            double diff = 0;
            for (int k = 0; k < 9; k++)
                diff = th_max(diff, fabs(P.model.K[9 * p + k] - F.model.K[9 * p + k]));
            if (m->on_boundary[i] && m->on_boundary[j])
                outer = th_max(outer, diff);
            else
                inner = th_max(inner, diff);
        }
    CHECK(inner <= tol);
    CHECK(outer > 1e-3 * th_kmax(&F));
    sq_level_free(&P);
    sq_level_free(&F);
    sq_mesh_free(m);
}

/* K_ji = K_ij^T for both operators; and the diagonal blocks are symmetric positive */
SQ_TEST(sim_operator_blocks_symmetric)
{
    sq_mesh *m = th_box(2, 3, 2, 0.5, 1, 0.8);
    TH_REQUIRE(m);
    sq_material mat = th_material(3000, 12000, 900);
    for (int op = 0; op < 2; op++) {
        sq_level L;
        sq_err e = {{0}};
        CHECK(sq_level_init(&L, m, &mat, (sq_operator_kind)op, NULL, 0, &e) == 0);
        double worst = 0;
        for (int i = 0; i < m->nnodes; i++)
            for (int p = m->adj_start[i]; p < m->adj_start[i + 1]; p++) {
                int j = m->adj[p], q = -1;
                for (int t = m->adj_start[j]; t < m->adj_start[j + 1]; t++)
                    if (m->adj[t] == i)
                        q = t;
                CHECK(q >= 0);
                if (q < 0)
                    continue;
                for (int r = 0; r < 3; r++)
                    for (int c = 0; c < 3; c++)
                        worst = th_max(worst, fabs(L.model.K[9 * p + 3 * r + c] - L.model.K[9 * q + 3 * c + r]));
            }
        CHECK(worst <= 1e-12 * th_kmax(&L)); /* same sums in another order: rounding only */
        sq_level_free(&L);
    }
    sq_mesh_free(m);
}

/* patch test: d = G x with a general constant gradient G gives zero force at interior nodes */
SQ_TEST(sim_operator_patch_test_uniform_strain)
{
    sq_mesh *m = th_box(4, 3, 3, 1, 0.9, 0.7);
    TH_REQUIRE(m);
    sq_material mat = th_material(40000, 100000, 1000);
    double G[3][3] = {{1e-3, 2e-4, -3e-4}, {5e-4, -2e-3, 1e-4}, {-4e-4, 3e-4, 1.5e-3}};
    double *d = malloc(sizeof(double) * 3 * m->nnodes);
    for (int i = 0; i < m->nnodes; i++)
        for (int r = 0; r < 3; r++)
            d[3 * i + r] = G[r][0] * m->x[3 * i] + G[r][1] * m->x[3 * i + 1] + G[r][2] * m->x[3 * i + 2];
    for (int op = 0; op < 2; op++) {
        sq_level L;
        sq_err e = {{0}};
        CHECK(sq_level_init(&L, m, &mat, (sq_operator_kind)op, NULL, 0, &e) == 0);
        th_elastic_force(&L, &mat, d);
        double interior, boundary;
        th_force_split(m, &L, &interior, &boundary);
        CHECK(interior <= 1e-3 * FTOL(&L));
        CHECK(boundary > 1e3 * 1e-3 * FTOL(&L)); /* the traction of the strain shows on the boundary */
        sq_level_free(&L);
    }
    free(d);
    sq_mesh_free(m);
}

/* lumped masses add up to rho * volume; nodal volumes to the volume */
SQ_TEST(sim_level_masses_sum_to_body_mass)
{
    sq_mesh *m = th_box(3, 2, 2, 1.5, 1, 0.5);
    TH_REQUIRE(m);
    sq_material mat = th_material(1e4, 1e4, 1200);
    sq_level L;
    sq_err e = {{0}};
    CHECK(sq_level_init(&L, m, &mat, SQ_OPERATOR_FEM, NULL, 0, &e) == 0);
    double M = 0, V = 0;
    for (int i = 0; i < L.model.n; i++) {
        M += L.model.mass[i];
        V += L.model.vol[i];
    }
    CHECK_NEAR(V, 0.75, 1e-12);       /* exact up to rounding */
    CHECK_NEAR(M, 1200 * 0.75, 1e-9);
    CHECK(L.model.hbar[0] > 0);
    sq_level_free(&L);
    sq_mesh_free(m);
}

/* constraints: box selects fixed nodes, half-space selects, per-axis rollers set bits */
SQ_TEST(sim_level_constraints_mark_axes)
{
    sq_mesh *m = th_box(2, 2, 2, 1, 1, 1);
    TH_REQUIRE(m);
    sq_material mat = th_material(1e4, 1e4, 1000);
    sq_constraint c[2];
    memset(c, 0, sizeof c);
    c[0].kind = SQ_REGION_BOX; /* bottom face, all axes */
    c[0].a[0] = c[0].a[1] = c[0].a[2] = -1;
    c[0].b[0] = c[0].b[1] = 2;
    c[0].b[2] = 0;
    c[0].axes = 7;
    c[1].kind = SQ_REGION_HALFSPACE; /* x >= 1 face: roller in x (normal -x selects x >= 1) */
    c[1].a[0] = 1;
    c[1].b[0] = -1;
    c[1].axes = 1;
    sq_level L;
    sq_err e = {{0}};
    CHECK(sq_level_init(&L, m, &mat, SQ_OPERATOR_FEM, c, 2, &e) == 0);
    int nbottom = 0, nroll = 0;
    for (int i = 0; i < L.model.n; i++) {
        const double *x = m->x + 3 * i;
        unsigned want = (x[2] == 0 ? 7u : 0u) | (x[0] == 1 ? 1u : 0u);
        CHECK(L.model.fixed[i] == want);
        nbottom += x[2] == 0;
        nroll += x[0] == 1 && x[2] != 0;
    }
    CHECK(nbottom == 9);
    CHECK(nroll == 6);
    CHECK(L.model.nfree == 27 - 9);
    sq_level_free(&L);
    sq_mesh_free(m);
}

/* the fused step gives the same values as forces + integrate, with and without stiffness
 * damping and with a mask (same arithmetic in the same order: equal to the last bit) */
SQ_TEST(sim_level_step_equals_forces_then_integrate)
{
    sq_mesh *m = th_box(3, 2, 3, 1, 0.8, 1.1);
    TH_REQUIRE(m);
    sq_constraint fixed = {SQ_REGION_BOX, {-1, -1, -1}, {2, 2, 1e-6}, 7};
    double g[3] = {0.5, 0, -9.81};
    for (int variant = 0; variant < 3; variant++) {
        sq_material mat = th_material(40000, 100000, 1000);
        mat.rayleigh_mass = 0.7;
        mat.rayleigh_stiffness = variant == 0 ? 0 : 2e-3;
        sq_level A, B;
        sq_err e = {{0}};
        CHECK(sq_level_init(&A, m, &mat, SQ_OPERATOR_FEM, &fixed, 1, &e) == 0);
        CHECK(sq_level_init(&B, m, &mat, SQ_OPERATOR_FEM, &fixed, 1, &e) == 0);
        unsigned char *mask = NULL;
        if (variant == 2) {
            mask = malloc(m->nnodes);
            for (int i = 0; i < m->nnodes; i++)
                mask[i] = i % 5 != 3;
        }
        for (int k = 0; k < 3 * m->nnodes; k++) {
            A.state.d[k] = B.state.d[k] = 1e-3 * sin(0.3 * k);
            A.state.v[k] = B.state.v[k] = 1e-2 * cos(0.7 * k);
        }
        for (int s = 0; s < 20; s++) {
            sq_level_forces(&A.model, &A.state, &mat, g, NULL);
            sq_level_integrate(&A.model, &A.state, 1e-3, mask);
            sq_level_step(&B.model, &B.state, &mat, g, 1e-3, mask);
        }
        CHECK(memcmp(A.state.d, B.state.d, sizeof(double) * 3 * m->nnodes) == 0);
        CHECK(memcmp(A.state.v, B.state.v, sizeof(double) * 3 * m->nnodes) == 0);
        CHECK(memcmp(A.state.f, B.state.f, sizeof(double) * 3 * m->nnodes) == 0);
        free(mask);
        sq_level_free(&A);
        sq_level_free(&B);
    }
    sq_mesh_free(m);
}

/* the masked force pass (full rows of K, used by the adaptive step) agrees with the fast pass
 * (upper half, difference form) to rounding: relative 1e-12 of the largest force term */
SQ_TEST(sim_level_masked_forces_match_fast_pass)
{
    sq_mesh *m = th_box(3, 3, 2, 1, 1, 0.6);
    TH_REQUIRE(m);
    sq_material mat = th_material(40000, 100000, 1000);
    mat.rayleigh_mass = 0.5;
    mat.rayleigh_stiffness = 1e-3;
    double g[3] = {0, 0, -9.81};
    sq_level L;
    sq_err e = {{0}};
    CHECK(sq_level_init(&L, m, &mat, SQ_OPERATOR_PAPER, NULL, 0, &e) == 0);
    for (int k = 0; k < 3 * m->nnodes; k++) {
        L.state.d[k] = 1e-2 * sin(0.9 * k);
        L.state.v[k] = 1e-1 * cos(0.4 * k);
    }
    unsigned char *all = malloc(m->nnodes);
    memset(all, 1, m->nnodes);
    double *fast = malloc(sizeof(double) * 3 * m->nnodes);
    sq_level_forces(&L.model, &L.state, &mat, g, NULL);
    memcpy(fast, L.state.f, sizeof(double) * 3 * m->nnodes);
    sq_level_forces(&L.model, &L.state, &mat, g, all);
    double diff = 0, scale = 0;
    for (int k = 0; k < 3 * m->nnodes; k++) {
        diff = th_max(diff, fabs(fast[k] - L.state.f[k]));
        scale = th_max(scale, fabs(fast[k]));
    }
    CHECK(scale > 0);
    CHECK(diff <= 1e-12 * 15 * th_kmax(&L) * 0.1); /* ~15 blocks x kmax x |d + b v| <= 0.1 */
    free(all);
    free(fast);
    sq_level_free(&L);
    sq_mesh_free(m);
}

/* the identities on the shipped (unstructured, Gmsh) meshes: translation and rotation under
 * both operators, symmetry, and paper = fem away from boundary edges */
SQ_TEST(sim_operator_identities_on_shipped_meshes)
{
    const char *names[] = {"cube/cube_l1.msh", "sphere/sphere_l1.msh", "organ/organ_l1.msh", "beam/beam_l1.msh"};
    sq_material mat = th_material(40000, 100000, 1000);
    for (size_t k = 0; k < sizeof names / sizeof names[0]; k++) {
        sq_mesh *m = th_shipped_mesh("%s", names[k]);
        CHECK(m != NULL);
        if (!m)
            continue;
        sq_err e = {{0}};
        double *dt = malloc(sizeof(double) * 3 * m->nnodes), *dr = malloc(sizeof(double) * 3 * m->nnodes);
        const double w[3] = {1e-3, 2e-3, -1e-3};
        for (int i = 0; i < m->nnodes; i++) {
            const double *x = m->x + 3 * i;
            dt[3 * i] = 0.01, dt[3 * i + 1] = -0.02, dt[3 * i + 2] = 0.03;
            dr[3 * i] = w[1] * x[2] - w[2] * x[1];
            dr[3 * i + 1] = w[2] * x[0] - w[0] * x[2];
            dr[3 * i + 2] = w[0] * x[1] - w[1] * x[0];
        }
        sq_level L[2];
        for (int op = 0; op < 2; op++) {
            CHECK(sq_level_init(&L[op], m, &mat, (sq_operator_kind)op, NULL, 0, &e) == 0);
            double tol = 1e-11 * th_kmax(&L[op]) * 0.03; /* |d| <= 0.03 m here */
            th_elastic_force(&L[op], &mat, dt);
            double ft = 0, fi, fb;
            for (int i = 0; i < m->nnodes; i++)
                ft = th_max(ft, th_norm3(L[op].state.f + 3 * i));
            th_elastic_force(&L[op], &mat, dr);
            th_force_split(m, &L[op], &fi, &fb);
            CHECK(ft <= tol);
            CHECK(fi <= tol);
            if (op == SQ_OPERATOR_FEM)
                CHECK(fb <= tol);
            else
                CHECK(fb > 1e3 * tol);
        }
        /* paper - fem only on boundary edges; both symmetric */
        double inner = 0, asym = 0;
        for (int i = 0; i < m->nnodes; i++)
            for (int p = m->adj_start[i]; p < m->adj_start[i + 1]; p++) {
                int j = m->adj[p];
                if (!(m->on_boundary[i] && m->on_boundary[j]))
                    for (int c = 0; c < 9; c++)
                        inner = th_max(inner, fabs(L[0].model.K[9 * p + c] - L[1].model.K[9 * p + c]));
                for (int q = m->adj_start[j]; q < m->adj_start[j + 1]; q++)
                    if (m->adj[q] == i)
                        for (int r = 0; r < 3; r++)
                            for (int c = 0; c < 3; c++)
                                asym = th_max(asym, fabs(L[0].model.K[9 * p + 3 * r + c] - L[0].model.K[9 * q + 3 * c + r]));
            }
        CHECK(inner <= 1e-12 * th_kmax(&L[0]));
        CHECK(asym <= 1e-12 * th_kmax(&L[0]));
        sq_level_free(&L[0]);
        sq_level_free(&L[1]);
        free(dt);
        free(dr);
        sq_mesh_free(m);
    }
}

/* sq_level_forces_to (the residual's force pass) gives bit for bit the forces sq_level_forces
 * writes to L->f, for the linear, viscous, corotational, nodal-pressure and smoothed paths, and leaves the
 * level as it was: state, L->f and the all-zero accumulator untouched (the level is only read) */
SQ_TEST(sim_operator_forces_to_matches_and_reads_only)
{
    sq_mesh *m = th_box(3, 2, 4, 1.0, 0.7, 1.3);
    TH_REQUIRE(m);
    sq_constraint fixed = {SQ_REGION_BOX, {-1, -1, -1}, {2, 2, 1e-3}, 7};
    const double g[3] = {0, 0, -9.81};
    for (int path = 0; path < 5; path++) {
        sq_material mat = th_material(40000, 100000, 1000);
        mat.rayleigh_mass = 0.5;
        mat.rayleigh_stiffness = path == 1 ? 0 : 1e-3;
        if (path == 1) {
            mat.use_viscosity = 1;
            mat.phi = 2000;
            mat.psi = 5000;
        }
        sq_level L;
        sq_err e = {{0}};
        CHECK(sq_level_init(&L, m, &mat, SQ_OPERATOR_FEM, &fixed, 1, &e) == 0);
        if (path == 2)
            CHECK(sq_level_corot_enable(&L, &mat, SQ_OPERATOR_FEM, &e) == 0);
        if (path >= 3)
            CHECK(sq_level_anp_enable(&L, &mat, SQ_OPERATOR_FEM, path == 3 ? SQ_PRESSURE_NODAL : SQ_PRESSURE_SMOOTHED,
                                      &e) == 0);
        size_t n3 = 3 * (size_t)L.model.n;
        uint64_t s = 12345;
        for (size_t k = 0; k < n3; k++) {
            s = s * 6364136223846793005ULL + 1442695040888963407ULL;
            L.state.d[k] = 1e-2 * ((double)(s >> 11) / 9007199254740992.0 - 0.5);
            L.state.v[k] = 1e-1 * ((double)((s * 3) >> 11) / 9007199254740992.0 - 0.5);
        }
        double *d0 = malloc(sizeof(double) * n3), *v0 = malloc(sizeof(double) * n3);
        double *f = malloc(sizeof(double) * n3), *acc = calloc(n3 + 1, sizeof(double));
        memcpy(d0, L.state.d, sizeof(double) * n3);
        memcpy(v0, L.state.v, sizeof(double) * n3);
        for (size_t k = 0; k < n3; k++)
            L.state.f[k] = -7; /* a marker: forces_to must not write it */
        sq_level_forces_to(&L.model, &L.state, &mat, g, NULL, f, acc);
        int fmark = 0, accz = 0;
        for (size_t k = 0; k < n3; k++) {
            fmark += L.state.f[k] == -7;
            accz += acc[k] == 0;
        }
        CHECK(fmark == (int)n3 && accz == (int)n3);
        CHECK(memcmp(d0, L.state.d, sizeof(double) * n3) == 0 && memcmp(v0, L.state.v, sizeof(double) * n3) == 0);
        sq_level_forces(&L.model, &L.state, &mat, g, NULL);
        CHECK(memcmp(f, L.state.f, sizeof(double) * n3) == 0);
        double fmax = 0;
        for (size_t k = 0; k < n3; k++)
            fmax = th_max(fmax, fabs(f[k]));
        CHECK(fmax > 0); /* a real force, not zeros on both sides */
        free(d0);
        free(v0);
        free(f);
        free(acc);
        sq_level_free(&L);
    }
    sq_mesh_free(m);
}
