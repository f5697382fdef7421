/* corot.c - corotational linear elasticity for the fem operator (fixed mode).
 *
 * Per tet T the force is f = R K_T (R^T x - X) (negated), K_T the rest element stiffness of the
 * fem operator and R the rotation of the tet's deformation gradient F = I + sum_j d_j a_j^T.
 * It is evaluated matrix-free: with G = R^T F - I (the gradient of the unrotated displacement
 * R^T x - X), eps = sym(G), sigma = 2 mu eps + lambda tr(eps) I, node j of T gets
 * -V R sigma a_j, which is exactly -[R K_T (R^T x - X)]_j (sum_j X_j a_j^T = I, sum_j a_j = 0).
 * Damping uses the rotated operators as well: Rayleigh b K becomes b R K_T R^T v, i.e. the
 * same stress formula applied to R^T grad(v) with (b mu, b lambda); the paper's viscosities
 * (phi, psi) the same way; the mass term a m v is per node as in the linear path.
 *
 * R maximises tr(R^T F) over proper rotations (the rotation of the polar decomposition when
 * det F > 0; a proper rotation, never a reflection, when the tet is inverted, so an inverted
 * tet is pushed back). It is kept per tet as a unit quaternion, warm-started from the last
 * step, and improved by one Newton step per substep on tr(R^T F) (R <- exp([w]) R with
 * (tr(B) I - sym(B)) w = axial(B - B^T), B = F R^T), which converges quadratically near the
 * solution; where that matrix is not safely positive definite (far from the solution, nearly
 * flat or inverted tets) the step falls back to w = axial(B - B^T) / |tr(B)| (always an
 * ascent direction, the scheme of Mueller et al. 2016), capped at 1 rad. Steps move a rotation
 * by at most a few 1e-3 rad, so one iteration per substep keeps R converged to ~1e-8.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sim/level.h"

struct sq_corot {
    int ntets;
    double *g;     /* per tet: a_1, a_2, a_3 (rest gradients of the first three basis functions), V */
    double *q;     /* per tet rotation as a unit quaternion (w, x, y, z) */
    double mu, lambda;
};

#define CG 10 /* doubles per tet in g */

int sq_level_corot_enable(sq_level *L, const sq_material *mat, sq_operator_kind op, sq_err *err)
{
    if (op != SQ_OPERATOR_FEM)
        return sq_err_set(err, "corotational elasticity needs the fem operator (the paper operator charges "
                               "rotation as strain, so it has no corotational form here): use \"operator\": "
                               "\"fem\" with \"elasticity\": \"corotational\", or \"elasticity\": \"linear\"");
    if (sq_material_check(mat, err) < 0)
        return -1;
    const sq_mesh *m = L->mesh;
    sq_corot *C = L->corot;
    if (!C) {
        C = sq_calloc(1, sizeof *C);
        C->ntets = m->ntets;
        C->g = sq_malloc(sizeof(double) * CG * (size_t)m->ntets);
        C->q = sq_malloc(sizeof(double) * 4 * (size_t)m->ntets);
        for (int t = 0; t < m->ntets; t++) {
            double a[4][3];
            double V = sq_tet_gradients(m, t, a);
            if (!(V > 0) || !isfinite(V)) {
                free(C->g);
                free(C->q);
                free(C);
                return sq_err_set(err, "%s: tetrahedron %d has volume %g: repair the mesh", m->source, t, V);
            }
            double *G = C->g + CG * (size_t)t;
            for (int k = 0; k < 3; k++)
                for (int c = 0; c < 3; c++)
                    G[3 * k + c] = a[k][c];
            G[9] = V;
        }
        L->corot = C;
        sq_level_corot_reset(L);
    }
    C->mu = mat->mu;
    C->lambda = mat->lambda;
    return 0;
}

void sq_level_corot_free(sq_level *L)
{
    if (!L->corot)
        return;
    free(L->corot->g);
    free(L->corot->q);
    free(L->corot);
    L->corot = NULL;
}

void sq_level_corot_reset(sq_level *L)
{
    sq_corot *C = L->corot;
    if (!C)
        return;
    for (int t = 0; t < C->ntets; t++) {
        C->q[4 * t] = 1;
        C->q[4 * t + 1] = C->q[4 * t + 2] = C->q[4 * t + 3] = 0;
    }
}

void sq_level_corot_copy(sq_level *dst, const sq_level *src)
{
    if (dst->corot && src->corot && dst->corot->ntets == src->corot->ntets)
        memcpy(dst->corot->q, src->corot->q, sizeof(double) * 4 * (size_t)src->corot->ntets);
}

/* R (row-major) of a unit quaternion */
static inline void quat_mat(const double *q, double R[9])
{
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    R[0] = 1 - 2 * (y * y + z * z);
    R[1] = 2 * (x * y - w * z);
    R[2] = 2 * (x * z + w * y);
    R[3] = 2 * (x * y + w * z);
    R[4] = 1 - 2 * (x * x + z * z);
    R[5] = 2 * (y * z - w * x);
    R[6] = 2 * (x * z - w * y);
    R[7] = 2 * (y * z + w * x);
    R[8] = 1 - 2 * (x * x + y * y);
}

/* one improvement of the rotation q towards argmax tr(R^T F); R = R(q) on entry; returns |w| */
static inline double rot_iterate(double *q, const double R[9], const double F[9])
{
    /* B = F R^T */
    double B[9];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            B[3 * r + c] = F[3 * r] * R[3 * c] + F[3 * r + 1] * R[3 * c + 1] + F[3 * r + 2] * R[3 * c + 2];
    const double g0 = B[7] - B[5], g1 = B[2] - B[6], g2 = B[3] - B[1];
    const double tr = B[0] + B[4] + B[8];
    /* H = tr(B) I - sym(B) */
    const double h00 = tr - B[0], h11 = tr - B[4], h22 = tr - B[8];
    const double h01 = -0.5 * (B[1] + B[3]), h02 = -0.5 * (B[2] + B[6]), h12 = -0.5 * (B[5] + B[7]);
    const double c00 = h11 * h22 - h12 * h12, c01 = h02 * h12 - h01 * h22, c02 = h01 * h12 - h02 * h11;
    const double det = h00 * c00 + h01 * c01 + h02 * c02;
    const double ht = h00 + h11 + h22;
    double w0, w1, w2;
    if (h00 > 0 && h00 * h11 - h01 * h01 > 0 && det > 1e-3 * ht * ht * ht / 27) {
        const double c11 = h00 * h22 - h02 * h02, c12 = h01 * h02 - h00 * h12, c22 = h00 * h11 - h01 * h01;
        const double id = 1.0 / det;
        w0 = id * (c00 * g0 + c01 * g1 + c02 * g2);
        w1 = id * (c01 * g0 + c11 * g1 + c12 * g2);
        w2 = id * (c02 * g0 + c12 * g1 + c22 * g2);
    } else {
        const double s = 1.0 / (fabs(tr) + 1e-12);
        w0 = s * g0;
        w1 = s * g1;
        w2 = s * g2;
    }
    double wn = sqrt(w0 * w0 + w1 * w1 + w2 * w2);
    if (wn > 1) {
        w0 /= wn;
        w1 /= wn;
        w2 /= wn;
    }
    /* q <- normalise((1, w/2) q): a rotation by 2 atan(|w|/2) about w, then q */
    const double hw0 = 0.5 * w0, hw1 = 0.5 * w1, hw2 = 0.5 * w2;
    const double qw = q[0], qx = q[1], qy = q[2], qz = q[3];
    double nw = qw - (hw0 * qx + hw1 * qy + hw2 * qz);
    double nx = qx + qw * hw0 + (hw1 * qz - hw2 * qy);
    double ny = qy + qw * hw1 + (hw2 * qx - hw0 * qz);
    double nz = qz + qw * hw2 + (hw0 * qy - hw1 * qx);
    const double in = 1.0 / sqrt(nw * nw + nx * nx + ny * ny + nz * nz);
    q[0] = nw * in;
    q[1] = nx * in;
    q[2] = ny * in;
    q[3] = nz * in;
    return wn;
}

/* deformation gradient F = I + sum_{k<3} (u_k - u_3) a_k^T of tet t (u = d), or the
 * displacement-rate gradient without the identity (u = v) */
static inline void tet_grad(const double *G, const int *tv, const double *u, double F[9], double diag)
{
    const double *u3 = u + 3 * (size_t)tv[3];
    for (int r = 0; r < 9; r++)
        F[r] = 0;
    for (int k = 0; k < 3; k++) {
        const double *uk = u + 3 * (size_t)tv[k];
        const double e0 = uk[0] - u3[0], e1 = uk[1] - u3[1], e2 = uk[2] - u3[2];
        const double *a = G + 3 * k;
        for (int c = 0; c < 3; c++) {
            F[c] += e0 * a[c];
            F[3 + c] += e1 * a[c];
            F[6 + c] += e2 * a[c];
        }
    }
    F[0] += diag;
    F[4] += diag;
    F[8] += diag;
}

/* S = R^T A */
static inline void rt_mul(const double R[9], const double A[9], double S[9])
{
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            S[3 * r + c] = R[r] * A[c] + R[3 + r] * A[3 + c] + R[6 + r] * A[6 + c];
}

/* elastic (+ damping) element forces of every tet added into f; iters rotation updates per tet;
 * store: write the updated rotations back (else they are only used) */
static void corot_tets(sq_level *L, const sq_material *mat, double *f, int iters, int store)
{
    sq_corot *C = L->corot;
    const sq_mesh *m = L->mesh;
    const double mu = C->mu, lam = C->lambda;
    double sv, lv;
    if (mat->use_viscosity) {
        sv = mat->phi;
        lv = mat->psi;
    } else {
        sv = mat->rayleigh_stiffness * mu;
        lv = mat->rayleigh_stiffness * lam;
    }
    const int damped = sv != 0 || lv != 0;
    const double *d = L->d, *v = L->v;
    for (int t = 0; t < C->ntets; t++) {
        const double *G = C->g + CG * (size_t)t;
        const int *tv = m->tets + 4 * (size_t)t;
        double F[9], R[9], q[4];
        tet_grad(G, tv, d, F, 1.0);
        memcpy(q, C->q + 4 * (size_t)t, sizeof q);
        for (int it = 0; it < iters; it++) {
            quat_mat(q, R);
            if (rot_iterate(q, R, F) < 1e-15)
                break;
        }
        quat_mat(q, R);
        if (store)
            memcpy(C->q + 4 * (size_t)t, q, sizeof q);
        double S[9], sig[9];
        rt_mul(R, F, S);
        /* eps = sym(S) - I */
        double e00 = S[0] - 1, e11 = S[4] - 1, e22 = S[8] - 1;
        double e01 = 0.5 * (S[1] + S[3]), e02 = 0.5 * (S[2] + S[6]), e12 = 0.5 * (S[5] + S[7]);
        double tr = lam * (e00 + e11 + e22);
        double m2 = 2 * mu;
        sig[0] = m2 * e00 + tr;
        sig[4] = m2 * e11 + tr;
        sig[8] = m2 * e22 + tr;
        sig[1] = sig[3] = m2 * e01;
        sig[2] = sig[6] = m2 * e02;
        sig[5] = sig[7] = m2 * e12;
        if (damped) {
            double Lv[9], Sv[9];
            tet_grad(G, tv, v, Lv, 0.0);
            rt_mul(R, Lv, Sv);
            double tv2 = lv * (Sv[0] + Sv[4] + Sv[8]), s2 = 2 * sv;
            sig[0] += s2 * Sv[0] + tv2;
            sig[4] += s2 * Sv[4] + tv2;
            sig[8] += s2 * Sv[8] + tv2;
            double x01 = sv * (Sv[1] + Sv[3]), x02 = sv * (Sv[2] + Sv[6]), x12 = sv * (Sv[5] + Sv[7]);
            sig[1] += x01;
            sig[3] += x01;
            sig[2] += x02;
            sig[6] += x02;
            sig[5] += x12;
            sig[7] += x12;
        }
        /* P = V R sigma */
        const double V = G[9];
        double P[9];
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++)
                P[3 * r + c] = V * (R[3 * r] * sig[c] + R[3 * r + 1] * sig[3 + c] + R[3 * r + 2] * sig[6 + c]);
        double s0 = 0, s1 = 0, s2 = 0;
        for (int k = 0; k < 3; k++) {
            const double *a = G + 3 * k;
            const double f0 = P[0] * a[0] + P[1] * a[1] + P[2] * a[2];
            const double f1 = P[3] * a[0] + P[4] * a[1] + P[5] * a[2];
            const double f2 = P[6] * a[0] + P[7] * a[1] + P[8] * a[2];
            double *fk = f + 3 * (size_t)tv[k];
            fk[0] -= f0;
            fk[1] -= f1;
            fk[2] -= f2;
            s0 += f0;
            s1 += f1;
            s2 += f2;
        }
        double *f3 = f + 3 * (size_t)tv[3];
        f3[0] += s0;
        f3[1] += s1;
        f3[2] += s2;
    }
}

/* f = m (g - a v) + element forces */
static void corot_forces(sq_level *L, const sq_material *mat, const double g[3], int iters, int store)
{
    const double a = mat->rayleigh_mass;
    for (int i = 0; i < L->n; i++) {
        const double mi = L->mass[i];
        for (int c = 0; c < 3; c++)
            L->f[3 * i + c] = mi * (g[c] - a * L->v[3 * i + c]);
    }
    corot_tets(L, mat, L->f, iters, store);
}

void sq_level_corot_step(sq_level *L, const sq_material *mat, const double g[3], double dt,
                         const unsigned char *mask)
{
    corot_forces(L, mat, g, 1, 1);
    sq_level_integrate(L, dt, mask);
}

void sq_level_corot_forces(sq_level *L, const sq_material *mat, const double g[3])
{
    /* rotations iterated to convergence from the stored ones, not stored: the state is unchanged */
    corot_forces(L, mat, g, 50, 0);
}

void sq_level_corot_converge(sq_level *L)
{
    sq_corot *C = L->corot;
    if (!C)
        return;
    const sq_mesh *m = L->mesh;
    for (int t = 0; t < C->ntets; t++) {
        double F[9], R[9];
        tet_grad(C->g + CG * (size_t)t, m->tets + 4 * (size_t)t, L->d, F, 1.0);
        double *q = C->q + 4 * (size_t)t;
        for (int it = 0; it < 50; it++) {
            quat_mat(q, R);
            if (rot_iterate(q, R, F) < 1e-15)
                break;
        }
    }
}

double sq_level_corot_energy(const sq_level *L)
{
    const sq_corot *C = L->corot;
    const sq_mesh *m = L->mesh;
    double e = 0;
    for (int t = 0; t < C->ntets; t++) {
        const double *G = C->g + CG * (size_t)t;
        double F[9], R[9], S[9], q[4];
        tet_grad(G, m->tets + 4 * (size_t)t, L->d, F, 1.0);
        memcpy(q, C->q + 4 * (size_t)t, sizeof q);
        for (int it = 0; it < 50; it++) {
            quat_mat(q, R);
            if (rot_iterate(q, R, F) < 1e-15)
                break;
        }
        quat_mat(q, R);
        rt_mul(R, F, S);
        double e00 = S[0] - 1, e11 = S[4] - 1, e22 = S[8] - 1;
        double e01 = 0.5 * (S[1] + S[3]), e02 = 0.5 * (S[2] + S[6]), e12 = 0.5 * (S[5] + S[7]);
        double tr = e00 + e11 + e22;
        double ee = e00 * e00 + e11 * e11 + e22 * e22 + 2 * (e01 * e01 + e02 * e02 + e12 * e12);
        e += G[9] * (C->mu * ee + 0.5 * C->lambda * tr * tr);
    }
    return e;
}

int sq_level_corot_inverted(const sq_level *L)
{
    const sq_corot *C = L->corot;
    const sq_mesh *m = L->mesh;
    int n = 0;
    for (int t = 0; t < m->ntets; t++) {
        double F[9];
        double a[4][3];
        const double *G = C ? C->g + CG * (size_t)t : NULL;
        if (!G) {
            sq_tet_gradients(m, t, a);
            double tmp[CG];
            for (int k = 0; k < 3; k++)
                for (int c = 0; c < 3; c++)
                    tmp[3 * k + c] = a[k][c];
            tet_grad(tmp, m->tets + 4 * (size_t)t, L->d, F, 1.0);
        } else {
            tet_grad(G, m->tets + 4 * (size_t)t, L->d, F, 1.0);
        }
        double det = F[0] * (F[4] * F[8] - F[5] * F[7]) - F[1] * (F[3] * F[8] - F[5] * F[6]) +
                     F[2] * (F[3] * F[7] - F[4] * F[6]);
        n += det <= 0;
    }
    return n;
}
