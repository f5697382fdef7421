/* cmd_render.c - squish render: headless PNG images of a scene (OSMesa).
 *
 *   squish render SCENE.json [--frames N] [--every K] [--size WxH] [--color level|plain|stress]
 *                 [--camera AZ,EL[,DIST] | EX,EY,EZ,TX,TY,TZ] [--out DIR]
 *   squish render --default ...
 *   squish render --bench [SCENE.json | --default] [--size WxH] ...
 *
 * Runs the scene with its tool keyframes and writes DIR/frame_00000.png, frame_00001.png, ...
 * (the state at frames 0, K, 2K, ... N). Same input -> byte-identical images on one machine.
 * Exit codes: 0 done, 1 bad scene or output error, 2 usage.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "app/commands.h"
#include "render/render.h"
#include "scene/scene.h"

#define BENCH_REPEATS 20 /* timed renders per stage in --bench */

static void usage(FILE *f)
{
    fprintf(f,
            "usage: squish render SCENE.json [options] --out DIR\n"
            "       squish render --default [options] --out DIR   (the built-in paper cube)\n"
            "       squish render --bench [SCENE.json | --default] [options]\n"
            "\n"
            "  --frames N        simulate N frames (default: the scene's \"duration\")\n"
            "  --every K         write an image every K frames (default 1); images are the\n"
            "                    states at frames 0, K, 2K, ... up to N, named frame_00000.png,\n"
            "                    frame_00001.png, ... in order\n"
            "  --size WxH        image size in pixels, each side %d..%d (default 800x600)\n"
            "  --color MODE      level (colour by active level of detail, default), plain, or\n"
            "                    stress (|displacement| on a blue-yellow-red ramp)\n"
            "  --stress-max M    stress mode: |displacement| in metres at the red end (default:\n"
            "                    the largest value of each frame)\n"
            "  --camera SPEC     AZ,EL or AZ,EL,DIST (degrees around the bodies' centre, metres;\n"
            "                    default 30,20 framed to fit) or EX,EY,EZ,TX,TY,TZ (eye, target)\n"
            "  --palette FILE    colours (default: built in, equal to web/palette.json)\n"
            "  --supersample S   samples per pixel side, 1..4 (default 2; 1 is fastest)\n"
            "  --no-floor, --no-tools   leave the floor or the tools out\n"
            "  --no-probes              leave the scene's probes out (drawn as beads by default)\n"
            "  --no-obstacles           leave the scene's obstacles out (a floor plane among them)\n"
            "  --out DIR         output directory (default ./squish-render)\n"
            "  --bench           time the stages of one frame (after --frames, default 25) at\n"
            "                    --size; writes nothing unless --out is given\n",
            SQ_RENDER_MIN_SIZE, SQ_RENDER_MAX_SIZE);
}

static int usage_error(const char *fmt, const char *arg)
{
    fprintf(stderr, "squish render: ");
    fprintf(stderr, fmt, arg);
    fprintf(stderr, "\nrun 'squish render --help' for the options\n");
    return 2;
}

/* a whole number in [lo, hi]; 0 on success */
static int parse_long(const char *s, long lo, long hi, long *out)
{
    char *end;
    errno = 0;
    long v = strtol(s, &end, 10);
    if (end == s || *end || errno || v < lo || v > hi)
        return -1;
    *out = v;
    return 0;
}

/* one image: capture, build, draw, encode, write; times (s) added to t[4] */
static int render_one(sq_render_state *st, sq_drawlist *dl, sq_renderer *r, unsigned char *rgb,
                      const sq_world *w, const sq_render_opts *o, int width, int height,
                      const char *path, double t[4], sq_err *err)
{
    double t0 = sq_now();
    if (sq_render_state_capture(st, w, err))
        return -1;
    double t1 = sq_now();
    if (sq_drawlist_build(dl, st, o, (double)width / height, err))
        return -1;
    double t2 = sq_now();
    if (sq_renderer_draw(r, dl, rgb, err))
        return -1;
    double t3 = sq_now();
    unsigned char *png = NULL;
    size_t len = 0;
    if (sq_png_encode(rgb, width, height, &png, &len, err))
        return -1;
    double t4 = sq_now();
    int rc = path ? sq_png_write_file(path, png, len, err) : 0;
    free(png);
    t[0] += t1 - t0;
    t[1] += t2 - t1;
    t[2] += t3 - t2;
    t[3] += t4 - t3;
    return rc;
}

/* CPU time of the whole process (all threads, llvmpipe's included), s */
static double cpu_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* --bench: time each stage BENCH_REPEATS times on the world's current state */
static int bench(const sq_world *w, const sq_render_opts *o, int width, int height)
{
    sq_err err = {{0}};
    sq_render_state st;
    sq_render_state_init(&st);
    sq_drawlist dl = {0};
    unsigned char *rgb = sq_malloc((size_t)width * height * 3);
    double tc = sq_now();
    sq_renderer *r = sq_renderer_create(width, height, o->supersample, &err);
    tc = sq_now() - tc;
    int rc = r ? 0 : 1;
    double t[4] = {0, 0, 0, 0}, best = INFINITY, total = 0, cpu0 = cpu_now();
    for (int i = 0; i < BENCH_REPEATS && rc == 0; i++) {
        double before[4] = {t[0], t[1], t[2], t[3]}, s = 0;
        rc = render_one(&st, &dl, r, rgb, w, o, width, height, NULL, t, &err) ? 1 : 0;
        for (int k = 0; k < 4; k++)
            s += t[k] - before[k];
        best = fmin(best, s);
        total += s;
    }
    double cpu = cpu_now() - cpu0;
    /* the one-call snapshot path, context creation included */
    double one = INFINITY;
    for (int i = 0; i < 5 && rc == 0; i++) {
        unsigned char *png = NULL;
        size_t len = 0;
        double t0 = sq_now();
        rc = sq_render_state_png(&st, width, height, o, &png, &len, &err) ? 1 : 0;
        one = fmin(one, sq_now() - t0);
        free(png);
    }
    if (rc) {
        fprintf(stderr, "squish render: %s\n", err.msg);
    } else {
        long tris = 0;
        for (int b = 0; b < st.nbodies; b++)
            tris += st.bodies[b].ntris;
        double n = BENCH_REPEATS;
        printf("render bench: %dx%d, supersample %d, %s colours, %ld body triangles, %d drawn\n",
               width, height, o->supersample, sq_color_mode_name(o->color), tris, dl.ntris);
        printf("  context creation     %8.2f ms (once per renderer)\n", 1e3 * tc);
        printf("  capture              %8.2f ms\n", 1e3 * t[0] / n);
        printf("  draw list            %8.2f ms\n", 1e3 * t[1] / n);
        printf("  draw (OSMesa)        %8.2f ms\n", 1e3 * t[2] / n);
        printf("  png encode           %8.2f ms\n", 1e3 * t[3] / n);
        printf("  per frame            %8.2f ms mean, %.2f ms best (%d frames)\n", 1e3 * total / n,
               1e3 * best, BENCH_REPEATS);
        printf("  per frame, CPU time  %8.2f ms (all threads; less sensitive to other load)\n",
               1e3 * cpu / n);
        printf("  one-call snapshot    %8.2f ms best of 5 (new context each time)\n", 1e3 * one);
    }
    sq_renderer_destroy(r);
    sq_drawlist_free(&dl);
    sq_render_state_free(&st);
    free(rgb);
    return rc;
}

/* the command line */
typedef struct render_args {
    const char *scene_path, *out, *size;
    int use_default, do_bench;
    long frames, every;
    sq_render_opts o;
} render_args;

/* -1: go on; else the exit code (--help, a usage error, a palette that cannot be read) */
static int parse_args(int argc, char **argv, render_args *ra)
{
    sq_err err = {{0}};
    *ra = (render_args){NULL, NULL, "800x600", 0, 0, -1, 1, sq_render_opts_default()};
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *val = i + 1 < argc ? argv[i + 1] : NULL;
        long v;
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(a, "--default")) {
            ra->use_default = 1;
        } else if (!strcmp(a, "--bench")) {
            ra->do_bench = 1;
        } else if (!strcmp(a, "--no-floor")) {
            ra->o.floor = 0;
        } else if (!strcmp(a, "--no-tools")) {
            ra->o.tools = 0;
        } else if (!strcmp(a, "--no-probes")) {
            ra->o.probes = 0;
        } else if (!strcmp(a, "--no-obstacles")) {
            ra->o.obstacles = 0;
        } else if (!strcmp(a, "--frames")) {
            if (!val || parse_long(val, 0, 1000000000L, &v))
                return usage_error("--frames needs a whole number of frames (0 to 1e9), got '%s'",
                                   val ? val : "");
            ra->frames = v;
            i++;
        } else if (!strcmp(a, "--every")) {
            if (!val || parse_long(val, 1, 1000000000L, &v))
                return usage_error("--every needs a whole number >= 1, got '%s'", val ? val : "");
            ra->every = v;
            i++;
        } else if (!strcmp(a, "--supersample")) {
            if (!val || parse_long(val, 1, 4, &v))
                return usage_error("--supersample needs 1, 2, 3 or 4, got '%s'", val ? val : "");
            ra->o.supersample = (int)v;
            i++;
        } else if (!strcmp(a, "--size")) {
            if (!val)
                return usage_error("%s--size needs WxH, e.g. 800x600", "");
            ra->size = argv[++i];
        } else if (!strcmp(a, "--color") || !strcmp(a, "--colour")) {
            if (sq_color_mode_parse(val, &ra->o.color, &err))
                return usage_error("%s", err.msg);
            i++;
        } else if (!strcmp(a, "--stress-max")) {
            char *end;
            double m = val ? strtod(val, &end) : 0;
            if (!val || end == val || *end || !(m > 0) || !isfinite(m))
                return usage_error("--stress-max needs a displacement > 0 in metres, got '%s'",
                                   val ? val : "");
            ra->o.stress_max = m;
            i++;
        } else if (!strcmp(a, "--camera")) {
            if (sq_camera_parse(val, &ra->o.camera, &err))
                return usage_error("%s", err.msg);
            i++;
        } else if (!strcmp(a, "--palette")) {
            if (!val)
                return usage_error("%s--palette needs a file", "");
            if (sq_palette_load(&ra->o.palette, val, &err)) {
                fprintf(stderr, "squish render: %s\n", err.msg);
                return 1;
            }
            i++;
        } else if (!strcmp(a, "--out")) {
            if (!val || !val[0])
                return usage_error("%s--out needs a directory", "");
            ra->out = argv[++i];
        } else if (a[0] == '-') {
            return usage_error("unknown option '%s'", a);
        } else if (ra->scene_path) {
            return usage_error("more than one scene given ('%s'); render one scene at a time", a);
        } else {
            ra->scene_path = a;
        }
    }
    return -1;
}

/* --bench: the world stepped nframes, then the renderer's cost (bench) and DIR/bench.png */
static int render_bench(sq_world *w, const sq_scene *scene, long nframes, const sq_render_opts *o, int width,
                        int height, const char *out)
{
    sq_err err = {{0}};
    for (long f = 0; f < nframes; f++)
        sq_world_step(w, 0);
    printf("scene %s (%s) at frame %ld (t = %.3f s)\n", scene->name, scene->path, w->frame,
           w->time);
    int rc = bench(w, o, width, height);
    if (rc == 0 && out) {
        unsigned char *png = NULL;
        size_t len = 0;
        char path[1100];
        snprintf(path, sizeof path, "%s/bench.png", out);
        if (sq_render_world_png(w, SQ_MIN(width, SQ_SNAPSHOT_MAX_SIZE),
                                SQ_MIN(height, SQ_SNAPSHOT_MAX_SIZE), o, &png, &len, &err) ||
            sq_png_write_file(path, png, len, &err)) {
            fprintf(stderr, "squish render: %s\n", err.msg);
            rc = 1;
        } else {
            printf("wrote %s\n", path);
        }
        free(png);
    }
    return rc;
}

/* the sequence: DIR/frame_NNNNN.png every `every` frames from frame 0 to nframes */
static int render_sequence(sq_world *w, const sq_scene *scene, long nframes, long every, const sq_render_opts *o,
                           int width, int height, const char *out)
{
    sq_err err = {{0}};
    int rc = 0;
    /* the sequence: one renderer, state and draw list reused for every image */
    sq_renderer *r = sq_renderer_create(width, height, o->supersample, &err);
    if (!r) {
        fprintf(stderr, "squish render: %s\n", err.msg);
        return 1;
    }
    sq_render_state st;
    sq_render_state_init(&st);
    sq_drawlist dl = {0};
    unsigned char *rgb = sq_malloc((size_t)width * height * 3);
    long nimages = nframes / every + 1, written = 0;
    printf("scene %s (%s): %ld frames, %ld images %dx%d, %s colours -> %s/\n", scene->name,
           scene->path, nframes, nimages, width, height, sq_color_mode_name(o->color), out);
    fflush(stdout);
    sq_progress prog;
    sq_progress_begin(&prog, "squish render", (double)nframes);
    double t[4] = {0, 0, 0, 0}, wall0 = sq_now();
    for (;;) {
        if (w->frame % every == 0) {
            char path[1100];
            snprintf(path, sizeof path, "%s/frame_%05ld.png", out, written);
            if (render_one(&st, &dl, r, rgb, w, o, width, height, path, t, &err)) {
                if (prog.enabled)
                    fputc('\n', stderr);
                fprintf(stderr, "squish render: %s\n", err.msg);
                rc = 1;
                break;
            }
            written++;
        }
        if (w->frame >= nframes)
            break;
        sq_world_step(w, 0);
        sq_progress_update(&prog, (double)w->frame);
    }
    sq_progress_end(&prog);
    double wall = sq_now() - wall0;
    if (rc == 0) {
        double n = written > 0 ? (double)written : 1.0;
        printf("done: %ld images in %.3g s; per image %.1f ms (capture %.1f, draw list %.1f, draw %.1f, "
               "png %.1f)\n",
               written, wall, 1e3 * (t[0] + t[1] + t[2] + t[3]) / n, 1e3 * t[0] / n, 1e3 * t[1] / n,
               1e3 * t[2] / n, 1e3 * t[3] / n);
        printf("wrote %s/frame_00000.png .. frame_%05ld.png\n", out, written - 1);
    }
    free(rgb);
    sq_drawlist_free(&dl);
    sq_render_state_free(&st);
    sq_renderer_destroy(r);
    return rc;
}

int sq_cmd_render(int argc, char **argv)
{
    render_args ra;
    sq_err err = {{0}};
    int rc = parse_args(argc, argv, &ra);
    if (rc >= 0)
        return rc;
    const char *out = ra.out;
    int width, height;
    if (sq_render_parse_size(ra.size, SQ_RENDER_MAX_SIZE, &width, &height, &err))
        return usage_error("%s", err.msg);
    if (!ra.scene_path && !ra.use_default)
        return usage_error("%sno scene given; pass SCENE.json or --default", "");
    if (ra.scene_path && ra.use_default)
        return usage_error("%sgive either SCENE.json or --default, not both", "");
    if (!out && !ra.do_bench)
        out = "squish-render";

    /* scene and world */
    sq_scene *scene = ra.use_default ? sq_scene_default(&err) : sq_scene_load(ra.scene_path, &err);
    if (!scene) {
        fprintf(stderr, "squish render: %s\n", err.msg);
        return 1;
    }
    sq_world *w = sq_world_create(scene, &err);
    if (!w) {
        fprintf(stderr, "squish render: %s\n", err.msg);
        sq_scene_free(scene);
        return 1;
    }
    long nframes = ra.frames >= 0 ? ra.frames
                   : ra.do_bench  ? 25
                                  : (long)ceil(scene->duration * scene->frame_rate - 1e-9);
    if (nframes < 0)
        nframes = 0;

    if (out && sq_mkdir_p(out)) {
        fprintf(stderr, "squish render: cannot create output directory %s: %s; choose another --out\n",
                out, strerror(errno));
        rc = 1;
    } else if (ra.do_bench) {
        rc = render_bench(w, scene, nframes, &ra.o, width, height, out);
    } else {
        rc = render_sequence(w, scene, nframes, ra.every, &ra.o, width, height, out);
    }
    sq_world_destroy(w);
    sq_scene_free(scene);
    return rc;
}
