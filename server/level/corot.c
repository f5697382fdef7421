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

#include "level/corot_impl.h"

/* zeroed, 64-byte aligned; released with free() */
static double *calloc_aligned(size_t count)
{
    size_t bytes = (count * sizeof(double) + 63) / 64 * 64;
    double *p = aligned_alloc(64, bytes);
    if (!p)
        return sq_calloc(count, sizeof(double));
    memset(p, 0, bytes);
    return p;
}

int sq_level_corot_enable(sq_level *L, const sq_material *mat, sq_operator_kind op, sq_err *err)
{
    if (op != SQ_OPERATOR_FEM)
        return sq_err_set(err, "corotational elasticity needs the fem operator (the paper operator charges "
                               "rotation as strain, so it has no corotational form here): use \"operator\": "
                               "\"fem\" with \"elasticity\": \"corotational\", or \"elasticity\": \"linear\"");
    if (sq_material_check(mat, err) < 0)
        return -1;
    const sq_mesh *m = L->model.mesh;
    sq_corot *C = L->state.corot;
    if (!C) {
        C = sq_calloc(1, sizeof *C);
        C->ntets = m->ntets;
        C->nblocks = (m->ntets + CW * CK - 1) / (CW * CK) * CK;
        C->g = calloc_aligned(10 * CW * (size_t)C->nblocks);
        C->q = calloc_aligned(4 * CW * (size_t)C->nblocks);
        C->to = sq_calloc(4 * CW * (size_t)C->nblocks, sizeof(int));
        C->u = calloc_aligned(4 * (size_t)L->model.n + 4);
        C->acc = calloc_aligned(4 * (size_t)L->model.n + 4);
        L->state.corot = C;
        sq_level_op_update(L);
        for (int t = 0; t < m->ntets; t++) {
            double a[4][3];
            double V = sq_tet_gradients(m, t, a);
            if (!(V > 0) || !isfinite(V)) {
                sq_level_corot_free(L);
                return sq_err_set(err, "%s: tetrahedron %d has volume %g: repair the mesh", m->source, t, V);
            }
            double *gb = C->g + 10 * CW * (size_t)tet_block(t);
            int *tb = C->to + 4 * CW * (size_t)tet_block(t);
            for (int k = 0; k < 3; k++)
                for (int c = 0; c < 3; c++)
                    gb[CW * (3 * k + c) + tet_lane(t)] = a[k][c];
            gb[CW * 9 + tet_lane(t)] = V;
            for (int k = 0; k < 4; k++)
                tb[CW * k + tet_lane(t)] = 4 * m->tets[4 * t + k];
        }
        sq_level_corot_reset(&L->state);
    }
    C->mu = mat->mu;
    C->lambda = mat->lambda;
    return 0;
}

void sq_level_corot_free(sq_level *L)
{
    if (!L->state.corot)
        return;
    free(L->state.corot->g);
    free(L->state.corot->q);
    free(L->state.corot->to);
    free(L->state.corot->u);
    free(L->state.corot->acc);
    free(L->state.corot);
    L->state.corot = NULL;
    sq_level_op_update(L);
}

void sq_level_corot_reset(sq_level_state *S)
{
    sq_corot *C = S->corot;
    if (!C)
        return;
    size_t nq = 4 * CW * (size_t)C->nblocks;
    memset(C->q, 0, sizeof(double) * nq);
    for (int b = 0; b < C->nblocks; b++)
        for (int l = 0; l < CW; l++)
            C->q[4 * CW * (size_t)b + l] = 1;
}

size_t sq_level_corot_state_len(const sq_level_state *S)
{
    return S->corot ? 4 * CW * (size_t)S->corot->nblocks : 0;
}

void sq_level_corot_save(const sq_level_state *S, double *q)
{
    if (S->corot)
        memcpy(q, S->corot->q, sizeof(double) * sq_level_corot_state_len(S));
}

void sq_level_corot_load(sq_level_state *S, const double *q)
{
    if (S->corot)
        memcpy(S->corot->q, q, sizeof(double) * sq_level_corot_state_len(S));
}

void sq_level_corot_copy(sq_level_state *dst, const sq_level_state *src)
{
    if (dst->corot && src->corot && dst->corot->ntets == src->corot->ntets)
        memcpy(dst->corot->q, src->corot->q, sizeof(double) * 4 * CW * (size_t)src->corot->nblocks);
}

/* elastic (+ damping) element forces of every tet added into f (n x 3), one tet at a time;
 * iters rotation updates per tet; store: write the updated rotations back (else they are only
 * used). Rayleigh damping: the rotation and the stress come from F = I + grad(d + b v), i.e.
 * f = -R K_T (R^T (x + b v) - X): the elastic force plus b R K_T R^T v, with R the rotation of
 * I + grad(d + b v) (it differs from that of I + grad d by O(b |grad v|)). Viscosities (not
 * proportional to K): R from I + grad d, and R D_T R^T v added. */
static void corot_tets(const sq_level_model *M, const sq_level_state *S, const sq_material *mat, double *f, int iters,
                       int store)
{
    for (int t = 0; t < S->corot->ntets; t++) {
        const int *tv = M->mesh->tets + 4 * (size_t)t;
        double f12[12];
        tet_force(S->corot, mat, t, tv, S->d, S->v, iters, store, f12);
        for (int k = 0; k < 4; k++) {
            double *fk = f + 3 * (size_t)tv[k];
            fk[0] += f12[3 * k];
            fk[1] += f12[3 * k + 1];
            fk[2] += f12[3 * k + 2];
        }
    }
}

#ifdef COROT_SIMD

/* u = d + b v per node into C->u (n x 4; lane 3 is whatever follows, never used): the tet
 * pass then gathers one aligned row per node instead of two unaligned ones and a multiply-add
 * (the same fma, so the same values) */
static void corot_gather_source(const sq_level_model *M, sq_level_state *S, double b)
{
    sq_corot *C = S->corot;
    const double *restrict d = S->d, *restrict v = S->v;
    double *restrict u = C->u;
    const vd vb = VSET1(b);
    if (b != 0)
        for (int i = 0; i < M->n; i++)
            _mm256_store_pd(u + 4 * (size_t)i, VFMA(vb, _mm256_loadu_pd(v + 3 * (size_t)i), _mm256_loadu_pd(d + 3 * (size_t)i)));
    else
        for (int i = 0; i < M->n; i++)
            _mm256_store_pd(u + 4 * (size_t)i, _mm256_loadu_pd(d + 3 * (size_t)i));
}

/* the same element forces as corot_tets (Rayleigh or no stiffness damping, one rotation
 * update), CW tets per vector lane group, into C->acc (n x 4); C->u holds d + b v.
 * The work of CK blocks at a time is split into four loops (gather and F; the rotation
 * update; R and S of the updated rotation; stress, forces and scatter) that hand over through
 * small L1-resident buffers: one loop body holding all of it needs more than the 16 vector
 * registers (~90 stack loads and stores in its compiled body, ~20 when split) and its
 * dependency chain (F, R, S, a Newton solve with a division, the quaternion update, R and S
 * again, stress, forces) is longer than the out-of-order window. Each expression is the one of
 * the single-loop form: the values are the same. */
static void corot_tets_simd(sq_corot *C)
{
    const double *u = C->u;
    double *acc = C->acc;
    const vd one = VSET1(1.0), half = VSET1(0.5);
    const vd m2n = VSET1(-2 * C->mu), lamn = VSET1(-C->lambda);
    /* per block of the chunk: F (9); then R (9) and S's diagonal and symmetric sums (6) */
    vd Fb[CK][9], Rb[CK][9], Sb[CK][6];
    for (int b0 = 0; b0 < C->nblocks; b0 += CK) {
        /* 1. gather u of the 4 nodes of the 4 tets (x/y/z lane vectors per node slot) and
         * F = I + sum_k (u_k - u_3) a_k^T */
        for (int j = 0; j < CK; j++) {
            const double *gb = C->g + 10 * CW * (size_t)(b0 + j);
            const int *tb = C->to + 4 * CW * (size_t)(b0 + j);
            /* node slot 3 first, then slots 0-2 one at a time into F: 15 live vectors */
            vd ux3, uy3, uz3;
            transpose_in(_mm256_load_pd(u + tb[CW * 3]), _mm256_load_pd(u + tb[CW * 3 + 1]),
                         _mm256_load_pd(u + tb[CW * 3 + 2]), _mm256_load_pd(u + tb[CW * 3 + 3]), &ux3, &uy3, &uz3);
            vd F[9];
            for (int r = 0; r < 9; r++)
                F[r] = _mm256_setzero_pd();
            for (int k = 0; k < 3; k++) {
                vd ux, uy, uz;
                transpose_in(_mm256_load_pd(u + tb[CW * k]), _mm256_load_pd(u + tb[CW * k + 1]),
                             _mm256_load_pd(u + tb[CW * k + 2]), _mm256_load_pd(u + tb[CW * k + 3]), &ux, &uy, &uz);
                vd e[3] = {VSUB(ux, ux3), VSUB(uy, uy3), VSUB(uz, uz3)};
                for (int r = 0; r < 3; r++)
                    for (int c = 0; c < 3; c++)
                        F[3 * r + c] = VFMA(e[r], _mm256_load_pd(gb + CW * (3 * k + c)), F[3 * r + c]);
            }
            F[0] = VADD(F[0], one);
            F[4] = VADD(F[4], one);
            F[8] = VADD(F[8], one);
            for (int r = 0; r < 9; r++)
                Fb[j][r] = F[r];
        }
        /* 2. R = R(q) from the last substep, S = R^T F; one Newton (or fallback) step in the
         * body frame, R <- R exp([w]) with (tr(S) I - sym(S)) w = axial(S - S^T); then R and S
         * again for this substep's stress. (Using the old rotation for the stress instead saves
         * a quarter of the work but is unstable: the lag acts as a negative damping of order
         * dt |stress| on the fastest modes; the arc-drag beam blew up at 15 degrees.) */
        for (int j = 0; j < CK; j++) { /* 2a: the rotation update */
            double *qb = C->q + 4 * CW * (size_t)(b0 + j);
            vd qw = _mm256_load_pd(qb), qx = _mm256_load_pd(qb + CW), qy = _mm256_load_pd(qb + 2 * CW),
               qz = _mm256_load_pd(qb + 3 * CW);
            rot_update_v(&qw, &qx, &qy, &qz, Fb[j]);
            _mm256_store_pd(qb, qw);
            _mm256_store_pd(qb + CW, qx);
            _mm256_store_pd(qb + 2 * CW, qy);
            _mm256_store_pd(qb + 3 * CW, qz);
        }
        for (int j = 0; j < CK; j++) { /* 2b: R and S of the updated rotation */
            const double *qb = C->q + 4 * CW * (size_t)(b0 + j);
            vd *R = Rb[j], S[9];
            quat_mat_v(_mm256_load_pd(qb), _mm256_load_pd(qb + CW), _mm256_load_pd(qb + 2 * CW),
                       _mm256_load_pd(qb + 3 * CW), R);
            rt_mul_v(R, Fb[j], S);
            vd *Sj = Sb[j];
            Sj[0] = S[0];
            Sj[1] = S[4];
            Sj[2] = S[8];
            Sj[3] = VADD(S[1], S[3]);
            Sj[4] = VADD(S[2], S[6]);
            Sj[5] = VADD(S[5], S[7]);
        }
        /* 3. sigma = 2 mu sym(S - I) + lambda tr(S - I) I, P = R (V sigma); node k < 3 gets
         * -P a_k, node 3 the sum, scattered lane by lane. Computed negated (-2 mu, -lambda:
         * exact), so the three nodes k < 3 add with the accumulator as a memory operand */
        for (int j = 0; j < CK; j++) {
            const double *gb = C->g + 10 * CW * (size_t)(b0 + j);
            const int *tb = C->to + 4 * CW * (size_t)(b0 + j);
            const vd *R = Rb[j], *Sj = Sb[j];
            vd V = _mm256_load_pd(gb + 9 * CW);
            vd e00 = VSUB(Sj[0], one), e11 = VSUB(Sj[1], one), e22 = VSUB(Sj[2], one);
            vd vm2 = VMUL(V, m2n), vhm = VMUL(half, vm2);
            vd t = VMUL(VMUL(V, lamn), VADD(VADD(e00, e11), e22));
            vd sg[9];
            sg[0] = VFMA(vm2, e00, t);
            sg[4] = VFMA(vm2, e11, t);
            sg[8] = VFMA(vm2, e22, t);
            sg[1] = sg[3] = VMUL(vhm, Sj[3]);
            sg[2] = sg[6] = VMUL(vhm, Sj[4]);
            sg[5] = sg[7] = VMUL(vhm, Sj[5]);
            vd P[9];
            for (int r = 0; r < 3; r++)
                for (int c = 0; c < 3; c++)
                    P[3 * r + c] = VFMA(R[3 * r], sg[c], VFMA(R[3 * r + 1], sg[3 + c], VMUL(R[3 * r + 2], sg[6 + c])));
            vd fx[4], fy[4], fz[4];
            fx[3] = fy[3] = fz[3] = _mm256_setzero_pd();
            for (int k = 0; k < 3; k++) {
                const double *ak = gb + CW * 3 * k;
                const vd a0 = _mm256_load_pd(ak), a1 = _mm256_load_pd(ak + CW), a2 = _mm256_load_pd(ak + 2 * CW);
                fx[k] = VFMA(P[0], a0, VFMA(P[1], a1, VMUL(P[2], a2)));
                fy[k] = VFMA(P[3], a0, VFMA(P[4], a1, VMUL(P[5], a2)));
                fz[k] = VFMA(P[6], a0, VFMA(P[7], a1, VMUL(P[8], a2)));
                fx[3] = VADD(fx[3], fx[k]);
                fy[3] = VADD(fy[3], fy[k]);
                fz[3] = VADD(fz[3], fz[k]);
            }
            for (int k = 0; k < 4; k++) {
                vd rows[4];
                transpose_out(fx[k], fy[k], fz[k], rows);
                for (int l = 0; l < 4; l++) {
                    double *ai = acc + tb[CW * k + l];
                    vd cur = _mm256_load_pd(ai);
                    _mm256_store_pd(ai, k < 3 ? VADD(rows[l], cur) : VSUB(cur, rows[l]));
                }
            }
        }
    }
}
#endif

/* f = m (g - a v) + element forces */
static void corot_forces(const sq_level_model *M, const sq_level_state *S, const sq_material *mat, const double g[3],
                         double *f, int iters,
                         int store)
{
    const double a = mat->rayleigh_mass;
    for (int i = 0; i < M->n; i++) {
        const double mi = M->mass[i];
        for (int c = 0; c < 3; c++)
            f[3 * i + c] = mi * (g[c] - a * S->v[3 * i + c]);
    }
    corot_tets(M, S, mat, f, iters, store);
}

void sq_level_corot_step(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double g[3],
                         double dt,
                         const unsigned char *mask)
{
#ifdef COROT_SIMD
    if (!mat->use_viscosity) {
        sq_corot *C = S->corot;
        corot_gather_source(M, S, mat->rayleigh_stiffness);
        corot_tets_simd(S->corot);
        /* forces, then symplectic Euler as in sq_level_integrate (the same operations per
         * component, so the same values; lane 3 is never stored) */
        double *restrict acc = C->acc, *restrict f = S->f, *restrict vv = S->v, *restrict dd = S->d;
        const unsigned char *restrict fixed = M->fixed;
        const vd va = VSET1(mat->rayleigh_mass), vg = _mm256_setr_pd(g[0], g[1], g[2], 0), vdt = VSET1(dt);
        const vd zero = _mm256_setzero_pd();
        /* lanes of the constrained axes of fixed bits 0..7, all ones */
        static const long long fixlanes[8][4] = {{0, 0, 0, 0},   {-1, 0, 0, 0},  {0, -1, 0, 0},  {-1, -1, 0, 0},
                                                 {0, 0, -1, 0},  {-1, 0, -1, 0}, {0, -1, -1, 0}, {-1, -1, -1, 0}};
        for (int i = 0; i < M->n; i++) {
            const double mi = M->mass[i];
            double *ai = acc + 4 * (size_t)i, *fi = f + 3 * (size_t)i, *vi = vv + 3 * (size_t)i, *di = dd + 3 * (size_t)i;
            const vd v0 = _mm256_loadu_pd(vi); /* lane 3: the next node's (or the padding) */
            const vd fv = VADD(_mm256_load_pd(ai), VMUL(VSET1(mi), VSUB(vg, VMUL(va, v0))));
            _mm256_store_pd(ai, zero);
            _mm_storeu_pd(fi, _mm256_castpd256_pd128(fv));
            _mm_store_sd(fi + 2, _mm256_extractf128_pd(fv, 1));
            if (dt > 0 && (!mask || mask[i])) {
                vd v1 = VADD(v0, VMUL(VSET1(dt / mi), fv));
                v1 = _mm256_andnot_pd(_mm256_castsi256_pd(_mm256_loadu_si256((const __m256i *)fixlanes[fixed[i] & 7])), v1);
                const vd d1 = VADD(_mm256_loadu_pd(di), VMUL(vdt, v1));
                _mm_storeu_pd(vi, _mm256_castpd256_pd128(v1));
                _mm_store_sd(vi + 2, _mm256_extractf128_pd(v1, 1));
                _mm_storeu_pd(di, _mm256_castpd256_pd128(d1));
                _mm_store_sd(di + 2, _mm256_extractf128_pd(d1, 1));
            }
        }
        return;
    }
#endif
    corot_forces(M, S, mat, g, S->f, 1, 1);
    /* symplectic Euler node by node, the update of level.c's sq_level_integrate */
    for (int i = 0; i < M->n; i++)
        if (!mask || mask[i])
            sq_level_euler_node(S->v, S->d, i, dt / M->mass[i], dt, S->f[3 * i], S->f[3 * i + 1],
                                S->f[3 * i + 2], M->fixed[i]);
}

void sq_level_corot_forces(const sq_level_model *M, const sq_level_state *S, const sq_material *mat,
                           const double g[3], double *f)
{
    /* rotations iterated to convergence from the stored ones, not stored: the state is unchanged */
    corot_forces(M, S, mat, g, f, 50, 0);
}

void sq_level_corot_forces_frozen(const sq_level_model *M, const sq_level_state *S, const sq_material *mat,
                                  const double g[3], double *f)
{
    corot_forces(M, S, mat, g, f, 0, 0);
}

void sq_level_corot_converge(const sq_level_model *M, sq_level_state *S)
{
    sq_corot *C = S->corot;
    if (!C)
        return;
    for (int t = 0; t < C->ntets; t++) {
        double G[10], q[4], F[9], R[9];
        tet_load(C, t, G, q);
        tet_grad(G, M->mesh->tets + 4 * (size_t)t, S->d, NULL, 0, F, 1.0);
        tet_rotation(q, F, 50, R);
        tet_store_q(C, t, q);
    }
}

double sq_level_corot_energy(const sq_level_model *M, const sq_level_state *S)
{
    const sq_corot *C = S->corot;
    double e = 0;
    for (int t = 0; t < C->ntets; t++)
        e += tet_energy(C, t, M->mesh->tets + 4 * (size_t)t, S->d);
    return e;
}

int sq_level_corot_inverted(const sq_level_model *M, const sq_level_state *S)
{
    const sq_mesh *m = M->mesh;
    int n = 0;
    for (int t = 0; t < m->ntets; t++) {
        double a[4][3], G[10], F[9];
        sq_tet_gradients(m, t, a);
        for (int k = 0; k < 3; k++)
            for (int c = 0; c < 3; c++)
                G[3 * k + c] = a[k][c];
        tet_grad(G, m->tets + 4 * (size_t)t, S->d, NULL, 0, F, 1.0);
        double det = F[0] * (F[4] * F[8] - F[5] * F[7]) - F[1] * (F[3] * F[8] - F[5] * F[6]) +
                     F[2] * (F[3] * F[7] - F[4] * F[6]);
        n += det <= 0;
    }
    return n;
}

void sq_level_corot_step_forces(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double g[3])
{
#ifdef COROT_SIMD
    if (!mat->use_viscosity) {
        sq_level_corot_step(M, S, mat, g, 0, NULL); /* dt = 0: forces into S->f, rotations stored, no update */
        return;
    }
#endif
    corot_forces(M, S, mat, g, S->f, 1, 1);
}
