/* test_render_probes.c - what renders and snapshots show besides the bodies: the scene's
 * probes as beads at their current position, and no bead for an inactive grab. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "render/render.h"
#include "sq_test.h"
#include "test_render_helpers.h"

/* vertices of the draw list whose colour is exactly rgb (no lighting in the draw list) */
static int count_rgb(const sq_drawlist *dl, const unsigned char rgb[3])
{
    int n = 0;
    for (int i = 0; i < dl->nverts; i++)
        n += !memcmp(dl->v[i].rgba, rgb, 3);
    return n;
}

/* triangles of a draw list of one tetrahedron body plus the given tools (no floor) */
static int tool_tris(const sq_tool *tools, int ntools)
{
    static const float xyz[] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1};
    static const int tris[] = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3};
    sq_render_state s;
    sq_render_state_init(&s);
    sq_err e = {{0}};
    CHECK(sq_render_state_add_body(&s, 4, xyz, NULL, NULL, 4, tris, &e) == 0);
    for (int i = 0; i < ntools; i++)
        CHECK(sq_render_state_add_tool(&s, &tools[i], &e) == 0);
    sq_render_opts o = sq_render_opts_default();
    o.floor = 0;
    sq_drawlist dl;
    memset(&dl, 0, sizeof dl);
    CHECK(sq_drawlist_build(&dl, &s, &o, 4.0 / 3.0, &e) == 0);
    int n = dl.ntris - dl.body_tris;
    sq_drawlist_free(&dl);
    sq_render_state_free(&s);
    return n;
}

SQ_TEST(render_inactive_grab_not_drawn)
{
    sq_tool grab = {.id = 1, .shape = SQ_TOOL_GRAB, .active = 1, .pos = {0.2, 0.2, 0.2}, .radius = 0.1};
    sq_tool idle = grab, sphere = {.id = 3, .shape = SQ_TOOL_SPHERE, .active = 0,
                                   .pos = {0.5, 0.5, 1.2}, .radius = 0.1};
    idle.id = 2;
    idle.active = 0;
    int active = tool_tris(&grab, 1);
    CHECK(active > 0);                            /* an active grab: a bead */
    CHECK(tool_tris(&idle, 1) == 0);              /* an inactive one: nothing */
    sq_tool both[2] = {grab, idle};
    CHECK(tool_tris(both, 2) == active);
    CHECK(tool_tris(&sphere, 1) > 0);             /* other inactive tools stay, at half colour */
}

/* the built-in cube (probe "corner" at (1, 1, 1)) after `frames` frames */
static sq_world *cube_world(sq_scene **sc, int frames)
{
    sq_err e = {{0}};
    *sc = sq_scene_default(&e);
    sq_world *w = *sc ? sq_world_create(*sc, &e) : NULL;
    if (!w)
        printf("    %s\n", e.msg);
    for (int f = 0; w && f < frames; f++)
        sq_world_step(w, 0);
    return w;
}

SQ_TEST(render_probes_captured_and_drawn)
{
    sq_scene *sc = NULL;
    sq_world *w = cube_world(&sc, 20);
    CHECK(w != NULL);
    if (!w) {
        sq_scene_free(sc);
        return;
    }
    sq_render_state s;
    sq_render_state_init(&s);
    sq_err e = {{0}};
    CHECK(sq_render_state_capture(&s, w, &e) == 0);
    CHECK(s.nprobes == 1);
    double u[3];
    CHECK(sq_world_probe(w, 0, u) == 0);
    CHECK(fabs(u[2]) > 1e-4); /* the corner has sagged: the bead follows it */
    for (int k = 0; k < 3; k++)
        CHECK_NEAR(s.probes[0][k], 1.0 + u[k], 1e-12);

    sq_render_opts o = sq_render_opts_default();
    unsigned char pc[3];
    for (int k = 0; k < 3; k++)
        pc[k] = (unsigned char)lrintf(o.palette.probe[k] * 255.0f);
    sq_drawlist dl;
    memset(&dl, 0, sizeof dl);
    CHECK(sq_drawlist_build(&dl, &s, &o, 4.0 / 3.0, &e) == 0);
    int nprobe = count_rgb(&dl, pc);
    CHECK(nprobe > 0);
    /* every probe vertex lies within 2.5 % of the scene diagonal (sqrt 3 m) of the probe */
    int near = 0;
    for (int i = 0; i < dl.nverts; i++)
        if (!memcmp(dl.v[i].rgba, pc, 3)) {
            double d2 = 0;
            for (int k = 0; k < 3; k++)
                d2 += (dl.v[i].pos[k] - s.probes[0][k]) * (dl.v[i].pos[k] - s.probes[0][k]);
            near += sqrt(d2) < 0.025 * sqrt(3.0);
        }
    CHECK(near == nprobe);
    o.probes = 0;
    CHECK(sq_drawlist_build(&dl, &s, &o, 4.0 / 3.0, &e) == 0);
    CHECK(count_rgb(&dl, pc) == 0);
    sq_drawlist_free(&dl);

#if !defined(__SANITIZE_ADDRESS__)
    /* rendered (as squish render and /snapshot.png do): probe-coloured pixels appear */
    o = sq_render_opts_default();
    for (int pass = 0; pass < 2; pass++) {
        o.probes = pass == 0;
        unsigned char *png = NULL, *rgb = NULL;
        size_t len = 0;
        int iw = 0, ih = 0;
        CHECK(sq_render_world_png(w, 320, 240, &o, &png, &len, &e) == 0);
        CHECK(png && sq_png_decode(png, len, &rgb, &iw, &ih, &e) == 0);
        if (rgb) {
            int n = count_lit(rgb, iw * ih, pc);
            printf("    probe pixels (%s): %d\n", pass == 0 ? "probes on" : "probes off", n);
            if (pass == 0)
                CHECK(n >= 10); /* a bead of 1.8 % of the diagonal, 7/8 of it inside the corner */
            else
                CHECK(n == 0);
        }
        free(png);
        free(rgb);
    }
#endif
    sq_render_state_free(&s);
    sq_world_destroy(w);
    sq_scene_free(sc);
}
