/* bench_scenes.c - scene benchmarks: frame-budget headroom of the shipped scenes, and the
 * throughput of 1 vs 2 threads running independent worlds (the server's session model).
 *
 *   squish tradeoff --bench [--scenes DIR] [--frames N] [--threads-scene NAME]
 *
 * Per scene: wall time of every sq_world_step with the live budget (the frame period, as the
 * server runs it: adaptive bodies stop splitting when a frame takes too long), its median, 95th percentile and maximum against the
 * frame period, and the headroom 1 - p95 / period. Meant to be wired into `squish bench` too
 * (sq_bench_scenes takes the arguments after the subcommand name).
 */
#include <dirent.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "engines/engines.h"
#include "scene/scene.h"
#include "body/body.h"

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

static int cmp_str(const void *a, const void *b)
{
    return strcmp(*(char *const *)a, *(char *const *)b);
}

typedef struct bench_job {
    const sq_scene *scene;
    long frames;
    double wall, cpu;      /* wall and thread CPU seconds of the run */
    int ok;
} bench_job;

/* run one world of the scene for job->frames frames */
static void *run_world(void *arg)
{
    bench_job *j = arg;
    sq_err err = {{0}};
    sq_world *w = sq_world_create(j->scene, &err);
    if (!w)
        return NULL;
    double t0 = sq_now(), c0 = sq_thread_cpu();
    for (long f = 0; f < j->frames; f++)
        sq_world_step(w, 0);
    j->wall = sq_now() - t0;
    j->cpu = sq_thread_cpu() - c0;
    j->ok = 1;
    sq_world_destroy(w);
    return NULL;
}

/* 1 vs 2 threads: two independent worlds of the scene, one after the other on this thread,
 * then at the same time on two threads; prints the throughput ratio */
static void bench_threads(const char *path, long frames)
{
    sq_err err = {{0}};
    sq_scene *s = sq_scene_load(path, &err);
    if (!s) {
        fprintf(stderr, "squish tradeoff --bench: %s\n", err.msg);
        return;
    }
    bench_job a = {s, frames, 0, 0, 0}, b = {s, frames, 0, 0, 0};
    double t0 = sq_now();
    run_world(&a);
    run_world(&b);
    double seq = sq_now() - t0;
    bench_job c = {s, frames, 0, 0, 0}, d = {s, frames, 0, 0, 0};
    pthread_t th;
    t0 = sq_now();
    int spawned = pthread_create(&th, NULL, run_world, &c) == 0;
    run_world(&d);
    if (spawned)
        pthread_join(th, NULL);
    double par = sq_now() - t0;
    if (a.ok && b.ok && c.ok && d.ok && spawned)
        printf("\n1 vs 2 threads (%s, two independent worlds x %ld frames): 1 thread %.3f s, 2 threads %.3f s: "
               "x%.2f throughput\n"
               "  CPU seconds per world: %.3f, %.3f alone; %.3f, %.3f side by side: x%.2f (1 = the threads do not\n"
               "  slow each other; on an idle 2-core machine the throughput would be about 2 / that)\n",
               s->name, frames, seq, par, seq / par, a.cpu, b.cpu, c.cpu, d.cpu, (c.cpu + d.cpu) / (a.cpu + b.cpu));
    else
        printf("\n1 vs 2 threads: could not run two worlds of %s\n", s->name);
    sq_scene_free(s);
}

/* ---- does a second thread add memory bandwidth to a step-like pass? -------------------------
 * y = K x over the full CSR blocks of a large level (rows independent, so they split between
 * threads with no reduction): the same bytes per row as the engine's force pass before its
 * upper-half form. Timed with 1 and 2 threads, best of several passes. */
typedef struct spmv_job {
    const sq_level *L;
    const double *x;
    double *y;
    int r0, r1, reps;
} spmv_job;

static void *spmv_rows(void *arg)
{
    spmv_job *j = arg;
    const sq_level *L = j->L;
    for (int rep = 0; rep < j->reps; rep++)
        for (int i = j->r0; i < j->r1; i++) {
            double a0 = 0, a1 = 0, a2 = 0;
            for (int p = L->model.row_start[i]; p < L->model.row_start[i + 1]; p++) {
                const double *B = L->model.K + 9 * (size_t)p, *xj = j->x + 3 * (size_t)L->model.col[p];
                a0 += B[0] * xj[0] + B[1] * xj[1] + B[2] * xj[2];
                a1 += B[3] * xj[0] + B[4] * xj[1] + B[5] * xj[2];
                a2 += B[6] * xj[0] + B[7] * xj[1] + B[8] * xj[2];
            }
            j->y[3 * i] = a0;
            j->y[3 * i + 1] = a1;
            j->y[3 * i + 2] = a2;
        }
    return NULL;
}

static void bench_spmv_threads(int cells)
{
    double size[3] = {1, 1, 1}, origin[3] = {0, 0, 0};
    sq_err err = {{0}};
    sq_mesh *m = sq_mesh_box(cells, cells, cells, size, origin, &err);
    if (!m) {
        fprintf(stderr, "squish tradeoff --bench: %s\n", err.msg);
        return;
    }
    sq_material mat = sq_material_paper();
    sq_level L;
    if (sq_level_init(&L, m, &mat, SQ_OPERATOR_FEM, NULL, 0, &err) < 0) {
        fprintf(stderr, "squish tradeoff --bench: %s\n", err.msg);
        sq_mesh_free(m);
        return;
    }
    double *x = sq_malloc(sizeof(double) * 3 * (size_t)L.model.n), *y = sq_malloc(sizeof(double) * 3 * (size_t)L.model.n);
    for (int i = 0; i < 3 * L.model.n; i++)
        x[i] = 1e-3 * ((i * 7919) % 1000);
    double bytes = (9.0 * 8 + 4) * L.model.nnz + (4 + 24 + 24) * (double)L.model.n; /* blocks, cols, rows, x once, y */
    double best[3] = {INFINITY, INFINITY, INFINITY};
    for (int trial = 0; trial < 5; trial++)
        for (int nt = 1; nt <= 2; nt++) {
            spmv_job j[2] = {{&L, x, y, 0, L.model.n, 1}, {&L, x, y, 0, 0, 1}};
            if (nt == 2) {
                j[0].r1 = L.model.n / 2;
                j[1].r0 = L.model.n / 2;
                j[1].r1 = L.model.n;
            }
            pthread_t th;
            double t0 = sq_now();
            int spawned = nt == 2 && pthread_create(&th, NULL, spmv_rows, &j[1]) == 0;
            spmv_rows(&j[0]);
            if (nt == 2 && !spawned)
                spmv_rows(&j[1]);
            if (spawned)
                pthread_join(th, NULL);
            double t = sq_now() - t0;
            if (t < best[nt])
                best[nt] = t;
        }
    printf("\nK x on a %d-node box (full CSR blocks, %.0f MB per pass, rows split between threads):\n"
           "  1 thread %.2f ms (%.1f GB/s), 2 threads %.2f ms (%.1f GB/s): x%.2f (best of 5)\n",
           L.model.n, bytes / 1e6, 1e3 * best[1], bytes / best[1] / 1e9, 1e3 * best[2], bytes / best[2] / 1e9,
           best[1] / best[2]);
    free(x);
    free(y);
    sq_level_free(&L);
    sq_mesh_free(m);
}

int sq_bench_scenes(int argc, char **argv)
{
    const char *dir = "meshes/scenes", *thread_scene = "organ", *one = NULL;
    long frames = 0;
    int spmv_cells = 79; /* 80^3 = 512,000 nodes, ~330 MB of blocks */
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--scenes") && i + 1 < argc) {
            dir = argv[++i];
        } else if (!strcmp(argv[i], "--frames") && i + 1 < argc) {
            char *end;
            frames = strtol(argv[++i], &end, 10);
            if (*end || frames < 1 || frames > 100000) {
                fprintf(stderr, "squish tradeoff --bench: --frames needs a whole number 1..100000\n");
                return 2;
            }
        } else if (!strcmp(argv[i], "--spmv-cells") && i + 1 < argc) {
            char *end;
            long c = strtol(argv[++i], &end, 10);
            if (*end || c < 1 || c > 150) {
                fprintf(stderr, "squish tradeoff --bench: --spmv-cells needs 1..150 (cells per side of the box)\n");
                return 2;
            }
            spmv_cells = (int)c;
        } else if (!strcmp(argv[i], "--scene") && i + 1 < argc) {
            one = argv[++i];
        } else if (!strcmp(argv[i], "--threads-scene") && i + 1 < argc) {
            thread_scene = argv[++i];
        } else {
            fprintf(stderr, "squish tradeoff --bench: unknown argument '%s'; options: --scenes DIR, --frames N, "
                            "--scene FILE, --threads-scene NAME, --spmv-cells C\n", argv[i]);
            return 2;
        }
    }
    char *names[64];
    int n = 0;
    if (one) {
        /* one scene file, no thread or spmv benches */
        dir = NULL;
        names[n++] = sq_strdup(one);
    } else {
        DIR *d = opendir(dir);
        if (!d) {
            fprintf(stderr, "squish tradeoff --bench: cannot open scene directory %s; pass --scenes DIR\n", dir);
            return 1;
        }
        struct dirent *e;
        while ((e = readdir(d)) && n < 64) {
            size_t len = strlen(e->d_name);
            if (len > 5 && !strcmp(e->d_name + len - 5, ".json"))
                names[n++] = sq_strdup(e->d_name);
        }
        closedir(d);
    }
    qsort(names, (size_t)n, sizeof *names, cmp_str);
    printf("# frame-budget headroom: wall time per frame (sq_world_step with the live budget = the frame\n"
           "# period, so adaptive bodies stop splitting above lod.budget of it), one thread\n");
    printf("%-14s %7s %8s %9s %9s %9s %9s %9s %7s %9s %9s %9s %9s %9s\n", "scene", "frames", "nodes", "period ms",
           "p50 ms", "p95 ms", "max ms", "headroom", "misses", "cpu p95", "cpu room", "cpu max*", "cpu late*",
           "cpu s/s");
    char thread_path[1024] = "";
    for (int k = 0; k < n; k++) {
        char path[1024];
        if (dir)
            snprintf(path, sizeof path, "%s/%s", dir, names[k]);
        else
            snprintf(path, sizeof path, "%s", names[k]);
        sq_err err = {{0}};
        sq_scene *s = sq_scene_load(path, &err);
        if (!s && strstr(err.msg, SQ_SCENE_MESHES_NOT_MADE)) {
            printf("%-14s skipped: %s\n", names[k], err.msg);
            continue;
        }
        if (!s) {
            printf("%-14s refused: %s\n", names[k], err.msg);
            continue;
        }
        if (!strcmp(s->name, thread_scene))
            snprintf(thread_path, sizeof thread_path, "%s", path);
        sq_world *w = sq_world_create(s, &err);
        if (!w) {
            printf("%-14s refused: %s\n", s->name, err.msg);
            sq_scene_free(s);
            continue;
        }
        long nf = frames > 0 ? frames : (long)ceil(s->duration * s->frame_rate - 1e-9);
        double *t = sq_malloc(sizeof(double) * (size_t)(nf > 0 ? nf : 1));
        double *tc = sq_malloc(sizeof(double) * (size_t)(nf > 0 ? nf : 1));
        long nodes = 0;
        for (int b = 0; b < w->nbodies; b++)
            nodes += sq_body_surface_mesh(w->bodies[b])->nnodes;
        double period = 1.0 / s->frame_rate;
        sq_world_prepare_budget(w); /* at load, as the server */
        for (long f = 0; f < nf; f++) {
            double t0 = sq_now(), c0 = sq_thread_cpu();
            sq_world_step(w, period); /* live budget: splits stop above lod.budget x period */
            t[f] = sq_now() - t0;
            tc[f] = sq_thread_cpu() - c0;
        }
        /* after the first frame (which may carry one-off set-up): the slowest frame in CPU time,
         * the frames over the period in CPU time, and CPU seconds per simulated second */
        double cmax1 = 0, csum = 0;
        long clate1 = 0;
        for (long f = 0; f < nf; f++) {
            csum += tc[f];
            if (f > 0) {
                cmax1 = fmax(cmax1, tc[f]);
                clate1 += tc[f] > period;
            }
        }
        qsort(t, (size_t)nf, sizeof *t, cmp_double);
        qsort(tc, (size_t)nf, sizeof *tc, cmp_double);
        long misses = 0;
        for (long f = 0; f < nf; f++)
            misses += t[f] > period;
        double p50 = nf ? t[nf / 2] : 0, p95 = nf ? t[(long)(0.95 * (nf - 1))] : 0, mx = nf ? t[nf - 1] : 0;
        double c95 = nf ? tc[(long)(0.95 * (nf - 1))] : 0;
        printf("%-14s %7ld %8ld %9.1f %9.2f %9.2f %9.2f %8.0f%% %7ld %9.2f %8.0f%% %9.2f %9ld %9.4f\n", s->name, nf,
               nodes, 1e3 * period, 1e3 * p50, 1e3 * p95, 1e3 * mx, 100 * (1 - p95 / period), misses, 1e3 * c95,
               100 * (1 - c95 / period), 1e3 * cmax1, clate1, nf ? csum / (nf * period) : 0);
        fflush(stdout);
        free(t);
        free(tc);
        sq_world_destroy(w);
        sq_scene_free(s);
    }
    printf("# nodes: finest loaded level of every body; headroom = 1 - p95 / period (negative: frames late);\n"
           "# cpu p95 / cpu room: the same from the thread's CPU time (what an idle core would take);\n"
           "# cpu max* / cpu late*: slowest frame and frames over the period in CPU time, after frame 1;\n"
           "# cpu s/s: thread CPU seconds per simulated second\n");
    if (one) {
        free(names[0]);
        return 0;
    }
    if (thread_path[0])
        bench_threads(thread_path, frames > 0 ? SQ_MIN(frames, 100L) : 100L);
    bench_spmv_threads(spmv_cells);
    for (int k = 0; k < n; k++)
        free(names[k]);
    return 0;
}
