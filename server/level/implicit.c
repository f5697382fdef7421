/* implicit.c - backward Euler on one level, matrix-free, by preconditioned conjugate gradients.
 *
 * One step of size h from (d0, v0): with P the projection onto the free axes (not constrained,
 * not held by a tool this frame), v1 = v0 + P dv and d1 = d0 + h P v1, and the force linearised
 * at the step's start, f(d1, v1) = f0 - h K P v1 - C P dv, backward Euler M dv = h f(d1, v1) is
 *
 *     P (c_m M + c_k K + c_d D) P dv = h P (f0 - h K P v0),
 *
 * c_m = 1 + h a, c_k = h b + h^2 with Rayleigh damping C = a M + b K, or c_m = 1, c_k = h^2,
 * c_d = h with the viscosity blocks D. K is the operator the explicit step applies: the linear
 * blocks, the nodal-pressure / smoothed operator (level/anp.c), or for corotational elasticity
 * the warped stiffness R K_T R^T per tet with the rotations of the step's start (one Newton
 * step; further Newton iterations re-linearise at the new state and report their residual).
 * docs/physics.md section 12.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "level/corot_impl.h"
#include "level/implicit_impl.h"
#include "level/level.h"

sq_implicit *sq_imp_get(const sq_level_model *M, sq_level_state *S)
{
    if (S->implicit)
        return S->implicit;
    sq_implicit *I = sq_calloc(1, sizeof *I);
    size_t n3 = 3 * (size_t)M->n;
    I->n = M->n;
    I->ntets = M->mesh->ntets;
    double **vecs[] = {&I->x, &I->r, &I->z, &I->p, &I->q, &I->rhs, &I->kv, &I->dv, &I->d0, &I->v0, &I->zo,
                       &I->vx, &I->vb, &I->vr, &I->vt, &I->dvprev, &I->acc};
    for (size_t k = 0; k < sizeof vecs / sizeof vecs[0]; k++)
        *vecs[k] = imp_calloc(n3 + 1, sizeof(double)); /* + 1: the fused pass reads 4 lanes a node */
    I->pre = imp_calloc(9 * (size_t)M->n, sizeof(double));
    I->rot = imp_calloc(9 * (size_t)I->ntets, sizeof(double));
    I->freeax = imp_calloc((size_t)M->n, 1);
    S->implicit = I;
    return I;
}

void sq_level_implicit_free(sq_level *L)
{
    sq_implicit *I = L->state.implicit;
    if (!I)
        return;
    double *vecs[] = {I->x, I->r, I->z, I->p, I->q, I->rhs, I->kv, I->dv, I->d0, I->v0, I->pre, I->rot, I->zo,
                      I->vx, I->vb, I->vr, I->vt, I->dvprev, I->acc};
    for (size_t k = 0; k < sizeof vecs / sizeof vecs[0]; k++)
        free(vecs[k]);
    sq_imp_mg_free(I);
    free(I->freeax);
    free(I->cuse);
    free(I->zc);
    free(I->kup_r);
    free(I->tet_edge);
    free(I);
    L->state.implicit = NULL;
}


/* y = K x for the operator the step applies (x already projected) */
void sq_imp_apply_k(const imp_op *o, const double *x, double *y)
{
    const sq_level_model *M = o->M;
    const size_t n3 = 3 * (size_t)M->n;
    if (o->S->anp) {
        sq_level_anp_apply(M, o->S, x, y);
        return;
    }
    if (o->S->corot) { /* the warped stiffness assembled at the linearisation, by the fused pass */
        sq_level_model W = *M;
        W.Kup = o->I->kup_r;
        sq_level_neg_k(&W, x, y, o->I->acc);
        for (size_t k = 0; k < n3; k++)
            y[k] = -y[k];
        return;
    }
    sq_level_neg_k(M, x, y, o->I->acc); /* the step's fused pass: y = -K x */
    for (size_t k = 0; k < n3; k++)
        y[k] = -y[k];
}

/* zero the axes that are not free, and the normal component at the contacts this step uses */
void sq_imp_project(const sq_implicit *I, double *x)
{
    for (int i = 0; i < I->n; i++) {
        unsigned fa = I->freeax[i];
        if (fa == 7)
            continue;
        for (int c = 0; c < 3; c++)
            if (!(fa & (1u << c)))
                x[3 * i + c] = 0;
    }
    if (I->ncuse)
        for (int k = 0; k < I->cc->n; k++)
            if (I->cuse[k]) {
                const double *nk = I->cc->normal + 3 * (size_t)k;
                double *xi = x + 3 * (size_t)I->cc->node[k];
                const double s = I->cc->stick[k] ? 0 : xi[0] * nk[0] + xi[1] * nk[1] + xi[2] * nk[2];
                for (int c = 0; c < 3; c++)
                    xi[c] = I->cc->stick[k] ? 0 : xi[c] - s * nk[c];
            }
}

void sq_level_implicit_set_contacts(const sq_level_model *M, sq_level_state *S, const sq_implicit_contacts *cc)
{
    sq_implicit *I = sq_imp_get(M, S);
    I->cc = cc && cc->n > 0 ? cc : NULL;
}

/* which of the caller's contacts this step uses (free nodes only), their impulses zeroed */
static void contacts_begin(sq_implicit *I)
{
    I->ncuse = 0;
    const sq_implicit_contacts *cc = I->cc;
    if (!cc)
        return;
    if (I->cuse_cap < cc->n) {
        free(I->cuse);
        I->cuse = sq_malloc((size_t)cc->n);
        I->cuse_cap = cc->n;
    }
    for (int k = 0; k < cc->n; k++) {
        const int i = cc->node[k];
        I->cuse[k] = i >= 0 && i < I->n && I->freeax[i] == 7;
        I->ncuse += I->cuse[k];
        cc->impulse[3 * (size_t)k] = cc->impulse[3 * (size_t)k + 1] = cc->impulse[3 * (size_t)k + 2] = 0;
    }
}

void sq_imp_apply_a(const imp_op *o, const double *x, double *y)
{
    const sq_level_model *M = o->M;
    sq_imp_apply_k(o, x, y);
    for (int i = 0; i < M->n; i++) {
        const double mi = o->cm * M->mass[i];
        for (int c = 0; c < 3; c++)
            y[3 * i + c] = mi * x[3 * i + c] + o->ck * y[3 * i + c];
    }
    if (o->cd != 0 && M->D) /* viscosity blocks: y += c_d D x */
        for (int i = 0; i < M->n; i++) {
            double out[3] = {0, 0, 0};
            sq_level_row(M, M->D, x, i, out); /* out = -D x */
            for (int c = 0; c < 3; c++)
                y[3 * i + c] -= o->cd * out[c];
        }
    sq_imp_project(o->I, y);
}

/* corotational: the rotations of the current state (converged from the stored ones and stored),
 * copied per tet for the warped stiffness */
static void corot_linearise(const sq_level_model *M, sq_level_state *S)
{
    sq_implicit *I = S->implicit;
    const sq_corot *C = S->corot;
    sq_level_corot_converge(M, S);
    if (!I->kup_r) {
        I->kup_r = imp_calloc(9 * (size_t)M->up_start[M->n], sizeof(double));
        I->tet_edge = imp_calloc(6 * (size_t)C->ntets, sizeof(int));
        for (int t = 0; t < C->ntets; t++) {
            const int *tv = M->mesh->tets + 4 * (size_t)t;
            int k = 0;
            for (int p = 0; p < 4; p++)
                for (int q = p + 1; q < 4; q++, k++) {
                    int i = SQ_MIN(tv[p], tv[q]), j = SQ_MAX(tv[p], tv[q]), at = -1;
                    for (int e = M->up_start[i]; e < M->up_start[i + 1]; e++)
                        if (M->up_col[e] == j)
                            at = e;
                    I->tet_edge[6 * (size_t)t + k] = at;
                }
        }
    }
    memset(I->kup_r, 0, sizeof(double) * 9 * (size_t)M->up_start[M->n]);
    for (int t = 0; t < C->ntets; t++) {
        double G[10], q[4];
        tet_load(C, t, G, q);
        double *R = I->rot + 9 * (size_t)t;
        quat_mat(q, R);
        /* the tet's off-diagonal blocks R K_pq R^T, added to the upper half (transposed when the
         * corners' nodes come in the other order); the diagonal follows from translation
         * invariance, as for the linear blocks */
        const int *tv = M->mesh->tets + 4 * (size_t)t;
        double a[4][3];
        for (int c = 0; c < 3; c++) {
            a[0][c] = G[c], a[1][c] = G[3 + c], a[2][c] = G[6 + c];
            a[3][c] = -(a[0][c] + a[1][c] + a[2][c]);
        }
        int k = 0;
        for (int p = 0; p < 4; p++)
            for (int qq = p + 1; qq < 4; qq++, k++) {
                const int e = I->tet_edge[6 * (size_t)t + k];
                if (e < 0)
                    continue;
                double B[9] = {0}, RB[9], W[9];
                sq_level_tet_block(SQ_OPERATOR_FEM, G[9], a[p], a[qq], C->mu, C->lambda, B);
                for (int r = 0; r < 3; r++)
                    for (int c = 0; c < 3; c++)
                        RB[3 * r + c] = R[3 * r] * B[c] + R[3 * r + 1] * B[3 + c] + R[3 * r + 2] * B[6 + c];
                for (int r = 0; r < 3; r++)
                    for (int c = 0; c < 3; c++)
                        W[3 * r + c] = RB[3 * r] * R[3 * c] + RB[3 * r + 1] * R[3 * c + 1] + RB[3 * r + 2] * R[3 * c + 2];
                double *out = I->kup_r + 9 * (size_t)e;
                if (tv[p] < tv[qq])
                    for (int r = 0; r < 9; r++)
                        out[r] += W[r];
                else
                    for (int r = 0; r < 3; r++)
                        for (int c = 0; c < 3; c++)
                            out[3 * r + c] += W[3 * c + r];
            }
    }
}

/* 3x3 symmetric inverse of B (row-major) into out; rows/columns of axes not in fa are taken
 * as identity and come out zero; 0 if singular (then out = 0) */
int sq_imp_inv3_free(const double *Bin, unsigned fa, double *out)
{
    double B[9];
    memcpy(B, Bin, sizeof B);
    for (int c = 0; c < 3; c++)
        if (!(fa & (1u << c)))
            for (int k = 0; k < 3; k++) {
                B[3 * c + k] = B[3 * k + c] = (k == c);
            }
    if (sq_inv3(B, out))
        return 0;
    for (int c = 0; c < 3; c++)
        if (!(fa & (1u << c)))
            for (int k = 0; k < 3; k++)
                out[3 * c + k] = out[3 * k + c] = 0;
    return 1;
}

/* the diagonal blocks of c_m M + c_k K + c_d D of model M into blk (9 per node). K's from its
 * CSR diagonal, or with kup (the corotational warped stiffness in the upper-half layout) from
 * translation invariance, K_ii = -sum_{j != i} K_ij, as the fused pass uses it */
void sq_imp_diag_blocks(const imp_op *o, const sq_level_model *M, const double *kup, double *blk)
{
    memset(blk, 0, sizeof(double) * 9 * (size_t)M->n);
    for (int i = 0; i < M->n; i++) {
        double *out = blk + 9 * (size_t)i;
        for (int e = M->row_start[i]; e < M->row_start[i + 1]; e++)
            if (M->col[e] == i)
                for (int k = 0; k < 9; k++) {
                    if (!kup)
                        out[k] += o->ck * M->K[9 * (size_t)e + k];
                    if (o->cd != 0 && M->D)
                        out[k] += o->cd * M->D[9 * (size_t)e + k];
                }
        for (int c = 0; c < 3; c++)
            out[4 * c] += o->cm * M->mass[i];
    }
    if (kup)
        for (int i = 0; i < M->n; i++)
            for (int e = M->up_start[i]; e < M->up_start[i + 1]; e++) {
                const double *B = kup + 9 * (size_t)e;
                double *bi = blk + 9 * (size_t)i, *bj = blk + 9 * (size_t)M->up_col[e];
                for (int r = 0; r < 3; r++)
                    for (int c = 0; c < 3; c++) {
                        bi[3 * r + c] -= o->ck * B[3 * r + c];
                        bj[3 * r + c] -= o->ck * B[3 * c + r];
                    }
            }
}


/* y = D^-1 r with the 3x3 inverse blocks dinv (9 per node) */
void sq_imp_block_apply(const double *dinv, int n, const double *r, double *z)
{
    for (int i = 0; i < n; i++) {
        const double *B = dinv + 9 * (size_t)i, *ri = r + 3 * (size_t)i;
        double *zi = z + 3 * (size_t)i;
        zi[0] = B[0] * ri[0] + B[1] * ri[1] + B[2] * ri[2];
        zi[1] = B[3] * ri[0] + B[4] * ri[1] + B[5] * ri[2];
        zi[2] = B[6] * ri[0] + B[7] * ri[1] + B[8] * ri[2];
    }
}

/* the preconditioner's data for this solve */
static void precond_setup(const imp_op *o, int kind)
{
    const sq_level_model *M = o->M;
    sq_implicit *I = (sq_implicit *)o->I;
    double *blk = sq_malloc(sizeof(double) * 9 * (size_t)M->n);
    sq_imp_diag_blocks(o, M, o->S->corot ? I->kup_r : NULL, blk);
    for (int i = 0; i < M->n; i++) {
        const double *B = blk + 9 * (size_t)i;
        double *out = I->pre + 9 * (size_t)i;
        unsigned fa = I->freeax[i];
        if (kind != SQ_PRECOND_JACOBI) {
            if (!sq_imp_inv3_free(B, fa, out)) { /* singular block: fall back to its diagonal */
                memset(out, 0, 9 * sizeof(double));
                for (int c = 0; c < 3; c++)
                    out[4 * c] = (fa & (1u << c)) && B[4 * c] > 0 ? 1.0 / B[4 * c] : 0;
            }
        } else {
            for (int c = 0; c < 3; c++)
                out[c] = (fa & (1u << c)) && B[4 * c] > 0 ? 1.0 / B[4 * c] : 0;
        }
    }
    free(blk);
    if (kind == SQ_PRECOND_MULTIGRID && I->nmg > 0) {
        for (int j = 0; j < I->nmg; j++)
            sq_imp_coarse_dinv(o, &I->mg[j]);
        /* the smoothers' dampings: estimated again when the coefficients change, or every 64
         * solves (the corotational operator turns with the body) */
        if (o->cm != I->omega_cm || o->ck != I->omega_ck || I->omega_age++ >= 64) {
            I->omega0 = 1.0 / sq_imp_cyc_lambda(o, 0, I->vx, I->vr, I->vt);
            for (int j = 0; j < I->nmg; j++)
                I->mg[j].omega = 1.0 / sq_imp_cyc_lambda(o, j + 1, I->mg[j].x, I->mg[j].r, I->mg[j].t);
            I->omega_cm = o->cm;
            I->omega_ck = o->ck;
            I->omega_age = 0;
        }
    }
}

static void precond_apply(const imp_op *o, int kind, const double *r, double *z)
{
    const sq_implicit *I = o->I;
    if (kind == SQ_PRECOND_MULTIGRID && I->nmg > 0) {
        sq_imp_vcycle(o, 0, r, z);
        sq_imp_project(I, z);
    } else if (kind != SQ_PRECOND_JACOBI) {
        sq_imp_block_apply(I->pre, I->n, r, z);
    } else {
        for (int i = 0; i < I->n; i++)
            for (int c = 0; c < 3; c++)
                z[3 * i + c] = I->pre[9 * (size_t)i + c] * r[3 * i + c];
    }
    if (I->ncuse) /* S B^-1 S: symmetric, positive on the contacts' free subspace */
        sq_imp_project(I, z);
}


double sq_imp_dot(const double *a, const double *b, size_t n)
{
    double s = 0;
    for (size_t k = 0; k < n; k++)
        s += a[k] * b[k];
    return s;
}

/* A x = b (b projected) from x = 0; stops at |r| <= tol |b|, at max_iter, or when the thread's
 * CPU clock passes deadline (> 0); returns iterations, *relres the final |r| / |b| */
static int pcg_run(const imp_op *o, const sq_implicit_def *def, int precond, int max_iter, int warm, const double *b,
                   double *x, double deadline, double *relres, int *capped)
{
    sq_implicit *I = (sq_implicit *)o->I;
    const size_t n3 = 3 * (size_t)I->n;
    double *r = I->r, *z = I->z, *p = I->p, *q = I->q;
    const double bnorm = sqrt(sq_imp_dot(b, b, n3));
    *relres = 0;
    *capped = 0;
    if (!(bnorm > 0)) {
        memset(x, 0, sizeof(double) * n3);
        return 0;
    }
    if (warm) { /* from the given x: r = b - A x */
        sq_imp_apply_a(o, x, q);
        for (size_t k = 0; k < n3; k++)
            r[k] = b[k] - q[k];
    } else {
        memset(x, 0, sizeof(double) * n3);
        memcpy(r, b, sizeof(double) * n3);
    }
    precond_apply(o, precond, r, z);
    memcpy(p, z, sizeof(double) * n3);
    memcpy(I->zo, z, sizeof(double) * n3);
    double rz = sq_imp_dot(r, z, n3), rr = sq_imp_dot(r, r, n3);
    int it = 0;
    while (sqrt(rr) > def->tol * bnorm) {
        if (it >= max_iter || (deadline > 0 && (it & 3) == 3 && sq_thread_cpu() > deadline)) {
            *capped = 1;
            break;
        }
        sq_imp_apply_a(o, p, q);
        const double pq = sq_imp_dot(p, q, n3);
        if (!(pq > 0)) {
            *capped = 1; /* breakdown (round-off at convergence, or a non-positive operator) */
            break;
        }
        const double alpha = rz / pq;
        for (size_t k = 0; k < n3; k++) {
            x[k] += alpha * p[k];
            r[k] -= alpha * q[k];
        }
        precond_apply(o, precond, r, z);
        const double rz2 = sq_imp_dot(r, z, n3);
        rr = sq_imp_dot(r, r, n3);
        /* flexible (Polak-Ribiere) beta: the multigrid cycle is not a fixed linear map (its
         * coarsest solve stops early); for the fixed preconditioners it equals the usual one up
         * to round-off (r.z_old = 0 in exact arithmetic) */
        double beta = rz2 / rz;
        if (precond == SQ_PRECOND_MULTIGRID)
            beta = (rz2 - sq_imp_dot(r, I->zo, n3)) / rz;
        memcpy(I->zo, z, sizeof(double) * n3);
        rz = rz2;
        for (size_t k = 0; k < n3; k++)
            p[k] = z[k] + beta * p[k];
        it++;
    }
    *relres = sqrt(rr) / bnorm;
    return it;
}

/* A x = b (b projected) from x = 0; stops at |r| <= tol |b|, at max_iter, or when the thread's
 * CPU clock passes deadline (> 0); returns iterations, *relres the final |r| / |b|. Multigrid
 * gets SQ_MG_TRIES iterations: when it has not converged by then (a hierarchy too coarse for
 * the material, as near-incompressible bodies on linear tets), the solve goes on from there
 * with block Jacobi */
#define SQ_MG_TRIES 100
static int pcg(const imp_op *o, const sq_implicit_def *def, const double *b, double *x, int warm, double deadline,
               double *relres, int *capped)
{
    if (def->precond != SQ_PRECOND_MULTIGRID || o->I->nmg == 0)
        return pcg_run(o, def, def->precond == SQ_PRECOND_MULTIGRID ? SQ_PRECOND_BLOCK : def->precond, def->max_iter,
                       warm, b, x, deadline, relres, capped);
    int it = pcg_run(o, def, SQ_PRECOND_MULTIGRID, SQ_MIN(def->max_iter, SQ_MG_TRIES), warm, b, x, deadline, relres,
                     capped);
    if (!*capped || it >= def->max_iter || (deadline > 0 && sq_thread_cpu() > deadline))
        return it;
    return it + pcg_run(o, def, SQ_PRECOND_BLOCK, def->max_iter - it, 1, b, x, deadline, relres, capped);
}

/* the force of the current state into S->f (corotational: rotations converged and stored) */
static void forces_now(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double g[3])
{
    if (S->corot)
        corot_linearise(M, S);
    sq_level_forces(M, S, mat, g, NULL);
}

/* FNV-1a over the bits of d, v and g: equal exactly when the state is the same */
static unsigned long long state_hash(const sq_level_model *M, const sq_level_state *S, const double g[3])
{
    unsigned long long h = 1469598103934665603ull;
    const size_t n3 = 3 * (size_t)M->n;
    const double *arr[3] = {S->d, S->v, g};
    const size_t len[3] = {n3, n3, 3};
    for (int a = 0; a < 3; a++)
        for (size_t k = 0; k < len[a]; k++) {
            unsigned long long bits;
            memcpy(&bits, arr[a] + k, sizeof bits);
            h = (h ^ bits) * 1099511628211ull;
        }
    return h;
}

/* kinetic + elastic + gravity potential energy of the state, J */
static double total_energy(const sq_level_model *M, const sq_level_state *S, const double g[3])
{
    double e = sq_level_elastic_energy(M, S);
    for (int i = 0; i < M->n; i++) {
        const double *v = S->v + 3 * (size_t)i, *d = S->d + 3 * (size_t)i;
        e += M->mass[i] * (0.5 * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) - (g[0] * d[0] + g[1] * d[1] + g[2] * d[2]));
    }
    return e;
}

int sq_implicit_def_check(const sq_implicit_def *d, sq_err *err)
{
    if (d->substeps < 1 || d->substeps > SQ_IMPLICIT_MAX_SUBSTEPS)
        return sq_err_set(err, "implicit substeps %d out of range: give 1..%d steps per frame", d->substeps,
                          SQ_IMPLICIT_MAX_SUBSTEPS);
    if (!(d->tol > 0) || !(d->tol < 1))
        return sq_err_set(err, "cg_tolerance %g out of range: give a relative residual in (0, 1), e.g. 1e-6",
                          d->tol);
    if (d->max_iter < 1 || d->max_iter > SQ_IMPLICIT_MAX_ITER)
        return sq_err_set(err, "cg_max_iterations %d out of range: give 1..%d", d->max_iter, SQ_IMPLICIT_MAX_ITER);
    if (d->precond < 0 || d->precond > SQ_PRECOND_MULTIGRID)
        return sq_err_set(err, "unknown preconditioner %d: use \"jacobi\", \"block_jacobi\" or \"multigrid\"",
                          d->precond);
    if (d->newton < 1 || d->newton > SQ_IMPLICIT_MAX_NEWTON)
        return sq_err_set(err, "newton_iterations %d out of range: give 1..%d", d->newton, SQ_IMPLICIT_MAX_NEWTON);
    return 0;
}

sq_implicit_def sq_implicit_def_default(void)
{
    sq_implicit_def d = {.substeps = 1, .tol = 1e-6, .max_iter = 500, .precond = SQ_PRECOND_BLOCK, .newton = 1};
    return d;
}

/* the contacts' prescribed part z of dv (the whole velocity relative to the obstacle at a
 * sticking contact, its normal part at a sliding one): rhs -= P A z, the solve adds z */
static void contacts_prescribe(const imp_op *o, sq_implicit *I, const sq_level_state *S)
{
    const size_t n3 = 3 * (size_t)I->n;
    if (!I->zc)
        I->zc = imp_calloc(n3 + 1, sizeof(double));
    memset(I->zc, 0, sizeof(double) * n3);
    for (int k = 0; k < I->cc->n; k++)
        if (I->cuse[k]) {
            const double *nk = I->cc->normal + 3 * (size_t)k, *uk = I->cc->u + 3 * (size_t)k;
            const size_t i3 = 3 * (size_t)I->cc->node[k];
            double rel[3] = {uk[0] - S->v[i3], uk[1] - S->v[i3 + 1], uk[2] - S->v[i3 + 2]};
            const double s = rel[0] * nk[0] + rel[1] * nk[1] + rel[2] * nk[2];
            for (int c = 0; c < 3; c++)
                I->zc[i3 + c] = I->cc->stick[k] ? rel[c] : s * nk[c];
        }
    sq_imp_apply_a(o, I->zc, I->kv);
    for (size_t k = 0; k < n3; k++)
        I->rhs[k] -= I->kv[k];
}

/* the constraints' impulses after the step: M (v1 - v0) - h f(end state) */
static void contacts_impulses(sq_implicit *I, const sq_level_model *M, sq_level_state *S, const sq_material *mat,
                              const double g[3], double h)
{
    forces_now(M, S, mat, g);
    for (int k = 0; k < I->cc->n; k++)
        if (I->cuse[k]) {
            const int i = I->cc->node[k];
            for (int c = 0; c < 3; c++) {
                const size_t j = 3 * (size_t)i + c;
                I->cc->impulse[3 * (size_t)k + c] = M->mass[i] * (S->v[j] - I->v0[j]) - h * S->f[j];
            }
        }
}

void sq_level_implicit_step(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double g[3],
                            double h,
                            const unsigned char *mask, const sq_implicit_def *def, double deadline,
                            sq_implicit_stats *st)
{
    sq_implicit *I = sq_imp_get(M, S);
    const int n = M->n;
    const size_t n3 = 3 * (size_t)n;
    for (int i = 0; i < n; i++)
        I->freeax[i] = (mask && !mask[i]) ? 0 : (unsigned char)(~M->fixed[i] & 7u);
    contacts_begin(I);
    /* c_d: the viscosity blocks (linear operators; corotational viscosity is applied from the
     * step's start, not in the operator: docs/physics.md); stiffness damping b with Rayleigh */
    const int visc = mat->use_viscosity != 0;
    imp_op o = {.M = M, .S = S, .I = I, .cm = 1 + h * mat->rayleigh_mass,
                .ck = h * h + (visc ? 0 : h * mat->rayleigh_stiffness), .cd = visc && M->D && !S->corot ? h : 0};
    memcpy(I->d0, S->d, sizeof(double) * n3);
    memcpy(I->v0, S->v, sizeof(double) * n3);
    /* corotational without holds: the start energy, for the Newton iterations' energy guard */
    const int e0_known = S->corot && !mask;
    double e0 = 0;
    if (e0_known)
        e0 = I->e_valid && I->e_hash == state_hash(M, S, g) ? I->e_cache : total_energy(M, S, g);
    I->e_valid = 0;

    /* f0 at the step's start (corotational: the rotations of the linearisation) */
    forces_now(M, S, mat, g);
    /* rhs = h P (f0 - h K w), w = P v0 + H u: the free nodes' velocities and the held nodes'
     * prescribed ones u (their displacement advances by h u in the step: a tool's motion enters
     * the solve as a known increment, not as a jump of the start state) */
    for (int i = 0; i < n; i++) {
        unsigned fx = M->fixed[i];
        for (int c = 0; c < 3; c++)
            I->x[3 * i + c] = (fx & (1u << c)) ? 0 : S->v[3 * i + c];
    }
    sq_imp_apply_k(&o, I->x, I->kv);
    for (size_t k = 0; k < n3; k++)
        I->rhs[k] = h * (S->f[k] - h * I->kv[k]);
    if (I->ncuse) /* the contacts' forces (kinetic friction) */
        for (int k = 0; k < I->cc->n; k++)
            if (I->cuse[k])
                for (int c = 0; c < 3; c++)
                    I->rhs[3 * (size_t)I->cc->node[k] + c] += h * I->cc->force[3 * (size_t)k + c];
    sq_imp_project(I, I->rhs);
    if (I->ncuse)
        contacts_prescribe(&o, I, S);
    double rhs0 = sqrt(sq_imp_dot(I->rhs, I->rhs, n3));
    /* held nodes move first: d += h u on their unconstrained axes */
    if (mask)
        for (int i = 0; i < n; i++)
            if (!mask[i])
                for (int c = 0; c < 3; c++)
                    if (!(M->fixed[i] & (1u << c)))
                        S->d[3 * i + c] += h * S->v[3 * i + c];

    memset(st, 0, sizeof *st);
    memset(I->dv, 0, sizeof(double) * n3);
    for (int nt = 0;; nt++) {
        precond_setup(&o, def->precond);
        double relres;
        int capped;
        /* the first solve starts from the last step's dv (projected): smooth motion needs few
         * iterations; Newton corrections start from zero */
        int warm = nt == 0 && I->have_prev;
        if (warm) {
            memcpy(I->x, I->dvprev, sizeof(double) * n3);
            sq_imp_project(I, I->x);
        }
        st->iterations += pcg(&o, def, I->rhs, I->x, warm, deadline, &relres, &capped);
        if (nt == 0 && I->ncuse)
            for (size_t k = 0; k < n3; k++)
                I->x[k] += I->zc[k];
        if (nt == 0 || relres > st->residual)
            st->residual = relres;
        st->unconverged |= capped;
        for (size_t k = 0; k < n3; k++)
            I->dv[k] += I->x[k];
        /* the new state: v1 = v0 + P dv, d1 = d0 + h P v1 */
        for (int i = 0; i < n; i++) {
            unsigned fa = I->freeax[i];
            for (int c = 0; c < 3; c++) {
                size_t k = 3 * (size_t)i + c;
                if (fa & (1u << c)) {
                    S->v[k] = I->v0[k] + I->dv[k];
                    S->d[k] = I->d0[k] + h * S->v[k];
                }
            }
        }
        st->newton = nt + 1;
        if (!S->corot)
            break; /* linear (and nodal-pressure) bodies: the one solve is the step */
        /* corotational: the Newton iterations asked for, and more (up to the maximum) while the
         * energy of a body no tool holds is above the step's start: the warped stiffness is not
         * the exact tangent, so one iteration alone may add energy; converged, backward Euler
         * cannot (a solve stopped by its cap is reported instead: more iterations of it would
         * not be converged either) */
        int more = nt + 1 < def->newton;
        if (!more && e0_known && !capped && nt + 1 < SQ_IMPLICIT_MAX_NEWTON) {
            const double e1 = total_energy(M, S, g);
            more = e1 > e0 + 1e-12 * fabs(e0);
            if (!more) { /* the next step's start energy, if nothing changes the state */
                I->e_cache = e1;
                I->e_hash = state_hash(M, S, g);
                I->e_valid = 1;
            }
        }
        if (more || def->newton > 1) {
            /* Newton residual P (h f(d1, v1) - M dv), re-linearised at the new state */
            forces_now(M, S, mat, g);
            for (int i = 0; i < n; i++)
                for (int c = 0; c < 3; c++) {
                    size_t k = 3 * (size_t)i + c;
                    I->rhs[k] = h * S->f[k] - M->mass[i] * I->dv[k];
                }
            sq_imp_project(I, I->rhs);
            st->newton_residual = rhs0 > 0 ? sqrt(sq_imp_dot(I->rhs, I->rhs, n3)) / rhs0 : 0;
            if (st->newton_residual <= def->tol)
                more = 0;
        }
        if (!more)
            break;
    }
    memcpy(I->dvprev, I->dv, sizeof(double) * n3);
    I->have_prev = 1;
    if (I->ncuse)
        contacts_impulses(I, M, S, mat, g, h);
    /* S->f holds the last force pass's values (the step's start, or with Newton iterations an
     * intermediate state): the caller evaluates the end state's force when it needs it */
}
