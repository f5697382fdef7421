/* cmd_sweep.c - squish sweep: numerical stability at the extremes (issue 7); the cases and
 * their runs are the sweep engine's (server/engines/sweep.c).
 *
 *   squish sweep [--out DIR] [--quick]
 *
 * Writes DIR/sweep.csv, DIR/sweep.md, DIR/locking.csv; exit 0 when no accepted case failed,
 * 1 when one did (or output failed), 2 on usage errors.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "app/commands.h"
#include "engines/engines.h"

/* locking and cost against nu: the clamped beam at three resolutions (sq_sweep_beam_ratio) */
static int write_locking(const char *dir, int quick)
{
    char path[1100];
    FILE *f = sq_cmd_open_out("sweep", dir, "locking.csv", path, sizeof path);
    if (!f)
        return -1;
    static const double nus[] = {0, 0.3, 0.4, 0.45, 0.49, 0.499, 0.4999};
    static const int res[][2] = {{10, 1}, {20, 2}, {40, 4}};
    /* the finest beam has 41 x 5 x 5 nodes: CG is a few seconds */
    int nres = quick ? 2 : 3;
    fprintf(f, "nu,nx,ny,operator,tip_fem_m,tip_theory_m,ratio,substeps_per_frame_50Hz\n");
    printf("\nlocking: clamped beam 1 x 0.1 x 0.1 m, E 1 MPa, gravity; static tip deflection / Timoshenko\n");
    printf("%-7s", "nu");
    for (int r = 0; r < nres; r++)
        printf("  %4dx%dx%d fem (steps/frame)", res[r][0], res[r][1], res[r][1]);
    printf("\n");
    for (size_t k = 0; k < SQ_COUNTOF(nus); k++) {
        printf("%-7g", nus[k]);
        for (int r = 0; r < nres; r++) {
            double tf = NAN, tt = NAN;
            int sub = 0;
            sq_err e = {{0}};
            double ratio = sq_sweep_beam_ratio(nus[k], res[r][0], res[r][1], SQ_OPERATOR_FEM, &tf, &tt, &sub, &e);
            fprintf(f, "%g,%d,%d,fem,%.6e,%.6e,%.6f,%d\n", nus[k], res[r][0], res[r][1], tf, tt, ratio, sub);
            printf("  %20.3f (%7d)", ratio, sub);
        }
        printf("\n");
    }
    if (fclose(f)) {
        fprintf(stderr, "squish sweep: writing %s failed: %s\n", path, strerror(errno));
        return -1;
    }
    return 0;
}

/* ---- the command -------------------------------------------------------------------------- */

static void usage(FILE *f)
{
    fprintf(f, "usage: squish sweep [--out DIR] [--quick]\n"
               "  stability at the extremes: Young's modulus, Poisson ratio, density, damping, step\n"
               "  against the bound, fast and deep tools, sliver meshes, a very long run. Each case is\n"
               "  refused with a reason, or accepted (possibly adjusted) and run; accepted cases must\n"
               "  stay finite, never trip the blow-up detector, and keep their energy bounded.\n"
               "  --out DIR   output directory (default squish-sweep): sweep.csv, sweep.md, locking.csv\n"
               "  --quick     shorter runs (the long run is 120 s instead of 3600 s)\n"
               "  --verbose   one line per case on stderr as it finishes\n"
               "  exit 0: every accepted case stable; 1: one was not (or output failed); 2: usage\n");
}

static void csv_text(FILE *f, const char *s)
{
    fputc('"', f);
    for (; *s; s++) {
        if (*s == '"')
            fputc('"', f);
        fputc(*s, f);
    }
    fputc('"', f);
}

int sq_cmd_sweep(int argc, char **argv)
{
    const char *out = "squish-sweep";
    int quick = 0, verbose = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(argv[i], "--quick")) {
            quick = 1;
        } else if (!strcmp(argv[i], "--verbose") || !strcmp(argv[i], "-v")) {
            verbose = 1;
        } else if (!strcmp(argv[i], "--out") && i + 1 < argc && argv[i + 1][0]) {
            out = argv[++i];
        } else {
            fprintf(stderr, "squish sweep: %s '%s'\n", !strcmp(argv[i], "--out") ? "--out needs a directory after"
                                                                               : "unknown argument", argv[i]);
            usage(stderr);
            return 2;
        }
    }
    if (sq_mkdir_p(out)) {
        fprintf(stderr, "squish sweep: cannot create output directory %s: %s; choose another --out\n", out,
                strerror(errno));
        return 1;
    }
    static sq_sweep_case cs[128];
    static sq_sweep_result rs[96];
    int n = sq_sweep_build_cases(cs, quick);
    double total = 0;
    for (int i = 0; i < n; i++)
        total += cs[i].seconds;
    sq_progress prog;
    sq_progress_begin(&prog, "squish sweep", total);
    double done = 0, w0 = sq_now();
    int failed = 0;
    for (int i = 0; i < n; i++) {
        sq_sweep_run_case(&cs[i], (quick ? 2e7 : 2e8) * (!strcmp(cs[i].group, "long") ? 10 : 1), &rs[i]);
        failed += rs[i].failed;
        if (verbose)
            fprintf(stderr, "%-9s %-42s %-26s %8d substeps %7.2f s\n", cs[i].group, cs[i].name, rs[i].status,
                    rs[i].substeps, rs[i].wall);
        done += cs[i].seconds;
        sq_progress_update(&prog, done);
    }
    sq_progress_end(&prog);

    char path[1100], mpath[1100];
    FILE *f = sq_cmd_open_out("sweep", out, "sweep.csv", path, sizeof path);
    FILE *md = f ? sq_cmd_open_out("sweep", out, "sweep.md", mpath, sizeof mpath) : NULL;
    if (!md) {
        if (f)
            fclose(f);
        return 1;
    }
    fprintf(f, "group,case,status,failed,substeps,bound_s,dt_s,steps_per_s,frames,resets,max_disp_m,"
               "energy_loaded_J,energy_late_J,wall_s,note\n");
    fprintf(md, "| group | case | result | substeps/frame | bound (s) | max \\|d\\| (m) | energy, loaded (J) | energy, last quarter (J) | wall (s) | note |\n"
                "|---|---|---|---:|---:|---:|---:|---:|---:|---|\n");
    for (int i = 0; i < n; i++) {
        const sq_sweep_result *r = &rs[i];
        fprintf(f, "%s,", cs[i].group);
        csv_text(f, cs[i].name);
        fprintf(f, ",%s,%d,%d,%.6e,%.6e,%.6e,%ld,%ld,%.6e,%.6e,%.6e,%.3f,", r->status, r->failed, r->substeps,
                r->bound, r->dt, r->steps_per_s, r->frames, r->resets, r->max_disp, r->e_load, r->e_late, r->wall);
        csv_text(f, r->note);
        fputc('\n', f);
        char el[32] = "", ea[32] = "";
        if (r->frames > 0 && isfinite(r->e_load))
            snprintf(el, sizeof el, "%.3g", r->e_load);
        if (r->frames > 0 && isfinite(r->e_late))
            snprintf(ea, sizeof ea, "%.3g", r->e_late);
        fprintf(md, "| %s | %s | %s%s%s | %d | %.3g | %.3g | %s | %s | %.2f | %s |\n", cs[i].group, cs[i].name,
                r->failed ? "**" : "", r->status, r->failed ? "**" : "", r->substeps, r->bound, r->max_disp, el, ea,
                r->wall, r->note);
    }
    int rc = 0;
    if (fclose(f) | fclose(md)) {
        fprintf(stderr, "squish sweep: writing %s failed: %s\n", path, strerror(errno));
        rc = 1;
    }
    /* stdout: the table */
    printf("%-9s %-42s %-26s %8s %10s %10s\n", "group", "case", "result", "substeps", "bound s", "max|d| m");
    for (int i = 0; i < n; i++)
        printf("%-9s %-42s %-26s %8d %10.3g %10.3g%s%s\n", cs[i].group, cs[i].name, rs[i].status, rs[i].substeps,
               rs[i].bound, rs[i].max_disp, rs[i].note[0] ? "  " : "", rs[i].note);
    if (write_locking(out, quick))
        rc = 1;
    int accepted = 0, refused = 0;
    for (int i = 0; i < n; i++) {
        if (!strcmp(rs[i].status, "refused"))
            refused++;
        else if (cs[i].above_bound <= 0)
            accepted++;
    }
    printf("\nsweep: %d cases (%d accepted and run, %d refused with a reason, %d test-only) in %.1f s; "
           "%d accepted case%s failed\n",
           n, accepted, refused, n - accepted - refused, sq_now() - w0, failed, failed == 1 ? "" : "s");
    printf("wrote %s, %s, %s/locking.csv\n", path, mpath, out);
    return failed ? 1 : rc;
}
