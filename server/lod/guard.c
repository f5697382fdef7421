/* guard.c - the guaranteed frame rate's cost model and the guard's own changes to the layout
 * (docs/lod.md, "Guaranteed frame rate"): the learned costs (sq_lodx_learn), what a pass and a
 * region cost, the node updates that fit; the merges the guard makes when a frame would not fit,
 * the pass limit (which regions a split/merge pass may change), the rest of merged regions.
 * frame.c's stages measure and ask; this file holds the model's arithmetic.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "lod/criterion.h"
#include "lod/guard.h"
#include "lod/lod_test.h"

/* ---------------------------------------------------------------- the guard's cost model
 *
 * A frame costs (thread CPU time, docs/lod.md "Guaranteed frame rate")
 *     cost_fixed + cost_update x node updates
 *     + for a split/merge pass: cost_couple + cost_bound + sum over the levels it rebuilds of
 *       (cost_level[k] + cost_blocks[k] + cost_block_change[k] x the level's changed nodes)
 * each term a maximum over its measurements that decays by 10 % a frame (the frame terms) or
 * 3 % a pass (the pass terms, measured only when a pass runs), an isolated outlier bounded
 * (sq_lodx_learn), or given (sq_lodx_set_costs, tests). The floors of a pass are timed once by a pass that changes nothing (calibrate) at
 * load when the caller says a budget follows (sq_lod_prepare_budget), else at the first
 * budgeted frame. The budget is def.budget x the period less the thread's time
 * around the lod frame (cost_outside). The guard:
 *   - at the end of a frame, the split/merge pass of levels k, k+1 runs only if its rebuild
 *     fits in what is left of this frame (SQ_GUARD_PASS_MARGIN x the model), and changes at most the
 *     regions that fit with it: the merges the criterion wants, least needed first, then its
 *     splits, most needed first; the others wait (sq_lodx_guard_limit);
 *   - splits stop where the next frame and a pass of every level would pass SQ_GUARD_SPLIT_HEADROOM
 *     of the budget (the node-update cap of sq_lodx_adapt_pair);
 *   - when the next frame would not fit even without a pass, the least needed regions merge
 *     (this frame, as many as its rebuild allows, the rest at the start of the next);
 *   - a region the guard merged rests SQ_GUARD_REST_FRAMES frames before it may split again. */

void sq_lodx_set_costs(sq_lod *lod, double per_update_s, double per_frame_s, double per_level_s, double per_pass_s,
                       double per_change_s)
{
    lod->guard.cost_given = per_update_s > 0 || per_frame_s > 0 || per_level_s > 0 || per_pass_s > 0 || per_change_s > 0;
    lod->guard.cost_update = SQ_MAX(per_update_s, 0.0);
    lod->guard.cost_fixed = SQ_MAX(per_frame_s, 0.0);
    for (int k = 0; k < SQ_MAX_LEVELS; k++)
        lod->guard.cost_level[k] = SQ_MAX(per_level_s, 0.0);
    lod->guard.cost_couple = SQ_MAX(per_pass_s, 0.0);
    lod->guard.cost_bound = 0;
    for (int k = 0; k < SQ_MAX_LEVELS; k++) {
        lod->guard.cost_blocks[k] = 0;
        lod->guard.cost_block_change[k] = SQ_MAX(per_change_s, 0.0);
    }
    lod->guard.cost_calibrated = lod->guard.cost_given;
    lod->guard.tr_update = lod->guard.tr_fixed = lod->guard.tr_outside = lod->guard.tr_couple = lod->guard.tr_bound = (sq_cost_track){0};
    for (int k = 0; k < SQ_MAX_LEVELS; k++)
        lod->guard.tr_level[k] = lod->guard.tr_blocks[k] = lod->guard.tr_block_change[k] = (sq_cost_track){0};
}

/* nodes a split or merge between levels k and k+1 changes, on average: the parent and its
 * children */
static double changes_per_region(const sq_lod *lod, int k)
{
    return 1.0 + (double)lod->lv[k + 1].model.n / (double)SQ_MAX(lod->lv[k].model.n, 1);
}

/* the block rebuild a split or merge between levels k and k+1 costs: the parent's changed
 * node on level k, the children's on level k+1 */
double sq_lodx_guard_region_cost(const sq_lod *lod, int k)
{
    return lod->guard.cost_block_change[k] + (changes_per_region(lod, k) - 1) * lod->guard.cost_block_change[k + 1];
}

/* the cost of adding the levels in `mask` (bits) to a pass that rebuilds the levels in `done`
 * already, before its changed nodes (the coupling and the bound are redone once per pass) */
double sq_lodx_guard_pass_cost(const sq_lod *lod, unsigned mask, unsigned done)
{
    unsigned add = mask & ~done;
    if (!add)
        return 0;
    double c = done ? 0 : lod->guard.cost_couple + lod->guard.cost_bound;
    for (int k = 0; k < lod->L; k++)
        if (add & (1u << k))
            c += lod->guard.cost_level[k] + lod->guard.cost_blocks[k];
    return c;
}

/* A measured cost into its decaying maximum (given costs stay): 10 % a frame for the terms
 * measured every frame, 3 % a pass for a pass's terms (measured only when one runs; a pass's
 * block build varies up to 4x per changed node from one pass to the next on box-big). An
 * isolated spike of the machine is not learned as the cost (docs/lod.md "An isolated spike"):
 * a measurement above SPIKE_FRAME (SPIKE_PASS) x the term raises it only to that bound, and
 * the next ordinary measurement puts the term back where it would be without the spike; a
 * second such measurement within SPIKE_WINDOW measurements, of the first one's size (at most
 * the bound x it), is learned whole (a sustained rise is followed at its second frame or pass);
 * one far above the first (a small term's jitter, then a real spike) is a new isolated one. Without outliers the term is the decaying maximum
 * exactly as before. */
#define SPIKE_FRAME 2.0 /* box-big: node updates 110-125 ns each a frame; one spike frame 381 ns */
#define SPIKE_PASS 3.0  /* box-big: a level-0 build 3,855 us per changed node once, ~100 us around */
#define SPIKE_WINDOW 8

double sq_lodx_learn(sq_cost_track *t, double cost, double measured, double decay, double spike)
{
    double ref = t->since ? t->base : cost; /* the term without a pending outlier */
    if (ref <= 0 || measured <= spike * ref) {
        t->base = fmax(measured, decay * ref);
        if (t->since && ++t->since > SPIKE_WINDOW)
            t->since = 0;
        return t->base;
    }
    if (t->since && measured <= spike * t->peak) { /* a second outlier of its size: a real rise */
        t->since = 0;
        t->base = fmax(measured, decay * cost);
        return t->base;
    }
    t->since = 1; /* an isolated one so far: bounded */
    t->peak = measured;
    t->base = decay * ref;
    return spike * ref;
}

void sq_lodx_guard_learn(const sq_lod *lod, double *cost, sq_cost_track *t, double measured)
{
    if (!lod->guard.cost_given)
        *cost = sq_lodx_learn(t, *cost, measured, 0.9, SPIKE_FRAME);
}

void sq_lodx_guard_learn_pass(const sq_lod *lod, double *cost, sq_cost_track *t, double measured)
{
    if (!lod->guard.cost_given)
        *cost = sq_lodx_learn(t, *cost, measured, 0.97, SPIKE_PASS);
}

/* every level that may take part in a pass: up to the highest simulated level + 1 */
unsigned sq_lodx_guard_all_levels(const sq_lod *lod)
{
    int hi = 0;
    for (int k = 0; k < lod->L; k++)
        if (lod->lev[k].lay.nactive > 0)
            hi = k;
    hi = SQ_MIN(hi + 1, lod->top);
    return (2u << hi) - 1;
}

/* node updates that fit in `seconds` of a frame's budget after its fixed cost */
long sq_lodx_guard_updates_fitting(const sq_lod *lod, double seconds)
{
    double fit = (seconds - lod->guard.cost_fixed) / lod->guard.cost_update;
    return fit > 1e15 ? (long)1e15 : SQ_MAX((long)fit, 0L);
}

/* nodes of level k the guard merged and that still rest: out of the split pass (their state
 * is masked as ST_RESTING while sq_lodx_adapt_pair runs: neither split nor merge reads it as
 * active); hide = 0 restores them and counts any that was split in its rest anyway */
void sq_lodx_guard_rest_mask(sq_lod *lod, int k, int hide)
{
    int *h = lod->guard.guard_hold[k];
    if (!h || lod->guard.guard_hold_until[k] <= lod->guard.guard_clock)
        return;
    unsigned char *st = lod->lev[k].lay.state;
    for (int p = 0; p < lod->lv[k].model.n; p++) {
        if (h[p] <= lod->guard.guard_clock)
            continue;
        if (hide && st[p] == ST_ACTIVE)
            st[p] = ST_RESTING;
        else if (!hide && st[p] == ST_RESTING)
            st[p] = ST_ACTIVE;
        else if (!hide && st[p] == ST_SPLIT)
            lod->test.guard_resplit++;
    }
}

/* ---------------------------------------------------------------- the guard's merges */

double sq_lodx_need(const sq_lod *lod, int k, int p)
{
    const sq_lod_link *ln = &lod->h.link[k];
    int c0 = ln->child_start[p], c1 = ln->child_start[p + 1];
    if (c0 == c1)
        return sq_lodx_delta(lod, k, p);
    double m = 0;
    for (int c = c0; c < c1; c++)
        m = fmax(m, sq_lodx_delta(lod, k + 1, ln->child[c]));
    return m;
}

typedef struct merge_cand {
    double need;
    int k, p;
} merge_cand;

/* least needed first; ties: finer level first, then node order (deterministic) */
static int cmp_cand(const void *pa, const void *pb)
{
    const merge_cand *a = pa, *b = pb;
    if (a->need != b->need)
        return a->need < b->need ? -1 : 1;
    if (a->k != b->k)
        return a->k > b->k ? -1 : 1;
    return (a->p > b->p) - (a->p < b->p);
}

long sq_lodx_guard_merge(sq_lod *lod, long cap, long *projected, adapt_out *out, int rest, long most)
{
    long made = 0;
    while (*projected > cap && made < most) {
        /* the regions mergeable now: split nodes whose children are all active */
        long nc = 0, capc = 0;
        merge_cand *cand = NULL;
        for (int k = 0; k < lod->top; k++) {
            const sq_lod_link *ln = &lod->h.link[k];
            const sq_lod_level *lk = &lod->lev[k];
            for (int a = 0; a < lk->lay.nsplit_ghost; a++) {
                int p = lk->lay.split_ghost[a], ok = lk->lay.state[p] == ST_SPLIT;
                for (int c = ln->child_start[p]; c < ln->child_start[p + 1] && ok; c++)
                    ok = lod->lev[k + 1].lay.state[ln->child[c]] == ST_ACTIVE;
                if (!ok)
                    continue;
                if (nc == capc) {
                    capc = SQ_MAX(2 * capc, 64L);
                    cand = sq_realloc(cand, sizeof(merge_cand) * (size_t)capc);
                }
                cand[nc].need = sq_lodx_need(lod, k, p);
                cand[nc].k = k;
                cand[nc].p = p;
                nc++;
            }
        }
        if (nc > 0)
            qsort(cand, (size_t)nc, sizeof(merge_cand), cmp_cand);
        long before = made;
        for (long c = 0; c < nc && *projected > cap && made < most; c++) {
            int k = cand[c].k, p = cand[c].p;
            const sq_lod_link *ln = &lod->h.link[k];
            long nch = ln->child_start[p + 1] - ln->child_start[p];
            sq_lodx_merge_node(lod, k, p);
            *projected -= nch * (1L << sub_log2(lod, k + 1)) - (1L << sub_log2(lod, k));
            if (!lod->guard.guard_hold[k])
                lod->guard.guard_hold[k] = sq_calloc((size_t)lod->lv[k].model.n, sizeof(int));
            lod->guard.guard_hold[k][p] = (int)SQ_MIN(lod->guard.guard_clock + rest, (long)1 << 30);
            lod->guard.guard_hold_until[k] = SQ_MAX(lod->guard.guard_hold_until[k], lod->guard.guard_hold[k][p]);
            out->merges++;
            out->changed[k] = out->changed[k + 1] = 1;
            made++;
        }
        free(cand);
        if (made == before)
            break; /* nothing mergeable is left (every level at 0) */
    }
    lod->guard.guard_merged_total += made;
    return made;
}

/* ---------------------------------------------------------------- the guard's pass limit */

typedef struct lim_cand {
    double need;
    int p, split; /* 1: an active node over the split threshold, 0: a mergeable split node */
} lim_cand;

/* merges first, least needed first; then splits, most needed first; ties in node order */
static int cmp_lim(const void *pa, const void *pb)
{
    const lim_cand *a = pa, *b = pb;
    if (a->split != b->split)
        return a->split - b->split;
    if (a->need != b->need)
        return (a->split ? a->need > b->need : a->need < b->need) ? -1 : 1;
    return (a->p > b->p) - (a->p < b->p);
}

long sq_lodx_guard_limit(sq_lod *lod, int k, int allow_split, long most)
{
    sq_lod_level *lk = &lod->lev[k];
    const sq_lod_link *ln = &lod->h.link[k];
    const sq_lod_def *def = &lod->def;
    lk->lay.nlimited = 0;
    if (def->split <= 0 || k >= lod->top)
        return 0; /* forced finest: no criterion to rank by */
    long nc = 0;
    int n = lod->lv[k].model.n;
    lim_cand *c = sq_malloc(sizeof(lim_cand) * (size_t)SQ_MAX(n, 1));
    /* every active node, also those the pass of levels k-1, k made active just now (not in
     * the active list yet) */
    if (allow_split && def->split < INFINITY)
        for (int i = 0; i < n; i++) {
            if (lk->lay.state[i] != ST_ACTIVE)
                continue; /* ghost or resting */
            double d = sq_lodx_delta(lod, k, i);
            if (d > def->split)
                c[nc++] = (lim_cand){d, i, 1};
        }
    for (int a = 0; a < lk->lay.nsplit_ghost; a++) {
        int p = lk->lay.split_ghost[a], ok = lk->lay.state[p] == ST_SPLIT;
        for (int q = ln->child_start[p]; q < ln->child_start[p + 1] && ok; q++)
            ok = lod->lev[k + 1].lay.state[ln->child[q]] == ST_ACTIVE;
        if (!ok)
            continue;
        double need = sq_lodx_need(lod, k, p);
        if (need < def->merge)
            c[nc++] = (lim_cand){need, p, 0};
    }
    if (nc <= most) {
        free(c);
        return 0;
    }
    qsort(c, (size_t)nc, sizeof(lim_cand), cmp_lim);
    if (!lk->lay.limited)
        lk->lay.limited = sq_malloc(sizeof(int) * (size_t)SQ_MAX(lod->lv[k].model.n, 1));
    for (long q = SQ_MAX(most, 0L); q < nc; q++) {
        lk->lay.limited[lk->lay.nlimited++] = c[q].p;
        lk->lay.state[c[q].p] = c[q].split ? ST_LIMITED_ACTIVE : ST_LIMITED_SPLIT;
    }
    free(c);
    return lk->lay.nlimited;
}

void sq_lodx_guard_limit_undo(sq_lod *lod, int k)
{
    sq_lod_level *lk = &lod->lev[k];
    for (int q = 0; q < lk->lay.nlimited; q++) {
        int p = lk->lay.limited[q];
        lk->lay.state[p] = lk->lay.state[p] == ST_LIMITED_ACTIVE ? ST_ACTIVE : ST_SPLIT;
    }
    lk->lay.nlimited = 0;
}
