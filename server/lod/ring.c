/* ring.c - stage: the ring ghosts as combinations of active nodes, and their reactions.
 *
 * Each ring ghost (a ghost next to an active node) is expanded into active sources over up to
 * two hops (sq_lodx_build_sources); its value is evaluated from them at a tick, linearly in time over
 * a source level's step (sq_lodx_eval_ring: the frame's ghost stage); the force on it is handed back
 * to the same sources with the same weights (sq_lodx_couple_out: part of the frame's step stage).
 */
#include "lod/lod.h"
#include "lod/corotational.h"
#include "lod/ring.h"
#include "lod/tick.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>


/* ---------------------------------------------------------------- coupling
 *
 * The paper couples levels through ghost values only: an active node feels its ghost
 * neighbours, and nothing feels the reaction. That operator is not symmetric: measured on
 * an undamped cube with half of it refined, the energy of the paper's scheme grows (x60 in
 * 4 s), and with a little damping a released poke never comes back to rest, so regions never
 * merge. Here the simulated system is the gradient of one energy,
 *     E = sum_k 1/2 x_k^T K_k[S_k, S_k] x_k,   S_k = active nodes of level k and their ghost ring,
 * where each ring ghost is a fixed linear combination of active nodes: its interpolation in
 * the next coarser (coarse ghost) or finer (split ghost) mesh, expanded through ghost sources
 * up to SOURCE_DEPTH hops, sources that are still ghosts dropped and the weights renormalised
 * to sum 1 (so a translation stays force-free). Ghost values are evaluated from those active
 * nodes, and the force -(K x)_j on a ring ghost (restricted to S_k) is handed back to the
 * same active nodes with the same weights: the transpose of the interpolation. Active rows
 * are full rows, so a uniform state (every region at one level) is exactly the fixed-level
 * operator. Levels step at their own rates: a finer level reads coarser sources linearly in
 * time over the coarser step; forces handed to a finer level are held for the giving level's
 * step; forces handed to a coarser level are sampled at that level's own step. */

#define SOURCE_DEPTH 2

typedef sq_lodx_source src_item;

int sq_lodx_source_cmp(const void *pa, const void *pb)
{
    const src_item *a = pa, *b = pb;
    if (a->level != b->level)
        return a->level < b->level ? -1 : 1;
    return (a->node > b->node) - (a->node < b->node);
}

static void expand(const sq_lod *lod, int lev, int j, double w, int depth, int max_depth, int anchors,
                   src_item **buf, int *n, int *cap)
{
    const unsigned char st = lod->lev[lev].lay.state[j];
    if (st == ST_ACTIVE || (anchors && lod->lv[lev].model.fixed[j])) {
        if (*n == *cap) {
            *cap = *cap ? 2 * *cap : 256;
            *buf = sq_realloc(*buf, sizeof(src_item) * (size_t)*cap);
        }
        (*buf)[(*n)++] = st == ST_ACTIVE ? (src_item){lev, j, w} : (src_item){-1, -1, w};
        return;
    }
    if (depth >= max_depth)
        return;
    int m;
    const double *b;
    const int *tn = sq_lodx_interp_tet(lod, lev, j, st == ST_COARSE, &m, &b);
    if (!tn)
        return;
    for (int q = 0; q < 4; q++)
        if (b[q] != 0)
            expand(lod, m, tn[q], w * b[q], depth + 1, max_depth, anchors, buf, n, cap);
}

void sq_lodx_expand(const sq_lod *lod, int lev, int j, int max_depth, int anchors, sq_lodx_source **buf, int *n,
                    int *cap)
{
    *n = 0;
    expand(lod, lev, j, 1.0, 0, max_depth, anchors, buf, n, cap);
}

int sq_lodx_sources_combine(sq_lodx_source *buf, int n, double *sum_out)
{
    for (int i = 1; i < n; i++) { /* a few dozen items: insertion sort */
        src_item x = buf[i];
        int q = i - 1;
        while (q >= 0 && sq_lodx_source_cmp(&buf[q], &x) > 0) {
            buf[q + 1] = buf[q];
            q--;
        }
        buf[q + 1] = x;
    }
    /* merge duplicates; the sum is the callers' to divide by */
    int u = 0;
    double sum = 0;
    for (int i = 0; i < n; i++) {
        if (u > 0 && buf[u - 1].level == buf[i].level && buf[u - 1].node == buf[i].node)
            buf[u - 1].w += buf[i].w;
        else
            buf[u++] = buf[i];
        sum += buf[i].w;
    }
    /* the kept weights must stay a bounded combination: the ghost's stiffness reaches
     * each source scaled by its weight, twice (value and reaction), so the coupled row
     * grows as the square of the weights. Negative coordinates (nodes outside the
     * other mesh) extrapolate exactly only within their full set; once ghost sources
     * are dropped, what is left can nearly cancel (a sphere's split ghost kept
     * +0.056 and -0.054: weights of +-19 after dividing by the sum, 190 times the
     * level's own stiffness on one node). When the negative weights outweigh the net
     * one (L1 norm above 3 after renormalising; a full coordinate set with one
     * coordinate down to -1 stays below), keep the positive sources only: a convex
     * combination, still a translation. */
    double neg = 0;
    for (int i = 0; i < u; i++)
        neg += buf[i].w < 0 ? -buf[i].w : 0;
    if (neg > 0 && !(sum > neg)) {
        int p = 0;
        sum = 0;
        for (int i = 0; i < u; i++)
            if (buf[i].w > 0) {
                buf[p++] = buf[i];
                sum += buf[i].w;
            }
        u = p;
    }
    if (!(fabs(sum) > 1e-3))
        u = 0;
    *sum_out = sum;
    return u;
}

/* the active sources of every ring ghost of every level */
/* src_rend of every ring ghost's sources: where the run of consecutive sources on the same
 * level as source q ends (the value and reaction loops take one run per level) */
static void source_runs(sq_lod_level *lk)
{
    if (lk->lay.nring == 0)
        return;
    lk->lay.src_rend = sq_realloc(lk->lay.src_rend, sizeof(int) * (size_t)SQ_MAX(lk->lay.src_cap, 1));
    for (int r = 0; r < lk->lay.nring; r++)
        for (int q = lk->lay.src_start[r + 1] - 1; q >= lk->lay.src_start[r]; q--)
            lk->lay.src_rend[q] = q + 1 < lk->lay.src_start[r + 1] && lk->lay.src_level[q + 1] == lk->lay.src_level[q]
                                  ? lk->lay.src_rend[q + 1] : q + 1;
}

void sq_lodx_build_sources(sq_lod *lod)
{
    src_item *buf = NULL;
    int cap = 0;
    for (int k = 0; k < lod->L; k++) {
        int total = 0;
        lod->lev[k].lay.src_start[0] = 0;
        sq_lodx_tick_hot_stale(lod, k);
        for (int r = 0; r < lod->lev[k].lay.nring; r++) {
            int n;
            sq_lodx_expand(lod, k, lod->lev[k].lay.ring[r], SOURCE_DEPTH, 0, &buf, &n, &cap);
            double sum;
            int u = sq_lodx_sources_combine(buf, n, &sum); /* 0: no active source, the ghost keeps
                                                            * its value and takes no force */
            if (total + u > lod->lev[k].lay.src_cap) {
                lod->lev[k].lay.src_cap = SQ_MAX(2 * lod->lev[k].lay.src_cap, total + u + 1024);
                size_t scap = (size_t)lod->lev[k].lay.src_cap;
                lod->lev[k].lay.src_level = sq_realloc(lod->lev[k].lay.src_level, sizeof(int) * scap);
                lod->lev[k].lay.src_node = sq_realloc(lod->lev[k].lay.src_node, sizeof(int) * scap);
                lod->lev[k].lay.src_weight = sq_realloc(lod->lev[k].lay.src_weight, sizeof(double) * scap);
                lod->lev[k].lay.src_rend = sq_realloc(lod->lev[k].lay.src_rend, sizeof(int) * scap);
            }
            for (int i = 0; i < u; i++) {
                lod->lev[k].lay.src_level[total + i] = buf[i].level;
                lod->lev[k].lay.src_node[total + i] = buf[i].node;
                lod->lev[k].lay.src_weight[total + i] = buf[i].w / sum;
            }
            for (int i = u - 1; i >= 0; i--) /* each source's run of its level ends at */
                lod->lev[k].lay.src_rend[total + i] =
                    i + 1 < u && buf[i + 1].level == buf[i].level ? lod->lev[k].lay.src_rend[total + i + 1] : total + i + 1;
            unsigned char bits = 0;
            for (int i = 0; i < u; i++)
                bits |= (unsigned char)(1u << buf[i].level);
            lod->lev[k].lay.src_levels[r] = bits;
            total += u;
            lod->lev[k].lay.src_start[r + 1] = total;
        }
    }
    free(buf);
    if (sq_lodx_corot_on(lod)) {
        sq_lodx_corot_affine_sources(lod); /* corotational levels: weights exact for affine fields */
        /* it rewrites the source lists (and may add sources): their level runs again */
        for (int k = 0; k < lod->L; k++)
            source_runs(&lod->lev[k]);
    }
}
