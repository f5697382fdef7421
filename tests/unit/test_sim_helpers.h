/* test_sim_helpers.h - small functions shared by the unit tests: the shipped meshes, boxes,
 * materials, forces, tools (the sim, physics, mesh and level-of-detail tests). */
#ifndef SQ_TEST_SIM_HELPERS_H
#define SQ_TEST_SIM_HELPERS_H

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "body/body.h"
#include "sq_test.h"

/* CHECK(p != NULL) and leave the test when it fails: the rest needs p (use after sq_test.h) */
#define TH_REQUIRE(p)                                                                   \
    do {                                                                                \
        CHECK(p != NULL);                                                               \
        if (!(p))                                                                       \
            return;                                                                     \
    } while (0)

/* max that propagates NaN (fmax would drop it and let a broken state pass) */
static inline double th_max(double a, double b) { return (a > b || isnan(a)) ? a : b; }

/* largest eigenvalue of the dense symmetric nf x nf matrix A (row-major) by cyclic Jacobi
 * rotations to off-diagonal mass 1e-24 of the diagonal's (at most 50 sweeps); A is destroyed.
 * The tests' independent reference for the step bounds (dense, so small meshes only). */
static inline double th_sym_eig_max(double *A, int nf)
{
    for (int sweep = 0; sweep < 50; sweep++) {
        double off = 0, diag = 0;
        for (int p = 0; p < nf; p++)
            for (int q = 0; q < nf; q++)
                if (p == q)
                    diag += A[(size_t)p * nf + q] * A[(size_t)p * nf + q];
                else
                    off += A[(size_t)p * nf + q] * A[(size_t)p * nf + q];
        if (off <= 1e-24 * diag)
            break;
        for (int p = 0; p < nf; p++)
            for (int q = p + 1; q < nf; q++) {
                double apq = A[(size_t)p * nf + q];
                if (fabs(apq) < 1e-300)
                    continue;
                double app = A[(size_t)p * nf + p], aqq = A[(size_t)q * nf + q];
                double th = (aqq - app) / (2 * apq);
                double t = (th >= 0 ? 1 : -1) / (fabs(th) + sqrt(th * th + 1));
                double c = 1 / sqrt(t * t + 1), s = t * c;
                for (int k = 0; k < nf; k++) { /* columns p, q */
                    double akp = A[(size_t)k * nf + p], akq = A[(size_t)k * nf + q];
                    A[(size_t)k * nf + p] = c * akp - s * akq;
                    A[(size_t)k * nf + q] = s * akp + c * akq;
                }
                for (int k = 0; k < nf; k++) { /* rows p, q */
                    double apk = A[(size_t)p * nf + k], aqk = A[(size_t)q * nf + k];
                    A[(size_t)p * nf + k] = c * apk - s * aqk;
                    A[(size_t)q * nf + k] = s * apk + c * aqk;
                }
            }
    }
    double lam = 0;
    for (int p = 0; p < nf; p++)
        lam = th_max(lam, A[(size_t)p * nf + p]);
    return lam;
}

/* the shipped mesh meshes/<printf(fmt, ...)> (meshes/ is beside tests/: the runner starts in the
 * repository root, SQ_TEST_DATA moves tests/data along with it); NULL, its error printed, when it
 * does not load: the caller checks */
static inline sq_mesh *th_shipped_mesh(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static inline sq_mesh *th_shipped_mesh(const char *fmt, ...)
{
    char rel[512], path[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(rel, sizeof rel, fmt, ap);
    va_end(ap);
    snprintf(path, sizeof path, "%s/../../meshes/%s", sq_test_data(), rel);
    sq_err e = {{0}};
    sq_mesh *m = sq_mesh_load(path, &e);
    if (!m)
        fprintf(stderr, "    %s\n", e.msg);
    return m;
}

/* a box mesh or fail the test (returns NULL) */
static inline sq_mesh *th_box(int nx, int ny, int nz, double sx, double sy, double sz)
{
    sq_err e = {{0}};
    double size[3] = {sx, sy, sz}, origin[3] = {0, 0, 0};
    sq_mesh *m = sq_mesh_box(nx, ny, nz, size, origin, &e);
    if (!m)
        fprintf(stderr, "sq_mesh_box: %s\n", e.msg);
    return m;
}

/* the body defaults with the one level m */
static inline sq_body_def th_body_def(const sq_mesh *m)
{
    sq_body_def def = sq_body_def_default();
    def.nlevels = 1;
    def.levels[0] = m;
    return def;
}

/* an undamped material with standard Lamé parameters */
static inline sq_material th_material(double mu, double lambda, double density)
{
    sq_material m;
    memset(&m, 0, sizeof m);
    m.mu = mu;
    m.lambda = lambda;
    m.density = density;
    return m;
}

/* elastic force of displacement d on level L into L->f (no gravity, no damping) */
static inline void th_elastic_force(sq_level *L, const sq_material *mat, const double *d)
{
    static const double zero[3] = {0, 0, 0};
    sq_material m = *mat;
    m.rayleigh_mass = m.rayleigh_stiffness = 0;
    m.use_viscosity = 0;
    memcpy(L->state.d, d, sizeof(double) * 3 * (size_t)L->model.n);
    memset(L->state.v, 0, sizeof(double) * 3 * (size_t)L->model.n);
    sq_level_forces(&L->model, &L->state, &m, zero, NULL);
}

/* largest |entry| of the level's K, a scale for force tolerances */
static inline double th_kmax(const sq_level *L)
{
    double s = 0;
    for (size_t k = 0; k < 9 * (size_t)L->model.nnz; k++)
        s = th_max(s, fabs(L->model.K[k]));
    return s;
}

static inline double th_norm3(const double *v) { return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

/* mean z displacement of the nodes of m at x >= x_end (to 1e-9 relative): a beam's tip */
static inline double th_tip_z(const sq_mesh *m, const double *d, double x_end)
{
    double s = 0;
    int n = 0;
    for (int i = 0; i < m->nnodes; i++)
        if (m->x[3 * i] > x_end * (1 - 1e-9)) {
            s += d[3 * i + 2];
            n++;
        }
    return n ? s / n : NAN;
}

/* a sphere tool pressing a body at rest: |tool force on the body + support reactions + weight|
 * (N), with the reactions from the fixed nodes' forces in L->f and the tool's own held nodes
 * (on its surface) carrying their weight; *weight receives |weight|, react_z the reactions' z */
static inline double th_tool_balance(const sq_level *L, const sq_mesh *m, const sq_tool *t, const sq_tool_feedback *fb,
                                     const double g[3], double *weight, double *react_z)
{
    double R[3] = {0, 0, 0}, W[3], Mh = 0, Mt = 0, sum[3];
    for (int i = 0; i < L->model.n; i++) {
        Mt += L->model.mass[i];
        if (L->model.fixed[i] == 7)
            for (int c = 0; c < 3; c++)
                R[c] -= L->state.f[3 * i + c];
        const double *x = m->x + 3 * i;
        double p[3] = {x[0] + L->state.d[3 * i] - t->pos[0], x[1] + L->state.d[3 * i + 1] - t->pos[1],
                       x[2] + L->state.d[3 * i + 2] - t->pos[2]};
        if (m->on_boundary[i] && fabs(th_norm3(p) - t->radius) < 1e-12)
            Mh += L->model.mass[i];
    }
    for (int c = 0; c < 3; c++) {
        W[c] = Mt * g[c];
        sum[c] = -(fb->force[c] + Mh * g[c]) + R[c] + W[c];
    }
    *weight = th_norm3(W);
    *react_z = R[2];
    return th_norm3(sum);
}

/* largest |force| of L->f over the interior nodes and over the boundary nodes of m */
static inline void th_force_split(const sq_mesh *m, const sq_level *L, double *interior, double *boundary)
{
    double fi = 0, fb = 0;
    for (int i = 0; i < m->nnodes; i++) {
        double f = th_norm3(L->state.f + 3 * i);
        if (m->on_boundary[i])
            fb = th_max(fb, f);
        else
            fi = th_max(fi, f);
    }
    *interior = fi;
    *boundary = fb;
}

/* an inactive tool of the given shape with every other field zero */
static inline sq_tool th_tool(sq_tool_shape shape)
{
    sq_tool t;
    memset(&t, 0, sizeof t);
    t.shape = shape;
    return t;
}

#endif
