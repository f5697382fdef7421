/* cmd_bench_contact.c - squish bench contact: the cost of contact (docs/physics.md section 13),
 * thread CPU time on one core.
 *
 *   squish bench contact [--quick]
 *
 * 1. A 10,648-node box (0.3 m, fem, fixed lod, linear and corotational) resting on a tray: a
 *    triangle mesh of 12,800 triangles, then on a floor plane: the frame's CPU time, the contact passes' share of
 *    it (the aim: at most 20 %), the nodes in contact.
 * 2. Every shipped scene with obstacles: frame CPU time after frame 1 (p50, p95, max) against
 *    the 20 ms of a 50 Hz frame.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/commands.h"
#include "scene/scene.h"

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

/* a flat grid of n x n quads over [lo, hi]^2 at height z (normal +z) */
static sq_trimesh *grid_tray(int n, double lo, double hi, double z, sq_err *err)
{
    int nv = (n + 1) * (n + 1), nt = 2 * n * n;
    double *x = sq_malloc(sizeof(double) * 3 * (size_t)nv);
    int *t = sq_malloc(sizeof(int) * 3 * (size_t)nt);
    for (int j = 0; j <= n; j++)
        for (int i = 0; i <= n; i++) {
            double *p = x + 3 * (j * (n + 1) + i);
            p[0] = lo + (hi - lo) * i / n;
            p[1] = lo + (hi - lo) * j / n;
            p[2] = z;
        }
    int k = 0;
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) {
            int a = j * (n + 1) + i, b = a + 1, c = a + n + 2, d = a + n + 1;
            int q[6] = {a, b, c, a, c, d};
            memcpy(t + 3 * k, q, sizeof q);
            k += 2;
        }
    sq_trimesh *m = sq_trimesh_from_arrays(nv, x, nt, t, "bench tray grid", err);
    free(x);
    free(t);
    return m;
}

/* frames of the box on obstacle o: mean frame CPU and contact CPU after the first 10 frames */
static int box_on(const sq_obstacle *o, int frames, int corot, const char *label)
{
    sq_err e = {{0}};
    const double size[3] = {0.3, 0.3, 0.3}, origin[3] = {0, 0, 0.0005};
    sq_mesh *m = sq_mesh_box(21, 21, 21, size, origin, &e);
    if (!m) {
        fprintf(stderr, "squish bench contact: %s\n", e.msg);
        return 1;
    }
    sq_body_def def = sq_body_def_default();
    def.name = "box";
    def.nlevels = 1;
    def.levels[0] = m;
    sq_material_from_E_nu(&def.material, 30000, 0.3, &e);
    def.material.density = 1000;
    def.material.rayleigh_mass = 2.0;
    def.gravity[2] = -9.81;
    def.elasticity = corot ? SQ_ELASTICITY_COROTATIONAL : SQ_ELASTICITY_LINEAR;
    sq_body *b = sq_body_create(&def, &e);
    if (!b) {
        fprintf(stderr, "squish bench contact: %s\n", e.msg);
        sq_mesh_free(m);
        return 1;
    }
    sq_body_set_obstacles(b, o, 1);
    double frame = 0, contact = 0;
    int nodes = 0, n = 0;
    for (int f = 0; f < frames; f++) {
        double t0 = sq_thread_cpu();
        sq_body_frame(b, NULL, 0, NULL, NULL, 0);
        double t = sq_thread_cpu() - t0;
        if (f >= 10) {
            frame += t;
            contact += sq_body_contact_cpu(b);
            double F[3];
            sq_body_contact_force(b, F, &nodes, NULL);
            n++;
        }
        if (f % 10 == 9)
            fprintf(stderr, "  %s: frame %d of %d\r", label, f + 1, frames);
    }
    int subs[SQ_MAX_LEVELS];
    sq_body_substeps(b, subs);
    printf("%-34s %8d %8d %10.2f %10.2f %8.1f %%\n", label, m->nnodes, subs[0], 1e3 * frame / n, 1e3 * contact / n,
           100 * contact / frame);
    (void)nodes;
    sq_body_destroy(b);
    sq_mesh_free(m);
    return 0;
}

static int shipped(const char *name, int frames)
{
    char path[256];
    snprintf(path, sizeof path, "meshes/scenes/%s.json", name);
    sq_err e = {{0}};
    sq_scene *sc = sq_scene_load(path, &e);
    if (!sc) {
        fprintf(stderr, "squish bench contact: %s (run from the source tree)\n", e.msg);
        return 1;
    }
    sq_world *w = sq_world_create(sc, &e);
    if (!w) {
        fprintf(stderr, "squish bench contact: %s\n", e.msg);
        sq_scene_free(sc);
        return 1;
    }
    double *t = sq_malloc(sizeof(double) * (size_t)frames);
    for (int f = 0; f < frames; f++) {
        double t0 = sq_thread_cpu();
        sq_world_step(w, 0);
        t[f] = sq_thread_cpu() - t0;
    }
    int n = frames - 1; /* after frame 1 */
    qsort(t + 1, (size_t)n, sizeof(double), cmp_double);
    double p50 = t[1 + n / 2], p95 = t[1 + (int)(0.95 * (n - 1))], mx = t[frames - 1];
    printf("%-14s %6d %9.3f %9.3f %9.3f   %s\n", name, frames, 1e3 * p50, 1e3 * p95, 1e3 * mx,
           mx < 0.02 ? "holds 50 Hz" : "OVER 20 ms");
    free(t);
    sq_world_destroy(w);
    sq_scene_free(sc);
    return 0;
}

int sq_bench_contact(int quick)
{
    int frames = quick ? 30 : 110;
    sq_err e = {{0}};
    printf("contact cost, thread CPU time of one core (docs/physics.md section 13)\n\n");
    printf("%-34s %8s %8s %10s %10s %10s\n", "body on", "nodes", "substeps", "frame ms", "contact ms", "share");
    sq_trimesh *tray = grid_tray(80, -0.1, 0.4, 0, &e);
    if (!tray) {
        fprintf(stderr, "squish bench contact: %s\n", e.msg);
        return 1;
    }
    sq_obstacle mesh = {.name = "tray", .kind = SQ_OBSTACLE_MESH, .mesh = tray, .thickness = 0.05, .mu_s = 0.5,
                        .mu_k = 0.5};
    sq_obstacle floor = {.name = "floor", .kind = SQ_OBSTACLE_PLANE, .normal = {0, 0, 1}, .mu_s = 0.5, .mu_k = 0.5};
    int rc = box_on(&mesh, frames, 0, "linear, tray mesh (12,800 tris)") ||
             box_on(&mesh, frames, 1, "corotational, tray mesh") || box_on(&floor, frames, 0, "linear, floor plane") ||
             box_on(&floor, frames, 1, "corotational, floor plane");
    sq_trimesh_free(tray);
    printf("\nshipped contact scenes: frame CPU after frame 1, ms (a 50 Hz frame is 20 ms)\n");
    printf("%-14s %6s %9s %9s %9s\n", "scene", "frames", "p50", "p95", "max");
    static const char *const scenes[] = {"jelly-drop", "squeeze", "organ-tray"};
    for (int i = 0; i < 3 && !rc; i++)
        rc = shipped(scenes[i], quick ? 50 : 200);
    return rc;
}
