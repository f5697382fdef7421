/* anp.c - average nodal pressure tets, and the same with face-smoothed deviatoric strain
 * (docs/physics.md section 10): the fem operator on the same nodes and tets (fixed mode, linear).
 *
 * Nodal pressure ("pressure": "nodal", mode SQ_PRESSURE_NODAL): energy
 *     sum_T V_T mu |dev eps_T|^2 + sum_i (kappa/2) W_i theta_i^2,
 * kappa = lambda + 2 mu / 3, W_i the nodal volume, theta_i = sum_{T ni i} (V_T / 4) tr(eps_T) / W_i;
 * a tet's pressure is kappa times the mean theta of its nodes.
 *
 * Smoothed ("pressure": "smoothed", mode SQ_PRESSURE_SMOOTHED; selective face-based smoothed FEM,
 * FS-FEM-T4 for the deviatoric part and node-based smoothing for the volumetric part, after
 * Nguyen-Thoi, Liu et al. 2009): the deviatoric strain is averaged over face domains. The domain
 * of face f is the two tets sharing it, each contributing a quarter of its volume (the sub-tet
 * of the face and the tet's centroid), one tet for a boundary face; eps_f = sum_{T ni f} V_T
 * eps_T / sum_{T ni f} V_T, W_f = sum_{T ni f} V_T / 4 (every tet's volume is shared out over its
 * four faces). Energy
 *     sum_f W_f mu |dev eps_f|^2 + sum_i (kappa/2) W_i theta_i^2.
 *
 * Both are quadratic energies of the displacement, so the operators are symmetric; both are never
 * stiffer than the element-wise operator (the averaged strain's square is below the mean of the
 * squares: Jensen, for the face and the node averages alike), so that operator's Gershgorin bound
 * is safe for them (the default rule); the sharp rule's Lanczos estimate runs on their own
 * operator through sq_level_anp_apply (level.c, sq_level_lanczos_max_own), under that Gershgorin
 * ceiling. Forces are evaluated matrix-free: a
 * pass over the tets (gradients, nodal theta), a node pass, a pass over the tets (the face
 * averages, through each tet's four neighbours across its faces, and the stresses).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "level/level.h"

struct sq_anp {
    int mode;       /* SQ_PRESSURE_NODAL or SQ_PRESSURE_SMOOTHED */
    int ntets, n;
    double *grad;   /* per tet: a_0..a_3 (12) and V */
    int *nb;        /* smoothed: per tet, the tet across the face opposite corner k, -1 on the boundary (4) */
    double *wf;     /* smoothed: per tet, the weights of its face averages: V_o / (V + V_o) of the tet o
                       across face k (0 on the boundary), then sum_k V / (V + V_o) (1 for a boundary face) (5) */
    double *E;      /* smoothed: scratch deviatoric strain per tet, xx yy zz xy yz xz (6) */
    double *theta;  /* nodal volumetric strain scratch (n) */
    double *w;      /* scratch u = d + b v (3n) */
    double mu, kappa;
    /* the step's copy of the same data in blocks of four tets, lane-innermost (the passes of
     * anp_apply_blocked run four tets at once in vector lanes; the last block is padded with
     * tets of zero gradients and volume on node 0) */
    int nblk;
    int *btv;       /* corners: [blk][corner k][lane] (16) */
    double *bg;     /* gradients and volume: [blk][3k + c or 12][lane] (52) */
    int *bnb;       /* smoothed: face neighbours [blk][k][lane], the tet itself on the boundary (16) */
    double *bw;     /* smoothed: face weights [blk][k or 4][lane], 0 on the boundary (20) */
    double *bE;     /* smoothed: scratch deviatoric strain per tet, xx yy zz xy yz xz and 2 pad (8: one
                       cache line, gathered whole for each face neighbour) */
};

/* the four faces of a tet: corners other than k */
typedef struct {
    int v[3];
    int t, k;
} face_key;

static int face_cmp(const void *pa, const void *pb)
{
    const face_key *a = pa, *b = pb;
    for (int c = 0; c < 3; c++)
        if (a->v[c] != b->v[c])
            return a->v[c] < b->v[c] ? -1 : 1;
    return a->t < b->t ? -1 : a->t > b->t;
}

/* neighbours across faces: sort the 4 ntets faces by their sorted corners, pair equal ones */
static void tet_neighbours(const sq_mesh *m, int *nb)
{
    size_t nf = 4 * (size_t)m->ntets;
    face_key *f = sq_malloc(sizeof *f * nf);
    for (int t = 0; t < m->ntets; t++)
        for (int k = 0; k < 4; k++) {
            face_key *q = &f[4 * (size_t)t + k];
            int c = 0;
            for (int j = 0; j < 4; j++)
                if (j != k)
                    q->v[c++] = m->tets[4 * (size_t)t + j];
            for (int a = 0; a < 2; a++) /* sort three */
                for (int b = 0; b < 2 - a; b++)
                    if (q->v[b] > q->v[b + 1]) {
                        int s = q->v[b];
                        q->v[b] = q->v[b + 1];
                        q->v[b + 1] = s;
                    }
            q->t = t;
            q->k = k;
            nb[4 * (size_t)t + k] = -1;
        }
    qsort(f, nf, sizeof *f, face_cmp);
    for (size_t i = 0; i + 1 < nf; i++)
        if (!memcmp(f[i].v, f[i + 1].v, sizeof f[i].v)) {
            nb[4 * (size_t)f[i].t + f[i].k] = f[i + 1].t;
            nb[4 * (size_t)f[i + 1].t + f[i + 1].k] = f[i].t;
            i++;
        }
    free(f);
}

sq_anp *sq_anp_create(const sq_mesh *m, int n, int mode)
{
    sq_anp *A = sq_calloc(1, sizeof *A);
    A->mode = mode;
    A->ntets = m->ntets;
    A->n = n;
    A->grad = sq_malloc(sizeof(double) * 13 * (size_t)m->ntets);
    A->theta = sq_malloc(sizeof(double) * (size_t)n);
    A->w = sq_malloc(sizeof(double) * 3 * (size_t)n);
    for (int t = 0; t < m->ntets; t++) {
        double a[4][3];
        double V = sq_tet_gradients(m, t, a);
        for (int k = 0; k < 4; k++)
            for (int r = 0; r < 3; r++)
                A->grad[13 * (size_t)t + 3 * k + r] = a[k][r];
        A->grad[13 * (size_t)t + 12] = V;
    }
    if (mode == SQ_PRESSURE_SMOOTHED) {
        A->nb = sq_malloc(sizeof(int) * 4 * (size_t)m->ntets);
        A->wf = sq_malloc(sizeof(double) * 5 * (size_t)m->ntets);
        A->E = sq_malloc(sizeof(double) * 6 * (size_t)m->ntets);
        tet_neighbours(m, A->nb);
        for (int t = 0; t < m->ntets; t++) {
            const double V = A->grad[13 * (size_t)t + 12];
            double *w = A->wf + 5 * (size_t)t;
            w[4] = 0;
            for (int k = 0; k < 4; k++) {
                int o = A->nb[4 * (size_t)t + k];
                double Vo = o < 0 ? 0 : A->grad[13 * (size_t)o + 12];
                w[k] = Vo / (V + Vo);
                w[4] += V / (V + Vo);
            }
        }
    }
    /* the blocked copy */
    A->nblk = (m->ntets + 3) / 4;
    size_t nb4 = (size_t)A->nblk;
    A->btv = sq_calloc(16 * nb4, sizeof(int));
    A->bg = sq_calloc(52 * nb4, sizeof(double));
    for (int t = 0; t < m->ntets; t++) {
        size_t b = (size_t)t / 4;
        int l = t % 4;
        for (int k = 0; k < 4; k++)
            A->btv[16 * b + 4 * k + l] = m->tets[4 * (size_t)t + k];
        for (int q = 0; q < 13; q++)
            A->bg[52 * b + 4 * q + l] = A->grad[13 * (size_t)t + q];
    }
    if (mode == SQ_PRESSURE_SMOOTHED) {
        A->bnb = sq_calloc(16 * nb4, sizeof(int));
        A->bw = sq_calloc(20 * nb4, sizeof(double));
        /* 64-byte aligned: each tet's 8 values are one cache line */
        A->bE = aligned_alloc(64, 32 * nb4 * sizeof(double));
        if (!A->bE)
            A->bE = sq_malloc(32 * nb4 * sizeof(double)); /* unaligned is only slower */
        memset(A->bE, 0, 32 * nb4 * sizeof(double));       /* the 2 pad values are read, never written */
        for (int t = 0; t < m->ntets; t++) {
            size_t b = (size_t)t / 4;
            int l = t % 4;
            for (int k = 0; k < 4; k++) {
                int o = A->nb[4 * (size_t)t + k];
                A->bnb[16 * b + 4 * k + l] = o < 0 ? t : o;
            }
            for (int q = 0; q < 5; q++)
                A->bw[20 * b + 4 * q + l] = A->wf[5 * (size_t)t + q];
        }
    }
    return A;
}

void sq_anp_set_moduli(sq_anp *A, double mu, double lambda)
{
    A->mu = mu;
    A->kappa = lambda + 2.0 * mu / 3.0;
}

int sq_anp_mode(const sq_anp *A)
{
    return A->mode;
}

void sq_anp_destroy(sq_anp *A)
{
    if (!A)
        return;
    free(A->grad);
    free(A->nb);
    free(A->wf);
    free(A->E);
    free(A->theta);
    free(A->w);
    free(A->btv);
    free(A->bg);
    free(A->bnb);
    free(A->bw);
    free(A->bE);
    free(A);
}

/* y = K x (all nodes; vol: the nodal volumes W_i): the plain per-tet form, the reference the
 * static solve uses and the blocked step pass is checked against */
void sq_anp_apply(const sq_anp *A, const sq_mesh *m, const double *vol, const double *x, double *y)
{
    const double mu = A->mu, kappa = A->kappa;
    const int smooth = A->mode == SQ_PRESSURE_SMOOTHED;
    memset(A->theta, 0, sizeof(double) * (size_t)A->n);
    memset(y, 0, sizeof(double) * 3 * (size_t)A->n);
    for (int t = 0; t < m->ntets; t++) {
        const double *a = A->grad + 13 * (size_t)t;
        const int *tv = m->tets + 4 * (size_t)t;
        double th = 0;
        if (smooth) {
            double G[9] = {0};
            for (int k = 0; k < 4; k++)
                for (int r = 0; r < 3; r++)
                    for (int c = 0; c < 3; c++)
                        G[3 * r + c] += x[3 * tv[k] + r] * a[3 * k + c];
            th = G[0] + G[4] + G[8];
            double *E = A->E + 6 * (size_t)t; /* dev sym G: the face averages are linear in it */
            E[0] = G[0] - th / 3;
            E[1] = G[4] - th / 3;
            E[2] = G[8] - th / 3;
            E[3] = 0.5 * (G[1] + G[3]);
            E[4] = 0.5 * (G[5] + G[7]);
            E[5] = 0.5 * (G[2] + G[6]);
        } else {
            for (int k = 0; k < 4; k++)
                th += a[3 * k] * x[3 * tv[k]] + a[3 * k + 1] * x[3 * tv[k] + 1] + a[3 * k + 2] * x[3 * tv[k] + 2];
        }
        for (int k = 0; k < 4; k++)
            A->theta[tv[k]] += a[12] / 4 * th;
    }
    for (int i = 0; i < A->n; i++)
        A->theta[i] /= vol[i];
    for (int t = 0; t < m->ntets; t++) {
        const double *a = A->grad + 13 * (size_t)t;
        const int *tv = m->tets + 4 * (size_t)t;
        const double V = a[12];
        double G[9] = {0};
        double sig[9];
        const double tbar = 0.25 * (A->theta[tv[0]] + A->theta[tv[1]] + A->theta[tv[2]] + A->theta[tv[3]]);
        if (smooth) {
            /* deviatoric stress: sum over the tet's four face domains f of (V / 4) 2 mu dev eps_f,
             * dev eps_f = (V E_t + V_o E_o) / (V + V_o) (E_t alone on a boundary face) */
            const double *w = A->wf + 5 * (size_t)t, *Et = A->E + 6 * (size_t)t;
            const int *nb = A->nb + 4 * (size_t)t;
            double S[6];
            for (int q = 0; q < 6; q++)
                S[q] = w[4] * Et[q];
            for (int k = 0; k < 4; k++)
                if (nb[k] >= 0) {
                    const double *Eo = A->E + 6 * (size_t)nb[k];
                    for (int q = 0; q < 6; q++)
                        S[q] += w[k] * Eo[q];
                }
            const double hm = 0.5 * mu * V, p = V * kappa * tbar;
            sig[0] = hm * S[0] + p;
            sig[4] = hm * S[1] + p;
            sig[8] = hm * S[2] + p;
            sig[1] = sig[3] = hm * S[3];
            sig[5] = sig[7] = hm * S[4];
            sig[2] = sig[6] = hm * S[5];
        } else {
            for (int k = 0; k < 4; k++)
                for (int r = 0; r < 3; r++)
                    for (int c = 0; c < 3; c++)
                        G[3 * r + c] += x[3 * tv[k] + r] * a[3 * k + c];
            double tr = G[0] + G[4] + G[8];
            for (int r = 0; r < 3; r++)
                for (int c = 0; c < 3; c++)
                    sig[3 * r + c] = V * (mu * (G[3 * r + c] + G[3 * c + r]) +
                                          (r == c ? kappa * tbar - 2.0 * mu * tr / 3.0 : 0));
        }
        for (int k = 0; k < 4; k++)
            for (int r = 0; r < 3; r++)
                y[3 * tv[k] + r] += sig[3 * r] * a[3 * k] + sig[3 * r + 1] * a[3 * k + 1] + sig[3 * r + 2] * a[3 * k + 2];
    }
}

/* y = K x, the same operator as sq_anp_apply, four tets at once: every loop over `l` is a
 * vector of the four lanes (portable C the compiler vectorises; gathers and scatters scalar) */
static void anp_apply_blocked(const sq_anp *A, const double *vol, const double *x, double *y)
{
    const double mu = A->mu, kappa = A->kappa;
    const int smooth = A->mode == SQ_PRESSURE_SMOOTHED;
    double *theta = A->theta;
    memset(theta, 0, sizeof(double) * (size_t)A->n);
    memset(y, 0, sizeof(double) * 3 * (size_t)A->n);
    /* pass 1: volumetric strain to the nodes; smoothed: each tet's deviatoric strain */
    for (int b = 0; b < A->nblk; b++) {
        const int *tv = A->btv + 16 * (size_t)b;
        const double *g = A->bg + 52 * (size_t)b;
        double xl[12][4], th[4];
        for (int k = 0; k < 4; k++)
            for (int l = 0; l < 4; l++)
                for (int r = 0; r < 3; r++)
                    xl[3 * k + r][l] = x[3 * (size_t)tv[4 * k + l] + r];
        if (smooth) {
            double G[9][4];
            for (int r = 0; r < 3; r++)
                for (int c = 0; c < 3; c++)
                    for (int l = 0; l < 4; l++)
                        G[3 * r + c][l] = xl[r][l] * g[4 * c + l] + xl[3 + r][l] * g[4 * (3 + c) + l] +
                                          xl[6 + r][l] * g[4 * (6 + c) + l] + xl[9 + r][l] * g[4 * (9 + c) + l];
            double Eb[6][4];
            for (int l = 0; l < 4; l++) {
                th[l] = G[0][l] + G[4][l] + G[8][l];
                Eb[0][l] = G[0][l] - th[l] / 3;
                Eb[1][l] = G[4][l] - th[l] / 3;
                Eb[2][l] = G[8][l] - th[l] / 3;
                Eb[3][l] = 0.5 * (G[1][l] + G[3][l]);
                Eb[4][l] = 0.5 * (G[5][l] + G[7][l]);
                Eb[5][l] = 0.5 * (G[2][l] + G[6][l]);
            }
            double *E = A->bE + 32 * (size_t)b;
            for (int l = 0; l < 4; l++)
                for (int q = 0; q < 6; q++)
                    E[8 * l + q] = Eb[q][l];
        } else {
            for (int l = 0; l < 4; l++)
                th[l] = 0;
            for (int q = 0; q < 12; q++)
                for (int l = 0; l < 4; l++)
                    th[l] += xl[q][l] * g[4 * q + l];
        }
        for (int l = 0; l < 4; l++)
            th[l] *= 0.25 * g[48 + l];
        for (int k = 0; k < 4; k++)
            for (int l = 0; l < 4; l++)
                theta[tv[4 * k + l]] += th[l];
    }
    /* node pass: the nodal pressure kappa theta_i */
    for (int i = 0; i < A->n; i++)
        theta[i] = kappa * theta[i] / vol[i];
    /* pass 2: stresses and forces */
    for (int b = 0; b < A->nblk; b++) {
        const int *tv = A->btv + 16 * (size_t)b;
        const double *g = A->bg + 52 * (size_t)b;
        double sig[9][4], p[4];
        for (int l = 0; l < 4; l++)
            p[l] = 0.25 * g[48 + l] *
                   (theta[tv[l]] + theta[tv[4 + l]] + theta[tv[8 + l]] + theta[tv[12 + l]]); /* V kappa tbar */
        if (smooth) {
            const int *nb = A->bnb + 16 * (size_t)b;
            const double *w = A->bw + 20 * (size_t)b, *E = A->bE + 32 * (size_t)b;
            double S[6][4];
            for (int l = 0; l < 4; l++) {
                double Sl[8];
                for (int q = 0; q < 8; q++)
                    Sl[q] = w[16 + l] * E[8 * l + q];
                for (int k = 0; k < 4; k++) {
                    const double *Eo = A->bE + 8 * (size_t)nb[4 * k + l], wk = w[4 * k + l];
                    for (int q = 0; q < 8; q++)
                        Sl[q] += wk * Eo[q];
                }
                for (int q = 0; q < 6; q++)
                    S[q][l] = Sl[q];
            }
            for (int l = 0; l < 4; l++) {
                const double hm = 0.5 * mu * g[48 + l];
                sig[0][l] = hm * S[0][l] + p[l];
                sig[4][l] = hm * S[1][l] + p[l];
                sig[8][l] = hm * S[2][l] + p[l];
                sig[1][l] = sig[3][l] = hm * S[3][l];
                sig[5][l] = sig[7][l] = hm * S[4][l];
                sig[2][l] = sig[6][l] = hm * S[5][l];
            }
        } else {
            double xl[12][4], G[9][4];
            for (int k = 0; k < 4; k++)
                for (int l = 0; l < 4; l++)
                    for (int r = 0; r < 3; r++)
                        xl[3 * k + r][l] = x[3 * (size_t)tv[4 * k + l] + r];
            for (int r = 0; r < 3; r++)
                for (int c = 0; c < 3; c++)
                    for (int l = 0; l < 4; l++)
                        G[3 * r + c][l] = xl[r][l] * g[4 * c + l] + xl[3 + r][l] * g[4 * (3 + c) + l] +
                                          xl[6 + r][l] * g[4 * (6 + c) + l] + xl[9 + r][l] * g[4 * (9 + c) + l];
            for (int l = 0; l < 4; l++) {
                const double V = g[48 + l], tr = G[0][l] + G[4][l] + G[8][l];
                const double dg = p[l] - V * 2.0 * mu * tr / 3.0;
                for (int r = 0; r < 3; r++)
                    for (int c = 0; c < 3; c++)
                        sig[3 * r + c][l] = V * mu * (G[3 * r + c][l] + G[3 * c + r][l]) + (r == c ? dg : 0);
            }
        }
        double f[12][4];
        for (int k = 0; k < 4; k++)
            for (int r = 0; r < 3; r++)
                for (int l = 0; l < 4; l++)
                    f[3 * k + r][l] = sig[3 * r][l] * g[4 * (3 * k) + l] + sig[3 * r + 1][l] * g[4 * (3 * k + 1) + l] +
                                      sig[3 * r + 2][l] * g[4 * (3 * k + 2) + l];
        for (int k = 0; k < 4; k++)
            for (int l = 0; l < 4; l++)
                for (int r = 0; r < 3; r++)
                    y[3 * (size_t)tv[4 * k + l] + r] += f[3 * k + r][l];
    }
}

/* the step's form of y = K x (the blocked pass); exposed for the test against sq_anp_apply */
void sq_anp_apply_fast(const sq_anp *A, const double *vol, const double *x, double *y)
{
    anp_apply_blocked(A, vol, x, y);
}

int sq_level_anp_enable(sq_level *L, const sq_material *mat, sq_operator_kind op, int mode, sq_err *err)
{
    if (op != SQ_OPERATOR_FEM)
        return sq_err_set(err, "nodal pressure and smoothed tets need the fem operator: use \"operator\": \"fem\" "
                               "with \"pressure\": \"nodal\" or \"smoothed\", or \"pressure\": \"element\" with "
                               "the paper operator");
    if (mode != SQ_PRESSURE_NODAL && mode != SQ_PRESSURE_SMOOTHED)
        return sq_err_set(err, "pressure mode %d is unknown: use element, nodal or smoothed", mode);
    if (L->state.anp && L->state.anp->mode != mode)
        sq_level_anp_free(L);
    if (!L->state.anp)
        L->state.anp = sq_anp_create(L->model.mesh, L->model.n, mode);
    sq_level_op_update(L); /* corotational elasticity keeps its row */
    sq_anp_set_moduli(L->state.anp, mat->mu, mat->lambda);
    return 0;
}

void sq_level_anp_free(sq_level *L)
{
    sq_anp_destroy(L->state.anp);
    L->state.anp = NULL;
    sq_level_op_update(L);
}

void sq_level_anp_apply(const sq_level_model *M, const sq_level_state *S, const double *x, double *y)
{
    anp_apply_blocked(S->anp, M->vol, x, y);
}

void sq_level_anp_forces(const sq_level_model *M, const sq_level_state *S, const sq_material *mat, const double g[3],
                         double *f)
{
    sq_anp *A = S->anp;
    const double b = mat->use_viscosity ? 0 : mat->rayleigh_stiffness, a = mat->rayleigh_mass;
    size_t n3 = 3 * (size_t)M->n;
    for (size_t k = 0; k < n3; k++)
        A->w[k] = S->d[k] + b * S->v[k];
    sq_level_anp_apply(M, S, A->w, f); /* f = K_np (d + b v) */
    for (int i = 0; i < M->n; i++) {
        double *fi = f + 3 * (size_t)i;
        for (int c = 0; c < 3; c++)
            fi[c] = M->mass[i] * (g[c] - a * S->v[3 * i + c]) - fi[c];
        if (mat->use_viscosity && M->D) /* the paper's viscosities: the element-wise D blocks */
            for (int e = M->row_start[i]; e < M->row_start[i + 1]; e++) {
                const double *B = M->D + 9 * (size_t)e, *vj = S->v + 3 * (size_t)M->col[e];
                for (int r = 0; r < 3; r++)
                    fi[r] -= B[3 * r] * vj[0] + B[3 * r + 1] * vj[1] + B[3 * r + 2] * vj[2];
            }
    }
}

double sq_level_anp_energy(const sq_level_model *M, const sq_level_state *S)
{
    size_t n3 = 3 * (size_t)M->n;
    double *y = sq_malloc(sizeof(double) * n3), e = 0;
    sq_level_anp_apply(M, S, S->d, y);
    for (size_t k = 0; k < n3; k++)
        e += S->d[k] * y[k];
    free(y);
    return 0.5 * e;
}
