/* level.c - one level of detail: operator assembly, stability bound, forces, integration.
 *
 * The operator is a CSR matrix of 3x3 blocks over the mesh adjacency (diagonal included),
 * stored contiguously per row so the force pass streams through it once per step.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "level/level.h"

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#define SQ_LEVEL_AVX2 1
#endif

/* does constraint c select the rest point x? (eps: tolerance in metres) */
static int constraint_selects(const sq_constraint *c, const double *x, double eps)
{
    if (c->kind == SQ_REGION_BOX) {
        for (int k = 0; k < 3; k++)
            if (x[k] < c->a[k] - eps || x[k] > c->b[k] + eps)
                return 0;
        return 1;
    }
    double nn = sqrt(c->b[0] * c->b[0] + c->b[1] * c->b[1] + c->b[2] * c->b[2]);
    if (nn == 0)
        return 0;
    double s = 0;
    for (int k = 0; k < 3; k++)
        s += (x[k] - c->a[k]) * c->b[k];
    return s / nn <= eps;
}

/* assemble blocks of one operator into out (nnz x 9) with shear-like coefficient s and
 * volume-like coefficient l (mu, lambda for K; phi, psi for D) */
static int assemble(const sq_level *L, sq_operator_kind op, double s, double l, double *out,
                    double *lap, double *mass, double *vol, double density, sq_err *err)
{
    const sq_mesh *m = L->model.mesh;
    memset(out, 0, sizeof(double) * 9 * (size_t)L->model.nnz);
    if (lap)
        memset(lap, 0, sizeof(double) * (size_t)L->model.nnz);
    if (mass) {
        memset(mass, 0, sizeof(double) * (size_t)L->model.n);
        memset(vol, 0, sizeof(double) * (size_t)L->model.n);
    }
    for (int t = 0; t < m->ntets; t++) {
        double a[4][3];
        double V = sq_tet_gradients(m, t, a);
        if (!(V > 0) || !isfinite(V))
            return sq_err_set(err, "%s: tetrahedron %d has volume %g: the operator needs positively "
                                   "oriented, non-degenerate tets; repair the mesh", m->source, t, V);
        const int *tv = m->tets + 4 * t;
        for (int p = 0; p < 4; p++) {
            int i = tv[p];
            if (mass) {
                mass[i] += density * V / 4;
                vol[i] += V / 4;
            }
            for (int q = 0; q < 4; q++) {
                int j = tv[q];
                int e = sq_csr_find(L->model.row_start, L->model.col, i, j);
                if (e < 0)
                    return sq_err_set(err, "%s: nodes %d and %d share tetrahedron %d but are not "
                                           "adjacent in the mesh topology; re-finalize the mesh",
                                      m->source, i, j, t);
                const double *ai = a[p], *aj = a[q];
                double dot = ai[0] * aj[0] + ai[1] * aj[1] + ai[2] * aj[2];
                sq_level_tet_block(op, V, ai, aj, s, l, out + 9 * (size_t)e);
                if (lap)
                    lap[e] += V * dot;
            }
        }
    }
    return 0;
}

/* Gershgorin bound on the largest eigenvalue of M^-1 A over unconstrained rows */
static double gershgorin(const sq_level *L, const double *A)
{
    double best = 0;
    for (int i = 0; i < L->model.n; i++) {
        for (int r = 0; r < 3; r++) {
            if (L->model.fixed[i] & (1u << r))
                continue;
            double s = 0;
            for (int e = L->model.row_start[i]; e < L->model.row_start[i + 1]; e++) {
                int j = L->model.col[e];
                const double *B = A + 9 * (size_t)e + 3 * r;
                for (int c = 0; c < 3; c++)
                    if (!(L->model.fixed[j] & (1u << c)))
                        s += fabs(B[c]);
            }
            s /= L->model.mass[i];
            if (s > best)
                best = s;
        }
    }
    return best;
}

int sq_level_init(sq_level *L, const sq_mesh *mesh, const sq_material *mat, sq_operator_kind op,
                  const sq_constraint *cons, int ncons, sq_err *err)
{
    memset(L, 0, sizeof *L);
    if (!mesh || mesh->nnodes <= 0 || mesh->ntets <= 0 || !mesh->adj_start)
        return sq_err_set(err, "level mesh is empty or not finalized; load it with sq_mesh_load");
    L->model.mesh = mesh;
    L->model.n = mesh->nnodes;
    L->model.row_start = mesh->adj_start;
    L->model.col = mesh->adj;
    L->model.nnz = mesh->adj_start[mesh->nnodes];
    size_t n3 = 3 * (size_t)L->model.n;
    L->model.K = sq_malloc(sizeof(double) * 9 * (size_t)L->model.nnz);
    L->model.lap = sq_malloc(sizeof(double) * (size_t)L->model.nnz);
    L->model.mass = sq_malloc(sizeof(double) * (size_t)L->model.n);
    L->model.vol = sq_malloc(sizeof(double) * (size_t)L->model.n);
    L->model.hbar = sq_calloc((size_t)L->model.n, sizeof(double));
    L->model.fixed = sq_calloc((size_t)L->model.n, 1);
    /* one spare double after d, v and acc: the vector force pass loads 4 lanes per node */
    L->state.d = sq_calloc(n3 + 1, sizeof(double));
    L->state.v = sq_calloc(n3 + 1, sizeof(double));
    L->state.f = sq_calloc(n3, sizeof(double));
    L->state.acc = sq_calloc(n3 + 1, sizeof(double));

    /* fixed axes: a tolerance of 1e-9 of the bounding-box diagonal absorbs rounding */
    double diag = 0;
    for (int k = 0; k < 3; k++)
        diag += (mesh->bbox_max[k] - mesh->bbox_min[k]) * (mesh->bbox_max[k] - mesh->bbox_min[k]);
    double eps = 1e-9 * sqrt(diag);
    for (int i = 0; i < L->model.n; i++) {
        const double *x = mesh->x + 3 * (size_t)i;
        for (int c = 0; c < ncons; c++)
            if (constraint_selects(&cons[c], x, eps))
                L->model.fixed[i] |= (unsigned char)(cons[c].axes & 7u);
        if (L->model.fixed[i] != 7)
            L->model.nfree++;
    }

    /* mean 1-ring edge length */
    for (int i = 0; i < L->model.n; i++) {
        double s = 0;
        int cnt = 0;
        for (int e = L->model.row_start[i]; e < L->model.row_start[i + 1]; e++) {
            int j = L->model.col[e];
            if (j == i)
                continue;
            double dx = mesh->x[3 * j] - mesh->x[3 * i], dy = mesh->x[3 * j + 1] - mesh->x[3 * i + 1],
                   dz = mesh->x[3 * j + 2] - mesh->x[3 * i + 2];
            s += sqrt(dx * dx + dy * dy + dz * dz);
            cnt++;
        }
        L->model.hbar[i] = cnt ? s / cnt : 0;
    }

    if (sq_level_set_material(L, mat, op, err) < 0) {
        sq_level_free(L);
        return -1;
    }
    return 0;
}

void sq_level_init_shared(sq_level *L, const sq_level *src)
{
    memset(L, 0, sizeof *L);
    L->model = src->model;
    sq_level_op_update(L); /* the element models are not shared: linear until enabled */
    L->model_shared = 1;
    size_t n3 = 3 * (size_t)L->model.n;
    /* as sq_level_init: one spare double after d, v and acc */
    L->state.d = sq_calloc(n3 + 1, sizeof(double));
    L->state.v = sq_calloc(n3 + 1, sizeof(double));
    L->state.f = sq_calloc(n3, sizeof(double));
    L->state.acc = sq_calloc(n3 + 1, sizeof(double));
    L->omega_max = src->omega_max; /* sq_level_set_material's figure for this model */
}

void sq_level_free(sq_level *L)
{
    if (!L)
        return;
    if (!L->model_shared) {
        free(L->model.K);
        free(L->model.D);
        free(L->model.lap);
        free(L->model.mass);
        free(L->model.vol);
        free(L->model.hbar);
        free(L->model.fixed);
        free(L->model.up_start);
        free(L->model.up_col);
        free(L->model.Kup);
    }
    free(L->state.d);
    free(L->state.v);
    free(L->state.f);
    free(L->state.acc);
    sq_level_corot_free(L);
    sq_level_anp_free(L);
    sq_level_implicit_free(L);
    memset(L, 0, sizeof *L);
}

int sq_level_set_material(sq_level *L, const sq_material *mat, sq_operator_kind op, sq_err *err)
{
    if (L->model_shared) /* its blocks are another level's: make a new level instead (body/set.c) */
        return sq_err_set(err, "level shares its operator with another level: it cannot change its material");
    if (sq_material_check(mat, err) < 0)
        return -1;
    if (op != SQ_OPERATOR_FEM && op != SQ_OPERATOR_PAPER)
        return sq_err_set(err, "operator %d is unknown: use fem or paper", (int)op);
    if (assemble(L, op, mat->mu, mat->lambda, L->model.K, L->model.lap, L->model.mass, L->model.vol, mat->density, err) < 0)
        return -1;
    if (mat->use_viscosity) {
        if (!L->model.D)
            L->model.D = sq_malloc(sizeof(double) * 9 * (size_t)L->model.nnz);
        if (assemble(L, op, mat->phi, mat->psi, L->model.D, NULL, NULL, NULL, 0, err) < 0)
            return -1;
    } else {
        free(L->model.D);
        L->model.D = NULL;
    }
    /* upper-half copy for the fast force pass */
    if (!L->model.up_start) {
        L->model.up_start = sq_malloc(sizeof(int) * ((size_t)L->model.n + 1));
        int h = 0;
        for (int i = 0; i < L->model.n; i++)
            for (int e = L->model.row_start[i]; e < L->model.row_start[i + 1]; e++)
                h += L->model.col[e] > i;
        L->model.up_col = sq_malloc(sizeof(int) * (size_t)(h ? h : 1));
        L->model.Kup = sq_calloc(9 * (size_t)h + 4, sizeof(double)); /* + 4: 4-lane loads of the last block */
    }
    int h = 0;
    for (int i = 0; i < L->model.n; i++) {
        L->model.up_start[i] = h;
        for (int e = L->model.row_start[i]; e < L->model.row_start[i + 1]; e++)
            if (L->model.col[e] > i) {
                L->model.up_col[h] = L->model.col[e];
                memcpy(L->model.Kup + 9 * (size_t)h, L->model.K + 9 * (size_t)e, 9 * sizeof(double));
                h++;
            }
    }
    L->model.up_start[L->model.n] = h;
    L->omega_max = sqrt(gershgorin(L, L->model.K));
    return 0;
}

int sq_level_choose_step(sq_level *L, const sq_material *mat, double frame_dt, double step_fraction,
                         sq_err *err)
{
    if (!(frame_dt > 0) || !isfinite(frame_dt))
        return sq_err_set(err, "frame period %g s is out of range: give a frame rate > 0", frame_dt);
    if (!(step_fraction > 0 && step_fraction <= 1))
        return sq_err_set(err, "step_fraction %g is out of range: give 0 < step_fraction <= 1", step_fraction);
    double w = L->omega_max;
    /* damping rate of the fastest mode: c = a + b w^2 (Rayleigh) or a + lambda_max(M^-1 D) */
    double c = mat->rayleigh_mass;
    if (mat->use_viscosity && L->model.D)
        c += gershgorin(L, L->model.D);
    else
        c += mat->rayleigh_stiffness * w * w;
    /* symplectic Euler with damping is stable iff w^2 dt^2 + 2 c dt <= 4, i.e.
     * dt <= (-c + sqrt(c^2 + 4 w^2)) / w^2 = 4 / (c + sqrt(c^2 + 4 w^2)) (the second form keeps
     * its digits when c >> w and also covers w = 0) */
    double bound = (w > 0 || c > 0) ? 4.0 / (c + sqrt(c * c + 4 * w * w)) : INFINITY;
    L->bound = bound;
    int n = 0;
    while (frame_dt / ldexp(1.0, n) > step_fraction * bound) {
        n++;
        if (n > 20) {
            int need = n;
            while (frame_dt / ldexp(1.0, need) > step_fraction * bound && need < 1000)
                need++;
            return sq_err_set(err, "needs 2^%d substeps per frame at %.4g Hz (bound %.3g s); the "
                                   "limit is 2^20: lower the stiffness or damping, raise the density, "
                                   "or use a coarser mesh", need, 1.0 / frame_dt, bound);
        }
    }
    L->substeps_log2 = n;
    L->dt = frame_dt / ldexp(1.0, n);
    return 0;
}

/* y = M^-1/2 K M^-1/2 x over the unconstrained axes (constrained components of y are zero);
 * rm: sqrt of each node's mass (n), made once per estimate. The same products, quotients and
 * sums in the same order as dividing by sqrt(mass) in place, so the estimate is the same to the
 * bit; the square roots are not taken again per entry and per product (that was 1.3 s of the
 * 117,649-node box level's load) */
static void scaled_matvec(const sq_level *L, const double *rm, const double *x, double *y)
{
    /* the three rows of node i in three lanes: lane r adds B[r][c] x_jc / rm_j for c = 0, 1, 2
     * in that order, the scalar sums' order, so each lane is the scalar row to the bit */
    typedef double v4 __attribute__((vector_size(32)));
    const int *rs = L->model.row_start, *col = L->model.col;
    const double *K = L->model.K;
    for (int i = 0; i < L->model.n; i++) {
        unsigned fx = L->model.fixed[i];
        v4 s = {0, 0, 0, 0};
        if ((fx & 7u) != 7u)
            for (int e = rs[i]; e < rs[i + 1]; e++) {
                int j = col[e];
                const double *B = K + 9 * (size_t)e, *xj = x + 3 * j;
                v4 q = {rm[j], rm[j], rm[j], 1};
                v4 b0 = {B[0], B[3], B[6], 0}, b1 = {B[1], B[4], B[7], 0}, b2 = {B[2], B[5], B[8], 0};
                v4 x0 = {xj[0], xj[0], xj[0], 0}, x1 = {xj[1], xj[1], xj[1], 0}, x2 = {xj[2], xj[2], xj[2], 0};
                s += b0 * x0 / q;
                s += b1 * x1 / q;
                s += b2 * x2 / q;
            }
        for (int r = 0; r < 3; r++)
            y[3 * i + r] = (fx & (1u << r)) ? 0 : s[r] / rm[i];
    }
}

/* the same product with the level's own operator when it has one (pressure nodal or smoothed:
 * the step's matrix-free pass of level/anp.c; scratch: 3n doubles); the element-wise K otherwise */
static void scaled_matvec_own(const sq_level *L, const double *rm, const double *x, double *y, double *z)
{
    if (!L->state.anp) {
        scaled_matvec(L, rm, x, y);
        return;
    }
    for (int i = 0; i < L->model.n; i++)
        for (int r = 0; r < 3; r++)
            z[3 * i + r] = (L->model.fixed[i] & (1u << r)) ? 0 : x[3 * i + r] / rm[i];
    sq_level_anp_apply(&L->model, &L->state, z, y);
    for (int i = 0; i < L->model.n; i++)
        for (int r = 0; r < 3; r++)
            y[3 * i + r] = (L->model.fixed[i] & (1u << r)) ? 0 : y[3 * i + r] / rm[i];
}

int sq_level_tridiag_above(const double *alpha, const double *beta, int m, double x)
{
    double q = 1;
    int above = 0;
    for (int i = 0; i < m; i++) {
        q = alpha[i] - x - (i > 0 ? beta[i - 1] * beta[i - 1] / q : 0);
        if (q == 0)
            q = 1e-300;
        above += q > 0;
    }
    return above;
}

double sq_level_tridiag_max(const double *alpha, const double *beta, int m)
{
    double lo = INFINITY, hi = -INFINITY;
    for (int i = 0; i < m; i++) {
        double r = (i > 0 ? fabs(beta[i - 1]) : 0) + (i < m - 1 ? fabs(beta[i]) : 0);
        lo = fmin(lo, alpha[i] - r);
        hi = fmax(hi, alpha[i] + r);
    }
    for (int it = 0; it < 200 && hi - lo > 1e-15 * fmax(fabs(hi), fabs(lo)); it++) {
        double x = 0.5 * (lo + hi);
        if (sq_level_tridiag_above(alpha, beta, m, x) > 0)
            lo = x;
        else
            hi = x;
    }
    return hi;
}

int sq_level_lanczos_steps(const sq_lanczos_op *op, size_t n, double *Q, int keep, double *w, int iters,
                           double *alpha, double *beta, int *abandoned)
{
    double *q = Q, *qp = keep ? Q : Q + n, bprev = 0;
    int m = 0;
    if (abandoned)
        *abandoned = 0;
    for (int j = 0; j < iters; j++) {
        if (op->go && !op->go(op->ctx, j)) {
            if (abandoned)
                *abandoned = 1;
            break;
        }
        op->apply(op->ctx, q, w);
        double a = 0, b = 0;
        for (size_t i = 0; i < n; i++)
            a += w[i] * q[i];
        for (size_t i = 0; i < n; i++) {
            w[i] -= a * q[i] + (j > 0 ? bprev * qp[i] : 0);
            b += w[i] * w[i];
        }
        b = sqrt(b);
        alpha[m] = a;
        beta[m] = b;
        m++;
        if (!(b > 1e-12 * fabs(a)) || j + 1 == iters)
            break;
        if (op->stop && op->stop(op->ctx, alpha, beta, m))
            break;
        /* the next vector: the basis's next column, or the other of the two */
        double *next = keep ? Q + n * (size_t)(j + 1) : qp;
        for (size_t i = 0; i < n; i++)
            next[i] = w[i] / b;
        qp = q;
        q = next;
        bprev = b;
    }
    return m;
}

/* the product of lanczos_max: M^-1/2 K M^-1/2 x (own: the level's own operator) */
typedef struct lanczos_ctx {
    const sq_level *L;
    const double *rm;
    double *z; /* scratch of scaled_matvec_own, NULL: the element-wise K */
} lanczos_ctx;

static void lanczos_apply(void *ctx, const double *x, double *y)
{
    const lanczos_ctx *c = ctx;
    if (c->z)
        scaled_matvec_own(c->L, c->rm, x, y, c->z);
    else
        scaled_matvec(c->L, c->rm, x, y);
}

/* own: 0 the element-wise K, 1 the level's own operator (scaled_matvec_own) */
static double lanczos_max(const sq_level *L, int iters, int own)
{
    size_t n3 = 3 * (size_t)L->model.n;
    double *Q = sq_calloc(2 * n3 + 1, sizeof(double)), *q = Q,
           *w = sq_malloc((n3 + 1) * sizeof(double)), *z = own && L->state.anp ? sq_malloc(n3 * sizeof(double)) : NULL;
    double *alpha = sq_malloc(sizeof(double) * (size_t)(iters + 1)),
           *beta = sq_malloc(sizeof(double) * (size_t)(iters + 1)), *rm = sq_malloc(sizeof(double) * (size_t)SQ_MAX(L->model.n, 1));
    for (int i = 0; i < L->model.n; i++)
        rm[i] = sqrt(L->model.mass[i]);
    /* deterministic start on the free axes */
    unsigned long long st = 88172645463325252ULL;
    double nn = 0;
    for (size_t k = 0; k < n3; k++) {
        st ^= st << 13, st ^= st >> 7, st ^= st << 17;
        q[k] = (L->model.fixed[k / 3] & (1u << (k % 3))) ? 0 : 0.5 + (double)(st >> 11) / 9007199254740992.0;
        nn += q[k] * q[k];
    }
    double theta = 0;
    if (nn > 0) {
        for (size_t k = 0; k < n3; k++)
            q[k] /= sqrt(nn);
        lanczos_ctx c = {L, rm, z};
        sq_lanczos_op op = {lanczos_apply, NULL, NULL, &c};
        int m = sq_level_lanczos_steps(&op, n3, Q, 0, w, iters, alpha, beta, NULL);
        theta = sq_level_tridiag_max(alpha, beta, m);
        /* residual of the Ritz pair: beta_m |s_m|, s the eigenvector of T for theta (recurrence) */
        double s0 = 1, s1 = m > 1 ? (theta - alpha[0]) / beta[0] : 0, ns = 1 + s1 * s1, last = m > 1 ? s1 : s0;
        for (int i = 1; i + 1 < m; i++) {
            double s2 = ((theta - alpha[i]) * s1 - beta[i - 1] * s0) / beta[i];
            s0 = s1;
            s1 = s2;
            ns += s2 * s2;
            last = s2;
        }
        if (isfinite(ns) && ns > 0)
            theta += fabs(beta[m - 1]) * fabs(last) / sqrt(ns);
        else
            theta = INFINITY; /* let the ceiling decide */
    }
    free(Q);
    free(w);
    free(z);
    free(alpha);
    free(beta);
    free(rm);
    return theta;
}

double sq_level_lanczos_max(const sq_level *L, int iters)
{
    return lanczos_max(L, iters, 0);
}

double sq_level_lanczos_max_own(const sq_level *L, int iters)
{
    return lanczos_max(L, iters, 1);
}

int sq_level_choose_step_sharp(sq_level *L, const sq_material *mat, double frame_dt, double step_fraction,
                               int iters, sq_err *err)
{
    if (!(frame_dt > 0) || !isfinite(frame_dt))
        return sq_err_set(err, "frame period %g s is out of range: give a frame rate > 0", frame_dt);
    if (!(step_fraction > 0 && step_fraction <= 1))
        return sq_err_set(err, "step_fraction %g is out of range: give 0 < step_fraction <= 1", step_fraction);
    /* the estimate on the operator the step applies: with "pressure" nodal or smoothed (L->state.anp)
     * that operator, never stiffer than the element-wise K (docs/physics.md section 10), so the
     * element-wise Gershgorin bound stays a safe ceiling */
    double g2 = L->omega_max * L->omega_max, lz = sq_level_lanczos_max_own(L, iters);
    double w2 = fmin(g2, lz); /* Gershgorin is the ceiling */
    double w = sqrt(w2);
    double c = mat->rayleigh_mass;
    if (mat->use_viscosity && L->model.D)
        c += gershgorin(L, L->model.D);
    else
        c += mat->rayleigh_stiffness * w2;
    double bound = (w > 0 || c > 0) ? 4.0 / (c + sqrt(c * c + 4 * w2)) : INFINITY;
    double need = ceil(frame_dt / (step_fraction * bound) * (1 - 1e-12));
    if (!(need >= 1))
        need = 1;
    if (need > 1048576)
        return sq_err_set(err, "needs %.0f substeps per frame at %.4g Hz (bound %.3g s); the limit is 2^20 "
                               "(1048576): lower the stiffness or damping, raise the density, or use a coarser mesh",
                          need, 1.0 / frame_dt, bound);
    /* rounded up to a power of two, the rule of the Gershgorin step and of the adaptive levels
     * (lod/bound.c), so a fixed level and a level forced finest take the same substeps */
    int nsub = 1;
    while (nsub < need)
        nsub *= 2;
    L->omega_est = w;
    L->bound_sharp = bound;
    L->nsub = nsub;
    L->dt_fixed = frame_dt / L->nsub;
    return 0;
}

/* the hot loop: f_i = -sum_j K_ij w_j + m_i (g - a v_i), w = d + b v, for all nodes, from the
 * upper half of K, optionally fused with the symplectic Euler update (dt > 0).
 * With K_ii = -sum_{j != i} K_ij: f_i = sum_{j != i} K_ij (w_i - w_j), and each edge block
 * serves both ends (K_ji = K_ij^T): row i adds its part to f_i and scatters -K_ij^T (w_i - w_j)
 * into the accumulator of every j > i. When row i ends, every contribution to f_i is in (rows
 * k < i scattered theirs before), and no later row reads node i again (row k reads only
 * nodes >= k), so node i can be integrated right there: one pass over memory per step.
 * The accumulator is cleared as it is consumed, so it is all zeros between calls.
 * A translation gives exactly zero force (the differences are exactly zero). */
static inline __attribute__((always_inline)) void
forces_pass(const sq_level_model *M, double *restrict d, double *restrict v, double *restrict f,
            double *restrict acc, const int damp, const double b, const double a, const double g[3],
            const double dt, const unsigned char *restrict mask)
{
    const int n = M->n;
    const int *restrict us = M->up_start;
    const int *restrict uc = M->up_col;
    const double *restrict A = M->Kup;
    const double *restrict mass = M->mass;
    const unsigned char *restrict fixed = M->fixed;
    const double g0 = g[0], g1 = g[1], g2 = g[2];
    for (int i = 0; i < n; i++) {
        double wi0 = d[3 * i], wi1 = d[3 * i + 1], wi2 = d[3 * i + 2];
        if (damp) {
            wi0 += b * v[3 * i];
            wi1 += b * v[3 * i + 1];
            wi2 += b * v[3 * i + 2];
        }
        double f0 = acc[3 * i], f1 = acc[3 * i + 1], f2 = acc[3 * i + 2];
        acc[3 * i] = acc[3 * i + 1] = acc[3 * i + 2] = 0;
#ifdef SQ_LEVEL_AVX2
        /* 4-lane form (lane 3 unused): the rows of B times the difference, accumulated lane by
         * lane and summed at the end (K delta), and the rows scaled by its components (K^T
         * delta) for the neighbour; lane 3 of the neighbour's accumulator is never stored */
        {
            const __m256d wi = _mm256_setr_pd(wi0, wi1, wi2, 0);
            const __m256d bb = _mm256_set1_pd(b);
            __m256d s0 = _mm256_setzero_pd(), s1 = _mm256_setzero_pd(), s2 = _mm256_setzero_pd();
            for (int e = us[i]; e < us[i + 1]; e++) {
                const double *B = A + 9 * (size_t)e;
                const size_t j = 3 * (size_t)uc[e];
                __m256d wj = _mm256_loadu_pd(d + j);
                if (damp)
                    wj = _mm256_fmadd_pd(bb, _mm256_loadu_pd(v + j), wj);
                const __m256d dl = _mm256_sub_pd(wi, wj);
                const __m256d r0 = _mm256_loadu_pd(B), r1 = _mm256_loadu_pd(B + 3), r2 = _mm256_loadu_pd(B + 6);
                s0 = _mm256_fmadd_pd(r0, dl, s0);
                s1 = _mm256_fmadd_pd(r1, dl, s1);
                s2 = _mm256_fmadd_pd(r2, dl, s2);
                __m256d t = _mm256_mul_pd(r0, _mm256_permute4x64_pd(dl, 0x00));
                t = _mm256_fmadd_pd(r1, _mm256_permute4x64_pd(dl, 0x55), t);
                t = _mm256_fmadd_pd(r2, _mm256_permute4x64_pd(dl, 0xAA), t);
                const __m256d aj = _mm256_sub_pd(_mm256_loadu_pd(acc + j), t);
                _mm_storeu_pd(acc + j, _mm256_castpd256_pd128(aj));
                _mm_store_sd(acc + j + 2, _mm256_extractf128_pd(aj, 1));
            }
            double l0[4], l1[4], l2[4];
            _mm256_storeu_pd(l0, s0);
            _mm256_storeu_pd(l1, s1);
            _mm256_storeu_pd(l2, s2);
            f0 += l0[0] + l0[1] + l0[2];
            f1 += l1[0] + l1[1] + l1[2];
            f2 += l2[0] + l2[1] + l2[2];
        }
#else
        for (int e = us[i]; e < us[i + 1]; e++) {
            const double *restrict B = A + 9 * (size_t)e;
            const size_t j = 3 * (size_t)uc[e];
            double d0 = wi0 - d[j], d1 = wi1 - d[j + 1], d2 = wi2 - d[j + 2];
            if (damp) {
                d0 -= b * v[j];
                d1 -= b * v[j + 1];
                d2 -= b * v[j + 2];
            }
            /* explicit fma: -std=c11 turns off contraction of a * b + c */
            f0 += fma(B[0], d0, fma(B[1], d1, B[2] * d2));
            f1 += fma(B[3], d0, fma(B[4], d1, B[5] * d2));
            f2 += fma(B[6], d0, fma(B[7], d1, B[8] * d2));
            acc[j] -= fma(B[0], d0, fma(B[3], d1, B[6] * d2));
            acc[j + 1] -= fma(B[1], d0, fma(B[4], d1, B[7] * d2));
            acc[j + 2] -= fma(B[2], d0, fma(B[5], d1, B[8] * d2));
        }
#endif
        const double m = mass[i];
        f0 += m * (g0 - a * v[3 * i]);
        f1 += m * (g1 - a * v[3 * i + 1]);
        f2 += m * (g2 - a * v[3 * i + 2]);
        f[3 * i] = f0;
        f[3 * i + 1] = f1;
        f[3 * i + 2] = f2;
        if (dt > 0 && (!mask || mask[i]))
            sq_level_euler_node(v, d, i, dt / m, dt, f0, f1, f2, fixed[i]);
    }
}

/* the two specialisations (with and without stiffness damping); d and v are written only when
 * dt > 0 (the force-only callers pass a level's state through a cast: it is left as it is) */
static void forces_pass_damped(const sq_level_model *M, double *d, double *v, double *f, double *acc, double b,
                               double a, const double g[3], double dt, const unsigned char *mask)
{
    forces_pass(M, d, v, f, acc, 1, b, a, g, dt, mask);
}

static void forces_pass_plain(const sq_level_model *M, double *d, double *v, double *f, double *acc, double a,
                              const double g[3], double dt, const unsigned char *mask)
{
    forces_pass(M, d, v, f, acc, 0, 0, a, g, dt, mask);
}

static void forces_all(const sq_level_model *M, double *d, double *v, double *f, double *acc, double b, double a,
                       const double g[3], double dt, const unsigned char *mask)
{
    if (b != 0)
        forces_pass_damped(M, d, v, f, acc, b, a, g, dt, mask);
    else
        forces_pass_plain(M, d, v, f, acc, a, g, dt, mask);
}

void sq_level_neg_k(const sq_level_model *M, const double *x, double *y, double *acc)
{
    static const double zero[3] = {0, 0, 0};
    /* the force pass of displacement x, no velocity, mass, damping or gravity: y = -K x (x is
     * only read: dt = 0) */
    forces_all(M, (double *)x, (double *)x, y, acc, 0, 0, zero, 0, NULL);
}

/* ---- the linear row of the operator table ---- */

static void linear_step(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double gravity[3],
                        double dt,
                        const unsigned char *mask)
{
    if (mat->use_viscosity && M->D) {
        /* the viscosity blocks are applied row by row: two passes */
        sq_level_forces(M, S, mat, gravity, NULL);
        sq_level_integrate(M, S, dt, mask);
        return;
    }
    forces_all(M, S->d, S->v, S->f, S->acc, mat->rayleigh_stiffness, mat->rayleigh_mass, gravity, dt,
               mask);
}

static void linear_forces(const sq_level_model *M, const sq_level_state *S, const sq_material *mat,
                          const double gravity[3],
                          const unsigned char *active, double *f_out, double *acc)
{
    const int n = M->n;
    const double b = mat->use_viscosity ? 0 : mat->rayleigh_stiffness;
    const double a = mat->rayleigh_mass;
    const double *restrict d = S->d;
    const double *restrict v = S->v;
    double *restrict f = f_out;
    const double g0 = gravity[0], g1 = gravity[1], g2 = gravity[2];

    if (!active) {
        /* dt = 0: the pass writes f and acc only (d and v are read) */
        forces_all(M, (double *)d, (double *)v, f, acc, b, a, gravity, 0, NULL);
        if (M->D && mat->use_viscosity)
            for (int i = 0; i < n; i++)
                sq_level_row(M, M->D, v, i, f + 3 * (size_t)i);
        return;
    }
    /* masked: full rows of K for the active nodes only; d + b v formed per neighbour, so the
     * cost follows the active nodes, not the level's size */
    for (int i = 0; i < n; i++) {
        if (!active[i])
            continue;
        double *fi = f + 3 * (size_t)i;
        sq_level_node_force(M, d, v, a, b, g0, g1, g2, i, fi);
        if (M->D && mat->use_viscosity)
            sq_level_row(M, M->D, v, i, fi);
    }
}

/* 0.5 d.K d */
static double linear_energy(const sq_level_model *M, const sq_level_state *S)
{
    double e = 0;
    for (int i = 0; i < M->n; i++) {
        const double *di = S->d + 3 * (size_t)i;
        for (int p = M->row_start[i]; p < M->row_start[i + 1]; p++) {
            const double *B = M->K + 9 * (size_t)p, *dj = S->d + 3 * (size_t)M->col[p];
            for (int r = 0; r < 3; r++)
                e += di[r] * (B[3 * r] * dj[0] + B[3 * r + 1] * dj[1] + B[3 * r + 2] * dj[2]);
        }
    }
    return 0.5 * e;
}

/* ---- the element models' rows: their force passes are level/corot.c's and level/anp.c's ---- */

static void corot_forces_row(const sq_level_model *M, const sq_level_state *S, const sq_material *mat,
                             const double g[3],
                             const unsigned char *active, double *f, double *acc)
{
    (void)active; /* all nodes (a superset of the active ones) */
    (void)acc;
    sq_level_corot_forces(M, S, mat, g, f);
}

static void anp_step(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double g[3], double dt,
                     const unsigned char *mask)
{
    sq_level_anp_forces(M, S, mat, g, S->f);
    sq_level_integrate(M, S, dt, mask);
}

static void anp_forces_row(const sq_level_model *M, const sq_level_state *S, const sq_material *mat, const double g[3],
                           const unsigned char *active, double *f, double *acc)
{
    (void)active; /* all nodes */
    (void)acc;
    sq_level_anp_forces(M, S, mat, g, f);
}

static const sq_level_ops level_ops[SQ_LEVEL_OP_NKINDS] = {
    [SQ_LEVEL_OP_LINEAR] = {"linear", linear_step, linear_forces, linear_energy},
    [SQ_LEVEL_OP_COROT] = {"corotational", sq_level_corot_step, corot_forces_row, sq_level_corot_energy},
    [SQ_LEVEL_OP_NODAL] = {"nodal", anp_step, anp_forces_row, sq_level_anp_energy},
    [SQ_LEVEL_OP_SMOOTHED] = {"smoothed", anp_step, anp_forces_row, sq_level_anp_energy},
};

void sq_level_op_update(sq_level *L)
{
    const sq_anp *A = L->state.anp;
    L->model.op_kind = L->state.corot ? SQ_LEVEL_OP_COROT
                       : !A       ? SQ_LEVEL_OP_LINEAR
                       : sq_anp_mode(A) == SQ_PRESSURE_SMOOTHED ? SQ_LEVEL_OP_SMOOTHED
                                                                : SQ_LEVEL_OP_NODAL;
}

const sq_level_ops *sq_level_ops_of(sq_level_op_kind k)
{
    return (unsigned)k < SQ_LEVEL_OP_NKINDS ? &level_ops[k] : NULL;
}

void sq_level_step(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double gravity[3],
                   double dt,
                   const unsigned char *mask)
{
    level_ops[M->op_kind].step(M, S, mat, gravity, dt, mask);
}

void sq_level_forces(const sq_level_model *M, sq_level_state *S, const sq_material *mat, const double gravity[3],
                     const unsigned char *active)
{
    sq_level_forces_to(M, S, mat, gravity, active, S->f, S->acc);
}

void sq_level_forces_to(const sq_level_model *M, const sq_level_state *S, const sq_material *mat,
                        const double gravity[3],
                        const unsigned char *active, double *f_out, double *acc)
{
    level_ops[M->op_kind].forces(M, S, mat, gravity, active, f_out, acc);
}

void sq_level_forces_frozen(const sq_level_model *M, const sq_level_state *S, const sq_material *mat,
                            const double gravity[3], double *f_out, double *acc)
{
    if (M->op_kind == SQ_LEVEL_OP_COROT)
        sq_level_corot_forces_frozen(M, S, mat, gravity, f_out);
    else
        sq_level_forces_to(M, S, mat, gravity, NULL, f_out, acc);
}

void sq_level_integrate(const sq_level_model *M, sq_level_state *S, double dt, const unsigned char *active)
{
    const int n = M->n;
    double *restrict d = S->d;
    double *restrict v = S->v;
    const double *restrict f = S->f;
    const double *restrict mass = M->mass;
    const unsigned char *restrict fixed = M->fixed;
    for (int i = 0; i < n; i++) {
        if (active && !active[i])
            continue;
        sq_level_euler_node(v, d, i, dt / mass[i], dt, f[3 * i], f[3 * i + 1], f[3 * i + 2], fixed[i]);
    }
}

void sq_level_laplacian(const sq_level_model *M, const sq_level_state *S, int i, double out[3])
{
    double s0 = 0, s1 = 0, s2 = 0;
    for (int e = M->row_start[i]; e < M->row_start[i + 1]; e++) {
        const double *dj = S->d + 3 * (size_t)M->col[e];
        double w = M->lap[e];
        s0 += w * dj[0];
        s1 += w * dj[1];
        s2 += w * dj[2];
    }
    double iv = M->vol[i] > 0 ? -1.0 / M->vol[i] : 0;
    out[0] = s0 * iv;
    out[1] = s1 * iv;
    out[2] = s2 * iv;
}

double sq_level_residual(const sq_level_model *M, const double *f, const double g[3], const int *active,
                         int nactive, const unsigned char *held)
{
    double gn = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
    double r = 0;
    int na = active ? nactive : M->n;
    for (int q = 0; q < na; q++) {
        int i = active ? active[q] : q;
        if (M->fixed[i] == 7 || (held && held[i]))
            continue;
        double s = 0;
        for (int c = 0; c < 3; c++)
            if (!(M->fixed[i] & (1u << c)))
                s += f[3 * i + c] * f[3 * i + c];
        s = sqrt(s) / (M->mass[i] * (gn > 0 ? gn : 1));
        if (s > r)
            r = s;
    }
    return r;
}

void sq_level_apply_hold(const sq_level_model *M, sq_level_state *S, int i, const double goal[3],
                         const double from[3], double span)
{
    const unsigned fx = M->fixed[i];
    for (int c = 0; c < 3; c++) {
        if (fx & (1u << c))
            continue; /* the constraint wins: the axis stays at rest */
        S->v[3 * i + c] = span > 0 ? (goal[c] - from[c]) / span : 0.0; /* before d: from may be d */
        S->d[3 * i + c] = goal[c];
    }
}

/* 0.5 d.K d of level k (the corotational energy with corotational elasticity) */
double sq_level_elastic_energy(const sq_level_model *M, const sq_level_state *S)
{
    return level_ops[M->op_kind].energy(M, S);
}
