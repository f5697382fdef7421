/* tradeoff.c - the engine of squish tradeoff (server/app/cmd_tradeoff.c): the grid of settings
 * as scene variants, one run of a variant measured against the reference at the reference's
 * surface samples and the scene's probes, and the numbers drawn from the runs (equal-error cost,
 * medians of the guarded runs, the Pareto front).
 */
#include <cJSON.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "engines/engines.h"

/* the cached reference's layout (SQ_TRADEOFF_REF): 2 adds the reference run's cost, so a fixed
 * row read from the cache keeps its CPU time (format 1 files are stepped and written again) */
#define REF_FILE_FORMAT 2L

static sq_tradeoff_debug debug = {.adaptive_max_level = -1};

void sq_tradeoff_set_debug(const sq_tradeoff_debug *d)
{
    debug = *d;
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
int sq_tradeoff_body_finest(const cJSON *body, int override)
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
void sq_tradeoff_scene_caps(const cJSON *root, double caps[SQ_MAX_BODIES])
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
char *sq_tradeoff_variant_text(cJSON *root, const sq_tradeoff_variant *v, int finest_override, const double caps[SQ_MAX_BODIES],
                          const int sharp[SQ_MAX_BODIES])
{
    cJSON *bodies = cJSON_GetObjectItemCaseSensitive(root, "bodies");
    cJSON *body;
    int bi = 0;
    cJSON_ArrayForEach(body, bodies)
    {
        int fin = sq_tradeoff_body_finest(body, finest_override);
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
        /* debugging: the adaptive rows (unbudgeted and guarded) with lod.max_level at most K,
         * measured against the same reference (docs/lod.md "The depth of the adaptive body") */
        if (v->adaptive && debug.adaptive_max_level >= 0)
            fin = SQ_MIN(fin, debug.adaptive_max_level);
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
double sq_tradeoff_scene_split(const cJSON *root)
{
    const cJSON *b0 = cJSON_GetArrayItem(cJSON_GetObjectItemCaseSensitive(root, "bodies"), 0);
    const cJSON *lod = b0 ? cJSON_GetObjectItemCaseSensitive(b0, "lod") : NULL;
    const cJSON *sp = lod ? cJSON_GetObjectItemCaseSensitive(lod, "split") : NULL;
    return cJSON_IsNumber(sp) && sp->valuedouble > 0 ? sp->valuedouble : 0.005;
}

/* the grid's rows: each a kind, fixed (its level) or adaptive (its split), an operator, a step
 * fraction and, for the integrator rows, backward Euler's steps a frame and CG tolerance */
typedef struct {
    sq_tradeoff_variant *v;
    int n;
} grid;

static void row(grid *g, sq_tradeoff_variant proto, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static void row(grid *g, sq_tradeoff_variant proto, const char *fmt, ...)
{
    sq_tradeoff_variant *v = &g->v[g->n++];
    *v = proto;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(v->name, sizeof v->name, fmt, ap);
    va_end(ap);
}

#define FIXED(kind, level, op, fraction) ((sq_tradeoff_variant){"", kind, 0, level, 0, op, fraction, 0, 0, 0})
#define ADAPTIVE(kind, split, op, fraction) ((sq_tradeoff_variant){"", kind, 1, 0, split, op, fraction, 0, 0, 0})
#define IMPLICIT(level, substeps, tol) ((sq_tradeoff_variant){"", "integrator", 0, level, 0, SQ_OPERATOR_FEM, 0.9, 1, substeps, tol})

int sq_tradeoff_build_grid(sq_tradeoff_variant *v, int finest, double s0, int quick, double ref_fraction)
{
    grid g = {v, 0};
    row(&g, FIXED("reference", finest, SQ_OPERATOR_FEM, ref_fraction), "reference"); /* the reference first */
    for (int k = 0; k <= finest; k++)
        row(&g, FIXED("fixed", k, SQ_OPERATOR_FEM, 0.9), "fixed L%d", k);
    static const double full_f[] = {0, 0.1, 0.3, 1, 3, 10, INFINITY};
    static const double quick_f[] = {0.3, 1, 3};
    const double *f = quick ? quick_f : full_f;
    int nf = quick ? (int)SQ_COUNTOF(quick_f) : (int)SQ_COUNTOF(full_f);
    for (int i = 0; finest > 0 && i < nf; i++) {
        if (isinf(f[i]))
            row(&g, ADAPTIVE("adaptive", INFINITY, SQ_OPERATOR_FEM, 0.9), "adaptive split inf");
        else
            row(&g, ADAPTIVE("adaptive", f[i] * s0, SQ_OPERATOR_FEM, 0.9), "adaptive split %.3g", f[i] * s0);
    }
    row(&g, FIXED("step", finest, SQ_OPERATOR_FEM, 0.5), "fixed L%d step 0.5", finest);
    if (!quick) /* finer than the reference: its error is the floor below which differences are
                 * noise (tool contact sets change with the step) */
        row(&g, FIXED("step", finest, SQ_OPERATOR_FEM, 0.1), "fixed L%d step 0.1", finest);
    if (!quick && finest > 0) {
        row(&g, ADAPTIVE("step", s0, SQ_OPERATOR_FEM, 0.25), "adaptive split %.3g step 0.25", s0);
        row(&g, ADAPTIVE("step", s0, SQ_OPERATOR_FEM, 0.5), "adaptive split %.3g step 0.5", s0);
    }
    /* the integrator axis: backward Euler on the finest level at 1, 2 and 4 steps a frame (CG to
     * 1e-6), and at one step with looser and tighter tolerances */
    static const int subs[] = {1, 2, 4};
    for (size_t k = 0; k < SQ_COUNTOF(subs); k++)
        if (!(quick && subs[k] == 2))
            row(&g, IMPLICIT(finest, subs[k], 1e-6), "implicit L%d x%d tol 1e-6", finest, subs[k]);
    static const double tols[] = {1e-3, 1e-9};
    for (size_t k = 0; k < SQ_COUNTOF(tols); k++)
        if (!(quick && k))
            row(&g, IMPLICIT(finest, 1, tols[k]), "implicit L%d x1 tol %g", finest, tols[k]);
    row(&g, FIXED("operator", finest, SQ_OPERATOR_PAPER, 0.9), "paper fixed L%d", finest);
    if (!quick && finest > 0) {
        row(&g, ADAPTIVE("operator", s0, SQ_OPERATOR_PAPER, 0.9), "paper adaptive split %.3g", s0);
        row(&g, FIXED("operator", 0, SQ_OPERATOR_PAPER, 0.9), "paper fixed L0");
    }
    return g.n;
}

/* ---- sampling ------------------------------------------------------------------------------ */

/* the level a body simulates whose values are the most detailed (fixed: its only level;
 * adaptive: the finest, which holds active or ghost values everywhere) */
static int sampled_level(const sq_body *b)
{
    return sq_body_sim_level(b);
}

static void samples_init(sq_tradeoff_samples *s, const sq_body *ref)
{
    const sq_mesh *m = sq_body_surface_mesh(ref);
    int stride = (m->nsurf + SQ_TRADEOFF_MAX_SAMPLES - 1) / SQ_TRADEOFF_MAX_SAMPLES;
    s->n = (m->nsurf + stride - 1) / stride;
    s->x = sq_malloc(sizeof(double) * 3 * (size_t)s->n);
    s->tet = sq_malloc(sizeof(int) * (size_t)s->n);
    s->bary = sq_malloc(sizeof(double) * 4 * (size_t)s->n);
    for (int i = 0; i < s->n; i++)
        memcpy(s->x + 3 * i, m->x + 3 * (size_t)m->surf_nodes[i * stride], sizeof(double) * 3);
}

/* locate the samples in the body's sampled level (nearest tet when outside it) */
static void samples_locate(sq_tradeoff_samples *s, const sq_body *b)
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
static void samples_eval(const sq_tradeoff_samples *s, const sq_body *b, double *u)
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

static void samples_free(sq_tradeoff_samples *s)
{
    free(s->x);
    free(s->tet);
    free(s->bary);
}

/* ---- the runs ------------------------------------------------------------------------------- */


/* the reference run's set-up: its samples (the rest positions of its surface vertices) and the
 * storage of every frame's samples and probes; -1 when that is too large (r->error) */
static int ref_setup(sq_tradeoff_ref *ref, const sq_scene *scene, const sq_world *w, sq_tradeoff_result *r)
{
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
        return -1;
    }
    ref->u = sq_malloc(sizeof(double) * 3 * (size_t)ref->ntotal * (size_t)(ref->nframes + 1));
    ref->probe = sq_malloc(sizeof(double) * 3 * (size_t)(ref->nprobes + 1) * (size_t)(ref->nframes + 1));
    return 0;
}

/* sizes of the reference's stored samples and probes (doubles) */
static size_t ref_nu(const sq_tradeoff_ref *ref)
{
    return 3 * (size_t)ref->ntotal * (size_t)(ref->nframes + 1);
}

static size_t ref_np(const sq_tradeoff_ref *ref)
{
    return 3 * (size_t)(ref->nprobes + 1) * (size_t)(ref->nframes + 1);
}

/* debugging: SQ_TRADEOFF_REF=FILE keeps the reference's samples in FILE (written by the first
 * run, read by later ones instead of stepping it). 1: read, r holds the reference run's cost */
static int ref_file_read(const char *ref_file, sq_tradeoff_ref *ref, const sq_scene *scene, sq_tradeoff_result *r)
{
    FILE *rf = fopen(ref_file, "rb");
    if (!rf)
        return 0;
    /* the file's shape first: a reference of another scene (another sampled surface, probe
     * count or frame count) is not read, but stepped and written again */
    size_t nu = ref_nu(ref), np = ref_np(ref);
    long shape[4] = {0, 0, 0, 0}, want[4] = {ref->ntotal, ref->nprobes, ref->nframes, REF_FILE_FORMAT};
    double cost[3]; /* the reference run's node updates, wall and thread CPU time */
    int okr = fread(shape, sizeof(long), 4, rf) == 4 && !memcmp(shape, want, sizeof shape) &&
              fread(ref->u, sizeof(double), nu, rf) == nu && fread(ref->probe, sizeof(double), np, rf) == np &&
              fread(&ref->rms_ref, sizeof(double), 1, rf) == 1 && fread(&ref->max_ref, sizeof(double), 1, rf) == 1 &&
              fread(cost, sizeof(double), 3, rf) == 3;
    fclose(rf);
    if (!okr)
        return 0;
    r->updates = cost[0];
    r->wall = cost[1];
    r->cpu = cost[2];
    r->frames = ref->nframes;
    r->sim_s = (double)ref->nframes / scene->frame_rate;
    r->ups = r->updates / r->sim_s;
    r->wps = r->wall / r->sim_s;
    r->cps = r->cpu / r->sim_s;
    r->ok = 1;
    return 1;
}

static void ref_file_write(const char *ref_file, const sq_tradeoff_ref *ref, const sq_tradeoff_result *r)
{
    FILE *rf = ref_file ? fopen(ref_file, "wb") : NULL;
    if (!rf)
        return;
    long shape[4] = {ref->ntotal, ref->nprobes, ref->nframes, REF_FILE_FORMAT};
    double cost[3] = {r->updates, r->wall, r->cpu};
    fwrite(shape, sizeof(long), 4, rf);
    fwrite(ref->u, sizeof(double), ref_nu(ref), rf);
    fwrite(ref->probe, sizeof(double), ref_np(ref), rf);
    fwrite(&ref->rms_ref, sizeof(double), 1, rf);
    fwrite(&ref->max_ref, sizeof(double), 1, rf);
    fwrite(cost, sizeof(double), 3, rf);
    fclose(rf);
}

/* with the live budget the run models the server's session thread (server/net/session.c):
 * each frame is stepped, then published (every body's surface state and its encoded frame, as
 * `squish serve` sends it); the guard sees publishing as the thread's time around the lod
 * frame, as in the server, and the late-frame count and slowest frame include it */
typedef struct to_publisher {
    sq_codec codec[SQ_MAX_BODIES];
    float *xyz;
    unsigned char *lev;
} to_publisher;

static void publisher_init(to_publisher *p, sq_world *w)
{
    int maxs = 1;
    for (int b = 0; b < w->nbodies; b++) {
        const sq_mesh *m = sq_body_surface_mesh(w->bodies[b]);
        sq_codec_init_surface(&p->codec[b], m, SQ_CODEC_PRECISION); /* serve's default */
        maxs = SQ_MAX(maxs, m->nsurf);
    }
    p->xyz = sq_malloc(sizeof(float) * 3 * (size_t)maxs);
    p->lev = sq_malloc((size_t)maxs);
    sq_world_prepare_budget(w); /* at load, as the server and `squish run --realtime` */
}

static void publisher_frame(to_publisher *p, sq_world *w)
{
    for (int b = 0; b < w->nbodies; b++) {
        sq_world_surface_state(w, b, p->xyz, p->lev);
        sq_blob_unref(sq_encode_frame(&p->codec[b], (uint32_t)b, (uint32_t)w->frame, w->time, 0, p->xyz, p->lev,
                                      w->tools, w->feedback[b], w->ntools));
    }
}

static void publisher_free(to_publisher *p, const sq_world *w)
{
    for (int b = 0; b < w->nbodies; b++)
        sq_codec_free(&p->codec[b]);
    free(p->xyz);
    free(p->lev);
}

/* frame f's surface samples: stored (record) or compared with the reference's; *fs: the sum of
 * |u - u_ref|^2 (record: of |u|^2) over the samples, *fm: its largest root */
static void frame_surface(sq_tradeoff_ref *ref, const sq_world *w, int record, long f, double *u, double *fs,
                          double *fm)
{
    double *ur = ref->u + 3 * (size_t)ref->ntotal * (size_t)f;
    int off = 0;
    for (int b = 0; b < w->nbodies; b++) {
        samples_eval(&ref->smp[b], w->bodies[b], (record ? ur : u) + 3 * off);
        off += ref->smp[b].n;
    }
    *fs = 0;
    *fm = 0;
    for (int i = 0; i < ref->ntotal; i++) {
        double e2 = 0;
        for (int c = 0; c < 3; c++) {
            double a = record ? ur[3 * i + c] : u[3 * i + c] - ur[3 * i + c];
            e2 += a * a;
        }
        if (!isfinite(e2))
            e2 = INFINITY;
        *fs += e2;
        *fm = fmax(*fm, sqrt(e2));
    }
}

/* frame f's probes: stored (record) or their largest distance from the reference's in r */
static void frame_probes(sq_tradeoff_ref *ref, sq_world *w, int record, long f, sq_tradeoff_result *r)
{
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
}

/* SQ_TRADEOFF_TRACE: one frame of a budgeted run (error, CPU, active nodes per level) on stderr */
static void trace_frame(const sq_world *w, long f, double rms, double fm, double c, double cp, double cs)
{
    fprintf(stderr, "frame %3ld rms %.3f mm max %.2f mm cpu %.2f ms publish %.2f sampling %.2f active", f, 1e3 * rms,
            1e3 * fm, 1e3 * c, 1e3 * cp, 1e3 * cs);
    for (int k = 0; k < SQ_MAX_LEVELS && k < 4; k++)
        fprintf(stderr, " %d", w->profile[0].active[k]);
    fprintf(stderr, " splits %d merges %d refused %d\n", w->profile[0].splits, w->profile[0].merges,
            w->profile[0].splits_refused);
}

/* the frames of one run: step (with the live budget when budget_s > 0, then publish), count the
 * cost, sample the surface and the probes. The error sampling is the harness's, not the
 * product's: its thread CPU time is kept out of the guard's view (sq_world_untimed) */
static void run_frames(sq_world *w, sq_tradeoff_ref *ref, int record, sq_tradeoff_result *r, double budget_s,
                       int trace, sq_progress *prog, double *prog_done)
{
    double *u = sq_malloc(sizeof(double) * 3 * (size_t)ref->ntotal);
    double sum_ref = 0;
    long cnt_ref = 0;
    double period = 1.0 / w->scene->frame_rate;
    to_publisher pub;
    if (budget_s > 0)
        publisher_init(&pub, w);
    for (long f = 1; f <= ref->nframes; f++) {
        double t0 = sq_now(), c0 = sq_thread_cpu();
        sq_world_step(w, budget_s); /* 0: no budget (deterministic); > 0: the live budget, the guard on */
        double c1 = sq_thread_cpu(), c = c1 - c0, cp = 0;
        r->wall += sq_now() - t0;
        r->cpu += c;
        if (budget_s > 0) {
            publisher_frame(&pub, w);
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
        double fs, fm;
        frame_surface(ref, w, record, f, u, &fs, &fm);
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
        frame_probes(ref, w, record, f, r);
        double cs = sq_thread_cpu() - cs0;
        r->cpu_smp += cs;
        if (budget_s > 0)
            sq_world_untimed(w, cs);
        if (trace)
            trace_frame(w, f, sqrt(fs / SQ_MAX(1, ref->ntotal)), fm, c, cp, cs);
        *prog_done += 1;
        sq_progress_update(prog, *prog_done);
    }
    if (record)
        ref->rms_ref = cnt_ref ? sqrt(sum_ref / cnt_ref) : 0;
    if (budget_s > 0)
        publisher_free(&pub, w);
    free(u);
}

/* run one variant; ref->u is recorded when record != 0, else errors are measured against it */
int sq_tradeoff_run_variant(const sq_scene *scene, sq_tradeoff_ref *ref, int record, sq_tradeoff_result *r,
                            sq_progress *prog, double *prog_done, double budget_s)
{
    sq_err err = {{0}};
    sq_world *w = sq_world_create(scene, &err);
    if (!w) {
        snprintf(r->error, sizeof r->error, "%.290s", err.msg);
        return -1;
    }
    if (record && ref_setup(ref, scene, w, r) != 0) {
        sq_world_destroy(w);
        return -1;
    }
    for (int b = 0; b < w->nbodies; b++)
        samples_locate(&ref->smp[b], w->bodies[b]);
    {
        const sq_body *b0 = w->bodies[0];
        int k = sampled_level(b0);
        double dt = sq_body_level_dt(b0, k);
        r->substeps_finest = dt > 0 ? (int)lround(sq_body_get_def(b0)->frame_dt / dt) : 0;
    }
    /* debugging (sq_tradeoff_debug): the cached reference; each frame traced */
    const char *ref_file = debug.ref_file;
    const int trace = debug.trace > 1 || (debug.trace > 0 && budget_s > 0);
    if (record && ref_file && ref_file_read(ref_file, ref, scene, r)) {
        sq_world_destroy(w);
        return 0;
    }
    run_frames(w, ref, record, r, budget_s, trace, prog, prog_done);
    if (record)
        ref_file_write(ref_file, ref, r);
    r->frames = ref->nframes;
    r->sim_s = w->time;
    r->resets = w->resets;
    r->rms = r->count ? sqrt(r->sum_sq / r->count) : 0;
    r->ups = r->sim_s > 0 ? r->updates / r->sim_s : 0;
    r->wps = r->sim_s > 0 ? r->wall / r->sim_s : 0;
    r->cps = r->sim_s > 0 ? r->cpu / r->sim_s : 0;
    r->ok = 1;
    sq_world_destroy(w);
    return 0;
}

/* the cheapest fixed-level cost reaching RMS error e: a fixed level with error <= e, or the
 * log-log interpolation between consecutive levels k, k+1 whose errors bracket e; -1 when no
 * fixed level is that accurate */
double sq_tradeoff_fixed_cost_at(const sq_tradeoff_variant *v, const sq_tradeoff_result *r, int n, double e, int wall)
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
void sq_tradeoff_spread(double *x, int k, double out[3])
{
    qsort(x, (size_t)k, sizeof *x, cmp_dbl);
    out[0] = x[0];
    out[1] = x[(k - 1) / 2];
    out[2] = x[k - 1];
}

/* r[gmed]: each column's median over the completed runs r[g0..gmed-1] (resets: the largest) */
void sq_tradeoff_guarded_median(sq_tradeoff_result *r, int g0, int gmed)
{
    double x[SQ_TRADEOFF_MAX_GUARDED], o[3];
    int k = 0;
    sq_tradeoff_result *m = &r[gmed];
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
        sq_tradeoff_spread(x, c, o);                                                                                           \
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

/* frees the reference's samples and stored frames */
void sq_tradeoff_ref_free(sq_tradeoff_ref *ref)
{
    for (int b = 0; b < ref->nbodies; b++)
        samples_free(&ref->smp[b]);
    free(ref->u);
    free(ref->probe);
}

/* the Pareto front over the fem settings (the paper operator is a different model), without
 * the runs with the live budget (not deterministic: they neither sit on it nor push a setting
 * off it) */
void sq_tradeoff_pareto(const sq_tradeoff_variant *v, sq_tradeoff_result *r, int n)
{
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
}
