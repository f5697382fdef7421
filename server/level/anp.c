/* anp.c - average nodal pressure tets (docs/physics.md section 10): the fem operator with the
 * volumetric strain averaged at the nodes, on the same nodes and tets (fixed mode, linear).
 *
 * Energy sum_T V_T mu |dev eps_T|^2 + sum_i (kappa/2) W_i theta_i^2, kappa = lambda + 2 mu / 3,
 * W_i the nodal volume, theta_i = sum_{T ni i} (V_T / 4) tr(eps_T) / W_i; a tet's pressure is
 * kappa times the mean theta of its nodes. Symmetric and never stiffer than the element-wise
 * operator (Jensen), so that operator's step bound is safe for it. Forces are evaluated
 * matrix-free in two passes over the tets (nodal theta, then the stresses).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "level/level.h"

struct sq_anp {
    double *grad;   /* per tet: a_0..a_3 (12) and V */
    double *theta;  /* nodal volumetric strain scratch (n) */
    double *w;      /* scratch u = d + b v (3n) */
    double mu, kappa;
};

int sq_level_anp_enable(sq_level *L, const sq_material *mat, sq_operator_kind op, sq_err *err)
{
    if (op != SQ_OPERATOR_FEM)
        return sq_err_set(err, "nodal pressure tets need the fem operator: use \"operator\": \"fem\" with "
                               "\"pressure\": \"nodal\", or \"pressure\": \"element\" with the paper operator");
    const sq_mesh *m = L->model.mesh;
    sq_anp *A = L->anp;
    if (!A) {
        A = sq_calloc(1, sizeof *A);
        A->grad = sq_malloc(sizeof(double) * 13 * (size_t)m->ntets);
        A->theta = sq_malloc(sizeof(double) * (size_t)L->model.n);
        A->w = sq_malloc(sizeof(double) * 3 * (size_t)L->model.n);
        for (int t = 0; t < m->ntets; t++) {
            double a[4][3];
            double V = sq_tet_gradients(m, t, a);
            for (int k = 0; k < 4; k++)
                for (int r = 0; r < 3; r++)
                    A->grad[13 * (size_t)t + 3 * k + r] = a[k][r];
            A->grad[13 * (size_t)t + 12] = V;
        }
        L->anp = A;
    }
    A->mu = mat->mu;
    A->kappa = mat->lambda + 2.0 * mat->mu / 3.0;
    return 0;
}

void sq_level_anp_free(sq_level *L)
{
    if (!L->anp)
        return;
    free(L->anp->grad);
    free(L->anp->theta);
    free(L->anp->w);
    free(L->anp);
    L->anp = NULL;
}

void sq_level_anp_apply(const sq_level *L, const double *x, double *y)
{
    const sq_anp *A = L->anp;
    const sq_mesh *m = L->model.mesh;
    const double mu = A->mu, kappa = A->kappa;
    memset(A->theta, 0, sizeof(double) * (size_t)L->model.n);
    memset(y, 0, sizeof(double) * 3 * (size_t)L->model.n);
    for (int t = 0; t < m->ntets; t++) {
        const double *a = A->grad + 13 * (size_t)t;
        const int *tv = m->tets + 4 * (size_t)t;
        double th = 0;
        for (int k = 0; k < 4; k++)
            th += a[3 * k] * x[3 * tv[k]] + a[3 * k + 1] * x[3 * tv[k] + 1] + a[3 * k + 2] * x[3 * tv[k] + 2];
        for (int k = 0; k < 4; k++)
            A->theta[tv[k]] += a[12] / 4 * th;
    }
    for (int i = 0; i < L->model.n; i++)
        A->theta[i] /= L->model.vol[i];
    for (int t = 0; t < m->ntets; t++) {
        const double *a = A->grad + 13 * (size_t)t;
        const int *tv = m->tets + 4 * (size_t)t;
        double G[9] = {0};
        for (int k = 0; k < 4; k++)
            for (int r = 0; r < 3; r++)
                for (int c = 0; c < 3; c++)
                    G[3 * r + c] += x[3 * tv[k] + r] * a[3 * k + c];
        double tr = G[0] + G[4] + G[8], tbar = 0.25 * (A->theta[tv[0]] + A->theta[tv[1]] + A->theta[tv[2]] +
                                                     A->theta[tv[3]]);
        double sig[9];
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++)
                sig[3 * r + c] = a[12] * (mu * (G[3 * r + c] + G[3 * c + r]) +
                                          (r == c ? kappa * tbar - 2.0 * mu * tr / 3.0 : 0));
        for (int k = 0; k < 4; k++)
            for (int r = 0; r < 3; r++)
                y[3 * tv[k] + r] += sig[3 * r] * a[3 * k] + sig[3 * r + 1] * a[3 * k + 1] + sig[3 * r + 2] * a[3 * k + 2];
    }
}

void sq_level_anp_forces(const sq_level *L, const sq_material *mat, const double g[3], double *f)
{
    sq_anp *A = L->anp;
    const double b = mat->use_viscosity ? 0 : mat->rayleigh_stiffness, a = mat->rayleigh_mass;
    size_t n3 = 3 * (size_t)L->model.n;
    for (size_t k = 0; k < n3; k++)
        A->w[k] = L->d[k] + b * L->v[k];
    sq_level_anp_apply(L, A->w, f); /* f = K_np (d + b v) */
    for (int i = 0; i < L->model.n; i++) {
        double *fi = f + 3 * (size_t)i;
        for (int c = 0; c < 3; c++)
            fi[c] = L->model.mass[i] * (g[c] - a * L->v[3 * i + c]) - fi[c];
        if (mat->use_viscosity && L->model.D) /* the paper's viscosities: the element-wise D blocks */
            for (int e = L->model.row_start[i]; e < L->model.row_start[i + 1]; e++) {
                const double *B = L->model.D + 9 * (size_t)e, *vj = L->v + 3 * (size_t)L->model.col[e];
                for (int r = 0; r < 3; r++)
                    fi[r] -= B[3 * r] * vj[0] + B[3 * r + 1] * vj[1] + B[3 * r + 2] * vj[2];
            }
    }
}

double sq_level_anp_energy(const sq_level *L)
{
    size_t n3 = 3 * (size_t)L->model.n;
    double *y = sq_malloc(sizeof(double) * n3), e = 0;
    sq_level_anp_apply(L, L->d, y);
    for (size_t k = 0; k < n3; k++)
        e += L->d[k] * y[k];
    free(y);
    return 0.5 * e;
}
