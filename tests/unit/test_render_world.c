/* test_render_world.c - capturing a world's bodies, tools and obstacles into a render state, and (outside
 * the sanitizer build) rendering an adaptive cube poked by a sphere: the finer level's colour
 * appears where the body was poked. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "render/render.h"
#include "sq_test.h"
#include "test_render_helpers.h"

/* a two-level adaptive cube [0,1]^3 (4^3 and 8^3 cells), bottom fixed, no gravity, poked for
 * `frames` frames by a sphere pressing 5 cm into the middle of the top face; w gets the body
 * and the tool. Measured with these values: about 170 of the 386 surface vertices split to
 * level 1 after 10 frames (0 without the poke), so the checks below have wide margins. */
static int poked_world(sq_world *w, sq_mesh **coarse, sq_mesh **fine, int frames)
{
    sq_err e = {{0}};
    double size[3] = {1, 1, 1}, origin[3] = {0, 0, 0};
    memset(w, 0, sizeof *w); /* callers read w->nbodies even when set-up fails */
    *coarse = sq_mesh_box(4, 4, 4, size, origin, &e);
    *fine = sq_mesh_box(8, 8, 8, size, origin, &e);
    if (!*coarse || !*fine)
        return -1;
    sq_body_def def = sq_body_def_default();
    def.name = "cube";
    def.nlevels = 2;
    def.levels[0] = *coarse;
    def.levels[1] = *fine;
    sq_material_from_E_nu(&def.material, 1e5, 0.3, &e);
    def.material.density = 1000;
    def.material.rayleigh_mass = 2;
    def.nconstraints = 1;
    def.constraints[0].kind = SQ_REGION_BOX;
    def.constraints[0].a[0] = def.constraints[0].a[1] = def.constraints[0].a[2] = -1;
    def.constraints[0].b[0] = def.constraints[0].b[1] = 2;
    def.constraints[0].b[2] = 1e-3;
    def.constraints[0].axes = 7;
    def.lod.mode = SQ_LOD_ADAPTIVE;
    def.lod.level = 0;
    def.lod.split = 0.01; /* m, on delta = hbar^2 |Lap d| */
    def.lod.merge = 0.005;
    def.lod.max_level = 1;
    memset(w, 0, sizeof *w);
    w->bodies[0] = sq_body_create(&def, &e);
    if (!w->bodies[0]) {
        fprintf(stderr, "sq_body_create: %s\n", e.msg);
        return -1;
    }
    w->nbodies = 1;
    w->ntools = 1;
    w->tools[0] = (sq_tool){.id = 7, .shape = SQ_TOOL_SPHERE, .active = 1,
                            .pos = {0.5, 0.5, 1.05}, .radius = 0.1};
    for (int f = 0; f < frames; f++) {
        sq_body_frame(w->bodies[0], w->tools, w->ntools, NULL, NULL, 0);
        w->frame++;
        w->time += def.frame_dt;
    }
    return 0;
}

static void free_world(sq_world *w, sq_mesh *coarse, sq_mesh *fine)
{
    if (w->nbodies)
        sq_body_destroy(w->bodies[0]);
    sq_mesh_free(coarse);
    sq_mesh_free(fine);
}

SQ_TEST(render_capture_world_poke_levels)
{
    sq_world w;
    sq_mesh *c = NULL, *f = NULL;
    CHECK(poked_world(&w, &c, &f, 10) == 0);
    if (!w.nbodies) {
        free_world(&w, c, f);
        return;
    }
    sq_render_state s;
    sq_render_state_init(&s);
    sq_err e = {{0}};
    CHECK(sq_render_state_capture(&s, &w, &e) == 0);
    CHECK(s.nbodies == 1 && s.ntools == 1 && s.tools[0].id == 7);
    CHECK(s.frame == 10);
    /* the rendered surface is the fine level's boundary; no gravity: up is +z */
    CHECK(s.bodies[0].nverts == f->nsurf && s.bodies[0].ntris == f->ntris);
    CHECK_NEAR(s.up[2], 1.0, 1e-12);
    CHECK_NEAR(s.bbox_max[2], 1.0, 1e-6);
    /* the top centre is pushed down by the sphere (to about 1.05 - 0.1 = 0.95) */
    const sq_render_body *b = &s.bodies[0];
    int top = -1, nfine = 0;
    for (int i = 0; i < b->nverts; i++) {
        if (fabsf(b->rest[3 * i] - 0.5f) < 1e-6f && fabsf(b->rest[3 * i + 1] - 0.5f) < 1e-6f &&
            b->rest[3 * i + 2] == 1.0f)
            top = i;
        nfine += b->level[i] == 1;
    }
    CHECK(top >= 0);
    if (top >= 0)
        CHECK(b->xyz[3 * top + 2] < 0.97f);
    /* adaptive: the poked region runs at level 1, the bottom stays at level 0 */
    CHECK(nfine > 0 && nfine < b->nverts);
    CHECK(top < 0 || b->level[top] == 1);

    /* a second capture reuses the buffers and gives the same state */
    float *xyz = b->xyz;
    CHECK(sq_render_state_capture(&s, &w, &e) == 0);
    CHECK(s.bodies[0].xyz == xyz && s.nbodies == 1);
    sq_render_state_free(&s);
    free_world(&w, c, f);
}

#if !defined(__SANITIZE_ADDRESS__)
SQ_TEST(render_world_png_poke_shows_both_levels)
{
    sq_world w;
    sq_mesh *c = NULL, *f = NULL;
    CHECK(poked_world(&w, &c, &f, 10) == 0);
    if (!w.nbodies) {
        free_world(&w, c, f);
        return;
    }
    sq_render_opts o = sq_render_opts_default();
    o.camera.el_deg = 45; /* see the poked top face */
    unsigned char *png = NULL, *png2 = NULL, *rgb = NULL;
    size_t len = 0, len2 = 0;
    sq_err e = {{0}};
    CHECK(sq_render_world_png(&w, 200, 150, &o, &png, &len, &e) == 0);
    CHECK(sq_render_world_png(&w, 200, 150, &o, &png2, &len2, &e) == 0);
    CHECK(len == len2 && png && png2 && !memcmp(png, png2, len));
    int iw = 0, ih = 0;
    CHECK(sq_png_decode(png, len, &rgb, &iw, &ih, &e) == 0);
    CHECK(iw == 200 && ih == 150);
    if (rgb) {
        unsigned char c0[3], c1[3];
        sq_render_level_rgb(&o.palette, 0, c0);
        sq_render_level_rgb(&o.palette, 1, c1);
        int n0 = count_lit(rgb, iw * ih, c0), n1 = count_lit(rgb, iw * ih, c1);
        CHECK(n0 > iw * ih / 100);
        CHECK(n1 > iw * ih / 100);
    }
    /* the snapshot limit is 2048 per side */
    CHECK(sq_render_world_png(&w, 2049, 100, &o, &png2, &len2, &e) == -1);
    CHECK_CONTAINS(e.msg, "2048");
    free(rgb);
    free(png);
    free(png2);
    free_world(&w, c, f);
}
#endif

/* ---- obstacles ---- */

/* the shipped scene meshes/scenes/<name>.json and a world of it; 0, or -1 with the error printed */
static int shipped_world(const char *name, sq_scene **sc, sq_world **w)
{
    char path[1200];
    snprintf(path, sizeof path, "%s/../../meshes/scenes/%s.json", sq_test_data(), name);
    sq_err e = {{0}};
    *w = NULL;
    *sc = sq_scene_load(path, &e);
    if (*sc)
        *w = sq_world_create(*sc, &e);
    if (!*w)
        fprintf(stderr, "    %s: %s\n", path, e.msg);
    return *w ? 0 : -1;
}

SQ_TEST(render_capture_jelly_drop_floor_plane)
{
    sq_scene *sc = NULL;
    sq_world *w = NULL;
    CHECK(shipped_world("jelly-drop", &sc, &w) == 0);
    if (!w) {
        sq_scene_free(sc);
        return;
    }
    sq_render_state s;
    sq_render_state_init(&s);
    sq_err e = {{0}};
    CHECK(sq_render_state_capture(&s, w, &e) == 0);
    CHECK(s.nobstacles == 1);
    CHECK(s.obstacles[0].shape.kind == SQ_OBSTACLE_PLANE && s.obstacles[0].shape.mesh == NULL);
    CHECK_CONTAINS(s.obstacles[0].shape.name, "floor");

    /* the plane replaces the default floor: one tiled square at z = 0 (the default floor would
     * sit under the body's rest box, at z = 0.3) */
    sq_render_opts o = sq_render_opts_default();
    sq_drawlist dl;
    memset(&dl, 0, sizeof dl);
    CHECK(sq_drawlist_build(&dl, &s, &o, 4.0 / 3.0, &e) == 0);
    CHECK(dl.floor_tris == 0 && dl.obstacle_tris == 2 * 12 * 12);
    int at_zero = 1;
    for (unsigned i = 3 * (unsigned)dl.body_tris; i < 3 * (unsigned)(dl.body_tris + dl.obstacle_tris); i++)
        at_zero &= fabsf(dl.v[dl.idx[i]].pos[2]) < 2e-3f;
    CHECK(at_zero);
    /* without obstacles the default floor comes back */
    o.obstacles = 0;
    CHECK(sq_drawlist_build(&dl, &s, &o, 4.0 / 3.0, &e) == 0);
    CHECK(dl.floor_tris == 2 * 12 * 12 && dl.obstacle_tris == 0);
    CHECK(dl.v[dl.idx[3 * dl.body_tris]].pos[2] > 0.25f);
    sq_drawlist_free(&dl);

#if !defined(__SANITIZE_ADDRESS__)
    /* rendered, default floor off: the floor plane's tiles cover a tenth of the picture more
     * with obstacles on than off (the body alone) */
    o = sq_render_opts_default();
    o.floor = 0;
    int n[2] = {0, 0};
    for (int pass = 0; pass < 2; pass++) {
        o.obstacles = pass == 0;
        unsigned char *png = NULL, *rgb = NULL;
        size_t len = 0;
        int iw = 0, ih = 0;
        CHECK(sq_render_state_png(&s, 160, 120, &o, &png, &len, &e) == 0);
        CHECK(png && sq_png_decode(png, len, &rgb, &iw, &ih, &e) == 0);
        if (rgb) {
            /* pixels not of the background (cleared to it exactly) */
            unsigned char bg[3];
            for (int k = 0; k < 3; k++)
                bg[k] = (unsigned char)lrintf(o.palette.background[k] * 255.0f);
            for (int i = 0; i < iw * ih; i++)
                n[pass] += memcmp(&rgb[3 * i], bg, 3) != 0;
        }
        free(rgb);
        free(png);
    }
    if (!(n[0] > n[1] + 160 * 120 / 10))
        fprintf(stderr, "    covered pixels: %d with obstacles, %d without\n", n[0], n[1]);
    CHECK(n[0] > n[1] + 160 * 120 / 10);
#endif
    sq_render_state_free(&s);
    sq_world_destroy(w);
    sq_scene_free(sc);
}

SQ_TEST(render_obstacle_shapes_drawn)
{
    sq_render_state s;
    sq_render_state_init(&s);
    sq_err e = {{0}};
    /* a small tetrahedron body at the origin frames the view */
    const float xyz[] = {-0.1f, -0.1f, 0, 0.1f, -0.1f, 0, 0, 0.1f, 0, 0, 0, 0.15f};
    const int tris[] = {0, 2, 1, 0, 1, 3, 1, 2, 3, 2, 0, 3};
    CHECK(sq_render_state_add_body(&s, 4, xyz, NULL, NULL, 4, tris, &e) == 0);
    sq_obstacle box = {.name = "box", .kind = SQ_OBSTACLE_BOX, .point = {0.3, 0, 0.05},
                       .half = {0.05, 0.05, 0.05}, .mu_s = 0.5, .mu_k = 0.4};
    sq_obstacle ball = {.name = "ball", .kind = SQ_OBSTACLE_SPHERE, .point = {-0.3, 0, 0.05},
                        .radius = 0.06, .mu_s = 0.5, .mu_k = 0.4};
    sq_obstacle rod = {.name = "rod", .kind = SQ_OBSTACLE_CAPSULE, .point = {-0.2, 0.3, 0.05},
                       .end = {0.2, 0.3, 0.05}, .radius = 0.03, .mu_s = 0.5, .mu_k = 0.4};
    const double mx[] = {-0.2, -0.3, 0.0, 0.2, -0.3, 0.0, 0.0, -0.3, 0.2};
    const int mt[] = {0, 1, 2};
    sq_trimesh *tm = sq_trimesh_from_arrays(3, mx, 1, mt, "test", &e);
    CHECK(tm != NULL);
    sq_obstacle mesh = {.name = "tri", .kind = SQ_OBSTACLE_MESH, .mesh = tm, .thickness = 0.01,
                        .mu_s = 0.5, .mu_k = 0.4};
    CHECK(sq_render_state_add_obstacle(&s, &box, &e) == 0);
    CHECK(sq_render_state_add_obstacle(&s, &ball, &e) == 0);
    CHECK(sq_render_state_add_obstacle(&s, &rod, &e) == 0);
    if (tm)
        CHECK(sq_render_state_add_obstacle(&s, &mesh, &e) == 0);
    sq_obstacle bad = ball;
    bad.radius = -1;
    CHECK(sq_render_state_add_obstacle(&s, &bad, &e) == -1);
    CHECK(s.nobstacles == (tm ? 4 : 3));
    /* the mesh is copied: the state does not borrow the scene's triangles */
    sq_trimesh_free(tm);
    CHECK(tm == NULL || (s.obstacles[3].ntris == 1 && s.obstacles[3].shape.mesh == NULL &&
                         s.obstacles[3].xyz[6] == 0.0f && s.obstacles[3].xyz[8] == 0.2f));

    sq_render_opts o = sq_render_opts_default();
    sq_drawlist dl;
    memset(&dl, 0, sizeof dl);
    CHECK(sq_drawlist_build(&dl, &s, &o, 4.0 / 3.0, &e) == 0);
    /* no plane: the default floor stays; box 12, sphere 2 x 12 x 24, capsule two spheres and a
     * 24-segment band, mesh 1 */
    CHECK(dl.floor_tris == 2 * 12 * 12);
    CHECK(dl.obstacle_tris == 12 + 576 + 2 * 576 + 48 + (s.nobstacles == 4));
    sq_drawlist_free(&dl);
#if !defined(__SANITIZE_ADDRESS__)
    unsigned char *png = NULL, *rgb = NULL;
    size_t len = 0;
    int iw = 0, ih = 0;
    o.camera.el_deg = 35;
    CHECK(sq_render_state_png(&s, 200, 150, &o, &png, &len, &e) == 0);
    CHECK(png && sq_png_decode(png, len, &rgb, &iw, &ih, &e) == 0);
    if (rgb) {
        unsigned char c[3];
        for (int k = 0; k < 3; k++)
            c[k] = (unsigned char)lrintf(o.palette.obstacle[k] * 255.0f);
        CHECK(count_lit(rgb, iw * ih, c) > iw * ih / 50);
    }
    free(rgb);
    free(png);
#endif
    sq_render_state_free(&s);
}
