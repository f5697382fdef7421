/* guard.c - the guaranteed frame rate's cost model and the guard's own changes to the layout
 * (docs/lod.md, "Guaranteed frame rate"): the learned costs (sq_lodx_learn), what a pass and a
 * region cost, the node updates that fit; the merges the guard makes when a frame would not fit,
 * the pass limit (which regions a split/merge pass may change), the rest of merged regions.
 * frame.c's and pass.c's stages measure and ask; this file holds the model's arithmetic, its
 * learning and the guard's parts of the stages (the guard stage, the budgeted split/merge).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "lod/criterion.h"
#include "lod/frame.h"
#include "lod/guard.h"
#include "lod/lod_test.h"
#include "lod/state.h"

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

/* every region at level 0, the cheapest layout */
double sq_lodx_guard_coarse_cost(const sq_lod *lod)
{
    return lod->guard.cost_fixed +
           lod->guard.cost_update * (double)((long)lod->lv[0].model.nfree << sub_log2(lod, 0));
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

/* ---------------------------------------------------------------- the guard's parts of the stages
 *
 * frame.c's stages run these on the frame's context (lod_frame, frame.h): the guard stage's
 * budget and cap, the cost per update measured by the ticks, the budgeted split/merge of the
 * criterion stage, the frame's cost at its end; pass.c's pass hands over its measured parts. */

void sq_lod_untimed(sq_lod *lod, double cpu_s)
{
    if (cpu_s > 0)
        lod->guard.untimed += cpu_s;
}

/* guaranteed frame rate, the guard stage (frame.c's stage_guard): no splitting after a frame
 * over budget (merging still allowed); the frame's budget less the time around it. Returns 1
 * with a budget (then the pass's reserve and calibration, sq_lodx_pass_prepare, and
 * sq_lodx_guard_cap follow) */
int sq_lodx_guard_open(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    double budget_s = fr->in->budget_s;
    fr->prev_time = lod->guard.last_time;
    fr->fr_budget = lod->def.budget * budget_s;
    /* the thread's time between two frames of this body (the body's own work around the lod
     * frame: tool holds, node levels, health; the caller's between its steps, less what it
     * declared not the product's, sq_lod_untimed), up to a quarter of the period, is not the
     * lod's */
    fr->outside_raw = lod->guard.last_c_end > 0 ? fr->c_start - lod->guard.last_c_end - lod->guard.untimed : 0;
    lod->guard.untimed = 0;
    if (budget_s > 0 && lod->guard.last_c_end > 0) {
        double outside = fmin(fmax(fr->outside_raw, 0.0), 0.25 * budget_s);
        sq_lodx_guard_learn(lod, &lod->guard.cost_outside, &lod->guard.tr_outside, outside);
        fr->fr_budget = fmax(0.0, fr->fr_budget - lod->guard.cost_outside);
    }
    fr->over_budget = budget_s > 0 && fr->prev_time > fr->fr_budget;
    fr->cap_user = lod->def.max_node_updates;
    fr->cap_guard = 0;
    if (budget_s <= 0)
        return 0;
    lod->guard.guard_clock++;
    return 1;
}

/* the node updates the next frames may have (the cost model above), once the pass terms are
 * calibrated */
void sq_lodx_guard_cap(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    fr->guard_on = lod->guard.cost_update > 0;
    if (fr->guard_on) /* the layout must fit without a pass */
        fr->cap_guard = sq_lodx_guard_updates_fitting(lod, fr->fr_budget);
}

/* a measured tick time per node update into the cost model */
static void learn_update(sq_lod *lod, double c_ticks, long updates)
{
    if (updates > 0)
        sq_lodx_guard_learn(lod, &lod->guard.cost_update, &lod->guard.tr_update, c_ticks / (double)updates);
}

void sq_lodx_guard_ticks_measured(lod_frame *fr)
{
    sq_lod *lod = fr->lod;
    learn_update(lod, fr->c_ticks, fr->tc.updates);
    if (fr->in->budget_s > 0 && lod->guard.cost_update > 0 && lod->guard.cost_calibrated)
        fr->guard_on = 1;
}

/* the criterion stage with the guard on (docs/lod.md "Guaranteed frame rate"): a pair of
 * levels is adapted only when its rebuild fits in what is left of the frame; splits stop where
 * the next frame and a pass would pass SQ_GUARD_SPLIT_HEADROOM of the budget; regions the
 * guard merged rest; and when the next frame would not fit even without a pass, the least
 * needed regions merge. now: the thread CPU clock at the stage's start; pairs: the split/merge
 * pairs run this frame (def.adapt_every) */
void sq_lodx_guard_adapt(lod_frame *fr, double now, int pairs)
{
    sq_lod *lod = fr->lod;
    int L = lod->L;
    double B = fr->fr_budget;
    /* what is left of this frame once the rest of it (push, feedback: within the fixed cost)
     * is paid */
    double used = lod->guard.cost_given ? lod->guard.cost_update * (double)fr->tc.updates + fr->modeled_pass : now - fr->c_start;
    double left = B - used - lod->guard.cost_fixed;
    long keep = sq_lodx_guard_updates_fitting(lod, B);
    long split_cap = sq_lodx_guard_updates_fitting(lod, SQ_GUARD_SPLIT_HEADROOM * B - SQ_GUARD_PASS_MARGIN * sq_lodx_guard_pass_cost(lod, sq_lodx_guard_all_levels(lod), 0));
    if (fr->cap_user > 0) {
        keep = SQ_MIN(keep, fr->cap_user);
        split_cap = SQ_MIN(split_cap, fr->cap_user);
    }
    unsigned sched = 0;
    for (int k = 0; k + 1 < L && k < lod->top && pairs; k++) {
        double pc = SQ_GUARD_PASS_MARGIN * sq_lodx_guard_pass_cost(lod, 3u << k, sched);
        if (pc > left) {
            fr->ao.refused = 1; /* deferred: this pair's splits and merges wait for a frame with room */
            continue;
        }
        /* the regions this pass can change; when the criterion wants more, the merges it
         * wants (least needed first), then the splits (most needed first) up to that count,
         * the others held out of this pass */
        double rc = SQ_GUARD_PASS_MARGIN * sq_lodx_guard_region_cost(lod, k);
        long afford = rc > 0 ? (long)fmin(1e9, fmax(0.0, (left - pc) / rc)) : 1000000000L;
        int allow = !fr->over_budget && split_cap > 0 && fr->projected < split_cap;
        int s0 = fr->ao.splits, m0 = fr->ao.merges;
        lod->def.max_node_updates = split_cap;
        sq_lodx_guard_rest_mask(lod, k, 1);
        long held = sq_lodx_guard_limit(lod, k, allow, afford);
        sq_lodx_adapt_pair(lod, k, allow, &fr->projected, &fr->ao);
        if (held > 0) {
            sq_lodx_guard_limit_undo(lod, k);
            fr->ao.refused = 1;
        }
        sq_lodx_guard_rest_mask(lod, k, 0);
        unsigned now_sched = 0;
        for (int m = 0; m < L; m++)
            now_sched |= fr->ao.changed[m] ? 1u << m : 0u;
        left -= SQ_GUARD_PASS_MARGIN * sq_lodx_guard_pass_cost(lod, now_sched, sched) + rc * (double)(fr->ao.splits - s0 + fr->ao.merges - m0);
        sched = now_sched;
    }
    lod->def.max_node_updates = fr->cap_user;
    if (fr->projected > keep) {
        /* the next frame would not fit even without a pass: merge the least needed regions,
         * as many as this frame can rebuild (the next frame's layout stage merges the rest) */
        double pc = SQ_GUARD_PASS_MARGIN * sq_lodx_guard_pass_cost(lod, sq_lodx_guard_all_levels(lod), sched), rc = 0;
        for (int k = 0; k + 1 < L; k++)
            rc = fmax(rc, SQ_GUARD_PASS_MARGIN * sq_lodx_guard_region_cost(lod, k));
        long most = rc > 0 ? (long)fmin(1e9, (left - pc) / rc) : 1000000000L;
        if (most > 0)
            fr->guard_merges += sq_lodx_guard_merge(lod, keep, &fr->projected, &fr->ao, SQ_GUARD_REST_FRAMES, most);
    }
}

void sq_lodx_guard_pass_measured(sq_lod *lod, unsigned mask, const double *t_level, const long *nchg, double couple)
{
    int L = lod->L;
    /* learn: each level's list rebuild; its block build, as a floor when none of its nodes
     * changed (the calibration pass), else per changed node above the floor; the bound; the
     * rest (sources, needed set) */
    for (int k = 0; k < L; k++) {
        if (!(mask & (1u << k)) && lod->lev[k].cpl.blocks_cpu == 0)
            continue;
        if (mask & (1u << k))
            sq_lodx_guard_learn_pass(lod, &lod->guard.cost_level[k], &lod->guard.tr_level[k], t_level[k]);
        if (nchg[k] == 0)
            sq_lodx_guard_learn_pass(lod, &lod->guard.cost_blocks[k], &lod->guard.tr_blocks[k], lod->lev[k].cpl.blocks_cpu);
        else
            sq_lodx_guard_learn_pass(lod, &lod->guard.cost_block_change[k], &lod->guard.tr_block_change[k],
                  fmax(0.0, lod->lev[k].cpl.blocks_cpu - lod->guard.cost_blocks[k]) / (double)nchg[k]);
    }
    sq_lodx_guard_learn_pass(lod, &lod->guard.cost_bound, &lod->guard.tr_bound, lod->cpl.bound_cpu);
    sq_lodx_guard_learn_pass(lod, &lod->guard.cost_couple, &lod->guard.tr_couple, couple);
}

void sq_lodx_guard_calibrated(sq_lod *lod)
{
    lod->guard.cost_calibrated = 1;
    /* a start for the cost per changed node until passes measure it (the decaying maximum then
     * rises at once to a higher measurement, and falls 3 % a pass) */
    for (int k = 0; k < lod->L && !lod->guard.cost_given; k++)
        lod->guard.cost_block_change[k] = fmax(lod->guard.cost_block_change[k], SQ_GUARD_BLOCK_CHANGE_START);
}

long sq_lodx_guard_frame_end(lod_frame *fr, double c_end, double cpu)
{
    sq_lod *lod = fr->lod;
    long updates = fr->tc.updates;
    lod->guard.last_c_end = c_end;
    if (fr->c_ticks == 0 && updates > 0) { /* a frame abandoned before its criterion stage */
        fr->c_ticks = fmax(0.0, cpu - fr->c_pass);
        learn_update(lod, fr->c_ticks, updates);
    }
    /* what is neither ticks nor passes (nor the reserve and owed estimates, done only with room left):
     * criterion, push, feedback, guard, layout, holds */
    sq_lodx_guard_learn(lod, &lod->guard.cost_fixed, &lod->guard.tr_fixed, fmax(0.0, cpu - fr->c_ticks - fr->c_pass - fr->c_reserve - fr->c_owed));
    lod->guard.guard_modeled = lod->guard.cost_fixed + lod->guard.cost_update * (double)updates + fr->modeled_pass;
    lod->guard.last_time = lod->guard.cost_given ? lod->guard.guard_modeled : cpu; /* given costs: deterministic */
    long next = sq_lod_projected_updates(lod);
    lod->guard.guard_predicted = lod->guard.cost_fixed + lod->guard.cost_update * (double)next;
    return next;
}
