/* test_physics_corot.c - corotational elasticity (level/corot.c, docs/physics.md section 9):
 * rotation invariance, agreement with linear at small strain, the arc-drag beam of issue 11
 * against the Neo-Hookean reference in tests/ref/, and its wiring (refusals, reset, energy). */
#include "sq_test.h"
#include "test_sim_helpers.h"

/* d = Q x - x for the rotation by angle th about axis (unit) through point c */
static void rotate_disp(const sq_mesh *m, const double axis[3], double th, const double c[3], double *d)
{
    double ct = cos(th), st = sin(th);
    for (int i = 0; i < m->nnodes; i++) {
        const double *x = m->x + 3 * i;
        double p[3] = {x[0] - c[0], x[1] - c[1], x[2] - c[2]};
        double kd = axis[0] * p[0] + axis[1] * p[1] + axis[2] * p[2];
        double kx[3] = {axis[1] * p[2] - axis[2] * p[1], axis[2] * p[0] - axis[0] * p[2],
                        axis[0] * p[1] - axis[1] * p[0]};
        for (int k = 0; k < 3; k++) {
            double r = p[k] * ct + kx[k] * st + axis[k] * kd * (1 - ct);
            d[3 * i + k] = r - p[k];
        }
    }
}

static double max_force(const sq_level *L)
{
    double s = 0;
    for (int i = 0; i < L->model.n; i++)
        s = th_max(s, th_norm3(L->state.f + 3 * i));
    return s;
}

/* a rigid 90 degree rotation of a free body: zero elastic force under corotational (to
 * round-off: 1e-9 of the force the linear operator gives for the same displacement, which is
 * of order E h^2), from rotations that start at identity (converged inside sq_level_forces) */
SQ_TEST(corot_rigid_rotation_gives_zero_force)
{
    sq_mesh *m = th_box(3, 4, 5, 0.3, 0.4, 0.5);
    TH_REQUIRE(m);
    sq_material mat = th_material(40000, 100000, 1000);
    sq_level L;
    sq_err e = {{0}};
    CHECK(sq_level_init(&L, m, &mat, SQ_OPERATOR_FEM, NULL, 0, &e) == 0);
    double *d = malloc(sizeof(double) * 3 * m->nnodes);
    const double axes[3][3] = {{0, 0, 1}, {1, 0, 0}, {0.48, 0.6, 0.64}};
    const double c[3] = {0.1, -0.2, 0.3};
    for (int a = 0; a < 3; a++) {
        rotate_disp(m, axes[a], M_PI / 2, c, d);
        th_elastic_force(&L, &mat, d);
        double lin = max_force(&L);
        CHECK(sq_level_corot_enable(&L, &mat, SQ_OPERATOR_FEM, &e) == 0);
        th_elastic_force(&L, &mat, d);
        double cor = max_force(&L);
        /* also through the stepping path: rotations converge over steps from identity */
        sq_level_corot_reset(&L.state);
        sq_material m0 = mat;
        double zero[3] = {0, 0, 0};
        for (int s = 0; s < 40; s++) {
            memcpy(L.state.d, d, sizeof(double) * 3 * m->nnodes);
            memset(L.state.v, 0, sizeof(double) * 3 * m->nnodes);
            sq_level_corot_step(&L.model, &L.state, &m0, zero, 0, NULL);
        }
        double cor_step = max_force(&L);
        double energy = sq_level_corot_energy(&L.model, &L.state);
        fprintf(stderr, "    axis %d: max |f| linear %.4g N, corotational %.3g N (step path %.3g N), energy %.3g J\n",
                a, lin, cor, cor_step, energy);
        CHECK(lin > 1);
        CHECK(cor <= 1e-9 * lin);
        CHECK(cor_step <= 1e-9 * lin);
        CHECK(energy <= 1e-20 * lin);
        sq_level_corot_free(&L);
    }
    free(d);
    sq_level_free(&L);
    sq_mesh_free(m);
}

/* small strain: corotational equals linear up to second order in the displacement. With
 * d = s u (u a fixed smooth field, rotation included), |f_cor - f_lin| / |f_lin| = O(s): it
 * halves when s halves (ratio 0.5 +- 0.05 between s = 1e-3 and 5e-4) and is below 1e-2 at 1e-3 */
SQ_TEST(corot_small_strain_agrees_with_linear_to_second_order)
{
    sq_mesh *m = th_box(4, 3, 3, 0.4, 0.3, 0.3);
    TH_REQUIRE(m);
    sq_material mat = th_material(40000, 100000, 1000);
    sq_level L, C;
    sq_err e = {{0}};
    CHECK(sq_level_init(&L, m, &mat, SQ_OPERATOR_FEM, NULL, 0, &e) == 0);
    CHECK(sq_level_init(&C, m, &mat, SQ_OPERATOR_FEM, NULL, 0, &e) == 0);
    CHECK(sq_level_corot_enable(&C, &mat, SQ_OPERATOR_FEM, &e) == 0);
    double *d = malloc(sizeof(double) * 3 * m->nnodes), *fl = malloc(sizeof(double) * 3 * m->nnodes);
    double rel[2];
    for (int k = 0; k < 2; k++) {
        double s = k ? 5e-4 : 1e-3;
        for (int i = 0; i < m->nnodes; i++) {
            const double *x = m->x + 3 * i;
            /* bending + twist + stretch, all O(1) strains times s */
            d[3 * i] = s * (0.3 * x[0] * x[2] + 0.2 * x[1]);
            d[3 * i + 1] = s * (0.5 * x[0] * x[2] - 0.1 * x[1] * x[1]);
            d[3 * i + 2] = s * (-0.15 * x[0] * x[0] + 0.4 * x[0] * x[1]);
        }
        th_elastic_force(&L, &mat, d);
        memcpy(fl, L.state.f, sizeof(double) * 3 * m->nnodes);
        th_elastic_force(&C, &mat, d);
        double num = 0, den = 0;
        for (int i = 0; i < 3 * m->nnodes; i++) {
            num += (C.state.f[i] - fl[i]) * (C.state.f[i] - fl[i]);
            den += fl[i] * fl[i];
        }
        rel[k] = sqrt(num / den);
    }
    fprintf(stderr, "    |f_cor - f_lin| / |f_lin|: %.3g at s = 1e-3, %.3g at 5e-4 (ratio %.3f)\n", rel[0], rel[1],
            rel[1] / rel[0]);
    CHECK(rel[0] < 1e-2);
    CHECK_NEAR(rel[1] / rel[0], 0.5, 0.05);
    free(d);
    free(fl);
    sq_level_free(&L);
    sq_level_free(&C);
    sq_mesh_free(m);
}

/* ---- the arc-drag beam (issue 11): 0.2 x 0.02 x 0.02 m, box 20 x 2 x 2, clamped at x = 0,
 * E 2 MPa, nu 0.45, rho 1000, gravity; the tip face (9 nodes) grabbed and dragged along an arc
 * about the clamp's centre line, or pulled up 100 mm; settled; against the Neo-Hookean static
 * solve of the same mesh and held nodes (tests/ref/arc_drag_reference.py -> arc_drag.csv). */

typedef struct {
    double volume;      /* current / rest volume */
    double force[3];    /* tool feedback (force of the body on the tool), N */
    int inverted;
    int nheld;
    double vrms;        /* rms speed at the end, m/s */
    int resets;         /* blow-up resets seen */
} arc_result;

/* the arc runs' variants: drag frames, integrator, and (explicit, sharp bound) a step made
 * `arc_shrink` times too large for the operator, standing in for a bound it outgrows */
static int arc_frames = 50;
static sq_integrator_kind arc_integrator = SQ_INTEGRATOR_EXPLICIT;
static int arc_shrink = 1;
static long arc_refined; /* step_refined warnings of the last run */

static sq_body *arc_body(sq_mesh **mp, sq_elasticity_kind el)
{
    sq_mesh *m = th_box(20, 2, 2, 0.2, 0.02, 0.02);
    *mp = m;
    if (!m)
        return NULL;
    sq_body_def def = th_body_def(m);
    CHECK(sq_material_from_E_nu(&def.material, 2e6, 0.45, NULL) == 0);
    def.material.density = 1000;
    def.material.rayleigh_mass = 30;
    def.material.rayleigh_stiffness = 0;
    def.gravity[2] = -9.81;
    def.nconstraints = 1;
    def.constraints[0] = (sq_constraint){SQ_REGION_BOX, {-1, -1, -1}, {1e-6, 1, 1}, 7};
    def.elasticity = el;
    def.integrator = arc_integrator;
    def.sharp_step = arc_shrink > 1;
    sq_err e = {{0}};
    sq_body *b = sq_body_create(&def, &e);
    if (!b) {
        fprintf(stderr, "%s\n", e.msg);
        return NULL;
    }
    sq_body_set_sleep(b, 0, 0, 0);
    if (arc_shrink > 1) {
        sq_level *L = sq_body_level(b, 0);
        L->nsub = SQ_MAX(1, L->nsub / arc_shrink);
        L->dt_fixed = def.frame_dt / L->nsub;
    }
    return b;
}

static double body_volume(const sq_body *b)
{
    const sq_mesh *m = sq_body_mesh(b, 0);
    const double *d = sq_body_displacement(b, 0);
    double v = 0, v0 = 0;
    for (int t = 0; t < m->ntets; t++) {
        double p[4][3];
        for (int k = 0; k < 4; k++)
            for (int c = 0; c < 3; c++) {
                int i = m->tets[4 * t + k];
                p[k][c] = m->x[3 * i + c] + d[3 * i + c];
            }
        double a[3], bb[3], cc[3], r[3], s[3], u[3];
        for (int c = 0; c < 3; c++) {
            a[c] = p[1][c] - p[0][c], bb[c] = p[2][c] - p[0][c], cc[c] = p[3][c] - p[0][c];
            r[c] = m->x[3 * m->tets[4 * t + 1] + c] - m->x[3 * m->tets[4 * t] + c];
            s[c] = m->x[3 * m->tets[4 * t + 2] + c] - m->x[3 * m->tets[4 * t] + c];
            u[c] = m->x[3 * m->tets[4 * t + 3] + c] - m->x[3 * m->tets[4 * t] + c];
        }
        v += (a[0] * (bb[1] * cc[2] - bb[2] * cc[1]) - a[1] * (bb[0] * cc[2] - bb[2] * cc[0]) +
              a[2] * (bb[0] * cc[1] - bb[1] * cc[0])) / 6;
        v0 += (r[0] * (s[1] * u[2] - s[2] * u[1]) - r[1] * (s[0] * u[2] - s[2] * u[0]) +
               r[2] * (s[0] * u[1] - s[1] * u[0])) / 6;
    }
    return v / v0;
}

/* tip displacement of case k: arc to 15/45/90 degrees, or (k = 3) 100 mm up */
static void arc_delta(int k, double frac, double out[3])
{
    static const double deg[3] = {15, 45, 90};
    if (k == 3) {
        out[0] = out[1] = 0;
        out[2] = 0.1 * frac;
        return;
    }
    double th = frac * deg[k] * M_PI / 180;
    out[0] = 0.2 * (cos(th) - 1);
    out[1] = 0;
    out[2] = 0.2 * sin(th);
}

/* drag over 1 s (50 frames), then hold for `hold` frames; the grab captures the tip face */
static arc_result arc_run(int k, sq_elasticity_kind el, int hold)
{
    arc_result r;
    memset(&r, 0, sizeof r);
    sq_mesh *m;
    sq_body *b = arc_body(&m, el);
    if (!b) {
        sq_mesh_free(m);
        r.volume = NAN;
        return r;
    }
    sq_tool t;
    memset(&t, 0, sizeof t);
    t.id = 1;
    t.shape = SQ_TOOL_GRAB;
    t.active = 1;
    t.radius = 0.0152;
    t.origin[0] = 0.205, t.origin[1] = 0.01, t.origin[2] = 0.01;
    t.has_origin = 1;
    sq_tool_feedback fb;
    memset(&fb, 0, sizeof fb);
    for (int f = 0; f < arc_frames + hold; f++) {
        double dl[3];
        arc_delta(k, f < arc_frames ? (f + 1.0) / arc_frames : 1.0, dl);
        for (int c = 0; c < 3; c++)
            t.pos[c] = t.origin[c] + dl[c];
        sq_frame_profile pf;
        sq_body_frame(b, &t, 1, &fb, &pf, 0);
        r.resets += pf.reset;
    }
    r.volume = body_volume(b);
    arc_refined = sq_body_health(b)[SQ_HEALTH_STEP_REFINED].count;
    memcpy(r.force, fb.force, sizeof r.force);
    r.nheld = fb.nnodes;
    r.inverted = sq_body_inverted_tets(b);
    double M = 0;
    const sq_level *L = sq_body_level(b, 0);
    for (int i = 0; i < L->model.n; i++)
        M += L->model.mass[i];
    r.vrms = sqrt(2 * sq_body_kinetic_energy(b) / M);
    sq_body_destroy(b);
    sq_mesh_free(m);
    return r;
}

/* reference rows: case, volume, fx, fy, fz (tests/ref/arc_drag.csv) */
static int read_reference(double ref[4][4])
{
    char path[512];
    snprintf(path, sizeof path, "%s/../ref/arc_drag.csv", sq_test_data());
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "    cannot read %s\n", path);
        return -1;
    }
    char line[512];
    int n = 0;
    while (fgets(line, sizeof line, f) && n < 4) {
        if (line[0] == '#' || !strncmp(line, "case", 4))
            continue;
        char name[64];
        double v, fx, fy, fz;
        if (sscanf(line, "%63[^,],%lf,%lf,%lf,%lf", name, &v, &fx, &fy, &fz) == 5) {
            ref[n][0] = v, ref[n][1] = fx, ref[n][2] = fy, ref[n][3] = fz;
            n++;
        }
    }
    fclose(f);
    return n == 4 ? 0 : -1;
}

/* the aims: volume within 2 % of rest at 45 degrees and 5 % at 90, at most a handful
 * (5) of inverted tets, tool force within 25 % (vector difference / reference magnitude) of
 * the Neo-Hookean reference; the run is settled (rms speed < 1e-4 m/s). */
SQ_TEST(corot_arc_drag_beam_against_neo_hookean)
{
    double ref[4][4];
    CHECK(read_reference(ref) == 0);
    static const char *const names[4] = {"15 deg", "45 deg", "90 deg", "pull up 100 mm"};
    for (int k = 0; k < 4; k++) {
        arc_result r = arc_run(k, SQ_ELASTICITY_COROTATIONAL, 100);
        double fr = th_norm3(ref[k] + 1), df[3] = {r.force[0] - ref[k][1], r.force[1] - ref[k][2],
                                                    r.force[2] - ref[k][3]};
        double ferr = th_norm3(df) / fr;
        fprintf(stderr, "    %-15s volume %.4f (ref %.4f), |F| %.3f N (ref %.3f N, vector error %.1f %%), "
                        "inverted %d, held %d, vrms %.2g m/s\n",
                names[k], r.volume, ref[k][0], th_norm3(r.force), fr, 100 * ferr, r.inverted, r.nheld, r.vrms);
        CHECK(r.nheld == 9);
        CHECK(r.resets == 0);
        CHECK(r.vrms < 1e-4);
        CHECK(r.inverted <= 5);
        CHECK(ferr <= 0.25);
        if (k == 1)
            CHECK(fabs(r.volume - 1) <= 0.02);
        if (k == 2)
            CHECK(fabs(r.volume - 1) <= 0.05);
    }
}

/* issue 23: the corotational beam dragged through 90 degrees in 0.5 s (25 frames), then held
 * 50 frames: no reset, explicit (at its bound) and implicit (one step per frame, one Newton
 * iteration and the energy guard) alike, and both end within the same 25 % of the Neo-Hookean
 * reference force as the 1 s drag */
SQ_TEST(corot_arc_drag_90_degrees_in_half_a_second)
{
    double ref[4][4];
    CHECK(read_reference(ref) == 0);
    arc_frames = 25;
    for (int in = 0; in < 2; in++) {
        arc_integrator = in ? SQ_INTEGRATOR_IMPLICIT : SQ_INTEGRATOR_EXPLICIT;
        arc_result r = arc_run(2, SQ_ELASTICITY_COROTATIONAL, 50);
        double fr = th_norm3(ref[2] + 1), df[3] = {r.force[0] - ref[2][1], r.force[1] - ref[2][2],
                                                    r.force[2] - ref[2][3]};
        fprintf(stderr, "    %s: resets %d, volume %.4f, |F| %.3f N (ref %.3f N, vector error %.1f %%)\n",
                in ? "implicit" : "explicit", r.resets, r.volume, th_norm3(r.force), fr, 100 * th_norm3(df) / fr);
        CHECK(r.resets == 0);
        CHECK(r.nheld == 9);
        CHECK(th_norm3(df) / fr <= 0.25);
    }
    arc_frames = 50;
    arc_integrator = SQ_INTEGRATOR_EXPLICIT;
}

/* the per-frame check: an explicit step 4x over what the operator takes (as when a bound is
 * outgrown) diverges in its first frame; the frame is re-run from its start with 2x, then 4x
 * the substeps before anything is seen, so the drag ends with no reset and the same force as a
 * run at the right step (within the 25 % of the reference test) */
SQ_TEST(explicit_step_outgrown_is_refined_not_reset)
{
    double ref[4][4];
    CHECK(read_reference(ref) == 0);
    arc_frames = 25;
    arc_shrink = 4;
    arc_result r = arc_run(2, SQ_ELASTICITY_COROTATIONAL, 10);
    arc_shrink = 1;
    arc_frames = 50;
    double fr = th_norm3(ref[2] + 1), df[3] = {r.force[0] - ref[2][1], r.force[1] - ref[2][2], r.force[2] - ref[2][3]};
    fprintf(stderr, "    step 4x too large: resets %d, refined frames %ld, |F| %.3f N (vector error %.1f %%)\n",
            r.resets, arc_refined, th_norm3(r.force), 100 * th_norm3(df) / fr);
    CHECK(r.resets == 0);
    CHECK(arc_refined >= 1);
    CHECK(th_norm3(df) / fr <= 0.25);
}

/* ---- wiring: scene key, refusals, set, reset ------------------------------------------- */

#include "scene/scene.h"
#include "test_scene_helpers.h"

/* the shipped sphere-grab scene (corotational) with one substring replaced */
static sq_scene *sphere_grab_with(const char *from, const char *to, sq_err *e)
{
    static char text[65536], out[66000];
    if (th_shipped_scene_text("sphere-grab", text, sizeof text))
        return NULL;
    char *at = from ? strstr(text, from) : NULL;
    if (from && !at)
        return NULL;
    if (at)
        snprintf(out, sizeof out, "%.*s%s%s", (int)(at - text), text, to, at + strlen(from));
    else
        snprintf(out, sizeof out, "%s", text);
    return sq_scene_parse(out, th_scenes_dir(), "sphere-grab", e);
}

SQ_TEST(corot_scene_key_and_refusals)
{
    sq_err e = {{0}};
    sq_scene *sc = sphere_grab_with(NULL, NULL, &e);
    TH_REQUIRE(sc);
    CHECK(sc->bodies[0].elasticity == SQ_ELASTICITY_COROTATIONAL);
    sq_scene_free(sc);
    /* adaptive + corotational: accepted (lod/corotational.c; refused before issue 11's
     * adaptive work, tests/unit/test_lod_corot.c checks it) */
    sc = sphere_grab_with("\"mode\": \"fixed\", \"level\": 1", "\"mode\": \"adaptive\"", &e);
    TH_REQUIRE(sc);
    CHECK(sc->bodies[0].elasticity == SQ_ELASTICITY_COROTATIONAL);
    CHECK(sc->bodies[0].lod.mode == SQ_LOD_ADAPTIVE);
    sq_scene_free(sc);
    /* paper + corotational */
    memset(&e, 0, sizeof e);
    sc = sphere_grab_with("\"operator\": \"fem\"", "\"operator\": \"paper\"", &e);
    CHECK(sc == NULL);
    CHECK_CONTAINS(e.msg, "needs \"operator\": \"fem\"");
    /* an unknown value */
    memset(&e, 0, sizeof e);
    sc = sphere_grab_with("\"corotational\"", "\"rotated\"", &e);
    CHECK(sc == NULL);
    CHECK_CONTAINS(e.msg, "\"rotated\" is not an elasticity");
    memset(&e, 0, sizeof e);
    sc = sphere_grab_with("\"corotational\"", "3", &e);
    CHECK(sc == NULL);
    CHECK_CONTAINS(e.msg, "expected \"linear\" or \"corotational\"");
    /* pressure: nodal with corotational refused at load; with linear accepted; a bad value */
    memset(&e, 0, sizeof e);
    sc = sphere_grab_with("\"elasticity\": \"corotational\",", "\"elasticity\": \"corotational\", \"pressure\": \"nodal\",", &e);
    CHECK(sc == NULL);
    CHECK_CONTAINS(e.msg, "bodies[0].pressure");
    sc = sphere_grab_with("\"elasticity\": \"corotational\",", "\"pressure\": \"nodal\",", &e);
    TH_REQUIRE(sc);
    CHECK(sc->bodies[0].nodal_pressure == 1);
    sq_scene_free(sc);
    memset(&e, 0, sizeof e);
    sc = sphere_grab_with("\"elasticity\": \"corotational\",", "\"pressure\": \"node\",", &e);
    CHECK(sc == NULL);
    CHECK_CONTAINS(e.msg, "expected \"element\"");
    /* default: linear */
    sc = sphere_grab_with("\"elasticity\": \"corotational\",", "", &e);
    TH_REQUIRE(sc);
    CHECK(sc->bodies[0].elasticity == SQ_ELASTICITY_LINEAR);
    sq_scene_free(sc);
}

/* the body API: switching at run time keeps the state; refusals change nothing; a reset puts
 * the rotations back to identity; the paper operator is refused while corotational, adaptive
 * lod is accepted; energy and feedback are the corotational ones */
SQ_TEST(corot_body_switch_refusals_and_reset)
{
    sq_mesh *m = th_box(6, 2, 2, 0.3, 0.1, 0.1);
    sq_mesh *m2 = th_box(3, 1, 1, 0.3, 0.1, 0.1);
    TH_REQUIRE(m);
    TH_REQUIRE(m2);
    sq_body_def def = sq_body_def_default();
    def.nlevels = 2;
    def.levels[0] = m2;
    def.levels[1] = m;
    def.lod.level = 1;
    def.gravity[2] = -9.81;
    def.nconstraints = 1;
    def.constraints[0] = (sq_constraint){SQ_REGION_BOX, {-1, -1, -1}, {1e-6, 1, 1}, 7};
    def.elasticity = SQ_ELASTICITY_COROTATIONAL;
    def.lod.mode = SQ_LOD_ADAPTIVE;
    sq_err e = {{0}};
    sq_body *ba = sq_body_create(&def, &e); /* adaptive + corotational: accepted */
    CHECK(ba != NULL);
    CHECK(ba && sq_body_level(ba, 1)->state.corot != NULL);
    sq_body_destroy(ba);
    def.lod.mode = SQ_LOD_FIXED;
    def.op = SQ_OPERATOR_PAPER;
    CHECK(sq_body_create(&def, &e) == NULL);
    CHECK_CONTAINS(e.msg, "needs the fem operator");
    def.op = SQ_OPERATOR_FEM;
    sq_body *b = sq_body_create(&def, &e);
    TH_REQUIRE(b);
    for (int f = 0; f < 20; f++)
        sq_body_frame(b, NULL, 0, NULL, NULL, 0);
    const sq_level *L = sq_body_level(b, 1);
    double tip = L->state.d[3 * (L->model.n - 1) + 2];
    CHECK(tip < 0);
    /* refusals leave everything as it was */
    sq_material mat = def.material;
    CHECK(sq_body_set_material(b, &mat, SQ_OPERATOR_PAPER, &e) < 0);
    CHECK_CONTAINS(e.msg, "needs the fem operator");
    sq_lod_def lod = def.lod;
    lod.mode = SQ_LOD_ADAPTIVE;
    CHECK(sq_body_get_def(b)->elasticity == SQ_ELASTICITY_COROTATIONAL);
    CHECK(sq_body_get_def(b)->lod.mode == SQ_LOD_FIXED);
    CHECK(L->state.corot != NULL);
    CHECK(L->state.d[3 * (L->model.n - 1) + 2] == tip);
    /* a material change keeps the rotations and the corotational model */
    mat.mu *= 1.1;
    CHECK(sq_body_set_material(b, &mat, SQ_OPERATOR_FEM, &e) == 0);
    L = sq_body_level(b, 1);
    CHECK(L->state.corot != NULL);
    /* energy: corotational (the linear one of the same state differs) */
    double ec = sq_body_elastic_energy(b);
    CHECK(ec > 0);
    CHECK(sq_body_set_elasticity(b, SQ_ELASTICITY_LINEAR, &e) == 0);
    CHECK(sq_body_level(b, 1)->state.corot == NULL);
    double el = sq_body_elastic_energy(b);
    fprintf(stderr, "    energy corotational %.6g J, linear %.6g J of the same state\n", ec, el);
    CHECK(fabs(ec - el) < 0.05 * el); /* small sag: the models agree closely */
    CHECK(ec != el);
    /* linear + adaptive, then corotational switched on in adaptive mode (accepted) and off */
    CHECK(sq_body_set_lod(b, &lod, &e) == 0);
    CHECK(sq_body_set_elasticity(b, SQ_ELASTICITY_COROTATIONAL, &e) == 0);
    CHECK(sq_body_level(b, 1)->state.corot != NULL);
    for (int f = 0; f < 3; f++)
        sq_body_frame(b, NULL, 0, NULL, NULL, 0);
    CHECK(sq_body_set_elasticity(b, SQ_ELASTICITY_LINEAR, &e) == 0);
    lod.mode = SQ_LOD_FIXED;
    lod.level = 0;
    CHECK(sq_body_set_lod(b, &lod, &e) == 0);
    CHECK(sq_body_set_elasticity(b, SQ_ELASTICITY_COROTATIONAL, &e) == 0);
    for (int f = 0; f < 5; f++)
        sq_body_frame(b, NULL, 0, NULL, NULL, 0);
    L = sq_body_level(b, 0);
    CHECK(L->state.corot != NULL);
    sq_body_reset(b);
    CHECK(sq_level_corot_energy(&L->model, &L->state) == 0);
    CHECK(L->state.d[3 * (L->model.n - 1) + 2] == 0);
    /* blow-up: a NaN (which poisons the rotations of its tets) is detected, the body and its
     * rotations are reset, and the next frames are finite and sag as before */
    for (int f = 0; f < 5; f++)
        sq_body_frame(b, NULL, 0, NULL, NULL, 0);
    double sag5 = L->state.d[3 * (L->model.n - 1) + 2];
    sq_body_level(b, 0)->state.d[3 * (L->model.n - 1)] = NAN;
    sq_frame_profile prof;
    sq_body_frame(b, NULL, 0, NULL, &prof, 0);
    CHECK(prof.reset == 1);
    CHECK_CONTAINS(prof.event, "blow-up detected");
    for (int f = 0; f < 5; f++)
        sq_body_frame(b, NULL, 0, NULL, &prof, 0);
    CHECK(!prof.reset);
    CHECK(L->state.d[3 * (L->model.n - 1) + 2] == sag5); /* bit for bit the run from rest */
    sq_body_destroy(b);
    sq_mesh_free(m);
    sq_mesh_free(m2);
}

/* the vector step (AVX2 builds: 4 tets per lane group, one rotation update) and the scalar
 * force pass (rotations converged) give the same forces on a large, damped deformation once
 * the stored rotations are converged: relative difference below 1e-10 */
SQ_TEST(corot_vector_step_matches_scalar_forces)
{
    sq_mesh *m = th_box(10, 3, 2, 0.5, 0.15, 0.1);
    TH_REQUIRE(m);
    sq_material mat = th_material(40000, 100000, 1000);
    mat.rayleigh_mass = 0.5;
    mat.rayleigh_stiffness = 1e-3;
    sq_level L;
    sq_err e = {{0}};
    CHECK(sq_level_init(&L, m, &mat, SQ_OPERATOR_FEM, NULL, 0, &e) == 0);
    CHECK(sq_level_corot_enable(&L, &mat, SQ_OPERATOR_FEM, &e) == 0);
    for (int i = 0; i < m->nnodes; i++) {
        const double *x = m->x + 3 * i;
        double th = 1.2 * x[0]; /* bent through ~34 degrees along the length, plus a twist */
        L.state.d[3 * i] = (x[0] * cos(th) - x[2] * sin(th)) - x[0];
        L.state.d[3 * i + 1] = 0.02 * sin(3 * x[0]);
        L.state.d[3 * i + 2] = (x[0] * sin(th) + x[2] * cos(th)) - x[2];
        for (int c = 0; c < 3; c++)
            L.state.v[3 * i + c] = 0.1 * sin(7 * x[0] + c);
    }
    /* rotations of I + grad(d + b v), converged: step with dt = 0 until they stop moving */
    double g[3] = {0, 0, -9.81};
    for (int s = 0; s < 30; s++)
        sq_level_corot_step(&L.model, &L.state, &mat, g, 0, NULL);
    double *fv = malloc(sizeof(double) * 3 * m->nnodes);
    memcpy(fv, L.state.f, sizeof(double) * 3 * m->nnodes);
    sq_level_corot_forces(&L.model, &L.state, &mat, g, L.state.f);
    double num = 0, den = 0;
    for (int i = 0; i < 3 * m->nnodes; i++) {
        num += (fv[i] - L.state.f[i]) * (fv[i] - L.state.f[i]);
        den += L.state.f[i] * L.state.f[i];
    }
    fprintf(stderr, "    step vs scalar forces: relative difference %.3g (|f| %.3g N)\n", sqrt(num / den), sqrt(den));
    CHECK(den > 0);
    CHECK(sqrt(num / den) < 1e-10);
    free(fv);
    sq_level_free(&L);
    sq_mesh_free(m);
}

/* the same arc drag with linear elasticity (the "today" column, printed for
 * docs/physics.md): the body swells by more than 10 % at 45 and 90 degrees and the tool force
 * at 45 degrees is more than 3 times the reference; the pull-up force is less than half of it */
SQ_TEST(corot_arc_drag_beam_linear_is_far_off)
{
    double ref[4][4];
    CHECK(read_reference(ref) == 0);
    static const char *const names[4] = {"15 deg", "45 deg", "90 deg", "pull up 100 mm"};
    arc_result r[4];
    for (int k = 0; k < 4; k++) {
        r[k] = arc_run(k, SQ_ELASTICITY_LINEAR, 100);
        fprintf(stderr, "    linear %-15s volume %.4f (ref %.4f), |F| %.3f N (ref %.3f N), inverted %d, resets %d\n",
                names[k], r[k].volume, ref[k][0], th_norm3(r[k].force), th_norm3(ref[k] + 1), r[k].inverted,
                r[k].resets);
    }
    CHECK(r[1].volume > 1.10);
    CHECK(r[2].volume > 1.10);
    CHECK(th_norm3(r[1].force) > 3 * th_norm3(ref[1] + 1));
    CHECK(th_norm3(r[3].force) < 0.5 * th_norm3(ref[3] + 1));
}

/* rest while a grab holds the body: sq_body_residual (the --until-rest and sleep measure)
 * leaves out the nodes a tool held in the last frame, whose unbalanced force is the tool's
 * reaction; the free nodes settle below 1e-6 of their weight, while a held node's force is of
 * the order of the whole pull (before: the residual stayed at ~15 with the beam at rest) */
SQ_TEST(body_rest_ignores_held_nodes)
{
    for (int el = 0; el < 2; el++) {
        sq_mesh *m;
        sq_body *b = arc_body(&m, el ? SQ_ELASTICITY_COROTATIONAL : SQ_ELASTICITY_LINEAR);
        TH_REQUIRE(b);
        sq_tool t;
        memset(&t, 0, sizeof t);
        t.id = 1;
        t.shape = SQ_TOOL_GRAB;
        t.active = 1;
        t.radius = 0.0152;
        t.origin[0] = 0.205, t.origin[1] = 0.01, t.origin[2] = 0.01;
        t.has_origin = 1;
        memcpy(t.pos, t.origin, sizeof t.pos);
        t.pos[2] += 0.02;
        sq_tool_feedback fb;
        for (int f = 0; f < 150; f++)
            sq_body_frame(b, &t, 1, &fb, NULL, 0);
        double res = sq_body_residual(b);
        fprintf(stderr, "    %s: residual of the free nodes %.3g (tool force %.3g N on %d nodes)\n",
                el ? "corotational" : "linear", res, th_norm3(fb.force), fb.nnodes);
        CHECK(fb.nnodes == 9);
        CHECK(th_norm3(fb.force) > 0.1);
        CHECK(res < 1e-6);
        /* released: the same measure sees the beam swing back */
        sq_body_frame(b, NULL, 0, NULL, NULL, 0);
        CHECK(sq_body_residual(b) > 1);
        sq_body_destroy(b);
        sq_mesh_free(m);
    }
}
