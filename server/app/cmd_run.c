/* cmd_run.c - squish run: a batch, headless, deterministic run of a scene.
 *
 *   squish run SCENE.json [--frames N | --seconds T | --until-rest] [--out DIR]
 *   squish run --default ...
 *
 * Writes DIR/probes.csv (frame,time,probe,ux,uy,uz), DIR/stats.csv (per frame profile),
 * DIR/tools.csv (tool poses and feedback forces) and DIR/final.vtk. probes.csv and final.vtk are byte-identical for the same input; only the
 * wall-time column of stats.csv changes between runs. Exit codes: 0 done, 1 bad scene or
 * output error, 2 usage.
 */
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "app/commands.h"
#include "scene/scene.h"
#include "body/body.h"

/* --until-rest defaults (documented in docs/scenes.md) */
#define REST_KE_PER_KG 1e-8   /* kinetic energy per kg of body, J/kg (rms speed ~1.4e-4 m/s) */
#define REST_RESIDUAL 1e-3    /* max |f_i| / (m_i |g|): unbalanced force below 0.1% of the weight */
#define REST_MAX_FRAMES 3000L /* cap: 60 s of simulated time at 50 Hz */

static void usage(FILE *f)
{
    fprintf(f,
            "usage: squish run SCENE.json [--frames N | --seconds T | --until-rest] [--out DIR]\n"
            "       squish run --default [...]   (the paper's 1 m cube, built in)\n"
            "\n"
            "  --frames N          run N frames (default: the scene's \"duration\")\n"
            "  --seconds T         run T seconds of simulated time\n"
            "  --until-rest        run until every body is at rest (after the last tool keyframe):\n"
            "                      kinetic energy per kg below --rest-ke (default %g J/kg) and\n"
            "                      residual force below --rest-residual (default %g of the weight),\n"
            "                      at most --max-frames frames (default %ld)\n"
            "  --realtime          give each frame the frame period as compute budget, as the server\n"
            "                      does (splits refused when over; outputs no longer deterministic)\n"
            "  --out DIR           output directory (default ./squish-out): probes.csv, stats.csv,\n"
            "                      tools.csv, final.vtk\n",
            REST_KE_PER_KG, REST_RESIDUAL, REST_MAX_FRAMES);
}

static int usage_error(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static int usage_error(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "squish run: ");
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\nrun 'squish run --help' for the options\n");
    va_end(ap);
    return 2;
}

/* parse a number argument fully; 0 on success */
static int parse_double(const char *s, double *out)
{
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    if (end == s || *end || errno || !isfinite(v))
        return -1;
    *out = v;
    return 0;
}

static FILE *open_out(const char *dir, const char *name, char *path, size_t n)
{
    snprintf(path, n, "%s/%s", dir, name);
    FILE *f = fopen(path, "w");
    if (!f)
        fprintf(stderr, "squish run: cannot write %s: %s; check that the --out directory is writable\n", path,
                strerror(errno));
    return f;
}

/* mass of a body from its finest loaded mesh (density x volume), kg */
static double body_mass(const sq_body *b)
{
    const sq_body_def *def = sq_body_get_def(b);
    const sq_mesh *m = def->levels[def->nlevels - 1];
    double v = 0;
    for (int t = 0; t < m->ntets; t++)
        v += sq_tet_volume(m, t);
    return v * def->material.density;
}

/* last keyframe time over the scene's tools: rest is only checked after it */
static double last_keyframe(const sq_scene *s)
{
    double t = 0;
    for (int i = 0; i < s->ntools; i++)
        if (s->tools[i].nkeys > 0)
            t = fmax(t, s->tools[i].keys[s->tools[i].nkeys - 1].t);
    return t;
}

static void print_setup(const sq_scene *s, const sq_world *w)
{
    printf("scene %s (%s): %d bod%s, %d tool%s, %d probe%s, %g Hz\n", s->name, s->path, s->nbodies,
           s->nbodies == 1 ? "y" : "ies", s->ntools, s->ntools == 1 ? "" : "s", s->nprobes,
           s->nprobes == 1 ? "" : "s", s->frame_rate);
    for (int b = 0; b < w->nbodies; b++) {
        const sq_body_def *def = sq_body_get_def(w->bodies[b]);
        double E, nu;
        sq_material_E_nu(&def->material, &E, &nu);
        printf("body %s: %s operator, %s elasticity, %s lod, E %.4g Pa, nu %.4g, density %g kg/m^3\n",
               s->body_names[b], def->op == SQ_OPERATOR_PAPER ? "paper" : "fem",
               def->elasticity == SQ_ELASTICITY_COROTATIONAL ? "corotational" : "linear",
               def->lod.mode == SQ_LOD_ADAPTIVE ? "adaptive" : "fixed", E, nu, def->material.density);
        int nl = sq_body_nlevels(w->bodies[b]);
        for (int k = 0; k < nl; k++) {
            double dt = sq_body_level_dt(w->bodies[b], k), bound = sq_body_level_bound(w->bodies[b], k);
            const sq_mesh *m = sq_body_mesh(w->bodies[b], k);
            long sub = dt > 0 ? lround(def->frame_dt / dt) : 0;
            if (!(dt > 0)) {
                printf("  level %d (%d nodes): loaded, not simulated in fixed mode\n", s->level_index[b][k],
                       m ? m->nnodes : 0);
                continue;
            }
            printf("  level %d (%d nodes): bound %.3g s, %ld substeps/frame, dt %.3g s\n", s->level_index[b][k],
                   m ? m->nnodes : 0, bound, sub, dt);
            const sq_level *L = sq_body_level(w->bodies[b], k);
            if (L && def->lod.mode == SQ_LOD_FIXED)
                printf("    step bounds: Gershgorin %.3g s (%d substeps, 2^n), sharp %.3g s (Lanczos omega %.4g rad/s, "
                       "Gershgorin/Lanczos %.3f: %d substeps)%s\n", L->bound, 1 << L->substeps_log2, L->bound_sharp,
                       L->omega_est, L->omega_max / L->omega_est, L->nsub,
                       def->sharp_step ? ", sharp in use" : ", Gershgorin in use");
        }
    }
    fflush(stdout);
}

static void write_probe_rows(FILE *f, const sq_world *w)
{
    const sq_scene *s = w->scene;
    for (int p = 0; p < s->nprobes; p++) {
        double u[3];
        if (sq_world_probe(w, p, u) != 0)
            u[0] = u[1] = u[2] = NAN;
        fprintf(f, "%ld,%.9e,%s,%.9e,%.9e,%.9e\n", w->frame, w->time, s->probes[p].name, u[0], u[1], u[2]);
    }
}

/* one row per tool and body: the pose used this frame and the body's reaction on it */
static void write_tool_rows(FILE *f, const sq_world *w)
{
    for (int t = 0; t < w->ntools; t++)
        for (int b = 0; b < w->nbodies; b++) {
            const sq_tool *tl = &w->tools[t];
            const sq_tool_feedback *fb = &w->feedback[b][t];
            fprintf(f, "%ld,%.9e,%d,%s,%d,%.9e,%.9e,%.9e,%.9e,%.9e,%.9e,%d\n", w->frame, w->time, tl->id,
                    w->scene->body_names[b], tl->active, tl->pos[0], tl->pos[1], tl->pos[2], fb->force[0],
                    fb->force[1], fb->force[2], fb->nnodes);
        }
}

/* the command line */
typedef struct run_opts {
    const char *scene_path, *out;
    int use_default, until_rest, nmodes, realtime;
    long frames, max_frames;
    double seconds, rest_ke, rest_res;
} run_opts;

/* -1: go on; else the exit code (--help, a usage error) */
static int parse_args(int argc, char **argv, run_opts *o)
{
    *o = (run_opts){NULL, "squish-out", 0, 0, 0, 0, -1, REST_MAX_FRAMES, -1, REST_KE_PER_KG, REST_RESIDUAL};
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        int has_val = i + 1 < argc;
        double v;
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(a, "--default")) {
            o->use_default = 1;
        } else if (!strcmp(a, "--realtime")) {
            o->realtime = 1;
        } else if (!strcmp(a, "--until-rest")) {
            o->until_rest = 1;
            o->nmodes++;
        } else if (!strcmp(a, "--frames") || !strcmp(a, "--max-frames")) {
            if (!has_val || parse_double(argv[i + 1], &v) || v < 0 || v != floor(v) || v > 1e9)
                return usage_error("%s needs a whole number of frames (0 to 1e9)", a);
            if (!strcmp(a, "--frames")) {
                o->frames = (long)v;
                o->nmodes++;
            } else {
                o->max_frames = (long)v;
            }
            i++;
        } else if (!strcmp(a, "--seconds")) {
            if (!has_val || parse_double(argv[i + 1], &v) || v < 0 || v > 1e7)
                return usage_error("%s needs a simulated time in seconds (0 to 1e7)", a);
            o->seconds = v;
            o->nmodes++;
            i++;
        } else if (!strcmp(a, "--rest-ke") || !strcmp(a, "--rest-residual")) {
            if (!has_val || parse_double(argv[i + 1], &v) || !(v > 0))
                return usage_error("%s needs a tolerance > 0", a);
            if (!strcmp(a, "--rest-ke"))
                o->rest_ke = v;
            else
                o->rest_res = v;
            i++;
        } else if (!strcmp(a, "--out")) {
            if (!has_val || !argv[i + 1][0])
                return usage_error("%s needs a directory", a);
            o->out = argv[++i];
        } else if (a[0] == '-') {
            return usage_error("unknown option '%s'", a);
        } else if (o->scene_path) {
            return usage_error("more than one scene given ('%s'); run one scene at a time", a);
        } else {
            o->scene_path = a;
        }
    }
    if (!o->scene_path && !o->use_default)
        return usage_error("no scene given; pass SCENE.json or --default");
    if (o->scene_path && o->use_default)
        return usage_error("give either SCENE.json or --default, not both");
    if (o->nmodes > 1)
        return usage_error("--frames, --seconds and --until-rest exclude each other; give one");

    return -1;
}

/* what the run adds up over its frames */
typedef struct run_totals {
    long updates;
    long iface[3];                 /* ring values, ring rows, frontier rows (adaptive bodies) */
    double sub_sum[SQ_MAX_LEVELS]; /* substeps of the frames a listed level has active nodes */
    long sub_frames[SQ_MAX_LEVELS];
    double mass[SQ_MAX_BODIES];
    int at_rest;
    double rest_ke_seen, rest_res_seen;
} run_totals;

/* the headers of the three CSV files; returns the number of listed levels (active_l columns) */
static int write_headers(FILE *fp, FILE *fs, FILE *ft, const sq_world *w)
{
    /* active counts per level as listed in the scene file, summed over bodies */
    int maxl = 0;
    for (int b = 0; b < w->nbodies; b++)
        for (int k = 0; k < sq_body_nlevels(w->bodies[b]); k++)
            maxl = SQ_MAX(maxl, sq_world_listed_level(w, b, k) + 1);
    fprintf(fp, "frame,time,probe,ux,uy,uz\n");
    fprintf(ft, "frame,time,tool,body,active,x,y,z,fx,fy,fz,nodes\n");
    fprintf(fs, "frame,time,node_updates,wall_ms");
    for (int k = 0; k < maxl; k++)
        fprintf(fs, ",active_l%d", k);
    fprintf(fs, ",splits,merges,resets,kinetic_energy,refused,health,missed,cg_iterations,cg_residual\n");
    return maxl;
}

/* the frame just stepped: its stats.csv row (missed0: the deadline misses before it), its
 * events on stdout, its counts into t */
static void stats_row(FILE *fs, const sq_world *w, int maxl, long missed0, run_totals *t, const sq_progress *prog)
{
    long nu = 0;
    int active[SQ_MAX_LEVELS] = {0}, splits = 0, merges = 0, resets = 0, refused = 0;
    long cg_it = 0;
    double ke = 0, cg_res = 0;
    char health[96] = ""; /* the frame's health warning kinds, '+' between bodies */
    for (int b = 0; b < w->nbodies; b++) {
        const sq_frame_profile *pr = &w->profile[b];
        if (pr->event_kind != SQ_HEALTH_NONE && strlen(health) + 24 < sizeof health)
            snprintf(health + strlen(health), sizeof health - strlen(health), "%s%s", health[0] ? "+" : "",
                     sq_health_kind_name(pr->event_kind));
        nu += pr->node_updates;
        cg_it += pr->cg_iterations;
        cg_res = SQ_MAX(cg_res, pr->cg_residual);
        t->iface[0] += pr->ring_values;
        t->iface[1] += pr->ring_rows;
        t->iface[2] += pr->frontier_rows;
        for (int k = 0; k < sq_body_nlevels(w->bodies[b]); k++) {
            active[sq_world_listed_level(w, b, k)] += pr->active[k];
            if (pr->active[k] > 0) {
                t->sub_sum[sq_world_listed_level(w, b, k)] += pr->substeps[k];
                t->sub_frames[sq_world_listed_level(w, b, k)]++;
            }
        }
        splits += pr->splits;
        refused += pr->splits_refused;
        merges += pr->merges;
        resets += pr->reset;
        ke += sq_body_kinetic_energy(w->bodies[b]);
        if (pr->event[0] || pr->reset) {
            if (prog->enabled)
                fputc('\n', stderr);
            printf("frame %ld (t = %.4f s): body %s: %s\n", w->frame, w->time, w->scene->body_names[b],
                   pr->event[0] ? pr->event : "blow-up: body reset to rest");
            fflush(stdout);
        }
    }
    t->updates += nu;
    fprintf(fs, "%ld,%.9e,%ld,%.3f", w->frame, w->time, nu, 1000.0 * w->last_frame_s);
    for (int k = 0; k < maxl; k++)
        fprintf(fs, ",%d", active[k]);
    fprintf(fs, ",%d,%d,%d,%.9e,%d,%s,%ld,%ld,%.3e\n", splits, merges, resets, ke, refused, health,
            w->deadline_misses - missed0, cg_it, cg_res);
}

/* rest: every body calm (or asleep); the largest kinetic energy per kg and residual seen go to t */
static int at_rest(const sq_world *w, const run_opts *o, run_totals *t)
{
    int calm = 1;
    t->rest_ke_seen = 0;
    t->rest_res_seen = 0;
    for (int b = 0; b < w->nbodies && calm; b++) {
        if (sq_body_is_sleeping(w->bodies[b]))
            continue;
        double kpm = t->mass[b] > 0 ? sq_body_kinetic_energy(w->bodies[b]) / t->mass[b] : 0;
        t->rest_ke_seen = fmax(t->rest_ke_seen, kpm);
        if (kpm >= o->rest_ke) {
            calm = 0;
            break;
        }
        double r = sq_body_residual(w->bodies[b]);
        t->rest_res_seen = fmax(t->rest_res_seen, r);
        if (!(r < o->rest_res))
            calm = 0;
    }
    return calm;
}

/* final.vtk (body 0) and final_NAME.vtk per body when there are several; 0 or 1 */
static int write_final(sq_world *w, const char *out)
{
    int rc = 0;
    sq_err err = {{0}};
    char vpath[1100];
    for (int b = 0; b < w->nbodies; b++) {
        char name[128];
        if (b == 0) {
            snprintf(vpath, sizeof vpath, "%s/final.vtk", out);
            if (sq_world_write_vtk(w, b, vpath, &err)) {
                fprintf(stderr, "squish run: %s\n", err.msg);
                rc = 1;
            }
        }
        if (w->nbodies > 1) {
            snprintf(name, sizeof name, "final_%s.vtk", w->scene->body_names[b]);
            snprintf(vpath, sizeof vpath, "%s/%s", out, name);
            if (sq_world_write_vtk(w, b, vpath, &err)) {
                fprintf(stderr, "squish run: %s\n", err.msg);
                rc = 1;
            }
        }
    }
    return rc;
}

/* the closing lines on stdout */
static void print_summary(const sq_world *w, const run_opts *o, const run_totals *t, long nframes, double wall,
                          double budget)
{
    printf("done: %ld frames, %.4g s simulated in %.3g s wall (%.3g x real time), %ld node updates "
           "(%.3g node-steps/s), %ld resets\n",
           w->frame, w->time, wall, wall > 0 ? w->time / wall : 0, t->updates, wall > 0 ? t->updates / wall : 0,
           w->resets);
    if (t->iface[0] + t->iface[1] + t->iface[2] > 0)
        printf("interface (adaptive bodies): %ld ring values, %ld ring rows, %ld frontier rows (per node update "
               "%.3g, %.3g, %.3g)\n",
               t->iface[0], t->iface[1], t->iface[2], t->updates > 0 ? (double)t->iface[0] / (double)t->updates : 0,
               t->updates > 0 ? (double)t->iface[1] / (double)t->updates : 0,
               t->updates > 0 ? (double)t->iface[2] / (double)t->updates : 0);
    if (t->sub_frames[0] + t->sub_frames[1] > 0) {
        printf("substeps per frame by level (mean over the frames the level has active nodes):");
        for (int k = 0; k < SQ_MAX_LEVELS; k++)
            if (t->sub_frames[k] > 0)
                printf(" L%d %.2f (%ld frames)", k, t->sub_sum[k] / (double)t->sub_frames[k], t->sub_frames[k]);
        printf("\n");
    }
    for (int b = 0; b < w->nbodies; b++) {
        long nest;
        double cpu;
        sq_body_step_bound_cost(w->bodies[b], &nest, &cpu);
        if (nest > 0)
            printf("body %s: sharp step bound: %ld estimates, %.4g s thread CPU (%.3g ms each)\n",
                   w->scene->body_names[b], nest, cpu, 1e3 * cpu / (double)nest);
    }
    if (o->realtime)
        printf("realtime: %ld of %ld frames over the %.4g s period (%.2f%%)\n", w->deadline_misses, w->frame, budget,
               w->frame > 0 ? 100.0 * (double)w->deadline_misses / (double)w->frame : 0.0);
    if (o->until_rest) {
        if (t->at_rest)
            printf("at rest at frame %ld (t = %.4g s)\n", w->frame, w->time);
        else
            printf("warning: not at rest after the cap of %ld frames (last kinetic energy %.3g J/kg, residual "
                   "%.3g); raise --max-frames or add damping\n",
                   nframes, t->rest_ke_seen, t->rest_res_seen);
    }
    for (int p = 0; p < w->scene->nprobes; p++) {
        double u[3];
        if (sq_world_probe(w, p, u) == 0)
            printf("probe %s: u = (%.6g, %.6g, %.6g) m\n", w->scene->probes[p].name, u[0], u[1], u[2]);
    }
    printf("wrote %s/probes.csv, %s/stats.csv, %s/tools.csv, %s/final.vtk\n", o->out, o->out, o->out, o->out);
}

int sq_cmd_run(int argc, char **argv)
{
    run_opts o;
    int rc = parse_args(argc, argv, &o);
    if (rc >= 0)
        return rc;

    /* scene and world */
    sq_err err = {{0}};
    sq_scene *scene = o.use_default ? sq_scene_default(&err) : sq_scene_load(o.scene_path, &err);
    if (!scene) {
        fprintf(stderr, "squish run: %s\n", err.msg);
        return 1;
    }
    sq_world *w = sq_world_create(scene, &err);
    if (!w) {
        fprintf(stderr, "squish run: %s\n", err.msg);
        sq_scene_free(scene);
        return 1;
    }
    long nframes;
    if (o.until_rest)
        nframes = o.max_frames;
    else if (o.frames >= 0)
        nframes = o.frames;
    else
        nframes = (long)ceil((o.seconds >= 0 ? o.seconds : scene->duration) * scene->frame_rate - 1e-9);
    if (nframes < 0)
        nframes = 0;

    /* batch runs have no compute budget (deterministic); --realtime gives the frame period */
    double budget = o.realtime ? 1.0 / scene->frame_rate : 0;
    print_setup(scene, w);
    if (o.realtime) {
        printf("realtime: compute budget %.4g s per frame (splits refused above it; output not deterministic)\n",
               budget);
        char msg[1024];
        if (sq_world_realtime_check(w, budget, msg, sizeof msg))
            fprintf(stderr, "squish run: %s\n", msg);
        printf("%s\n", msg);
        sq_world_prepare_budget(w); /* the first budgeted frame's set-up, at load */
    }
    if (o.until_rest)
        printf("run: until rest (kinetic energy < %g J/kg, residual < %g), at most %ld frames (%g s)\n", o.rest_ke,
               o.rest_res, nframes, nframes / scene->frame_rate);
    else
        printf("run: %ld frames (%g s)\n", nframes, nframes / scene->frame_rate);
    fflush(stdout);

    const char *out = o.out;
    char ppath[1100], spath[1100], tpath[1100];
    FILE *fp = NULL, *fs = NULL, *ft = NULL;
    if (sq_mkdir_p(out)) {
        fprintf(stderr, "squish run: cannot create output directory %s: %s; choose another --out\n", out,
                strerror(errno));
        rc = 1;
        goto done;
    }
    rc = 0;
    fp = open_out(out, "probes.csv", ppath, sizeof ppath);
    fs = open_out(out, "stats.csv", spath, sizeof spath);
    ft = open_out(out, "tools.csv", tpath, sizeof tpath);
    if (!fp || !fs || !ft) {
        rc = 1;
        goto done;
    }
    int maxl = write_headers(fp, fs, ft, w);
    write_probe_rows(fp, w);

    run_totals t;
    memset(&t, 0, sizeof t);
    for (int b = 0; b < w->nbodies; b++)
        t.mass[b] = body_mass(w->bodies[b]);
    double t_last_key = last_keyframe(scene);

    /* the loop */
    sq_progress prog;
    sq_progress_begin(&prog, "squish run", (double)nframes);
    double wall0 = sq_now();
    while (w->frame < nframes) {
        long missed0 = w->deadline_misses;
        sq_world_step(w, budget);
        stats_row(fs, w, maxl, missed0, &t, &prog);
        write_probe_rows(fp, w);
        write_tool_rows(ft, w);
        sq_progress_update(&prog, (double)w->frame);
        /* rest: every body calm (or asleep), after the last scripted keyframe */
        if (o.until_rest && w->time >= t_last_key && at_rest(w, &o, &t)) {
            t.at_rest = 1;
            break;
        }
    }
    sq_progress_end(&prog);
    double wall = sq_now() - wall0;

    if (write_final(w, out))
        rc = 1;
    print_summary(w, &o, &t, nframes, wall, budget);

done:
    if (fp && fclose(fp)) {
        fprintf(stderr, "squish run: writing %s failed: %s\n", ppath, strerror(errno));
        rc = 1;
    }
    if (ft && fclose(ft)) {
        fprintf(stderr, "squish run: writing %s failed: %s\n", tpath, strerror(errno));
        rc = 1;
    }
    if (fs && fclose(fs)) {
        fprintf(stderr, "squish run: writing %s failed: %s\n", spath, strerror(errno));
        rc = 1;
    }
    sq_world_destroy(w);
    sq_scene_free(scene);
    return rc;
}
