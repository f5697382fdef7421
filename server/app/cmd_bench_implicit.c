/* cmd_bench_implicit.c - squish bench implicit: the cost of the implicit integrator
 * (level/implicit.c; docs/physics.md section 12), thread CPU time on one core.
 *
 *   squish bench implicit [--quick]
 *
 * 1. SOFA's CPU reference beam: 16 x 16 x 76 nodes, backward Euler at dt 0.04 s with 10 CG
 *    iterations a step, linear and corotational; and at dt 0.02 s (50 Hz).
 * 2. A stiff cantilever (E 1e8 Pa, nu 0.45, ~12k nodes) at 50 Hz: CPU per frame, its static
 *    tip against the static solve, and the substeps the explicit step would need.
 * 3. The first bending mode's period and decay, explicit against implicit at 1, 2, 4 steps.
 * 4. CG iterations per frame against stiffness and mesh size for each preconditioner.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/commands.h"
#include "body/body.h"

/* a box beam along x of length lx and section s, cells nx x ns x ns, with `extra` coarser
 * levels (cells halved each level, at least 1) below it; clamped at x = 0 */
typedef struct bi_beam {
    sq_mesh *m[SQ_MAX_LEVELS];
    int nl;
    sq_body *b;
} bi_beam;

static void beam_free(bi_beam *bb)
{
    sq_body_destroy(bb->b);
    for (int k = 0; k < bb->nl; k++)
        sq_mesh_free(bb->m[k]);
    memset(bb, 0, sizeof *bb);
}

static double bi_gravity = -9.81; /* gravity z of the next beam */

static int beam_make(bi_beam *bb, double lx, double s, int nx, int ns, int coarse, double E, double nu, double a,
                     double frame_dt, sq_elasticity_kind el, const sq_implicit_def *imp, sq_err *err)
{
    memset(bb, 0, sizeof *bb);
    double size[3] = {lx, s, s}, origin[3] = {0, 0, 0};
    for (int k = coarse; k >= 0; k--) {
        int cx = SQ_MAX(1, nx >> k), cs = SQ_MAX(1, ns >> k);
        if (!(bb->m[bb->nl++] = sq_mesh_box(cx, cs, cs, size, origin, err))) {
            beam_free(bb);
            return -1;
        }
    }
    sq_body_def def = sq_body_def_default();
    def.name = "beam";
    def.nlevels = bb->nl;
    for (int k = 0; k < bb->nl; k++)
        def.levels[k] = bb->m[k];
    def.lod.level = bb->nl - 1;
    if (sq_material_from_E_nu(&def.material, E, nu, err) < 0) {
        beam_free(bb);
        return -1;
    }
    def.material.density = 1000;
    def.material.rayleigh_mass = a;
    def.material.rayleigh_stiffness = 0;
    def.gravity[2] = bi_gravity;
    def.frame_dt = frame_dt;
    def.nconstraints = 1;
    def.constraints[0] = (sq_constraint){SQ_REGION_BOX, {-1, -1, -1}, {1e-9 * lx, 2 * s, 2 * s}, 7};
    def.elasticity = el;
    def.integrator = SQ_INTEGRATOR_IMPLICIT;
    def.implicit = *imp;
    if (!(bb->b = sq_body_create(&def, err))) {
        beam_free(bb);
        return -1;
    }
    sq_body_set_sleep(bb->b, 0, 0, 0);
    return 0;
}

/* frames of the body: CPU seconds per frame (median of the frames after the first) and the CG
 * iterations summed */
static double run_frames(sq_body *b, int frames, long *iterations)
{
    double *t = sq_malloc(sizeof(double) * (size_t)frames);
    *iterations = 0;
    for (int f = 0; f < frames; f++) {
        sq_frame_profile pf;
        double c0 = sq_thread_cpu();
        sq_body_frame(b, NULL, 0, NULL, &pf, 0);
        t[f] = sq_thread_cpu() - c0;
        *iterations += pf.cg_iterations;
    }
    /* median of frames 1.. (frame 0 allocates the solver's scratch) */
    int n = frames > 1 ? frames - 1 : frames;
    double *s = t + (frames > 1);
    for (int i = 1; i < n; i++)
        for (int j = i; j > 0 && s[j - 1] > s[j]; j--) {
            double x = s[j];
            s[j] = s[j - 1];
            s[j - 1] = x;
        }
    double med = n ? s[n / 2] : 0;
    free(t);
    return med;
}

/* mean z displacement d of the nodes of m at x = lx (the beam's tip) */
static double tip_of(const sq_mesh *m, const double *d, double lx)
{
    double s = 0;
    int n = 0;
    for (int i = 0; i < m->nnodes; i++)
        if (m->x[3 * i] > lx * (1 - 1e-9)) {
            s += d[3 * i + 2];
            n++;
        }
    return n ? s / n : NAN;
}

static double tip_z(const sq_body *b, double lx)
{
    int L = sq_body_sim_level(b);
    return tip_of(sq_body_mesh(b, L), sq_body_displacement(b, L), lx);
}

/* 1. the SOFA beam: 15 x 15 x 75 cells (16 x 16 x 76 = 19,456 nodes), 10 CG iterations a step */
static int bench_sofa_beam(int quick)
{
    printf("\n--- SOFA's CPU reference beam: 16 x 16 x 76 nodes (19,456), backward Euler, 10 CG iterations a step\n");
    printf("%-14s %-7s %10s %12s %10s %14s\n", "elasticity", "dt_s", "frames", "cpu_ms/frame", "fps", "real_time_50Hz");
    for (int el = 0; el < 2; el++)
        for (int k = 0; k < 2; k++) {
            double dt = k ? 0.02 : 0.04;
            sq_implicit_def imp = sq_implicit_def_default();
            imp.max_iter = 10;
            imp.tol = 1e-12; /* the cap decides, as in SOFA's CGLinearSolver iterations="10" */
            imp.precond = SQ_PRECOND_BLOCK;
            bi_beam bb;
            sq_err e = {{0}};
            if (beam_make(&bb, 0.75, 0.15, 75, 15, 0, 1e6, 0.45, 1, dt, el, &imp, &e) < 0) {
                fprintf(stderr, "squish bench implicit: %s\n", e.msg);
                return -1;
            }
            int frames = quick ? 6 : 26;
            long it;
            double cpu = run_frames(bb.b, frames, &it);
            printf("%-14s %-7g %10d %12.2f %10.1f %14s\n", el ? "corotational" : "linear", dt, frames, 1e3 * cpu,
                   cpu > 0 ? 1 / cpu : 0, cpu <= dt && cpu <= 0.02 ? "yes" : (cpu <= dt ? "at dt" : "no"));
            beam_free(&bb);
        }
    return 0;
}

/* 2. the stiff cantilever: 1 x 0.1 x 0.1 m, 100 x 10 x 10 cells (12,221 nodes), E 1e8 Pa, nu 0.45,
 * 50 Hz, multigrid over 2 coarser levels (50 x 5 x 5, 25 x 2 x 2), at two CG tolerances */
static int bench_stiff_cantilever(int quick)
{
    printf("\n--- stiff cantilever: 1 x 0.1 x 0.1 m, 12,221 nodes, E 1e8 Pa, nu 0.45, 50 Hz, one step a frame, "
           "multigrid over 2 coarser levels\n");
    static const double tols[] = {1e-6, 1e-3};
    for (size_t ti = 0; ti < SQ_COUNTOF(tols); ti++) {
        sq_implicit_def imp = sq_implicit_def_default();
        imp.precond = SQ_PRECOND_MULTIGRID;
        imp.tol = tols[ti];
        imp.max_iter = 2000;
        bi_beam bb;
        sq_err e = {{0}};
        if (beam_make(&bb, 1, 0.1, 100, 10, 2, 1e8, 0.45, 20, 0.02, SQ_ELASTICITY_LINEAR, &imp, &e) < 0) {
            fprintf(stderr, "squish bench implicit: %s\n", e.msg);
            return -1;
        }
        int frames = quick ? 20 : 100;
        long it;
        double cpu = run_frames(bb.b, frames, &it);
        double tip = tip_z(bb.b, 1);
        const sq_level *L = sq_body_level(bb.b, sq_body_sim_level(bb.b));
        double *d = sq_malloc(sizeof(double) * 3 * (size_t)L->model.n);
        double g[3] = {0, 0, -9.81};
        int sit = 0;
        double tip_s = NAN;
        if (sq_level_static_solve(&L->model, g, 1e-10, 100000, d, &sit, &e) == 0)
            tip_s = tip_of(L->model.mesh, d, 1);
        free(d);
        printf("tol %g: cpu per frame %.2f ms (median of %d frames after the first; %s real time at 50 Hz), CG %.1f "
               "iterations per frame; tip after %.1f s (damping a = 20 1/s) %.6g m, static solve %.6g m: %.3f %%\n",
               tols[ti], 1e3 * cpu, frames, cpu <= 0.02 ? "within" : "NOT within", (double)it / frames, frames * 0.02,
               tip, tip_s, 100 * fabs(tip - tip_s) / fabs(tip_s));
        if (ti == 0) {
            int nsub = L->nsub, gsub = 1 << L->substeps_log2;
            /* the same body stepped explicitly (sharp bound), a few frames */
            if (sq_body_set_integrator(bb.b, SQ_INTEGRATOR_EXPLICIT, &imp, &e) == 0) {
                double ce = run_frames(bb.b, 4, &it);
                printf("explicit on the same body: %d substeps per frame (sharp bound; %d with Gershgorin), cpu per "
                       "frame %.1f ms (median of 3 frames after the first)\n", nsub, gsub, 1e3 * ce);
            }
        }
        beam_free(&bb);
    }
    return 0;
}

/* 3. CG iterations per frame against stiffness and mesh size, per preconditioner */
static int bench_preconditioners(int quick)
{
    printf("\n--- CG iterations per frame (mean over 6 frames, tol 1e-6; cpu: median of frames 2-6): cantilever 1 x 0.2 x 0.2 m, 50 Hz, "
           "linear; multigrid over the coarser levels (cells halved)\n");
    printf("%-8s %-6s %-8s %12s %12s %12s   %s\n", "nodes", "nu", "E_Pa", "jacobi", "block_jacobi", "multigrid",
           "cpu_ms/frame (j / bj / mg)");
    static const int sizes[][2] = {{10, 2}, {20, 4}, {40, 8}};
    static const double Es[] = {1e5, 1e7, 1e9};
    static const double nus[] = {0.3, 0.45, 0.49};
    int nsize = quick ? 2 : 3;
    for (int si = 0; si < nsize; si++)
        for (size_t ni = 0; ni < SQ_COUNTOF(nus); ni++)
            for (size_t ei = 0; ei < SQ_COUNTOF(Es); ei++) {
                double its[3], cpu[3];
                int nodes = 0;
                for (int pc = 0; pc < 3; pc++) {
                    sq_implicit_def imp = sq_implicit_def_default();
                    imp.precond = pc;
                    imp.max_iter = SQ_IMPLICIT_MAX_ITER;
                    bi_beam bb;
                    sq_err e = {{0}};
                    if (beam_make(&bb, 1, 0.2, sizes[si][0], sizes[si][1], si + 1, Es[ei], nus[ni], 1, 0.02,
                                  SQ_ELASTICITY_LINEAR, &imp, &e) < 0) {
                        fprintf(stderr, "squish bench implicit: %s\n", e.msg);
                        return -1;
                    }
                    nodes = bb.m[bb.nl - 1]->nnodes;
                    long it;
                    cpu[pc] = run_frames(bb.b, 6, &it);
                    its[pc] = it / 6.0;
                    beam_free(&bb);
                }
                printf("%-8d %-6g %-8g %12.1f %12.1f %12.1f   %.2f / %.2f / %.2f\n", nodes, nus[ni], Es[ei], its[0], its[1],
                       its[2], 1e3 * cpu[0], 1e3 * cpu[1], 1e3 * cpu[2]);
                fflush(stdout);
            }
    return 0;
}

/* y = K x on the free axes (constrained components zero): the first mode's inverse iteration */
static void k_free(const sq_level_model *M, const void *ctx, const double *x, double *y)
{
    double *acc = (double *)ctx;
    sq_level_neg_k(M, x, y, acc);
    for (int i = 0; i < M->n; i++)
        for (int c = 0; c < 3; c++)
            y[3 * i + c] = (M->fixed[i] & (1u << c)) ? 0 : -y[3 * i + c];
}

/* the first mode of K phi = lambda M phi on the free axes, by 30 inverse iterations (each a CG
 * solve to 1e-12), scaled to a tip displacement of 1 cm; -1 + err on failure */
static int first_mode(const sq_level *L, double *phi, sq_err *err)
{
    const sq_level_model *M = &L->model;
    const size_t n3 = 3 * (size_t)M->n;
    double *b = sq_calloc(n3 + 1, sizeof(double)), *acc = sq_calloc(n3 + 1, sizeof(double));
    double *pre = sq_calloc(n3, sizeof(double)), *x = sq_calloc(n3 + 1, sizeof(double));
    for (int i = 0; i < M->n; i++) {
        for (int e = M->row_start[i]; e < M->row_start[i + 1]; e++)
            if (M->col[e] == i)
                for (int c = 0; c < 3; c++)
                    pre[3 * i + c] = (M->fixed[i] & (1u << c)) ? 0 : 1.0 / M->K[9 * (size_t)e + 4 * c];
        phi[3 * i + 2] = (M->fixed[i] & 4u) ? 0 : M->mesh->x[3 * i]; /* a start: bent down the beam */
    }
    int rc = 0;
    for (int it = 0; it < 30 && rc == 0; it++) {
        for (int i = 0; i < M->n; i++)
            for (int c = 0; c < 3; c++)
                b[3 * i + c] = (M->fixed[i] & (1u << c)) ? 0 : M->mass[i] * phi[3 * i + c];
        rc = sq_level_pcg(M, k_free, acc, b, pre, 1e-12, 100000, x, NULL, err);
        double mx = 0;
        for (size_t k = 0; k < n3; k++)
            mx = fmax(mx, fabs(x[k]));
        for (size_t k = 0; k < n3; k++)
            phi[k] = mx > 0 ? 0.01 * x[k] / mx : 0;
    }
    free(b);
    free(acc);
    free(pre);
    free(x);
    return rc;
}

/* 3. the implicit scheme's damping: the first bending mode of an undamped cantilever (1 x 0.1 x
 * 0.1 m, 20 x 2 x 2 cells, E 1e6 Pa, nu 0.3, no gravity) released at rest from that mode's shape
 * (1 cm at the tip), 50 Hz: its period and the amplitude ratio of successive peaks of the tip,
 * explicit (sharp bound) against implicit at 1, 2 and 4 steps a frame */
static int bench_first_mode(int quick)
{
    printf("\n--- first bending mode, undamped cantilever 1 x 0.1 x 0.1 m (20 x 2 x 2 cells), E 1e6 Pa, released "
           "from the mode's shape (1 cm at the tip), 50 Hz, %s s\n", quick ? "6" : "12");
    printf("%-22s %10s %14s %12s %14s\n", "integrator", "period_s", "peak_ratio", "cpu_ms/frame", "steps/frame");
    const int frames = quick ? 300 : 600;
    for (int k = 0; k < 4; k++) {
        static const int subs[] = {0, 1, 2, 4};
        sq_implicit_def imp = sq_implicit_def_default();
        imp.substeps = subs[k] ? subs[k] : 1;
        imp.tol = 1e-9;
        imp.max_iter = SQ_IMPLICIT_MAX_ITER;
        bi_beam bb;
        sq_err e = {{0}};
        bi_gravity = 0;
        int rc = beam_make(&bb, 1, 0.1, 20, 2, 0, 1e6, 0.3, 0, 0.02, SQ_ELASTICITY_LINEAR, &imp, &e);
        bi_gravity = -9.81;
        if (rc < 0) {
            fprintf(stderr, "squish bench implicit: %s\n", e.msg);
            return -1;
        }
        sq_level *L0 = sq_body_level(bb.b, sq_body_sim_level(bb.b));
        if (first_mode(L0, L0->state.d, &e) < 0) {
            fprintf(stderr, "squish bench implicit: %s\n", e.msg);
            beam_free(&bb);
            return -1;
        }
        if (!subs[k] && sq_body_set_integrator(bb.b, SQ_INTEGRATOR_EXPLICIT, &imp, &e) < 0) {
            fprintf(stderr, "squish bench implicit: %s\n", e.msg);
            beam_free(&bb);
            return -1;
        }
        double *z = sq_malloc(sizeof(double) * (size_t)frames);
        double c0 = sq_thread_cpu();
        for (int f = 0; f < frames; f++) {
            sq_body_frame(bb.b, NULL, 0, NULL, NULL, 0);
            z[f] = tip_z(bb.b, 1);
        }
        double cpu = (sq_thread_cpu() - c0) / frames;
        /* the oscillation about rest: the tip's lowest points (peaks of -z) */
        const double mean = 0;
        for (int f = 0; f < frames; f++)
            z[f] = -z[f];
        double peaks_t[64], peaks_a[64];
        int np = 0;
        for (int f = 1; f + 1 < frames && np < 64; f++)
            if (z[f] > z[f - 1] && z[f] >= z[f + 1] && z[f] > mean) {
                peaks_t[np] = (f + 1) * 0.02;
                peaks_a[np] = z[f] - mean;
                np++;
            }
        double period = np >= 2 ? (peaks_t[np - 1] - peaks_t[0]) / (np - 1) : NAN;
        double ratio = np >= 2 && peaks_a[0] > 0 ? pow(peaks_a[np - 1] / peaks_a[0], 1.0 / (np - 1)) : NAN;
        char name[32];
        if (subs[k])
            snprintf(name, sizeof name, "implicit x%d", subs[k]);
        else
            snprintf(name, sizeof name, "explicit (sharp bound)");
        const sq_level *L = sq_body_level(bb.b, sq_body_sim_level(bb.b));
        printf("%-22s %10.4f %14.4f %12.3f %14d\n", name, period, ratio, 1e3 * cpu, subs[k] ? subs[k] : L->nsub);
        free(z);
        beam_free(&bb);
    }
    return 0;
}

int sq_bench_implicit(int quick)
{
    printf("squish bench implicit: thread CPU time on one core%s\n", quick ? " (quick)" : "");
    if (bench_sofa_beam(quick) < 0 || bench_stiff_cantilever(quick) < 0 || bench_first_mode(quick) < 0 ||
        bench_preconditioners(quick) < 0)
        return 1;
    return 0;
}
