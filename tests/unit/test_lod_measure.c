/* test_lod_measure.c - the speed/accuracy trade of the adaptive levels on the shipped poke
 * scenes: node updates per simulated second and the rendered surface's error against the
 * fixed finest run, for each fixed level and several split thresholds.
 *
 * In the suite it runs the first second of cube-poke and checks the ordering that makes the
 * method worth having. The full table of docs/lod.md (both scenes, whole duration):
 *     SQ_LOD_MEASURE=1 build-X/unit_tests lod_measure
 */
#include <stdlib.h>
#include <string.h>

#include "lod/lod.h"
#include "scene/scene.h"
#include "sq_test.h"
#include "test_scene_helpers.h"

typedef struct run_result {
    double updates_per_s;  /* node updates per simulated second */
    double rms, max;       /* surface error against the reference, m */
    double mean_ms;        /* wall compute time per frame, ms */
    double stage_ms[4];    /* pull, integrate, push, adapt per frame, ms */
    int peak_active[SQ_MAX_LEVELS];
} run_result;

/* run scene with body 0's lod replaced; surface positions of every frame into `surf` (frames
 * x nsurf x 3) when recording, else compared with `ref` */
static int run_variant(sq_scene *sc, const sq_lod_def *lod, int frames, float *ref, int record,
                       run_result *out)
{
    sq_lod_def keep = sc->bodies[0].lod;
    sc->bodies[0].lod = *lod;
    sq_err e = {{0}};
    sq_world *w = sq_world_create(sc, &e);
    sc->bodies[0].lod = keep;
    if (!w) {
        fprintf(stderr, "world: %s\n", e.msg);
        return -1;
    }
    const sq_mesh *sm = sq_body_surface_mesh(w->bodies[0]);
    int ns = sm->nsurf;
    float *xyz = malloc(sizeof(float) * 3 * ns);
    double se = 0, me = 0, t_ms = 0;
    long updates = 0, count = 0;
    memset(out, 0, sizeof(*out));
    for (int f = 0; f < frames; f++) {
        sq_world_step(w, 0);
        const sq_frame_profile *p = &w->profile[0];
        updates += p->node_updates;
        t_ms += 1e3 * p->t_total;
        out->stage_ms[0] += 1e3 * p->t_pull / frames;
        out->stage_ms[1] += 1e3 * p->t_integrate / frames;
        out->stage_ms[2] += 1e3 * p->t_push / frames;
        out->stage_ms[3] += 1e3 * p->t_adapt / frames;
        for (int k = 0; k < SQ_MAX_LEVELS; k++)
            out->peak_active[k] = SQ_MAX(out->peak_active[k], p->active[k]);
        sq_body_surface_state(w->bodies[0], xyz, NULL);
        float *r = ref + (size_t)f * 3 * ns;
        if (record) {
            memcpy(r, xyz, sizeof(float) * 3 * ns);
            continue;
        }
        for (int s = 0; s < ns; s++) {
            double d2 = 0;
            for (int c = 0; c < 3; c++) {
                double d = (double)xyz[3 * s + c] - (double)r[3 * s + c];
                d2 += d * d;
            }
            se += d2;
            me = fmax(me, sqrt(d2));
            count++;
        }
    }
    double seconds = frames / sc->frame_rate;
    out->updates_per_s = updates / seconds;
    out->rms = count ? sqrt(se / count) : 0;
    out->max = me;
    out->mean_ms = t_ms / frames;
    free(xyz);
    sq_world_destroy(w);
    return 0;
}

/* the table for one scene; checks the ordering when `check` */
static void measure_scene(const char *name, double seconds, const double *splits, int nsplits, int check)
{
    sq_scene *sc = th_shipped_scene(name);
    CHECK(sc != NULL);
    if (!sc)
        return;
    sq_err e = {{0}};
    int frames = (int)(seconds * sc->frame_rate + 0.5);
    sq_lod_def base = sc->bodies[0].lod;
    int nl = SQ_MIN(sc->bodies[0].nlevels, base.max_level + 1);
    int fine = nl - 1;
    sq_body *probe_body = NULL;
    (void)probe_body;
    /* reference: the fixed finest run */
    sq_lod_def d = base;
    d.mode = SQ_LOD_FIXED;
    d.level = fine;
    int nsurf = 0;
    {
        sq_world *w = sq_world_create(sc, &e);
        CHECK(w != NULL);
        if (!w) {
            sq_scene_free(sc);
            return;
        }
        nsurf = sq_body_surface_mesh(w->bodies[0])->nsurf;
        sq_world_destroy(w);
    }
    float *ref = malloc(sizeof(float) * 3 * (size_t)nsurf * (size_t)frames);
    run_result rf, r;
    CHECK(run_variant(sc, &d, frames, ref, 1, &rf) == 0);
    fprintf(stderr, "\n%s, %.1f s (%d frames), surface of level %d (%d vertices)\n", name, seconds, frames,
            fine, nsurf);
    fprintf(stderr, "  %-28s %14s %11s %11s %9s  %s\n", "run", "updates/s", "rms (mm)", "max (mm)", "ms/frame",
            "peak active per level");
    run_result fixed[SQ_MAX_LEVELS];
    for (int k = 0; k <= fine; k++) {
        d = base;
        d.mode = SQ_LOD_FIXED;
        d.level = k;
        run_variant(sc, &d, frames, ref, 0, &fixed[k]);
        fprintf(stderr, "  fixed level %-16d %14.0f %11.3f %11.3f %9.2f\n", k, fixed[k].updates_per_s,
                1e3 * fixed[k].rms, 1e3 * fixed[k].max, fixed[k].mean_ms);
    }
    for (int i = 0; i < nsplits; i++) {
        d = base;
        d.mode = SQ_LOD_ADAPTIVE;
        d.level = 0;
        d.split = splits[i];
        d.merge = splits[i] * (base.merge / base.split);
        run_variant(sc, &d, frames, ref, 0, &r);
        char label[64];
        snprintf(label, sizeof label, "adaptive split %g merge %g", d.split, d.merge);
        fprintf(stderr, "  %-28s %14.0f %11.3f %11.3f %9.2f  ", label, r.updates_per_s, 1e3 * r.rms, 1e3 * r.max,
                r.mean_ms);
        for (int k = 0; k <= fine; k++)
            fprintf(stderr, "%d%s", r.peak_active[k], k < fine ? " / " : "");
        fprintf(stderr, "  (ms: ghosts %.2f, integrate %.2f, end-of-frame ghosts %.2f, adapt %.2f)\n",
                r.stage_ms[0], r.stage_ms[1], r.stage_ms[2], r.stage_ms[3]);
        if (check && i == 0) {
            /* the adaptive run sits between the fixed coarsest and the fixed finest: more
             * accurate than level 0, cheaper than the finest */
            CHECK(r.rms < fixed[0].rms);
            CHECK(r.updates_per_s < fixed[fine].updates_per_s);
        }
    }
    free(ref);
    sq_scene_free(sc);
}

SQ_TEST(lod_measure_tradeoff)
{
    int full = getenv("SQ_LOD_MEASURE") != NULL;
    if (!full) {
        /* the scene's own threshold over the pressing second of the poke */
        double s[1] = {0.005};
        measure_scene("cube-poke", 1.0, s, 1, 1);
        return;
    }
    double cube[] = {0.005, 0.01, 0.02, 0.04};
    measure_scene("cube-poke", 4.0, cube, 4, 1);
    double organ[] = {0.005, 0.01, 0.02, 0.04};
    measure_scene("organ", 4.0, organ, 4, 0);
}
