/* cmd_tradeoff.c - squish tradeoff: the speed/accuracy trade of a scene (issue 7).
 *
 *   squish tradeoff SCENE.json [--out DIR] [--frames N] [--quick] [--finest K] [--reference-step F]
 *                              [--guarded N]
 *   squish tradeoff --bench [...]          (server/engines/bench_scenes.c)
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
#include "engines/engines.h"

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

/* summary lines of the runs with the live budget, beside fixed L(finest-1), the fixed finest level
 * and the same setting without a budget, and the aims of a scene that needs adaptivity (issue
 * 10): RMS error within 1.5x fixed L(finest-1)'s, at least 100x less CPU than the fixed finest
 * level, every frame after the first within the period in thread CPU time */
static void guarded_summary(FILE *f, const sq_tradeoff_variant *v, const sq_tradeoff_result *r, int n, int g0, int gmed, int finest,
                            double frame_rate)
{
    double period = 1.0 / frame_rate;
    int nrun = gmed - g0, k = 0;
    double x[SQ_TRADEOFF_MAX_GUARDED], o[3];
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
        sq_tradeoff_spread(x, c, o);                                                                                           \
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

static int write_plot(const char *dir, const char *scene_name, const sq_tradeoff_variant *v, const sq_tradeoff_result *r, int n)
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
    int idx[SQ_TRADEOFF_MAX_VARIANTS], np = 0;
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

/* the command line */
typedef struct to_opts {
    const char *scene_path, *out;
    long frames;
    int quick, finest_override, guarded;
    double ref_fraction;
} to_opts;

/* -1: go on; else the exit code (--help, --bench, a usage error) */
static int parse_args(int argc, char **argv, to_opts *o)
{
    *o = (to_opts){NULL, "squish-tradeoff", -1, 0, -1, 3, 0.25};
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(a, "--bench")) {
            return sq_bench_scenes(argc - i, argv + i);
        } else if (!strcmp(a, "--quick")) {
            o->quick = 1;
        } else if (!strcmp(a, "--reference-step")) {
            char *end = NULL;
            double f = i + 1 < argc ? strtod(argv[i + 1], &end) : 0;
            if (i + 1 >= argc || *end || !(f > 0 && f <= 1))
                return usage_error("--reference-step needs a step fraction of the bound in (0, 1]", NULL);
            o->ref_fraction = f;
            i++;
        } else if (!strcmp(a, "--guarded")) {
            char *end = NULL;
            long g = i + 1 < argc ? strtol(argv[i + 1], &end, 10) : -1;
            if (i + 1 >= argc || *end || g < 0 || g > SQ_TRADEOFF_MAX_GUARDED)
                return usage_error("--guarded needs a number of runs with the live budget (0 to 15)", NULL);
            o->guarded = (int)g;
            i++;
        } else if (!strcmp(a, "--out")) {
            if (i + 1 >= argc || !argv[i + 1][0])
                return usage_error("--out needs a directory", NULL);
            o->out = argv[++i];
        } else if (!strcmp(a, "--frames") || !strcmp(a, "--finest")) {
            char *end = NULL;
            long v = i + 1 < argc ? strtol(argv[i + 1], &end, 10) : -1;
            if (i + 1 >= argc || *end || v < (a[2] == 'f' && a[3] == 'r' ? 1 : 0) || v > 1000000)
                return usage_error(!strcmp(a, "--frames") ? "--frames needs a whole number of frames (1 to 1e6)"
                                                          : "--finest needs a level index (0 to 5)",
                                   NULL);
            if (!strcmp(a, "--frames"))
                o->frames = v;
            else
                o->finest_override = (int)v;
            i++;
        } else if (a[0] == '-') {
            return usage_error("unknown option", a);
        } else if (o->scene_path) {
            return usage_error("more than one scene given; run one at a time:", a);
        } else {
            o->scene_path = a;
        }
    }
    if (!o->scene_path)
        return usage_error("no scene given; pass SCENE.json", NULL);
    return -1;
}

/* what the grid needs of the scene */
typedef struct to_setup {
    cJSON *root;                /* the scene's JSON, for the variants */
    char dir[512];              /* its folder (meshes are relative to it) */
    int finest;
    double s0;                  /* the scene's split threshold */
    long nframes;
    char scene_name[64];
    double frame_rate;
    int sharp[SQ_MAX_BODIES];   /* each body's "step_bound" as the scene gives it */
    double caps[SQ_MAX_BODIES];
} to_setup;

/* the scene: loaded once as given (validates it), and as JSON for the variants; 0 or 1 */
static int load_setup(const to_opts *o, to_setup *st)
{
    memset(st, 0, sizeof *st);
    sq_err err = {{0}};
    sq_scene *base = sq_scene_load(o->scene_path, &err);
    if (!base) {
        fprintf(stderr, "squish tradeoff: %s\n", err.msg);
        return 1;
    }
    char *text = sq_read_file(o->scene_path, NULL, 1 << 24, &err);
    st->root = text ? cJSON_Parse(text) : NULL;
    free(text);
    if (!st->root) {
        fprintf(stderr, "squish tradeoff: %s: cannot re-read the scene\n", o->scene_path);
        sq_scene_free(base);
        return 1;
    }
    snprintf(st->dir, sizeof st->dir, "%s", o->scene_path);
    char *slash = strrchr(st->dir, '/');
    if (slash)
        *(slash == st->dir ? slash + 1 : slash) = 0;
    else
        snprintf(st->dir, sizeof st->dir, ".");
    cJSON *body;
    cJSON_ArrayForEach(body, cJSON_GetObjectItemCaseSensitive(st->root, "bodies"))
    st->finest = SQ_MAX(st->finest, sq_tradeoff_body_finest(body, o->finest_override));
    st->s0 = sq_tradeoff_scene_split(st->root);
    st->nframes = o->frames > 0 ? o->frames : (long)ceil(base->duration * base->frame_rate - 1e-9);
    snprintf(st->scene_name, sizeof st->scene_name, "%s", base->name);
    st->frame_rate = base->frame_rate;
    for (int b = 0; b < base->nbodies && b < SQ_MAX_BODIES; b++)
        st->sharp[b] = base->bodies[b].sharp_step;
    sq_scene_free(base);
    sq_tradeoff_scene_caps(st->root, st->caps);
    return 0;
}

/* the scene's adaptive setting again, with the live budget: the same scene text as its
 * unbudgeted row, stepped with the frame period as budget (the guard on), one thread; the guard
 * decides from measured CPU time, so these runs are not deterministic: `guarded` runs, then one
 * row of their medians (*gmed, -1 when none). Returns the new count */
static int add_guarded(sq_tradeoff_variant *v, int n, const to_setup *st, int guarded, int *gmed)
{
    *gmed = -1;
    if (!(st->finest > 0 && guarded > 0))
        return n;
    double s0 = st->s0;
    for (int k = 0; k < guarded; k++) {
        v[n] = (sq_tradeoff_variant){"", "guarded_run", 1, 0, s0, SQ_OPERATOR_FEM, 0.9, 0, 0, 0};
        snprintf(v[n].name, sizeof v[n].name, "adaptive split %.3g guarded run %d", s0, k + 1);
        n++;
    }
    *gmed = n;
    v[n] = (sq_tradeoff_variant){"", "guarded", 1, 0, s0, SQ_OPERATOR_FEM, 0.9, 0, 0, 0};
    snprintf(v[n].name, sizeof v[n].name, "adaptive split %.3g guarded median", s0);
    return n + 1;
}

/* every variant in turn, the reference first; 0, or 1 when the reference run failed */
static int run_grid(const to_opts *o, const to_setup *st, const sq_tradeoff_variant *v, sq_tradeoff_result *r, int n,
                    int gmed, sq_tradeoff_ref *ref)
{
    long nframes = st->nframes;
    sq_err err = {{0}};
    sq_progress prog;
    sq_progress_begin(&prog, "squish tradeoff", (double)(gmed >= 0 ? n - 1 : n) * nframes);
    double done = 0;
    for (int i = 0; i < n; i++) {
        if (i == gmed)
            continue; /* not a run: the medians of the guarded runs, after the grid */
        if (i > 0 && getenv("SQ_TRADEOFF_ONLY_GUARDED") && strcmp(v[i].kind, getenv("SQ_TRADEOFF_ONLY_GUARDED"))) {
            done += nframes; /* debugging: only the reference and the runs with the live budget */
            continue;
        }
        if (i > 0 && !strcmp(v[i].kind, "fixed") && v[i].level == st->finest && v[i].fraction == v[0].fraction &&
            r[0].ok) {
            /* the same run as the reference (--reference-step 0.9): its numbers, zero error */
            r[i] = r[0];
            done += nframes;
            sq_progress_update(&prog, done);
            continue;
        }
        char *vt = sq_tradeoff_variant_text(st->root, &v[i], o->finest_override, st->caps, st->sharp);
        char label[600];
        snprintf(label, sizeof label, "%.500s [%.47s]", o->scene_path, v[i].name);
        sq_scene *s = sq_scene_parse(vt, st->dir, label, &err);
        cJSON_free(vt);
        if (!s) {
            snprintf(r[i].error, sizeof r[i].error, "%.290s", err.msg);
        } else {
            sq_tradeoff_run_variant(s, ref, i == 0, &r[i], &prog, &done,
                                    !strcmp(v[i].kind, "guarded_run") ? 1.0 / st->frame_rate : 0);
            sq_scene_free(s);
        }
        if (!r[i].ok) {
            done += nframes;
            if (i == 0) {
                sq_progress_end(&prog);
                fprintf(stderr, "squish tradeoff: the reference run failed: %s\n", r[i].error);
                return 1;
            }
        }
    }
    sq_progress_end(&prog);
    return 0;
}

/* DIR/tradeoff.csv: one row a setting; 0, -1 when it cannot be opened, 1 when writing it failed */
static int write_csv(const char *out, const sq_tradeoff_variant *v, const sq_tradeoff_result *r, int n,
                     const sq_tradeoff_ref *ref)
{
    char path[1100];
    FILE *f = sq_cmd_open_out("tradeoff", out, "tradeoff.csv", path, sizeof path);
    if (!f)
        return -1;
    fprintf(f, "setting,kind,operator,lod,level,split_m,step_fraction,substeps,frames,sim_s,"
               "node_updates_per_s,wall_s_per_s,rms_err_m,max_err_m,rms_rel,probe_err_m,final_rms_m,"
               "final_max_m,resets,pareto,cpu_s_per_s,cpu_late_frames,cpu_max_s,error,integrator,cg_iterations_per_frame\n");
    for (int i = 0; i < n; i++) {
        fprintf(f, "\"%s\",%s,%s,%s,%d,%.6g,%.3g,%d,%ld,%.6g,%.6e,%.6e,%.6e,%.6e,%.6e,%.6e,%.6e,%.6e,%ld,%d,%.6e,%ld,"
                   "%.6e,\"%s\",%s,%.1f\n",
                v[i].name, v[i].kind, v[i].op == SQ_OPERATOR_PAPER ? "paper" : "fem",
                v[i].adaptive ? "adaptive" : "fixed", v[i].adaptive ? -1 : v[i].level, v[i].adaptive ? v[i].split : 0,
                v[i].fraction, r[i].substeps_finest, r[i].frames, r[i].sim_s, r[i].ups, r[i].wps, r[i].rms,
                r[i].max_err, ref->rms_ref > 0 ? r[i].rms / ref->rms_ref : 0, r[i].probe_err, r[i].final_rms,
                r[i].final_max, r[i].resets, r[i].pareto, r[i].cps, r[i].cpu_late1, r[i].cpu_max1, r[i].error,
                v[i].implicit ? "implicit" : "explicit",
                v[i].implicit && r[i].frames ? (double)r[i].cg_iterations / r[i].frames : 0.0);
    }
    if (fclose(f)) {
        fprintf(stderr, "squish tradeoff: writing %s failed: %s\n", path, strerror(errno));
        return 1;
    }
    return 0;
}

/* the table of every setting */
static void print_table(FILE *f, const to_setup *st, const sq_tradeoff_variant *v, const sq_tradeoff_result *r, int n,
                        const sq_tradeoff_ref *ref)
{
    const char *scene_name = st->scene_name;
    long nframes = st->nframes;
    fprintf(f, "scene %s, %ld frames; reference RMS |u| %.3g m, max |u| %.3g m\n", scene_name, nframes,
            ref->rms_ref, ref->max_ref);
    fprintf(f, "%-40s %8s %12s %10s %10s %10s %10s %10s %10s %7s %s\n", "setting", "substeps", "updates/s",
            "wall/s", "cpu/s", "rms err m", "rel", "max err m", "probe m", "pareto", "");
    for (int i = 0; i < n; i++) {
        if (!r[i].ok) {
            fprintf(f, "%-40s refused: %s\n", v[i].name, r[i].error);
            continue;
        }
        fprintf(f, "%-40s %8d %12.4g %10.3g %10.3g %10.3g %10.3g %10.3g %10.3g %7s %s\n", v[i].name,
                r[i].substeps_finest, r[i].ups, r[i].wps, r[i].cps, r[i].rms,
                ref->rms_ref > 0 ? r[i].rms / ref->rms_ref : 0, r[i].max_err, r[i].probe_err,
                r[i].pareto ? "*" : "",
                v[i].op == SQ_OPERATOR_PAPER ? "(model difference, not discretisation error)"
                : r[i].resets                ? "(resets!)"
                : !strncmp(v[i].kind, "guarded", 7) ? "(live budget: not deterministic, off the front)"
                : v[i].implicit ? "(implicit: cost in cpu/s; updates/s counts steps, not CG iterations)"
                                : "");
    }
}

/* the headline: adaptive settings against the fixed levels at equal RMS error */
static void print_headline(FILE *f, int finest, const sq_tradeoff_variant *v, const sq_tradeoff_result *r, int n)
{
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
        double cu = sq_tradeoff_fixed_cost_at(v, r, n, r[i].rms, 0), cw = sq_tradeoff_fixed_cost_at(v, r, n, r[i].rms, 1);
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
                v[besti].name, best, sq_tradeoff_fixed_cost_at(v, r, n, r[besti].rms, 1) / r[besti].wps);
    else
        fprintf(f, "headline: no adaptive setting (0 < split < inf) reaches a fixed mesh's error at a lower "
                   "node-update cost on this scene\n");
}

/* the table and the headline, on stdout and in DIR/summary.txt; 0 or 1 */
static int write_summary(const char *out, const to_setup *st, const sq_tradeoff_variant *v, const sq_tradeoff_result *r,
                         int n, int g0, int gmed, const sq_tradeoff_ref *ref)
{
    char path[1100];
    snprintf(path, sizeof path, "%s/summary.txt", out);
    FILE *sf = fopen(path, "w");
    FILE *outs[2] = {stdout, sf};
    for (int o = 0; o < 2; o++) {
        FILE *f = outs[o];
        if (!f)
            continue;
        print_table(f, st, v, r, n, ref);
        print_headline(f, st->finest, v, r, n);
        if (gmed >= 0)
            guarded_summary(f, v, r, n, g0, gmed, st->finest, st->frame_rate);
        for (int i = 0; i < n; i++)
            if (r[i].ok && r[i].resets)
                fprintf(f, "warning: %s tripped the blow-up detector %ld time%s (body reset to rest); its "
                           "errors include the resets: run that setting with 'squish run' to see the frames\n",
                        v[i].name, r[i].resets, r[i].resets == 1 ? "" : "s");
    }
    return sf && fclose(sf) ? 1 : 0;
}

int sq_cmd_tradeoff(int argc, char **argv)
{
    to_opts o;
    int rc = parse_args(argc, argv, &o);
    if (rc >= 0)
        return rc;
    const char *maxl = getenv("SQ_TRADEOFF_ADAPTIVE_MAX_LEVEL"), *tr = getenv("SQ_TRADEOFF_TRACE");
    sq_tradeoff_set_debug(&(sq_tradeoff_debug){.adaptive_max_level = maxl ? atoi(maxl) : -1,
                                               .ref_file = getenv("SQ_TRADEOFF_REF"),
                                               .trace = tr ? atoi(tr) : 0});
    to_setup st;
    if (load_setup(&o, &st))
        return 1;
    sq_tradeoff_variant v[SQ_TRADEOFF_MAX_VARIANTS];
    static sq_tradeoff_result r[SQ_TRADEOFF_MAX_VARIANTS];
    memset(r, 0, sizeof r);
    int n = sq_tradeoff_build_grid(v, st.finest, st.s0, o.quick, o.ref_fraction);
    int gmed, g0 = n;
    n = add_guarded(v, n, &st, o.guarded, &gmed);
    if (sq_mkdir_p(o.out)) {
        fprintf(stderr, "squish tradeoff: cannot create output directory %s: %s; choose another --out\n", o.out,
                strerror(errno));
        cJSON_Delete(st.root);
        return 1;
    }
    printf("tradeoff %s: %d settings x %ld frames (%.3g s simulated each); reference: fixed L%d, fem, step %.3g "
           "x bound; adaptive thresholds around the scene's split %.3g m\n",
           st.scene_name, g0, st.nframes, st.nframes / st.frame_rate, st.finest, o.ref_fraction, st.s0);
    if (gmed >= 0)
        printf("tradeoff %s: and %d runs of split %.3g m with the live budget (the %.3g ms frame period, the guard "
               "on, one thread): not deterministic, reported as min / median / max\n",
               st.scene_name, gmed - g0, st.s0, 1e3 / st.frame_rate);
    fflush(stdout);

    sq_tradeoff_ref ref;
    memset(&ref, 0, sizeof ref);
    ref.nframes = st.nframes;
    rc = run_grid(&o, &st, v, r, n, gmed, &ref);
    if (rc == 0) {
        if (gmed >= 0)
            sq_tradeoff_guarded_median(r, g0, gmed);
        sq_tradeoff_pareto(v, r, n);
        int csv = write_csv(o.out, v, r, n, &ref);
        rc = csv != 0;
        if (csv >= 0) {
            rc |= write_summary(o.out, &st, v, r, n, g0, gmed, &ref);
            if (write_plot(o.out, st.scene_name, v, r, n) == 0)
                printf("wrote %s/tradeoff.csv, %s/tradeoff.png, %s/summary.txt\n", o.out, o.out, o.out);
            else
                rc = 1;
        }
    }
    sq_tradeoff_ref_free(&ref);
    cJSON_Delete(st.root);
    return rc;
}
