/* static.c - static equilibrium K d = M g on a level, by preconditioned conjugate gradients.
 *
 * The reference the dynamic runs are checked against (PHYSICS.md section 6): same blocks,
 * same constraints (constrained axes held at zero displacement), Jacobi preconditioner.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sim/level.h"

/* y = K x on unconstrained axes (constrained components of x are taken as zero) */
static void matvec(const sq_level *L, const double *x, double *y)
{
    for (int i = 0; i < L->n; i++) {
        double s[3] = {0, 0, 0};
        for (int e = L->row_start[i]; e < L->row_start[i + 1]; e++) {
            const double *B = L->K + 9 * (size_t)e, *xj = x + 3 * (size_t)L->col[e];
            for (int r = 0; r < 3; r++)
                s[r] += B[3 * r] * xj[0] + B[3 * r + 1] * xj[1] + B[3 * r + 2] * xj[2];
        }
        for (int r = 0; r < 3; r++)
            y[3 * i + r] = (L->fixed[i] & (1u << r)) ? 0 : s[r];
    }
}

static double dot(const double *a, const double *b, size_t n)
{
    double s = 0;
    for (size_t k = 0; k < n; k++)
        s += a[k] * b[k];
    return s;
}

int sq_level_static_solve(const sq_level *L, const double gravity[3], double tol, int max_iter,
                          double *d, int *iterations, sq_err *err)
{
    size_t n3 = 3 * (size_t)L->n;
    double *r = sq_malloc(sizeof(double) * n3), *z = sq_malloc(sizeof(double) * n3);
    double *p = sq_malloc(sizeof(double) * n3), *q = sq_malloc(sizeof(double) * n3);
    double *pre = sq_malloc(sizeof(double) * n3);
    /* right-hand side M g on free axes; Jacobi preconditioner from the diagonal blocks */
    for (int i = 0; i < L->n; i++) {
        int e = L->row_start[i];
        while (L->col[e] != i)
            e++;
        for (int c = 0; c < 3; c++) {
            int fx = (L->fixed[i] >> c) & 1;
            r[3 * i + c] = fx ? 0 : L->mass[i] * gravity[c];
            double kd = L->K[9 * (size_t)e + 4 * c];
            pre[3 * i + c] = fx || !(kd > 0) ? 0 : 1.0 / kd;
        }
    }
    memset(d, 0, sizeof(double) * n3);
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
            matvec(L, p, q);
            double pq = dot(p, q, n3);
            if (!(pq > 0)) {
                rc = sq_err_set(err, "%s: conjugate gradients broke down (p.Kp = %g at iteration %d): "
                                     "the operator is not positive definite on the free axes; add constraints",
                                L->mesh->source, pq, it);
                break;
            }
            double alpha = rz / pq;
            for (size_t k = 0; k < n3; k++) {
                d[k] += alpha * p[k];
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
                                 "(now %g)", L->mesh->source, tol, max_iter, sqrt(dot(r, r, n3)) / bnorm);
    }
    if (iterations)
        *iterations = it;
    free(r);
    free(z);
    free(p);
    free(q);
    free(pre);
    return rc;
}
