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
#include "level/level.h"

/* one coarser level of the multigrid preconditioner: the level (its linear operator, masses
 * and constrained axes), its V-cycle vectors, the inverse diagonal blocks of its matrix, the
 * smoother's damping, and for every node of the next finer level the tet of this level's rest
 * mesh containing it with its barycentrics (the prolongation; its transpose restricts) */
typedef struct mg_level {
    const sq_level *L;
    int n;
    double *x, *b, *r, *t;     /* 3 n */
    double *dinv;              /* 9 n */
    double *acc;               /* zero scratch of the fused K pass (3 n + 1) */
    double omega;
    double *chol;              /* coarsest level, 3 n <= SQ_MG_DENSE: dense Cholesky factor of its
                                  matrix (lower, row-major), for chol_cm/ck/cd; else NULL */
    double chol_cm, chol_ck, chol_cd;
    int nfine;                 /* nodes of the finer level */
    int *tet;                  /* nfine */
    double *bary;              /* 4 nfine */
} mg_level;

struct sq_implicit {
    int n, ntets;
    double *zo;                   /* the previous preconditioned residual (flexible CG) */
    double *dvprev;               /* the last step's dv: the next solve's start (3 n) */
    int have_prev;
    double *acc;                  /* zero scratch of the fused K pass (3 n + 1) */
    /* multigrid: the coarser levels (coarse[0] next to this one), the finest level's V-cycle
     * vectors and smoother damping, and the coefficients the dampings were estimated for */
    int nmg;
    mg_level mg[SQ_MAX_LEVELS];
    double *vx, *vb, *vr, *vt;
    double omega0, omega_cm, omega_ck;
    int omega_age;
    double *x, *r, *z, *p, *q;    /* CG vectors (3 n) */
    double *rhs, *kv, *dv;        /* right-hand side, K P v0, the solved dv (3 n) */
    double *d0, *v0;              /* the step's start state (3 n), for Newton iterations */
    double *pre;                  /* Jacobi: inverse diagonal (3 n); block: inverse 3x3 (9 n) */
    double *rot;                  /* corotational: R per tet (9 ntets), the linearisation's */
    /* corotational: the warped stiffness assembled in the level's upper-half layout (Kup
     * blocks, up_start[n] x 9) at each linearisation, and for each tet the index of each of its
     * 6 edges in that layout (6 ntets, corner pairs 01 02 03 12 13 23) */
    double *kup_r;
    int *tet_edge;
    /* the energy guard: the total energy of the last step's end state and a hash of that state
     * (d and v bits, gravity), so the next step's start energy is not computed again when
     * nothing changed the state in between */
    double e_cache;
    unsigned long long e_hash;
    int e_valid;
    unsigned char *freeax;        /* free axes per node this step, bits x=1 y=2 z=4 (n) */
    /* contacts as constraints: the caller's list, and which of its entries this step uses (a
     * free node: 1), their prescribed part of dv (3 n, zero elsewhere) */
    const sq_implicit_contacts *cc;
    unsigned char *cuse;
    int ncuse, cuse_cap;
    double *zc;
};

static void *imp_calloc(size_t count, size_t size) { return sq_calloc(count ? count : 1, size); }

static void mg_free(sq_implicit *I)
{
    for (int j = 0; j < I->nmg; j++) {
        mg_level *g = &I->mg[j];
        double *vecs[] = {g->x, g->b, g->r, g->t, g->dinv, g->bary, g->chol, g->acc};
        for (size_t k = 0; k < sizeof vecs / sizeof vecs[0]; k++)
            free(vecs[k]);
        free(g->tet);
    }
    I->nmg = 0;
}

static sq_implicit *imp_get(sq_level *L)
{
    if (L->implicit)
        return L->implicit;
    const sq_level_model *M = &L->model;
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
    L->implicit = I;
    return I;
}

void sq_level_implicit_free(sq_level *L)
{
    sq_implicit *I = L->implicit;
    if (!I)
        return;
    double *vecs[] = {I->x, I->r, I->z, I->p, I->q, I->rhs, I->kv, I->dv, I->d0, I->v0, I->pre, I->rot, I->zo,
                      I->vx, I->vb, I->vr, I->vt, I->dvprev, I->acc};
    for (size_t k = 0; k < sizeof vecs / sizeof vecs[0]; k++)
        free(vecs[k]);
    mg_free(I);
    free(I->freeax);
    free(I->cuse);
    free(I->zc);
    free(I->kup_r);
    free(I->tet_edge);
    free(I);
    L->implicit = NULL;
}

/* the operator of one solve: y = P (c_m M + c_k K + c_d D) P x */
typedef struct imp_op {
    const sq_level *L;
    const sq_implicit *I;
    double cm, ck, cd;
} imp_op;

/* y = K x for the operator the step applies (x already projected) */
static void apply_k(const imp_op *o, const double *x, double *y)
{
    const sq_level *L = o->L;
    const sq_level_model *M = &L->model;
    const size_t n3 = 3 * (size_t)M->n;
    if (L->anp) {
        sq_level_anp_apply(L, x, y);
        return;
    }
    if (L->corot) { /* the warped stiffness assembled at the linearisation, by the fused pass */
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
static void project(const sq_implicit *I, double *x)
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

void sq_level_implicit_set_contacts(sq_level *L, const sq_implicit_contacts *cc)
{
    sq_implicit *I = imp_get(L);
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

static void apply_a(const imp_op *o, const double *x, double *y)
{
    const sq_level_model *M = &o->L->model;
    apply_k(o, x, y);
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
    project(o->I, y);
}

/* corotational: the rotations of the current state (converged from the stored ones and stored),
 * copied per tet for the warped stiffness */
static void corot_linearise(sq_level *L)
{
    sq_implicit *I = L->implicit;
    const sq_corot *C = L->corot;
    const sq_level_model *M = &L->model;
    sq_level_corot_converge(L);
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
static int inv3_free(const double *Bin, unsigned fa, double *out)
{
    double B[9];
    memcpy(B, Bin, sizeof B);
    for (int c = 0; c < 3; c++)
        if (!(fa & (1u << c)))
            for (int k = 0; k < 3; k++) {
                B[3 * c + k] = B[3 * k + c] = (k == c);
            }
    double c00 = B[4] * B[8] - B[5] * B[7], c01 = B[5] * B[6] - B[3] * B[8], c02 = B[3] * B[7] - B[4] * B[6];
    double det = B[0] * c00 + B[1] * c01 + B[2] * c02;
    memset(out, 0, 9 * sizeof(double));
    if (!(fabs(det) > 0) || !isfinite(det))
        return 0;
    double id = 1.0 / det;
    out[0] = c00 * id;
    out[1] = (B[2] * B[7] - B[1] * B[8]) * id;
    out[2] = (B[1] * B[5] - B[2] * B[4]) * id;
    out[3] = c01 * id;
    out[4] = (B[0] * B[8] - B[2] * B[6]) * id;
    out[5] = (B[2] * B[3] - B[0] * B[5]) * id;
    out[6] = c02 * id;
    out[7] = (B[1] * B[6] - B[0] * B[7]) * id;
    out[8] = (B[0] * B[4] - B[1] * B[3]) * id;
    for (int c = 0; c < 3; c++)
        if (!(fa & (1u << c)))
            for (int k = 0; k < 3; k++)
                out[3 * c + k] = out[3 * k + c] = 0;
    return 1;
}

/* the diagonal blocks of c_m M + c_k K + c_d D of model M into blk (9 per node). K's from its
 * CSR diagonal, or with kup (the corotational warped stiffness in the upper-half layout) from
 * translation invariance, K_ii = -sum_{j != i} K_ij, as the fused pass uses it */
static void diag_blocks(const imp_op *o, const sq_level_model *M, const double *kup, double *blk)
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

static double dot(const double *a, const double *b, size_t n);

/* y = D^-1 r with the 3x3 inverse blocks dinv (9 per node) */
static void block_apply(const double *dinv, int n, const double *r, double *z)
{
    for (int i = 0; i < n; i++) {
        const double *B = dinv + 9 * (size_t)i, *ri = r + 3 * (size_t)i;
        double *zi = z + 3 * (size_t)i;
        zi[0] = B[0] * ri[0] + B[1] * ri[1] + B[2] * ri[2];
        zi[1] = B[3] * ri[0] + B[4] * ri[1] + B[5] * ri[2];
        zi[2] = B[6] * ri[0] + B[7] * ri[1] + B[8] * ri[2];
    }
}

/* inverse diagonal blocks of c_m M + c_k K + c_d D of a coarse level (linear K), constrained
 * axes zeroed */
static void coarse_dinv(const imp_op *o, mg_level *g)
{
    const sq_level_model *M = &g->L->model;
    diag_blocks(o, M, NULL, g->dinv);
    for (int i = 0; i < M->n; i++) {
        double B[9];
        memcpy(B, g->dinv + 9 * (size_t)i, sizeof B);
        if (!inv3_free(B, ~M->fixed[i] & 7u, g->dinv + 9 * (size_t)i))
            memset(g->dinv + 9 * (size_t)i, 0, 9 * sizeof(double));
    }
}

/* y = (c_m M + c_k K + c_d D) x on coarse level g, constrained axes zeroed */
static void coarse_apply(const imp_op *o, const mg_level *g, const double *x, double *y)
{
    const sq_level_model *M = &g->L->model;
    sq_level_neg_k(M, x, y, g->acc); /* y = -K x, the fused pass */
    for (int i = 0; i < M->n; i++) {
        const double s0 = -y[3 * i], s1 = -y[3 * i + 1], s2 = -y[3 * i + 2];
        double out[3] = {0, 0, 0};
        if (o->cd != 0 && M->D)
            sq_level_row(M, M->D, x, i, out);
        const double m = o->cm * M->mass[i];
        const double yi[3] = {m * x[3 * i] + o->ck * s0 - o->cd * out[0], m * x[3 * i + 1] + o->ck * s1 - o->cd * out[1],
                              m * x[3 * i + 2] + o->ck * s2 - o->cd * out[2]};
        for (int c = 0; c < 3; c++)
            y[3 * i + c] = (M->fixed[i] & (1u << c)) ? 0 : yi[c];
    }
}

/* level j of the cycle: 0 the solved level, j >= 1 coarse level mg[j - 1] */
static int cyc_n(const sq_implicit *I, int j) { return j ? I->mg[j - 1].n : I->n; }

static void cyc_apply(const imp_op *o, int j, const double *x, double *y)
{
    if (j == 0)
        apply_a(o, x, y);
    else
        coarse_apply(o, &o->I->mg[j - 1], x, y);
}

static const double *cyc_dinv(const sq_implicit *I, int j) { return j ? I->mg[j - 1].dinv : I->pre; }

/* largest eigenvalue of D^-1 A at cycle level j, by 12 power iterations from a fixed rough
 * start (deterministic), times 1.25 for the power method's underestimate */
static double cyc_lambda(const imp_op *o, int j, double *x, double *y, double *z)
{
    const sq_implicit *I = o->I;
    const int n = cyc_n(I, j);
    const size_t n3 = 3 * (size_t)n;
    /* a rough start (signs from a hash of the index): the top of D^-1 A is the roughest mode */
    for (size_t k = 0; k < n3; k++)
        x[k] = (((k * 2654435761u) >> 7) & 1) ? 1.0 : -1.0;
    double lam = 1;
    for (int it = 0; it < 12; it++) {
        block_apply(cyc_dinv(I, j), n, x, z);
        double zn = sqrt(dot(z, z, n3));
        if (!(zn > 0))
            return 1;
        for (size_t k = 0; k < n3; k++)
            z[k] /= zn;
        cyc_apply(o, j, z, y);
        block_apply(cyc_dinv(I, j), n, y, x); /* x = D^-1 A z */
        lam = dot(z, x, n3);
    }
    return 1.25 * (lam > 0 ? lam : 1);
}

/* one damped block-Jacobi sweep x += omega D^-1 (b - A x) at cycle level j (t: scratch) */
static void cyc_smooth(const imp_op *o, int j, double omega, const double *b, double *x, double *r, double *t)
{
    const sq_implicit *I = o->I;
    const int n = cyc_n(I, j);
    const size_t n3 = 3 * (size_t)n;
    cyc_apply(o, j, x, t);
    for (size_t k = 0; k < n3; k++)
        r[k] = b[k] - t[k];
    block_apply(cyc_dinv(I, j), n, r, t);
    for (size_t k = 0; k < n3; k++)
        x[k] += omega * t[k];
}

/* the coarsest level's dense factor: its matrix with constrained rows and columns as identity,
 * Cholesky-factored in place (lower triangle); 0, or -1 if not positive definite */
#define SQ_MG_DENSE 2400
static int coarse_factor(const imp_op *o, mg_level *g)
{
    const sq_level_model *M = &g->L->model;
    const int N = 3 * g->n;
    if (!g->chol)
        g->chol = sq_malloc(sizeof(double) * (size_t)N * (size_t)N);
    double *A = g->chol;
    memset(A, 0, sizeof(double) * (size_t)N * (size_t)N);
    for (int i = 0; i < M->n; i++)
        for (int e = M->row_start[i]; e < M->row_start[i + 1]; e++) {
            const int j = M->col[e];
            for (int r = 0; r < 3; r++)
                for (int c = 0; c < 3; c++) {
                    double v = o->ck * M->K[9 * (size_t)e + 3 * r + c];
                    if (o->cd != 0 && M->D)
                        v += o->cd * M->D[9 * (size_t)e + 3 * r + c];
                    if (i == j && r == c)
                        v += o->cm * M->mass[i];
                    A[(size_t)(3 * i + r) * N + 3 * j + c] = v;
                }
        }
    for (int i = 0; i < M->n; i++)
        for (int r = 0; r < 3; r++)
            if (M->fixed[i] & (1u << r)) {
                const int q = 3 * i + r;
                for (int k = 0; k < N; k++)
                    A[(size_t)q * N + k] = A[(size_t)k * N + q] = 0;
                A[(size_t)q * N + q] = 1;
            }
    for (int j = 0; j < N; j++) {
        double *Aj = A + (size_t)j * N;
        double d = Aj[j];
        for (int k = 0; k < j; k++)
            d -= Aj[k] * Aj[k];
        if (!(d > 0))
            return -1;
        d = sqrt(d);
        Aj[j] = d;
        for (int i = j + 1; i < N; i++) {
            double *Ai = A + (size_t)i * N, s = Ai[j];
            for (int k = 0; k < j; k++)
                s -= Ai[k] * Aj[k];
            Ai[j] = s / d;
        }
    }
    g->chol_cm = o->cm, g->chol_ck = o->ck, g->chol_cd = o->cd;
    return 0;
}

/* the coarsest level: by its dense factor when it is small (SQ_MG_DENSE unknowns), else 40
 * block-Jacobi CG iterations (or to 1e-3 relative) */
static void coarsest_solve(const imp_op *o, mg_level *g, const double *b, double *x)
{
    const int N = 3 * g->n;
    if (N <= SQ_MG_DENSE) {
        if ((!g->chol || g->chol_cm != o->cm || g->chol_ck != o->ck || g->chol_cd != o->cd) &&
            coarse_factor(o, g) < 0) {
            free(g->chol);
            g->chol = NULL;
        }
        if (g->chol) {
            const double *A = g->chol;
            for (int i = 0; i < N; i++) { /* L y = b */
                double s = b[i];
                for (int k = 0; k < i; k++)
                    s -= A[(size_t)i * N + k] * x[k];
                x[i] = s / A[(size_t)i * N + i];
            }
            for (int i = N - 1; i >= 0; i--) { /* L^T x = y */
                double s = x[i];
                for (int k = i + 1; k < N; k++)
                    s -= A[(size_t)k * N + i] * x[k];
                x[i] = s / A[(size_t)i * N + i];
            }
            for (int i = 0; i < g->n; i++)
                for (int r = 0; r < 3; r++)
                    if (g->L->model.fixed[i] & (1u << r))
                        x[3 * i + r] = 0;
            return;
        }
    }
    const size_t n3 = 3 * (size_t)g->n;
    double *r = g->r, *z = g->t;
    double *p = sq_malloc(sizeof(double) * n3), *q = sq_malloc(sizeof(double) * n3);
    memset(x, 0, sizeof(double) * n3);
    memcpy(r, b, sizeof(double) * n3);
    double bn = sqrt(dot(b, b, n3));
    block_apply(g->dinv, g->n, r, z);
    memcpy(p, z, sizeof(double) * n3);
    double rz = dot(r, z, n3);
    for (int it = 0; it < 40 && bn > 0 && sqrt(dot(r, r, n3)) > 1e-3 * bn; it++) {
        coarse_apply(o, g, p, q);
        double pq = dot(p, q, n3);
        if (!(pq > 0))
            break;
        double al = rz / pq;
        for (size_t k = 0; k < n3; k++) {
            x[k] += al * p[k];
            r[k] -= al * q[k];
        }
        block_apply(g->dinv, g->n, r, z);
        double rz2 = dot(r, z, n3);
        for (size_t k = 0; k < n3; k++)
            p[k] = z[k] + (rz2 / rz) * p[k];
        rz = rz2;
    }
    free(p);
    free(q);
}

/* V-cycle at level j: x ~ A_j^-1 b (SQ_MG_SWEEPS pre- and post-smoothing sweeps) */
#define SQ_MG_SWEEPS 2
static __attribute__((noinline)) void vcycle(const imp_op *o, int j, const double *b, double *x)
{
    sq_implicit *I = (sq_implicit *)o->I;
    if (j >= I->nmg || j >= SQ_MAX_LEVELS - 1) {
        coarsest_solve(o, &I->mg[SQ_MAX(I->nmg, 1) - 1], b, x); /* nmg >= 1 here */
        return;
    }
    const int n = cyc_n(I, j);
    const size_t n3 = 3 * (size_t)n;
    double *r = j ? I->mg[j - 1].r : I->vr, *t = j ? I->mg[j - 1].t : I->vt;
    const double omega = j ? I->mg[j - 1].omega : I->omega0;
    /* pre-smoothing from x = 0: the first sweep is x = omega D^-1 b (no product) */
    block_apply(cyc_dinv(I, j), n, b, x);
    for (size_t k = 0; k < n3; k++)
        x[k] *= omega;
    for (int s = 1; s < SQ_MG_SWEEPS; s++)
        cyc_smooth(o, j, omega, b, x, r, t);
    cyc_apply(o, j, x, t);
    for (size_t k = 0; k < n3; k++)
        r[k] = b[k] - t[k];
    /* restrict to level j + 1 (coarse level mg[j]): b_c = P^T r, constrained axes zeroed */
    mg_level *c = &I->mg[j];
    memset(c->b, 0, sizeof(double) * 3 * (size_t)c->n);
    const int *tets = c->L->model.mesh->tets;
    for (int i = 0; i < n; i++) {
        const int *tv = tets + 4 * (size_t)c->tet[i];
        const double *w = c->bary + 4 * (size_t)i;
        for (int k = 0; k < 4; k++)
            for (int q = 0; q < 3; q++)
                c->b[3 * (size_t)tv[k] + q] += w[k] * r[3 * (size_t)i + q];
    }
    for (int i = 0; i < c->n; i++)
        for (int q = 0; q < 3; q++)
            if (c->L->model.fixed[i] & (1u << q))
                c->b[3 * (size_t)i + q] = 0;
    vcycle(o, j + 1, c->b, c->x);
    /* prolongate and correct: x += P x_c, then this level's projection */
    for (int i = 0; i < n; i++) {
        const int *tv = tets + 4 * (size_t)c->tet[i];
        const double *w = c->bary + 4 * (size_t)i;
        for (int q = 0; q < 3; q++) {
            double e = 0;
            for (int k = 0; k < 4; k++)
                e += w[k] * c->x[3 * (size_t)tv[k] + q];
            t[3 * (size_t)i + q] = e;
        }
    }
    if (j == 0)
        project(I, t);
    else
        for (int i = 0; i < n; i++)
            for (int q = 0; q < 3; q++)
                if (I->mg[j - 1].L->model.fixed[i] & (1u << q))
                    t[3 * (size_t)i + q] = 0;
    for (size_t k = 0; k < n3; k++)
        x[k] += t[k];
    for (int s = 0; s < SQ_MG_SWEEPS; s++)
        cyc_smooth(o, j, omega, b, x, r, t);
}

/* the preconditioner's data for this solve */
static void precond_setup(const imp_op *o, int kind)
{
    const sq_level_model *M = &o->L->model;
    sq_implicit *I = (sq_implicit *)o->I;
    double *blk = sq_malloc(sizeof(double) * 9 * (size_t)M->n);
    diag_blocks(o, M, o->L->corot ? I->kup_r : NULL, blk);
    for (int i = 0; i < M->n; i++) {
        const double *B = blk + 9 * (size_t)i;
        double *out = I->pre + 9 * (size_t)i;
        unsigned fa = I->freeax[i];
        if (kind != SQ_PRECOND_JACOBI) {
            if (!inv3_free(B, fa, out)) { /* singular block: fall back to its diagonal */
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
            coarse_dinv(o, &I->mg[j]);
        /* the smoothers' dampings: estimated again when the coefficients change, or every 64
         * solves (the corotational operator turns with the body) */
        if (o->cm != I->omega_cm || o->ck != I->omega_ck || I->omega_age++ >= 64) {
            I->omega0 = 1.0 / cyc_lambda(o, 0, I->vx, I->vr, I->vt);
            for (int j = 0; j < I->nmg; j++)
                I->mg[j].omega = 1.0 / cyc_lambda(o, j + 1, I->mg[j].x, I->mg[j].r, I->mg[j].t);
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
        vcycle(o, 0, r, z);
        project(I, z);
    } else if (kind != SQ_PRECOND_JACOBI) {
        block_apply(I->pre, I->n, r, z);
    } else {
        for (int i = 0; i < I->n; i++)
            for (int c = 0; c < 3; c++)
                z[3 * i + c] = I->pre[9 * (size_t)i + c] * r[3 * i + c];
    }
    if (I->ncuse) /* S B^-1 S: symmetric, positive on the contacts' free subspace */
        project(I, z);
}

int sq_level_implicit_set_coarse(sq_level *L, const sq_level *const *coarse, int ncoarse)
{
    sq_implicit *I = imp_get(L);
    if (ncoarse > SQ_MAX_LEVELS - 1)
        ncoarse = SQ_MAX_LEVELS - 1;
    /* the same hierarchy as already built: nothing to do */
    int same = I->nmg == ncoarse;
    for (int j = 0; same && j < ncoarse; j++)
        same = I->mg[j].L == coarse[j] && I->mg[j].n == coarse[j]->model.n;
    if (same)
        return ncoarse;
    mg_free(I);
    const sq_mesh *fine = L->model.mesh;
    for (int j = 0; j < ncoarse; j++) {
        mg_level *g = &I->mg[j];
        memset(g, 0, sizeof *g);
        g->L = coarse[j];
        g->n = coarse[j]->model.n;
        size_t n3 = 3 * (size_t)g->n;
        g->x = imp_calloc(n3 + 1, sizeof(double));
        g->b = imp_calloc(n3 + 1, sizeof(double));
        g->r = imp_calloc(n3 + 1, sizeof(double));
        g->t = imp_calloc(n3 + 1, sizeof(double));
        g->acc = imp_calloc(n3 + 1, sizeof(double));
        g->dinv = imp_calloc(3 * n3, sizeof(double));
        g->nfine = fine->nnodes;
        g->tet = imp_calloc((size_t)g->nfine, sizeof(int));
        g->bary = imp_calloc(4 * (size_t)g->nfine, sizeof(double));
        for (int i = 0; i < g->nfine; i++)
            g->tet[i] = sq_mesh_locate(coarse[j]->model.mesh, fine->x + 3 * (size_t)i, g->bary + 4 * (size_t)i);
        fine = coarse[j]->model.mesh;
        I->nmg = j + 1;
    }
    I->omega_cm = I->omega_ck = -1;
    return I->nmg;
}

static double dot(const double *a, const double *b, size_t n)
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
    const double bnorm = sqrt(dot(b, b, n3));
    *relres = 0;
    *capped = 0;
    if (!(bnorm > 0)) {
        memset(x, 0, sizeof(double) * n3);
        return 0;
    }
    if (warm) { /* from the given x: r = b - A x */
        apply_a(o, x, q);
        for (size_t k = 0; k < n3; k++)
            r[k] = b[k] - q[k];
    } else {
        memset(x, 0, sizeof(double) * n3);
        memcpy(r, b, sizeof(double) * n3);
    }
    precond_apply(o, precond, r, z);
    memcpy(p, z, sizeof(double) * n3);
    memcpy(I->zo, z, sizeof(double) * n3);
    double rz = dot(r, z, n3), rr = dot(r, r, n3);
    int it = 0;
    while (sqrt(rr) > def->tol * bnorm) {
        if (it >= max_iter || (deadline > 0 && (it & 3) == 3 && sq_thread_cpu() > deadline)) {
            *capped = 1;
            break;
        }
        apply_a(o, p, q);
        const double pq = dot(p, q, n3);
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
        const double rz2 = dot(r, z, n3);
        rr = dot(r, r, n3);
        /* flexible (Polak-Ribiere) beta: the multigrid cycle is not a fixed linear map (its
         * coarsest solve stops early); for the fixed preconditioners it equals the usual one up
         * to round-off (r.z_old = 0 in exact arithmetic) */
        double beta = rz2 / rz;
        if (precond == SQ_PRECOND_MULTIGRID)
            beta = (rz2 - dot(r, I->zo, n3)) / rz;
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

/* the force of the current state into L->f (corotational: rotations converged and stored) */
static void forces_now(sq_level *L, const sq_material *mat, const double g[3])
{
    if (L->corot)
        corot_linearise(L);
    sq_level_forces(L, mat, g, NULL);
}

/* FNV-1a over the bits of d, v and g: equal exactly when the state is the same */
static unsigned long long state_hash(const sq_level *L, const double g[3])
{
    unsigned long long h = 1469598103934665603ull;
    const size_t n3 = 3 * (size_t)L->model.n;
    const double *arr[3] = {L->d, L->v, g};
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
static double total_energy(const sq_level *L, const double g[3])
{
    const sq_level_model *M = &L->model;
    double e = sq_level_elastic_energy(L);
    for (int i = 0; i < M->n; i++) {
        const double *v = L->v + 3 * (size_t)i, *d = L->d + 3 * (size_t)i;
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

void sq_level_implicit_step(sq_level *L, const sq_material *mat, const double g[3], double h,
                            const unsigned char *mask, const sq_implicit_def *def, double deadline,
                            sq_implicit_stats *st)
{
    sq_implicit *I = imp_get(L);
    const sq_level_model *M = &L->model;
    const int n = M->n;
    const size_t n3 = 3 * (size_t)n;
    for (int i = 0; i < n; i++)
        I->freeax[i] = (mask && !mask[i]) ? 0 : (unsigned char)(~M->fixed[i] & 7u);
    contacts_begin(I);
    /* c_d: the viscosity blocks (linear operators; corotational viscosity is applied from the
     * step's start, not in the operator: docs/physics.md); stiffness damping b with Rayleigh */
    const int visc = mat->use_viscosity != 0;
    imp_op o = {.L = L, .I = I, .cm = 1 + h * mat->rayleigh_mass,
                .ck = h * h + (visc ? 0 : h * mat->rayleigh_stiffness), .cd = visc && M->D && !L->corot ? h : 0};
    memcpy(I->d0, L->d, sizeof(double) * n3);
    memcpy(I->v0, L->v, sizeof(double) * n3);
    /* corotational without holds: the start energy, for the Newton iterations' energy guard */
    const int e0_known = L->corot && !mask;
    double e0 = 0;
    if (e0_known)
        e0 = I->e_valid && I->e_hash == state_hash(L, g) ? I->e_cache : total_energy(L, g);
    I->e_valid = 0;

    /* f0 at the step's start (corotational: the rotations of the linearisation) */
    forces_now(L, mat, g);
    /* rhs = h P (f0 - h K w), w = P v0 + H u: the free nodes' velocities and the held nodes'
     * prescribed ones u (their displacement advances by h u in the step: a tool's motion enters
     * the solve as a known increment, not as a jump of the start state) */
    for (int i = 0; i < n; i++) {
        unsigned fx = M->fixed[i];
        for (int c = 0; c < 3; c++)
            I->x[3 * i + c] = (fx & (1u << c)) ? 0 : L->v[3 * i + c];
    }
    apply_k(&o, I->x, I->kv);
    for (size_t k = 0; k < n3; k++)
        I->rhs[k] = h * (L->f[k] - h * I->kv[k]);
    if (I->ncuse) /* the contacts' forces (kinetic friction) */
        for (int k = 0; k < I->cc->n; k++)
            if (I->cuse[k])
                for (int c = 0; c < 3; c++)
                    I->rhs[3 * (size_t)I->cc->node[k] + c] += h * I->cc->force[3 * (size_t)k + c];
    project(I, I->rhs);
    if (I->ncuse) { /* the contacts' prescribed part z of dv: rhs -= P A z (the solve adds z) */
        if (!I->zc)
            I->zc = imp_calloc(n3 + 1, sizeof(double));
        memset(I->zc, 0, sizeof(double) * n3);
        for (int k = 0; k < I->cc->n; k++)
            if (I->cuse[k]) {
                const double *nk = I->cc->normal + 3 * (size_t)k, *uk = I->cc->u + 3 * (size_t)k;
                const size_t i3 = 3 * (size_t)I->cc->node[k];
                double rel[3] = {uk[0] - L->v[i3], uk[1] - L->v[i3 + 1], uk[2] - L->v[i3 + 2]};
                const double s = rel[0] * nk[0] + rel[1] * nk[1] + rel[2] * nk[2];
                for (int c = 0; c < 3; c++)
                    I->zc[i3 + c] = I->cc->stick[k] ? rel[c] : s * nk[c];
            }
        apply_a(&o, I->zc, I->kv);
        for (size_t k = 0; k < n3; k++)
            I->rhs[k] -= I->kv[k];
    }
    double rhs0 = sqrt(dot(I->rhs, I->rhs, n3));
    /* held nodes move first: d += h u on their unconstrained axes */
    if (mask)
        for (int i = 0; i < n; i++)
            if (!mask[i])
                for (int c = 0; c < 3; c++)
                    if (!(M->fixed[i] & (1u << c)))
                        L->d[3 * i + c] += h * L->v[3 * i + c];

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
            project(I, I->x);
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
                    L->v[k] = I->v0[k] + I->dv[k];
                    L->d[k] = I->d0[k] + h * L->v[k];
                }
            }
        }
        st->newton = nt + 1;
        if (!L->corot)
            break; /* linear (and nodal-pressure) bodies: the one solve is the step */
        /* corotational: the Newton iterations asked for, and more (up to the maximum) while the
         * energy of a body no tool holds is above the step's start: the warped stiffness is not
         * the exact tangent, so one iteration alone may add energy; converged, backward Euler
         * cannot (a solve stopped by its cap is reported instead: more iterations of it would
         * not be converged either) */
        int more = nt + 1 < def->newton;
        if (!more && e0_known && !capped && nt + 1 < SQ_IMPLICIT_MAX_NEWTON) {
            const double e1 = total_energy(L, g);
            more = e1 > e0 + 1e-12 * fabs(e0);
            if (!more) { /* the next step's start energy, if nothing changes the state */
                I->e_cache = e1;
                I->e_hash = state_hash(L, g);
                I->e_valid = 1;
            }
        }
        if (more || def->newton > 1) {
            /* Newton residual P (h f(d1, v1) - M dv), re-linearised at the new state */
            forces_now(L, mat, g);
            for (int i = 0; i < n; i++)
                for (int c = 0; c < 3; c++) {
                    size_t k = 3 * (size_t)i + c;
                    I->rhs[k] = h * L->f[k] - M->mass[i] * I->dv[k];
                }
            project(I, I->rhs);
            st->newton_residual = rhs0 > 0 ? sqrt(dot(I->rhs, I->rhs, n3)) / rhs0 : 0;
            if (st->newton_residual <= def->tol)
                more = 0;
        }
        if (!more)
            break;
    }
    memcpy(I->dvprev, I->dv, sizeof(double) * n3);
    I->have_prev = 1;
    if (I->ncuse) { /* the constraints' impulses: M (v1 - v0) - h f(end state) */
        forces_now(L, mat, g);
        for (int k = 0; k < I->cc->n; k++)
            if (I->cuse[k]) {
                const int i = I->cc->node[k];
                for (int c = 0; c < 3; c++) {
                    const size_t j = 3 * (size_t)i + c;
                    I->cc->impulse[3 * (size_t)k + c] = M->mass[i] * (L->v[j] - I->v0[j]) - h * L->f[j];
                }
            }
    }
    /* L->f holds the last force pass's values (the step's start, or with Newton iterations an
     * intermediate state): the caller evaluates the end state's force when it needs it */
}
