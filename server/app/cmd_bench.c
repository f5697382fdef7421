/* cmd_bench.c - squish bench: speed of the fixed-resolution step, and the measured
 * difference between the two operators (static solutions of the cube and a clamped beam).
 *
 *   squish bench [step] [--sizes 1k,10k,100k,1M] [--seconds T] [--op fem|paper|both]
 *   squish bench operators
 *   squish bench cube [--meshes DIR] [--seconds T] [--out FILE]
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/commands.h"
#include "body/body.h"

/* memory bandwidth of one core on the reference machine (docs/benchmarks.md), bytes/s */
#define SQ_BENCH_BANDWIDTH 20e9

static int usage(FILE *f)
{
    fprintf(f, "usage: squish bench [step] [--sizes LIST] [--seconds T] [--op fem|paper|both|corot]\n"
               "       squish bench operators\n"
               "       squish bench cube [--meshes DIR] [--seconds T] [--out FILE]\n"
               "       squish bench implicit [--quick]\n"
               "       squish bench contact [--quick]\n"
               "  step       node-steps per second of the fixed-resolution step on box meshes\n"
               "             (LIST: node counts such as 1k,10k,100k,1M; default all four); fem, paper\n"
               "             and fem with corotational elasticity (fem-corot) by default; --op corot:\n"
               "             fem linear beside fem-corot\n"
               "  operators  static corner/tip deflection of the paper cube and a clamped beam,\n"
               "             paper vs fem operator\n"
               "  cube       the paper's section 2.6: corner (1,1,1) vertical displacement over time of\n"
               "             the 1 m cube (bottom fixed, gravity) at three resolutions (DIR/cube_l1..l3.msh,\n"
               "             default meshes/cube), both operators; CSV on stdout or FILE\n"
               "  implicit   the implicit integrator: SOFA's reference beam (16 x 16 x 76 nodes, 10 CG\n"
               "             iterations), a stiff cantilever at 50 Hz, CG iterations per preconditioner\n"
               "  contact    a 10k-node box on a 12,800-triangle tray and on a plane: the contact passes'\n"
               "             share of the frame; the shipped contact scenes' frame CPU after frame 1\n");
    return f == stdout ? 0 : 2;
}


/* cells per side of a cube box mesh with about `nodes` nodes */
static int cells_for(double nodes)
{
    int c = (int)lround(cbrt(nodes)) - 1;
    return c < 1 ? 1 : c;
}

/* bytes one node-step moves from and to memory in the fused pass of level/level.c: each
 * upper-half block and column index once (72 + 4 B per entry); per node the row start (4),
 * d and v read and written (96), the force accumulator read and cleared (48), f written (24),
 * mass (8) and the fixed byte (1). Neighbour values are assumed to hit the cache. */
static double bytes_per_node_step(const sq_level *L)
{
    double per_entry = 9 * sizeof(double) + sizeof(int);
    double per_node = 4 + 96 + 48 + 24 + 8 + 1;
    if (L->state.corot) /* per tet: 3 gradients + volume + quaternion read, quaternion written, 4 indices */
        return (14.0 * 8 + 4 * 8 + 16) * L->model.mesh->ntets / L->model.n + per_node;
    return per_entry * L->model.up_start[L->model.n] / L->model.n + per_node;
}

/* measured streaming bandwidth of this thread (STREAM-like triad a = b + s c over 3 x 64 MB,
 * counting 24 B per element; best of 5), bytes per CPU second */
static double measure_bandwidth(void)
{
    size_t n = (size_t)8 << 20;
    double *a = sq_malloc(n * sizeof(double)), *b = sq_malloc(n * sizeof(double)), *c = sq_malloc(n * sizeof(double));
    for (size_t k = 0; k < n; k++)
        a[k] = 0, b[k] = (double)k, c[k] = 1.0 / (double)(k + 1);
    double best = 0;
    for (int r = 0; r < 5; r++) {
        double t0 = sq_thread_cpu();
        for (size_t k = 0; k < n; k++)
            a[k] = b[k] + 0.5 * c[k];
        double t = sq_thread_cpu() - t0;
        if (t > 0 && 24.0 * (double)n / t > best)
            best = 24.0 * (double)n / t;
        b[r] = a[n - 1 - r]; /* keep the loop */
    }
    free(a);
    free(b);
    free(c);
    return best;
}

static int bench_step(const char *sizes, double seconds, int op_mask)
{
    double want[16];
    int nsizes = 0;
    char buf[256];
    snprintf(buf, sizeof buf, "%s", sizes);
    for (char *tok = strtok(buf, ","); tok && nsizes < 16; tok = strtok(NULL, ",")) {
        char *end;
        double v = strtod(tok, &end);
        if (*end == 'k' || *end == 'K')
            v *= 1e3, end++;
        else if (*end == 'M' || *end == 'm')
            v *= 1e6, end++;
        if (*end || !(v >= 8) || v > 2e7) {
            fprintf(stderr, "squish bench step: size '%s' is not a node count between 8 and 2e7 "
                            "(write e.g. 10k or 1M)\n", tok);
            return 2;
        }
        want[nsizes++] = v;
    }
    printf("# fixed-resolution step (sq_level_step: forces + symplectic Euler fused in one pass), all nodes,\n"
           "# box meshes (6 tets per cell),\n"
           "# bottom face fixed, gravity, Rayleigh damping (a = 0.5/s, b = 1e-3 s), one thread.\n"
           "# bound = %.0f GB/s / bytes per node-step\n", SQ_BENCH_BANDWIDTH / 1e9);
    double bw = measure_bandwidth();
    printf("# rates per CPU second of the benchmark thread (wall-clock rate beside it)\n"
           "# measured triad bandwidth of this thread: %.1f GB/s ('of meas.' uses it)\n", bw / 1e9);
    printf("%-9s %8s %9s %6s %8s %13s %8s %11s %10s %8s %9s\n", "operator", "nodes", "csr", "steps", "cpu s",
           "Mnode-steps/s", "wall M/s", "B/node-step", "bound M/s", "of bound", "of meas.");
    for (int s = 0; s < nsizes; s++) {
        int c = cells_for(want[s]);
        double size[3] = {1, 1, 1}, origin[3] = {0, 0, 0};
        sq_err err = {{0}};
        sq_mesh *m = sq_mesh_box(c, c, c, size, origin, &err);
        if (!m) {
            fprintf(stderr, "squish bench step: %s\n", err.msg);
            return 1;
        }
        double fem_cpu_rate = 0;
        for (int variant = 0; variant < 3; variant++) {
            if (!(op_mask & (1 << variant)))
                continue;
            int op = variant == 1; /* 0 fem, 1 paper, 2 fem corotational */
            if (variant == 2 && m->nnodes > 200000) { /* ~130 B per tet: 0.8 GB at 1M nodes */
                printf("# %d nodes: fem-corot skipped (its per-tet state would need %.2g GB)\n", m->nnodes,
                       130e-9 * m->ntets);
                continue;
            }
            const char *name = variant == 0 ? "fem" : variant == 1 ? "paper" : "fem-corot";
            sq_body_def def = sq_body_def_default();
            sq_constraint fixed = {SQ_REGION_BOX, {-1, -1, -1}, {2, 2, 1e-3}, 7};
            double g[3] = {0, 0, -9.81};
            sq_level L;
            if (sq_level_init(&L, m, &def.material, (sq_operator_kind)op, &fixed, 1, &err) < 0 ||
                (variant == 2 && sq_level_corot_enable(&L, &def.material, SQ_OPERATOR_FEM, &err) < 0) ||
                sq_level_choose_step(&L, &def.material, def.frame_dt, def.step_fraction, &err) < 0) {
                fprintf(stderr, "squish bench step: %s\n", err.msg);
                sq_mesh_free(m);
                return 1;
            }
            /* warm up, then time batches of steps until `seconds` have passed */
            char label[64];
            snprintf(label, sizeof label, "bench step %s %d nodes", name, m->nnodes);
            sq_progress pr;
            sq_progress_begin(&pr, label, seconds);
            sq_level_step(&L.model, &L.state, &def.material, g, L.dt, NULL);
            long steps = 0;
            int batch = SQ_MAX(1, (int)(2e6 / m->nnodes));
            double t0 = sq_now(), c0 = sq_thread_cpu(), t = 0;
            while (t < seconds) {
                for (int k = 0; k < batch; k++)
                    sq_level_step(&L.model, &L.state, &def.material, g, L.dt, NULL);
                steps += batch;
                t = sq_now() - t0;
                sq_progress_update(&pr, t);
            }
            sq_progress_end(&pr);
            double cpu = sq_thread_cpu() - c0;
            double rate = (double)m->nnodes * steps / cpu, wall = (double)m->nnodes * steps / t;
            double bps = bytes_per_node_step(&L);
            double bound = SQ_BENCH_BANDWIDTH / bps;
            printf("%-9s %8d %9d %6ld %8.3f %13.2f %8.2f %11.0f %10.2f %7.0f%% %8.0f%%\n", name,
                   m->nnodes, L.model.nnz, steps, cpu, rate / 1e6, wall / 1e6, bps, bound / 1e6, 100 * rate / bound,
                   100 * rate * bps / bw);
            if (variant == 0)
                fem_cpu_rate = rate;
            if (variant == 2 && fem_cpu_rate > 0)
                printf("# %d nodes: corotational costs %.2fx the linear fem step per node-step (CPU time; "
                       "%d tets)\n", m->nnodes, fem_cpu_rate / rate, m->ntets);
            fflush(stdout);
            sq_level_free(&L);
        }
        sq_mesh_free(m);
    }
    return 0;
}

/* static vertical displacement at rest point p under both operators (interpolated) */
static int static_pair(const sq_mesh *m, const sq_material *mat, const sq_constraint *cons, int ncons,
                       const double p[3], double out[2])
{
    double g[3] = {0, 0, -9.81}, bary[4];
    int t = sq_mesh_locate(m, p, bary);
    if (t < 0)
        return -1;
    for (int op = 0; op < 2; op++) {
        sq_level L;
        sq_err err = {{0}};
        if (sq_level_init(&L, m, mat, (sq_operator_kind)op, cons, ncons, &err) < 0) {
            fprintf(stderr, "squish bench operators: %s\n", err.msg);
            return -1;
        }
        double *d = sq_malloc(sizeof(double) * 3 * (size_t)m->nnodes);
        int rc = sq_level_static_solve(&L.model, g, 1e-10, 50000, d, NULL, &err);
        if (rc < 0)
            fprintf(stderr, "squish bench operators: %s\n", err.msg);
        out[op] = 0;
        for (int k = 0; k < 4; k++)
            out[op] += bary[k] * d[3 * (size_t)m->tets[4 * t + k] + 2];
        free(d);
        sq_level_free(&L);
        if (rc < 0)
            return -1;
    }
    return 0;
}

/* one row of the operator table */
static int operator_row(const char *name, const sq_mesh *m, const sq_material *mat, const sq_constraint *c,
                        const double p[3])
{
    double u[2];
    if (static_pair(m, mat, c, 1, p, u) < 0)
        return -1;
    printf("%-40s %8d %14.6e %14.6e %10.4f\n", name, m->nnodes, u[1], u[0], u[1] / u[0]);
    fflush(stdout);
    return 0;
}

/* rows for the shipped levels meshes/<shape>/<shape>_l0..3.msh, named "<label>, <path>" (a level
 * not found is noted and skipped); -1 when a row fails */
static int shipped_rows(const char *shape, const char *label, const sq_material *mat, const sq_constraint *c,
                        const double p[3])
{
    for (int l = 0; l < 4; l++) {
        char path[64], name[128];
        snprintf(path, sizeof path, "meshes/%s/%s_l%d.msh", shape, shape, l);
        sq_err err = {{0}};
        sq_mesh *m = sq_mesh_load(path, &err);
        if (!m) {
            printf("# %s: not available (%s)\n", path, err.msg);
            continue;
        }
        snprintf(name, sizeof name, "%s, %s", label, path);
        int rc = operator_row(name, m, mat, c, p);
        sq_mesh_free(m);
        if (rc < 0)
            return -1;
    }
    return 0;
}

static int bench_operators(void)
{
    sq_material mat = sq_material_paper();
    printf("# static solutions (CG to relative residual 1e-10) under gravity 9.81 m/s^2, rho = 1000 kg/m^3\n");
    printf("%-40s %8s %14s %14s %10s\n", "case", "nodes", "paper uz (m)", "fem uz (m)", "paper/fem");
    /* the paper's cube: 1 m, bottom face fixed; corner (1,1,1); mu = 40 kPa, lambda = 100 kPa */
    sq_constraint bottom = {SQ_REGION_BOX, {-1, -1, -1}, {2, 2, 1e-6}, 7};
    double corner[3] = {1, 1, 1};
    int cube_n[] = {3, 5, 7, 10};
    for (size_t k = 0; k < SQ_COUNTOF(cube_n); k++) {
        int c = cube_n[k];
        double size[3] = {1, 1, 1}, origin[3] = {0, 0, 0};
        sq_err err = {{0}};
        sq_mesh *m = sq_mesh_box(c, c, c, size, origin, &err);
        if (!m)
            return 1;
        char name[64];
        snprintf(name, sizeof name, "cube corner, box %d^3 cells", c);
        int rc = operator_row(name, m, &mat, &bottom, corner);
        sq_mesh_free(m);
        if (rc < 0)
            return 1;
    }
    if (shipped_rows("cube", "cube corner", &mat, &bottom, corner) < 0)
        return 1;
    /* a clamped beam 1 x 0.1 x 0.1 m along x (y, z in [-0.05, 0.05]), clamped at x = 0, tip
     * centre (1, 0, 0); a rubber-like mu = 4 MPa, lambda = 10 MPa keeps the sag small */
    sq_material rub = mat;
    rub.mu = 4e6;
    rub.lambda = 1e7;
    sq_constraint clamp = {SQ_REGION_BOX, {-1, -1, -1}, {1e-6, 2, 2}, 7};
    double tip[3] = {1, 0, 0};
    int beam_n[] = {10, 20, 40, 80};
    for (size_t k = 0; k < SQ_COUNTOF(beam_n); k++) {
        int c = beam_n[k], t = SQ_MAX(1, c / 10);
        double size[3] = {1, 0.1, 0.1}, origin[3] = {0, -0.05, -0.05};
        sq_err err = {{0}};
        sq_mesh *m = sq_mesh_box(c, t, t, size, origin, &err);
        if (!m)
            return 1;
        char name[64];
        snprintf(name, sizeof name, "beam tip, box %dx%dx%d cells", c, t, t);
        int rc = operator_row(name, m, &rub, &clamp, tip);
        sq_mesh_free(m);
        if (rc < 0)
            return 1;
    }
    if (shipped_rows("beam", "beam tip", &rub, &clamp, tip) < 0)
        return 1;
    /* Euler-Bernoulli cantilever under its own weight: w = q L^4 / (8 E I), q = rho g A */
    double E, nu;
    sq_material_E_nu(&rub, &E, &nu);
    double A = 0.01, I = 0.1 * 0.1 * 0.1 * 0.1 / 12;
    printf("# beam theory (Euler-Bernoulli, E = %.4g Pa): tip deflection %.6e m\n", E,
           -1000 * 9.81 * A / (8 * E * I));
    return 0;
}

/* the paper's cube: corner displacement curves at three resolutions, both operators */
static int bench_cube(const char *dir, double seconds, const char *out)
{
    enum { NRES = 3 };
    sq_mesh *mesh[NRES];
    sq_body *body[2][NRES];
    FILE *f = out ? fopen(out, "w") : stdout;
    if (!f) {
        fprintf(stderr, "squish bench cube: cannot write '%s'; check the directory exists\n", out);
        return 1;
    }
    for (int r = 0; r < NRES; r++) {
        char path[1024];
        snprintf(path, sizeof path, "%s/cube_l%d.msh", dir, r + 1);
        sq_err err = {{0}};
        mesh[r] = sq_mesh_load(path, &err);
        if (!mesh[r]) {
            fprintf(stderr, "squish bench cube: %s\n", err.msg);
            return 1;
        }
        for (int op = 0; op < 2; op++) {
            sq_body_def def = sq_body_def_default();
            def.name = "cube";
            def.nlevels = 1;
            def.levels[0] = mesh[r];
            def.op = (sq_operator_kind)op;
            def.gravity[2] = -9.81;
            def.nconstraints = 1;
            def.constraints[0] = (sq_constraint){SQ_REGION_BOX, {-1, -1, -1}, {2, 2, 1e-6}, 7};
            body[op][r] = sq_body_create(&def, &err);
            if (!body[op][r]) {
                fprintf(stderr, "squish bench cube: %s\n", err.msg);
                return 1;
            }
            sq_body_set_sleep(body[op][r], 0, 0, 0);
        }
    }
    fprintf(f, "# paper section 2.6: 1 m cube, bottom face fixed, gravity 9.81, mu=40 kPa, lambda=100 kPa,\n"
               "# rho=1000, Rayleigh a=0.5/s b=1e-3 s, 50 Hz; corner (1,1,1) u_z in m\n");
    fprintf(f, "time");
    for (int op = 0; op < 2; op++)
        for (int r = 0; r < NRES; r++)
            fprintf(f, ",%s_%dnodes", op ? "paper" : "fem", mesh[r]->nnodes);
    fprintf(f, "\n");
    int frames = (int)lround(seconds * 50);
    double corner[3] = {1, 1, 1};
    sq_progress pr;
    sq_progress_begin(&pr, "bench cube", frames);
    for (int fr = 0; fr <= frames; fr++) {
        fprintf(f, "%.3f", fr / 50.0);
        for (int op = 0; op < 2; op++)
            for (int r = 0; r < NRES; r++) {
                double u[3] = {0, 0, 0};
                sq_body_probe(body[op][r], corner, u);
                fprintf(f, ",%.6e", u[2]);
            }
        fprintf(f, "\n");
        for (int op = 0; op < 2; op++)
            for (int r = 0; r < NRES; r++)
                sq_body_frame(body[op][r], NULL, 0, NULL, NULL, 0);
        sq_progress_update(&pr, fr);
    }
    sq_progress_end(&pr);
    for (int r = 0; r < NRES; r++) {
        sq_body_destroy(body[0][r]);
        sq_body_destroy(body[1][r]);
        sq_mesh_free(mesh[r]);
    }
    if (out)
        fclose(f);
    return 0;
}

int sq_cmd_bench(int argc, char **argv)
{
    const char *meshdir = "meshes/cube", *out = NULL;
    int seconds_given = 0;
    const char *what = "all", *sizes = "1k,10k,100k,1M";
    double seconds = 1.0;
    int op_mask = 7, quick = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h"))
            return usage(stdout);
        else if (!strcmp(argv[i], "step") || !strcmp(argv[i], "operators") || !strcmp(argv[i], "all") ||
                 !strcmp(argv[i], "cube") || !strcmp(argv[i], "implicit") || !strcmp(argv[i], "contact"))
            what = argv[i];
        else if (!strcmp(argv[i], "--quick"))
            quick = 1;
        else if (!strcmp(argv[i], "--sizes") && i + 1 < argc)
            sizes = argv[++i];
        else if (!strcmp(argv[i], "--meshes") && i + 1 < argc)
            meshdir = argv[++i];
        else if (!strcmp(argv[i], "--out") && i + 1 < argc)
            out = argv[++i];
        else if (!strcmp(argv[i], "--seconds") && i + 1 < argc) {
            char *end;
            seconds = strtod(argv[++i], &end);
            seconds_given = 1;
            if (*end || !(seconds > 0) || seconds > 3600) {
                fprintf(stderr, "squish bench: --seconds '%s' must be a number in (0, 3600]\n", argv[i]);
                return 2;
            }
        } else if (!strcmp(argv[i], "--op") && i + 1 < argc) {
            i++;
            if (!strcmp(argv[i], "fem"))
                op_mask = 1;
            else if (!strcmp(argv[i], "paper"))
                op_mask = 2;
            else if (!strcmp(argv[i], "both"))
                op_mask = 3;
            else if (!strcmp(argv[i], "corot"))
                op_mask = 5; /* linear fem beside corotational */
            else {
                fprintf(stderr, "squish bench: --op '%s' must be fem, paper, both or corot\n", argv[i]);
                return 2;
            }
        } else {
            fprintf(stderr, "squish bench: unknown argument '%s'\n", argv[i]);
            return usage(stderr);
        }
    }
    int rc = 0;
    if (!strcmp(what, "implicit"))
        return sq_bench_implicit(quick);
    if (!strcmp(what, "contact"))
        return sq_bench_contact(quick);
    if (!strcmp(what, "cube"))
        return bench_cube(meshdir, seconds_given ? seconds : 4.0, out);
    if (!strcmp(what, "step") || !strcmp(what, "all"))
        rc = bench_step(sizes, seconds, op_mask);
    if (rc == 0 && (!strcmp(what, "operators") || !strcmp(what, "all")))
        rc = bench_operators();
    return rc;
}
