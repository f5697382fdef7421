/* corot_impl.h - the corotational model's per-tet data and kernels, shared by level/corot.c
 * (the fixed step's passes) and level/corot_tets.c (per tet, for the adaptive frame). Private
 * to the level module. */
#ifndef SQ_COROT_IMPL_H
#define SQ_COROT_IMPL_H

#include <math.h>
#include <string.h>

#include "level/level.h"

struct sq_corot {
    int ntets, nblocks;    /* tets, blocks of CW tets (padded with V = 0 tets at node 0) */
    double *g;             /* per block: [10][CW] a_1, a_2, a_3 (rest gradients of the first three
                              basis functions, x y z each), V (tet_lane, tet_block) */
    double *q;             /* per block: [4][CW] rotation as a unit quaternion (w, x, y, z) */
    int *to;               /* per block: [4][CW] node offsets 4 i into u and acc (padding: node 0) */
    double *u;             /* the vector pass's gather source: d + b v per node, n x 4 (lane 3
                              unused), 64-byte aligned so a node's row never straddles a cache line */
    double *acc;           /* force accumulator of the vector pass, n x 4 (aligned as u), zero
                              between calls */
    double mu, lambda;
};

#define CW 4 /* tets per block */

/* lane and block of tet t: groups of CW * CK consecutive tets fill CK blocks, lane l taking
 * the l-th run of CK tets, so the lanes of a block are CK tets apart (a few cells in a
 * structured mesh: they rarely share a node) while a block's nodes stay close in memory */
#define CK 16
static inline int tet_lane(int t) { return (t % (CW * CK)) / CK; }
static inline int tet_block(int t) { return (t / (CW * CK)) * CK + t % CK; }

/* a tet's gradients and volume (G[10]) and rotation (q[4]) out of / into the block layout */
static inline void tet_load(const sq_corot *C, int t, double G[10], double q[4])
{
    const double *gb = C->g + 10 * CW * (size_t)tet_block(t);
    const double *qb = C->q + 4 * CW * (size_t)tet_block(t);
    int l = tet_lane(t);
    for (int k = 0; k < 10; k++)
        G[k] = gb[CW * k + l];
    if (q)
        for (int k = 0; k < 4; k++)
            q[k] = qb[CW * k + l];
}

static inline void tet_store_q(sq_corot *C, int t, const double q[4])
{
    double *qb = C->q + 4 * CW * (size_t)tet_block(t);
    for (int k = 0; k < 4; k++)
        qb[CW * k + tet_lane(t)] = q[k];
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

/* F = diag I + sum_{k<3} (u_k - u_3) a_k^T of a tet with u = d + b v (b = 0: u = d; d = NULL:
 * u = v, for the displacement-rate gradient) */
static inline void tet_grad(const double *G, const int *tv, const double *d, const double *v, double b,
                            double F[9], double diag)
{
    double u[4][3];
    for (int k = 0; k < 4; k++)
        for (int c = 0; c < 3; c++) {
            size_t i = 3 * (size_t)tv[k] + c;
            u[k][c] = d ? (b != 0 ? d[i] + b * v[i] : d[i]) : v[i];
        }
    for (int r = 0; r < 9; r++)
        F[r] = 0;
    for (int k = 0; k < 3; k++) {
        const double e0 = u[k][0] - u[3][0], e1 = u[k][1] - u[3][1], e2 = u[k][2] - u[3][2];
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

/* rotation of F from q: iters improvements (stopping when converged), R = R(q) on return */
static inline void tet_rotation(double q[4], const double F[9], int iters, double R[9])
{
    for (int it = 0; it < iters; it++) {
        quat_mat(q, R);
        if (rot_iterate(q, R, F) < 1e-15)
            break;
    }
    quat_mat(q, R);
}

/* sigma = 2 s sym(S - I) + l tr(S - I) I, added to sig (or set when add == 0) */
static inline void add_stress(const double S[9], double s, double l, double diag, double sig[9], int add)
{
    double e00 = S[0] - diag, e11 = S[4] - diag, e22 = S[8] - diag;
    double t = l * (e00 + e11 + e22), s2 = 2 * s;
    double x01 = s * (S[1] + S[3]), x02 = s * (S[2] + S[6]), x12 = s * (S[5] + S[7]);
    double o[9] = {s2 * e00 + t, x01, x02, x01, s2 * e11 + t, x12, x02, x12, s2 * e22 + t};
    for (int k = 0; k < 9; k++)
        sig[k] = add ? sig[k] + o[k] : o[k];
}

/* the element force of tet t, the scalar pass's arithmetic, with its corners tv[0..3] indexing
 * d and v (the level's nodes, or the corner values a caller gathered): f12[3 k + c] is the
 * force on corner k; P = V R sigma, corner k < 3 gets -P a_k, corner 3 the opposite of their
 * sum. Rayleigh damping: R and the stress from F = I + grad(d + b v); viscosities: R from
 * I + grad d, and R D_T R^T v added. store: the rotation kept as the next call's start. */
static inline void tet_force(sq_corot *C, const sq_material *mat, int t, const int *tv, const double *d,
                             const double *v, int iters, int store, double f12[12])
{
    const int visc = mat->use_viscosity;
    const double b = visc ? 0 : mat->rayleigh_stiffness;
    double G[10], q[4], F[9], R[9], S[9], sig[9];
    tet_load(C, t, G, q);
    tet_grad(G, tv, d, v, b, F, 1.0);
    tet_rotation(q, F, iters, R);
    if (store)
        tet_store_q(C, t, q);
    rt_mul(R, F, S);
    add_stress(S, C->mu, C->lambda, 1.0, sig, 0);
    if (visc) {
        double Lv[9];
        tet_grad(G, tv, NULL, v, 0, Lv, 0.0);
        rt_mul(R, Lv, S);
        add_stress(S, mat->phi, mat->psi, 0.0, sig, 1);
    }
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
        f12[3 * k] = -f0;
        f12[3 * k + 1] = -f1;
        f12[3 * k + 2] = -f2;
        s0 += f0;
        s1 += f1;
        s2 += f2;
    }
    f12[9] = s0;
    f12[10] = s1;
    f12[11] = s2;
}

/* the elastic energy of tet t at displacement d (corners tv[0..3] indexing d), its rotation
 * converged from the stored one (50 improvements at most) */
static inline double tet_energy(const sq_corot *C, int t, const int *tv, const double *d)
{
    double G[10], q[4], F[9], R[9], S[9];
    tet_load(C, t, G, q);
    tet_grad(G, tv, d, NULL, 0, F, 1.0);
    tet_rotation(q, F, 50, R);
    rt_mul(R, F, S);
    double e00 = S[0] - 1, e11 = S[4] - 1, e22 = S[8] - 1;
    double e01 = 0.5 * (S[1] + S[3]), e02 = 0.5 * (S[2] + S[6]), e12 = 0.5 * (S[5] + S[7]);
    double tr = e00 + e11 + e22;
    double ee = e00 * e00 + e11 * e11 + e22 * e22 + 2 * (e01 * e01 + e02 * e02 + e12 * e12);
    return G[9] * (C->mu * ee + 0.5 * C->lambda * tr * tr);
}

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#define COROT_SIMD 1
typedef __m256d vd;
#define VADD _mm256_add_pd
#define VSUB _mm256_sub_pd
#define VMUL _mm256_mul_pd
#define VFMA _mm256_fmadd_pd   /* a b + c */
#define VFNMA _mm256_fnmadd_pd /* c - a b */
#define VSET1 _mm256_set1_pd

/* 4 nodes' (x, y, z, .) rows -> x, y, z vectors (lane l = row l) */
static inline void transpose_in(vd r0, vd r1, vd r2, vd r3, vd *x, vd *y, vd *z)
{
    vd t0 = _mm256_unpacklo_pd(r0, r1), t1 = _mm256_unpackhi_pd(r0, r1);
    vd t2 = _mm256_unpacklo_pd(r2, r3), t3 = _mm256_unpackhi_pd(r2, r3);
    *x = _mm256_permute2f128_pd(t0, t2, 0x20);
    *y = _mm256_permute2f128_pd(t1, t3, 0x20);
    *z = _mm256_permute2f128_pd(t0, t2, 0x31);
}

/* x, y, z vectors -> 4 rows (x, y, z, 0) */
static inline void transpose_out(vd x, vd y, vd z, vd out[4])
{
    vd zero = _mm256_setzero_pd();
    vd t0 = _mm256_unpacklo_pd(x, y), t1 = _mm256_unpackhi_pd(x, y);
    vd t2 = _mm256_unpacklo_pd(z, zero), t3 = _mm256_unpackhi_pd(z, zero);
    out[0] = _mm256_permute2f128_pd(t0, t2, 0x20);
    out[1] = _mm256_permute2f128_pd(t1, t3, 0x20);
    out[2] = _mm256_permute2f128_pd(t0, t2, 0x31);
    out[3] = _mm256_permute2f128_pd(t1, t3, 0x31);
}

/* R (row-major) of unit quaternions (w, x, y, z), 4 lanes */
static inline void quat_mat_v(vd qw, vd qx, vd qy, vd qz, vd R[9])
{
    const vd one = VSET1(1.0), two = VSET1(2.0);
    vd xx = VMUL(qx, qx), yy = VMUL(qy, qy), zz = VMUL(qz, qz);
    vd xy = VMUL(qx, qy), xz = VMUL(qx, qz), yz = VMUL(qy, qz);
    vd wx = VMUL(qw, qx), wy = VMUL(qw, qy), wz = VMUL(qw, qz);
    R[0] = VFNMA(two, VADD(yy, zz), one);
    R[1] = VMUL(two, VSUB(xy, wz));
    R[2] = VMUL(two, VADD(xz, wy));
    R[3] = VMUL(two, VADD(xy, wz));
    R[4] = VFNMA(two, VADD(xx, zz), one);
    R[5] = VMUL(two, VSUB(yz, wx));
    R[6] = VMUL(two, VSUB(xz, wy));
    R[7] = VMUL(two, VADD(yz, wx));
    R[8] = VFNMA(two, VADD(xx, yy), one);
}

/* S = R^T F, 4 lanes */
static inline void rt_mul_v(const vd R[9], const vd F[9], vd S[9])
{
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            S[3 * r + c] = VFMA(R[r], F[c], VFMA(R[3 + r], F[3 + c], VMUL(R[6 + r], F[6 + c])));
}

/* the rotation update of 4 tets (lanes): with R = R(q) and S = R^T F, one Newton (or fallback)
 * step in the body frame, R <- R exp([w]) with (tr(S) I - sym(S)) w = axial(S - S^T); |w| capped
 * at 1 rad, then q <- normalise(q (1, w/2)). The fixed pass (corot.c) and the adaptive per-tet
 * kernel (corot_tets.c) share it, so their rotations are the same to the bit. */
static inline void rot_update_v(vd *pqw, vd *pqx, vd *pqy, vd *pqz, const vd F[9])
{
    const vd one = VSET1(1.0), half = VSET1(0.5);
    const vd tiny = VSET1(1e-12), thr = VSET1(1e-3 / 27);
    const vd absmask = _mm256_castsi256_pd(_mm256_set1_epi64x(0x7fffffffffffffffLL));
    vd qw = *pqw, qx = *pqx, qy = *pqy, qz = *pqz;
    vd R[9], S[9];
    quat_mat_v(qw, qx, qy, qz, R);
    rt_mul_v(R, F, S);
    vd g0 = VSUB(S[7], S[5]), g1 = VSUB(S[2], S[6]), g2 = VSUB(S[3], S[1]);
    vd tr = VADD(VADD(S[0], S[4]), S[8]);
    vd h00 = VSUB(tr, S[0]), h11 = VSUB(tr, S[4]), h22 = VSUB(tr, S[8]);
    vd h01 = VMUL(half, VADD(S[1], S[3])), h02 = VMUL(half, VADD(S[2], S[6])),
       h12 = VMUL(half, VADD(S[5], S[7])); /* the negated off-diagonals of H */
    /* cofactors of H = [[h00, -h01, -h02], [-h01, h11, -h12], [-h02, -h12, h22]] */
    vd c00 = VFNMA(h12, h12, VMUL(h11, h22));
    vd c01 = VFMA(h01, h22, VMUL(h02, h12));
    vd c02 = VFMA(h02, h11, VMUL(h01, h12));
    vd c11 = VFNMA(h02, h02, VMUL(h00, h22));
    vd c12 = VFMA(h00, h12, VMUL(h01, h02));
    vd c22 = VFNMA(h01, h01, VMUL(h00, h11));
    vd det = VFNMA(h02, c02, VFNMA(h01, c01, VMUL(h00, c00)));
    vd ht = VADD(VADD(h00, h11), h22);
    vd ok = _mm256_and_pd(_mm256_cmp_pd(h00, _mm256_setzero_pd(), _CMP_GT_OQ),
                          _mm256_cmp_pd(c22, _mm256_setzero_pd(), _CMP_GT_OQ));
    ok = _mm256_and_pd(ok, _mm256_cmp_pd(det, VMUL(thr, VMUL(ht, VMUL(ht, ht))), _CMP_GT_OQ));
    /* Newton: w = adj(H) g / det; fallback: g / (|tr| + tiny) */
    vd s = _mm256_div_pd(one, _mm256_blendv_pd(VADD(_mm256_and_pd(tr, absmask), tiny), det, ok));
    vd n0 = VFMA(c00, g0, VFMA(c01, g1, VMUL(c02, g2)));
    vd n1 = VFMA(c01, g0, VFMA(c11, g1, VMUL(c12, g2)));
    vd n2 = VFMA(c02, g0, VFMA(c12, g1, VMUL(c22, g2)));
    vd w0 = VMUL(_mm256_blendv_pd(g0, n0, ok), s), w1 = VMUL(_mm256_blendv_pd(g1, n1, ok), s),
       w2 = VMUL(_mm256_blendv_pd(g2, n2, ok), s);
    /* cap |w| at 1 rad, then q <- normalise(q (1, w/2)) */
    vd wn2 = VFMA(w0, w0, VFMA(w1, w1, VMUL(w2, w2)));
    vd cap = half;
    if (_mm256_movemask_pd(_mm256_cmp_pd(wn2, one, _CMP_GT_OQ)))
        cap = _mm256_div_pd(half, _mm256_max_pd(one, _mm256_sqrt_pd(wn2)));
    vd hw0 = VMUL(w0, cap), hw1 = VMUL(w1, cap), hw2 = VMUL(w2, cap);
    vd nw = VFNMA(qx, hw0, VFNMA(qy, hw1, VFNMA(qz, hw2, qw)));
    vd nx = VFMA(qw, hw0, VFMA(qy, hw2, VFNMA(qz, hw1, qx)));
    vd ny = VFMA(qw, hw1, VFMA(qz, hw0, VFNMA(qx, hw2, qy)));
    vd nz = VFMA(qw, hw2, VFMA(qx, hw1, VFNMA(qy, hw0, qz)));
    /* 1 / |n|: |n|^2 = (1 + |w/2|^2) |q|^2 is 1 + O(1e-8) in a normal step, where
     * (3 - x) / 2 is exact to ~1e-16; otherwise divide */
    vd nn = VFMA(nw, nw, VFMA(nx, nx, VFMA(ny, ny, VMUL(nz, nz))));
    vd in = VFNMA(half, nn, VSET1(1.5));
    if (_mm256_movemask_pd(_mm256_cmp_pd(_mm256_and_pd(VSUB(nn, one), absmask), VSET1(1e-8), _CMP_GT_OQ)))
        in = _mm256_div_pd(one, _mm256_sqrt_pd(nn));
    *pqw = VMUL(nw, in);
    *pqx = VMUL(nx, in);
    *pqy = VMUL(ny, in);
    *pqz = VMUL(nz, in);
}
#endif

#endif
