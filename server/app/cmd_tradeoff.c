/* cmd_tradeoff.c - squish tradeoff: the speed/accuracy trade of a scene (issue 7).
 *
 *   squish tradeoff SCENE.json [--out DIR] [--frames N] [--quick] [--finest K] [--reference-step F]
 *                              [--guarded N]
 *   squish tradeoff --bench [...]          (bench_scenes.c)
 *
 * Runs the scene, with its scripted tools, under a grid of settings: every fixed level, the
 * adaptive method at several split thresholds, both operators, several step fractions of the
 * stability bound. The reference is the finest level, fem operator, step fraction 0.25 (or F:
 * at 0.9 it is the fixed finest run itself, which is then not run twice: for scenes whose finest
 * level is too slow to run four times over).
 * Every variant is compared with it at the same points: the rest positions of the reference's
 * surface vertices (displacement interpolated in the variant's simulated level, so coarse
 * levels are compared where the user sees them) and the scene's probes, every frame.
 *
 * After the grid, N runs (default 3) of the scene's adaptive setting with the live budget (the
 * frame period as each frame's budget, the guard on, one thread: as `squish run --realtime` and
 * the server), measured the same way; not deterministic (the guard reads CPU time), so reported
 * as min / median / max, kept off the Pareto front and the equal-error headline, with the
 * aims of a scene that needs adaptivity counted per run.
 *
 * Writes DIR/tradeoff.csv, DIR/tradeoff.png (gnuplot: RMS surface error against node updates
 * per simulated second, Pareto front marked) and DIR/summary.txt (the adaptive speed-up at
 * equal error). Exit 0 done, 1 bad scene or output error, 2 usage.
 */
#include <cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "app/commands.h"
#include "app/tradeoff.h"
#include "scene/scene.h"
#include "body/body.h"
#include "net/net.h"

#define TO_MAX_VARIANTS 40
#define TO_MAX_GUARDED 15 /* --guarded runs at most */
#define TO_MAX_SAMPLES 4000 /* surface points compared per body (evenly strided) */

/* one setting of the grid */
typedef struct to_variant {
    char name[48];
    const char *kind;      /* reference, fixed, adaptive, step, operator */
    int adaptive;
    int level;             /* fixed: listed level index */
    double split;          /* adaptive: threshold (m); INFINITY = never split */
    sq_operator_kind op;
    double fraction;
    int implicit;          /* integrator rows: backward Euler at `substeps` steps a frame, CG to tol */
    int substeps;
    double tol;
} to_variant;

/* the cached reference's layout (SQ_TRADEOFF_REF): 2 adds the reference run's cost, so a fixed
 * row read from the cache keeps its CPU time (format 1 files are stepped and written again) */
#define REF_FILE_FORMAT 2L

typedef struct to_result {
    int ok;
    char error[300];
    long frames;
    double sim_s;
    double updates;        /* node updates in total */
    double wall;           /* s inside sq_world_step */
    double sum_sq;         /* sum over frames and samples of |u - u_ref|^2 */
    long count;
    double max_err, probe_err, final_rms, final_max;
    double rms, ups, wps;  /* RMS error (m), node updates and wall seconds per simulated second */
    double cpu;            /* thread CPU s inside sq_world_step */
    double cps;            /* thread CPU s per simulated second */
    double cpu_max1;       /* slowest frame after frame 1, thread CPU s (with a budget: step +
                            * publish, what the server's session thread does per frame) */
    long cpu_late1;        /* frames after frame 1 over the frame period in thread CPU time (same) */
    double cpu_pub;        /* with a budget: thread CPU s of publishing every frame (surface
                            * state and frame encoding, as `squish serve`), not in cpu */
    double cpu_smp;        /* thread CPU s of the error sampling (not the product's: kept out
                            * of the guard's time around the frame, sq_world_untimed) */
    int substeps_finest;   /* substeps per frame at the variant's finest simulated level, body 0 */
    long cg_iterations;    /* implicit rows: CG iterations of all frames and bodies */
    long resets;
    int pareto;
} to_result;

/* comparison points of one body: rest positions and, per variant, their location */
typedef struct to_samples {
    int n;
    double *x;             /* n x 3 */
    int *tet;              /* n */
    double *bary;          /* n x 4 */
} to_samples;

static void usage(FILE *f)
{
    fprintf(f,
            "usage: squish tradeoff SCENE.json [--out DIR] [--frames N] [--quick] [--finest K]\n"
            "                                  [--reference-step F] [--guarded N]\n"
            "       squish tradeoff --bench [--scenes DIR] [--frames N]\n"
            "\n"
            "  Runs the scene (its scripted tools included) under a grid of settings and measures\n"
            "  error against a reference (finest level, fem operator, step fraction 0.25) and cost.\n"
            "  --out DIR    output directory (default squish-tradeoff): tradeoff.csv, tradeoff.png,\n"
            "               summary.txt\n"
            "  --frames N   frames per run (default: the scene's duration)\n"
            "  --quick      a smaller grid (fixed levels, three thresholds, paper at the finest)\n"
            "  --finest K   listed level index used as the finest (default: each body's max_level)\n"
            "  --reference-step F  step fraction of the reference (default 0.25; 0.9: the fixed finest\n"
            "               run is the reference, for large scenes; the finer-step rows give its noise)\n"
            "  --guarded N  runs of the scene's adaptive setting with the live budget (the frame period,\n"
            "               the guard on, as 'squish run --realtime' and the server; not deterministic:\n"
            "               reported as min / median / max; default 3, 0: none, at most 15)\n"
            "  --bench      frame-budget headroom of the shipped scenes and 1 vs 2 threads\n");
}

static int usage_error(const char *msg, const char *arg)
{
    fprintf(stderr, "squish tradeoff: %s%s%s\nrun 'squish tradeoff --help' for the options\n", msg,
            arg ? " " : "", arg ? arg : "");
    return 2;
}

/* ---- scene variants through the scene's own JSON ------------------------------------------ */

static void set_item(cJSON *obj, const char *key, cJSON *val)
{
    if (cJSON_GetObjectItemCaseSensitive(obj, key))
        cJSON_ReplaceItemInObjectCaseSensitive(obj, key, val);
    else
        cJSON_AddItemToObject(obj, key, val);
}

/* the finest listed level each body uses: its lod.max_level, or the last listed level */
static int body_finest(const cJSON *body, int override)
{
    const cJSON *levels = cJSON_GetObjectItemCaseSensitive(body, "levels");
    int n = cJSON_IsArray(levels) ? cJSON_GetArraySize(levels) : 1;
    if (override >= 0)
        return SQ_MIN(override, n - 1);
    const cJSON *lod = cJSON_GetObjectItemCaseSensitive(body, "lod");
    const cJSON *ml = lod ? cJSON_GetObjectItemCaseSensitive(lod, "max_level") : NULL;
    if (cJSON_IsNumber(ml) && ml->valuedouble >= 0 && ml->valuedouble < n)
        return (int)ml->valuedouble;
    return n - 1;
}

/* each body's lod.max_node_updates in the scene as given (0: none), read before the variants
 * replace the lod objects */
static void scene_caps(const cJSON *root, double caps[SQ_MAX_BODIES])
{
    int b = 0;
    const cJSON *body;
    cJSON_ArrayForEach(body, cJSON_GetObjectItemCaseSensitive(root, "bodies"))
    {
        if (b == SQ_MAX_BODIES)
            break;
        const cJSON *lod = cJSON_GetObjectItemCaseSensitive(body, "lod");
        const cJSON *cap = lod ? cJSON_GetObjectItemCaseSensitive(lod, "max_node_updates") : NULL;
        caps[b++] = cJSON_IsNumber(cap) ? cap->valuedouble : 0;
    }
}

/* scene text of a variant: every body gets the variant's lod, operator and step fraction; an
 * adaptive variant keeps the body's max_node_updates (caps[]): the scene's deterministic
 * per-frame cap, a stand-in for the live budget, which the trade-off does not run (it is not
 * deterministic) */
static char *variant_text(cJSON *root, const to_variant *v, int finest_override, const double caps[SQ_MAX_BODIES],
                          const int sharp[SQ_MAX_BODIES])
{
    cJSON *bodies = cJSON_GetObjectItemCaseSensitive(root, "bodies");
    cJSON *body;
    int bi = 0;
    cJSON_ArrayForEach(body, bodies)
    {
        int fin = body_finest(body, finest_override);
        double cap_v = bi < SQ_MAX_BODIES ? caps[bi] : 0;
        int sharp_v = bi < SQ_MAX_BODIES && sharp[bi];
        bi++;
        cJSON *lod = cJSON_CreateObject();
        cJSON_AddStringToObject(lod, "mode", v->adaptive ? "adaptive" : "fixed");
        /* the scene's share of the frame for the simulation (lod.budget) is the guard's: kept */
        const cJSON *given = cJSON_GetObjectItemCaseSensitive(body, "lod");
        const cJSON *share = given ? cJSON_GetObjectItemCaseSensitive(given, "budget") : NULL;
        if (cJSON_IsNumber(share))
            cJSON_AddNumberToObject(lod, "budget", share->valuedouble);
        /* and its split/merge period, part of its adaptive setting (kept by every row: the
         * variants replace the lod object of the scene they are made from) */
        const cJSON *every = given ? cJSON_GetObjectItemCaseSensitive(given, "adapt_every") : NULL;
        if (cJSON_IsNumber(every))
            cJSON_AddNumberToObject(lod, "adapt_every", every->valuedouble);
        /* debugging: SQ_TRADEOFF_ADAPTIVE_MAX_LEVEL=K runs the adaptive rows (unbudgeted and
         * guarded) with lod.max_level at most K, measured against the same reference (docs/lod.md
         * "The depth of the adaptive body") */
        if (v->adaptive && getenv("SQ_TRADEOFF_ADAPTIVE_MAX_LEVEL"))
            fin = SQ_MIN(fin, atoi(getenv("SQ_TRADEOFF_ADAPTIVE_MAX_LEVEL")));
        cJSON_AddNumberToObject(lod, "max_level", fin);
        cJSON_AddNumberToObject(lod, "level", v->adaptive ? 0 : SQ_MIN(v->level, fin));
        if (v->adaptive) {
            if (isinf(v->split)) {
                cJSON_AddStringToObject(lod, "split", "inf");
            } else {
                cJSON_AddNumberToObject(lod, "split", v->split);
                cJSON_AddNumberToObject(lod, "merge", 0.4 * v->split);
            }
            if (cap_v > 0)
                cJSON_AddNumberToObject(lod, "max_node_updates", cap_v);
        }
        set_item(body, "lod", lod);
        set_item(body, "operator", cJSON_CreateString(v->op == SQ_OPERATOR_PAPER ? "paper" : "fem"));
        set_item(body, "step_fraction", cJSON_CreateNumber(v->fraction));
        /* fixed rows (the reference among them) at the Gershgorin 2^n rule whatever the scene's
         * "step_bound": the reference stays the same run; adaptive rows keep the scene's rule */
        set_item(body, "step_bound", cJSON_CreateString(v->adaptive && sharp_v ? "sharp" : "gershgorin"));
        /* one model for every variant (the paper operator runs linear elasticity only): linear,
         * whatever the scene chose, so every row's error is discretisation, not model */
        set_item(body, "elasticity", cJSON_CreateString("linear"));
        /* the integrator: explicit at its bound on every row but the integrator rows */
        set_item(body, "integrator", cJSON_CreateString(v->implicit ? "implicit" : "explicit"));
        cJSON *imp = cJSON_CreateObject();
        cJSON_AddNumberToObject(imp, "substeps", v->implicit ? v->substeps : 1);
        cJSON_AddNumberToObject(imp, "cg_tolerance", v->implicit ? v->tol : 1e-6);
        cJSON_AddNumberToObject(imp, "cg_max_iterations", SQ_IMPLICIT_MAX_ITER);
        set_item(body, "implicit", imp);
    }
    return cJSON_PrintUnformatted(root);
}

/* the scene's split threshold of body 0 (default 0.005 m) */
static double scene_split(const cJSON *root)
{
    const cJSON *b0 = cJSON_GetArrayItem(cJSON_GetObjectItemCaseSensitive(root, "bodies"), 0);
    const cJSON *lod = b0 ? cJSON_GetObjectItemCaseSensitive(b0, "lod") : NULL;
    const cJSON *sp = lod ? cJSON_GetObjectItemCaseSensitive(lod, "split") : NULL;
    return cJSON_IsNumber(sp) && sp->valuedouble > 0 ? sp->valuedouble : 0.005;
}

static int build_grid(to_variant *v, int finest, double s0, int quick, double ref_fraction)
{
    int n = 0;
    /* the reference first */
    v[n++] = (to_variant){"reference", "reference", 0, finest, 0, SQ_OPERATOR_FEM, ref_fraction, 0, 0, 0};
    for (int k = 0; k <= finest; k++) {
        v[n] = (to_variant){"", "fixed", 0, k, 0, SQ_OPERATOR_FEM, 0.9, 0, 0, 0};
        snprintf(v[n].name, sizeof v[n].name, "fixed L%d", k);
        n++;
    }
    static const double full_f[] = {0, 0.1, 0.3, 1, 3, 10, INFINITY};
    static const double quick_f[] = {0.3, 1, 3};
    const double *f = quick ? quick_f : full_f;
    int nf = quick ? (int)SQ_COUNTOF(quick_f) : (int)SQ_COUNTOF(full_f);
    if (finest > 0)
        for (int i = 0; i < nf; i++) {
            double s = isinf(f[i]) ? INFINITY : f[i] * s0;
            v[n] = (to_variant){"", "adaptive", 1, 0, s, SQ_OPERATOR_FEM, 0.9, 0, 0, 0};
            if (isinf(s))
                snprintf(v[n].name, sizeof v[n].name, "adaptive split inf");
            else
                snprintf(v[n].name, sizeof v[n].name, "adaptive split %.3g", s);
            n++;
        }
    v[n] = (to_variant){"", "step", 0, finest, 0, SQ_OPERATOR_FEM, 0.5, 0, 0, 0};
    snprintf(v[n].name, sizeof v[n].name, "fixed L%d step 0.5", finest);
    n++;
    if (!quick) {
        /* finer than the reference: its error is the floor below which differences are noise
         * (tool contact sets change with the step) */
        v[n] = (to_variant){"", "step", 0, finest, 0, SQ_OPERATOR_FEM, 0.1, 0, 0, 0};
        snprintf(v[n].name, sizeof v[n].name, "fixed L%d step 0.1", finest);
        n++;
    }
    if (!quick && finest > 0) {
        v[n] = (to_variant){"", "step", 1, 0, s0, SQ_OPERATOR_FEM, 0.25, 0, 0, 0};
        snprintf(v[n].name, sizeof v[n].name, "adaptive split %.3g step 0.25", s0);
        n++;
        v[n] = (to_variant){"", "step", 1, 0, s0, SQ_OPERATOR_FEM, 0.5, 0, 0, 0};
        snprintf(v[n].name, sizeof v[n].name, "adaptive split %.3g step 0.5", s0);
        n++;
    }
    /* the integrator axis: backward Euler on the finest level at 1, 2 and 4 steps a frame (CG to
     * 1e-6), and at one step with looser and tighter tolerances */
    static const int subs[] = {1, 2, 4};
    for (size_t k = 0; k < SQ_COUNTOF(subs); k++) {
        if (quick && subs[k] == 2)
            continue;
        v[n] = (to_variant){"", "integrator", 0, finest, 0, SQ_OPERATOR_FEM, 0.9, 1, subs[k], 1e-6};
        snprintf(v[n].name, sizeof v[n].name, "implicit L%d x%d tol 1e-6", finest, subs[k]);
        n++;
    }
    static const double tols[] = {1e-3, 1e-9};
    for (size_t k = 0; k < SQ_COUNTOF(tols); k++) {
        if (quick && k)
            continue;
        v[n] = (to_variant){"", "integrator", 0, finest, 0, SQ_OPERATOR_FEM, 0.9, 1, 1, tols[k]};
        snprintf(v[n].name, sizeof v[n].name, "implicit L%d x1 tol %g", finest, tols[k]);
        n++;
    }
    v[n] = (to_variant){"", "operator", 0, finest, 0, SQ_OPERATOR_PAPER, 0.9, 0, 0, 0};
    snprintf(v[n].name, sizeof v[n].name, "paper fixed L%d", finest);
    n++;
    if (!quick && finest > 0) {
        v[n] = (to_variant){"", "operator", 1, 0, s0, SQ_OPERATOR_PAPER, 0.9, 0, 0, 0};
        snprintf(v[n].name, sizeof v[n].name, "paper adaptive split %.3g", s0);
        n++;
        v[n] = (to_variant){"", "operator", 0, 0, 0, SQ_OPERATOR_PAPER, 0.9, 0, 0, 0};
        snprintf(v[n].name, sizeof v[n].name, "paper fixed L0");
        n++;
    }
    return n;
}

/* ---- sampling ------------------------------------------------------------------------------ */

/* the level a body simulates whose values are the most detailed (fixed: its only level;
 * adaptive: the finest, which holds active or ghost values everywhere) */
static int sampled_level(const sq_body *b)
{
    return sq_body_sim_level(b);
}

static void samples_init(to_samples *s, const sq_body *ref)
{
    const sq_mesh *m = sq_body_surface_mesh(ref);
    int stride = (m->nsurf + TO_MAX_SAMPLES - 1) / TO_MAX_SAMPLES;
    s->n = (m->nsurf + stride - 1) / stride;
    s->x = sq_malloc(sizeof(double) * 3 * (size_t)s->n);
    s->tet = sq_malloc(sizeof(int) * (size_t)s->n);
    s->bary = sq_malloc(sizeof(double) * 4 * (size_t)s->n);
    for (int i = 0; i < s->n; i++)
        memcpy(s->x + 3 * i, m->x + 3 * (size_t)m->surf_nodes[i * stride], sizeof(double) * 3);
}

/* locate the samples in the body's sampled level (nearest tet when outside it) */
static void samples_locate(to_samples *s, const sq_body *b)
{
    const sq_mesh *m = sq_body_mesh(b, sampled_level(b));
    for (int i = 0; i < s->n; i++) {
        s->tet[i] = sq_mesh_locate(m, s->x + 3 * i, s->bary + 4 * i);
        if (s->tet[i] < 0) {
            s->tet[i] = 0;
            s->bary[4 * i] = 1;
            s->bary[4 * i + 1] = s->bary[4 * i + 2] = s->bary[4 * i + 3] = 0;
        }
    }
}

/* displacement at every sample (n x 3) */
static void samples_eval(const to_samples *s, const sq_body *b, double *u)
{
    int k = sampled_level(b);
    const sq_mesh *m = sq_body_mesh(b, k);
    const double *d = sq_body_displacement(b, k);
    for (int i = 0; i < s->n; i++) {
        const int *tv = m->tets + 4 * (size_t)s->tet[i];
        const double *w = s->bary + 4 * i;
        for (int c = 0; c < 3; c++)
            u[3 * i + c] = w[0] * d[3 * tv[0] + c] + w[1] * d[3 * tv[1] + c] + w[2] * d[3 * tv[2] + c] +
                           w[3] * d[3 * tv[3] + c];
    }
}

static void samples_free(to_samples *s)
{
    free(s->x);
    free(s->tet);
    free(s->bary);
}

/* ---- the runs ------------------------------------------------------------------------------- */

typedef struct to_ref {
    int nbodies, nprobes, ntotal;      /* ntotal: samples over all bodies */
    to_samples smp[SQ_MAX_BODIES];
    long nframes;
    double *u;                         /* nframes x ntotal x 3 */
    double *probe;                     /* nframes x nprobes x 3 */
    double rms_ref, max_ref;           /* RMS and max |u_ref| over frames and samples */
} to_ref;

/* run one variant; ref->u is recorded when record != 0, else errors are measured against it */
static int run_variant(const sq_scene *scene, to_ref *ref, int record, to_result *r, sq_progress *prog,
                       double *prog_done, double budget_s)
{
    sq_err err = {{0}};
    sq_world *w = sq_world_create(scene, &err);
    if (!w) {
        snprintf(r->error, sizeof r->error, "%.290s", err.msg);
        return -1;
    }
    if (record) {
        ref->nbodies = w->nbodies;
        ref->nprobes = scene->nprobes;
        ref->ntotal = 0;
        for (int b = 0; b < w->nbodies; b++) {
            samples_init(&ref->smp[b], w->bodies[b]);
            ref->ntotal += ref->smp[b].n;
        }
        double bytes = 24.0 * ref->ntotal * (double)(ref->nframes + 1);
        if (bytes > 4e9) {
            snprintf(r->error, sizeof r->error,
                     "storing the reference (%d surface points x %ld frames) needs %.1f GB; give fewer --frames "
                     "(at most %.0f)", ref->ntotal, ref->nframes, bytes / 1e9, 4e9 / (24.0 * ref->ntotal));
            sq_world_destroy(w);
            return -1;
        }
        ref->u = sq_malloc(sizeof(double) * 3 * (size_t)ref->ntotal * (size_t)(ref->nframes + 1));
        ref->probe = sq_malloc(sizeof(double) * 3 * (size_t)(ref->nprobes + 1) * (size_t)(ref->nframes + 1));
    }
    for (int b = 0; b < w->nbodies; b++)
        samples_locate(&ref->smp[b], w->bodies[b]);
    {
        const sq_body *b0 = w->bodies[0];
        int k = sampled_level(b0);
        double dt = sq_body_level_dt(b0, k);
        r->substeps_finest = dt > 0 ? (int)lround(sq_body_get_def(b0)->frame_dt / dt) : 0;
    }
    double *u = sq_malloc(sizeof(double) * 3 * (size_t)ref->ntotal);
    double sum_ref = 0;
    long cnt_ref = 0;
    double period = 1.0 / scene->frame_rate;
    /* debugging: SQ_TRADEOFF_REF=FILE keeps the reference's samples in FILE (written by the
     * first run, read by later ones instead of stepping it); SQ_TRADEOFF_TRACE=1 prints each
     * frame of a budgeted run (error, CPU, active nodes per level) on stderr */
    const char *ref_file = getenv("SQ_TRADEOFF_REF");
    int trace = getenv("SQ_TRADEOFF_TRACE") ? atoi(getenv("SQ_TRADEOFF_TRACE")) : 0;
    trace = trace > 1 || (trace > 0 && budget_s > 0);
    size_t nu = 3 * (size_t)ref->ntotal * (size_t)(ref->nframes + 1);
    size_t np = 3 * (size_t)(ref->nprobes + 1) * (size_t)(ref->nframes + 1);
    if (record && ref_file) {
        FILE *rf = fopen(ref_file, "rb");
        if (rf) {
            /* the file's shape first: a reference of another scene (another sampled surface,
             * probe count or frame count) is not read, but stepped and written again */
            long shape[4] = {0, 0, 0, 0}, want[4] = {ref->ntotal, ref->nprobes, ref->nframes, REF_FILE_FORMAT};
            double cost[3]; /* the reference run's node updates, wall and thread CPU time */
            int okr = fread(shape, sizeof(long), 4, rf) == 4 && !memcmp(shape, want, sizeof shape) &&
                      fread(ref->u, sizeof(double), nu, rf) == nu && fread(ref->probe, sizeof(double), np, rf) == np &&
                      fread(&ref->rms_ref, sizeof(double), 1, rf) == 1 && fread(&ref->max_ref, sizeof(double), 1, rf) == 1 &&
                      fread(cost, sizeof(double), 3, rf) == 3;
            fclose(rf);
            if (okr) {
                r->updates = cost[0];
                r->wall = cost[1];
                r->cpu = cost[2];
                r->frames = ref->nframes;
                r->sim_s = (double)ref->nframes / scene->frame_rate;
                r->ups = r->updates / r->sim_s;
                r->wps = r->wall / r->sim_s;
                r->cps = r->cpu / r->sim_s;
                r->ok = 1;
                free(u);
                sq_world_destroy(w);
                return 0;
            }
        }
    }
    /* with the live budget the run models the server's session thread (server/net/session.c):
     * each frame is stepped, then published (every body's surface state and its encoded frame,
     * as `squish serve` sends it); the guard sees publishing as the thread's time around the
     * lod frame, as in the server, and the late-frame count and slowest frame include it. The
     * error sampling below is the harness's, not the product's: its thread CPU time is kept
     * out of the guard's view (sq_world_untimed) */
    sq_codec codec[SQ_MAX_BODIES];
    float *pub_xyz = NULL;
    unsigned char *pub_lev = NULL;
    if (budget_s > 0) {
        int maxs = 1;
        for (int b = 0; b < w->nbodies; b++) {
            const sq_mesh *m = sq_body_surface_mesh(w->bodies[b]);
            sq_codec_init_surface(&codec[b], m, SQ_CODEC_PRECISION); /* serve's default */
            maxs = SQ_MAX(maxs, m->nsurf);
        }
        pub_xyz = sq_malloc(sizeof(float) * 3 * (size_t)maxs);
        pub_lev = sq_malloc((size_t)maxs);
        sq_world_prepare_budget(w); /* at load, as the server and `squish run --realtime` */
    }
    for (long f = 1; f <= ref->nframes; f++) {
        double t0 = sq_now(), c0 = sq_thread_cpu();
        sq_world_step(w, budget_s); /* 0: no budget (deterministic); > 0: the live budget, the guard on */
        double c1 = sq_thread_cpu(), c = c1 - c0, cp = 0;
        r->wall += sq_now() - t0;
        r->cpu += c;
        if (budget_s > 0) {
            for (int b = 0; b < w->nbodies; b++) {
                sq_world_surface_state(w, b, pub_xyz, pub_lev);
                sq_blob_unref(sq_encode_frame(&codec[b], (uint32_t)b, (uint32_t)w->frame, w->time, 0, pub_xyz,
                                              pub_lev, w->tools, w->feedback[b], w->ntools));
            }
            cp = sq_thread_cpu() - c1;
            r->cpu_pub += cp;
        }
        double cs0 = sq_thread_cpu();
        if (f > 1) {
            /* after the first frame (one-off set-up), as `squish tradeoff --bench` counts */
            r->cpu_max1 = fmax(r->cpu_max1, c + cp);
            r->cpu_late1 += c + cp > period;
        }
        for (int b = 0; b < w->nbodies; b++) {
            r->updates += (double)w->profile[b].node_updates;
            r->cg_iterations += w->profile[b].cg_iterations;
        }
        /* surface samples */
        double *ur = ref->u + 3 * (size_t)ref->ntotal * (size_t)f;
        int off = 0;
        for (int b = 0; b < w->nbodies; b++) {
            samples_eval(&ref->smp[b], w->bodies[b], (record ? ur : u) + 3 * off);
            off += ref->smp[b].n;
        }
        double fs = 0, fm = 0;
        for (int i = 0; i < ref->ntotal; i++) {
            double e2 = 0;
            for (int c = 0; c < 3; c++) {
                double a = record ? ur[3 * i + c] : u[3 * i + c] - ur[3 * i + c];
                e2 += a * a;
            }
            if (!isfinite(e2))
                e2 = INFINITY;
            fs += e2;
            fm = fmax(fm, sqrt(e2));
        }
        if (record) {
            sum_ref += fs;
            cnt_ref += ref->ntotal;
            ref->max_ref = fmax(ref->max_ref, fm);
        } else {
            r->sum_sq += fs;
            r->count += ref->ntotal;
            r->max_err = fmax(r->max_err, fm);
            if (f == ref->nframes) {
                r->final_rms = sqrt(fs / SQ_MAX(1, ref->ntotal));
                r->final_max = fm;
            }
        }
        /* probes */
        double *pr = ref->probe + 3 * (size_t)ref->nprobes * (size_t)f;
        for (int p = 0; p < ref->nprobes; p++) {
            double up[3];
            if (sq_world_probe(w, p, up) != 0)
                up[0] = up[1] = up[2] = NAN;
            if (record) {
                memcpy(pr + 3 * p, up, sizeof up);
            } else if (isfinite(pr[3 * p])) {
                double e = sqrt((up[0] - pr[3 * p]) * (up[0] - pr[3 * p]) + (up[1] - pr[3 * p + 1]) * (up[1] - pr[3 * p + 1]) +
                                (up[2] - pr[3 * p + 2]) * (up[2] - pr[3 * p + 2]));
                r->probe_err = isfinite(e) ? fmax(r->probe_err, e) : INFINITY;
            }
        }
        double cs = sq_thread_cpu() - cs0;
        r->cpu_smp += cs;
        if (budget_s > 0)
            sq_world_untimed(w, cs);
        if (trace) {
            fprintf(stderr, "frame %3ld rms %.3f mm max %.2f mm cpu %.2f ms publish %.2f sampling %.2f active", f,
                    1e3 * sqrt(fs / SQ_MAX(1, ref->ntotal)), 1e3 * fm, 1e3 * c, 1e3 * cp, 1e3 * cs);
            for (int k = 0; k < SQ_MAX_LEVELS && k < 4; k++)
                fprintf(stderr, " %d", w->profile[0].active[k]);
            fprintf(stderr, " splits %d merges %d refused %d\n", w->profile[0].splits, w->profile[0].merges,
                    w->profile[0].splits_refused);
        }
        *prog_done += 1;
        sq_progress_update(prog, *prog_done);
    }
    if (record) {
        ref->rms_ref = cnt_ref ? sqrt(sum_ref / cnt_ref) : 0;
        FILE *rf = ref_file ? fopen(ref_file, "wb") : NULL;
        if (rf) {
            long shape[4] = {ref->ntotal, ref->nprobes, ref->nframes, REF_FILE_FORMAT};
            double cost[3] = {r->updates, r->wall, r->cpu};
            fwrite(shape, sizeof(long), 4, rf);
            fwrite(ref->u, sizeof(double), nu, rf);
            fwrite(ref->probe, sizeof(double), np, rf);
            fwrite(&ref->rms_ref, sizeof(double), 1, rf);
            fwrite(&ref->max_ref, sizeof(double), 1, rf);
            fwrite(cost, sizeof(double), 3, rf);
            fclose(rf);
        }
    }
    if (budget_s > 0) {
        for (int b = 0; b < w->nbodies; b++)
            sq_codec_free(&codec[b]);
        free(pub_xyz);
        free(pub_lev);
    }
    r->frames = ref->nframes;
    r->sim_s = w->time;
    r->resets = w->resets;
    r->rms = r->count ? sqrt(r->sum_sq / r->count) : 0;
    r->ups = r->sim_s > 0 ? r->updates / r->sim_s : 0;
    r->wps = r->sim_s > 0 ? r->wall / r->sim_s : 0;
    r->cps = r->sim_s > 0 ? r->cpu / r->sim_s : 0;
    r->ok = 1;
    free(u);
    sq_world_destroy(w);
    return 0;
}

/* the cheapest fixed-level cost reaching RMS error e: a fixed level with error <= e, or the
 * log-log interpolation between consecutive levels k, k+1 whose errors bracket e; -1 when no
 * fixed level is that accurate */
static double fixed_cost_at(const to_variant *v, const to_result *r, int n, double e, int wall)
{
    double best = -1;
    for (int i = 0; i < n; i++) {
        if (strcmp(v[i].kind, "fixed") || !r[i].ok)
            continue;
        double ci = wall ? r[i].wps : r[i].ups;
        if (r[i].rms <= e && (best < 0 || ci < best))
            best = ci;
        for (int j = 0; j < n; j++) {
            if (strcmp(v[j].kind, "fixed") || !r[j].ok || v[j].level != v[i].level + 1)
                continue;
            double ei = r[i].rms, ej = r[j].rms, cj = wall ? r[j].wps : r[j].ups;
            if (!(e < ei && e >= ej) || !(ej > 0))
                continue;
            double t = log(ei / e) / log(ei / ej);
            double c = exp(log(ci) + t * (log(cj) - log(ci)));
            if (best < 0 || c < best)
                best = c;
        }
    }
    return best;
}

/* ---- the runs with the live budget ----------------------------------------------------------- */

static int cmp_dbl(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* min, median (the lower middle for an even count) and max of x[0..k-1] (k > 0; sorts x) */
static void spread(double *x, int k, double out[3])
{
    qsort(x, (size_t)k, sizeof *x, cmp_dbl);
    out[0] = x[0];
    out[1] = x[(k - 1) / 2];
    out[2] = x[k - 1];
}

/* r[gmed]: each column's median over the completed runs r[g0..gmed-1] (resets: the largest) */
static void guarded_median(to_result *r, int g0, int gmed)
{
    double x[TO_MAX_GUARDED], o[3];
    int k = 0;
    to_result *m = &r[gmed];
    for (int i = g0; i < gmed; i++)
        if (r[i].ok) {
            if (!k)
                *m = r[i];
            k++;
        }
    if (!k) {
        m->ok = 0;
        snprintf(m->error, sizeof m->error, "no run with the live budget completed");
        return;
    }
#define TO_MEDIAN(field)                                                                                           \
    do {                                                                                                           \
        int c = 0;                                                                                                 \
        for (int i = g0; i < gmed; i++)                                                                            \
            if (r[i].ok)                                                                                           \
                x[c++] = (double)r[i].field;                                                                       \
        spread(x, c, o);                                                                                           \
        m->field = o[1];                                                                                           \
    } while (0)
    TO_MEDIAN(updates);
    TO_MEDIAN(wall);
    TO_MEDIAN(cpu);
    TO_MEDIAN(max_err);
    TO_MEDIAN(probe_err);
    TO_MEDIAN(final_rms);
    TO_MEDIAN(final_max);
    TO_MEDIAN(rms);
    TO_MEDIAN(ups);
    TO_MEDIAN(wps);
    TO_MEDIAN(cps);
    TO_MEDIAN(cpu_max1);
    TO_MEDIAN(cpu_late1);
#undef TO_MEDIAN
    for (int i = g0; i < gmed; i++)
        if (r[i].ok && r[i].resets > m->resets)
            m->resets = r[i].resets;
    m->pareto = 0;
    m->error[0] = 0;
}

/* summary lines of the runs with the live budget, beside fixed L(finest-1), the fixed finest level
 * and the same setting without a budget, and the aims of a scene that needs adaptivity (issue
 * 10): RMS error within 1.5x fixed L(finest-1)'s, at least 100x less CPU than the fixed finest
 * level, every frame after the first within the period in thread CPU time */
static void guarded_summary(FILE *f, const to_variant *v, const to_result *r, int n, int g0, int gmed, int finest,
                            double frame_rate)
{
    double period = 1.0 / frame_rate;
    int nrun = gmed - g0, k = 0;
    double x[TO_MAX_GUARDED], o[3];
    for (int i = g0; i < gmed; i++)
        k += r[i].ok;
    fprintf(f, "\nwith the live budget (each frame's budget the %.3g ms frame period, the guard on, one thread: as "
               "'squish run --realtime' and the server run it), split %.3g m, %d of %d runs completed; NOT "
               "deterministic (the guard decides from measured CPU time): min / median / max over the runs, "
               "kept off the Pareto front and the equal-error speed-up above\n",
            1e3 * period, v[gmed].split, k, nrun);
    if (!k)
        return;
#define TO_SPREAD(label, field, scale, fmt)                                                                       \
    do {                                                                                                           \
        int c = 0;                                                                                                 \
        for (int i = g0; i < gmed; i++)                                                                            \
            if (r[i].ok)                                                                                           \
                x[c++] = (double)r[i].field * (scale);                                                             \
        spread(x, c, o);                                                                                           \
        fprintf(f, "  %-50s " fmt " / " fmt " / " fmt "\n", label, o[0], o[1], o[2]);                              \
    } while (0)
    TO_SPREAD("rms surface error (m)", rms, 1, "%.3g");
    TO_SPREAD("max surface error (m)", max_err, 1, "%.3g");
    TO_SPREAD("probe error (m)", probe_err, 1, "%.3g");
    TO_SPREAD("node updates per simulated s", ups, 1, "%.4g");
    TO_SPREAD("thread CPU s per simulated s", cps, 1, "%.3g");
    TO_SPREAD("frames over the period in CPU time, after frame 1", cpu_late1, 1, "%.0f");
    TO_SPREAD("slowest frame after frame 1, CPU ms", cpu_max1, 1e3, "%.3g");
    TO_SPREAD("publishing, CPU s/s (in late/slowest, not above)", cpu_pub / r[i].sim_s, 1, "%.3g");
    TO_SPREAD("error sampling (not the product's), CPU s/s", cpu_smp / r[i].sim_s, 1, "%.3g");
    TO_SPREAD("wall s per simulated s (includes other load)", wps, 1, "%.3g");
#undef TO_SPREAD
    int fc = -1, ff = -1, ua = -1;
    for (int i = 0; i < n; i++) {
        if (!r[i].ok)
            continue;
        if (!strcmp(v[i].kind, "fixed") && v[i].level == finest - 1)
            fc = i;
        if (!strcmp(v[i].kind, "fixed") && v[i].level == finest)
            ff = i;
        if (!strcmp(v[i].kind, "adaptive") && v[i].split == v[gmed].split && v[i].fraction == v[gmed].fraction)
            ua = i;
    }
    if (fc >= 0)
        fprintf(f, "  next to fixed L%d: rms %.3g m, %.3g CPU s/s\n", finest - 1, r[fc].rms, r[fc].cps);
    if (ff >= 0)
        fprintf(f, "  next to fixed L%d (finest): rms %.3g m, %.3g CPU s/s\n", finest, r[ff].rms, r[ff].cps);
    if (ua >= 0)
        fprintf(f, "  next to the same setting without a budget: rms %.3g m, %.3g CPU s/s, %ld frames over the "
                   "period in CPU time after frame 1, slowest %.3g ms\n",
                r[ua].rms, r[ua].cps, r[ua].cpu_late1, 1e3 * r[ua].cpu_max1);
    if (fc < 0 || ff < 0 || !(r[fc].rms > 0))
        return;
    /* the aims, per run: met when every completed run meets it */
    int acc = 0, cost = 0, rate = 0, all = 0;
    double lim = 1.5 * r[fc].rms;
    for (int i = g0; i < gmed; i++) {
        if (!r[i].ok)
            continue;
        int a = r[i].rms <= lim, c = r[i].cps > 0 && r[ff].cps >= 100 * r[i].cps, t = r[i].cpu_late1 == 0;
        acc += a;
        cost += c;
        rate += t;
        all += a && c && t;
    }
    fprintf(f, "aims with the live budget (met: in every run):\n");
    fprintf(f, "  accuracy: rms error within 1.5x fixed L%d's (at most %.3g m): %s (%d of %d runs; median %.3g m, "
               "%.2fx fixed L%d)\n",
            finest - 1, lim, acc == k ? "met" : "NOT met", acc, k, r[gmed].rms, r[gmed].rms / r[fc].rms, finest - 1);
    fprintf(f, "  cost: at least 100x less thread CPU than fixed L%d (%.3g CPU s/s): %s (%d of %d runs; median "
               "x%.1f; x%.1f in node updates)\n",
            finest, r[ff].cps, cost == k ? "met" : "NOT met", cost, k, r[gmed].cps > 0 ? r[ff].cps / r[gmed].cps : 0,
            r[gmed].ups > 0 ? r[ff].ups / r[gmed].ups : 0);
    fprintf(f, "  rate: every frame after the first within %.3g ms of thread CPU: %s (%d of %d runs)\n", 1e3 * period,
            rate == k ? "met" : "NOT met", rate, k);
    fprintf(f, "  all three in the same run: %d of %d runs\n", all, k);
}

/* ---- output -------------------------------------------------------------------------------- */

static int write_plot(const char *dir, const char *scene_name, const to_variant *v, const to_result *r, int n)
{
    char dat[1100], gp[1100], png[1100];
    snprintf(dat, sizeof dat, "%s/tradeoff_plot.dat", dir);
    snprintf(gp, sizeof gp, "%s/tradeoff.gp", dir);
    snprintf(png, sizeof png, "%s/tradeoff.png", dir);
    FILE *f = fopen(dat, "w");
    if (!f)
        return -1;
    /* blocks: 0 fixed, 1 adaptive, 2 step, 3 paper (model difference), 4 Pareto front (sorted) */
    static const char *kinds[] = {"fixed", "adaptive", "step", "operator"};
    for (int k = 0; k < 4; k++) {
        fprintf(f, "# %s\n", kinds[k]);
        for (int i = 0; i < n; i++)
            if (r[i].ok && !strcmp(v[i].kind, kinds[k]) && r[i].rms > 0)
                fprintf(f, "%.6e %.6e \"%s\"\n", r[i].ups, r[i].rms, v[i].name);
        fprintf(f, "\n\n");
    }
    /* block 4 is the front (below), block 5 the runs with the live budget */
    fprintf(f, "# pareto\n");
    int idx[TO_MAX_VARIANTS], np = 0;
    for (int i = 0; i < n; i++)
        if (r[i].pareto && r[i].rms > 0)
            idx[np++] = i;
    for (int a = 0; a < np; a++)
        for (int b = a + 1; b < np; b++)
            if (r[idx[b]].ups < r[idx[a]].ups) {
                int t = idx[a];
                idx[a] = idx[b];
                idx[b] = t;
            }
    for (int a = 0; a < np; a++)
        fprintf(f, "%.6e %.6e\n", r[idx[a]].ups, r[idx[a]].rms);
    fprintf(f, "\n\n");
    int nguard = 0;
    fprintf(f, "# guarded runs (live budget, not deterministic)\n");
    for (int i = 0; i < n; i++)
        if (r[i].ok && !strcmp(v[i].kind, "guarded_run") && r[i].rms > 0 && r[i].ups > 0) {
            fprintf(f, "%.6e %.6e\n", r[i].ups, r[i].rms);
            nguard++;
        }
    fprintf(f, "\n\n");
    fclose(f);
    f = fopen(gp, "w");
    if (!f)
        return -1;
    int plottable = 0;
    for (int i = 0; i < n; i++)
        plottable += r[i].ok && r[i].rms > 0 && r[i].ups > 0;
    if (!plottable) {
        /* nothing differs from the reference (e.g. a run too short for the tool to touch) */
        fprintf(f, "set terminal pngcairo size 1000,700 font 'sans,10'\nset output '%s'\n"
                   "set title \"%s: every setting equals the reference (zero error): run more frames\"\n"
                   "set xrange [1:10]\nset yrange [1:10]\nunset key\nplot NaN\n", png, scene_name);
    } else
    fprintf(f,
            "set terminal pngcairo size 1000,700 font 'sans,10'\n"
            "set output '%s'\n"
            "set title \"%s: RMS surface error vs cost (reference: finest level, fem, step %g x bound)\"\n"
            "set logscale xy\n"
            "set xlabel 'node updates per simulated second'\n"
            "set ylabel 'RMS surface displacement error (m)'\n"
            "set grid\n"
            "set key top right box opaque\n"
            "plot '%s' index 4 with linespoints lw 2 lc rgb '#888888' pt 0 title 'Pareto front (fem)', \\\n"
            "     '' index 0 with points pt 7 ps 1.5 lc rgb '#1f77b4' title 'fixed level', \\\n"
            "     '' index 1 with points pt 9 ps 1.5 lc rgb '#d62728' title 'adaptive', \\\n"
            "     '' index 2 with points pt 5 ps 1.3 lc rgb '#2ca02c' title 'step fraction', \\\n"
            "     '' index 3 with points pt 13 ps 1.3 lc rgb '#9467bd' title 'paper operator (model difference)', \\\n"
            "     '' index 0 using 1:2:3 with labels offset 1,0.7 left font ',8' notitle, \\\n"
            "     '' index 1 using 1:2:3 with labels offset 1,-0.7 left font ',8' tc rgb '#d62728' notitle, \\\n"
            "     '' index 2 using 1:2:3 with labels offset 1,0.7 left font ',8' tc rgb '#2ca02c' notitle, \\\n"
            "     '' index 3 using 1:2:3 with labels offset 1,0.7 left font ',8' tc rgb '#9467bd' notitle%s\n",
            png, scene_name, v[0].fraction, dat,
            nguard ? ", \\\n     '' index 5 with points pt 11 ps 1.5 lc rgb '#ff7f0e' title 'adaptive, live budget "
                     "(guard; each run; not deterministic)'"
                   : "");
    fclose(f);
    char cmd[2400];
    snprintf(cmd, sizeof cmd, "gnuplot '%s' 2>&1", gp);
    FILE *p = popen(cmd, "r");
    if (!p)
        return -1;
    char line[512];
    while (fgets(line, sizeof line, p))
        fprintf(stderr, "gnuplot: %s", line);
    int rc = pclose(p);
    if (rc != 0) {
        fprintf(stderr, "squish tradeoff: gnuplot failed (status %d) on %s; install it with 'make deps' "
                        "(package gnuplot-nox); the CSV is complete without the plot\n", rc, gp);
        return -1;
    }
    return 0;
}

/* ---- the command ---------------------------------------------------------------------------- */

int sq_cmd_tradeoff(int argc, char **argv)
{
    const char *scene_path = NULL, *out = "squish-tradeoff";
    long frames = -1;
    int quick = 0, finest_override = -1, guarded = 3;
    double ref_fraction = 0.25;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(a, "--bench")) {
            return sq_bench_scenes(argc - i, argv + i);
        } else if (!strcmp(a, "--quick")) {
            quick = 1;
        } else if (!strcmp(a, "--reference-step")) {
            char *end = NULL;
            double f = i + 1 < argc ? strtod(argv[i + 1], &end) : 0;
            if (i + 1 >= argc || *end || !(f > 0 && f <= 1))
                return usage_error("--reference-step needs a step fraction of the bound in (0, 1]", NULL);
            ref_fraction = f;
            i++;
        } else if (!strcmp(a, "--guarded")) {
            char *end = NULL;
            long g = i + 1 < argc ? strtol(argv[i + 1], &end, 10) : -1;
            if (i + 1 >= argc || *end || g < 0 || g > TO_MAX_GUARDED)
                return usage_error("--guarded needs a number of runs with the live budget (0 to 15)", NULL);
            guarded = (int)g;
            i++;
        } else if (!strcmp(a, "--out")) {
            if (i + 1 >= argc || !argv[i + 1][0])
                return usage_error("--out needs a directory", NULL);
            out = argv[++i];
        } else if (!strcmp(a, "--frames") || !strcmp(a, "--finest")) {
            char *end = NULL;
            long v = i + 1 < argc ? strtol(argv[i + 1], &end, 10) : -1;
            if (i + 1 >= argc || *end || v < (a[2] == 'f' && a[3] == 'r' ? 1 : 0) || v > 1000000)
                return usage_error(!strcmp(a, "--frames") ? "--frames needs a whole number of frames (1 to 1e6)"
                                                          : "--finest needs a level index (0 to 5)",
                                   NULL);
            if (!strcmp(a, "--frames"))
                frames = v;
            else
                finest_override = (int)v;
            i++;
        } else if (a[0] == '-') {
            return usage_error("unknown option", a);
        } else if (scene_path) {
            return usage_error("more than one scene given; run one at a time:", a);
        } else {
            scene_path = a;
        }
    }
    if (!scene_path)
        return usage_error("no scene given; pass SCENE.json", NULL);

    /* the scene: loaded once as given (validates it), and as JSON for the variants */
    sq_err err = {{0}};
    sq_scene *base = sq_scene_load(scene_path, &err);
    if (!base) {
        fprintf(stderr, "squish tradeoff: %s\n", err.msg);
        return 1;
    }
    char *text = sq_read_file(scene_path, NULL, 1 << 24, &err);
    cJSON *root = text ? cJSON_Parse(text) : NULL;
    free(text);
    if (!root) {
        fprintf(stderr, "squish tradeoff: %s: cannot re-read the scene\n", scene_path);
        sq_scene_free(base);
        return 1;
    }
    char dir[512];
    snprintf(dir, sizeof dir, "%s", scene_path);
    char *slash = strrchr(dir, '/');
    if (slash)
        *(slash == dir ? slash + 1 : slash) = 0;
    else
        snprintf(dir, sizeof dir, ".");
    int finest = 0;
    {
        cJSON *body;
        cJSON_ArrayForEach(body, cJSON_GetObjectItemCaseSensitive(root, "bodies"))
        finest = SQ_MAX(finest, body_finest(body, finest_override));
    }
    double s0 = scene_split(root);
    long nframes = frames > 0 ? frames : (long)ceil(base->duration * base->frame_rate - 1e-9);
    char scene_name[64];
    snprintf(scene_name, sizeof scene_name, "%s", base->name);
    double frame_rate = base->frame_rate;
    int sharp[SQ_MAX_BODIES] = {0}; /* each body's "step_bound" as the scene gives it */
    for (int b = 0; b < base->nbodies && b < SQ_MAX_BODIES; b++)
        sharp[b] = base->bodies[b].sharp_step;
    sq_scene_free(base);

    to_variant v[TO_MAX_VARIANTS];
    static to_result r[TO_MAX_VARIANTS];
    memset(r, 0, sizeof r);
    int n = build_grid(v, finest, s0, quick, ref_fraction);
    /* the scene's adaptive setting again, with the live budget: the same scene text as its
     * unbudgeted row, stepped with the frame period as budget (the guard on), one thread; the
     * guard decides from measured CPU time, so these runs are not deterministic: `guarded` runs,
     * then one row of their medians (gmed) */
    int gmed = -1, g0 = n;
    if (finest > 0 && guarded > 0) {
        for (int k = 0; k < guarded; k++) {
            v[n] = (to_variant){"", "guarded_run", 1, 0, s0, SQ_OPERATOR_FEM, 0.9, 0, 0, 0};
            snprintf(v[n].name, sizeof v[n].name, "adaptive split %.3g guarded run %d", s0, k + 1);
            n++;
        }
        gmed = n;
        v[n] = (to_variant){"", "guarded", 1, 0, s0, SQ_OPERATOR_FEM, 0.9, 0, 0, 0};
        snprintf(v[n].name, sizeof v[n].name, "adaptive split %.3g guarded median", s0);
        n++;
    }
    double caps[SQ_MAX_BODIES] = {0};
    scene_caps(root, caps);
    if (sq_mkdir_p(out)) {
        fprintf(stderr, "squish tradeoff: cannot create output directory %s: %s; choose another --out\n", out,
                strerror(errno));
        cJSON_Delete(root);
        return 1;
    }
    printf("tradeoff %s: %d settings x %ld frames (%.3g s simulated each); reference: fixed L%d, fem, step %.3g "
           "x bound; adaptive thresholds around the scene's split %.3g m\n",
           scene_name, g0, nframes, nframes / frame_rate, finest, ref_fraction, s0);
    if (gmed >= 0)
        printf("tradeoff %s: and %d runs of split %.3g m with the live budget (the %.3g ms frame period, the guard "
               "on, one thread): not deterministic, reported as min / median / max\n",
               scene_name, gmed - g0, s0, 1e3 / frame_rate);
    fflush(stdout);

    to_ref ref;
    memset(&ref, 0, sizeof ref);
    ref.nframes = nframes;
    sq_progress prog;
    sq_progress_begin(&prog, "squish tradeoff", (double)(gmed >= 0 ? n - 1 : n) * nframes);
    double done = 0;
    int rc = 0;
    for (int i = 0; i < n; i++) {
        if (i == gmed)
            continue; /* not a run: the medians of the guarded runs, below */
        if (i > 0 && getenv("SQ_TRADEOFF_ONLY_GUARDED") && strcmp(v[i].kind, getenv("SQ_TRADEOFF_ONLY_GUARDED"))) {
            done += nframes; /* debugging: only the reference and the runs with the live budget */
            continue;
        }
        if (i > 0 && !strcmp(v[i].kind, "fixed") && v[i].level == finest && v[i].fraction == v[0].fraction &&
            r[0].ok) {
            /* the same run as the reference (--reference-step 0.9): its numbers, zero error */
            r[i] = r[0];
            done += nframes;
            sq_progress_update(&prog, done);
            continue;
        }
        char *vt = variant_text(root, &v[i], finest_override, caps, sharp);
        char label[600];
        snprintf(label, sizeof label, "%.500s [%.47s]", scene_path, v[i].name);
        sq_scene *s = sq_scene_parse(vt, dir, label, &err);
        cJSON_free(vt);
        if (!s) {
            snprintf(r[i].error, sizeof r[i].error, "%.290s", err.msg);
        } else {
            run_variant(s, &ref, i == 0, &r[i], &prog, &done,
                        !strcmp(v[i].kind, "guarded_run") ? 1.0 / frame_rate : 0);
            sq_scene_free(s);
        }
        if (!r[i].ok) {
            done += nframes;
            if (i == 0) {
                sq_progress_end(&prog);
                fprintf(stderr, "squish tradeoff: the reference run failed: %s\n", r[i].error);
                rc = 1;
                goto out;
            }
        }
    }
    sq_progress_end(&prog);
    if (gmed >= 0)
        guarded_median(r, g0, gmed);

    /* the Pareto front over the fem settings (the paper operator is a different model), without
     * the runs with the live budget (not deterministic: they neither sit on it nor push a
     * setting off it) */
    for (int i = 0; i < n; i++) {
        if (!r[i].ok || v[i].op != SQ_OPERATOR_FEM || !strncmp(v[i].kind, "guarded", 7) || v[i].implicit)
            continue; /* implicit rows: their cost is CG iterations, not node updates (cpu/s compares) */
        int dominated = 0;
        for (int j = 0; j < n && !dominated; j++)
            if (j != i && r[j].ok && v[j].op == SQ_OPERATOR_FEM && strncmp(v[j].kind, "guarded", 7) && !v[j].implicit &&
                r[j].ups <= r[i].ups && r[j].rms <= r[i].rms &&
                (r[j].ups < r[i].ups || r[j].rms < r[i].rms))
                dominated = 1;
        r[i].pareto = !dominated;
    }

    /* CSV */
    {
        char path[1100];
        snprintf(path, sizeof path, "%s/tradeoff.csv", out);
        FILE *f = fopen(path, "w");
        if (!f) {
            fprintf(stderr, "squish tradeoff: cannot write %s: %s\n", path, strerror(errno));
            rc = 1;
            goto out;
        }
        fprintf(f, "setting,kind,operator,lod,level,split_m,step_fraction,substeps,frames,sim_s,"
                   "node_updates_per_s,wall_s_per_s,rms_err_m,max_err_m,rms_rel,probe_err_m,final_rms_m,"
                   "final_max_m,resets,pareto,cpu_s_per_s,cpu_late_frames,cpu_max_s,error,integrator,cg_iterations_per_frame\n");
        for (int i = 0; i < n; i++) {
            fprintf(f, "\"%s\",%s,%s,%s,%d,%.6g,%.3g,%d,%ld,%.6g,%.6e,%.6e,%.6e,%.6e,%.6e,%.6e,%.6e,%.6e,%ld,%d,%.6e,%ld,"
                       "%.6e,\"%s\",%s,%.1f\n",
                    v[i].name, v[i].kind, v[i].op == SQ_OPERATOR_PAPER ? "paper" : "fem",
                    v[i].adaptive ? "adaptive" : "fixed", v[i].adaptive ? -1 : v[i].level, v[i].adaptive ? v[i].split : 0,
                    v[i].fraction, r[i].substeps_finest, r[i].frames, r[i].sim_s, r[i].ups, r[i].wps, r[i].rms,
                    r[i].max_err, ref.rms_ref > 0 ? r[i].rms / ref.rms_ref : 0, r[i].probe_err, r[i].final_rms,
                    r[i].final_max, r[i].resets, r[i].pareto, r[i].cps, r[i].cpu_late1, r[i].cpu_max1, r[i].error,
                    v[i].implicit ? "implicit" : "explicit",
                    v[i].implicit && r[i].frames ? (double)r[i].cg_iterations / r[i].frames : 0.0);
        }
        if (fclose(f)) {
            fprintf(stderr, "squish tradeoff: writing %s failed: %s\n", path, strerror(errno));
            rc = 1;
        }
    }

    /* table and the headline */
    {
        char path[1100];
        snprintf(path, sizeof path, "%s/summary.txt", out);
        FILE *sf = fopen(path, "w");
        FILE *outs[2] = {stdout, sf};
        for (int o = 0; o < 2; o++) {
            FILE *f = outs[o];
            if (!f)
                continue;
            fprintf(f, "scene %s, %ld frames; reference RMS |u| %.3g m, max |u| %.3g m\n", scene_name, nframes,
                    ref.rms_ref, ref.max_ref);
            fprintf(f, "%-40s %8s %12s %10s %10s %10s %10s %10s %10s %7s %s\n", "setting", "substeps", "updates/s",
                    "wall/s", "cpu/s", "rms err m", "rel", "max err m", "probe m", "pareto", "");
            for (int i = 0; i < n; i++) {
                if (!r[i].ok) {
                    fprintf(f, "%-40s refused: %s\n", v[i].name, r[i].error);
                    continue;
                }
                fprintf(f, "%-40s %8d %12.4g %10.3g %10.3g %10.3g %10.3g %10.3g %10.3g %7s %s\n", v[i].name,
                        r[i].substeps_finest, r[i].ups, r[i].wps, r[i].cps, r[i].rms,
                        ref.rms_ref > 0 ? r[i].rms / ref.rms_ref : 0, r[i].max_err, r[i].probe_err,
                        r[i].pareto ? "*" : "",
                        v[i].op == SQ_OPERATOR_PAPER ? "(model difference, not discretisation error)"
                        : r[i].resets                ? "(resets!)"
                        : !strncmp(v[i].kind, "guarded", 7) ? "(live budget: not deterministic, off the front)"
                        : v[i].implicit ? "(implicit: cost in cpu/s; updates/s counts steps, not CG iterations)"
                                        : "");
            }
            /* the headline: adaptive settings against the fixed levels at equal RMS error */
            int fine = -1;
            for (int i = 0; i < n; i++)
                if (!strcmp(v[i].kind, "fixed") && v[i].level == finest && r[i].ok)
                    fine = i;
            fprintf(f, "\nadaptive speed-up at equal error (equal error: the fixed-level cost at the adaptive run's RMS "
                       "surface error, interpolated log-log between the two fixed levels that bracket it):\n");
            double best = 0;
            int besti = -1;
            for (int i = 0; i < n; i++) {
                if (strcmp(v[i].kind, "adaptive") || !r[i].ok)
                    continue;
                double cu = fixed_cost_at(v, r, n, r[i].rms, 0), cw = fixed_cost_at(v, r, n, r[i].rms, 1);
                char su[64] = "below the finest level's error", sw[64] = "";
                if (cu > 0) {
                    snprintf(su, sizeof su, "x%.2f in node updates", cu / r[i].ups);
                    snprintf(sw, sizeof sw, ", x%.2f in wall time", cw > 0 ? cw / r[i].wps : 0);
                    /* the headline counts settings that adapt: split 0 is the finest level
                     * everywhere, inf the coarsest */
                    if (v[i].split > 0 && isfinite(v[i].split) && cu / r[i].ups > best) {
                        best = cu / r[i].ups;
                        besti = i;
                    }
                }
                fprintf(f, "  %-28s rms %.3g m: %s%s", v[i].name, r[i].rms, su, sw);
                if (fine >= 0)
                    fprintf(f, "; vs fixed L%d (rms %.3g m): x%.2f updates, x%.2f wall", finest, r[fine].rms,
                            r[fine].ups / r[i].ups, r[fine].wps / r[i].wps);
                /* the equal-error rule takes the cheapest fixed level at or below the adaptive
                 * error, so a setting a little more accurate than a level is compared with the
                 * next finer one; name also the cheapest level within 1.5x its error, in CPU time */
                int near = -1;
                for (int j = 0; j < n; j++)
                    if (!strcmp(v[j].kind, "fixed") && r[j].ok && r[j].rms <= 1.5 * r[i].rms &&
                        (near < 0 || r[j].cps < r[near].cps))
                        near = j;
                if (near >= 0 && r[i].cps > 0)
                    fprintf(f, "; cheapest fixed level within 1.5x its error: L%d (rms %.3g m, %.3g CPU s/s: x%.2f "
                               "the adaptive CPU time)",
                            v[near].level, r[near].rms, r[near].cps, r[near].cps / r[i].cps);
                fprintf(f, "\n");
            }
            if (besti >= 0)
                fprintf(f, "headline: %s is x%.2f cheaper in node updates (x%.2f in wall time) than a fixed mesh of "
                           "the same RMS error\n",
                        v[besti].name, best, fixed_cost_at(v, r, n, r[besti].rms, 1) / r[besti].wps);
            else
                fprintf(f, "headline: no adaptive setting (0 < split < inf) reaches a fixed mesh's error at a lower "
                           "node-update cost on this scene\n");
            if (gmed >= 0)
                guarded_summary(f, v, r, n, g0, gmed, finest, frame_rate);
            for (int i = 0; i < n; i++)
                if (r[i].ok && r[i].resets)
                    fprintf(f, "warning: %s tripped the blow-up detector %ld time%s (body reset to rest); its "
                               "errors include the resets: run that setting with 'squish run' to see the frames\n",
                            v[i].name, r[i].resets, r[i].resets == 1 ? "" : "s");
        }
        if (sf && fclose(sf))
            rc = 1;
    }
    if (write_plot(out, scene_name, v, r, n) == 0)
        printf("wrote %s/tradeoff.csv, %s/tradeoff.png, %s/summary.txt\n", out, out, out);
    else
        rc = 1;

out:
    for (int b = 0; b < ref.nbodies; b++)
        samples_free(&ref.smp[b]);
    free(ref.u);
    free(ref.probe);
    cJSON_Delete(root);
    return rc;
}
