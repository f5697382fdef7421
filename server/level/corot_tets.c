/* corot_tets.c - corotational elasticity per tet, for the adaptive frame (lod/corotational.c):
 * one tet's element force from corner values the caller gathers (the scalar pass's
 * arithmetic), four at once (the vector pass's), and one tet's energy. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "level/corot_impl.h"

/* ---------------------------------------------------------------- per tet, for the adaptive frame
 *
 * lod/ couples levels tet by tet (docs/lod.md, "Corotational elasticity"): it gathers a tet's
 * corner values itself (active nodes, ghost values, values interpolated in time) and weights
 * the element force. These give it the element force of one tet from given corner values by
 * the scalar pass's own kernel (tet_force, corot_impl.h), four at once with the vector pass's. */

void sq_level_corot_tet_force(const sq_level_model *M, const sq_level_state *S, const sq_material *mat, int t,
                              const double *d4, const double *v4, int iters, int store, double *f4)
{
    (void)M; /* the tet's data are the corotational state's */
    static const int tv[4] = {0, 1, 2, 3};
    tet_force(S->corot, mat, t, tv, d4, v4, iters, store, f4);
}

double sq_level_corot_tet_energy(const sq_level_model *M, const sq_level_state *S, int t, const double *d4)
{
    (void)M;
    static const int tv[4] = {0, 1, 2, 3};
    return tet_energy(S->corot, t, tv, d4);
}

#ifdef COROT_SIMD
/* four tets at once (lanes; t[l] < 0: an empty lane), Rayleigh or no stiffness damping: the
 * vector pass's arithmetic (corot_tets_simd) on corner values gathered by the caller */
static void tet_force4_simd(sq_corot *C, const sq_material *mat, const int t[4], const double *d, const double *v,
                            int store, double *f)
{
    const double b = mat->rayleigh_stiffness;
    const vd one = VSET1(1.0), half = VSET1(0.5);
    const vd m2n = VSET1(-2 * C->mu), lamn = VSET1(-C->lambda);
    double gl[10][4] __attribute__((aligned(32))), ql[4][4] __attribute__((aligned(32)));
    double ul[4][3][4] __attribute__((aligned(32))); /* corner, component, lane */
    for (int l = 0; l < 4; l++) {
        double G[10], q[4];
        if (t[l] >= 0) {
            tet_load(C, t[l], G, q);
        } else {
            memset(G, 0, sizeof G);
            q[0] = 1;
            q[1] = q[2] = q[3] = 0;
        }
        for (int k = 0; k < 10; k++)
            gl[k][l] = G[k];
        for (int k = 0; k < 4; k++)
            ql[k][l] = q[k];
        for (int k = 0; k < 4; k++)
            for (int c = 0; c < 3; c++) {
                size_t i = 12 * (size_t)l + 3 * (size_t)k + (size_t)c;
                ul[k][c][l] = t[l] < 0 ? 0 : (b != 0 ? fma(b, v[i], d[i]) : d[i]); /* as corot_gather_source */
            }
    }
    vd F[9];
    for (int r = 0; r < 9; r++)
        F[r] = _mm256_setzero_pd();
    for (int k = 0; k < 3; k++) {
        vd e[3];
        for (int r = 0; r < 3; r++)
            e[r] = VSUB(_mm256_load_pd(ul[k][r]), _mm256_load_pd(ul[3][r]));
        for (int r = 0; r < 3; r++)
            for (int c = 0; c < 3; c++)
                F[3 * r + c] = VFMA(e[r], _mm256_load_pd(gl[3 * k + c]), F[3 * r + c]);
    }
    F[0] = VADD(F[0], one);
    F[4] = VADD(F[4], one);
    F[8] = VADD(F[8], one);
    /* the rotation update (rot_update_v, as corot_tets_simd 2a) */
    vd qw = _mm256_load_pd(ql[0]), qx = _mm256_load_pd(ql[1]), qy = _mm256_load_pd(ql[2]), qz = _mm256_load_pd(ql[3]);
    rot_update_v(&qw, &qx, &qy, &qz, F);
    vd R[9], S[9];
    if (store) {
        _mm256_store_pd(ql[0], qw);
        _mm256_store_pd(ql[1], qx);
        _mm256_store_pd(ql[2], qy);
        _mm256_store_pd(ql[3], qz);
        for (int l = 0; l < 4; l++)
            if (t[l] >= 0) {
                double q[4] = {ql[0][l], ql[1][l], ql[2][l], ql[3][l]};
                tet_store_q(C, t[l], q);
            }
    }
    /* R and S of the updated rotation, stress (negated), forces (as corot_tets_simd, 2b and 3) */
    quat_mat_v(qw, qx, qy, qz, R);
    rt_mul_v(R, F, S);
    vd V = _mm256_load_pd(gl[9]);
    vd e00 = VSUB(S[0], one), e11 = VSUB(S[4], one), e22 = VSUB(S[8], one);
    vd vm2 = VMUL(V, m2n), vhm = VMUL(half, vm2);
    vd tt = VMUL(VMUL(V, lamn), VADD(VADD(e00, e11), e22));
    vd sg[9];
    sg[0] = VFMA(vm2, e00, tt);
    sg[4] = VFMA(vm2, e11, tt);
    sg[8] = VFMA(vm2, e22, tt);
    sg[1] = sg[3] = VMUL(vhm, VADD(S[1], S[3]));
    sg[2] = sg[6] = VMUL(vhm, VADD(S[2], S[6]));
    sg[5] = sg[7] = VMUL(vhm, VADD(S[5], S[7]));
    vd P[9];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            P[3 * r + c] = VFMA(R[3 * r], sg[c], VFMA(R[3 * r + 1], sg[3 + c], VMUL(R[3 * r + 2], sg[6 + c])));
    double fo[4][3][4] __attribute__((aligned(32))); /* corner, component, lane */
    vd sx = _mm256_setzero_pd(), sy = sx, sz = sx;
    for (int k = 0; k < 3; k++) {
        const vd a0 = _mm256_load_pd(gl[3 * k]), a1 = _mm256_load_pd(gl[3 * k + 1]), a2 = _mm256_load_pd(gl[3 * k + 2]);
        vd fx = VFMA(P[0], a0, VFMA(P[1], a1, VMUL(P[2], a2)));
        vd fy = VFMA(P[3], a0, VFMA(P[4], a1, VMUL(P[5], a2)));
        vd fz = VFMA(P[6], a0, VFMA(P[7], a1, VMUL(P[8], a2)));
        _mm256_store_pd(fo[k][0], fx);
        _mm256_store_pd(fo[k][1], fy);
        _mm256_store_pd(fo[k][2], fz);
        sx = VADD(sx, fx);
        sy = VADD(sy, fy);
        sz = VADD(sz, fz);
    }
    const vd zero = _mm256_setzero_pd();
    _mm256_store_pd(fo[3][0], VSUB(zero, sx));
    _mm256_store_pd(fo[3][1], VSUB(zero, sy));
    _mm256_store_pd(fo[3][2], VSUB(zero, sz));
    for (int l = 0; l < 4; l++)
        for (int k = 0; k < 4; k++)
            for (int c = 0; c < 3; c++)
                f[12 * l + 3 * k + c] = fo[k][c][l];
}
#endif

void sq_level_corot_tet_force4(const sq_level_model *M, const sq_level_state *S, const sq_material *mat, const int t[4],
                               const double *d, const double *v, int store, double *f)
{
#ifdef COROT_SIMD
    if (!mat->use_viscosity) {
        tet_force4_simd(S->corot, mat, t, d, v, store, f);
        return;
    }
#endif
    for (int l = 0; l < 4; l++)
        if (t[l] >= 0)
            sq_level_corot_tet_force(M, S, mat, t[l], d + 12 * l, v + 12 * l, 1, store, f + 12 * l);
        else
            memset(f + 12 * l, 0, 12 * sizeof(double));
}
