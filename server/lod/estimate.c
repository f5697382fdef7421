/* estimate.c - one level's sharp estimate for bound.c (docs/lod.md "Coupling the levels",
 * docs/stability.md): the operator of level k over its active nodes, S_kk + C_k (its block of
 * the coupled operator's block-diagonal majorant, bound.c's head comment), its Gershgorin
 * ceiling, the Lanczos run on it (level/level.h sq_level_lanczos_steps) with its deadline and
 * early stop in the ceiling's substep bin, the Ritz vector kept for the next warm start; the
 * dense forms the tests compare with, and the debug check (sq_debug()->sharp_check).
 */
#include "lod/lod.h"
#include "lod/bound_internal.h"
#include "lod/lod_test.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>


/* largest absolute row sum of a 3x3 block */
static double bnorm(const double *B)
{
    double m = 0;
    for (int r = 0; r < 3; r++) {
        double x = fabs(B[3 * r]) + fabs(B[3 * r + 1]) + fabs(B[3 * r + 2]);
        m = x > m ? x : m;
    }
    return m;
}

/* the operator of level k over its active nodes (compact: 3 per active node) */
typedef struct op_ctx {
    sq_lod *lod;
    int k, nact;
    int *idx;            /* active index of a level-k node, or -1 (n_k) */
    int *fpos;           /* per active index: offset (blocks) of its merged frontier row, -1 inner */
    double *isq;         /* per active index: 1 / sqrt(mass) */
    double *off;         /* per active index: scaled row sum of |O| (C_k), 1/s^2 */
    double *u[SQ_MAX_LEVELS]; /* values of each level's nodes under the product (3 n_m) */
    double *y;           /* unscaled product, compact */
    /* the ring ghosts with a source on level k (in the order of levels, then rings), found once
     * per operator: level and ring index, and their level-k sources (start per ghost into
     * the active index, node and weight of each, in the ghost's source order) */
    int nrel;
    int *rel_m, *rel_r, *rel_start, *rel_a, *rel_node;
    double *rel_w;
    double *gsplit[SQ_MAX_LEVELS]; /* row_sums: per ring ghost of each level, its col_split (in,
                                    * out) once computed (NaN before), NULL outside row_sums */
    int scratch;         /* 1: idx and u are the lod_sharp's kept arrays (ctx_free cleans them) */
    const double *dense; /* tests (sq_lodx_sharp_lanczos_dense): this 3 nact x 3 nact matrix instead */
    /* the early stop (lanczos, stop_rule): the Gershgorin ceiling (0: no early stop), the rule
     * (1 on, 0 off), for the dense tests the bins' unit (substep bins of a factor 4 in w2 from
     * it), and how the run stopped (0: all its steps, 1: in the ceiling's bin) */
    double ceiling;
    int rule;
    double bin_unit;
    int stopped;
    /* the ceiling's bin as the interval (below, top] of w2 (stop_edges): below the largest
     * value of a lower bin (-INFINITY: none), top the largest of the ceiling's bin (INFINITY:
     * none above); have_edges 0 before stop_edges */
    double below, top;
    int have_edges;
} op_ctx;

/* coupling of column l of level m seen from level k, each weight over sqrt(mass) of the node it
 * reaches: on level k (in) and elsewhere (out); a ring ghost through its sources */
static void col_split(const op_ctx *c, int m, int l, double *in, double *out)
{
    const sq_lod *lod = c->lod;
    int k = c->k;
    const sq_lod_level *lm = &lod->lev[m];
    *in = *out = 0;
    if (lm->lay.active[l]) {
        /* on level k: the operator's own 1 / sqrt(mass), the same value */
        int a = m == k && c->idx ? c->idx[l] : -1;
        double s = a >= 0 ? c->isq[a] : 1 / sqrt(lod->lv[m].model.mass[l]);
        *(m == k ? in : out) = s;
        return;
    }
    int rl = lm->lay.ring_index[l];
    if (rl < 0)
        return;
    /* a ghost is a column of many rows: its sums once per operator (the same sums in the same
     * order, so the same values) */
    double *memo = c->gsplit[m] ? c->gsplit[m] + 2 * (size_t)rl : NULL;
    if (memo && !isnan(memo[0])) {
        *in = memo[0];
        *out = memo[1];
        return;
    }
    for (int q = lm->lay.src_start[rl]; q < lm->lay.src_start[rl + 1]; q++) {
        double s = fabs(lm->lay.src_weight[q]) / sqrt(lod->lv[lm->lay.src_level[q]].model.mass[lm->lay.src_node[q]]);
        *(lm->lay.src_level[q] == k ? in : out) += s;
    }
    if (memo) {
        memo[0] = *in;
        memo[1] = *out;
    }
}

/* the off-level row sums of the scaled operator M^-1/2 A M^-1/2 (C_k, 1/s^2) and the
 * Gershgorin ceiling of its full rows (which bounds the rows of the majorant's block) */
static double row_sums(op_ctx *c)
{
    sq_lod *lod = c->lod;
    int k = c->k;
    const sq_lod_level *lk = &lod->lev[k];
    const sq_level *Lk = &lod->lv[k];
    double *tot = sq_calloc((size_t)c->nact, sizeof(double));
    for (int m = 0; m < lod->L; m++) {
        int nr = lod->lev[m].lay.nring;
        c->gsplit[m] = nr > 0 ? sq_malloc(sizeof(double) * 2 * (size_t)nr) : NULL;
        for (int r = 0; r < 2 * nr; r++)
            c->gsplit[m][r] = NAN;
    }
    for (int a = 0; a < c->nact; a++) {
        int i = lk->lists.active_list[a];
        const double *R = c->fpos[a] >= 0 ? lk->cpl.front_merged + 9 * (size_t)c->fpos[a]
                                          : Lk->model.K + 9 * (size_t)Lk->model.row_start[i];
        for (int e = Lk->model.row_start[i], x = 0; e < Lk->model.row_start[i + 1]; e++, x++) {
            double bn = bnorm(R + 9 * (size_t)x), in, out;
            int l = Lk->model.col[e], al = c->idx[l];
            if (al >= 0) { /* an active column of the level (col_split's value, without the call) */
                in = c->isq[al];
                out = 0;
            } else {
                col_split(c, k, l, &in, &out);
            }
            tot[a] += bn * (in + out) * c->isq[a];
            c->off[a] += bn * out * c->isq[a];
        }
    }
    for (int m = 0; m < lod->L; m++) {
        const sq_lod_level *lm = &lod->lev[m];
        for (int r = 0; r < lm->lay.nring; r++) {
            if (!(lm->lay.src_levels[r] & (1u << k)))
                continue;
            double rin = 0, rout = 0;
            for (int e = lm->cpl.ring_off[r]; e < lm->cpl.ring_off[r + 1]; e++) {
                double bn = bnorm(lm->cpl.ring_K + 9 * (size_t)e), in, out;
                col_split(c, m, lm->cpl.ring_col[e], &in, &out);
                rin += bn * in;
                rout += bn * out;
            }
            for (int q = lm->lay.src_start[r]; q < lm->lay.src_start[r + 1]; q++)
                if (lm->lay.src_level[q] == k) {
                    int a = c->idx[lm->lay.src_node[q]];
                    double w = fabs(lm->lay.src_weight[q]) * c->isq[a];
                    tot[a] += w * (rin + rout);
                    c->off[a] += w * rout;
                }
        }
    }
    double g = 0;
    for (int a = 0; a < c->nact; a++) {
        int i = lk->lists.active_list[a];
        if (Lk->model.fixed[i] != 7)
            g = fmax(g, tot[a]);
    }
    free(tot);
    for (int m = 0; m < lod->L; m++) {
        free(c->gsplit[m]);
        c->gsplit[m] = NULL;
    }
    return g;
}

/* yc = M^-1/2 (A_kk + C_k) M^-1/2 xc over the free axes of level k's active nodes */
static void op_apply(op_ctx *c, const double *xc, double *yc)
{
    if (c->dense) {
        size_t N = 3 * (size_t)c->nact;
        for (size_t i = 0; i < N; i++) {
            double t = 0;
            for (size_t j = 0; j < N; j++)
                t += c->dense[i * N + j] * xc[j];
            yc[i] = t;
        }
        return;
    }
    sq_lod *lod = c->lod;
    int k = c->k;
    const sq_lod_level *lk = &lod->lev[k];
    const sq_level *Lk = &lod->lv[k];
    double *uk = c->u[k];
    for (int a = 0; a < c->nact; a++) {
        int i = lk->lists.active_list[a];
        for (int x = 0; x < 3; x++)
            uk[3 * i + x] = xc[3 * a + x] * c->isq[a];
    }
    /* ring ghost values from their level-k sources (constrained axes zero, as sq_lodx_eval_ring);
     * the ghosts and sources of the list ctx_init made (the same sums in the same order as a
     * scan of every ring) */
    for (int t = 0; t < c->nrel; t++) {
        int m = c->rel_m[t], g = c->lod->lev[m].lay.ring[c->rel_r[t]];
        double v[3] = {0, 0, 0};
        for (int q = c->rel_start[t]; q < c->rel_start[t + 1]; q++)
            for (int x = 0; x < 3; x++)
                v[x] += c->rel_w[q] * uk[3 * c->rel_node[q] + x];
        unsigned char fx = lod->lv[m].model.fixed[g];
        for (int x = 0; x < 3; x++)
            c->u[m][3 * g + x] = fx & (1u << x) ? 0.0 : v[x];
    }
    /* own rows: K rows of inner nodes, merged rows of frontier nodes */
    for (int a = 0; a < c->nact; a++) {
        int i = lk->lists.active_list[a];
        const double *R = c->fpos[a] >= 0 ? lk->cpl.front_merged + 9 * (size_t)c->fpos[a]
                                          : Lk->model.K + 9 * (size_t)Lk->model.row_start[i];
        double f0 = 0, f1 = 0, f2 = 0;
        for (int e = Lk->model.row_start[i]; e < Lk->model.row_start[i + 1]; e++, R += 9) {
            const double *w = uk + 3 * (size_t)Lk->model.col[e];
            f0 += R[0] * w[0] + R[1] * w[1] + R[2] * w[2];
            f1 += R[3] * w[0] + R[4] * w[1] + R[5] * w[2];
            f2 += R[6] * w[0] + R[7] * w[1] + R[8] * w[2];
        }
        c->y[3 * a] = f0;
        c->y[3 * a + 1] = f1;
        c->y[3 * a + 2] = f2;
    }
    /* ring rows handed back to their level-k sources (as sq_lodx_couple_out) */
    for (int t = 0; t < c->nrel; t++) {
        int m = c->rel_m[t], r = c->rel_r[t];
        const sq_lod_level *lm = &lod->lev[m];
        const double *um = c->u[m];
        double g[3] = {0, 0, 0};
        for (int e = lm->cpl.ring_off[r]; e < lm->cpl.ring_off[r + 1]; e++) {
            const double *B = lm->cpl.ring_K + 9 * (size_t)e, *w = um + 3 * (size_t)lm->cpl.ring_col[e];
            for (int x = 0; x < 3; x++)
                g[x] += B[3 * x] * w[0] + B[3 * x + 1] * w[1] + B[3 * x + 2] * w[2];
        }
        unsigned char fx = lod->lv[m].model.fixed[lm->lay.ring[r]];
        for (int x = 0; x < 3; x++)
            if (fx & (1u << x))
                g[x] = 0;
        for (int q = c->rel_start[t]; q < c->rel_start[t + 1]; q++) {
            int a = c->rel_a[q];
            for (int x = 0; x < 3; x++)
                c->y[3 * a + x] += c->rel_w[q] * g[x];
        }
    }
    for (int a = 0; a < c->nact; a++) {
        unsigned char fx = Lk->model.fixed[lk->lists.active_list[a]];
        for (int x = 0; x < 3; x++)
            yc[3 * a + x] = fx & (1u << x) ? 0.0 : c->y[3 * a + x] * c->isq[a] + c->off[a] * xc[3 * a + x];
    }
}

static double dot(const double *a, const double *b, size_t n)
{
    double s = 0;
    for (size_t i = 0; i < n; i++)
        s += a[i] * b[i];
    return s;
}

/* s: the unit eigenvector of the Lanczos tridiagonal T (alpha on the diagonal, beta beside it,
 * order m <= ITERS_REF) for its largest eigenvalue theta, by inverse iteration on T - sigma I
 * (sigma just above theta) with a pivoted tridiagonal solve: stable whatever the basis did,
 * unlike the three-term recurrence from s[0] = 1 */
static void ritz_coefficients(const double *alpha, const double *beta, int m, double theta, double *s)
{
    double scale = 0;
    for (int i = 0; i < m; i++)
        scale = fmax(scale, fabs(alpha[i]) + (i + 1 < m ? fabs(beta[i]) : 0) + (i > 0 ? fabs(beta[i - 1]) : 0));
    double tiny = fmax(scale, 1e-300) * 1e-15, sigma = theta + fmax(fabs(theta), tiny) * 1e-10;
    double d[ITERS_REF + 1], du[ITERS_REF + 1], du2[ITERS_REF + 1], dl[ITERS_REF + 1], b[ITERS_REF + 1];
    for (int i = 0; i < m; i++)
        s[i] = 1;
    for (int it = 0; it < 3; it++) {
        for (int i = 0; i < m; i++) {
            d[i] = alpha[i] - sigma;
            du[i] = dl[i] = i + 1 < m ? beta[i] : 0;
            du2[i] = 0;
            b[i] = s[i];
        }
        for (int i = 0; i + 1 < m; i++) { /* elimination with row interchanges */
            if (fabs(d[i]) >= fabs(dl[i])) {
                if (d[i] == 0)
                    d[i] = tiny;
                double f = dl[i] / d[i];
                d[i + 1] -= f * du[i];
                b[i + 1] -= f * b[i];
            } else {
                double f = d[i] / dl[i], t = d[i + 1];
                d[i] = dl[i];
                d[i + 1] = du[i] - f * t;
                if (i + 2 < m) {
                    du2[i] = du[i + 1];
                    du[i + 1] = -f * du2[i];
                }
                du[i] = t;
                t = b[i];
                b[i] = b[i + 1];
                b[i + 1] = t - f * b[i + 1];
            }
        }
        if (d[m - 1] == 0)
            d[m - 1] = tiny;
        for (int i = m - 1; i >= 0; i--)
            b[i] = (b[i] - (i + 1 < m ? du[i] * b[i + 1] : 0) - (i + 2 < m ? du2[i] * b[i + 2] : 0)) / d[i];
        double n2 = 0;
        for (int i = 0; i < m; i++)
            n2 += b[i] * b[i];
        double n = sqrt(n2);
        if (!(n > 0) || !isfinite(n))
            break; /* keep the last s */
        for (int i = 0; i < m; i++)
            s[i] = b[i] / n;
    }
}

/* the substep bin of w2: the level's exponent (sq_lodx_sharp_exponent), or for the dense tests
 * floor(log4(w2 / bin_unit)) */
static int bin_of(const op_ctx *c, double w2)
{
    if (c->dense)
        return w2 > 0 ? (int)floor(log(w2 / c->bin_unit) / log(4.0)) : -1000;
    return sq_lodx_sharp_exponent(c->lod, c->lod->sharp, c->k, w2);
}

/* the early stop after m Lanczos steps: 1 when the largest Ritz value theta (at or below
 * lambda_max, in exact arithmetic and to rounding in practice) is in the Gershgorin ceiling's
 * bin: lambda_max, the full run's estimate (at least its theta, at most the ceiling) and the
 * ceiling are then all in that bin, so the substeps are decided and further products would
 * not change them; else 0, go on. A rule on the residual (stop when theta + 2 beta_m |s_m| is
 * in theta's bin) was tried and dropped: a Ritz pair converged on a lower eigenvalue passes it
 * (docs/stability.md) */
/* the largest double x in [a, b] (0 <= a < b, finite) with bin_of(x) <= n, given
 * bin_of(a) <= n < bin_of(b): bisection on the bit patterns (ordered as the values for
 * non-negative doubles), at most 64 halvings */
static double last_in_bin(const op_ctx *c, double a, double b, int n)
{
    uint64_t lo, hi;
    memcpy(&lo, &a, sizeof lo);
    memcpy(&hi, &b, sizeof hi);
    while (hi - lo > 1) {
        uint64_t mid = lo + (hi - lo) / 2;
        double x;
        memcpy(&x, &mid, sizeof x);
        if (bin_of(c, x) <= n)
            lo = mid;
        else
            hi = mid;
    }
    double x;
    memcpy(&x, &lo, sizeof x);
    return x;
}

/* the ceiling's bin n as (below, top]: every w2 with below < w2 <= top, and only those, is in
 * bin n (bin_of is non-decreasing in w2), found once per Lanczos run (bisection on the bit
 * patterns of doubles, at most 64 bins each side) */
static void stop_edges(op_ctx *c)
{
    int n = bin_of(c, c->ceiling);
    /* a level's bins depend only on its frame step, the step fraction and the damping: the
     * edges of the same bin are kept from its last estimate (the search was 6.4 M of the 289 M
     * instructions of 100 frames of cube-poke) */
    struct lod_sharp *S = c->dense ? NULL : c->lod->sharp;
    double of[4] = {0, 0, 0, 0};
    if (S) {
        const sq_level *Lk = &c->lod->lv[c->k];
        of[0] = ldexp(Lk->dt, Lk->substeps_log2);
        of[1] = S->step_fraction;
        of[2] = c->lod->cpl.mat.rayleigh_mass;
        of[3] = c->lod->cpl.mat.rayleigh_stiffness;
        if (S->have_edges[c->k] && S->edge_n[c->k] == n && !memcmp(S->edge_of[c->k], of, sizeof of)) {
            c->below = S->edge_below[c->k];
            c->top = S->edge_top[c->k];
            c->have_edges = 1;
            return;
        }
    }
    c->below = bin_of(c, 0.0) >= n ? -INFINITY : last_in_bin(c, 0.0, c->ceiling, n - 1);
    double up = c->ceiling;
    for (int i = 0; i < 64 && isfinite(up) && bin_of(c, up) <= n; i++)
        up *= 2;
    c->top = !isfinite(up) || bin_of(c, up) <= n ? INFINITY : last_in_bin(c, c->ceiling, up, n);
    c->have_edges = 1;
    if (S) {
        S->have_edges[c->k] = 1;
        S->edge_n[c->k] = n;
        memcpy(S->edge_of[c->k], of, sizeof of);
        S->edge_below[c->k] = c->below;
        S->edge_top[c->k] = c->top;
    }
}

/* the rule, in Sturm counts: theta is in the ceiling's bin (below, top] when T has an
 * eigenvalue above `below` and none above `top`; two counts of order m instead of the
 * bisection of theta (up to 200 counts: 10.7 M instructions of 100 frames of cube-poke).
 * The decision is the bisection's except for a theta within the bisection's tolerance (1e-15
 * relative) of an edge of the bin */
static int stop_rule(op_ctx *c, const double *alpha, const double *beta, int m)
{
    if (c->rule <= 0 || !(c->ceiling > 0) || (c->dense && !(c->bin_unit > 0)))
        return 0;
    if (!c->have_edges)
        stop_edges(c);
    if (c->below > -INFINITY && sq_level_tridiag_above(alpha, beta, m, c->below) == 0)
        return 0;
    return c->top == INFINITY || sq_level_tridiag_above(alpha, beta, m, c->top) == 0;
}

/* lanczos's run on the shared recurrence (level/level.h sq_level_lanczos_steps): the product,
 * the deadline before each product, the early stop after each step */
typedef struct lanczos_run {
    op_ctx *c;
    double deadline, tprod, tlast;
} lanczos_run;

static void run_apply(void *ctx, const double *x, double *y)
{
    op_apply(((lanczos_run *)ctx)->c, x, y);
}

static int run_go(void *ctx, int j)
{
    lanczos_run *r = ctx;
    if (!(r->deadline > 0))
        return 1;
    if (j > 0) {
        double now = sq_thread_cpu();
        r->tprod = fmax(r->tprod, now - r->tlast);
        r->tlast = now;
    }
    return r->tlast + r->tprod <= r->deadline;
}

static int run_stop(void *ctx, const double *alpha, const double *beta, int m)
{
    op_ctx *c = ((lanczos_run *)ctx)->c;
    return (c->stopped = stop_rule(c, alpha, beta, m)) != 0;
}

/* upper estimate of lambda_max of the operator from start vector q (unit, free axes only):
 * Lanczos, then the Ritz vector (into q), its Rayleigh quotient plus its residual norm. With a
 * deadline (thread CPU time, 0: none), a product starts only when it ends before the deadline
 * at the slowest product's time so far (tprod at first, the prediction): else NAN, q untouched */
static double lanczos(op_ctx *c, double *q, int iters, int *done, double deadline, double tprod)
{
    size_t N = 3 * (size_t)c->nact;
    if ((long)N * iters > BASIS_MAX_DOUBLES)
        iters = (int)SQ_MAX(BASIS_MAX_DOUBLES / (long)N, 4);
    /* the basis and the work vector are kept between estimates (struct lod_sharp): a fresh
     * allocation of a few MB each time was a few hundred page faults, about 13 us each on
     * this kind of machine */
    struct lod_sharp *S = c->lod->sharp;
    size_t need = N * (size_t)(iters + 1);
    if (need > S->basis_cap) {
        free(S->basis);
        S->basis_cap = SQ_MAX(need, 2 * S->basis_cap);
        S->basis = sq_malloc(sizeof(double) * S->basis_cap);
    }
    double *Q = S->basis, *w = S->basis + N * (size_t)iters;
    double alpha[ITERS_COLD + 1], beta[ITERS_COLD + 1];
    memcpy(Q, q, sizeof(double) * N);
    c->stopped = 0;
    c->have_edges = 0;
    lanczos_run run = {c, deadline, tprod, deadline > 0 ? sq_thread_cpu() : 0};
    sq_lanczos_op op = {run_apply, run_go, run_stop, &run};
    int abandoned = 0;
    int m = sq_level_lanczos_steps(&op, N, Q, 1, w, iters, alpha, beta, &abandoned);
    tprod = run.tprod;
    double tlast = run.tlast;
    if (abandoned) {
        *done = m;
        return NAN;
    }
    *done = m;
    if (deadline > 0 && c->stopped != 1) { /* the Ritz vector's product too */
        double now = sq_thread_cpu();
        tprod = fmax(tprod, now - tlast);
        if (now + tprod > deadline)
            return NAN;
    }
    double theta = sq_level_tridiag_max(alpha, beta, m);
    /* eigenvector s of T for theta, the Ritz vector Q s (inverse iteration: the forward
     * recurrence s[i+1] = ((theta - alpha[i]) s[i] - beta[i-1] s[i-1]) / beta[i] used before
     * grows the other eigenvectors' parts without bound once theta has converged, and the
     * Ritz vector it gave could be far from the top one: docs/stability.md) */
    double s[ITERS_COLD + 1];
    ritz_coefficients(alpha, beta, m, theta, s);
    memset(q, 0, sizeof(double) * N);
    for (int j = 0; j < m; j++)
        for (size_t i = 0; i < N; i++)
            q[i] += s[j] * Q[N * (size_t)j + i];
    double nq = sqrt(dot(q, q, N)), est = INFINITY;
    if (c->stopped == 1) {
        /* decided by the ceiling's bin: the ceiling is the estimate (a rigorous bound in the
         * same bin), the Ritz vector kept for the next warm start without its product */
        if (isfinite(nq) && nq > 0)
            for (size_t i = 0; i < N; i++)
                q[i] /= nq;
        return c->ceiling;
    }
    if (isfinite(nq) && nq > 0) {
        for (size_t i = 0; i < N; i++)
            q[i] /= nq;
        op_apply(c, q, w);
        double rho = dot(q, w, N), r2 = 0;
        for (size_t i = 0; i < N; i++) {
            double r = w[i] - rho * q[i];
            r2 += r * r;
        }
        /* never below the largest Ritz value theta (at or below lambda_max: a Ritz vector
         * spoilt by rounding gave rho + ||r|| at 0.66 of theta on box-big) */
        est = rho + sqrt(r2);
        if (!isfinite(est))
            est = INFINITY; /* the ceiling decides */
        else
            est = fmax(est, theta);
    }
    return est;
}

double sq_lodx_sharp_lanczos_dense_stop(const double *A, int n, const double *start, int iters, double ceiling,
                                        double bin_unit, int rule, int *steps, int *stopped)
{
    struct lod_sharp S;
    memset(&S, 0, sizeof S);
    sq_lod *lod = sq_calloc(1, sizeof *lod);
    lod->sharp = &S;
    op_ctx c;
    memset(&c, 0, sizeof c);
    c.lod = lod;
    c.nact = n / 3;
    c.dense = A;
    c.ceiling = ceiling;
    c.bin_unit = bin_unit;
    c.rule = rule;
    size_t N = 3 * (size_t)c.nact;
    double *q = sq_malloc(sizeof(double) * SQ_MAX(N, 1)), nq = 0;
    for (size_t i = 0; i < N; i++)
        nq += start[i] * start[i];
    for (size_t i = 0; i < N; i++)
        q[i] = start[i] / sqrt(nq);
    int done = 0;
    double est = lanczos(&c, q, SQ_MIN(iters, ITERS_COLD), &done, 0, 0);
    if (ceiling > 0)
        est = fmin(est, ceiling);
    if (steps)
        *steps = done;
    if (stopped)
        *stopped = c.stopped;
    free(q);
    free(S.basis);
    free(lod);
    return est;
}

int sq_lodx_sharp_stop_tridiag(const double *alpha, const double *beta, int m, double ceiling, double bin_unit)
{
    static const double none = 0;
    op_ctx c;
    memset(&c, 0, sizeof c);
    c.dense = &none; /* the dense tests' bins */
    c.ceiling = ceiling;
    c.bin_unit = bin_unit;
    c.rule = 1;
    return stop_rule(&c, alpha, beta, m);
}

double sq_lodx_sharp_lanczos_dense(const double *A, int n, const double *start, int iters)
{
    return sq_lodx_sharp_lanczos_dense_stop(A, n, start, iters, 0, 0, 0, NULL, NULL);
}

/* the early stop of the estimates (stop_rule): on, or off with sq_debug()->sharp_no_stop (to
 * compare) */
static int sharp_rule(void)
{
    return !sq_debug()->sharp_no_stop;
}

/* the operator of level k: lists, masses, the off-level row sums; returns the Gershgorin ceiling */
static double ctx_init(op_ctx *cc, sq_lod *lod, int k)
{
    sq_lod_level *lk = &lod->lev[k];
    const sq_level *Lk = &lod->lv[k];
    int n = Lk->model.n, nact = lk->lay.nactive;
    op_ctx c;
    memset(&c, 0, sizeof c);
    c.lod = lod;
    c.k = k;
    c.nact = nact;
    /* the node-sized arrays are kept between estimates (bound.c's scratch: allocating and
     * zeroing some MB per estimate cost up to 8 ms in page faults on the box-big levels) and
     * handed back clean by ctx_free: idx all -1, u all zero */
    struct lod_sharp *S = lod->sharp;
    if (S && !S->idx[k]) {
        S->idx[k] = sq_malloc(sizeof(int) * (size_t)SQ_MAX(n, 1));
        for (int i = 0; i < n; i++)
            S->idx[k][i] = -1;
    }
    c.scratch = S != NULL;
    c.idx = S ? S->idx[k] : sq_malloc(sizeof(int) * (size_t)SQ_MAX(n, 1));
    for (int i = 0; !S && i < n; i++)
        c.idx[i] = -1;
    c.fpos = sq_malloc(sizeof(int) * (size_t)nact);
    c.isq = sq_malloc(sizeof(double) * (size_t)nact);
    c.off = sq_calloc((size_t)nact, sizeof(double));
    c.y = sq_malloc(sizeof(double) * 3 * (size_t)nact);
    for (int a = 0; a < nact; a++) {
        int i = lk->lists.active_list[a];
        c.idx[i] = a;
        c.fpos[a] = -1;
        c.isq[a] = 1.0 / sqrt(Lk->model.mass[i]);
    }
    for (int r = 0, pos = 0; r < lk->lay.nfrontier; r++) {
        int i = lk->lay.frontier[r];
        c.fpos[c.idx[i]] = pos;
        pos += Lk->model.row_start[i + 1] - Lk->model.row_start[i];
    }
    for (int m = 0; m < lod->L; m++) {
        if (S && !S->u[m])
            S->u[m] = sq_calloc(3 * (size_t)SQ_MAX(lod->lv[m].model.n, 1), sizeof(double));
        c.u[m] = S ? S->u[m] : sq_calloc(3 * (size_t)SQ_MAX(lod->lv[m].model.n, 1), sizeof(double));
    }
    /* the ring ghosts with a level-k source and those sources (op_apply, ctx_free) */
    int nrel = 0, nsrc = 0;
    for (int m = 0; m < lod->L; m++) {
        const sq_lod_level *lm = &lod->lev[m];
        for (int r = 0; r < lm->lay.nring; r++)
            if (lm->lay.src_levels[r] & (1u << k)) {
                nrel++;
                for (int q = lm->lay.src_start[r]; q < lm->lay.src_start[r + 1]; q++)
                    nsrc += lm->lay.src_level[q] == k;
            }
    }
    c.rel_m = sq_malloc(sizeof(int) * (size_t)SQ_MAX(nrel, 1));
    c.rel_r = sq_malloc(sizeof(int) * (size_t)SQ_MAX(nrel, 1));
    c.rel_start = sq_malloc(sizeof(int) * (size_t)(nrel + 1));
    c.rel_a = sq_malloc(sizeof(int) * (size_t)SQ_MAX(nsrc, 1));
    c.rel_node = sq_malloc(sizeof(int) * (size_t)SQ_MAX(nsrc, 1));
    c.rel_w = sq_malloc(sizeof(double) * (size_t)SQ_MAX(nsrc, 1));
    c.rel_start[0] = 0;
    for (int m = 0, t = 0, p = 0; m < lod->L; m++) {
        const sq_lod_level *lm = &lod->lev[m];
        for (int r = 0; r < lm->lay.nring; r++) {
            if (!(lm->lay.src_levels[r] & (1u << k)))
                continue;
            for (int q = lm->lay.src_start[r]; q < lm->lay.src_start[r + 1]; q++)
                if (lm->lay.src_level[q] == k) {
                    c.rel_node[p] = lm->lay.src_node[q];
                    c.rel_a[p] = c.idx[lm->lay.src_node[q]];
                    c.rel_w[p++] = lm->lay.src_weight[q];
                }
            c.rel_m[t] = m;
            c.rel_r[t] = r;
            c.rel_start[++t] = p;
        }
    }
    c.nrel = nrel;
    double g = row_sums(&c);
    *cc = c;
    return g;
}

static void ctx_free(op_ctx *c)
{
    const sq_lod *lod = c->lod;
    if (c->scratch) {
        /* back to all zero / -1: the entries op_apply wrote (level k's active nodes and the
         * ring ghosts with a source on level k) and the active indices */
        const sq_lod_level *lk = &lod->lev[c->k];
        for (int a = 0; a < c->nact; a++) {
            int i = lk->lists.active_list[a];
            c->idx[i] = -1;
            c->u[c->k][3 * i] = c->u[c->k][3 * i + 1] = c->u[c->k][3 * i + 2] = 0;
        }
        for (int t = 0; t < c->nrel; t++) {
            int m = c->rel_m[t], g = lod->lev[m].lay.ring[c->rel_r[t]];
            c->u[m][3 * g] = c->u[m][3 * g + 1] = c->u[m][3 * g + 2] = 0;
        }
    } else {
        for (int m = 0; m < lod->L; m++)
            free(c->u[m]);
        free(c->idx);
    }
    free(c->rel_m);
    free(c->rel_r);
    free(c->rel_start);
    free(c->rel_a);
    free(c->rel_node);
    free(c->rel_w);
    free(c->fpos);
    free(c->isq);
    free(c->off);
    free(c->y);
}

/* the upper estimate of lambda_max(M^-1 (A_kk + C_k)) of level k (1/s^2), its ceiling in *gersh;
 * NAN when the deadline (0: none) came first (the Ritz vector then kept) */
double sq_lodx_sharp_estimate(sq_lod *lod, struct lod_sharp *S, int k, double *gersh, double deadline, double tprod)
{
    sq_lod_level *lk = &lod->lev[k];
    const sq_level *Lk = &lod->lv[k];
    int n = Lk->model.n, nact = lk->lay.nactive;
    op_ctx c;
    *gersh = ctx_init(&c, lod, k);
    /* start: the previous Ritz vector on the nodes still active, plus a fixed pseudo-random
     * part (1% of it, all of it the first time) so that new regions are reached */
    size_t N = 3 * (size_t)nact;
    double *q = sq_malloc(sizeof(double) * N);
    unsigned long long st = 88172645463325252ULL;
    double nr = 0;
    int warm = S->ritz[k] != NULL;
    for (int a = 0; a < nact; a++) {
        int i = lk->lists.active_list[a];
        for (int x = 0; x < 3; x++) {
            st ^= st << 13, st ^= st >> 7, st ^= st << 17;
            double rnd = 0.5 + (double)(st >> 11) / 9007199254740992.0;
            q[3 * a + x] = (Lk->model.fixed[i] & (1u << x)) ? 0 : rnd;
            if (warm)
                nr += S->ritz[k][3 * i + x] * S->ritz[k][3 * i + x];
        }
    }
    double nrand = sqrt(dot(q, q, N));
    warm = warm && nr > 0 && nrand > 0;
    if (warm) {
        double scale = 0.01 * sqrt(nr) / nrand;
        for (int a = 0; a < nact; a++) {
            int i = lk->lists.active_list[a];
            for (int x = 0; x < 3; x++)
                if (!(Lk->model.fixed[i] & (1u << x)))
                    q[3 * a + x] = S->ritz[k][3 * i + x] + scale * q[3 * a + x];
        }
    }
    double nq = sqrt(dot(q, q, N)), est = 0;
    int done = 0;
    if (nq > 0) {
        for (size_t i = 0; i < N; i++)
            q[i] /= nq;
        c.ceiling = *gersh;
        c.rule = sharp_rule();
        est = lanczos(&c, q, warm ? ITERS_WARM : ITERS_COLD, &done, deadline, tprod);
        S->stopped[k] = c.stopped;
        if (isnan(est)) { /* not made in time */
            S->iters[k] = done;
            free(q);
            ctx_free(&c);
            return NAN;
        }
        if (!S->ritz[k])
            S->ritz[k] = sq_calloc(3 * (size_t)SQ_MAX(n, 1), sizeof(double));
        /* zero only where the last Ritz vector was (its nodes), not the whole level */
        for (int a = 0; a < S->nritz[k]; a++) {
            int i = S->ritz_nodes[k][a];
            S->ritz[k][3 * i] = S->ritz[k][3 * i + 1] = S->ritz[k][3 * i + 2] = 0;
        }
        S->ritz_nodes[k] = sq_realloc(S->ritz_nodes[k], sizeof(int) * (size_t)SQ_MAX(nact, 1));
        memcpy(S->ritz_nodes[k], lk->lists.active_list, sizeof(int) * (size_t)nact);
        S->nritz[k] = nact;
        for (int a = 0; a < nact; a++)
            for (int x = 0; x < 3; x++)
                S->ritz[k][3 * lk->lists.active_list[a] + x] = isfinite(q[3 * a + x]) ? q[3 * a + x] : 0;
    }
    S->iters[k] = done;
    free(q);
    ctx_free(&c);
    return fmin(est, *gersh);
}

double *sq_lodx_sharp_dense(sq_lod *lod, int k, double **off)
{
    op_ctx c;
    ctx_init(&c, lod, k);
    size_t N = 3 * (size_t)c.nact;
    double *A = sq_calloc(N * N, sizeof(double)), *x = sq_calloc(N, sizeof(double));
    double *y = sq_malloc(sizeof(double) * N);
    for (size_t j = 0; j < N; j++) {
        /* a constrained axis's column stays zero: op_apply zeroes the constrained rows only
         * (the Lanczos vectors are zero on those axes), so the column a free row reads from a
         * constrained axis was here before, and the matrix looked asymmetric (up to 0.23 of its
         * largest entry on the organ, glued at its base: docs/stability.md) */
        if (lod->lv[k].model.fixed[lod->lev[k].lists.active_list[j / 3]] & (1u << (j % 3)))
            continue;
        x[j] = 1;
        op_apply(&c, x, y);
        x[j] = 0;
        for (size_t i = 0; i < N; i++)
            A[i * N + j] = y[i];
    }
    *off = sq_malloc(sizeof(double) * N);
    for (size_t i = 0; i < N; i++)
        (*off)[i] = c.off[i / 3];
    free(x);
    free(y);
    ctx_free(&c);
    return A;
}

/* sq_debug()->sharp_check 1 (a debug path, never taken in normal runs): level k's estimate est against a
 * reference of the same operator, ITERS_REF Lanczos steps with full reorthogonalisation from the
 * cold start, whose largest Ritz value theta_ref is at or below lambda_max (its residual
 * beta |s_m| shows how far it may be below); prints one line. sharp_check 2 also assembles the
 * operator densely (up to 3,000 axes) and prints its largest asymmetry and where it is */
void sq_lodx_sharp_check(sq_lod *lod, struct lod_sharp *S, int k, double est)
{
    op_ctx c;
    ctx_init(&c, lod, k);
    const sq_lod_level *lk = &lod->lev[k];
    const sq_level *Lk = &lod->lv[k];
    size_t N = 3 * (size_t)c.nact;
    int nfree = 0;
    for (int a = 0; a < c.nact; a++)
        for (int x = 0; x < 3; x++)
            nfree += !(Lk->model.fixed[lk->lists.active_list[a]] & (1u << x));
    int iters = SQ_MIN(ITERS_REF, nfree);
    double *Q = sq_calloc(N * (size_t)(iters + 1), sizeof(double)), *w = sq_malloc(sizeof(double) * SQ_MAX(N, 1));
    unsigned long long st = 88172645463325252ULL;
    for (int a = 0; a < c.nact; a++)
        for (int x = 0; x < 3; x++) {
            st ^= st << 13, st ^= st >> 7, st ^= st << 17;
            double rnd = 0.5 + (double)(st >> 11) / 9007199254740992.0;
            Q[3 * a + x] = (Lk->model.fixed[lk->lists.active_list[a]] & (1u << x)) ? 0 : rnd;
        }
    double nq = sqrt(dot(Q, Q, N));
    for (size_t i = 0; i < N; i++)
        Q[i] /= nq;
    double alpha[ITERS_REF + 1], beta[ITERS_REF + 1], s[ITERS_REF + 1];
    int m = 0;
    for (int j = 0; j < iters; j++) {
        double *qj = Q + N * (size_t)j;
        op_apply(&c, qj, w);
        alpha[m] = dot(w, qj, N);
        for (int pass = 0; pass < 2; pass++) /* full reorthogonalisation, twice */
            for (int l = 0; l <= j; l++) {
                double h = dot(w, Q + N * (size_t)l, N);
                for (size_t i = 0; i < N; i++)
                    w[i] -= h * Q[N * (size_t)l + i];
            }
        double b = sqrt(dot(w, w, N));
        beta[m++] = b;
        if (!(b > 1e-13 * fabs(alpha[0])))
            break;
        for (size_t i = 0; i < N; i++)
            Q[N * (size_t)(j + 1) + i] = w[i] / b;
    }
    double theta = sq_level_tridiag_max(alpha, beta, m);
    ritz_coefficients(alpha, beta, m, theta, s);
    double resid = fabs(beta[m - 1] * s[m - 1]);
    int ne = sq_lodx_sharp_exponent(lod, S, k, est), nr = sq_lodx_sharp_exponent(lod, S, k, theta), nh = sq_lodx_sharp_exponent(lod, S, k, theta + resid);
    /* the substep this estimate gives against the stable step at theta_ref (> 1: beyond it) */
    double frame_dt = ldexp(Lk->dt, Lk->substeps_log2);
    double over = frame_dt / ldexp(1.0, ne) / sq_lodx_step_bound_of(&lod->cpl.mat, theta);
    fprintf(stderr, "sharp-check L%d: %d active, %d free axes, est %.9g, ref %.9g (resid %.3g, %d steps), est/ref %.6f, "
            "2^%d vs ref 2^%d..2^%d, step/ref bound %.4f, Lanczos steps %d, stop %d, ceiling %.6g\n",
            k, c.nact, nfree, est, theta, resid, m, est / theta, ne, nr, nh, over, S->iters[k], S->stopped[k], S->gersh[k]);
    if (sq_debug()->sharp_check >= 2 && N <= 3000) {
        double *A = sq_calloc(N * N, sizeof(double)), *x = sq_calloc(N, sizeof(double));
        for (size_t j = 0; j < N; j++) {
            x[j] = 1;
            op_apply(&c, x, w);
            x[j] = 0;
            for (size_t i = 0; i < N; i++)
                A[i * N + j] = w[i];
        }
        double amax = 0, dmax = 0;
        size_t wi = 0, wj = 0;
        for (size_t i = 0; i < N * N; i++)
            amax = fmax(amax, fabs(A[i]));
        /* over the free axes only (the Lanczos vectors are zero on the constrained ones; a
         * constrained column is read by free rows, its row is zero: not an asymmetry of the
         * operator Lanczos sees) */
        for (size_t i = 0; i < N; i++)
            for (size_t j = i + 1; j < N; j++) {
                if ((Lk->model.fixed[lk->lists.active_list[i / 3]] & (1u << (i % 3))) ||
                    (Lk->model.fixed[lk->lists.active_list[j / 3]] & (1u << (j % 3))))
                    continue;
                double d = fabs(A[i * N + j] - A[j * N + i]);
                if (d > dmax) {
                    dmax = d;
                    wi = i;
                    wj = j;
                }
            }
        int ai = (int)(wi / 3), aj = (int)(wj / 3);
        int srci = 0, srcj = 0;
        for (int mm = 0; mm < lod->L; mm++) {
            const sq_lod_level *lm = &lod->lev[mm];
            for (int q = 0; lm->lay.nring && q < lm->lay.src_start[lm->lay.nring]; q++)
                if (lm->lay.src_level[q] == k) {
                    srci += lm->lay.src_node[q] == lk->lists.active_list[ai];
                    srcj += lm->lay.src_node[q] == lk->lists.active_list[aj];
                }
        }
        fprintf(stderr, "sharp-check L%d: asymmetry max |A_ij - A_ji| %.3g of max |A| %.3g (%.3g) at axes %zu, %zu: "
                "%.6g vs %.6g; nodes %d (%s, source %d times), %d (%s, source %d times)\n",
                k, dmax, amax, dmax / amax, wi, wj, A[wi * N + wj], A[wj * N + wi], lk->lists.active_list[ai],
                c.fpos[ai] >= 0 ? "frontier" : "inner", srci, lk->lists.active_list[aj], c.fpos[aj] >= 0 ? "frontier" : "inner", srcj);
        free(A);
        free(x);
    }
    free(Q);
    free(w);
    ctx_free(&c);
}
