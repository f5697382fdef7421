/* test_render.c - render module: palette, option parsing, draw lists, PNG, and (outside the
 * sanitizer build, which must not create OSMesa contexts: they leak 16 bytes by design)
 * real OSMesa renders of a raw-array body. */
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "render/render.h"
#include "sq_test.h"
#include "test_render_helpers.h"

/* a box surface [0,1]^3 built from 6 faces of n x n quads (vertices not shared between faces),
 * counter-clockwise from outside; level of each vertex: 3 where x > 0.5, else 0 */
typedef struct test_box {
    int nverts, ntris;
    float *xyz;
    unsigned char *level;
    int *tris;
} test_box;

static test_box make_box(int n)
{
    test_box b;
    b.nverts = 6 * (n + 1) * (n + 1);
    b.ntris = 6 * 2 * n * n;
    b.xyz = malloc((size_t)b.nverts * 3 * sizeof(float));
    b.level = malloc((size_t)b.nverts);
    b.tris = malloc((size_t)b.ntris * 3 * sizeof(int));
    int v = 0, t = 0;
    for (int axis = 0; axis < 3; axis++)
        for (int side = 0; side < 2; side++) {
            int u = (axis + 1) % 3, w = (axis + 2) % 3, base = v;
            for (int i = 0; i <= n; i++)
                for (int j = 0; j <= n; j++) {
                    float p[3];
                    p[axis] = (float)side;
                    p[u] = (float)i / n;
                    p[w] = (float)j / n;
                    memcpy(&b.xyz[3 * v], p, sizeof p);
                    b.level[v] = p[0] > 0.5f ? 3 : 0;
                    v++;
                }
            for (int i = 0; i < n; i++)
                for (int j = 0; j < n; j++) {
                    int a = base + i * (n + 1) + j, c = a + n + 1;
                    /* (u, w) counter-clockwise is outward for side 1; flip for side 0 */
                    int q[4] = {a, c, c + 1, a + 1};
                    if (side == 0) {
                        int tmp = q[1];
                        q[1] = q[3];
                        q[3] = tmp;
                    }
                    int *tt = &b.tris[3 * t];
                    tt[0] = q[0], tt[1] = q[1], tt[2] = q[2];
                    tt[3] = q[0], tt[4] = q[2], tt[5] = q[3];
                    t += 2;
                }
        }
    return b;
}

static void free_box(test_box *b)
{
    free(b->xyz);
    free(b->level);
    free(b->tris);
}

static void box_state(sq_render_state *s, const test_box *b)
{
    sq_err e = {{0}};
    sq_render_state_init(s);
    CHECK(sq_render_state_add_body(s, b->nverts, b->xyz, NULL, b->level, b->ntris, b->tris, &e) == 0);
}

SQ_TEST(render_palette_default_matches_web_palette_json)
{
    /* the compiled-in palette is the one definition's copy: it must equal the file */
    char path[512];
    snprintf(path, sizeof path, "%s/../../web/palette.json", sq_test_data());
    sq_palette def, file;
    sq_palette_default(&def);
    memset(&file, 0, sizeof file);
    sq_err e = {{0}};
    CHECK(sq_palette_load(&file, path, &e) == 0);
    CHECK(memcmp(&def, &file, sizeof def) == 0);
    CHECK_NEAR(def.level[0][0], 0x4e / 255.0, 1e-6);
}

SQ_TEST(render_palette_errors_name_the_key)
{
    sq_palette p;
    sq_palette_default(&p);
    sq_err e = {{0}};
    CHECK(sq_palette_parse(&p, "{\"flor\": \"#000000\"}", "pal.json", &e) == -1);
    CHECK_CONTAINS(e.msg, "pal.json: flor: unknown key");
    CHECK(sq_palette_parse(&p, "{\"floor\": \"#00000\"}", "pal.json", &e) == -1);
    CHECK_CONTAINS(e.msg, "floor: must be a colour");
    CHECK(sq_palette_parse(&p, "{\"level\": [\"#000000\", 3]}", "pal.json", &e) == -1);
    CHECK_CONTAINS(e.msg, "level[1]");
    CHECK(sq_palette_parse(&p, "{\"level\": [", "pal.json", &e) == -1);
    CHECK_CONTAINS(e.msg, "not valid JSON");
    /* a partial palette overrides only its keys */
    CHECK(sq_palette_parse(&p, "{\"tool\": \"#ff0000\"}", "pal.json", &e) == 0);
    CHECK_NEAR(p.tool[0], 1.0, 1e-6);
    CHECK_NEAR(p.tool[1], 0.0, 1e-6);
}

SQ_TEST(render_parse_size)
{
    int w = 0, h = 0;
    sq_err e = {{0}};
    CHECK(sq_render_parse_size("800x600", 2048, &w, &h, &e) == 0);
    CHECK(w == 800 && h == 600);
    const char *bad[] = {"", "800", "800x", "x600", "800x600x2", "abcxdef", "0x600",
                         "15x600", "800x-1", "4097x100", "99999999999999999999x10"};
    for (size_t i = 0; i < SQ_COUNTOF(bad); i++) {
        e.msg[0] = 0;
        CHECK(sq_render_parse_size(bad[i], 4096, &w, &h, &e) == -1);
        CHECK(e.msg[0] != 0);
    }
    CHECK(sq_render_parse_size("3000x100", 2048, &w, &h, &e) == -1);
    CHECK_CONTAINS(e.msg, "[16, 2048]");
}

SQ_TEST(render_parse_camera_and_colour)
{
    sq_camera c = sq_camera_default();
    sq_err e = {{0}};
    CHECK(sq_camera_parse("45,30", &c, &e) == 0);
    CHECK(c.eye_target == 0 && c.az_deg == 45 && c.el_deg == 30 && c.dist == 0);
    CHECK(sq_camera_parse("-10,5,2.5", &c, &e) == 0);
    CHECK(c.dist == 2.5);
    CHECK(sq_camera_parse("3,0,1,0,0,0.5", &c, &e) == 0);
    CHECK(c.eye_target == 1 && c.eye[0] == 3 && c.target[2] == 0.5);
    CHECK(sq_camera_parse("1,2,3,4", &c, &e) == -1);
    CHECK_CONTAINS(e.msg, "AZ,EL");
    CHECK(sq_camera_parse("10,95", &c, &e) == -1);
    CHECK(sq_camera_parse("10,20,-1", &c, &e) == -1);
    CHECK(sq_camera_parse("1,1,1,1,1,1", &c, &e) == -1);
    CHECK(sq_camera_parse("nan,1", &c, &e) == -1);
    sq_color_mode m;
    CHECK(sq_color_mode_parse("stress", &m, &e) == 0 && m == SQ_COLOR_STRESS);
    CHECK(sq_color_mode_parse("levels", &m, &e) == -1);
    CHECK_CONTAINS(e.msg, "level, plain or stress");
}

SQ_TEST(render_state_rejects_bad_indices)
{
    sq_render_state s;
    sq_render_state_init(&s);
    float xyz[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    int tris[3] = {0, 1, 3};
    sq_err e = {{0}};
    CHECK(sq_render_state_add_body(&s, 3, xyz, NULL, NULL, 1, tris, &e) == -1);
    CHECK_CONTAINS(e.msg, "triangle 0 uses vertex 3");
    CHECK(s.nbodies == 0);
    float nan_rest[9] = {0, 0, 0, NAN, 0, 0, 0, 1, 0};
    tris[2] = 2;
    CHECK(sq_render_state_add_body(&s, 3, xyz, nan_rest, NULL, 1, tris, &e) == -1);
    CHECK_CONTAINS(e.msg, "vertex 1");
    CHECK(sq_render_state_add_body(&s, 3, xyz, NULL, NULL, 1, tris, &e) == 0);
    CHECK(s.nbodies == 1);
    CHECK(s.bbox_max[0] == 1 && s.bbox_min[2] == 0);
    double g[3] = {0, -9.81, 0};
    sq_render_state_set_gravity(&s, g);
    CHECK_NEAR(s.up[1], 1.0, 1e-12);
    sq_render_state_free(&s);
}

SQ_TEST(render_drawlist_body_floor_tools_and_framing)
{
    test_box b = make_box(4);
    sq_render_state s;
    box_state(&s, &b);
    sq_tool sphere = {.id = 1, .shape = SQ_TOOL_SPHERE, .active = 1, .pos = {0.5, 0.5, 1.2}, .radius = 0.15};
    sq_tool box = {.id = 2, .shape = SQ_TOOL_BOX, .active = 0, .pos = {2, 0, 0}, .half = {0.1, 0.1, 0.1}};
    sq_err e = {{0}};
    CHECK(sq_render_state_add_tool(&s, &sphere, &e) == 0);
    CHECK(sq_render_state_add_tool(&s, &box, &e) == 0);
    sq_render_opts o = sq_render_opts_default();
    sq_drawlist dl = {0};
    CHECK(sq_drawlist_build(&dl, &s, &o, 4.0 / 3.0, &e) == 0);
    /* bodies first, then 12 x 12 floor tiles (2 triangles each), then tools */
    CHECK(dl.body_tris == b.ntris);
    CHECK(dl.ntris == b.ntris + 2 * 144 + 2 * 12 * 24 + 12);
    CHECK(dl.skipped_tris == 0);

    /* normals are unit; level colours are exactly the palette's */
    unsigned char c0[3], c3[3];
    sq_render_level_rgb(&o.palette, 0, c0);
    sq_render_level_rgb(&o.palette, 3, c3);
    int n0 = 0, n3 = 0, bad_normal = 0;
    for (int i = 0; i < 3 * dl.body_tris; i++) {
        const sq_draw_vertex *v = &dl.v[dl.idx[i]];
        double len = sqrt(v->normal[0] * v->normal[0] + v->normal[1] * v->normal[1] +
                          v->normal[2] * v->normal[2]);
        bad_normal += fabs(len - 1.0) > 1e-5;
        n0 += !memcmp(v->rgba, c0, 3);
        n3 += !memcmp(v->rgba, c3, 3);
    }
    CHECK(bad_normal == 0);
    CHECK(n0 > 0 && n3 > 0);
    CHECK(n0 + n3 == 3 * dl.body_tris);

    /* a flat face keeps its face normal at the box edges (crease angle) */
    const sq_draw_vertex *top = NULL;
    for (int i = 0; i < 3 * dl.body_tris && !top; i++) {
        const sq_draw_vertex *v = &dl.v[dl.idx[i]];
        if (v->pos[2] == 1.0f && v->pos[0] == 0.0f && v->pos[1] == 0.0f && v->normal[2] > 0.5f)
            top = v;
    }
    CHECK(top != NULL);
    if (top)
        CHECK_NEAR(top->normal[2], 1.0, 1e-6);

    /* framed: every body vertex lies inside the view frustum with a margin */
    double f[3], len = 0;
    for (int k = 0; k < 3; k++)
        f[k] = dl.target[k] - dl.eye[k], len += f[k] * f[k];
    len = sqrt(len);
    for (int k = 0; k < 3; k++)
        f[k] /= len;
    double r[3] = {f[1] * dl.up[2] - f[2] * dl.up[1], f[2] * dl.up[0] - f[0] * dl.up[2],
                   f[0] * dl.up[1] - f[1] * dl.up[0]};
    double rl = sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]);
    double u[3] = {r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]};
    double t = tan(0.5 * dl.fovy_deg * M_PI / 180.0), worst = 0;
    for (int i = 0; i < b.nverts; i++) {
        double p[3];
        for (int k = 0; k < 3; k++)
            p[k] = b.xyz[3 * i + k] - dl.eye[k];
        double z = p[0] * f[0] + p[1] * f[1] + p[2] * f[2];
        double x = (p[0] * r[0] + p[1] * r[1] + p[2] * r[2]) / rl / (z * t * 4.0 / 3.0);
        double y = (p[0] * u[0] + p[1] * u[1] + p[2] * u[2]) / rl / (z * t);
        CHECK(z > dl.znear && z < dl.zfar);
        worst = fmax(worst, fmax(fabs(x), fabs(y)));
    }
    /* the bounding sphere fit leaves room: the box fills 40-95% of the narrower side */
    CHECK(worst < 0.95 && worst > 0.4);
    sq_drawlist_free(&dl);
    sq_render_state_free(&s);
    free_box(&b);
}

SQ_TEST(render_drawlist_stress_and_nonfinite)
{
    test_box b = make_box(2);
    sq_render_state s;
    box_state(&s, &b);
    /* displace one vertex by 0.2 m; poison another (its triangles are skipped) */
    sq_render_body *rb = &s.bodies[0];
    rb->xyz[2] += 0.2f;
    rb->xyz[3 * 10] = NAN;
    sq_render_opts o = sq_render_opts_default();
    o.color = SQ_COLOR_STRESS;
    o.floor = 0;
    sq_drawlist dl = {0};
    sq_err e = {{0}};
    CHECK(sq_drawlist_build(&dl, &s, &o, 1.0, &e) == 0);
    CHECK(dl.skipped_tris > 0);
    CHECK(dl.body_tris == b.ntris - dl.skipped_tris);
    CHECK_NEAR(dl.stress_scale, 0.2, 1e-6);
    unsigned char lo[3] = {0x2c, 0x7b, 0xb6}, hi[3] = {0xd7, 0x19, 0x1c};
    int nlo = 0, nhi = 0;
    for (int i = 0; i < dl.nverts; i++) {
        nlo += !memcmp(dl.v[i].rgba, lo, 3);
        nhi += !memcmp(dl.v[i].rgba, hi, 3);
        CHECK(isfinite(dl.v[i].pos[0]) && isfinite(dl.v[i].normal[0]));
    }
    CHECK(nhi >= 1);
    CHECK(nlo > nhi);
    /* a fixed scale of 0.4 m puts the 0.2 m vertex at mid-ramp */
    o.stress_max = 0.4;
    CHECK(sq_drawlist_build(&dl, &s, &o, 1.0, &e) == 0);
    int nmid = 0;
    for (int i = 0; i < dl.nverts; i++)
        nmid += dl.v[i].rgba[0] == 0xff && dl.v[i].rgba[1] == 0xff && dl.v[i].rgba[2] == 0xbf;
    CHECK(nmid >= 1);
    sq_drawlist_free(&dl);
    sq_render_state_free(&s);
    free_box(&b);
}

SQ_TEST(render_png_roundtrip)
{
    int w = 37, h = 23;
    unsigned char *rgb = malloc((size_t)w * h * 3);
    for (int i = 0; i < w * h * 3; i++)
        rgb[i] = (unsigned char)(i * 7 + i / 3);
    unsigned char *png = NULL, *back = NULL;
    size_t len = 0;
    sq_err e = {{0}};
    CHECK(sq_png_encode(rgb, w, h, &png, &len, &e) == 0);
    CHECK(len > 8 && !memcmp(png, "\x89PNG\r\n\x1a\n", 8));
    int bw = 0, bh = 0;
    CHECK(sq_png_decode(png, len, &back, &bw, &bh, &e) == 0);
    CHECK(bw == w && bh == h);
    CHECK(back && !memcmp(back, rgb, (size_t)w * h * 3));
    /* a truncated file is an error, not a crash */
    free(back);
    back = NULL;
    CHECK(sq_png_decode(png, len / 2, &back, &bw, &bh, &e) == -1);
    CHECK(e.msg[0] != 0);
    char path[512];
    snprintf(path, sizeof path, "/nonexistent-dir/x.png");
    CHECK(sq_png_write_file(path, png, len, &e) == -1);
    CHECK_CONTAINS(e.msg, "/nonexistent-dir/x.png");
    free(png);
    free(back);
    free(rgb);
}

#if !defined(__SANITIZE_ADDRESS__)
SQ_TEST(render_osmesa_box_levels_size_and_determinism)
{
    test_box b = make_box(8);
    sq_render_state s;
    box_state(&s, &b);
    sq_render_opts o = sq_render_opts_default();
    unsigned char *png1 = NULL, *png2 = NULL, *rgb = NULL;
    size_t len1 = 0, len2 = 0;
    sq_err e = {{0}};
    CHECK(sq_render_state_png(&s, 160, 120, &o, &png1, &len1, &e) == 0);
    CHECK(sq_render_state_png(&s, 160, 120, &o, &png2, &len2, &e) == 0);
    /* byte-identical across two renders */
    CHECK(len1 == len2 && png1 && png2 && !memcmp(png1, png2, len1));
    int w = 0, h = 0;
    CHECK(sq_png_decode(png1, len1, &rgb, &w, &h, &e) == 0);
    CHECK(w == 160 && h == 120);
    if (rgb) {
        /* not blank: the body and floor cover well over 10% of the image */
        unsigned char bg[3] = {0x20, 0x24, 0x2b};
        int n = w * h, non_bg = 0;
        for (int i = 0; i < n; i++)
            non_bg += memcmp(&rgb[3 * i], bg, 3) != 0;
        CHECK(non_bg > n / 10);
        /* both level colours of the body are visible (each > 2% of the pixels) */
        unsigned char c0[3], c3[3], c5[3];
        sq_render_level_rgb(&o.palette, 0, c0);
        sq_render_level_rgb(&o.palette, 3, c3);
        sq_render_level_rgb(&o.palette, 5, c5);
        CHECK(count_lit(rgb, n, c0) > n / 50);
        CHECK(count_lit(rgb, n, c3) > n / 50);
        /* and a level that is not there is not found */
        CHECK(count_lit(rgb, n, c5) < n / 500);
    }
    free(rgb);
    free(png1);
    free(png2);

    /* plain mode: no level colours; a different size is honoured */
    o.color = SQ_COLOR_PLAIN;
    CHECK(sq_render_state_png(&s, 64, 200, &o, &png1, &len1, &e) == 0);
    CHECK(sq_png_decode(png1, len1, &rgb, &w, &h, &e) == 0);
    CHECK(w == 64 && h == 200);
    if (rgb) {
        unsigned char c3[3];
        sq_render_level_rgb(&o.palette, 3, c3);
        CHECK(count_lit(rgb, w * h, c3) < w * h / 500);
    }
    free(rgb);
    free(png1);
    sq_render_state_free(&s);
    free_box(&b);
}

/* one render on its own thread (the server renders snapshots off the simulation thread) */
typedef struct render_job {
    const sq_render_state *s;
    unsigned char *png;
    size_t len;
    int rc;
} render_job;

static void *render_thread(void *arg)
{
    render_job *j = arg;
    sq_err e = {{0}};
    j->rc = sq_render_state_png(j->s, 96, 64, NULL, &j->png, &j->len, &e);
    return NULL;
}

SQ_TEST(render_osmesa_threads_give_identical_images)
{
    test_box b = make_box(4);
    sq_render_state s;
    box_state(&s, &b);
    render_job jobs[3];
    pthread_t th[3];
    for (int i = 0; i < 3; i++) {
        jobs[i] = (render_job){.s = &s};
        CHECK(pthread_create(&th[i], NULL, render_thread, &jobs[i]) == 0);
    }
    for (int i = 0; i < 3; i++)
        pthread_join(th[i], NULL);
    for (int i = 0; i < 3; i++) {
        CHECK(jobs[i].rc == 0 && jobs[i].png != NULL);
        CHECK(jobs[i].len == jobs[0].len);
        if (jobs[i].png && jobs[0].png && jobs[i].len == jobs[0].len)
            CHECK(!memcmp(jobs[i].png, jobs[0].png, jobs[0].len));
    }
    for (int i = 0; i < 3; i++)
        free(jobs[i].png);
    sq_render_state_free(&s);
    free_box(&b);
}

SQ_TEST(render_osmesa_bad_size_is_an_error)
{
    sq_render_state s;
    sq_render_state_init(&s);
    unsigned char *png = NULL;
    size_t len = 0;
    sq_err e = {{0}};
    CHECK(sq_render_state_png(&s, 8, 600, NULL, &png, &len, &e) == -1);
    CHECK_CONTAINS(e.msg, "8x600");
    CHECK(png == NULL);
    CHECK(sq_render_state_png(&s, 5000, 600, NULL, &png, &len, &e) == -1);
    /* an empty scene still renders (floor only) */
    CHECK(sq_render_state_png(&s, 32, 32, NULL, &png, &len, &e) == 0);
    free(png);
}
#endif
