/* bound.c - stage: the sharp per-level step of adaptive mode ("step_bound": "sharp";
 * docs/lod.md "Coupling the levels", docs/stability.md): which level is estimated when (a level
 * whose operator did not change keeps its estimate), the estimates' deadline and the ones owed,
 * the substeps taken from an estimate. One level's estimate is estimate.c's.
 *
 * The coupled operator of the adaptive frame is A = sum_m P_m^T K_m P_m over the active nodes of
 * every level (P_m: identity on level m's active nodes, the ring interpolation on its ring ghosts;
 * K_m: the level's tets touching an active node, mixed ones at half weight). Split A into the
 * blocks of the levels in the mass-scaled frame, S = M^-1/2 A M^-1/2 = D + O (D = diag(S_kk), O
 * the blocks between levels). With C the diagonal of the row sums of |O| (per node, bounding each
 * axis row), C - O is diagonally dominant, so S <= D + C: the block-diagonal majorant, level k's
 * block S_kk + C_k (one C for every level, so the inequality holds for the whole system at once).
 * Each level takes its step from lambda_max(S_kk + C_k) over its active free axes, estimated by Lanczos
 * (Rayleigh quotient of the Ritz vector plus its residual, computed with one more product),
 * capped by the Gershgorin row sums of the full coupled row, damped as in docs/physics.md
 * section 3, and rounded to 2^n substeps per frame. The Lanczos starts from the level's previous
 * Ritz vector after a rebuild (few iterations), from a fixed pseudo-random vector the first time.
 * The products read the assembled rows: the level's K rows (inner nodes), the merged frontier
 * rows, and every level's ring rows with their sources, as the frame's step stage applies them.
 */
#include "lod/lod.h"
#include "lod/bound_internal.h"
#include "lod/bound.h"
#include "lod/coupling.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>



/* ---------------------------------------------------------------- skipping unchanged levels */

static inline unsigned long long mix(unsigned long long h, unsigned long long x)
{
    h ^= x;
    h *= 0x9E3779B97F4A7C15ULL;
    return h ^ (h >> 29);
}

static unsigned long long mix_ints(unsigned long long h, const int *a, long n)
{
    h = mix(h, (unsigned long long)n);
    for (long i = 0; i < n; i++)
        h = mix(h, (unsigned long long)(unsigned)a[i]);
    return h;
}

static unsigned long long mix_doubles(unsigned long long h, const double *a, long n)
{
    for (long i = 0; i < n; i++) {
        unsigned long long x;
        memcpy(&x, a + i, sizeof x);
        h = mix(h, x);
    }
    return h;
}

/* fingerprint of everything level k's estimate reads: the material and step rule, level k's
 * active and frontier lists (its own and merged frontier rows follow from them and the
 * material), and for every level whose ring ghosts have a source on level k, that level's
 * active list (its ring rows follow from it), ring and sources with their weights. Equal
 * fingerprints: the same operator, so the same estimate (a 64-bit hash: a collision would
 * keep the previous step, about 2^-64 per rebuild). */
static unsigned long long level_key(const sq_lod *lod, const struct lod_sharp *S, int k)
{
    unsigned long long h = 0x243F6A8885A308D3ULL;
    const sq_material *mt = &lod->cpl.mat;
    const double mv[7] = {mt->mu, mt->lambda, mt->density, mt->rayleigh_mass, mt->rayleigh_stiffness,
                          mt->phi, mt->psi};
    h = mix_doubles(h, mv, 7);
    h = mix(h, (unsigned long long)mt->use_viscosity);
    h = mix_doubles(h, &S->step_fraction, 1);
    h = mix_doubles(h, &lod->lv[k].dt, 1);
    h = mix(h, (unsigned long long)lod->lv[k].substeps_log2);
    h = mix(h, (unsigned long long)(uintptr_t)lod->lv[k].model.K);
    const sq_lod_level *lk = &lod->lev[k];
    h = mix_ints(h, lk->lists.active_list, lk->lay.nactive);
    h = mix_ints(h, lk->lay.frontier, lk->lay.nfrontier);
    for (int m = 0; m < lod->L; m++) {
        const sq_lod_level *lm = &lod->lev[m];
        int uses = 0;
        for (int r = 0; r < lm->lay.nring && !uses; r++)
            uses = (lm->lay.src_levels[r] & (1u << k)) != 0;
        if (!uses)
            continue;
        int ns = lm->lay.src_start[lm->lay.nring];
        h = mix(h, (unsigned long long)m);
        h = mix_ints(h, lm->lists.active_list, lm->lay.nactive);
        h = mix_ints(h, lm->lay.ring, lm->lay.nring);
        h = mix_ints(h, lm->lay.src_start, lm->lay.nring + 1);
        h = mix_ints(h, lm->lay.src_level, ns);
        h = mix_ints(h, lm->lay.src_node, ns);
        h = mix_doubles(h, lm->lay.src_weight, ns);
    }
    return h;
}

void sq_lodx_sharp_invalidate(sq_lod *lod)
{
    if (lod->sharp)
        memset(lod->sharp->have_key, 0, sizeof lod->sharp->have_key);
}

/* the size of level k's product, for its cost: its active nodes and the ring ghosts of every
 * level with a source on it (their rows are read) */
static double level_units(const sq_lod *lod, int k)
{
    long u = lod->lev[k].lay.nactive;
    for (int m = 0; m < lod->L; m++) {
        const sq_lod_level *lm = &lod->lev[m];
        for (int r = 0; r < lm->lay.nring; r++)
            u += (lm->lay.src_levels[r] >> k) & 1u;
    }
    return (double)u;
}


/* the damped stable step of an undamped rate w2 (1/s^2), s */
double sq_lodx_step_bound_of(const sq_material *mat, double w2)
{
    double c = mat->rayleigh_mass + mat->rayleigh_stiffness * w2;
    return (w2 > 0 || c > 0) ? 4.0 / (c + sqrt(c * c + 4 * w2)) : INFINITY;
}

/* the exponent n of level k's 2^n substeps per frame for the estimate w2 (non-decreasing in
 * w2); 21: above 2^20, -1: no estimate (NaN or negative) */
int sq_lodx_sharp_exponent(const sq_lod *lod, const struct lod_sharp *S, int k, double w2)
{
    const sq_level *Lk = &lod->lv[k];
    double bound = sq_lodx_step_bound_of(&lod->cpl.mat, w2);
    double frame_dt = ldexp(Lk->dt, Lk->substeps_log2);
    int n = 0;
    while (n <= 20 && frame_dt / ldexp(1.0, n) > S->step_fraction * bound)
        n++;
    return w2 >= 0 ? n : -1;
}

/* level k's substeps from its estimate w2 (damping as docs/physics.md section 3: c = a + b
 * omega^2): the smallest 2^n within step_fraction of the bound; above 2^20 (or no estimate)
 * the Gershgorin substeps coupling_bound gave stay */
static void take_estimate(sq_lod *lod, struct lod_sharp *S, int k, double w2)
{
    int n = sq_lodx_sharp_exponent(lod, S, k, w2);
    if (n > 20 || n < 0)
        return; /* keep the Gershgorin substeps */
    S->nsub[k] = n;
    lod->lev[k].rate.extra_log2 = n - lod->lv[k].substeps_log2;
    if (sq_debug()->sharp_trace)
        fprintf(stderr, "sharp L%d: %d active, lambda %.6g, ceiling %.6g, %d steps%s, 2^%d", k,
                lod->lev[k].lay.nactive, w2, S->gersh[k], S->iters[k],
                S->stopped[k] ? " (stopped: in the ceiling's bin)" : "", n);
}

/* one estimate of level k by the deadline (0: none): 1 made and taken; 0 not in time (none of
 * it taken: the level keeps its Gershgorin substeps) */
static int estimate_by(sq_lod *lod, struct lod_sharp *S, int k, double deadline)
{
    double units = SQ_MAX(level_units(lod, k), 1.0);
    /* warm (sq_lodx_sharp_estimate) when the last Ritz vector is nonzero on a node still active */
    int iters = ITERS_COLD;
    for (int a = 0; S->ritz[k] && a < lod->lev[k].lay.nactive && iters == ITERS_COLD; a++) {
        const double *r = S->ritz[k] + 3 * (size_t)lod->lev[k].lists.active_list[a];
        if (r[0] != 0 || r[1] != 0 || r[2] != 0)
            iters = ITERS_WARM;
    }
    double t0 = sq_thread_cpu();
    /* predicted: its products (Lanczos, the Ritz vector's) and the operator's set-up (about two) */
    if (deadline > 0 && t0 + S->cost_unit[k] * units * (iters + 3) > deadline)
        return 0;
    double gersh = 0;
    double w2 = sq_lodx_sharp_estimate(lod, S, k, &gersh, deadline, S->cost_unit[k] * units);
    if (isnan(w2))
        return 0;
    double spent = sq_thread_cpu() - t0;
    S->cost_unit[k] = fmax(spent / (units * (S->iters[k] + 3)), 0.97 * S->cost_unit[k]);
    S->gersh[k] = gersh;
    S->lambda[k] = w2;
    S->calls++;
    take_estimate(lod, S, k, w2);
    if (sq_debug()->sharp_check && S->nsub[k] >= 0)
        sq_lodx_sharp_check(lod, S, k, w2);
    if (sq_debug()->sharp_trace) /* (after take_estimate's line; alone when Gershgorin's kept) */
        fprintf(stderr, "%s%.3f ms (%.0f units, %.1f ns per unit and product)\n",
                S->nsub[k] >= 0 ? ", " : "sharp: Gershgorin kept, ", 1e3 * spent, units,
                1e9 * spent / (units * (S->iters[k] + 3)));
    return 1;
}

/* the sharp substeps of every level with active nodes (after coupling_bound's Gershgorin ones):
 * extra_log2 becomes the sharp exponent less the level's own, negative when the sharp step is
 * longer than the level's own Gershgorin step. With a deadline (sq_lodx_sharp_deadline), an
 * estimate that cannot end by it is not made (or abandoned): that level keeps its Gershgorin
 * substeps, a rigorous bound, and owes its estimate (sq_lodx_sharp_owed); the levels are then
 * taken most node updates first (their estimates save the most) */
void sq_lodx_sharp_bound(sq_lod *lod)
{
    struct lod_sharp *S = lod->sharp;
    if (!S || !S->on || !lod->cpl.have_mat || lod->cpl.mat.use_viscosity)
        return;
    double t0 = sq_thread_cpu();
    int order[SQ_MAX_LEVELS];
    for (int k = 0; k < lod->L; k++)
        order[k] = k;
    if (S->deadline > 0) /* most node updates first: active nodes x substeps (Gershgorin's now) */
        for (int i = 1; i < lod->L; i++)
            for (int j = i; j > 0; j--) {
                int a = order[j - 1], b = order[j];
                double ua = ldexp((double)lod->lev[a].lay.nactive, lod->lv[a].substeps_log2 + lod->lev[a].rate.extra_log2);
                double ub = ldexp((double)lod->lev[b].lay.nactive, lod->lv[b].substeps_log2 + lod->lev[b].rate.extra_log2);
                if (ub > ua) {
                    order[j - 1] = b;
                    order[j] = a;
                }
            }
    for (int o = 0; o < lod->L; o++) {
        int k = order[o];
        if (lod->lev[k].lay.nactive == 0) {
            S->lambda[k] = S->gersh[k] = 0;
            S->have_key[k] = 0;
            S->owed[k] = 0;
            continue;
        }
        /* the rows this level's estimate reads did not change since its last estimate: the
         * same estimate (the Gershgorin pass before rewrote extra_log2: put it back; an owed
         * estimate stays owed) */
        unsigned long long key = level_key(lod, S, k);
        if (S->have_key[k] && S->key[k] == key) {
            if (S->nsub[k] >= 0)
                lod->lev[k].rate.extra_log2 = S->nsub[k] - lod->lv[k].substeps_log2;
            S->skipped++;
            continue;
        }
        S->key[k] = key;
        S->have_key[k] = 1;
        S->nsub[k] = -1;
        S->lambda[k] = S->gersh[k] = 0;
        S->owed[k] = !estimate_by(lod, S, k, S->deadline);
        if (S->owed[k]) {
            S->late++;
            if (sq_debug()->sharp_trace)
                fprintf(stderr, "sharp L%d: %d active, not made by its deadline (%d steps): Gershgorin 2^%d, owed\n",
                        k, lod->lev[k].lay.nactive, S->iters[k], lod->lv[k].substeps_log2 + lod->lev[k].rate.extra_log2);
        }
    }
    S->cpu_s += sq_thread_cpu() - t0;
}

void sq_lodx_sharp_deadline(sq_lod *lod, double cpu_deadline)
{
    if (lod->sharp)
        lod->sharp->deadline = cpu_deadline > 0 ? cpu_deadline : 0;
}

int sq_lodx_sharp_owed(sq_lod *lod, double seconds)
{
    struct lod_sharp *S = lod->sharp;
    if (!S || !S->on || !lod->cpl.have_mat || lod->cpl.mat.use_viscosity)
        return 0;
    double t0 = sq_thread_cpu(), deadline = isfinite(seconds) ? t0 + fmax(seconds, 1e-12) : 0;
    int made = 0;
    for (int k = 0; k < lod->L; k++) {
        if (!S->owed[k] || !S->have_key[k] || lod->lev[k].lay.nactive == 0)
            continue;
        /* the operator is the one the owed estimate was keyed on: a pass since would have
         * made the estimate again */
        if (estimate_by(lod, S, k, deadline)) {
            S->owed[k] = 0;
            S->made_later++;
            made++;
        }
    }
    S->cpu_s += sq_thread_cpu() - t0;
    return made;
}

int sq_lodx_sharp_owes(const sq_lod *lod, int k)
{
    const struct lod_sharp *S = lod->sharp;
    if (!S)
        return 0;
    int n = 0;
    for (int m = 0; m < lod->L; m++)
        if ((k < 0 || m == k) && S->owed[m] && S->have_key[m])
            n++;
    return n;
}

void sq_lodx_sharp_late(const sq_lod *lod, long *late, long *made_later)
{
    const struct lod_sharp *S = lod->sharp;
    *late = S ? S->late : 0;
    *made_later = S ? S->made_later : 0;
}

void sq_lod_set_step_rule(sq_lod *lod, int sharp, double step_fraction)
{
    if (!lod->sharp)
        lod->sharp = sq_calloc(1, sizeof(struct lod_sharp));
    struct lod_sharp *S = lod->sharp;
    int changed = S->on != (sharp != 0) || S->step_fraction != step_fraction;
    S->on = sharp != 0;
    S->step_fraction = step_fraction;
    if (changed) {
        memset(S->have_key, 0, sizeof S->have_key);
        memset(S->owed, 0, sizeof S->owed);
    }
    /* the node-sized arrays made (and their pages touched) now, at load, rather than at the
     * first split into a level (a first touch cost 8 ms on box-big's finest level) */
    for (int k = 0; S->on && k < lod->L; k++) {
        int n = SQ_MAX(lod->lv[k].model.n, 1);
        if (!S->ritz[k]) {
            S->ritz[k] = sq_malloc(sizeof(double) * 3 * (size_t)n);
            memset(S->ritz[k], 0, sizeof(double) * 3 * (size_t)n);
        }
        if (!S->u[k]) {
            S->u[k] = sq_malloc(sizeof(double) * 3 * (size_t)n);
            memset(S->u[k], 0, sizeof(double) * 3 * (size_t)n);
        }
        if (!S->idx[k]) {
            S->idx[k] = sq_malloc(sizeof(int) * (size_t)n);
            for (int i = 0; i < lod->lv[k].model.n; i++)
                S->idx[k][i] = -1;
        }
    }
    if (changed && lod->cpl.have_mat)
        sq_lodx_coupling_bound(lod); /* Gershgorin substeps, then the sharp ones if on */
}

int sq_lod_sharp_info(const sq_lod *lod, int k, double *lambda, double *gersh, int *iters)
{
    const struct lod_sharp *S = lod->sharp;
    if (!S || !S->on || k < 0 || k >= lod->L)
        return 0;
    if (lambda)
        *lambda = S->lambda[k];
    if (gersh)
        *gersh = S->gersh[k];
    if (iters)
        *iters = S->iters[k];
    return 1;
}

void sq_lod_sharp_cost(const sq_lod *lod, long *calls, double *cpu_s)
{
    const struct lod_sharp *S = lod->sharp;
    *calls = S ? S->calls : 0;
    *cpu_s = S ? S->cpu_s : 0;
}

void sq_lodx_sharp_free(sq_lod *lod)
{
    struct lod_sharp *S = lod->sharp;
    if (!S)
        return;
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        free(S->ritz[k]);
        free(S->idx[k]);
        free(S->u[k]);
        free(S->ritz_nodes[k]);
    }
    free(S->basis);
    free(S);
    lod->sharp = NULL;
}
