/* test_contact.c - obstacles, the bounding-volume hierarchy, triangle-mesh files and contact of
 * free bodies with the floor, a slope and each other (docs/physics.md section 13). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "contact/contact_internal.h"
#include "scene/scene.h"
#include "sq_test.h"
#include "test_scene_helpers.h"

/* ---- shapes: exact distances (round-off tolerance 1e-12 m) ------------------------------ */

SQ_TEST(contact_shape_distances)
{
    sq_obstacle o = {.name = "s"};
    double n[3];
    o.kind = SQ_OBSTACLE_PLANE;
    o.normal[2] = 1;
    CHECK_NEAR(sq_obstacle_distance(&o, (double[]){3, -2, -0.25}, n), -0.25, 1e-12);
    CHECK_NEAR(n[2], 1, 1e-12);
    o.kind = SQ_OBSTACLE_SPHERE;
    o.radius = 0.5;
    CHECK_NEAR(sq_obstacle_distance(&o, (double[]){0, 2, 0}, n), 1.5, 1e-12);
    CHECK_NEAR(n[1], 1, 1e-12);
    o.kind = SQ_OBSTACLE_BOX;
    o.half[0] = 1, o.half[1] = 2, o.half[2] = 3;
    CHECK_NEAR(sq_obstacle_distance(&o, (double[]){0.9, 0, 0}, n), -0.1, 1e-12); /* nearest face +x */
    CHECK_NEAR(n[0], 1, 1e-12);
    CHECK_NEAR(sq_obstacle_distance(&o, (double[]){4, 6, 3}, n), 5, 1e-12); /* edge: (3, 4, 0) away */
    CHECK_NEAR(n[0], 0.6, 1e-12);
    o.kind = SQ_OBSTACLE_CAPSULE;
    o.radius = 0.1;
    o.end[0] = 1;
    CHECK_NEAR(sq_obstacle_distance(&o, (double[]){0.5, 0, 0.3}, n), 0.2, 1e-12);
    CHECK_NEAR(sq_obstacle_distance(&o, (double[]){2, 0, 0}, n), 0.9, 1e-12); /* past end b */
    CHECK_NEAR(n[0], 1, 1e-12);
}

/* a unit square floor z = 0 as two triangles (normal +z) */
static sq_trimesh *square(void)
{
    double x[] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
    int t[] = {0, 1, 2, 0, 2, 3};
    sq_err e = {{0}};
    return sq_trimesh_from_arrays(4, x, 2, t, "square", &e);
}

SQ_TEST(contact_mesh_obstacle_sign_and_thickness)
{
    sq_trimesh *m = square();
    CHECK(m && m->ntris == 2);
    if (!m)
        return;
    sq_obstacle o = {.name = "tray", .kind = SQ_OBSTACLE_MESH, .mesh = m, .thickness = 0.05};
    double n[3];
    CHECK_NEAR(sq_obstacle_distance(&o, (double[]){0.3, 0.6, 0.02}, n), 0.02, 1e-12);
    CHECK_NEAR(sq_obstacle_distance(&o, (double[]){0.3, 0.6, -0.03}, n), -0.03, 1e-12);
    CHECK_NEAR(n[2], 1, 1e-12);
    CHECK(isinf(sq_obstacle_distance(&o, (double[]){0.3, 0.6, -0.2}, n))); /* beyond thickness */
    sq_err e = {{0}};
    CHECK(sq_obstacle_check(&o, &e) == 0);
    sq_trimesh_free(m);
}

/* the hierarchy's nearest triangle is the brute-force one (1e-12 m) on a sphere-like surface */
SQ_TEST(contact_bvh_nearest_matches_brute_force)
{
    sq_err e = {{0}};
    const double size[3] = {1, 1, 1}, origin[3] = {0, 0, 0};
    sq_mesh *box = sq_mesh_box(6, 5, 4, size, origin, &e);
    CHECK(box != NULL);
    if (!box)
        return;
    sq_trimesh *m = sq_trimesh_from_arrays(box->nnodes, box->x, box->ntris, box->tris, "box", &e);
    CHECK(m != NULL);
    srand(7);
    int agree = 0;
    for (int k = 0; k < 300; k++) {
        double p[3], best = INFINITY, d, q[3], bary[3];
        for (int c = 0; c < 3; c++)
            p[c] = -0.3 + 1.6 * rand() / (double)RAND_MAX;
        for (int t = 0; t < m->ntris; t++) {
            const int *v = m->tris + 3 * t;
            double qq[3], bb[3];
            double d2 = sq_closest_on_triangle(p, m->x + 3 * v[0], m->x + 3 * v[1], m->x + 3 * v[2], qq, bb);
            best = fmin(best, sqrt(d2));
        }
        int t = sq_trimesh_nearest(m, p, 10, &d, q, bary);
        agree += t >= 0 && fabs(d - best) <= 1e-12 && fabs(bary[0] + bary[1] + bary[2] - 1) <= 1e-12;
    }
    CHECK(agree == 300);
    sq_trimesh_free(m);
    sq_mesh_free(box);
}

static void write_text(const char *path, const char *text)
{
    FILE *f = fopen(path, "wb");
    if (f) {
        fputs(text, f);
        fclose(f);
    }
}

SQ_TEST(contact_trimesh_files_obj_and_stl)
{
    char dir[380], p[700];
    snprintf(dir, sizeof dir, "%s/trimesh", sq_test_tmpdir());
    th_make_dir(dir);
    sq_err e = {{0}};
    /* an OBJ quad (fanned into 2 triangles), with normals, texture indices and comments */
    snprintf(p, sizeof p, "%s/quad.obj", dir);
    write_text(p, "# quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 1/1/1 2/2/1 3/3/1 4/4/1\n");
    double off[3] = {0, 0, 1};
    sq_trimesh *m = sq_trimesh_load(p, 2, off, &e);
    CHECK(m && m->ntris == 2 && m->nverts == 4);
    if (m) {
        CHECK_NEAR(m->bbox_max[0], 2, 1e-12);
        CHECK_NEAR(m->bbox_min[2], 1, 1e-12);
        CHECK_NEAR(m->normal[2], 1, 1e-12);
    }
    sq_trimesh_free(m);
    /* ASCII STL: one facet */
    snprintf(p, sizeof p, "%s/tri.stl", dir);
    write_text(p, "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\n"
                  "endfacet\nendsolid t\n");
    m = sq_trimesh_load(p, 1, NULL, &e);
    CHECK(m && m->ntris == 1);
    sq_trimesh_free(m);
    /* binary STL: 80-byte header, count, one facet of 50 bytes */
    snprintf(p, sizeof p, "%s/bin.stl", dir);
    FILE *f = fopen(p, "wb");
    if (f) {
        char header[80] = "binary";
        unsigned int n = 1;
        float facet[12] = {0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0};
        unsigned short attr = 0;
        fwrite(header, 1, 80, f);
        fwrite(&n, 4, 1, f);
        fwrite(facet, 4, 12, f);
        fwrite(&attr, 2, 1, f);
        fclose(f);
    }
    m = sq_trimesh_load(p, 1, NULL, &e);
    CHECK(m && m->ntris == 1);
    if (m)
        CHECK_NEAR(m->x[3], 1, 1e-7);
    sq_trimesh_free(m);
    /* broken: a face naming a vertex that does not exist, a missing file, a truncated STL */
    snprintf(p, sizeof p, "%s/bad.obj", dir);
    write_text(p, "v 0 0 0\nv 1 0 0\nf 1 2 9\n");
    CHECK(sq_trimesh_load(p, 1, NULL, &e) == NULL);
    CHECK_CONTAINS(e.msg, "bad.obj");
    CHECK_CONTAINS(e.msg, "bad.obj:3:");
    snprintf(p, sizeof p, "%s/none.obj", dir);
    CHECK(sq_trimesh_load(p, 1, NULL, &e) == NULL);
    CHECK_CONTAINS(e.msg, "none.obj");
    snprintf(p, sizeof p, "%s/short.stl", dir);
    f = fopen(p, "wb");
    if (f) {
        char junk[90] = {0};
        junk[80] = 5; /* 5 facets announced, none there */
        fwrite(junk, 1, 90, f);
        fclose(f);
    }
    CHECK(sq_trimesh_load(p, 1, NULL, &e) == NULL);
    CHECK_CONTAINS(e.msg, "short.stl");
    /* found by fuzzing: zero-area triangles (no side) are dropped, all of them is an error; a
     * coordinate beyond 1e6 m (the cross product overflowed) is refused naming the units */
    snprintf(p, sizeof p, "%s/flat.obj", dir);
    write_text(p, "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n");
    m = sq_trimesh_load(p, 1, NULL, &e);
    CHECK(m && m->ntris == 1);
    if (m)
        CHECK_NEAR(m->normal[2], 1, 1e-12);
    sq_trimesh_free(m);
    write_text(p, "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n");
    CHECK(sq_trimesh_load(p, 1, NULL, &e) == NULL);
    CHECK_CONTAINS(e.msg, "zero area");
    write_text(p, "v 0 0 0\nv 1e300 0 0\nv 0 1e300 0\nf 1 2 3\n");
    CHECK(sq_trimesh_load(p, 1, NULL, &e) == NULL);
    CHECK_CONTAINS(e.msg, "units");
}

SQ_TEST(contact_obstacle_check_names_the_fix)
{
    sq_err e = {{0}};
    sq_obstacle o = {.name = "ball", .kind = SQ_OBSTACLE_SPHERE, .radius = NAN, .mu_s = 0.5, .mu_k = 0.5};
    CHECK(sq_obstacle_check(&o, &e) < 0);
    CHECK_CONTAINS(e.msg, "\"ball\"");
    CHECK_CONTAINS(e.msg, "radius");
    o.radius = 0.1;
    o.mu_s = -0.1;
    CHECK(sq_obstacle_check(&o, &e) < 0);
    CHECK_CONTAINS(e.msg, "friction");
    o.mu_s = 0.3;
    CHECK(sq_obstacle_check(&o, &e) < 0); /* kinetic 0.5 > static 0.3 */
    CHECK_CONTAINS(e.msg, "kinetic");
    o.mu_k = 0.2;
    o.point[1] = NAN;
    CHECK(sq_obstacle_check(&o, &e) < 0);
    CHECK_CONTAINS(e.msg, "finite");
    o.point[1] = 0;
    CHECK(sq_obstacle_check(&o, &e) == 0);
    o.kind = SQ_OBSTACLE_BOX;
    o.half[0] = 1, o.half[1] = 0, o.half[2] = 1;
    CHECK(sq_obstacle_check(&o, &e) < 0);
    CHECK_CONTAINS(e.msg, "size");
}

/* ---- scenes ----------------------------------------------------------------------------- */

/* a scene of the shipped cube mesh (level 1, 142 nodes) scaled to `edge` m; body and rest of
 * the scene as JSON fragments */
static sq_scene *cube_scene_damped(const char *gravity, double rayleigh_mass, const char *body_extra, const char *rest,
                                   sq_err *e)
{
    char text[6000];
    snprintf(text, sizeof text,
             "{\"name\": \"t\", \"gravity\": %s, \"frame_rate\": 50,"
             " \"bodies\": [{\"name\": \"block\", \"levels\": [\"../cube/cube_l1.msh\"], \"scale\": 0.2,"
             "   \"material\": {\"E\": 100000, \"nu\": 0.3, \"density\": 1000,"
             "                  \"damping\": {\"rayleigh_mass\": %g, \"rayleigh_stiffness\": 0.002}},"
             "   \"elasticity\": \"corotational\", \"step_bound\": \"sharp\", \"lod\": {\"mode\": \"fixed\"} %s}]"
             " %s}",
             gravity, rayleigh_mass, body_extra, rest);
    return sq_scene_parse(text, th_scenes_dir(), "t.json", e);
}

static sq_scene *cube_scene(const char *gravity, const char *body_extra, const char *rest, sq_err *e)
{
    return cube_scene_damped(gravity, 2.0, body_extra, rest, e);
}

static double total_mass(sq_body *b)
{
    const sq_level *L = sq_body_level(b, sq_body_sim_level(b));
    double m = 0;
    for (int i = 0; i < L->model.n; i++)
        m += L->model.mass[i];
    return m;
}

/* lowest z of the simulated level's nodes (the floor is z = 0), m */
static double lowest_z(sq_body *b)
{
    const sq_level *L = sq_body_level(b, sq_body_sim_level(b));
    double z = INFINITY;
    for (int i = 0; i < L->model.n; i++)
        z = fmin(z, L->model.mesh->x[3 * i + 2] + L->state.d[3 * i + 2]);
    return z;
}

/* at rest on the floor: the deepest node under 1 % of the block's 0.2 m edge (the bar,
 * 2 mm; the method lands nodes on the plane, so this also holds to 1 % of the smallest element
 * edge, 1 mm x 1 %), and the mean contact force over the last second equal to the weight
 * within 1 % (what is left of the bounce after 3 s of damping is far below that) */
SQ_TEST(contact_rest_on_floor_depth_and_weight)
{
    sq_err e = {{0}};
    sq_scene *sc = cube_scene("[0, 0, -9.81]", ", \"offset\": [0, 0, 0.05]",
                              ", \"obstacles\": [{\"name\": \"floor\", \"type\": \"plane\", \"point\": [0, 0, 0]}]", &e);
    CHECK(sc != NULL);
    if (!sc) {
        printf("    %s\n", e.msg);
        return;
    }
    sq_world *w = sq_world_create(sc, &e);
    CHECK(w != NULL);
    double fz = 0, deepest = 0;
    int n = 0;
    for (int f = 0; f < 200; f++) {
        sq_world_step(w, 0);
        if (f >= 150) {
            double F[3];
            sq_body_contact_force(w->bodies[0], F, NULL, NULL);
            fz += F[2];
            n++;
            deepest = fmax(deepest, -lowest_z(w->bodies[0]));
        }
    }
    double weight = total_mass(w->bodies[0]) * 9.81;
    printf("    mean contact force %.6g N, weight %.6g N, deepest %.3g m\n", fz / n, weight, deepest);
    CHECK_NEAR(fz / n, weight, 0.01 * weight);
    CHECK(deepest < 0.01 * 0.2);
    CHECK(deepest < 1e-5);
    CHECK(w->resets == 0);
    sq_world_destroy(w);
    sq_scene_free(sc);
}

/* mean x of the block's bottom face nodes (rest z below 1 mm), m */
static double bottom_x(sq_body *b)
{
    const sq_level *L = sq_body_level(b, sq_body_sim_level(b));
    double s = 0;
    int n = 0;
    for (int i = 0; i < L->model.n; i++)
        if (L->model.mesh->x[3 * i + 2] < 1e-3) {
            s += L->model.mesh->x[3 * i] + L->state.d[3 * i];
            n++;
        }
    return n ? s / n : NAN;
}

/* a block on a 20-degree slope: the slope is the floor with gravity tilted by 20 degrees
 * (the same physics in the slope's frame). Friction 0.5 > tan 20 = 0.364: the bottom face stays
 * (drift under 1 mm over 2 s once it has landed). Friction 0.2: it slides with
 * a = g (sin 20 - 0.2 cos 20) = 1.5115 m/s^2, fitted over 0.5-1.5 s, within 5 % */
static double slope_run_with(double mu, const char *body_extra, double *drift)
{
    const double th = 20 * M_PI / 180, g = 9.81;
    char grav[80], obs[200];
    snprintf(grav, sizeof grav, "[%.12g, 0, %.12g]", g * sin(th), -g * cos(th));
    snprintf(obs, sizeof obs, ", \"obstacles\": [{\"name\": \"slope\", \"type\": \"plane\", \"point\": [0, 0, 0], "
                              "\"friction\": %g}]", mu);
    sq_err e = {{0}};
    /* stiffness damping only: mass damping would drag the sliding block (it damps rigid motion) */
    sq_scene *sc = cube_scene_damped(grav, 0, body_extra, obs, &e);
    if (!sc) {
        printf("    %s\n", e.msg);
        return NAN;
    }
    sq_world *w = sq_world_create(sc, &e);
    /* x(t) at 50 Hz for 2.5 s */
    double x[126];
    x[0] = bottom_x(w->bodies[0]);
    for (int f = 1; f <= 125; f++) {
        sq_world_step(w, 0);
        x[f] = bottom_x(w->bodies[0]);
    }
    *drift = fabs(x[125] - x[25]);
    if (getenv("SQ_TEST_VERBOSE"))
        for (int f = 0; f <= 125; f += 25)
            printf("    t %.2f s: x %.6g m\n", f / 50.0, x[f]);
    /* least-squares x = c0 + c1 t + c2 t^2 over frames 25..75 */
    double S[5] = {0}, R[3] = {0};
    for (int f = 25; f <= 75; f++) {
        double t = f / 50.0, p = 1;
        for (int k = 0; k < 5; k++, p *= t)
            S[k] += p;
        R[0] += x[f];
        R[1] += x[f] * t;
        R[2] += x[f] * t * t;
    }
    /* solve the 3x3 normal equations [S0 S1 S2; S1 S2 S3; S2 S3 S4] c = R by Cramer */
    double A[3][3] = {{S[0], S[1], S[2]}, {S[1], S[2], S[3]}, {S[2], S[3], S[4]}};
    double det = A[0][0] * (A[1][1] * A[2][2] - A[1][2] * A[2][1]) - A[0][1] * (A[1][0] * A[2][2] - A[1][2] * A[2][0]) +
                 A[0][2] * (A[1][0] * A[2][1] - A[1][1] * A[2][0]);
    double d2 = A[0][0] * (A[1][1] * R[2] - R[1] * A[2][1]) - A[0][1] * (A[1][0] * R[2] - R[1] * A[2][0]) +
                R[0] * (A[1][0] * A[2][1] - A[1][1] * A[2][0]);
    CHECK(w->resets == 0);
    sq_world_destroy(w);
    sq_scene_free(sc);
    return 2 * d2 / det;
}

static double slope_run(double mu, double *drift) { return slope_run_with(mu, "", drift); }

SQ_TEST(contact_slope_sticks_with_friction_0_5)
{
    double drift;
    double a = slope_run(0.5, &drift);
    printf("    friction 0.5: drift %.3g m over 2 s (acceleration fit %.3g m/s^2)\n", drift, a);
    CHECK(drift < 1e-3);
}

SQ_TEST(contact_slope_slides_with_friction_0_2)
{
    const double th = 20 * M_PI / 180, want = 9.81 * (sin(th) - 0.2 * cos(th));
    double drift;
    double a = slope_run(0.2, &drift);
    printf("    friction 0.2: acceleration %.4g m/s^2, expected %.4g\n", a, want);
    CHECK_NEAR(a, want, 0.05 * want);
}

/* undamped drop on the floor (no damping, friction 0.5) for 10 s: the total energy (kinetic +
 * corotational elastic + gravity) never rises above its start by more than 0.5 % of the drop's
 * potential energy M g h (the explicit step's own energy oscillation, measured without contact
 * at about 0.1 %); no reset */
static void undamped_drop(double E, const char *extra)
{
    sq_err e = {{0}};
    char text[4000];
    snprintf(text, sizeof text,
             "{\"name\": \"t\", \"gravity\": [0, 0, -9.81], \"frame_rate\": 50,"
             " \"bodies\": [{\"name\": \"block\", \"levels\": [\"../cube/cube_l1.msh\"], \"scale\": 0.2,"
             "   \"offset\": [0, 0, 0.1],"
             "   \"material\": {\"E\": %g, \"nu\": 0.3, \"density\": 1000},"
             "   \"elasticity\": \"corotational\", \"step_bound\": \"sharp\", \"lod\": {\"mode\": \"fixed\"}%s}],"
             " \"obstacles\": [{\"name\": \"floor\", \"type\": \"plane\", \"point\": [0, 0, 0]}]}",
             E, extra);
    sq_scene *sc = sq_scene_parse(text, th_scenes_dir(), "t.json", &e);
    CHECK(sc != NULL);
    if (!sc) {
        printf("    %s\n", e.msg);
        return;
    }
    sq_world *w = sq_world_create(sc, &e);
    sq_body *b = w->bodies[0];
    sq_body_set_sleep(b, 0, 0, 0);
    const sq_level *L = sq_body_level(b, sq_body_sim_level(b));
    double M = total_mass(b);
    double E0 = -1, Emax = -INFINITY, Emin = INFINITY;
    for (int f = 0; f <= 500; f++) {
        if (f)
            sq_world_step(w, 0);
        double pe = 0;
        for (int i = 0; i < L->model.n; i++)
            pe += L->model.mass[i] * 9.81 * (L->model.mesh->x[3 * i + 2] + L->state.d[3 * i + 2]);
        double E = sq_body_kinetic_energy(b) + sq_body_elastic_energy(b) + pe;
        if (f == 0)
            E0 = E;
        Emax = fmax(Emax, E);
        Emin = fmin(Emin, E);
    }
    double scale = M * 9.81 * 0.1;
    printf("    start %.6g J, max %.6g J (+%.3g %% of M g h), min %.6g J\n", E0, Emax, 100 * (Emax - E0) / scale, Emin);
    CHECK(Emax <= E0 + 0.005 * scale);
    CHECK(Emin < E0 - 0.05 * scale); /* the impact did dissipate: contact acted */
    CHECK(w->resets == 0);
    sq_world_destroy(w);
    sq_scene_free(sc);
}

SQ_TEST(contact_undamped_drop_gains_no_energy) { undamped_drop(30000, ""); }

/* the same drop with the implicit integrator (contacts as constraints of its solve), at the
 * jelly's 30 kPa and at a stiff 100 MPa, one backward Euler step a frame: the same bar (backward
 * Euler damps, so the margin is the explicit step's, not needed here) */
SQ_TEST(contact_implicit_undamped_drop_gains_no_energy)
{
    undamped_drop(30000, ", \"integrator\": \"implicit\"");
    undamped_drop(1e8, ", \"integrator\": \"implicit\"");
}

/* bad scenes: each refused with the obstacle or body named and the fix */
SQ_TEST(contact_bad_scenes_name_the_problem)
{
    static const struct {
        const char *obstacles, *want, *where;
    } cases[] = {
        {"[{\"type\": \"box\", \"center\": [0, 0, -1], \"size\": [1, 0, 1]}]", "size", NULL},
        {"[{\"name\": \"ball\", \"type\": \"sphere\", \"center\": [0, 0, -1], \"radius\": -1}]", "radius", NULL},
        {"[{\"type\": \"plane\", \"point\": [0, 0, 0], \"friction\": -0.1}]", "friction", NULL},
        {"[{\"type\": \"plane\", \"point\": [0, 0, 0], \"friction\": {\"static\": 0.2, \"kinetic\": 0.4}}]", "kinetic", NULL},
        {"[{\"type\": \"plane\", \"point\": [0, 0, 0], \"normal\": [0, 0, 0]}]", "normal", NULL},
        {"[{\"type\": \"mesh\", \"file\": \"no-such-tray.obj\"}]", "no-such-tray.obj", NULL},
        {"[{\"type\": \"cone\"}]", "cone", NULL},
        {"[{\"name\": \"slab\", \"type\": \"box\", \"center\": [0.1, 0.1, 0.1], \"size\": [1, 1, 0.1]}]", "starts inside obstacle \"slab\"", "bodies[0]"},
    };
    for (size_t k = 0; k < sizeof cases / sizeof cases[0]; k++) {
        char rest[600];
        snprintf(rest, sizeof rest, ", \"obstacles\": %s", cases[k].obstacles);
        sq_err e = {{0}};
        sq_scene *sc = cube_scene("[0, 0, -9.81]", ", \"offset\": [0, 0, 0.01]", rest, &e);
        CHECK(sc == NULL);
        CHECK_CONTAINS(e.msg, cases[k].want);
        CHECK_CONTAINS(e.msg, cases[k].where ? cases[k].where : "obstacles[0]");
        sq_scene_free(sc);
    }
}

SQ_TEST(contact_body_starting_inside_another_is_refused)
{
    sq_err e = {{0}};
    char text[3000];
    const char *body = "{\"name\": \"%s\", \"levels\": [\"../cube/cube_l1.msh\"], \"scale\": 0.2, \"offset\": [%g, 0, 0],"
                       " \"material\": {\"E\": 30000, \"nu\": 0.3}, \"elasticity\": \"corotational\", \"lod\": {\"mode\": \"fixed\"}}";
    char a[400], b[400];
    snprintf(a, sizeof a, body, "a", 0.0);
    snprintf(b, sizeof b, body, "b", 0.1);
    snprintf(text, sizeof text, "{\"name\": \"t\", \"gravity\": [0, 0, 0], \"bodies\": [%s, %s]%s}", a, b, "");
    sq_scene *sc = sq_scene_parse(text, th_scenes_dir(), "t.json", &e);
    CHECK(sc == NULL);
    CHECK_CONTAINS(e.msg, "starts inside body");
    CHECK_CONTAINS(e.msg, "offset");
    snprintf(text, sizeof text, "{\"name\": \"t\", \"gravity\": [0, 0, 0], \"bodies\": [%s, %s]%s}", a, b,
             ", \"contact\": {\"bodies\": false}");
    sc = sq_scene_parse(text, th_scenes_dir(), "t.json", &e);
    CHECK(sc != NULL); /* overlap allowed when body contact is off */
    sq_scene_free(sc);
}

/* a free linear body meeting an obstacle is loaded with a warning naming corotational */
SQ_TEST(contact_free_linear_body_warns)
{
    sq_err e = {{0}};
    const char *text = "{\"name\": \"t\", \"bodies\": [{\"name\": \"b\", \"levels\": [\"../cube/cube_l1.msh\"],"
                       " \"scale\": 0.2, \"offset\": [0, 0, 0.1], \"material\": {\"E\": 30000, \"nu\": 0.3}}],"
                       " \"obstacles\": [{\"type\": \"plane\", \"point\": [0, 0, 0]}]}";
    sq_scene *sc = sq_scene_parse(text, th_scenes_dir(), "t.json", &e);
    CHECK(sc != NULL);
    if (!sc)
        return;
    CHECK(sc->nwarnings == 1);
    CHECK_CONTAINS(sc->warnings[0], "corotational");
    sq_scene_free(sc);
}

/* a keyframed obstacle moves and has the keyframes' velocity */
SQ_TEST(contact_obstacle_keyframes_move_it)
{
    sq_obstacle_script s;
    memset(&s, 0, sizeof s);
    s.obstacle.kind = SQ_OBSTACLE_SPHERE;
    s.obstacle.radius = 0.1;
    s.nkeys = 2;
    s.keys[1].t = 1;
    s.keys[1].pos[0] = 0.5;
    sq_obstacle o;
    sq_obstacle_script_pose(&s, 0.5, 0.02, &o);
    CHECK_NEAR(o.point[0], 0.25, 1e-12);
    CHECK_NEAR(o.velocity[0], 0.5, 1e-9);
    sq_obstacle_script_pose(&s, 2, 0.02, &o);
    CHECK_NEAR(o.point[0], 0.5, 1e-12);
    CHECK_NEAR(o.velocity[0], 0, 1e-12);
}

/* ---- adaptive bodies --------------------------------------------------------------------- */

/* the 20 cm cube on three levels (cube_l0..2) dropped 2 cm onto the floor with lod `lod` (JSON)
 * for `frames` frames; the world (caller frees it and *sc) */
static sq_world *adaptive_drop(const char *lod, int frames, sq_scene **sc)
{
    char text[3000];
    snprintf(text, sizeof text,
             "{\"name\": \"t\", \"gravity\": [0, 0, -9.81], \"frame_rate\": 50,"
             " \"bodies\": [{\"name\": \"block\", \"levels\": [\"../cube/cube_l0.msh\", \"../cube/cube_l1.msh\","
             "   \"../cube/cube_l2.msh\"], \"scale\": 0.2, \"offset\": [0, 0, 0.02],"
             "   \"material\": {\"E\": 30000, \"nu\": 0.3, \"density\": 1000, \"damping\": {\"rayleigh_mass\": 2.0}},"
             "   \"elasticity\": \"corotational\", \"lod\": %s}],"
             " \"obstacles\": [{\"name\": \"floor\", \"type\": \"plane\", \"point\": [0, 0, 0], \"friction\": 0.5}]}",
             lod);
    sq_err e = {{0}};
    *sc = sq_scene_parse(text, th_scenes_dir(), "t.json", &e);
    if (!*sc) {
        printf("    %s\n", e.msg);
        return NULL;
    }
    sq_world *w = sq_world_create(*sc, &e);
    if (!w) {
        printf("    %s\n", e.msg);
        return NULL;
    }
    for (int f = 0; f < frames; f++)
        sq_world_step(w, 0);
    return w;
}

/* forced finest (split 0: every region at level 2, at level 2's step, the same contact calls)
 * equals the fixed finest run to rounding (1e-12 of the largest displacement, as
 * lod_forced_finest_and_coarsest_match_fixed_runs): contact keeps that property */
SQ_TEST(contact_adaptive_forced_finest_equals_fixed_finest)
{
    sq_scene *sf = NULL, *sa = NULL;
    sq_world *wf = adaptive_drop("{\"mode\": \"fixed\", \"level\": 2}", 40, &sf);
    sq_world *wa = adaptive_drop("{\"mode\": \"adaptive\", \"level\": 0, \"max_level\": 2, \"split\": 0, \"merge\": 0}",
                                 40, &sa);
    CHECK(wf && wa);
    if (wf && wa) {
        const sq_level *Lf = sq_body_level(wf->bodies[0], sq_body_sim_level(wf->bodies[0]));
        const sq_level *La = sq_body_level(wa->bodies[0], sq_body_sim_level(wa->bodies[0]));
        CHECK(Lf->model.n == La->model.n);
        double dmax = 0, diff = 0;
        for (int i = 0; Lf->model.n == La->model.n && i < 3 * Lf->model.n; i++) {
            dmax = fmax(dmax, fabs(Lf->state.d[i]));
            diff = fmax(diff, fabs(Lf->state.d[i] - La->state.d[i]));
        }
        double Ff[3], Fa[3];
        sq_body_contact_force(wf->bodies[0], Ff, NULL, NULL);
        sq_body_contact_force(wa->bodies[0], Fa, NULL, NULL);
        printf("    max |d| %.4g m, max diff %.3g m; contact force fixed %.6g N, adaptive %.6g N\n", dmax, diff, Ff[2],
               Fa[2]);
        CHECK(dmax > 0.015); /* it fell onto the floor */
        CHECK(diff <= 1e-12 * dmax);
        CHECK(Fa[2] > 1);
        CHECK_NEAR(Fa[2], Ff[2], 1e-9 * fabs(Ff[2]));
    }
    sq_world_destroy(wf);
    sq_world_destroy(wa);
    sq_scene_free(sf);
    sq_scene_free(sa);
}

/* an adaptive body at rest on the floor: the contact acts through the active levels, the
 * deepest node stays under 1 % of the edge and the mean contact force over the last second is
 * the weight within 1 %; the contact region refines (level 2 active somewhere) */
SQ_TEST(contact_adaptive_rests_on_floor)
{
    sq_scene *sc = NULL;
    sq_world *w = adaptive_drop("{\"mode\": \"adaptive\", \"level\": 0, \"max_level\": 2, \"split\": 0.0005, \"merge\": 0.0002}",
                                100, &sc);
    CHECK(w != NULL);
    if (!w) {
        sq_scene_free(sc);
        return;
    }
    sq_body *b = w->bodies[0];
    double fz = 0, M = 0;
    for (int f = 0; f < 50; f++) {
        sq_world_step(w, 0);
        double F[3];
        sq_body_contact_force(b, F, NULL, NULL);
        fz += F[2] / 50;
    }
    const sq_level *L = sq_body_level(b, sq_body_sim_level(b));
    for (int i = 0; i < L->model.n; i++)
        M += L->model.mass[i];
    double low = INFINITY;
    for (int i = 0; i < L->model.n; i++)
        low = fmin(low, L->model.mesh->x[3 * i + 2] + L->state.d[3 * i + 2]);
    int active[SQ_MAX_LEVELS];
    sq_body_active_nodes(b, active);
    printf("    mean contact force %.6g N, weight %.6g N, lowest node %.3g m, active %d %d %d\n", fz, M * 9.81, low,
           active[0], active[1], active[2]);
    CHECK_NEAR(fz, M * 9.81, 0.01 * M * 9.81);
    CHECK(low > -0.01 * 0.2);
    CHECK(active[1] + active[2] > 0);
    CHECK(w->resets == 0);
    sq_world_destroy(w);
    sq_scene_free(sc);
}

/* a mesh obstacle read from a tetrahedral mesh's boundary (cube_l0, scaled to a 0.6 m slab top
 * at z = 0): a block dropped 1 cm settles on it, its weight carried within 1 % */
SQ_TEST(contact_tet_mesh_boundary_as_obstacle)
{
    sq_err e = {{0}};
    sq_scene *sc = cube_scene("[0, 0, -9.81]", ", \"offset\": [0.2, 0.2, 0.01]",
                              ", \"obstacles\": [{\"name\": \"slab\", \"type\": \"mesh\", \"file\": "
                              "\"../cube/cube_l0.msh\", \"scale\": 0.6, \"offset\": [0, 0, -0.6], \"thickness\": 0.05}]",
                              &e);
    CHECK(sc != NULL);
    if (!sc) {
        printf("    %s\n", e.msg);
        return;
    }
    CHECK(sc->trimeshes[0] && sc->trimeshes[0]->ntris > 0);
    sq_world *w = sq_world_create(sc, &e);
    double fz = 0;
    for (int f = 0; f < 200; f++) {
        sq_world_step(w, 0);
        if (f >= 150) {
            double F[3];
            sq_body_contact_force(w->bodies[0], F, NULL, NULL);
            fz += F[2] / 50;
        }
    }
    double weight = total_mass(w->bodies[0]) * 9.81, low = lowest_z(w->bodies[0]);
    printf("    mean contact force %.6g N, weight %.6g N, lowest node %.3g m\n", fz, weight, low);
    CHECK_NEAR(fz, weight, 0.01 * weight);
    CHECK(low > -0.002); /* 1 % of the edge */
    CHECK(w->resets == 0);
    sq_world_destroy(w);
    sq_scene_free(sc);
}

/* ---- the frame's cache: the same contact as without it ------------------------------------ */

/* a tray with a step as a triangle soup: a floor z = 0 for x in [0, 0.5], a wall up to z = 0.02
 * at x = 0.5 and a plateau z = 0.02 for x in [0.5, 1.5], y in [0, 1], in cells of 0.125 m */
static sq_trimesh *step_tray(void)
{
    enum { MAXQ = 104 }; /* 32 floor, 8 wall and 64 plateau quads */
    double x[MAXQ * 12];
    int t[MAXQ * 6], nq = 0;
    for (int part = 0; part < 3; part++)
        for (int j = 0; j < 8; j++)
            for (int i = 0; i < (part == 1 ? 1 : part == 0 ? 4 : 8); i++) {
                double y0 = 0.125 * j, y1 = y0 + 0.125, *q = x + 12 * nq;
                double c[4][3];
                if (part == 1) { /* the wall, facing -x (towards the floor) */
                    double w[4][3] = {{0.5, y0, 0}, {0.5, y0, 0.02}, {0.5, y1, 0.02}, {0.5, y1, 0}};
                    memcpy(c, w, sizeof c);
                } else {
                    double x0 = (part == 0 ? 0 : 0.5) + 0.125 * i, x1 = x0 + 0.125, z = part == 0 ? 0 : 0.02;
                    double f[4][3] = {{x0, y0, z}, {x1, y0, z}, {x1, y1, z}, {x0, y1, z}};
                    memcpy(c, f, sizeof c);
                }
                memcpy(q, c, sizeof c);
                int v = 4 * nq, tt[6] = {v, v + 1, v + 2, v, v + 2, v + 3};
                memcpy(t + 6 * nq, tt, sizeof tt);
                nq++;
            }
    sq_err e = {{0}};
    return sq_trimesh_from_arrays(4 * nq, x, 2 * nq, t, "step tray", &e);
}

/* particles sliding over the step tray (across triangle edges, into the wall's corner, along the
 * plateau) with and without the frame's cache: the cache only skips work, so both runs agree to
 * round-off. Tolerance 1e-9 m and m/s: the two paths compute a flat triangle's distance by
 * different formulas (n . x - off against (x - q) . n), which differ by ~1e-17 m per step; a
 * wrong plane (the wall or the plateau missed) differs by millimetres. The run ends before any
 * particle reaches an open edge of the mesh: there the signed distance flips sign across the
 * nearest face's plane (a node beside the edge, a few mm away, counts as inside when just below
 * it), so a node the cache rightly finds out of reach is pushed by the uncached pass. */
SQ_TEST(contact_cache_matches_uncached_over_a_step)
{
    sq_trimesh *m = step_tray();
    CHECK(m != NULL);
    if (!m)
        return;
    enum { N = 48 };
    sq_obstacle o = {.name = "tray", .kind = SQ_OBSTACLE_MESH, .mesh = m, .thickness = 0.04, .mu_s = 0.02,
                     .mu_k = 0.01};
    double X[3 * N], mass[N], d[2][3 * N], v[2][3 * N];
    int list[N];
    unsigned char fixed[N] = {0};
    for (int k = 0; k < N; k++) {
        int onplateau = k >= N / 2, j = k % (N / 2);
        X[3 * k] = (onplateau ? 0.55 : 0.05) + 0.4 * (j % 6) / 6.0;
        X[3 * k + 1] = 0.06 + 0.2 * (j / 6) + 0.01 * j;
        X[3 * k + 2] = (onplateau ? 0.02 : 0) + 0.0005 * (1 + j % 3);
        mass[k] = 0.01;
        list[k] = k;
        for (int r = 0; r < 2; r++) {
            d[r][3 * k] = d[r][3 * k + 1] = d[r][3 * k + 2] = 0;
            v[r][3 * k] = 0.6 + 0.02 * (j % 5);
            v[r][3 * k + 1] = 0.05 * ((j % 3) - 1);
            v[r][3 * k + 2] = 0;
        }
    }
    sq_contact_cache *cache = sq_contact_cache_create();
    sq_contact_nodes nd[2] = {{.n = N, .list = list, .X = X, .mass = mass, .fixed = fixed, .cache = cache},
                              {.n = N, .list = list, .X = X, .mass = mass, .fixed = fixed}};
    const double h = 0.001;
    double worst = 0;
    int most_flat = 0, touching = 0;
    for (int frame = 0; frame < 80; frame++) {
        sq_contact_cache_reset(cache);
        for (int s = 0; s < 10; s++) {
            for (int r = 0; r < 2; r++) {
                for (int k = 0; k < N; k++) {
                    v[r][3 * k + 2] -= 9.81 * h;
                    for (int c = 0; c < 3; c++)
                        d[r][3 * k + c] += h * v[r][3 * k + c];
                }
                int t = sq_contact_step(&o, 1, &nd[r], d[r], v[r], h, NULL);
                if (r == 0)
                    touching = t > touching ? t : touching;
            }
            if (s == 0)
                most_flat = sq_contact_cache_flat_count(cache) > most_flat ? sq_contact_cache_flat_count(cache)
                                                                           : most_flat;
            for (int c = 0; c < 3 * N; c++)
                worst = fmax(worst, fmax(fabs(d[0][c] - d[1][c]), fabs(v[0][c] - v[1][c])));
        }
    }
    CHECK(most_flat >= N / 2); /* the shortcut was taken (else this test proves nothing) */
    CHECK(touching >= N / 2);
    CHECK(worst < 1e-9);
    int hit_wall = 0; /* some particles met the wall and stayed before it */
    for (int k = 0; k < N / 2; k++)
        hit_wall += X[3 * k] + d[0][3 * k] < 0.5 && X[3 * k] + d[0][3 * k] > 0.49;
    CHECK(hit_wall > 0);
    sq_contact_cache_free(cache);
    sq_trimesh_free(m);
}

/* ---- the implicit integrator: contacts as constraints in the solve ---- */

/* a cube at rest on the floor with the implicit integrator, one backward Euler step a frame:
 * E (Pa) and the mean contact force over frames 150-199, the deepest node then, the rms
 * frame-to-frame change of the contact force (N) and the kinetic energy at the end */
static int implicit_rest(double E, double *fz, double *weight, double *deepest, double *jitter, double *ke)
{
    sq_err e = {{0}};
    char extra[200];
    snprintf(extra, sizeof extra, ", \"offset\": [0, 0, 0.02], \"integrator\": \"implicit\"");
    char text[6000];
    snprintf(text, sizeof text,
             "{\"name\": \"t\", \"gravity\": [0, 0, -9.81], \"frame_rate\": 50,"
             " \"bodies\": [{\"name\": \"block\", \"levels\": [\"../cube/cube_l1.msh\"], \"scale\": 0.2,"
             "   \"material\": {\"E\": %g, \"nu\": 0.3, \"density\": 1000,"
             "                  \"damping\": {\"rayleigh_mass\": 2.0, \"rayleigh_stiffness\": 0.002}},"
             "   \"elasticity\": \"corotational\", \"lod\": {\"mode\": \"fixed\"} %s}],"
             " \"obstacles\": [{\"name\": \"floor\", \"type\": \"plane\", \"point\": [0, 0, 0]}]}",
             E, extra);
    sq_scene *sc = sq_scene_parse(text, th_scenes_dir(), "t.json", &e);
    if (!sc) {
        printf("    %s\n", e.msg);
        return -1;
    }
    sq_world *w = sq_world_create(sc, &e);
    if (!w) {
        printf("    %s\n", e.msg);
        sq_scene_free(sc);
        return -1;
    }
    double sum = 0, sq = 0, prev = NAN;
    int n = 0, nj = 0;
    *deepest = 0;
    for (int f = 0; f < 200; f++) {
        sq_world_step(w, 0);
        if (f >= 150) {
            double F[3];
            sq_body_contact_force(w->bodies[0], F, NULL, NULL);
            sum += F[2];
            n++;
            if (!isnan(prev)) {
                sq += (F[2] - prev) * (F[2] - prev);
                nj++;
            }
            prev = F[2];
            *deepest = fmax(*deepest, -lowest_z(w->bodies[0]));
        }
    }
    *fz = sum / n;
    *weight = total_mass(w->bodies[0]) * 9.81;
    *jitter = sqrt(sq / nj);
    const sq_level *L = sq_body_level(w->bodies[0], sq_body_sim_level(w->bodies[0]));
    *ke = 0;
    for (int i = 0; i < L->model.n; i++)
        for (int c = 0; c < 3; c++)
            *ke += 0.5 * L->model.mass[i] * L->state.v[3 * i + c] * L->state.v[3 * i + c];
    int resets = (int)w->resets;
    sq_world_destroy(w);
    sq_scene_free(sc);
    return resets;
}

SQ_TEST(contact_implicit_rest_on_floor)
{
    static const double Es[] = {1e5, 1e8};
    for (int k = 0; k < 2; k++) {
        double fz, weight, deepest, jitter, ke;
        int resets = implicit_rest(Es[k], &fz, &weight, &deepest, &jitter, &ke);
        printf("    E %.0e: mean contact force %.6g N, weight %.6g N, deepest %.3g m, frame-to-frame rms %.3g N, "
               "kinetic %.3g J\n", Es[k], fz, weight, deepest, jitter, ke);
        CHECK(resets == 0);
        CHECK_NEAR(fz, weight, 0.01 * weight);
        CHECK(deepest < 0.01 * 0.2);
    }
}

SQ_TEST(contact_implicit_slope)
{
    const double th = 20 * M_PI / 180, want = 9.81 * (sin(th) - 0.2 * cos(th));
    double drift, drift2;
    double a5 = slope_run_with(0.5, ", \"integrator\": \"implicit\"", &drift);
    double a2 = slope_run_with(0.2, ", \"integrator\": \"implicit\"", &drift2);
    printf("    friction 0.5: drift %.3g m over 2 s; friction 0.2: acceleration %.4g m/s^2, expected %.4g\n", drift, a2,
           want);
    (void)a5;
    CHECK(drift < 1e-3);
    CHECK_NEAR(a2, want, 0.05 * want);
}
