/* views.c - stage: what the rest of the program reads of the adaptive state.
 *
 * The hierarchy, the active masks and lists of each level, the level active at each finest
 * node (the colour of the rendered surface), the energy the frame conserves, and the node
 * updates one frame of the current layout costs.
 */
#include "lod/lod.h"
#include "lod/corotational.h"
#include "lod/lod_test.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>


const sq_hierarchy *sq_lod_hierarchy(const sq_lod *lod)
{
    return &lod->h;
}

const unsigned char *sq_lod_active(const sq_lod *lod, int level)
{
    if (level < 0 || level >= lod->L)
        return NULL;
    return lod->lev[level].lay.active;
}

const int *sq_lod_active_list(const sq_lod *lod, int level, int *n)
{
    if (level < 0 || level >= lod->L) {
        *n = 0;
        return NULL;
    }
    *n = lod->lev[level].lay.nactive;
    return lod->lev[level].lists.active_list;
}

void sq_lod_substeps(const sq_lod *lod, int out[SQ_MAX_LEVELS])
{
    for (int k = 0; k < SQ_MAX_LEVELS; k++)
        out[k] = k < lod->L ? 1 << sub_log2(lod, k) : 0;
}

long sq_lod_projected_updates(const sq_lod *lod)
{
    long u = 0;
    for (int k = 0; k < lod->L; k++)
        u += (long)lod->lev[k].lay.nactive << sub_log2(lod, k);
    return u;
}

/* ---------------------------------------------------------------- views */

void sq_lod_node_levels(sq_lod *lod, unsigned char *out)
{
    /* the states change only at a rebuild: the same buffer needs no new walk before then */
    if (lod->view.nl_gen == lod->view.gen && lod->view.nl_out == out)
        return;
    lod->view.nl_gen = lod->view.gen;
    lod->view.nl_out = out;
    /* level by level, coarse to fine: a node's level is its own if active, else its parent's
     * (the walk up from each finest node to its active ancestor, without repeating it) */
    int F = lod->L - 1;
    if (F == 0) {
        memset(out, 0, (size_t)lod->lv[0].model.n);
        return;
    }
    unsigned char *prev = lod->view.nlv[0], *cur = lod->view.nlv[1];
    memset(prev, 0, (size_t)lod->lv[0].model.n);
    for (int k = 1; k <= F; k++) {
        unsigned char *dst = k == F ? out : cur;
        const unsigned char *st = lod->lev[k].lay.state;
        const int *par = lod->h.link[k - 1].parent;
        for (int j = 0; j < lod->lv[k].model.n; j++)
            dst[j] = st[j] == ST_ACTIVE ? (unsigned char)k : prev[par[j]];
        unsigned char *t = prev;
        prev = cur;
        cur = t;
    }
}

double sq_lod_energy(const sq_lod *lod, double *kinetic, double *elastic)
{
    if (sq_lodx_corot_on(lod))
        return sq_lodx_corot_energy(lod, kinetic, elastic);
    double ek = 0, ee = 0;
    for (int k = 0; k < lod->L; k++) {
        const sq_level *Lk = &lod->lv[k];
        /* sum over the tets touching active nodes of their weighted elastic energy: full
         * rows on active nodes less the frontier correction, ring rows from the ring blocks */
        for (int i = 0; i < Lk->model.n; i++) {
            if (lod->lev[k].lay.state[i] != ST_ACTIVE)
                continue;
            const double *v = Lk->state.v + 3 * i, *d = Lk->state.d + 3 * i;
            ek += 0.5 * Lk->model.mass[i] * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
            double f[3] = {0, 0, 0};
            for (int q = Lk->model.row_start[i]; q < Lk->model.row_start[i + 1]; q++) {
                const double *K = Lk->model.K + 9 * q, *dl = Lk->state.d + 3 * Lk->model.col[q];
                for (int r = 0; r < 3; r++)
                    f[r] += K[3 * r] * dl[0] + K[3 * r + 1] * dl[1] + K[3 * r + 2] * dl[2];
            }
            ee += 0.5 * (d[0] * f[0] + d[1] * f[1] + d[2] * f[2]);
        }
        if (!lod->cpl.have_mat || lod->lev[k].cpl.blocks_dirty)
            continue;
        for (int r = 0; r < lod->lev[k].lay.nfrontier; r++) {
            int i = lod->lev[k].lay.frontier[r];
            const double *d = Lk->state.d + 3 * i;
            double f[3] = {0, 0, 0};
            for (int e = lod->lev[k].cpl.front_off[r]; e < lod->lev[k].cpl.front_off[r + 1]; e++) {
                const double *K = lod->lev[k].cpl.front_K + 9 * (size_t)e, *dl = Lk->state.d + 3 * lod->lev[k].cpl.front_col[e];
                for (int rr = 0; rr < 3; rr++)
                    f[rr] += K[3 * rr] * dl[0] + K[3 * rr + 1] * dl[1] + K[3 * rr + 2] * dl[2];
            }
            ee -= 0.5 * (d[0] * f[0] + d[1] * f[1] + d[2] * f[2]);
        }
        for (int r = 0; r < lod->lev[k].lay.nring; r++) {
            int j = lod->lev[k].lay.ring[r];
            const double *d = Lk->state.d + 3 * j;
            double f[3] = {0, 0, 0};
            for (int e = lod->lev[k].cpl.ring_off[r]; e < lod->lev[k].cpl.ring_off[r + 1]; e++) {
                const double *K = lod->lev[k].cpl.ring_K + 9 * (size_t)e, *dl = Lk->state.d + 3 * lod->lev[k].cpl.ring_col[e];
                for (int rr = 0; rr < 3; rr++)
                    f[rr] += K[3 * rr] * dl[0] + K[3 * rr + 1] * dl[1] + K[3 * rr + 2] * dl[2];
            }
            ee += 0.5 * (d[0] * f[0] + d[1] * f[1] + d[2] * f[2]);
        }
    }
    if (kinetic)
        *kinetic = ek;
    if (elastic)
        *elastic = ee;
    return ek + ee;
}

sq_lod_test *sq_lod_test_of(sq_lod *lod)
{
    return &lod->test;
}
