/* test_stability.c - the fast subset of `squish sweep`: stability at the extremes through the
 * public body API. Every case is either refused with a reason, or accepted and stays finite,
 * never trips the blow-up detector, and keeps its energy bounded. Meshes are tiny (2-3 cells
 * per side) so the ASan build stays fast. */
#include "sq_test.h"
#include "test_sim_helpers.h"

/* a 10 cm cube body, bottom fixed, gravity, scene-default damping; NULL + err if refused */
static sq_body *cube_body(sq_mesh *m, const sq_material *mat, double step_fraction, double frame_dt, sq_err *err)
{
    sq_body_def def = th_body_def(m);
    def.material = *mat;
    def.gravity[2] = -9.81;
    def.frame_dt = frame_dt;
    def.step_fraction = step_fraction;
    def.nconstraints = 1;
    def.constraints[0].kind = SQ_REGION_HALFSPACE;
    def.constraints[0].a[2] = 1e-9;
    def.constraints[0].b[2] = 1;
    def.constraints[0].axes = 7;
    return sq_body_create(&def, err);
}

static sq_material mat_E_nu(double E, double nu, double b)
{
    sq_material m = th_material(1, 0, 1000);
    sq_err e = {{0}};
    sq_material_from_E_nu(&m, E, nu, &e);
    m.rayleigh_mass = 0.5;
    m.rayleigh_stiffness = b;
    return m;
}

/* total energy relative to rest: kinetic + elastic + gravity potential */
static double total_energy(sq_body *b)
{
    const sq_level *L = sq_body_level(b, sq_body_fixed_level(b));
    double ep = 0;
    for (int i = 0; i < L->model.n; i++)
        ep += L->model.mass[i] * 9.81 * L->state.d[3 * i + 2];
    return sq_body_kinetic_energy(b) + sq_body_elastic_energy(b) + ep;
}

/* run frames with an optional sphere tool pressing the top until t_release; returns resets and
 * fills the max total energy before/after release and the largest |d| (NaN if non-finite) */
static int run_frames(sq_body *b, int frames, double depth, double t_release, double *e_before, double *e_after,
                      double *dmax)
{
    const sq_mesh *m = sq_body_mesh(b, 0);
    const double dt = sq_body_get_def(b)->frame_dt;
    int resets = 0;
    *e_before = *e_after = -INFINITY;
    *dmax = 0;
    for (int f = 1; f <= frames; f++) {
        double t = f * dt;
        sq_tool tool;
        memset(&tool, 0, sizeof tool);
        tool.id = 1;
        tool.shape = SQ_TOOL_SPHERE;
        tool.radius = 0.03;
        tool.pos[0] = tool.pos[1] = 0.05;
        tool.pos[2] = m->bbox_max[2] + tool.radius - depth * fmin(1.0, t / (0.5 * t_release + 1e-12));
        tool.active = t < t_release;
        sq_frame_profile prof;
        sq_body_frame(b, &tool, depth > 0 ? 1 : 0, NULL, &prof, 0);
        resets += prof.reset;
        double e = total_energy(b);
        if (t < t_release + 0.2)
            *e_before = th_max(*e_before, e);
        else
            *e_after = th_max(*e_after, e);
        const double *d = sq_body_displacement(b, 0);
        for (int i = 0; i < 3 * m->nnodes; i++)
            *dmax = th_max(*dmax, fabs(d[i]));
    }
    return resets;
}

SQ_TEST(stability_stiff_material_accepted_and_stable)
{
    /* E = 1e9 Pa with light stiffness damping: many substeps, each below the bound */
    sq_mesh *m = th_box(2, 2, 2, 0.1, 0.1, 0.1);
    sq_material mat = mat_E_nu(1e9, 0.3, 1e-6);
    sq_err e = {{0}};
    sq_body *b = cube_body(m, &mat, 0.9, 0.02, &e);
    CHECK(b != NULL);
    if (b) {
        CHECK(sq_body_level_dt(b, 0) <= 0.9 * sq_body_level_bound(b, 0) * (1 + 1e-12));
        CHECK(lround(0.02 / sq_body_level_dt(b, 0)) >= 256);
        double eb, ea, dmax;
        CHECK(run_frames(b, 10, 0.01, 0.1, &eb, &ea, &dmax) == 0);
        CHECK(isfinite(dmax) && dmax < 0.02);
        sq_body_destroy(b);
    }
    sq_mesh_free(m);
}

SQ_TEST(stability_soft_material_stable)
{
    /* E = 100 Pa: a jelly that sags a lot (linear model), one substep, no blow-up */
    sq_mesh *m = th_box(2, 2, 2, 0.1, 0.1, 0.1);
    sq_material mat = mat_E_nu(100, 0.3, 0.001);
    sq_err e = {{0}};
    sq_body *b = cube_body(m, &mat, 0.9, 0.02, &e);
    CHECK(b != NULL);
    if (b) {
        double eb, ea, dmax;
        CHECK(run_frames(b, 150, 0.03, 1.0, &eb, &ea, &dmax) == 0);
        CHECK(isfinite(dmax));
        /* damped after release: energy no higher than while loaded (10% slack of |energy| for
         * the O(w dt) difference between measured and conserved symplectic energy) */
        CHECK(ea <= eb + 0.1 * fabs(eb) + 1e-12);
        sq_body_destroy(b);
    }
    sq_mesh_free(m);
}

SQ_TEST(stability_near_incompressible_costs_steps)
{
    /* nu -> 0.5: lambda explodes, so does the P-wave speed and the substep count */
    sq_mesh *m = th_box(2, 2, 2, 0.1, 0.1, 0.1);
    sq_material m3 = mat_E_nu(1e5, 0.3, 0), m499 = mat_E_nu(1e5, 0.499, 0);
    sq_err e = {{0}};
    sq_body *b3 = cube_body(m, &m3, 0.9, 0.02, &e), *b499 = cube_body(m, &m499, 0.9, 0.02, &e);
    CHECK(b3 && b499);
    if (b3 && b499) {
        /* P-wave speed ratio sqrt((lambda + 2 mu) / ...) is ~5.6 between nu 0.3 and 0.499:
         * at least 4x the substeps (powers of two) */
        double s3 = 0.02 / sq_body_level_dt(b3, 0), s499 = 0.02 / sq_body_level_dt(b499, 0);
        CHECK(s499 >= 4 * s3);
        double eb, ea, dmax;
        CHECK(run_frames(b499, 20, 0.01, 0.2, &eb, &ea, &dmax) == 0);
        CHECK(isfinite(dmax));
    }
    sq_body_destroy(b3);
    sq_body_destroy(b499);
    sq_mesh_free(m);
}

SQ_TEST(stability_step_requests_refused_or_adjusted)
{
    sq_mesh *m = th_box(2, 2, 2, 0.1, 0.1, 0.1);
    sq_material mat = mat_E_nu(1e5, 0.3, 0);
    sq_err e = {{0}};
    /* a fraction above 1 is refused, the message names the value and the range */
    CHECK(cube_body(m, &mat, 1.5, 0.02, &e) == NULL);
    CHECK_CONTAINS(e.msg, "step_fraction 1.5");
    /* a frame period of 2x the bound is cut into substeps below it */
    sq_body *b = cube_body(m, &mat, 0.9, 0.02, &e);
    CHECK(b != NULL);
    if (b) {
        double bound = sq_body_level_bound(b, 0);
        sq_body_destroy(b);
        b = cube_body(m, &mat, 0.9, 2 * bound, &e);
        CHECK(b != NULL);
        if (b) {
            CHECK_NEAR(2 * bound / sq_body_level_dt(b, 0), 4, 1e-9);
            CHECK(sq_body_level_dt(b, 0) <= 0.9 * bound);
            double eb, ea, dmax;
            CHECK(run_frames(b, 2000, 0, 1e9, &eb, &ea, &dmax) == 0);
            CHECK(isfinite(dmax));
            sq_body_destroy(b);
        }
    }
    /* stiffness damping so high the bound needs more than 2^20 substeps: refused, named */
    sq_material hd = mat_E_nu(1e5, 0.3, 1000);
    CHECK(cube_body(m, &hd, 0.9, 0.02, &e) == NULL);
    CHECK_CONTAINS(e.msg, "substeps per frame");
    sq_mesh_free(m);
}

SQ_TEST(stability_above_bound_blows_up_test_only)
{
    /* the path the body never takes: step the level directly at 2x its bound (undamped) */
    sq_mesh *m = th_box(2, 2, 2, 0.1, 0.1, 0.1);
    sq_material mat = mat_E_nu(1e5, 0.3, 0);
    mat.rayleigh_mass = 0;
    sq_err e = {{0}};
    sq_body *b = cube_body(m, &mat, 0.9, 0.02, &e);
    CHECK(b != NULL);
    if (b) {
        sq_level *L = sq_body_level(b, 0);
        double grow[2];
        static const double frac[2] = {1.0, 2.0};
        for (int k = 0; k < 2; k++) {
            for (int i = 0; i < 3 * L->model.n; i++) {
                L->state.d[i] = (L->model.fixed[i / 3] & (1u << (i % 3))) ? 0 : 1e-7 * (i % 2 ? 1 : -1);
                L->state.v[i] = 0;
            }
            double dmax = 0;
            for (int s = 0; s < 1000; s++) {
                sq_level_forces(&L->model, &L->state, &mat, sq_body_get_def(b)->gravity, NULL);
                sq_level_integrate(&L->model, &L->state, frac[k] * L->bound, NULL);
            }
            for (int i = 0; i < 3 * L->model.n; i++)
                dmax = th_max(dmax, fabs(L->state.d[i]));
            grow[k] = dmax;
        }
        /* at the bound: gravity sag only (~1e-4 m); at 2x: exponential growth (or overflow) */
        CHECK(grow[0] < 1e-3);
        CHECK(!(grow[1] < 1e3));
        sq_body_destroy(b);
    }
    sq_mesh_free(m);
}

SQ_TEST(stability_slivers_accepted_or_refused)
{
    /* a double pyramid around one sliver A B C D of flatness eps (sweep's mesh) */
    static const double eps[2] = {1e-6, 1e-10};
    for (int k = 0; k < 2; k++) {
        const double s = 0.1;
        double x[6][3] = {{0, 0, 0}, {s, s, 0}, {s, 0, eps[k] * s}, {0, s, eps[k] * s}, {s / 2, s / 2, s},
                          {s / 2, s / 2, -s}};
        int t[5][4] = {{0, 1, 2, 3}, {0, 2, 3, 4}, {1, 2, 3, 4}, {0, 1, 2, 5}, {0, 1, 3, 5}};
        for (int q = 0; q < 5; q++) { /* orient positively */
            const double *a = x[t[q][0]], *bb = x[t[q][1]], *c = x[t[q][2]], *d = x[t[q][3]];
            double u[3], v[3], w[3];
            for (int j = 0; j < 3; j++) {
                u[j] = bb[j] - a[j];
                v[j] = c[j] - a[j];
                w[j] = d[j] - a[j];
            }
            double vol = u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0]) +
                         u[2] * (v[0] * w[1] - v[1] * w[0]);
            if (vol < 0) {
                int tmp = t[q][2];
                t[q][2] = t[q][3];
                t[q][3] = tmp;
            }
        }
        sq_err e = {{0}};
        sq_mesh *m = sq_mesh_from_arrays(6, &x[0][0], 5, &t[0][0], "sliver", &e);
        if (k == 1) {
            CHECK(m == NULL);
            CHECK_CONTAINS(e.msg, "degenerate");
            sq_mesh_free(m);
            continue;
        }
        CHECK(m != NULL);
        if (!m) {
            fprintf(stderr, "%s\n", e.msg);
            continue;
        }
        sq_material mat = mat_E_nu(1e5, 0.3, 0);
        sq_body_def def = th_body_def(m);
        def.material = mat;
        def.gravity[2] = -9.81;
        def.nconstraints = 1;
        def.constraints[0].kind = SQ_REGION_HALFSPACE; /* the bottom apex */
        def.constraints[0].a[2] = -0.5 * s;
        def.constraints[0].b[2] = 1;
        def.constraints[0].axes = 7;
        sq_body *b = sq_body_create(&def, &e);
        CHECK(b != NULL);
        if (b) {
            /* the sliver's tiny height sets the bound: thousands of substeps, still stable */
            CHECK(lround(def.frame_dt / sq_body_level_dt(b, 0)) >= 1024);
            int resets = 0;
            for (int f = 0; f < 3; f++) {
                sq_frame_profile prof;
                sq_body_frame(b, NULL, 0, NULL, &prof, 0);
                resets += prof.reset;
            }
            CHECK(resets == 0);
            const double *d = sq_body_displacement(b, 0);
            for (int i = 0; i < 18; i++)
                CHECK(isfinite(d[i]) && fabs(d[i]) < 0.05);
            sq_body_destroy(b);
        }
        sq_mesh_free(m);
    }
}

SQ_TEST(stability_deep_tool_and_undamped_release)
{
    /* a sphere pushed to the body's centre, held, released, no damping at all: nothing blows
     * up and the energy after the release stays at the level the tool left */
    sq_mesh *m = th_box(3, 3, 3, 0.1, 0.1, 0.1);
    sq_material mat = mat_E_nu(1e4, 0.3, 0);
    mat.rayleigh_mass = 0;
    sq_err e = {{0}};
    sq_body *b = cube_body(m, &mat, 0.9, 0.02, &e);
    CHECK(b != NULL);
    if (b) {
        double eb, ea, dmax;
        CHECK(run_frames(b, 100, 0.08, 0.6, &eb, &ea, &dmax) == 0);
        CHECK(isfinite(dmax) && dmax < 0.2);
        CHECK(isfinite(ea) && ea <= eb + 0.1 * fabs(eb) + 1e-12);
        sq_body_destroy(b);
    }
    sq_mesh_free(m);
}
