/* criterion.c - stage: the split/merge criterion and the decisions it drives.
 *
 * delta_i = hbar_i^2 |Lap(d)_i| (paper Eq. 9) with the boundary-corrected lumped Laplacian
 * (its weights made at creation, state.c's sq_lodx_criterion_weights),
 * judged from each level's static equilibrium; splits of active nodes above lod.split (or
 * inside one of the frame's focus spheres), merges of split nodes whose children are all
 * below lod.merge (never inside a focus sphere) (each made by state.c's
 * sq_lodx_split_node, sq_lodx_merge_node), the node-update cap
 * (sq_lodx_enforce_cap), and the stand-alone pass sq_lod_adapt. The frame runs this at its end, when
 * every level is at the same time (frame.c's criterion stage).
 */
#include "lod/lod.h"
#include "lod/activeset.h"
#include "lod/criterion.h"
#include "lod/state.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>


/* ---------------------------------------------------------------- split / merge */

/* delta_i = hbar_i^2 |Lap(d - d_static)_i| at node i of level k (boundary-corrected
 * Laplacian); the one computation of the criterion: the split/merge pass here, sq_lod_delta
 * and the guard's ranking (activeset.c) all call it */
double sq_lodx_delta(const sq_lod *lod, int k, int i)
{
    const sq_lod_level *lk = &lod->lev[k];
    const sq_level *L = &lod->lv[k];
    const double *w = lk->tab.crit_weight;
    double s[3] = {0, 0, 0};
    const unsigned char *st = lk->lay.state;
    const unsigned *ps = lk->lists.push_stamp;
    int all_valid = lod->push.full_no == lod->push.cascade_no;
    const double *ds = lk->d_static;
    for (int q = L->model.row_start[i]; q < L->model.row_start[i + 1]; q++) {
        int j = L->model.col[q];
        const double *dj = L->state.d + 3 * j;
        double fresh[3], fv[3];
        if (k > 0 && st[j] == ST_COARSE && !all_valid && ps[j] != lod->push.cascade_no) {
            /* a neighbour the last cascade did not push (a node that just became active in
             * this split pass sees beyond the old ring): its value now, on demand */
            sq_lodx_value(lod, k, j, fresh, fv);
            dj = fresh;
        }
        if (ds) {
            /* the motion from the static equilibrium (the sag alone has no curvature here) */
            if (dj != fresh)
                memcpy(fresh, dj, sizeof fresh);
            fresh[0] -= ds[3 * j];
            fresh[1] -= ds[3 * j + 1];
            fresh[2] -= ds[3 * j + 2];
            dj = fresh;
        }
        s[0] += w[q] * dj[0];
        s[1] += w[q] * dj[1];
        s[2] += w[q] * dj[2];
    }
    double h2 = L->model.hbar[i] * L->model.hbar[i];
    return h2 / L->model.vol[i] * sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
}

double sq_lod_delta(const sq_lod *lod, int level, int node)
{
    if (level < 0 || level >= lod->L || node < 0 || node >= lod->lv[level].model.n)
        return 0;
    sq_lod_flush((sq_lod *)lod); /* ghost values pushed on demand are part of the state */
    return sq_lodx_delta(lod, level, node);
}

/* node i of level k (at its rest position plus its displacement) lies within its mean edge
 * length (hbar) of a focus sphere of the frame (sq_lod_frame_in.focus): its neighbourhood
 * reaches into the sphere, so it is kept at the finest level (a coarse node whose tets cover
 * the sphere splits though the node itself lies outside) */
static int in_focus(const sq_lod *lod, int k, int i)
{
    const sq_level *L = &lod->lv[k];
    const double *x = L->model.mesh->x + 3 * (size_t)i, *d = L->state.d + 3 * (size_t)i;
    for (int s = 0; s < lod->nfocus; s++) {
        const double *f = lod->focus[s], reach = f[3] + L->model.hbar[i];
        double r2 = 0;
        for (int c = 0; c < 3; c++)
            r2 += (x[c] + d[c] - f[c]) * (x[c] + d[c] - f[c]);
        if (r2 < reach * reach)
            return 1;
    }
    return 0;
}

/* split/merge between levels k and k+1 (both at the same time); `allow_split` from the
 * budget; the node-update cap refuses splits that would exceed it */
void sq_lodx_adapt_pair(sq_lod *lod, int k, int allow_split, long *projected, adapt_out *out)
{
    sq_lod_level *lk = &lod->lev[k];
    if (k >= lod->top)
        return;
    const sq_lod_def *def = &lod->def;
    const sq_lod_link *ln = &lod->h.link[k];
    sq_level *Lk = &lod->lv[k];
    int forced = def->split <= 0;
    long cost_k = 1L << sub_log2(lod, k), cost_f = 1L << sub_log2(lod, k + 1);
    int changed = 0;

    /* splits: active nodes of level k above the threshold */
    if (def->split < INFINITY) {
        for (int i = 0; i < Lk->model.n; i++) {
            if (lk->lay.state[i] != ST_ACTIVE)
                continue;
            if (!forced && !(sq_lodx_delta(lod, k, i) > def->split) && !(lod->nfocus && in_focus(lod, k, i)))
                continue;
            int nch = ln->child_start[i + 1] - ln->child_start[i];
            long extra = nch * cost_f - cost_k;
            if (!allow_split || (def->max_node_updates > 0 && *projected + extra > def->max_node_updates)) {
                out->refused = 1;
                continue;
            }
            sq_lodx_split_node(lod, k, i); /* children from their interpolated d and v (state.c) */
            *projected += extra;
            out->splits++;
            changed = 1;
        }
    }

    /* merges: split nodes of level k whose children are all active and calm */
    if (!forced) {
        int parent_test = lk->d_static != NULL;
        if (parent_test)
            sq_lodx_pull_level(lod, k);
        for (int p = 0; p < Lk->model.n; p++) {
            if (lk->lay.state[p] != ST_SPLIT || lk->lay.fresh[p] || (lod->nfocus && in_focus(lod, k, p)))
                continue;
            int ok = 1;
            int c0 = ln->child_start[p], c1 = ln->child_start[p + 1];
            for (int c = c0; c < c1 && ok; c++)
                if (lod->lev[k + 1].lay.state[ln->child[c]] != ST_ACTIVE)
                    ok = 0;
            if (!ok)
                continue;
            if (c1 == c0) {
                /* no child: judge the node on its own (interpolated) field */
                if (!(sq_lodx_delta(lod, k, p) < def->merge))
                    continue;
            } else {
                for (int c = c0; c < c1 && ok; c++)
                    if (!(sq_lodx_delta(lod, k + 1, ln->child[c]) < def->merge))
                        ok = 0;
                if (ok && parent_test && !(sq_lodx_delta(lod, k, p) < def->merge))
                    ok = 0;
                if (!ok)
                    continue;
            }
            sq_lodx_merge_node(lod, k, p);
            *projected -= (long)(c1 - c0) * cost_f - cost_k;
            out->merges++;
            changed = 1;
        }
    }
    sq_lodx_fresh_clear(lod, k);
    if (changed) {
        out->changed[k] = out->changed[k + 1] = 1;
    }
}

/* hard cap: merge the finest mergeable regions until the projected cost fits */
void sq_lodx_enforce_cap(sq_lod *lod, long *projected, adapt_out *out)
{
    long cap = lod->def.max_node_updates;
    if (cap <= 0 || *projected <= cap)
        return;
    for (int k = lod->top - 1; k >= 0 && *projected > cap; k--) {
        const sq_lod_link *ln = &lod->h.link[k];
        long cost_k = 1L << sub_log2(lod, k), cost_f = 1L << sub_log2(lod, k + 1);
        for (int p = 0; p < lod->lv[k].model.n && *projected > cap; p++) {
            if (lod->lev[k].lay.state[p] != ST_SPLIT)
                continue;
            int ok = 1;
            for (int c = ln->child_start[p]; c < ln->child_start[p + 1] && ok; c++)
                if (lod->lev[k + 1].lay.state[ln->child[c]] != ST_ACTIVE)
                    ok = 0;
            if (!ok)
                continue;
            sq_lodx_merge_node(lod, k, p);
            *projected -= (long)(ln->child_start[p + 1] - ln->child_start[p]) * cost_f - cost_k;
            out->merges++;
            out->changed[k] = out->changed[k + 1] = 1;
        }
    }
}

int sq_lod_adapt(sq_lod *lod, int allow_split, int *splits, int *merges)
{
    adapt_out ao;
    memset(&ao, 0, sizeof(ao));
    long projected = sq_lod_projected_updates(lod);
    for (int k = lod->L - 2; k >= 0; k--)
        sq_lodx_pull_level(lod, k);
    for (int k = 0; k + 1 < lod->L; k++)
        sq_lodx_adapt_pair(lod, k, allow_split, &projected, &ao);
    sq_lodx_enforce_cap(lod, &projected, &ao);
    for (int k = 0; k < lod->L; k++)
        if (ao.changed[k])
            sq_lodx_rebuild_level(lod, k);
    sq_lod_sync(lod);
    if (splits)
        *splits = ao.splits;
    if (merges)
        *merges = ao.merges;
    return ao.refused;
}
