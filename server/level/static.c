/* static.c - static equilibrium K d = M g on a level, by preconditioned conjugate gradients.
 *
 * The reference the dynamic runs are checked against (PHYSICS.md section 6): same blocks,
 * same constraints (constrained axes held at zero displacement), Jacobi preconditioner.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "level/level.h"

/* y = K x on unconstrained axes (constrained components of x are taken as zero) */
static void matvec(const sq_level_model *M, const void *ctx, const double *x, double *y)
{
    (void)ctx;
    for (int i = 0; i < M->n; i++) {
        double s[3] = {0, 0, 0};
        for (int e = M->row_start[i]; e < M->row_start[i + 1]; e++) {
            const double *B = M->K + 9 * (size_t)e, *xj = x + 3 * (size_t)M->col[e];
            for (int r = 0; r < 3; r++)
                s[r] += B[3 * r] * xj[0] + B[3 * r + 1] * xj[1] + B[3 * r + 2] * xj[2];
        }
        for (int r = 0; r < 3; r++)
            y[3 * i + r] = (M->fixed[i] & (1u << r)) ? 0 : s[r];
    }
}

static double dot(const double *a, const double *b, size_t n)
{
    double s = 0;
    for (size_t k = 0; k < n; k++)
        s += a[k] * b[k];
    return s;
}

int sq_level_pcg(const sq_level_model *M, sq_level_op op, const void *ctx, const double *b, const double *pre,
                 double tol, int max_iter, double *x, int *iterations, sq_err *err)
{
    size_t n3 = 3 * (size_t)M->n;
    double *r = sq_malloc(sizeof(double) * n3), *z = sq_malloc(sizeof(double) * n3);
    double *p = sq_malloc(sizeof(double) * n3), *q = sq_malloc(sizeof(double) * n3);
    memcpy(r, b, sizeof(double) * n3);
    memset(x, 0, sizeof(double) * n3);
    double bnorm = sqrt(dot(r, r, n3));
    int it = 0, rc = 0;
    if (bnorm > 0) {
        for (size_t k = 0; k < n3; k++)
            z[k] = pre[k] * r[k];
        memcpy(p, z, sizeof(double) * n3);
        double rz = dot(r, z, n3);
        for (it = 0; it < max_iter; it++) {
            if (sqrt(dot(r, r, n3)) <= tol * bnorm)
                break;
            op(M, ctx, p, q);
            double pq = dot(p, q, n3);
            if (!(pq > 0)) {
                rc = sq_err_set(err, "%s: conjugate gradients broke down (p.Kp = %g at iteration %d): "
                                     "the operator is not positive definite on the free axes; add constraints",
                                M->mesh->source, pq, it);
                break;
            }
            double alpha = rz / pq;
            for (size_t k = 0; k < n3; k++) {
                x[k] += alpha * p[k];
                r[k] -= alpha * q[k];
            }
            for (size_t k = 0; k < n3; k++)
                z[k] = pre[k] * r[k];
            double rz2 = dot(r, z, n3);
            double beta = rz2 / rz;
            rz = rz2;
            for (size_t k = 0; k < n3; k++)
                p[k] = z[k] + beta * p[k];
        }
        if (rc == 0 && it >= max_iter)
            rc = sq_err_set(err, "%s: conjugate gradients did not reach relative residual %g in %d iterations "
                                 "(now %g)", M->mesh->source, tol, max_iter, sqrt(dot(r, r, n3)) / bnorm);
    }
    if (iterations)
        *iterations = it;
    free(r);
    free(z);
    free(p);
    free(q);
    return rc;
}

/* K d = M g on the free axes by sq_level_pcg, Jacobi-preconditioned from the diagonal blocks */
static int cg_solve(const sq_level_model *M, sq_level_op op, const void *ctx, const double gravity[3], double tol,
                    int max_iter, double *d, int *iterations, sq_err *err)
{
    size_t n3 = 3 * (size_t)M->n;
    double *b = sq_malloc(sizeof(double) * n3), *pre = sq_malloc(sizeof(double) * n3);
    for (int i = 0; i < M->n; i++) {
        int e = M->row_start[i];
        while (M->col[e] != i)
            e++;
        for (int c = 0; c < 3; c++) {
            int fx = (M->fixed[i] >> c) & 1;
            b[3 * i + c] = fx ? 0 : M->mass[i] * gravity[c];
            double kd = M->K[9 * (size_t)e + 4 * c];
            pre[3 * i + c] = fx || !(kd > 0) ? 0 : 1.0 / kd;
        }
    }
    int rc = sq_level_pcg(M, op, ctx, b, pre, tol, max_iter, d, iterations, err);
    free(b);
    free(pre);
    return rc;
}

int sq_level_static_solve(const sq_level_model *M, const double gravity[3], double tol, int max_iter,
                          double *d, int *iterations, sq_err *err)
{
    return cg_solve(M, matvec, NULL, gravity, tol, max_iter, d, iterations, err);
}

/* ---- average nodal pressure tets (static solve; the step is level/anp.c) --------------------
 * Energy sum_T V_T mu |dev eps_T|^2 + sum_i (kappa / 2) W_i theta_i^2, kappa = lambda + 2 mu / 3,
 * W_i the nodal volume, theta_i = sum_{T ni i} (V_T / 4) tr(eps_T) / W_i: the volumetric strain
 * averaged at the nodes, so a tet's pressure is kappa times the mean of its 4 nodes' theta. The
 * operator is symmetric and not above the standard one (Jensen), so the standard bound holds. */
typedef struct {
    const sq_material *mat;
    double *grad;  /* per tet: a_0..a_3 (12) and V */
    double *theta; /* scratch, n */
} anp_ctx;

static void anp_matvec(const sq_level_model *M, const void *vctx, const double *x, double *y)
{
    const anp_ctx *c = vctx;
    const sq_mesh *m = M->mesh;
    const double mu = c->mat->mu, kappa = c->mat->lambda + 2.0 * c->mat->mu / 3.0;
    memset(c->theta, 0, sizeof(double) * (size_t)M->n);
    memset(y, 0, sizeof(double) * 3 * (size_t)M->n);
    for (int t = 0; t < m->ntets; t++) {
        const double *a = c->grad + 13 * (size_t)t;
        double th = 0;
        for (int k = 0; k < 4; k++) {
            int i = m->tets[4 * t + k];
            for (int r = 0; r < 3; r++)
                if (!(M->fixed[i] & (1u << r)))
                    th += a[3 * k + r] * x[3 * i + r];
        }
        for (int k = 0; k < 4; k++)
            c->theta[m->tets[4 * t + k]] += a[12] / 4 * th;
    }
    for (int i = 0; i < M->n; i++)
        c->theta[i] /= M->vol[i];
    for (int t = 0; t < m->ntets; t++) {
        const double *a = c->grad + 13 * (size_t)t;
        const int *tv = m->tets + 4 * t;
        double G[9] = {0};
        for (int k = 0; k < 4; k++)
            for (int r = 0; r < 3; r++) {
                double u = (M->fixed[tv[k]] & (1u << r)) ? 0 : x[3 * tv[k] + r];
                for (int cc = 0; cc < 3; cc++)
                    G[3 * r + cc] += u * a[3 * k + cc];
            }
        double tr = G[0] + G[4] + G[8], tbar = 0;
        for (int k = 0; k < 4; k++)
            tbar += 0.25 * c->theta[tv[k]];
        double sig[9];
        for (int r = 0; r < 3; r++)
            for (int cc = 0; cc < 3; cc++)
                sig[3 * r + cc] = mu * (G[3 * r + cc] + G[3 * cc + r]) +
                                  (r == cc ? kappa * tbar - 2.0 * mu * tr / 3.0 : 0);
        for (int k = 0; k < 4; k++)
            for (int r = 0; r < 3; r++)
                y[3 * tv[k] + r] += a[12] * (sig[3 * r] * a[3 * k] + sig[3 * r + 1] * a[3 * k + 1] +
                                             sig[3 * r + 2] * a[3 * k + 2]);
    }
    for (int i = 0; i < M->n; i++)
        for (int r = 0; r < 3; r++)
            if (M->fixed[i] & (1u << r))
                y[3 * i + r] = 0;
}

int sq_level_static_solve_nodal_pressure(const sq_level_model *M, const sq_material *mat, const double gravity[3],
                                         double tol, int max_iter, double *d, int *iterations, sq_err *err)
{
    const sq_mesh *m = M->mesh;
    anp_ctx c = {mat, sq_malloc(sizeof(double) * 13 * (size_t)m->ntets), sq_malloc(sizeof(double) * (size_t)M->n)};
    for (int t = 0; t < m->ntets; t++) {
        double a[4][3];
        double V = sq_tet_gradients(m, t, a);
        for (int k = 0; k < 4; k++)
            for (int r = 0; r < 3; r++)
                c.grad[13 * (size_t)t + 3 * k + r] = a[k][r];
        c.grad[13 * (size_t)t + 12] = V;
    }
    int rc = cg_solve(M, anp_matvec, &c, gravity, tol, max_iter, d, iterations, err);
    free(c.grad);
    free(c.theta);
    return rc;
}

/* ---- the pressure modes of level/anp.c (nodal, smoothed) through its operator ---------------
 * y = P K P x with P zeroing the constrained axes: symmetric, and the step's own operator */
typedef struct {
    sq_anp *A;
    double *xm; /* scratch: x with the constrained axes zeroed */
} anp_op_ctx;

static void anp_op_matvec(const sq_level_model *M, const void *vctx, const double *x, double *y)
{
    const anp_op_ctx *c = vctx;
    for (int i = 0; i < M->n; i++)
        for (int r = 0; r < 3; r++)
            c->xm[3 * i + r] = (M->fixed[i] & (1u << r)) ? 0 : x[3 * i + r];
    sq_anp_apply(c->A, M->mesh, M->vol, c->xm, y);
    for (int i = 0; i < M->n; i++)
        for (int r = 0; r < 3; r++)
            if (M->fixed[i] & (1u << r))
                y[3 * i + r] = 0;
}

int sq_level_static_solve_pressure(const sq_level_model *M, const sq_material *mat, int mode, const double gravity[3],
                                   double tol, int max_iter, double *d, int *iterations, sq_err *err)
{
    if (mode == SQ_PRESSURE_ELEMENT)
        return sq_level_static_solve(M, gravity, tol, max_iter, d, iterations, err);
    if (mode != SQ_PRESSURE_NODAL && mode != SQ_PRESSURE_SMOOTHED)
        return sq_err_set(err, "pressure mode %d is unknown: use element, nodal or smoothed", mode);
    anp_op_ctx c = {sq_anp_create(M->mesh, M->n, mode), sq_malloc(sizeof(double) * 3 * (size_t)M->n)};
    sq_anp_set_moduli(c.A, mat->mu, mat->lambda);
    int rc = cg_solve(M, anp_op_matvec, &c, gravity, tol, max_iter, d, iterations, err);
    sq_anp_destroy(c.A);
    free(c.xm);
    return rc;
}
