/* test_sim_body.c - the fixed-mode body: create, frame, surface, probe, vtk, health, sleep,
 * set_material refusal, tools. */
#include "sq_test.h"
#include "test_sim_helpers.h"

/* cube [0,1]^3 at n^3 cells, bottom face fixed, gravity -z, the paper's material */
static sq_body_def cube_def(const sq_mesh *m)
{
    sq_body_def def = th_body_def(m);
    def.name = "cube";
    def.gravity[2] = -9.81;
    def.nconstraints = 1;
    def.constraints[0].kind = SQ_REGION_BOX;
    def.constraints[0].a[0] = def.constraints[0].a[1] = def.constraints[0].a[2] = -1;
    def.constraints[0].b[0] = def.constraints[0].b[1] = 2;
    def.constraints[0].b[2] = 1e-3;
    def.constraints[0].axes = 7;
    return def;
}

SQ_TEST(sim_body_fixed_frame_surface_probe_vtk)
{
    sq_mesh *m = th_box(3, 3, 3, 1, 1, 1);
    TH_REQUIRE(m);
    sq_body_def def = cube_def(m);
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    CHECK(b != NULL);
    if (!b) {
        fprintf(stderr, "%s\n", e.msg);
        return;
    }
    CHECK(sq_body_level_dt(b, 0) > 0);
    CHECK(sq_body_level_dt(b, 0) <= 0.9 * sq_body_level_bound(b, 0) * (1 + 1e-12));
    sq_frame_profile prof;
    for (int f = 0; f < 10; f++) {
        CHECK(sq_body_frame(b, NULL, 0, NULL, &prof, 0) == 0);
        CHECK(!prof.reset);
    }
    CHECK(prof.node_updates == (long)m->nnodes * prof.substeps[0]);
    /* the top sags under gravity */
    double u[3], top[3] = {1, 1, 1};
    CHECK(sq_body_probe(b, top, u) == 0);
    CHECK(u[2] < -1e-5);
    double out[3] = {2, 2, 2};
    CHECK(sq_body_probe(b, out, u) == -1);
    /* surface state = rest + displacement of the surface nodes */
    const sq_mesh *sm = sq_body_surface_mesh(b);
    CHECK(sm == m);
    float *xyz = malloc(sizeof(float) * 3 * sm->nsurf);
    unsigned char *lev = malloc(sm->nsurf);
    sq_body_surface_state(b, xyz, lev);
    const double *d = sq_body_displacement(b, 0);
    for (int s = 0; s < sm->nsurf; s++) {
        int i = sm->surf_nodes[s];
        CHECK_NEAR(xyz[3 * s + 2], m->x[3 * i + 2] + d[3 * i + 2], 1e-6); /* float rounding */
        CHECK(lev[s] == 0);
    }
    char path[512];
    snprintf(path, sizeof path, "%s/body.vtk", sq_test_tmpdir());
    CHECK(sq_body_write_vtk(b, path, &e) == 0);
    FILE *f = fopen(path, "r");
    CHECK(f != NULL);
    if (f)
        fclose(f);
    CHECK(sq_body_kinetic_energy(b) > 0);
    CHECK(sq_body_elastic_energy(b) > 0);
    free(xyz);
    free(lev);
    sq_body_destroy(b);
    sq_mesh_free(m);
}

/* a fixed coarse level drives the finest surface by interpolation */
SQ_TEST(sim_body_coarse_level_drives_fine_surface)
{
    sq_mesh *c = th_box(2, 2, 2, 1, 1, 1), *fm = th_box(4, 4, 4, 1, 1, 1);
    CHECK(c && fm);
    if (!c || !fm)
        return;
    sq_body_def def = cube_def(c);
    def.nlevels = 2;
    def.levels[1] = fm;
    def.lod.level = 0;
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    CHECK(b != NULL);
    if (!b) {
        fprintf(stderr, "%s\n", e.msg);
        return;
    }
    CHECK(sq_body_displacement(b, 1) == NULL); /* fixed at 0: level 1's operator is not built */
    for (int f = 0; f < 5; f++)
        sq_body_frame(b, NULL, 0, NULL, NULL, 0);
    const sq_mesh *sm = sq_body_surface_mesh(b);
    CHECK(sm == fm);
    float *xyz = malloc(sizeof(float) * 3 * sm->nsurf);
    sq_body_surface_state(b, xyz, NULL);
    /* a fine surface vertex that is also a coarse node has exactly the coarse displacement */
    const double *dc = sq_body_displacement(b, 0);
    int checked = 0;
    for (int s = 0; s < sm->nsurf; s++) {
        const double *x = fm->x + 3 * sm->surf_nodes[s];
        for (int i = 0; i < c->nnodes; i++)
            if (fabs(c->x[3 * i] - x[0]) + fabs(c->x[3 * i + 1] - x[1]) + fabs(c->x[3 * i + 2] - x[2]) < 1e-12) {
                CHECK_NEAR(xyz[3 * s + 2] - x[2], dc[3 * i + 2], 1e-6);
                checked++;
            }
    }
    CHECK(checked == 26);
    free(xyz);
    sq_body_destroy(b);
    sq_mesh_free(c);
    sq_mesh_free(fm);
}

/* health: a NaN injected into the state is detected, reported and the body reset */
SQ_TEST(sim_body_nan_resets_and_reports)
{
    sq_mesh *m = th_box(2, 2, 2, 1, 1, 1);
    TH_REQUIRE(m);
    sq_body_def def = cube_def(m);
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    sq_body_frame(b, NULL, 0, NULL, NULL, 0);
    sq_level *L = sq_body_level(b, 0);
    L->state.d[3 * (L->model.n - 1) + 2] = NAN;
    sq_frame_profile prof;
    sq_body_frame(b, NULL, 0, NULL, &prof, 0);
    CHECK(prof.reset == 1);
    CHECK_CONTAINS(prof.event, "blow-up detected");
    CHECK_CONTAINS(prof.event, "reset to rest");
    /* typed: the kind, its value (the node) and the counter of the body */
    CHECK(prof.event_kind == SQ_HEALTH_BLOWUP_NAN);
    /* value: the first non-finite node (the NaN has spread to neighbours within the frame) */
    CHECK(prof.event_value[0] >= 0 && prof.event_value[0] < L->model.n &&
          prof.event_value[0] == floor(prof.event_value[0]));
    const sq_health_stat *hs = sq_body_health(b);
    CHECK(hs[SQ_HEALTH_BLOWUP_NAN].count == 1 && hs[SQ_HEALTH_BLOWUP_NAN].last_frame == 2);
    CHECK(hs[SQ_HEALTH_BLOWUP_NAN].last_value == prof.event_value[0]);
    CHECK(hs[SQ_HEALTH_BLOWUP_SPEED].count == 0 && hs[SQ_HEALTH_BLOWUP_STRETCH].count == 0);
    CHECK(strcmp(sq_health_kind_name(SQ_HEALTH_BLOWUP_NAN), "blowup_nan") == 0);
    for (int i = 0; i < 3 * L->model.n; i++)
        CHECK(L->state.d[i] == 0 && L->state.v[i] == 0);
    /* and it keeps going */
    sq_body_frame(b, NULL, 0, NULL, &prof, 0);
    CHECK(prof.reset == 0);
    CHECK(isfinite(sq_body_kinetic_energy(b)) && sq_body_kinetic_energy(b) > 0);
    sq_body_destroy(b);
    sq_mesh_free(m);
}

/* a material needing more than 2^20 substeps is refused and nothing changes */
SQ_TEST(sim_body_set_material_refusal_keeps_state)
{
    sq_mesh *m = th_box(2, 2, 2, 1, 1, 1);
    TH_REQUIRE(m);
    sq_body_def def = cube_def(m);
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    for (int f = 0; f < 3; f++)
        sq_body_frame(b, NULL, 0, NULL, NULL, 0);
    sq_level *L = sq_body_level(b, 0);
    size_t n3 = 3 * (size_t)L->model.n;
    double *d0 = malloc(sizeof(double) * n3), K0 = L->model.K[0], dt0 = L->dt;
    memcpy(d0, L->state.d, sizeof(double) * n3);
    sq_material hard = def.material;
    CHECK(sq_material_from_E_nu(&hard, 1e18, 0.3, &e) == 0);
    CHECK(sq_body_set_material(b, &hard, SQ_OPERATOR_FEM, &e) == -1);
    CHECK_CONTAINS(e.msg, "substeps per frame at 50 Hz");
    CHECK_CONTAINS(e.msg, "the limit is 2^20");
    CHECK_CONTAINS(e.msg, "E=1e+18");
    L = sq_body_level(b, 0);
    CHECK(memcmp(d0, L->state.d, sizeof(double) * n3) == 0);
    CHECK(L->model.K[0] == K0 && L->dt == dt0);
    CHECK(sq_body_get_def(b)->material.mu == def.material.mu);
    /* a bad value names itself */
    sq_material bad = def.material;
    bad.density = -1;
    CHECK(sq_body_set_material(b, &bad, SQ_OPERATOR_FEM, &e) == -1);
    CHECK_CONTAINS(e.msg, "density=-1");
    /* an accepted change keeps the state and rebuilds the operator */
    sq_material soft = def.material;
    soft.mu *= 0.5;
    CHECK(sq_body_set_material(b, &soft, SQ_OPERATOR_PAPER, &e) == 0);
    L = sq_body_level(b, 0);
    CHECK(memcmp(d0, L->state.d, sizeof(double) * n3) == 0);
    CHECK(L->dt >= dt0);
    free(d0);
    sq_body_destroy(b);
    sq_mesh_free(m);
}

/* creation errors name the problem */
SQ_TEST(sim_body_create_errors)
{
    sq_mesh *m = th_box(1, 1, 1, 1, 1, 1);
    TH_REQUIRE(m);
    sq_body_def def = cube_def(m);
    def.constraints[0].b[2] = 2; /* fixes everything */
    sq_err e = {{0}};
    CHECK(sq_body_create(&def, &e) == NULL);
    CHECK_CONTAINS(e.msg, "nothing can move");
    def = cube_def(m);
    def.material.mu = 0;
    CHECK(sq_body_create(&def, &e) == NULL);
    CHECK_CONTAINS(e.msg, "mu=0");
    def = cube_def(m);
    def.lod.level = 3;
    CHECK(sq_body_create(&def, &e) == NULL);
    CHECK_CONTAINS(e.msg, "lod level 3");
    CHECK(sq_material_from_E_nu(&def.material, 1e5, 0.5, &e) == -1);
    CHECK_CONTAINS(e.msg, "nu=0.5");
    sq_mesh_free(m);
}

SQ_TEST(sim_material_E_nu_round_trip)
{
    sq_material m = th_material(0, 0, 1000);
    sq_err e = {{0}};
    /* the paper cube: E = 760000/7 Pa, nu = 5/14; relative rounding ~1e-15 */
    CHECK(sq_material_from_E_nu(&m, 760000.0 / 7, 5.0 / 14, &e) == 0);
    CHECK_NEAR(m.mu, 40000, 1e-8);
    CHECK_NEAR(m.lambda, 100000, 1e-8);
    double E, nu;
    sq_material_E_nu(&m, &E, &nu);
    CHECK_NEAR(E, 760000.0 / 7, 1e-8);
    CHECK_NEAR(nu, 5.0 / 14, 1e-14);
}

/* a damped body at rest sleeps (zero updates) and a tool wakes it */
SQ_TEST(sim_body_sleeps_and_wakes)
{
    sq_mesh *m = th_box(2, 2, 2, 1, 1, 1);
    TH_REQUIRE(m);
    sq_body_def def = cube_def(m);
    def.material.rayleigh_mass = 20; /* heavily damped so it settles in a few hundred frames */
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    sq_frame_profile prof;
    int slept = -1;
    for (int f = 0; f < 3000 && slept < 0; f++) {
        sq_body_frame(b, NULL, 0, NULL, &prof, 0);
        if (sq_body_is_sleeping(b))
            slept = f;
    }
    CHECK(slept > 0);
    /* the sleep warning: its sentence, counted once, at the frame it fell asleep */
    CHECK(prof.event_kind == SQ_HEALTH_SLEEP);
    CHECK(strcmp(prof.event, "body 'cube' at rest: sleeping until touched") == 0);
    CHECK(sq_body_health(b)[SQ_HEALTH_SLEEP].count == 1);
    CHECK(sq_body_health(b)[SQ_HEALTH_SLEEP].last_frame == slept + 1 && sq_body_frames(b) == slept + 1);
    CHECK(sq_body_health(b)[SQ_HEALTH_WAKE].count == 0);
    sq_body_frame(b, NULL, 0, NULL, &prof, 0);
    CHECK(prof.sleeping == 1 && prof.node_updates == 0);
    CHECK(sq_body_residual(b) < 1e-4);
    sq_tool t = th_tool(SQ_TOOL_SPHERE);
    t.active = 1;
    t.radius = 0.3;
    t.pos[0] = t.pos[1] = 0.5;
    t.pos[2] = 1.2; /* dips 0.1 m into the top face */
    sq_tool_feedback fb;
    sq_body_frame(b, &t, 1, &fb, &prof, 0);
    CHECK(prof.sleeping == 0 && prof.node_updates > 0);
    CHECK(fb.nnodes >= 1);
    CHECK(fb.force[2] > 0); /* the body pushes back up on the tool */
    CHECK(sq_body_health(b)[SQ_HEALTH_WAKE].count == 1 && sq_body_health(b)[SQ_HEALTH_WAKE].last_frame == slept + 3);
    CHECK(prof.event_kind == SQ_HEALTH_NONE && prof.event[0] == 0); /* a wake has no sentence */
    sq_body_destroy(b);
    sq_mesh_free(m);
}

/* same input, same bits: two bodies driven identically (with a moving grab) end bit-identical */
SQ_TEST(sim_body_deterministic)
{
    sq_mesh *m = th_box(3, 3, 3, 1, 1, 1);
    TH_REQUIRE(m);
    sq_body_def def = cube_def(m);
    sq_err e = {{0}};
    sq_body *b[2] = {sq_body_create(&def, &e), sq_body_create(&def, &e)};
    CHECK(b[0] && b[1]);
    if (!b[0] || !b[1])
        return;
    uint64_t h[2];
    for (int k = 0; k < 2; k++) {
        sq_tool t = th_tool(SQ_TOOL_GRAB);
        t.radius = 0.2;
        t.pos[0] = t.pos[1] = 1;
        t.pos[2] = 1;
        for (int f = 0; f < 40; f++) {
            t.active = f >= 5 && f < 25;
            t.pos[0] = 1 + 0.004 * f;
            sq_body_frame(b[k], &t, 1, NULL, NULL, 0);
        }
        const sq_level *L = sq_body_level(b[k], 0);
        h[k] = sq_hash_bytes(SQ_HASH_INIT, L->state.d, sizeof(double) * 3 * L->model.n);
        h[k] = sq_hash_bytes(h[k], L->state.v, sizeof(double) * 3 * L->model.n);
    }
    CHECK(h[0] == h[1]);
    CHECK(sq_body_kinetic_energy(b[0]) > 0);
    sq_body_destroy(b[0]);
    sq_body_destroy(b[1]);
    sq_mesh_free(m);
}
