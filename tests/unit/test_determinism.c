/* test_determinism.c - pins a hash of the simulated state of every shipped scene.
 *
 * Each shipped scene (the .json files of meshes/scenes) runs a fixed number of frames with its scripted
 * tools and no wall-clock budget (sq_world_step(w, 0): splitting never depends on timing);
 * then a 64-bit FNV-1a hash is taken over the bytes of every loaded level's displacement and
 * velocity of every body, and of the simulated time. A scene whose bodies are adaptive is
 * also run with every body fixed at its finest loaded level. The hashes are compared with
 * the table below, so "no change of behaviour" is checked by the suite, not by eye: a
 * refactor must leave them as they are, and a change that alters the physics on purpose
 * re-pins them in the same commit, saying why.
 *
 * Build flags change the hash: the optimised build (-O3 -march=x86-64-v3) runs the AVX2+FMA
 * step kernel of server/level/level.c, the sanitizer build (-O1, no -march) the scalar one,
 * whose sums round differently, so each has its own table. Both builds use the ISO C default
 * -ffp-contract=off outside the intrinsics; a compiler that contracts a*b+c into FMA on its
 * own, -ffast-math, or another -march would change them too.
 *
 * To re-pin: SQ_DETERMINISM_PRINT=1 build/unit_tests determinism (and the same with
 * build/san/unit_tests) prints the table rows.
 */
#include <dirent.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scene/scene.h"
#include "sq_test.h"
#include "test_scene_helpers.h"

#define DET_FRAMES 40
/* cube-poke's sphere first holds nodes in frame 44 and lets go after frame 77 (`squish run`'s
 * tools.csv): 40 frames hashed only its approach. It runs 100, which cover the press, the hold,
 * the release and the first merges back (about 0.1 s more in the optimised build). */
#define DET_FRAMES_CUBE_POKE 100

static int det_frames(const char *name)
{
    return strcmp(name, "cube-poke") == 0 ? DET_FRAMES_CUBE_POKE : DET_FRAMES;
}
#define DET_MAX_FIXED_NODES 50000 /* the "fixed" mode is skipped above this finest level size */

typedef struct det_pin {
    const char *scene;
    const char *mode;      /* "scene": as the file says; "fixed": every body at its finest loaded level */
    uint64_t hash;
} det_pin;

#if defined(__AVX2__) && defined(__FMA__)
static const det_pin pins[] = {
    {"beam", "scene", 0x3d292a04cd0a2813ull},
    {"box-big", "scene", 0xf97ce5a48eef9d91ull}, /* only once `make meshes` has made its meshes */
    {"column", "scene", 0x2655479d8adb8706ull},
    {"cube-poke", "scene", 0x7f69eaa33d71a5c7ull},
    {"cube-poke", "fixed", 0x32f23f55dfa8617dull},
    {"organ", "scene", 0xd0a49bcc32ec2f54ull},
    {"organ", "fixed", 0xdce4ff797d752cd3ull},
    {"paper-cube", "scene", 0x496e9643d07c487full},
    {"sphere-grab", "scene", 0x6db7e82fd34177ccull},
    {"jelly-drop", "scene", 0x304a9b51a76ef039ull},
    {"organ-tray", "scene", 0xf30cfb0f60b7337dull},
    {"squeeze", "scene", 0xfdb41d4bfd3b625eull},
};
#else
static const det_pin pins[] = {
    {"beam", "scene", 0xe117e2774e2b932eull},
    {"box-big", "scene", 0x219958bbe459e845ull}, /* only once `make meshes` has made its meshes */
    {"column", "scene", 0x20c81c236dd2af9full},
    {"cube-poke", "scene", 0x224bec84d974c1cdull},
    {"cube-poke", "fixed", 0x696853e837d85319ull},
    {"organ", "scene", 0x03e2e0e0ebf37354ull},
    {"organ", "fixed", 0xaf01e98ce32a5dfaull},
    {"paper-cube", "scene", 0x60a12bacd6867c62ull},
    {"sphere-grab", "scene", 0x11163f0684736a2bull},
    {"jelly-drop", "scene", 0xc62ce1956859bac2ull},
    {"organ-tray", "scene", 0x0d97b942aebe7c83ull},
    {"squeeze", "scene", 0x0b50f8c39c1dc775ull},
};
#endif

static uint64_t fnv1a(uint64_t h, const void *p, size_t n)
{
    const unsigned char *b = p;
    for (size_t i = 0; i < n; i++) {
        h ^= b[i];
        h *= 0x100000001b3ull;
    }
    return h;
}

/* run the scene for `frames` frames and hash its state; 0 and a message on failure */
static uint64_t run_and_hash(const char *path, int frames, int force_fixed, int *skipped)
{
    sq_err e = {{0}};
    *skipped = 0;
    sq_scene *sc = sq_scene_load(path, &e);
    if (!sc && strstr(e.msg, SQ_SCENE_MESHES_NOT_MADE)) {
        /* a scene whose meshes `make meshes` generates (box-big), in a tree where it has not run */
        if (!force_fixed)
            fprintf(stderr, "determinism: skipping %s: %s\n", path, e.msg);
        *skipped = 1;
        return 0;
    }
    if (!sc) {
        sq_test_fail(__FILE__, __LINE__, "%s: %s", path, e.msg);
        return 0;
    }
    if (force_fixed) {
        int any = 0;
        for (int b = 0; b < sc->nbodies; b++) {
            /* a finest level too large to run fixed in the suite (box-big: 117,649 nodes at 128
             * substeps, 53 CPU s for these 40 frames: what its adaptive run exists to avoid) */
            if (sc->meshes[b][sc->bodies[b].nlevels - 1] &&
                sc->meshes[b][sc->bodies[b].nlevels - 1]->nnodes > DET_MAX_FIXED_NODES) {
                any = 0;
                break;
            }
            if (sc->bodies[b].lod.mode == SQ_LOD_ADAPTIVE) {
                sc->bodies[b].lod.mode = SQ_LOD_FIXED;
                sc->bodies[b].lod.level = sc->bodies[b].nlevels - 1;
                any = 1;
            }
        }
        if (!any) {
            *skipped = 1;
            sq_scene_free(sc);
            return 0;
        }
    }
    sq_world *w = sq_world_create(sc, &e);
    if (!w) {
        sq_test_fail(__FILE__, __LINE__, "%s: %s", path, e.msg);
        sq_scene_free(sc);
        return 0;
    }
    for (int f = 0; f < frames; f++)
        sq_world_step(w, 0);
    uint64_t h = 0xcbf29ce484222325ull;
    h = fnv1a(h, &w->time, sizeof w->time);
    for (int b = 0; b < sc->nbodies; b++) {
        const sq_body *body = w->bodies[b];
        for (int k = 0; k < sq_body_nlevels(body); k++) {
            const sq_mesh *m = sq_body_mesh(body, k);
            const double *d = sq_body_displacement(body, k);
            const double *v = sq_body_velocity(body, k);
            if (!m || !d || !v)
                continue;
            h = fnv1a(h, d, sizeof(double) * 3 * (size_t)m->nnodes);
            h = fnv1a(h, v, sizeof(double) * 3 * (size_t)m->nnodes);
        }
    }
    sq_world_destroy(w);
    sq_scene_free(sc);
    return h;
}

static int by_name(const void *a, const void *b)
{
    return strcmp(*(const char *const *)a, *(const char *const *)b);
}

SQ_TEST(determinism_shipped_scene_hashes)
{
    const char *dir = th_scenes_dir();
    DIR *dp = opendir(dir);
    CHECK(dp != NULL);
    if (!dp)
        return;
    char *names[64];
    int n = 0;
    struct dirent *de;
    while ((de = readdir(dp)) && n < 64) {
        size_t len = strlen(de->d_name);
        if (len > 5 && strcmp(de->d_name + len - 5, ".json") == 0)
            names[n++] = strndup(de->d_name, len - 5);
    }
    closedir(dp);
    qsort(names, (size_t)n, sizeof names[0], by_name);
    CHECK(n >= 6); /* the six scenes shipped when this test was written */

    int print = getenv("SQ_DETERMINISM_PRINT") != NULL;
    int npins = (int)(sizeof pins / sizeof pins[0]);
    int checked = 0;
    for (int i = 0; i < n; i++) {
        for (int fixed = 0; fixed <= 1; fixed++) {
            char path[1200];
            snprintf(path, sizeof path, "%s/%s.json", dir, names[i]);
            int skipped = 0;
            uint64_t h = run_and_hash(path, det_frames(names[i]), fixed, &skipped);
            if (skipped)
                continue;
            const char *mode = fixed ? "fixed" : "scene";
            if (print)
                printf("    {\"%s\", \"%s\", 0x%016llxull},\n", names[i], mode, (unsigned long long)h);
            const det_pin *pin = NULL;
            for (int p = 0; p < npins; p++)
                if (strcmp(pins[p].scene, names[i]) == 0 && strcmp(pins[p].mode, mode) == 0)
                    pin = &pins[p];
            if (!pin) {
                sq_test_fail(__FILE__, __LINE__, "%s (%s): no pinned hash (got 0x%016llx); add it to "
                             "the table in tests/unit/test_determinism.c", names[i], mode,
                             (unsigned long long)h);
                continue;
            }
            if (pin->hash != h)
                sq_test_fail(__FILE__, __LINE__, "%s (%s): state hash 0x%016llx after %d frames, pinned "
                             "0x%016llx: the simulation's behaviour changed; if on purpose, re-pin "
                             "(SQ_DETERMINISM_PRINT=1) and say why in the commit", names[i], mode,
                             (unsigned long long)h, det_frames(names[i]), (unsigned long long)pin->hash);
            checked++;
        }
    }
    CHECK(checked >= 8); /* six scenes, two of them adaptive, also run fixed */
    for (int i = 0; i < n; i++)
        free(names[i]);
}

/* the same scene run twice in one process gives the same hash: the state hashed is the
 * whole simulated state, and nothing outside it (wall clock, allocation addresses) leaks in */
SQ_TEST(determinism_same_run_twice)
{
    char path[1200];
    snprintf(path, sizeof path, "%s/cube-poke.json", th_scenes_dir());
    int s1 = 0, s2 = 0;
    uint64_t a = run_and_hash(path, DET_FRAMES_CUBE_POKE, 0, &s1);
    uint64_t b = run_and_hash(path, DET_FRAMES_CUBE_POKE, 0, &s2);
    CHECK(a != 0 && a == b);
}
