/* test_physics_locking.c - locking of linear tets, the average nodal pressure option
 * (sq_level_static_solve_nodal_pressure) and the smoothed option (face-smoothed deviatoric strain
 * with nodal pressure, sq_level_static_solve_pressure; docs/physics.md section 10): the clamped
 * beam's static tip under its own weight against beam theory, the three side by side. */
#include "net/net.h"
#include "scene/scene.h"
#include "sq_test.h"
#include "test_scene_helpers.h"
#include "test_sim_helpers.h"

/* mean tip-face u_z of the cantilever (clamped at x = 0) under gravity -z; anp: 0 element-wise,
 * 1 nodal pressure, 2 smoothed */
static double beam_tip(const sq_mesh *m, double nu, int anp)
{
    sq_material mat = th_material(1, 1, 1000);
    if (sq_material_from_E_nu(&mat, 1e7, nu, NULL) < 0)
        return NAN;
    sq_constraint clamp = {SQ_REGION_BOX, {-1, -1, -1}, {m->bbox_min[0] + 1e-3, 1, 1}, 7};
    sq_level L;
    sq_err e = {{0}};
    if (sq_level_init(&L, m, &mat, SQ_OPERATOR_FEM, &clamp, 1, &e) < 0)
        return NAN;
    double g[3] = {0, 0, -9.81}, *d = malloc(sizeof(double) * 3 * m->nnodes), tip = 0;
    int rc = anp == 2 ? sq_level_static_solve_pressure(&L.model, &mat, SQ_PRESSURE_SMOOTHED, g, 1e-10, 200000, d, NULL, &e)
             : anp    ? sq_level_static_solve_nodal_pressure(&L.model, &mat, g, 1e-10, 200000, d, NULL, &e)
                      : sq_level_static_solve(&L.model, g, 1e-10, 200000, d, NULL, &e);
    if (rc < 0) {
        fprintf(stderr, "    %s\n", e.msg);
        tip = NAN;
    } else {
        int cnt = 0;
        for (int i = 0; i < m->nnodes; i++)
            if (m->x[3 * i] > m->bbox_max[0] - 1e-6) {
                tip += d[3 * i + 2];
                cnt++;
            }
        tip /= cnt;
    }
    free(d);
    sq_level_free(&L);
    return tip;
}

/* Euler-Bernoulli tip of a cantilever under self-weight: q L^4 / (8 E I), q = rho g A */
static double eb_tip(double L, double h)
{
    double E = 1e7, I = h * h * h * h / 12, q = 1000 * 9.81 * h * h;
    return -q * L * L * L * L / (8 * E * I);
}

/* beam 1 x 0.1 x 0.1 m: the shipped levels 0-3 and box meshes, nu 0.3 / 0.45 / 0.49. Today's
 * tets lock (0.1-0.95 of beam theory, worse as nu -> 0.5 and on coarse meshes); nodal pressure
 * tets remove the volumetric part (not the shear locking of coarse bending), never stiffen, and
 * are never more than 3 % softer than beam theory (the converged 3-D tip: shear adds about 1 %,
 * the clamp's full restraint takes some off). */
/* the converged 3-D tip of this cantilever over Euler-Bernoulli at nu 0.3 / 0.45 / 0.49: the
 * smoothed tets' static tip on the 160 x 16 x 16 box mesh (46,529 nodes), the finest mesh
 * measured (docs/physics.md section 10: all three elements converge to it from below over the
 * 40 x 4 x 4, 80 x 8 x 8 and 160 x 16 x 16 boxes; the extrapolated limit, 1.002 / 0.991 / 0.987,
 * is within 1 % above it; too slow for this test, measured once) */
static const double converged_3d[3] = {0.9971, 0.9833, 0.9771};

SQ_TEST(locking_beam_tip_today_nodal_smoothed)
{
#ifdef __SANITIZE_ADDRESS__
    /* the sanitizer build checks memory, not the physics twice (as test_physics_cube.c): 36
     * static solves up to 22k nodes take many minutes at -O1 with ASan; the nodal pressure
     * code runs under ASan in locking_nodal_pressure_body_settles_and_refuses */
    return;
#endif
    static const double nus[3] = {0.3, 0.45, 0.49};
    const double ref = eb_tip(1, 0.1);
    const char *names[6] = {"beam_l0", "beam_l1", "beam_l2", "beam_l3", "box 20x2x2", "box 40x4x4"};
    double r_std[6][3], r_anp[6][3], r_sm[6][3];
    int nodes[6];
    for (int k = 0; k < 6; k++) {
        sq_mesh *m = NULL;
        if (k < 4) {
            m = th_shipped_mesh("beam/beam_l%d.msh", k);
        } else {
            int c = k == 4 ? 2 : 4;
            m = th_box(10 * c, c, c, 1, 0.1, 0.1);
        }
        TH_REQUIRE(m);
        nodes[k] = m->nnodes;
        for (int j = 0; j < 3; j++) {
            r_std[k][j] = beam_tip(m, nus[j], 0) / ref;
            r_anp[k][j] = beam_tip(m, nus[j], 1) / ref;
            r_sm[k][j] = beam_tip(m, nus[j], 2) / ref;
        }
        fprintf(stderr, "    %-11s %5d nodes: tip / Euler-Bernoulli  today %.3f %.3f %.3f   nodal pressure %.3f %.3f %.3f"
                        "   smoothed %.3f %.3f %.3f  (nu 0.3 0.45 0.49)\n", names[k], nodes[k], r_std[k][0], r_std[k][1],
                r_std[k][2], r_anp[k][0], r_anp[k][1], r_anp[k][2], r_sm[k][0], r_sm[k][1], r_sm[k][2]);
        sq_mesh_free(m);
    }
    for (int k = 0; k < 6; k++)
        for (int j = 0; j < 3; j++) {
            CHECK(r_std[k][j] > 0 && r_std[k][j] < 1.0);  /* today's tets are too stiff */
            CHECK(r_anp[k][j] >= r_std[k][j]);            /* the option never stiffens */
            CHECK(r_anp[k][j] <= 1.03);                   /* never beyond 3 % softer */
        }
    /* convergence over the shipped levels: the tip grows towards the theory, both elements */
    for (int k = 0; k < 3; k++)
        for (int j = 0; j < 3; j++) {
            if (j < 2) /* at nu 0.49 today's level 1 bends less than level 0 (0.229 vs 0.251) */
                CHECK(r_std[k + 1][j] > r_std[k][j]);
            CHECK(r_anp[k + 1][j] > r_anp[k][j]);
        }
    /* at nu 0.49 the option recovers most of the volumetric locking: on the finest level within
     * 8 % of the theory (today 23 % short), and at least 3x today's tip on the 20x2x2 box */
    CHECK(r_anp[3][2] > 0.92);
    CHECK(r_anp[4][2] > 3 * r_std[4][2]);
    /* locking grows with nu for today's tets, on every mesh */
    for (int k = 0; k < 6; k++)
        CHECK(r_std[k][2] < r_std[k][1] && r_std[k][1] < r_std[k][0]);

    /* smoothed: never stiffer than nodal pressure (its energy is below that one's: Jensen over the
     * face domains), and takes off shear locking too: at least 0.04 of the theory more than nodal
     * pressure on every mesh but the finest level (where the two are within 0.02 of the limit).
     * No over-softening: below the converged 3-D tip on every mesh and nu (the elements converge
     * from below), which is itself within 2.5 % of Euler-Bernoulli (shear adds about 1 %, the
     * clamped end face's restrained Poisson contraction takes off about as much, more as nu
     * grows). */
    for (int k = 0; k < 6; k++)
        for (int j = 0; j < 3; j++) {
            CHECK(r_sm[k][j] >= r_anp[k][j]);
            if (k != 3)
                CHECK(r_sm[k][j] >= r_anp[k][j] + 0.04);
            CHECK(r_sm[k][j] < converged_3d[j]);
        }
    /* convergence over the shipped levels at every nu */
    for (int k = 0; k < 3; k++)
        for (int j = 0; j < 3; j++)
            CHECK(r_sm[k + 1][j] > r_sm[k][j]);
    /* the aim: 0.89-0.93 of the reference at nu 0.45 where today's tets give 0.77: on
     * beam_l2 (today 0.735) and the 40 x 4 x 4 box (today 0.600), 0.90 of Euler-Bernoulli,
     * 0.91-0.92 of the converged tip; the 20 x 2 x 2 box (two tets' edges across) stays at 0.73 */
    CHECK(r_sm[2][1] >= 0.89 && r_sm[5][1] >= 0.89);
    CHECK(r_sm[4][1] >= 0.70);
    /* at nu 0.49: within 6 % of the theory on level 3 (nodal pressure 7 %, today 23 %) */
    CHECK(r_sm[3][2] >= 0.94);
}

/* the simulation with "pressure": "nodal": the damped run settles to the nodal pressure static
 * solution (relative 1e-6: the step uses that operator), which bends 2x today's at nu 0.45 on
 * this mesh; the refused combinations and run-time switching */
SQ_TEST(locking_nodal_pressure_body_settles_and_refuses)
{
    sq_mesh *m = th_box(20, 2, 2, 1, 0.1, 0.1);
    TH_REQUIRE(m);
    sq_body_def def = th_body_def(m);
    CHECK(sq_material_from_E_nu(&def.material, 1e7, 0.45, NULL) == 0);
    def.material.density = 1000;
    def.material.rayleigh_mass = 40;
    def.material.rayleigh_stiffness = 0;
    def.gravity[2] = -9.81;
    def.nconstraints = 1;
    def.constraints[0] = (sq_constraint){SQ_REGION_BOX, {-1, -1, -1}, {1e-3, 1, 1}, 7};
    def.nodal_pressure = 1;
    sq_err e = {{0}};
    def.elasticity = SQ_ELASTICITY_COROTATIONAL;
    CHECK(sq_body_create(&def, &e) == NULL);
    CHECK_CONTAINS(e.msg, "nodal pressure tets");
    def.elasticity = SQ_ELASTICITY_LINEAR;
    def.op = SQ_OPERATOR_PAPER;
    CHECK(sq_body_create(&def, &e) == NULL);
    def.op = SQ_OPERATOR_FEM;
    sq_body *b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    sq_body_set_sleep(b, 0, 0, 0);
    for (int f = 0; f < 250; f++)
        sq_body_frame(b, NULL, 0, NULL, NULL, 0);
    sq_level *L = sq_body_level(b, 0);
    double *ds = malloc(sizeof(double) * 3 * m->nnodes), *dl = malloc(sizeof(double) * 3 * m->nnodes);
    CHECK(sq_level_static_solve_nodal_pressure(&L->model, &def.material, def.gravity, 1e-12, 100000, ds, NULL, &e) == 0);
    CHECK(sq_level_static_solve(&L->model, def.gravity, 1e-12, 100000, dl, NULL, &e) == 0);
    double diff = 0, scale = 0, tl = 0;
    for (int i = 0; i < 3 * m->nnodes; i++) {
        diff = th_max(diff, fabs(L->state.d[i] - ds[i]));
        scale = th_max(scale, fabs(ds[i]));
        tl = th_max(tl, fabs(dl[i]));
    }
    fprintf(stderr, "    settled vs nodal pressure static: %.3g relative; max |d| nodal %.4g m, element %.4g m\n",
            diff / scale, scale, tl);
    CHECK(diff <= 1e-6 * scale);
    CHECK(scale > 1.8 * tl);
    CHECK(sq_body_residual(b) < 1e-6);
    /* refusals while nodal: corotational, paper, adaptive; switching back keeps the state */
    CHECK(sq_body_set_elasticity(b, SQ_ELASTICITY_COROTATIONAL, &e) < 0);
    CHECK_CONTAINS(e.msg, "nodal pressure tets");
    CHECK(sq_body_set_material(b, &def.material, SQ_OPERATOR_PAPER, &e) < 0);
    CHECK(sq_body_get_def(b)->nodal_pressure == 1);
    double e_np = sq_body_elastic_energy(b);
    CHECK(sq_body_set_pressure(b, 0, &e) == 0);
    CHECK(sq_body_level(b, 0)->state.anp == NULL);
    CHECK(sq_body_elastic_energy(b) > e_np); /* the same state costs more energy element-wise */
    CHECK(sq_body_set_pressure(b, 1, &e) == 0);
    CHECK(sq_body_level(b, 0)->state.anp != NULL);
    free(ds);
    free(dl);
    sq_body_destroy(b);
    sq_mesh_free(m);
}


/* the smoothed operator (level/anp.c, SQ_PRESSURE_SMOOTHED) on an irregular mesh: the step's
 * blocked pass equals the plain per-tet form (both options); symmetric
 * (x.Ky = y.Kx), rigid motions (translation, infinitesimal rotation) give no force, never
 * stiffer than the element-wise operator nor than nodal pressure tets (x.Kx; Jensen: both
 * average strains over domains), positive on strain; its face domains are found (an interior
 * face is shared by two tets) */
SQ_TEST(locking_smoothed_operator_symmetric_rigid_softer)
{
    sq_mesh *m = th_shipped_mesh("beam/beam_l1.msh");
    TH_REQUIRE(m);
    sq_err e = {{0}};
    sq_material mat = th_material(1, 1, 1000);
    CHECK(sq_material_from_E_nu(&mat, 1e7, 0.45, NULL) == 0);
    sq_level L;
    int rc = sq_level_init(&L, m, &mat, SQ_OPERATOR_FEM, NULL, 0, &e);
    CHECK(rc == 0);
    if (rc)
        return;
    size_t n3 = 3 * (size_t)m->nnodes;
    double *x = malloc(sizeof(double) * n3), *y = malloc(sizeof(double) * n3);
    double *kx = malloc(sizeof(double) * n3), *ky = malloc(sizeof(double) * n3);
    uint64_t st = 777;
    for (size_t k = 0; k < n3; k++) {
        st = st * 6364136223846793005ULL + 1442695040888963407ULL;
        x[k] = (double)(st >> 11) / 9007199254740992.0 - 0.5;
        st = st * 6364136223846793005ULL + 1442695040888963407ULL;
        y[k] = (double)(st >> 11) / 9007199254740992.0 - 0.5;
    }
    double ex[3]; /* x.Kx: element-wise, nodal pressure, smoothed */
    for (int mode = 0; mode < 3; mode++) {
        if (mode == 0) {
            memcpy(L.state.d, x, sizeof(double) * n3);
            ex[0] = 2 * sq_level_elastic_energy(&L.model, &L.state);
            continue;
        }
        CHECK(sq_level_anp_enable(&L, &mat, SQ_OPERATOR_FEM, mode, &e) == 0);
        sq_level_anp_apply(&L.model, &L.state, x, kx);
        sq_level_anp_apply(&L.model, &L.state, y, ky);
        double xky = 0, ykx = 0, xkx = 0, scale = 0;
        for (size_t k = 0; k < n3; k++) {
            xky += x[k] * ky[k];
            ykx += y[k] * kx[k];
            xkx += x[k] * kx[k];
            scale = th_max(scale, fabs(kx[k]));
        }
        ex[mode] = xkx;
        CHECK(fabs(xky - ykx) <= 1e-12 * fabs(xkx));
        /* the step's blocked pass (four tets at once) against the plain per-tet form */
        sq_anp_apply(L.state.anp, m, L.model.vol, x, ky);
        double dfast = 0;
        for (size_t k = 0; k < n3; k++)
            dfast = th_max(dfast, fabs(ky[k] - kx[k]));
        CHECK(dfast <= 1e-12 * scale);
        CHECK(m->ntets % 4 != 0); /* the padded last block is exercised */
        /* rigid motion: translation (1, -2, 0.5) plus small rotation w x X, w = (0.3, -0.2, 0.1) */
        const double w[3] = {0.3, -0.2, 0.1};
        for (int i = 0; i < m->nnodes; i++) {
            const double *X = m->x + 3 * (size_t)i;
            y[3 * i] = 1 + w[1] * X[2] - w[2] * X[1];
            y[3 * i + 1] = -2 + w[2] * X[0] - w[0] * X[2];
            y[3 * i + 2] = 0.5 + w[0] * X[1] - w[1] * X[0];
        }
        sq_level_anp_apply(&L.model, &L.state, y, ky);
        double rig = 0;
        for (size_t k = 0; k < n3; k++)
            rig = th_max(rig, fabs(ky[k]));
        fprintf(stderr, "    mode %d: x.Kx %.6g, |x.Ky - y.Kx| / x.Kx %.2g, rigid force / |Kx| %.2g, step pass vs plain %.2g\n",
                mode, xkx, fabs(xky - ykx) / xkx, rig / scale, dfast / scale);
        CHECK(rig <= 1e-12 * scale);
        for (size_t k = 0; k < n3; k++) { /* y back to random for the next mode */
            st = st * 6364136223846793005ULL + 1442695040888963407ULL;
            y[k] = (double)(st >> 11) / 9007199254740992.0 - 0.5;
        }
    }
    fprintf(stderr, "    x.Kx element %.6g, nodal %.6g, smoothed %.6g\n", ex[0], ex[1], ex[2]);
    CHECK(ex[2] > 0 && ex[2] < ex[1] && ex[1] < ex[0]);
    CHECK(sq_anp_mode(L.state.anp) == SQ_PRESSURE_SMOOTHED);
    /* the step bound: the smoothed lambda_max(M^-1 K) (300 power iterations on M^-1/2 K M^-1/2,
     * a lower estimate) stays below the element-wise operator's Lanczos estimate and its
     * Gershgorin ceiling, which the step uses */
    for (size_t k = 0; k < n3; k++)
        x[k] = (double)((k * 7919) % 101) / 101.0 - 0.5;
    double lam = 0;
    for (int it = 0; it < 300; it++) {
        double nx = 0;
        for (size_t k = 0; k < n3; k++)
            nx += x[k] * x[k];
        nx = sqrt(nx);
        for (size_t k = 0; k < n3; k++) {
            x[k] /= nx;
            y[k] = x[k] / sqrt(L.model.mass[k / 3]);
        }
        sq_level_anp_apply(&L.model, &L.state, y, ky);
        lam = 0;
        for (size_t k = 0; k < n3; k++) {
            x[k] = ky[k] / sqrt(L.model.mass[k / 3]);
            lam += y[k] * ky[k];
        }
    }
    double lan = sq_level_lanczos_max(&L, 40), ger = L.omega_max * L.omega_max;
    fprintf(stderr, "    lambda_max(M^-1 K): smoothed (power) %.5g, element-wise Lanczos %.5g, Gershgorin %.5g\n", lam, lan,
            ger);
    CHECK(lam > 0 && lam < lan && lan <= ger * (1 + 1e-12));
    free(x);
    free(y);
    free(kx);
    free(ky);
    sq_level_free(&L);
    sq_mesh_free(m);
}

/* the simulation with "pressure": "smoothed": the damped run settles to the smoothed static
 * solution (relative 1e-6: the step uses that operator), softer than nodal pressure and than
 * today's tets; the refused combinations, run-time switching between the three, the scene key
 * and the protocol's set */
SQ_TEST(locking_smoothed_body_settles_and_refuses)
{
    sq_mesh *m = th_box(20, 2, 2, 1, 0.1, 0.1);
    TH_REQUIRE(m);
    sq_body_def def = th_body_def(m);
    CHECK(sq_material_from_E_nu(&def.material, 1e7, 0.45, NULL) == 0);
    def.material.density = 1000;
    def.material.rayleigh_mass = 40;
    def.material.rayleigh_stiffness = 1e-5; /* both damping terms: the stiffness one uses the smoothed operator */
    def.gravity[2] = -9.81;
    def.nconstraints = 1;
    def.constraints[0] = (sq_constraint){SQ_REGION_BOX, {-1, -1, -1}, {1e-3, 1, 1}, 7};
    def.nodal_pressure = SQ_PRESSURE_SMOOTHED;
    sq_err e = {{0}};
    def.elasticity = SQ_ELASTICITY_COROTATIONAL;
    CHECK(sq_body_create(&def, &e) == NULL);
    CHECK_CONTAINS(e.msg, "smoothed tets");
    CHECK_CONTAINS(e.msg, "fem operator, linear elasticity and fixed lod");
    def.elasticity = SQ_ELASTICITY_LINEAR;
    def.op = SQ_OPERATOR_PAPER;
    CHECK(sq_body_create(&def, &e) == NULL);
    CHECK_CONTAINS(e.msg, "smoothed tets");
    def.op = SQ_OPERATOR_FEM;
    sq_body *b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    sq_body_set_sleep(b, 0, 0, 0);
    for (int f = 0; f < 250; f++)
        sq_body_frame(b, NULL, 0, NULL, NULL, 0);
    sq_level *L = sq_body_level(b, 0);
    TH_REQUIRE(L->state.anp);
    CHECK(sq_anp_mode(L->state.anp) == SQ_PRESSURE_SMOOTHED);
    size_t n3 = 3 * (size_t)m->nnodes;
    double *ds = malloc(sizeof(double) * n3), *dn = malloc(sizeof(double) * n3), *dl = malloc(sizeof(double) * n3);
    CHECK(sq_level_static_solve_pressure(&L->model, &def.material, SQ_PRESSURE_SMOOTHED, def.gravity, 1e-12, 100000, ds,
                                         NULL, &e) == 0);
    CHECK(sq_level_static_solve_pressure(&L->model, &def.material, SQ_PRESSURE_NODAL, def.gravity, 1e-12, 100000, dn,
                                         NULL, &e) == 0);
    CHECK(sq_level_static_solve(&L->model, def.gravity, 1e-12, 100000, dl, NULL, &e) == 0);
    double diff = 0, scale = 0, tn = 0, tl = 0;
    for (size_t i = 0; i < n3; i++) {
        diff = th_max(diff, fabs(L->state.d[i] - ds[i]));
        scale = th_max(scale, fabs(ds[i]));
        tn = th_max(tn, fabs(dn[i]));
        tl = th_max(tl, fabs(dl[i]));
    }
    fprintf(stderr, "    settled vs smoothed static: %.3g relative; max |d| smoothed %.4g m, nodal %.4g m, element %.4g m\n",
            diff / scale, scale, tn, tl);
    CHECK(diff <= 1e-6 * scale);
    CHECK(scale > 1.1 * tn && scale > 2.2 * tl);
    CHECK(sq_body_residual(b) < 1e-6);
    /* refusals while smoothed: corotational, paper, adaptive lod; naming the combination */
    CHECK(sq_body_set_elasticity(b, SQ_ELASTICITY_COROTATIONAL, &e) < 0);
    CHECK_CONTAINS(e.msg, "smoothed tets");
    CHECK(sq_body_set_material(b, &def.material, SQ_OPERATOR_PAPER, &e) < 0);
    CHECK_CONTAINS(e.msg, "smoothed tets");
    sq_lod_def lod = sq_body_get_def(b)->lod;
    lod.mode = SQ_LOD_ADAPTIVE;
    CHECK(sq_body_set_lod(b, &lod, &e) < 0);
    CHECK_CONTAINS(e.msg, "smoothed tets");
    CHECK(sq_body_set_pressure(b, 3, &e) < 0);
    CHECK_CONTAINS(e.msg, "use element, nodal or smoothed");
    CHECK(sq_body_get_def(b)->nodal_pressure == SQ_PRESSURE_SMOOTHED);
    /* switching keeps the state; the same state costs more energy nodal, more again element-wise */
    double e_sm = sq_body_elastic_energy(b);
    CHECK(sq_body_set_pressure(b, SQ_PRESSURE_NODAL, &e) == 0);
    CHECK(sq_anp_mode(sq_body_level(b, 0)->state.anp) == SQ_PRESSURE_NODAL);
    double e_np = sq_body_elastic_energy(b);
    CHECK(sq_body_set_pressure(b, SQ_PRESSURE_ELEMENT, &e) == 0);
    CHECK(sq_body_level(b, 0)->state.anp == NULL);
    double e_el = sq_body_elastic_energy(b);
    CHECK(e_sm < e_np && e_np < e_el);
    CHECK(sq_body_set_pressure(b, SQ_PRESSURE_SMOOTHED, &e) == 0);
    CHECK(sq_anp_mode(sq_body_level(b, 0)->state.anp) == SQ_PRESSURE_SMOOTHED);
    CHECK(fabs(sq_body_elastic_energy(b) - e_sm) <= 1e-12 * e_sm);
    free(ds);
    free(dn);
    free(dl);
    sq_body_destroy(b);
    sq_mesh_free(m);

    /* the scene key: "smoothed" accepted; refused with corotational / paper / adaptive, naming
     * the supported combination; a wrong value lists the three */
    char dir[300];
    snprintf(dir, sizeof dir, "%s/locking-scene", sq_test_tmpdir());
    CHECK(th_make_dir(dir) == 0);
    th_write_box_msh(dir, "a.msh", 2);
    static const struct {
        const char *extra, *expect;
    } sc[] = {
        {"\"pressure\": \"smoothed\"", NULL},
        {"\"pressure\": \"smoothed\", \"elasticity\": \"corotational\"",
         "pressure: \"smoothed\" runs with \"operator\": \"fem\", \"elasticity\": \"linear\" and fixed lod only"},
        {"\"pressure\": \"smoothed\", \"operator\": \"paper\"", "\"smoothed\" runs with \"operator\": \"fem\""},
        {"\"pressure\": \"smoothed\", \"lod\": {\"mode\": \"adaptive\"}", "\"smoothed\" runs with"},
        {"\"pressure\": \"face\"", "\"element\" (default: one pressure per tet), \"nodal\""},
    };
    for (int k = 0; k < 5; k++) {
        char json[600];
        snprintf(json, sizeof json,
                 "{\"bodies\": [{\"name\": \"c\", \"levels\": [\"a.msh\"], \"material\": {\"E\": 1e5, \"nu\": 0.45}, "
                 "\"fixed\": [{\"box\": [[-1, -1, -1], [2, 2, 0.01]]}], %s}]}",
                 sc[k].extra);
        memset(&e, 0, sizeof e);
        sq_scene *s = sq_scene_parse(json, dir, "t.json", &e);
        if (!sc[k].expect) {
            CHECK(s != NULL);
            if (!s)
                fprintf(stderr, "    %s\n", e.msg);
            else
                CHECK(s->bodies[0].nodal_pressure == SQ_PRESSURE_SMOOTHED);
        } else {
            CHECK(s == NULL);
            CHECK_CONTAINS(e.msg, sc[k].expect);
        }
        if (s)
            sq_scene_free(s);
    }

    /* the protocol: set.pressure "smoothed" decodes to SQ_PRESSURE_SMOOTHED; a wrong value is refused */
    sq_request r;
    sq_net_error ne;
    const char *ok = "{\"type\": \"set\", \"pressure\": \"smoothed\"}";
    CHECK(sq_request_decode(ok, strlen(ok), 65536, &r, &ne) == 0);
    CHECK(r.set.has_pressure && r.set.nodal_pressure == SQ_PRESSURE_SMOOTHED);
    const char *bad = "{\"type\": \"set\", \"pressure\": \"fs\"}";
    CHECK(sq_request_decode(bad, strlen(bad), 65536, &r, &ne) == -1);
}

/* the converged reference of docs/physics.md section 10 (the 80 x 8 x 8 and 160 x 16 x 16 boxes,
 * minutes of CG): runs only with SQ_LOCKING_REFERENCE=1 in the environment, e.g.
 * SQ_LOCKING_REFERENCE=1 build/unit_tests locking_converged_reference; prints the table rows */
SQ_TEST(locking_converged_reference)
{
    const char *on = getenv("SQ_LOCKING_REFERENCE");
    if (!on || strcmp(on, "1"))
        return;
    static const double nus[3] = {0.3, 0.45, 0.49};
    const double ref = eb_tip(1, 0.1);
    double prev[3] = {0, 0, 0};
    for (int c = 4; c <= 16; c *= 2) {
        sq_mesh *m = th_box(10 * c, c, c, 1, 0.1, 0.1);
        TH_REQUIRE(m);
        for (int j = 0; j < 3; j++) {
            double r[3];
            for (int mode = 0; mode < 3; mode++)
                r[mode] = beam_tip(m, nus[j], mode) / ref;
            fprintf(stderr, "    box %dx%dx%d (%d nodes) nu %.2f: today %.4f nodal %.4f smoothed %.4f\n", 10 * c, c, c,
                    m->nnodes, nus[j], r[0], r[1], r[2]);
            CHECK(r[2] > prev[j]); /* converging from below */
            prev[j] = r[2];
        }
        sq_mesh_free(m);
    }
}
