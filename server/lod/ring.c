/* ring.c - stage: the ring ghosts as combinations of active nodes, and their reactions.
 *
 * Each ring ghost (a ghost next to an active node) is expanded into active sources over up to
 * two hops (sq_lodx_build_sources); its value is evaluated from them at a tick, linearly in time over
 * a source level's step (sq_lodx_eval_ring: the frame's ghost stage); the force on it is handed back
 * to the same sources with the same weights (sq_lodx_couple_out: part of the frame's step stage).
 */
#include "lod/lod.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lod/lod_internal.h"

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

typedef struct src_item {
    int level, node;
    double w;
} src_item;

static int cmp_src(const void *pa, const void *pb)
{
    const src_item *a = pa, *b = pb;
    if (a->level != b->level)
        return a->level < b->level ? -1 : 1;
    return (a->node > b->node) - (a->node < b->node);
}

/* expand ghost j of level `lev` (weight w) into active sources */
static void expand(const sq_lod *lod, int lev, int j, double w, int depth, src_item **buf, int *n,
                   int *cap)
{
    unsigned char st = lod->lev[lev].state[j];
    if (st == ST_ACTIVE) {
        if (*n == *cap) {
            *cap = *cap ? 2 * *cap : 256;
            *buf = sq_realloc(*buf, sizeof(src_item) * (size_t)*cap);
        }
        (*buf)[(*n)++] = (src_item){lev, j, w};
        return;
    }
    if (depth >= SOURCE_DEPTH)
        return;
    int m, t;
    const double *b;
    if (st == ST_COARSE) {
        if (lev == 0)
            return;
        m = lev - 1;
        t = lod->h.link[m].up_tet[j];
        b = lod->h.link[m].up_bary + 4 * j;
    } else {
        if (lev + 1 >= lod->L)
            return;
        m = lev + 1;
        t = lod->h.link[lev].down_tet[j];
        b = lod->h.link[lev].down_bary + 4 * j;
    }
    const int *tn = lod->lv[m].model.mesh->tets + 4 * t;
    for (int q = 0; q < 4; q++)
        if (b[q] != 0)
            expand(lod, m, tn[q], w * b[q], depth + 1, buf, n, cap);
}

/* the active sources of every ring ghost of every level */
/* src_rend of every ring ghost's sources: where the run of consecutive sources on the same
 * level as source q ends (the value and reaction loops take one run per level) */
static void source_runs(sq_lod_level *lk)
{
    if (lk->nring == 0)
        return;
    lk->src_rend = sq_realloc(lk->src_rend, sizeof(int) * (size_t)SQ_MAX(lk->src_cap, 1));
    for (int r = 0; r < lk->nring; r++)
        for (int q = lk->src_start[r + 1] - 1; q >= lk->src_start[r]; q--)
            lk->src_rend[q] = q + 1 < lk->src_start[r + 1] && lk->src_level[q + 1] == lk->src_level[q]
                                  ? lk->src_rend[q + 1] : q + 1;
}

void sq_lodx_build_sources(sq_lod *lod)
{
    src_item *buf = NULL;
    int cap = 0;
    for (int k = 0; k < lod->L; k++) {
        int total = 0;
        lod->lev[k].src_start[0] = 0;
        lod->lev[k].hot_valid = 0;
        for (int r = 0; r < lod->lev[k].nring; r++) {
            int n = 0;
            expand(lod, k, lod->lev[k].ring[r], 1.0, 0, &buf, &n, &cap);
            for (int i = 1; i < n; i++) { /* a few dozen items: insertion sort */
                src_item x = buf[i];
                int q = i - 1;
                while (q >= 0 && cmp_src(&buf[q], &x) > 0) {
                    buf[q + 1] = buf[q];
                    q--;
                }
                buf[q + 1] = x;
            }
            /* merge duplicates, renormalise */
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
                u = 0; /* no active source: the ghost keeps its value and takes no force */
            if (total + u > lod->lev[k].src_cap) {
                lod->lev[k].src_cap = SQ_MAX(2 * lod->lev[k].src_cap, total + u + 1024);
                size_t scap = (size_t)lod->lev[k].src_cap;
                lod->lev[k].src_level = sq_realloc(lod->lev[k].src_level, sizeof(int) * scap);
                lod->lev[k].src_node = sq_realloc(lod->lev[k].src_node, sizeof(int) * scap);
                lod->lev[k].src_weight = sq_realloc(lod->lev[k].src_weight, sizeof(double) * scap);
                lod->lev[k].src_rend = sq_realloc(lod->lev[k].src_rend, sizeof(int) * scap);
            }
            for (int i = 0; i < u; i++) {
                lod->lev[k].src_level[total + i] = buf[i].level;
                lod->lev[k].src_node[total + i] = buf[i].node;
                lod->lev[k].src_weight[total + i] = buf[i].w / sum;
            }
            for (int i = u - 1; i >= 0; i--) /* each source's run of its level ends at */
                lod->lev[k].src_rend[total + i] =
                    i + 1 < u && buf[i + 1].level == buf[i].level ? lod->lev[k].src_rend[total + i + 1] : total + i + 1;
            unsigned char bits = 0;
            for (int i = 0; i < u; i++)
                bits |= (unsigned char)(1u << buf[i].level);
            lod->lev[k].src_levels[r] = bits;
            total += u;
            lod->lev[k].src_start[r + 1] = total;
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

/* the ring ghosts of level k at tick t: sources of a level between two of its steps are
 * taken linearly in time over that step */
static inline __attribute__((always_inline)) void eval_list(sq_lod *lod, int k, long t, const int *list, int n)
{
    sq_lod_level *lk = &lod->lev[k];
    sq_level *Lk = &lod->lv[k];
    double fr[SQ_MAX_LEVELS];
    const double *dcur[SQ_MAX_LEVELS], *vcur[SQ_MAX_LEVELS];
    for (int m = 0; m < lod->L; m++) {
        double f = (double)(t - lod->lev[m].step_start) / (double)lod->lev[m].step_len;
        fr[m] = f < 0 ? 0 : (f > 1 ? 1 : f);
        dcur[m] = lod->lv[m].d;
        vcur[m] = lod->lv[m].v;
    }
    /* the level's lists in locals (the value stores below would make the compiler reload them) */
    const int *ring = lk->ring, *src_start = lk->src_start;
    const int *fl = lk->src_level, *fn = lk->src_node, *rend = lk->src_rend;
    const double *fw = lk->src_weight;
    double *restrict Dk = Lk->d, *restrict Vk = Lk->v;
    const unsigned char *fixed = Lk->model.fixed;
    for (int x = 0; x < n; x++) {
        const int r = list ? list[x] : x;
        int j = ring[r];
        int a = src_start[r], b = src_start[r + 1];
        if (a == b)
            continue;
        /* a node's d and v as 4 lanes (lane 3 unused), each lane summed as the scalar sums
         * were: d += w * d1, or d += w * (d0 + f (d1 - d0)) */
        sq_v4 d = {0, 0, 0, 0}, v = {0, 0, 0, 0};
        /* the sources are sorted by level: one run per level, its time fraction hoisted */
        for (int q = a; q < b;) {
            const int m = fl[q], qe = rend[q];
            double f = fr[m];
            const double *D1 = dcur[m], *V1 = vcur[m];
            if (f == 1) {
                /* a source level at the end of its step (the common case): its values */
                for (; q < qe; q++) {
                    const sq_v4 w = v4_set1(fw[q]);
                    const size_t n3 = 3 * (size_t)fn[q];
                    d += w * v4_load(D1 + n3);
                    v += w * v4_load(V1 + n3);
                }
                continue;
            }
            const double *D0 = lod->lev[m].d_start, *V0 = lod->lev[m].v_start;
            const sq_v4 fv = v4_set1(f);
            for (; q < qe; q++) {
                const sq_v4 w = v4_set1(fw[q]);
                const size_t n3 = 3 * (size_t)fn[q];
                const sq_v4 d0 = v4_load(D0 + n3), v0 = v4_load(V0 + n3);
                d += w * (d0 + fv * (v4_load(D1 + n3) - d0));
                v += w * (v0 + fv * (v4_load(V1 + n3) - v0));
            }
        }
        sq_lodx_store_free(fixed[j], &d, &v, Dk + 3 * (size_t)j, Vk + 3 * (size_t)j);
    }
}

void sq_lodx_eval_ring(sq_lod *lod, int k, long t)
{
    eval_list(lod, k, t, NULL, lod->lev[k].nring);
}

/* the ring ghosts of level k that the ring rows with a source on a level in `mask` read (the
 * ghost columns of those rows), increasing ring order: lk->hot, made once per layout */
static void hot_list(sq_lod *lod, int k, unsigned mask)
{
    sq_lod_level *lk = &lod->lev[k];
    if (lk->hot_valid && lk->hot_mask == mask)
        return;
    if (!lk->hot)
        lk->hot = sq_malloc(sizeof(int) * (size_t)SQ_MAX(lod->lv[k].model.n, 1));
    unsigned char *mark = lk->mark; /* all zero between uses */
    for (int r = 0; r < lk->nring; r++)
        if (lk->src_levels[r] & mask)
            for (int e = lk->ring_off[r]; e < lk->ring_off[r + 1]; e++) {
                int l = lk->ring_index[lk->ring_col[e]];
                if (l >= 0)
                    mark[l] = 1;
            }
    int nh = 0;
    for (int r = 0; r < lk->nring; r++)
        if (mark[r]) {
            lk->hot[nh++] = r;
            mark[r] = 0;
        }
    lk->nhot = nh;
    lk->hot_mask = mask;
    lk->hot_valid = 1;
}

int sq_lodx_eval_ring_hot(sq_lod *lod, int k, long t, unsigned mask)
{
    hot_list(lod, k, mask);
    eval_list(lod, k, t, lod->lev[k].hot, lod->lev[k].nhot);
    return lod->lev[k].nhot;
}

/* force on ring ghost r (node j) of level k from the tets touching active nodes, -(K w)_j -
 * (D v)_j, with the active nodes of level k taken at fraction fr of its current step */
static void ring_force(const sq_lod *lod, const sq_material *mat, int k, int r, double fr, double g[3])
{
    const sq_lod_level *lk = &lod->lev[k];
    const sq_level *L = &lod->lv[k];
    const unsigned char *act = lk->active;
    double b = mat->use_viscosity ? 0 : mat->rayleigh_stiffness;
    const double *Bd = mat->use_viscosity ? lk->ring_D : NULL;
    g[0] = g[1] = g[2] = 0;
    if (!Bd) {
        /* no viscosity: the three rows of a block in the lanes of one vector (the ring rows in
         * column form), each lane summed as the scalar rows were: g_r -= (K_r0 w0 + K_r1 w1)
         * + K_r2 w2 */
        const double *restrict d = L->d, *restrict v = L->v;
        const double *T = lk->ring_T;
        const int *col = lk->ring_col;
        const sq_v4 bb = v4_set1(b);
        sq_v4 acc = {0, 0, 0, 0};
        const int e0 = lk->ring_off[r], e1 = lk->ring_off[r + 1];
        if (fr >= 1) {
            /* the level at the end of its step (without viscosity sq_lodx_couple_out does
             * this itself, from d + b v formed once for the step) */
            for (int e = e0; e < e1; e++) {
                const size_t j = 3 * (size_t)col[e];
                acc -= v4_block(T + 12 * (size_t)e, v4_load(d + j) + bb * v4_load(v + j));
            }
        } else {
            /* active nodes of the level between two of its steps, at fraction fr */
            const double *restrict d0s = lk->d_start, *restrict v0s = lk->v_start;
            const sq_v4 fv = v4_set1(fr);
            for (int e = e0; e < e1; e++) {
                const int l = col[e];
                const size_t j = 3 * (size_t)l;
                sq_v4 dl = v4_load(d + j), vl = v4_load(v + j);
                if (act[l]) {
                    const sq_v4 d0 = v4_load(d0s + j), v0 = v4_load(v0s + j);
                    dl = d0 + fv * (dl - d0);
                    vl = v0 + fv * (vl - v0);
                }
                acc -= v4_block(T + 12 * (size_t)e, dl + bb * vl);
            }
        }
        g[0] = acc[0];
        g[1] = acc[1];
        g[2] = acc[2];
        return;
    }
    for (int e = lk->ring_off[r]; e < lk->ring_off[r + 1]; e++) {
        int l = lk->ring_col[e];
        double dl[3], vl[3];
        for (int c = 0; c < 3; c++) {
            dl[c] = L->d[3 * l + c];
            vl[c] = L->v[3 * l + c];
        }
        if (fr < 1 && act[l])
            for (int c = 0; c < 3; c++) {
                double d0 = lk->d_start[3 * l + c], v0 = lk->v_start[3 * l + c];
                dl[c] = d0 + fr * (dl[c] - d0);
                vl[c] = v0 + fr * (vl[c] - v0);
            }
        const double *K = lk->ring_K + 9 * (size_t)e;
        double w[3] = {dl[0] + b * vl[0], dl[1] + b * vl[1], dl[2] + b * vl[2]};
        for (int rr = 0; rr < 3; rr++)
            g[rr] -= K[3 * rr] * w[0] + K[3 * rr + 1] * w[1] + K[3 * rr + 2] * w[2];
        const double *D = Bd + 9 * (size_t)e;
        for (int rr = 0; rr < 3; rr++)
            g[rr] -= D[3 * rr] * vl[0] + D[3 * rr + 1] * vl[1] + D[3 * rr + 2] * vl[2];
    }
}

/* the ring reactions of level k at tick t go back to their active sources, into the force of
 * the levels that step at this tick. A level between two of its steps (a coarser one) still
 * hands its reactions to the finer levels stepping now, from its values at this tick: those
 * reactions depend on the finer nodes themselves, so they must follow them step by step.
 * Reactions for a coarser level are sampled at its own steps. */
int sq_lodx_couple_out(sq_lod *lod, const sq_material *mat, int k, long t)
{
    int rows = 0;
    sq_lod_level *lk = &lod->lev[k];
    const sq_level *Lk = &lod->lv[k];
    double fr = (double)(t - lk->step_start) / (double)lk->step_len;
    fr = fr < 0 ? 0 : (fr > 1 ? 1 : fr);
    unsigned due_bits = 0;
    for (int m = 0; m < lod->L; m++)
        due_bits |= lod->lev[m].due ? 1u << m : 0u;
    /* the level's lists in locals: the force stores below could otherwise alias them for the
     * compiler, which would reload them at every ring ghost */
    const int nring = lk->nring, *ring = lk->ring, *src_start = lk->src_start;
    const unsigned char *src_levels = lk->src_levels;
    const int *fl = lk->src_level, *fn = lk->src_node, *rend = lk->src_rend;
    const double *fw = lk->src_weight;
    /* the level at the end of its step without viscosity (the common case): the ring rows
     * here, from d + b v formed once for the step (sq_lodx_form_w); the others by ring_force */
    const int fast = fr >= 1 && !mat->use_viscosity;
    if (fast && !lk->w_ok) /* called outside the frame's tick */
        sq_lodx_form_w(lod, mat, k);
    const double *restrict W = lk->w_tick, *T = lk->ring_T;
    const int *col = lk->ring_col, *roff = lk->ring_off;
    const unsigned char *fixed = Lk->model.fixed;
    double *Fl[SQ_MAX_LEVELS];
    for (int m = 0; m < lod->L; m++)
        Fl[m] = lod->lv[m].f;
    for (int r = 0; r < nring; r++) {
        int j = ring[r];
        int a = src_start[r], b = src_start[r + 1];
        if (!(src_levels[r] & due_bits))
            continue;
        double g[3];
        if (fast) {
            /* -(K w) over the row in column form, each lane summed as the scalar rows were:
             * g_r -= (K_r0 w0 + K_r1 w1) + K_r2 w2, two blocks a turn in row order */
            sq_v4 acc = {0, 0, 0, 0};
            int e = roff[r];
            const int e1 = roff[r + 1];
            for (; e + 1 < e1; e += 2) {
                const sq_v4 x0 = v4_block_s(T + 12 * (size_t)e, W + 3 * (size_t)col[e]);
                const sq_v4 x1 = v4_block_s(T + 12 * (size_t)e + 12, W + 3 * (size_t)col[e + 1]);
                acc -= x0;
                acc -= x1;
            }
            if (e < e1)
                acc -= v4_block_s(T + 12 * (size_t)e, W + 3 * (size_t)col[e]);
            g[0] = acc[0];
            g[1] = acc[1];
            g[2] = acc[2];
        } else {
            ring_force(lod, mat, k, r, fr, g);
        }
        rows++;
        unsigned char fx = fixed[j];
        if (fx)
            for (int c = 0; c < 3; c++)
                if (fx & (1u << c))
                    g[c] = 0; /* a constrained axis of a ghost does not follow its sources */
        const sq_v2 g01 = {g[0], g[1]};
        /* one run of sources per level (sorted by level); levels not stepping now skipped */
        for (int q = a; q < b;) {
            const int m = fl[q], qe = rend[q];
            if (!(due_bits & (1u << m))) {
                q = qe;
                continue;
            }
            double *F = Fl[m];
            for (; q < qe; q++) {
                /* dst[c] += w g[c]: x and y as one 2-lane vector */
                double w = fw[q], *dst = F + 3 * (size_t)fn[q];
                sq_v2 xy;
                memcpy(&xy, dst, sizeof xy);
                xy += (sq_v2){w, w} * g01;
                memcpy(dst, &xy, sizeof xy);
                dst[2] += w * g[2];
            }
        }
    }
    return rows;
}
