/* fuzz_scene.c - libFuzzer harness of the scene loader (server/scene/): parse the input
 * as a scene file whose mesh paths resolve in a directory of small real meshes (copied from
 * tests/data at start), then, if it loads, check it, create a world and step a few frames.
 * Never a crash, a leak or undefined behaviour; every refusal is a message naming the scene.
 *
 * Resource limits, so that one input cannot make one run take seconds: inputs with '/' or '\'
 * are skipped (mesh paths stay inside the directory, no /dev/zero), and frames are stepped
 * only while the world's work per frame (nodes x substeps over all loaded levels) is at most
 * FUZZ_MAX_WORK; a scene that asks for more is loaded and checked but not stepped. */
#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "scene/scene.h"
#include "body/body_internal.h"

#define FUZZ_MAX_WORK (1L << 16)
#define FUZZ_FRAMES 3

static char dir[256];

static void expect(int cond, const char *what)
{
    if (!cond) {
        fprintf(stderr, "fuzz_scene: check failed: %s\n", what);
        abort();
    }
}

static void copy(const char *from_dir, const char *name)
{
    char src[512], dst[512];
    snprintf(src, sizeof src, "%s/%s", from_dir, name);
    snprintf(dst, sizeof dst, "%s/%s", dir, name);
    FILE *in = fopen(src, "rb"), *out = fopen(dst, "wb");
    if (!in || !out) {
        fprintf(stderr, "fuzz_scene: cannot copy %s (set SQ_FUZZ_DATA to tests/data)\n", src);
        exit(1);
    }
    char buf[8192];
    size_t n;
    while ((n = fread(buf, 1, sizeof buf, in)) > 0)
        fwrite(buf, 1, n, out);
    fclose(in);
    fclose(out);
}

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc;
    (void)argv;
    const char *tmp = getenv("TMPDIR"), *data = getenv("SQ_FUZZ_DATA");
    if (!data)
        data = "tests/data";
    snprintf(dir, sizeof dir, "%s/squish-fuzz-scene-%d", tmp ? tmp : "/tmp", (int)getpid());
    mkdir(dir, 0700);
    char d[512];
    snprintf(d, sizeof d, "%s/scenes", data);
    copy(d, "cube_3.msh");
    snprintf(d, sizeof d, "%s/mesh", data);
    static const char *const meshes[] = {"cube_h1.msh", "cube_h1_v41.msh", "cube_h05_v41.msh",
                                         "cube_h1.mesh", "cube_tetgen.node", "cube_tetgen.ele"};
    for (size_t i = 0; i < sizeof meshes / sizeof *meshes; i++)
        copy(d, meshes[i]);
    return 0;
}

/* nodes x substeps of every loaded level of every body */
static long work_per_frame(const sq_world *w)
{
    long work = 0;
    for (int b = 0; b < w->nbodies; b++) {
        const sq_body *body = w->bodies[b];
        for (int k = 0; k < body->nuse; k++) {
            const sq_level *l = &body->level[k];
            if (l->substeps_log2 > 24)
                return LONG_MAX;
            work += (long)l->model.n << l->substeps_log2;
        }
    }
    return work;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (memchr(data, '/', size) || memchr(data, '\\', size))
        return 0;
    char *text = malloc(size + 1);
    memcpy(text, data, size);
    text[size] = 0;
    sq_err err = {{0}};
    sq_scene *s = sq_scene_parse(text, dir, "fuzz.json", &err);
    free(text);
    if (!s) {
        expect(!strncmp(err.msg, "fuzz.json", 9), "the error names the scene");
        return 0;
    }
    expect(s->nbodies >= 1 && s->nbodies <= SQ_MAX_BODIES, "body count");
    expect(s->frame_rate > 0 && isfinite(s->frame_rate), "frame rate");
    if (sq_scene_check(s, &err) == 0) {
        sq_world *w = sq_world_create(s, &err);
        expect(w != NULL, "a checked scene makes a world");
        if (w && work_per_frame(w) <= FUZZ_MAX_WORK) {
            for (int f = 0; f < FUZZ_FRAMES; f++)
                sq_world_step(w, 0.01);
            expect(w->frame == FUZZ_FRAMES, "frames stepped");
            for (int p = 0; p < s->nprobes; p++) {
                double u[3];
                if (sq_world_probe(w, p, u) == 0)
                    expect(isfinite(u[0]) && isfinite(u[1]) && isfinite(u[2]), "finite probe");
            }
            for (int b = 0; b < w->nbodies; b++) {
                const sq_mesh *sm = sq_body_surface_mesh(w->bodies[b]);
                float *xyz = malloc(3 * sizeof *xyz * (size_t)(sm->nsurf ? sm->nsurf : 1));
                unsigned char *lv = malloc((size_t)(sm->nsurf ? sm->nsurf : 1));
                sq_world_surface_state(w, b, xyz, lv);
                free(xyz);
                free(lv);
            }
        }
        sq_world_destroy(w);
    } else {
        expect(err.msg[0] != 0, "a check error has a message");
    }
    sq_scene_free(s);
    return 0;
}
