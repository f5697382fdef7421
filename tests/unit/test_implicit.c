/* test_implicit.c - the implicit integrator (level/implicit.c, docs/physics.md section 12):
 * the static limit, energy that never grows, stiff and near-incompressible extremes at large
 * steps, tools and feedback inside the solve, the stop rule, and the refusals. */
#include "sq_test.h"
#include "test_sim_helpers.h"

/* a clamped cantilever 1 x 0.2 x 0.2 m (nx x 2 x 2 cells), gravity -z, the given material */
static double cantilever_g = -9.81; /* gravity z of the next cantilever */

static sq_body *cantilever(sq_mesh **mp, int nx, double E, double nu, double a, sq_integrator_kind in,
                           sq_elasticity_kind el)
{
    sq_mesh *m = th_box(nx, 2, 2, 1, 0.2, 0.2);
    *mp = m;
    if (!m)
        return NULL;
    sq_body_def def = th_body_def(m);
    CHECK(sq_material_from_E_nu(&def.material, E, nu, NULL) == 0);
    def.material.density = 1000;
    def.material.rayleigh_mass = a;
    def.material.rayleigh_stiffness = 0;
    def.gravity[2] = cantilever_g;
    def.nconstraints = 1;
    def.constraints[0] = (sq_constraint){SQ_REGION_BOX, {-1, -1, -1}, {1e-6, 1, 1}, 7};
    def.integrator = in;
    def.elasticity = el;
    def.implicit.tol = 1e-9;
    def.implicit.max_iter = 5000;
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    if (!b)
        fprintf(stderr, "    %s\n", e.msg);
    else
        sq_body_set_sleep(b, 0, 0, 0);
    return b;
}

static double tip_z(const sq_body *b)
{
    int k = sq_body_sim_level(b);
    return th_tip_z(sq_body_mesh(b, k), sq_body_displacement(b, k), 1);
}

/* damped to rest, one backward Euler step per frame reaches the static solve: the fixed point of
 * the step is K d = M g exactly (the damping terms vanish at v = 0), so after 12 s at a = 20
 * (residual motion ~e^-100 of the first mode's) the tip equals the static tip to the CG
 * tolerance: 1e-6 relative */
SQ_TEST(implicit_damped_run_reaches_static_solve)
{
    sq_mesh *m;
    sq_body *b = cantilever(&m, 10, 1e6, 0.3, 20, SQ_INTEGRATOR_IMPLICIT, SQ_ELASTICITY_LINEAR);
    TH_REQUIRE(b);
    for (int f = 0; f < 600; f++)
        sq_body_frame(b, NULL, 0, NULL, NULL, 0);
    const sq_level *L = sq_body_level(b, 0);
    double *d = malloc(sizeof(double) * 3 * m->nnodes);
    sq_err e = {{0}};
    double g[3] = {0, 0, -9.81};
    CHECK(sq_level_static_solve(&L->model, g, 1e-12, 20000, d, NULL, &e) == 0);
    double ts = th_tip_z(m, d, 1);
    double ti = tip_z(b);
    fprintf(stderr, "    tip: implicit %.9g m, static %.9g m\n", ti, ts);
    CHECK(ts < 0);
    CHECK(fabs(ti - ts) <= 1e-6 * fabs(ts));
    free(d);
    sq_body_destroy(b);
    sq_mesh_free(m);
}

/* undamped, no gravity, released from a bent shape: kinetic + elastic energy never grows from one
 * frame to the next (backward Euler dissipates; a CG residual of 1e-9 may add at most ~1e-9 of
 * the energy per frame, the tolerance), and it does decay (the scheme's numerical damping) */
static void energy_check(sq_elasticity_kind el, int substeps, int newton)
{
    sq_mesh *m;
    cantilever_g = 0;
    sq_body *b = cantilever(&m, 8, 1e6, 0.3, 0, SQ_INTEGRATOR_IMPLICIT, el);
    cantilever_g = -9.81;
    TH_REQUIRE(b);
    sq_level *L = sq_body_level(b, 0);
    sq_body_def def = *sq_body_get_def(b);
    def.implicit.substeps = substeps;
    def.implicit.newton = newton;
    sq_err e = {{0}};
    CHECK(sq_body_set_integrator(b, SQ_INTEGRATOR_IMPLICIT, &def.implicit, &e) == 0);
    /* the bent shape: the static sag under 20 g (the body itself has no gravity) */
    double g[3] = {0, 0, -196.2};
    CHECK(sq_level_static_solve(&L->model, g, 1e-10, 20000, L->state.d, NULL, &e) == 0);
    sq_level_corot_reset(&L->state);
    double e0 = sq_body_kinetic_energy(b) + sq_body_elastic_energy(b), prev = e0, grew = 0;
    for (int f = 0; f < 150; f++) {
        sq_frame_profile pf;
        sq_body_frame(b, NULL, 0, NULL, &pf, 0);
        CHECK(pf.reset == 0);
        double en = sq_body_kinetic_energy(b) + sq_body_elastic_energy(b);
        grew = th_max(grew, (en - prev) / e0);
        prev = en;
    }
    fprintf(stderr, "    %s, %d substep(s): energy %.4g J -> %.4g J, largest growth in a frame %.3g of E0\n",
            el == SQ_ELASTICITY_LINEAR ? "linear" : "corotational", substeps, e0, prev, grew);
    CHECK(e0 > 0);
    CHECK(grew <= 1e-9);
    CHECK(prev < 0.9 * e0);
    sq_body_destroy(b);
    sq_mesh_free(m);
}

SQ_TEST(implicit_undamped_energy_never_grows)
{
    energy_check(SQ_ELASTICITY_LINEAR, 1, 1);
    energy_check(SQ_ELASTICITY_LINEAR, 4, 1);
    energy_check(SQ_ELASTICITY_COROTATIONAL, 1, 1); /* the energy guard's extra Newton iterations */
    energy_check(SQ_ELASTICITY_COROTATIONAL, 2, 3);
}

/* the extremes the explicit step cannot take: E 1e10 Pa, nu 0.499, 10 Hz frames (h = 0.1 s),
 * a tool dragging the tip: no reset, finite state, and the sag at the end within 1 % of the
 * static solve's (after the tool lets go and 2 s of damped settling) */
SQ_TEST(implicit_stiff_near_incompressible_large_step)
{
    sq_mesh *m = th_box(10, 2, 2, 1, 0.2, 0.2);
    TH_REQUIRE(m);
    sq_body_def def = th_body_def(m);
    CHECK(sq_material_from_E_nu(&def.material, 1e10, 0.499, NULL) == 0);
    def.material.density = 1000;
    def.material.rayleigh_mass = 5;
    def.material.rayleigh_stiffness = 0;
    def.gravity[2] = -9.81;
    def.frame_dt = 0.1;
    def.nconstraints = 1;
    def.constraints[0] = (sq_constraint){SQ_REGION_BOX, {-1, -1, -1}, {1e-6, 1, 1}, 7};
    def.integrator = SQ_INTEGRATOR_IMPLICIT;
    def.implicit.tol = 1e-8;
    def.implicit.max_iter = SQ_IMPLICIT_MAX_ITER;
    sq_err e = {{0}};
    /* what the explicit integrator would take for this body at 10 Hz (reported, and large) */
    sq_body *b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    int sub[SQ_MAX_LEVELS];
    sq_level *L0 = sq_body_level(b, 0);
    sub[0] = 1 << L0->substeps_log2;
    fprintf(stderr, "    explicit would need %d substeps per frame (Gershgorin), %d (sharp)\n", sub[0], L0->nsub);
    CHECK(L0->nsub > 10000);
    sq_body_destroy(b);
    b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    sq_body_set_sleep(b, 0, 0, 0);
    sq_tool t = th_tool(SQ_TOOL_GRAB);
    t.id = 1;
    t.active = 1;
    t.radius = 0.06;
    t.origin[0] = 1, t.origin[1] = 0.1, t.origin[2] = 0.1;
    t.has_origin = 1;
    int resets = 0, unconverged = 0;
    for (int f = 0; f < 40; f++) {
        t.active = f < 20;
        memcpy(t.pos, t.origin, sizeof t.pos);
        t.pos[2] += 1e-4 * sin(M_PI * f / 10.0);
        sq_frame_profile pf;
        sq_body_frame(b, &t, 1, NULL, &pf, 0);
        resets += pf.reset;
        unconverged += pf.event_kind == SQ_HEALTH_SOLVE_UNCONVERGED;
    }
    const sq_level *L = sq_body_level(b, 0);
    double *d = malloc(sizeof(double) * 3 * m->nnodes);
    double g[3] = {0, 0, -9.81};
    CHECK(sq_level_static_solve(&L->model, g, 1e-12, 50000, d, NULL, &e) == 0);
    double ts = th_tip_z(m, d, 1), ti = tip_z(b);
    fprintf(stderr, "    E 1e10 nu 0.499 h 0.1 s: resets %d, unconverged %d, tip %.4g m (static %.4g m)\n", resets,
            unconverged, ti, ts);
    CHECK(resets == 0);
    CHECK(unconverged == 0);
    CHECK(isfinite(ti));
    CHECK(fabs(ti - ts) <= 0.01 * fabs(ts));
    free(d);
    sq_body_destroy(b);
    sq_mesh_free(m);
}

/* a sphere pressing on a clamped cube, implicit: at rest, tool force + support reactions +
 * weight = 0 (the test of the explicit step in test_physics.c, same tolerance: 1e-6 of the
 * weight, the CG tolerance being 1e-10) */
SQ_TEST(implicit_tool_force_balance_at_rest)
{
    sq_mesh *m = th_box(4, 4, 4, 1, 1, 1);
    TH_REQUIRE(m);
    sq_body_def def = th_body_def(m);
    def.gravity[2] = -9.81;
    def.nconstraints = 1;
    def.constraints[0] = (sq_constraint){SQ_REGION_BOX, {-1, -1, -1}, {2, 2, 1e-6}, 7};
    def.material.rayleigh_mass = 20;
    def.integrator = SQ_INTEGRATOR_IMPLICIT;
    def.implicit.tol = 1e-10;
    def.implicit.max_iter = 5000;
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    sq_tool t = th_tool(SQ_TOOL_SPHERE);
    t.id = 7;
    t.active = 1;
    t.radius = 0.3;
    t.pos[0] = t.pos[1] = 0.5;
    t.pos[2] = 1.2;
    sq_tool_feedback fb;
    for (int f = 0; f < 300; f++)
        sq_body_frame(b, &t, 1, &fb, NULL, 0);
    CHECK(fb.id == 7);
    CHECK(fb.nnodes >= 1);
    sq_level *L = sq_body_level(b, 0);
    double wn, rz;
    double off = th_tool_balance(L, m, &t, &fb, def.gravity, &wn, &rz);
    fprintf(stderr, "    implicit balance: tool %.4g N (%d nodes), reactions %.4g N, weight %.4g N, sum %.3g N\n",
            fb.force[2], fb.nnodes, rz, -wn, off);
    CHECK(fb.force[2] > 0.05 * wn);
    CHECK(off <= 1e-6 * wn);
    sq_body_destroy(b);
    sq_mesh_free(m);
}

/* the stop rule: a cap below what the tolerance needs ends the solve there, raises the typed
 * warning with its numbers, and the frame still advances (no reset) */
SQ_TEST(implicit_iteration_cap_is_a_health_warning)
{
    sq_mesh *m;
    sq_body *b = cantilever(&m, 10, 1e7, 0.45, 5, SQ_INTEGRATOR_IMPLICIT, SQ_ELASTICITY_LINEAR);
    TH_REQUIRE(b);
    sq_implicit_def imp = sq_body_get_def(b)->implicit;
    imp.max_iter = 3;
    imp.tol = 1e-10;
    sq_err e = {{0}};
    CHECK(sq_body_set_integrator(b, SQ_INTEGRATOR_IMPLICIT, &imp, &e) == 0);
    sq_frame_profile pf;
    sq_body_frame(b, NULL, 0, NULL, &pf, 0);
    CHECK(pf.cg_iterations == 3);
    CHECK(pf.cg_residual > 1e-10);
    CHECK(pf.event_kind == SQ_HEALTH_SOLVE_UNCONVERGED);
    CHECK_CONTAINS(pf.event, "cg_max_iterations");
    CHECK(sq_body_health(b)[SQ_HEALTH_SOLVE_UNCONVERGED].count == 1);
    CHECK(pf.reset == 0);
    CHECK(tip_z(b) < 0);
    /* with room to converge: no warning, the residual under the tolerance */
    imp.max_iter = 5000;
    CHECK(sq_body_set_integrator(b, SQ_INTEGRATOR_IMPLICIT, &imp, &e) == 0);
    sq_body_frame(b, NULL, 0, NULL, &pf, 0);
    CHECK(pf.event_kind == SQ_HEALTH_NONE);
    CHECK(pf.cg_residual <= 1e-10);
    CHECK(pf.cg_iterations > 3);
    sq_body_destroy(b);
    sq_mesh_free(m);
}

/* Jacobi and block Jacobi reach the same step (to the tolerance), block Jacobi in fewer
 * iterations on a near-incompressible body; more Newton iterations shrink the corotational
 * residual they report */
SQ_TEST(implicit_preconditioners_and_newton)
{
    int its[2];
    double tips[2];
    for (int pc = 0; pc < 2; pc++) {
        sq_mesh *m;
        sq_body *b = cantilever(&m, 10, 1e6, 0.49, 5, SQ_INTEGRATOR_IMPLICIT, SQ_ELASTICITY_LINEAR);
        TH_REQUIRE(b);
        sq_implicit_def imp = sq_body_get_def(b)->implicit;
        imp.precond = pc ? SQ_PRECOND_BLOCK : SQ_PRECOND_JACOBI;
        sq_err e = {{0}};
        CHECK(sq_body_set_integrator(b, SQ_INTEGRATOR_IMPLICIT, &imp, &e) == 0);
        its[pc] = 0;
        for (int f = 0; f < 5; f++) {
            sq_frame_profile pf;
            sq_body_frame(b, NULL, 0, NULL, &pf, 0);
            its[pc] += pf.cg_iterations;
        }
        tips[pc] = tip_z(b);
        sq_body_destroy(b);
        sq_mesh_free(m);
    }
    fprintf(stderr, "    5 frames, nu 0.49: Jacobi %d CG iterations, block Jacobi %d; tips %.9g, %.9g\n", its[0], its[1],
            tips[0], tips[1]);
    CHECK(its[1] < its[0]);
    CHECK(fabs(tips[0] - tips[1]) <= 1e-6 * fabs(tips[1]));

    /* corotational, a grab swinging the tip 0.3 m in a frame: Newton residual falls with iterations */
    double res[2];
    for (int k = 0; k < 2; k++) {
        sq_mesh *m;
        sq_body *b = cantilever(&m, 10, 1e5, 0.3, 5, SQ_INTEGRATOR_IMPLICIT, SQ_ELASTICITY_COROTATIONAL);
        TH_REQUIRE(b);
        sq_implicit_def imp = sq_body_get_def(b)->implicit;
        imp.newton = k ? 4 : 2;
        sq_err e = {{0}};
        CHECK(sq_body_set_integrator(b, SQ_INTEGRATOR_IMPLICIT, &imp, &e) == 0);
        sq_tool t = th_tool(SQ_TOOL_GRAB);
        t.id = 1, t.active = 1, t.radius = 0.06, t.has_origin = 1;
        t.origin[0] = 1, t.origin[1] = 0.1, t.origin[2] = 0.1;
        memcpy(t.pos, t.origin, sizeof t.pos);
        t.pos[2] += 0.3;
        sq_frame_profile pf;
        sq_body_frame(b, &t, 1, NULL, &pf, 0);
        CHECK(pf.newton_iterations >= 2);
        res[k] = pf.newton_residual;
        sq_body_destroy(b);
        sq_mesh_free(m);
    }
    fprintf(stderr, "    corotational Newton residual: 2 iterations %.3g, 4 iterations %.3g\n", res[0], res[1]);
    CHECK(res[0] > 0);
    CHECK(res[1] < 0.5 * res[0]);
}

/* refusals: implicit with adaptive lod, settings out of range, explicit back when the explicit
 * step cannot run; each names the fix and changes nothing */
SQ_TEST(implicit_refusals_name_the_range)
{
    sq_mesh *m;
    sq_body *b = cantilever(&m, 4, 1e6, 0.3, 5, SQ_INTEGRATOR_EXPLICIT, SQ_ELASTICITY_LINEAR);
    TH_REQUIRE(b);
    sq_implicit_def ok = sq_implicit_def_default(), bad;
    sq_err e = {{0}};
    struct {
        int field;
        double value;
        const char *word;
    } cases[] = {{0, 0, "substeps"}, {0, 65, "substeps"}, {1, 0, "cg_tolerance"}, {1, NAN, "cg_tolerance"},
                 {1, -1e-6, "cg_tolerance"}, {1, 1, "cg_tolerance"}, {2, 0, "cg_max_iterations"},
                 {2, SQ_IMPLICIT_MAX_ITER + 1, "cg_max_iterations"}, {3, 7, "preconditioner"},
                 {4, 0, "newton_iterations"}};
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
        bad = ok;
        switch (cases[k].field) {
        case 0: bad.substeps = (int)cases[k].value; break;
        case 1: bad.tol = cases[k].value; break;
        case 2: bad.max_iter = (int)cases[k].value; break;
        case 3: bad.precond = (int)cases[k].value; break;
        default: bad.newton = (int)cases[k].value; break;
        }
        e.msg[0] = 0;
        CHECK(sq_body_set_integrator(b, SQ_INTEGRATOR_IMPLICIT, &bad, &e) == -1);
        CHECK_CONTAINS(e.msg, cases[k].word);
        CHECK(sq_body_get_def(b)->integrator == SQ_INTEGRATOR_EXPLICIT);
    }
    CHECK(sq_body_set_integrator(b, (sq_integrator_kind)5, &ok, &e) == -1);
    CHECK_CONTAINS(e.msg, "\"explicit\" or \"implicit\"");
    /* adaptive lod: refused at creation and by set */
    sq_body_def def = *sq_body_get_def(b);
    def.lod.mode = SQ_LOD_ADAPTIVE;
    def.integrator = SQ_INTEGRATOR_IMPLICIT;
    CHECK(sq_body_create(&def, &e) == NULL);
    CHECK_CONTAINS(e.msg, "fixed lod");
    CHECK(sq_body_set_integrator(b, SQ_INTEGRATOR_IMPLICIT, &ok, &e) == 0);
    sq_lod_def lod = sq_body_get_def(b)->lod;
    lod.mode = SQ_LOD_ADAPTIVE;
    CHECK(sq_body_set_lod(b, &lod, &e) == -1);
    CHECK_CONTAINS(e.msg, "implicit");
    CHECK(sq_body_get_def(b)->lod.mode == SQ_LOD_FIXED);
    /* a stiffness only the implicit step can take: back to explicit is refused */
    sq_material mat = sq_body_get_def(b)->material;
    CHECK(sq_material_from_E_nu(&mat, 1e17, 0.3, NULL) == 0);
    CHECK(sq_body_set_material(b, &mat, SQ_OPERATOR_FEM, &e) == 0);
    CHECK(sq_body_set_integrator(b, SQ_INTEGRATOR_EXPLICIT, &ok, &e) == -1);
    CHECK_CONTAINS(e.msg, "substeps");
    CHECK(sq_body_get_def(b)->integrator == SQ_INTEGRATOR_IMPLICIT);
    sq_body_destroy(b);
    sq_mesh_free(m);
}

/* the multigrid preconditioner over the body's own coarser levels (boxes of 5, 10 and 20 cells
 * along the beam; the levels' grids are not nested tet-wise): far fewer CG iterations than
 * block Jacobi on the finest, and the same step to the tolerance (1e-6 relative on the tip,
 * the CG tolerance being 1e-9) */
SQ_TEST(implicit_multigrid_over_the_coarser_levels)
{
    sq_mesh *ms[3];
    for (int k = 0; k < 3; k++) {
        int nx = 5 << k;
        ms[k] = th_box(nx, nx / 5, nx / 5, 1, 0.2, 0.2);
        TH_REQUIRE(ms[k]);
    }
    int its[3];
    double tips[3];
    for (int pc = 0; pc < 3; pc++) {
        sq_body_def def = th_body_def(ms[2]);
        def.nlevels = 3;
        for (int k = 0; k < 3; k++)
            def.levels[k] = ms[k];
        def.lod.level = 2;
        CHECK(sq_material_from_E_nu(&def.material, 1e7, 0.4, NULL) == 0);
        def.material.density = 1000;
        def.material.rayleigh_mass = 1;
        def.material.rayleigh_stiffness = 0;
        def.gravity[2] = -9.81;
        def.nconstraints = 1;
        def.constraints[0] = (sq_constraint){SQ_REGION_BOX, {-1, -1, -1}, {1e-6, 1, 1}, 7};
        def.integrator = SQ_INTEGRATOR_IMPLICIT;
        def.implicit.precond = pc;
        def.implicit.tol = 1e-9;
        def.implicit.max_iter = 5000;
        sq_err e = {{0}};
        sq_body *b = sq_body_create(&def, &e);
        TH_REQUIRE(b);
        its[pc] = 0;
        for (int f = 0; f < 5; f++) {
            sq_frame_profile pf;
            sq_body_frame(b, NULL, 0, NULL, &pf, 0);
            its[pc] += pf.cg_iterations;
            CHECK(pf.event_kind == SQ_HEALTH_NONE);
        }
        tips[pc] = tip_z(b);
        sq_body_destroy(b);
    }
    fprintf(stderr, "    5 frames, %d nodes: CG iterations Jacobi %d, block Jacobi %d, multigrid %d; tips %.9g %.9g %.9g\n",
            ms[2]->nnodes, its[0], its[1], its[2], tips[0], tips[1], tips[2]);
    CHECK(its[2] * 5 < its[1]);
    CHECK(fabs(tips[2] - tips[1]) <= 1e-6 * fabs(tips[1]));
    CHECK(fabs(tips[0] - tips[1]) <= 1e-6 * fabs(tips[1]));
    for (int k = 0; k < 3; k++)
        sq_mesh_free(ms[k]);
}

/* ---- scene keys ------------------------------------------------------------------------ */

#include "scene/scene.h"
#include "test_scene_helpers.h"

/* the shipped sphere-grab scene (fixed lod) with "elasticity": ... replaced by `to` */
static sq_scene *sphere_grab_keys(const char *from, const char *to, sq_err *e)
{
    static char text[65536], out[66000];
    if (th_shipped_scene_text("sphere-grab", text, sizeof text))
        return NULL;
    char *at = strstr(text, from);
    if (!at)
        return NULL;
    snprintf(out, sizeof out, "%.*s%s%s", (int)(at - text), text, to, at + strlen(from));
    return sq_scene_parse(out, th_scenes_dir(), "sphere-grab", e);
}

SQ_TEST(implicit_scene_keys_and_refusals)
{
    const char *el = "\"elasticity\": \"corotational\",";
    sq_err e = {{0}};
    sq_scene *sc = sphere_grab_keys(el, "\"elasticity\": \"corotational\", \"integrator\": \"implicit\", \"implicit\": "
                                        "{\"substeps\": 2, \"cg_tolerance\": 1e-5, \"cg_max_iterations\": 300, "
                                        "\"preconditioner\": \"multigrid\", \"newton_iterations\": 2},", &e);
    TH_REQUIRE(sc);
    const sq_body_def *d = &sc->bodies[0];
    CHECK(d->integrator == SQ_INTEGRATOR_IMPLICIT);
    CHECK(d->implicit.substeps == 2 && d->implicit.tol == 1e-5 && d->implicit.max_iter == 300);
    CHECK(d->implicit.precond == SQ_PRECOND_MULTIGRID && d->implicit.newton == 2);
    sq_scene_free(sc);
    /* without the keys: explicit, the defaults */
    sc = sphere_grab_keys(el, el, &e);
    TH_REQUIRE(sc);
    CHECK(sc->bodies[0].integrator == SQ_INTEGRATOR_EXPLICIT);
    CHECK(sc->bodies[0].implicit.substeps == 1 && sc->bodies[0].implicit.tol == 1e-6);
    sq_scene_free(sc);
    static const char *const bad[][2] = {
        {"\"integrator\": \"rk4\",", "bodies[0].integrator"},
        {"\"integrator\": \"implicit\", \"implicit\": {\"cg_tolerance\": 0},", "cg_tolerance"},
        {"\"integrator\": \"implicit\", \"implicit\": {\"cg_tolerance\": -1},", "(0, 1)"},
        {"\"integrator\": \"implicit\", \"implicit\": {\"cg_max_iterations\": 0},", "cg_max_iterations"},
        {"\"integrator\": \"implicit\", \"implicit\": {\"cg_max_iterations\": 20000},", "cg_max_iterations"},
        {"\"integrator\": \"implicit\", \"implicit\": {\"substeps\": 100},", "substeps"},
        {"\"integrator\": \"implicit\", \"implicit\": {\"preconditioner\": \"ilu\"},", "multigrid"},
        {"\"integrator\": \"implicit\", \"implicit\": {\"tolerance\": 1e-3},", "tolerance"},
        {"\"integrator\": \"implicit\", \"implicit\": [1],", "bodies[0].implicit"},
    };
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
        memset(&e, 0, sizeof e);
        sc = sphere_grab_keys(el, bad[k][0], &e);
        CHECK(sc == NULL);
        CHECK_CONTAINS(e.msg, bad[k][1]);
        sq_scene_free(sc);
    }
    /* implicit with adaptive lod: refused at load, naming the fix */
    memset(&e, 0, sizeof e);
    static char text[65536], out[66000], out2[66000];
    CHECK(th_shipped_scene_text("sphere-grab", text, sizeof text) == 0);
    char *at = strstr(text, "\"mode\": \"fixed\", \"level\": 1");
    TH_REQUIRE(at);
    snprintf(out, sizeof out, "%.*s\"mode\": \"adaptive\"%s", (int)(at - text), text, at + strlen("\"mode\": \"fixed\", \"level\": 1"));
    at = strstr(out, el);
    TH_REQUIRE(at);
    snprintf(out2, sizeof out2, "%.*s\"integrator\": \"implicit\",%s", (int)(at - out), out, at + strlen(el));
    sc = sq_scene_parse(out2, th_scenes_dir(), "sphere-grab", &e);
    CHECK(sc == NULL);
    CHECK_CONTAINS(e.msg, "fixed lod");
    sq_scene_free(sc);
}
