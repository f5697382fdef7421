/* implicit_mg.c - the implicit solve's multigrid preconditioner: one V-cycle over the body's
 * coarser levels (each fine node located in the coarser rest mesh; barycentric prolongation,
 * its transpose restricting), damped block-Jacobi smoothing, and a dense Cholesky solve or a
 * few CG iterations on the coarsest level. docs/physics.md section 12.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "level/implicit_impl.h"
#include "level/level.h"

void sq_imp_mg_free(sq_implicit *I)
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

/* inverse diagonal blocks of c_m M + c_k K + c_d D of a coarse level (linear K), constrained
 * axes zeroed */
void sq_imp_coarse_dinv(const imp_op *o, mg_level *g)
{
    const sq_level_model *M = g->M;
    sq_imp_diag_blocks(o, M, NULL, g->dinv);
    for (int i = 0; i < M->n; i++) {
        double B[9];
        memcpy(B, g->dinv + 9 * (size_t)i, sizeof B);
        if (!sq_imp_inv3_free(B, ~M->fixed[i] & 7u, g->dinv + 9 * (size_t)i))
            memset(g->dinv + 9 * (size_t)i, 0, 9 * sizeof(double));
    }
}

/* y = (c_m M + c_k K + c_d D) x on coarse level g, constrained axes zeroed */
static void coarse_apply(const imp_op *o, const mg_level *g, const double *x, double *y)
{
    const sq_level_model *M = g->M;
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
        sq_imp_apply_a(o, x, y);
    else
        coarse_apply(o, &o->I->mg[j - 1], x, y);
}

static const double *cyc_dinv(const sq_implicit *I, int j) { return j ? I->mg[j - 1].dinv : I->pre; }

/* largest eigenvalue of D^-1 A at cycle level j, by 12 power iterations from a fixed rough
 * start (deterministic), times 1.25 for the power method's underestimate */
double sq_imp_cyc_lambda(const imp_op *o, int j, double *x, double *y, double *z)
{
    const sq_implicit *I = o->I;
    const int n = cyc_n(I, j);
    const size_t n3 = 3 * (size_t)n;
    /* a rough start (signs from a hash of the index): the top of D^-1 A is the roughest mode */
    for (size_t k = 0; k < n3; k++)
        x[k] = (((k * 2654435761u) >> 7) & 1) ? 1.0 : -1.0;
    double lam = 1;
    for (int it = 0; it < 12; it++) {
        sq_imp_block_apply(cyc_dinv(I, j), n, x, z);
        double zn = sqrt(sq_imp_dot(z, z, n3));
        if (!(zn > 0))
            return 1;
        for (size_t k = 0; k < n3; k++)
            z[k] /= zn;
        cyc_apply(o, j, z, y);
        sq_imp_block_apply(cyc_dinv(I, j), n, y, x); /* x = D^-1 A z */
        lam = sq_imp_dot(z, x, n3);
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
    sq_imp_block_apply(cyc_dinv(I, j), n, r, t);
    for (size_t k = 0; k < n3; k++)
        x[k] += omega * t[k];
}

/* the coarsest level's dense factor: its matrix with constrained rows and columns as identity,
 * Cholesky-factored in place (lower triangle); 0, or -1 if not positive definite */
#define SQ_MG_DENSE 2400
static int coarse_factor(const imp_op *o, mg_level *g)
{
    const sq_level_model *M = g->M;
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
                    if (g->M->fixed[i] & (1u << r))
                        x[3 * i + r] = 0;
            return;
        }
    }
    const size_t n3 = 3 * (size_t)g->n;
    double *r = g->r, *z = g->t;
    double *p = sq_malloc(sizeof(double) * n3), *q = sq_malloc(sizeof(double) * n3);
    memset(x, 0, sizeof(double) * n3);
    memcpy(r, b, sizeof(double) * n3);
    double bn = sqrt(sq_imp_dot(b, b, n3));
    sq_imp_block_apply(g->dinv, g->n, r, z);
    memcpy(p, z, sizeof(double) * n3);
    double rz = sq_imp_dot(r, z, n3);
    for (int it = 0; it < 40 && bn > 0 && sqrt(sq_imp_dot(r, r, n3)) > 1e-3 * bn; it++) {
        coarse_apply(o, g, p, q);
        double pq = sq_imp_dot(p, q, n3);
        if (!(pq > 0))
            break;
        double al = rz / pq;
        for (size_t k = 0; k < n3; k++) {
            x[k] += al * p[k];
            r[k] -= al * q[k];
        }
        sq_imp_block_apply(g->dinv, g->n, r, z);
        double rz2 = sq_imp_dot(r, z, n3);
        for (size_t k = 0; k < n3; k++)
            p[k] = z[k] + (rz2 / rz) * p[k];
        rz = rz2;
    }
    free(p);
    free(q);
}

/* V-cycle at level j: x ~ A_j^-1 b (SQ_MG_SWEEPS pre- and post-smoothing sweeps) */
#define SQ_MG_SWEEPS 2
__attribute__((noinline)) void sq_imp_vcycle(const imp_op *o, int j, const double *b, double *x)
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
    sq_imp_block_apply(cyc_dinv(I, j), n, b, x);
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
    const int *tets = c->M->mesh->tets;
    for (int i = 0; i < n; i++) {
        const int *tv = tets + 4 * (size_t)c->tet[i];
        const double *w = c->bary + 4 * (size_t)i;
        for (int k = 0; k < 4; k++)
            for (int q = 0; q < 3; q++)
                c->b[3 * (size_t)tv[k] + q] += w[k] * r[3 * (size_t)i + q];
    }
    for (int i = 0; i < c->n; i++)
        for (int q = 0; q < 3; q++)
            if (c->M->fixed[i] & (1u << q))
                c->b[3 * (size_t)i + q] = 0;
    sq_imp_vcycle(o, j + 1, c->b, c->x);
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
        sq_imp_project(I, t);
    else
        for (int i = 0; i < n; i++)
            for (int q = 0; q < 3; q++)
                if (I->mg[j - 1].M->fixed[i] & (1u << q))
                    t[3 * (size_t)i + q] = 0;
    for (size_t k = 0; k < n3; k++)
        x[k] += t[k];
    for (int s = 0; s < SQ_MG_SWEEPS; s++)
        cyc_smooth(o, j, omega, b, x, r, t);
}

int sq_level_implicit_set_coarse(const sq_level_model *M, sq_level_state *S, const sq_level_model *const *coarse,
                                 int ncoarse)
{
    sq_implicit *I = sq_imp_get(M, S);
    if (ncoarse > SQ_MAX_LEVELS - 1)
        ncoarse = SQ_MAX_LEVELS - 1;
    /* the same hierarchy as already built: nothing to do */
    int same = I->nmg == ncoarse;
    for (int j = 0; same && j < ncoarse; j++)
        same = I->mg[j].M == coarse[j] && I->mg[j].n == coarse[j]->n;
    if (same)
        return ncoarse;
    sq_imp_mg_free(I);
    const sq_mesh *fine = M->mesh;
    for (int j = 0; j < ncoarse; j++) {
        mg_level *g = &I->mg[j];
        memset(g, 0, sizeof *g);
        g->M = coarse[j];
        g->n = coarse[j]->n;
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
            g->tet[i] = sq_mesh_locate(coarse[j]->mesh, fine->x + 3 * (size_t)i, g->bary + 4 * (size_t)i);
        fine = coarse[j]->mesh;
        I->nmg = j + 1;
    }
    I->omega_cm = I->omega_ck = -1;
    return I->nmg;
}
