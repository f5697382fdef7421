/* coupling.c - stage: the coupling blocks between levels (docs/lod.md, "Coupling the levels").
 *
 * The element blocks of the mixed tets (active and ghost corners, half weight): the ring rows
 * (forces on the ring ghosts, handed back to their sources in ring.c) and the frontier
 * corrections (the other half given back to the active rows, folded into merged rows); the
 * Gershgorin bound of the coupled operator and the extra substeps a level needs at an
 * interface (coupling_bound); all rebuilt by sq_lodx_update_ring_blocks after a layout or
 * material change.
 */
#include "lod/lod.h"
#include "lod/bound.h"
#include "lod/coupling.h"
#include "lod/lod_vec.h"
#include "lod/reserve.h"
#include "lod/tick.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>


/* ---------------------------------------------------------------- ring blocks */

/* weight of a tet with both active and ghost corners in its level's energy: the band where
 * two levels meet is covered by the mixed tets of both, so each counts half */
#define MIXED_WEIGHT 0.5


/* dst += w src over one 3x3 block */
static inline void axpy9(double *restrict dst, double w, const double *restrict src)
{
    /* written out so the compiler packs it into vector operations */
    dst[0] += w * src[0];
    dst[1] += w * src[1];
    dst[2] += w * src[2];
    dst[3] += w * src[3];
    dst[4] += w * src[4];
    dst[5] += w * src[5];
    dst[6] += w * src[6];
    dst[7] += w * src[7];
    dst[8] += w * src[8];
}

/* cached element blocks of tet t of level k (built on first use for the current material):
 * 16 blocks (p, q) of 9, then with viscosity 16 viscous ones */
static const double *tet_blocks(sq_lod *lod, int k, int t, int visc)
{
    sq_lod_level *lk = &lod->lev[k];
    int sl = lk->cpl.blocks_slot[t];
    size_t per = visc ? 288 : 144;
    if (sl >= 0)
        return lk->cpl.blocks_chunk[sl / SQ_BLOCKS_CHUNK] + per * (size_t)(sl % SQ_BLOCKS_CHUNK);
    if (lk->cpl.blocks_per != (int)per) { /* chunks made for the other slot size: made again */
        for (int c = 0; c < lk->cpl.blocks_nchunk; c++)
            free(lk->cpl.blocks_chunk[c]);
        lk->cpl.blocks_nchunk = lk->cpl.blocks_cap = 0;
        lk->cpl.blocks_per = (int)per;
    }
    if (lk->cpl.blocks_used == lk->cpl.blocks_cap) {
        lk->cpl.blocks_chunk = sq_realloc(lk->cpl.blocks_chunk, sizeof(double *) * (size_t)(lk->cpl.blocks_nchunk + 1));
        lk->cpl.blocks_chunk[lk->cpl.blocks_nchunk++] = sq_malloc(sizeof(double) * per * SQ_BLOCKS_CHUNK);
        lk->cpl.blocks_cap += SQ_BLOCKS_CHUNK;
        lk->cpl.blocks_mapped = 0; /* its pages mapped by the slots' first use or sq_lodx_reserve_blocks */
    }
    sl = lk->cpl.blocks_used++;
    lk->cpl.blocks_slot[t] = sl;
    double *E = lk->cpl.blocks_chunk[sl / SQ_BLOCKS_CHUNK] + per * (size_t)(sl % SQ_BLOCKS_CHUNK);
    memset(E, 0, sizeof(double) * per);
    const double *g = lk->tab.tet_geom + 13 * (size_t)t;
    const sq_material *mat = &lod->cpl.mat;
    for (int p = 0; p < 4; p++)
        for (int q = 0; q < 4; q++) {
            sq_level_tet_block(lod->cpl.op, g[0], g + 1 + 3 * p, g + 1 + 3 * q, mat->mu, mat->lambda, E + 9 * (4 * p + q));
            if (visc)
                sq_level_tet_block(lod->cpl.op, g[0], g + 1 + 3 * p, g + 1 + 3 * q, mat->phi, mat->psi,
                          E + 144 + 9 * (4 * p + q));
        }
    return E;
}

/* forget the cached element blocks (material or operator changed) */
static void drop_tet_blocks(sq_lod *lod)
{
    for (int k = 0; k < lod->L; k++) {
        /* and the column-form rows of the inner nodes (activeset.c) */
        for (int i = 0; i < lod->lv[k].model.n && lod->lev[k].cpl.krow_used > 0 && lod->lev[k].cpl.krow_at; i++)
            lod->lev[k].cpl.krow_at[i] = -1;
        lod->lev[k].cpl.krow_used = 0;
        for (int t = 0; t < lod->lv[k].model.mesh->ntets && lod->lev[k].cpl.blocks_used > 0; t++)
            lod->lev[k].cpl.blocks_slot[t] = -1;
        lod->lev[k].cpl.blocks_used = 0;
    }
}

/* the mixed-tet blocks of row j (incidences c0..c1) into B (and Bd), times weight (a power
 * of two, so the products equal those of the blocks built with weight * V) */
static inline void row_blocks(sq_lod *lod, int k, int c0, int c1, double weight, double *restrict B,
                              double *restrict Bd)
{
    sq_lod_level *lk = &lod->lev[k];
    const sq_mesh *m = lod->lv[k].model.mesh;
    const unsigned char *act = lk->lay.active;
    int visc = Bd != NULL;
    for (int c = c0; c < c1; c++) {
        int t = lk->tab.node_tet[c];
        const int *tv = m->tets + 4 * t;
        int na = act[tv[0]] + act[tv[1]] + act[tv[2]] + act[tv[3]];
        if (na == 0 || na == 4)
            continue;
        const double *E = tet_blocks(lod, k, t, visc) + 36 * lk->tab.inc_corner[c];
        const int *ev = lk->tab.inc_block + 4 * (size_t)c;
        for (int q = 0; q < 4; q++) {
            axpy9(B + 9 * ev[q], weight, E + 9 * q);
            if (visc)
                axpy9(Bd + 9 * ev[q], weight, E + 144 + 9 * q);
        }
    }
}

/* which operator the level's K was built with: rebuild one row both ways, keep the closer */
static sq_operator_kind infer_op(const sq_lod *lod, const sq_material *mat)
{
    const sq_level *L = &lod->lv[0];
    const sq_mesh *m = L->model.mesh;
    /* a boundary node: the two operators differ there */
    int i = 0;
    while (i < m->nnodes && !m->on_boundary[i])
        i++;
    if (i == m->nnodes)
        return SQ_OPERATOR_FEM;
    int n = L->model.row_start[i + 1] - L->model.row_start[i];
    double *row[2];
    double err[2] = {0, 0};
    for (int o = 0; o < 2; o++) {
        row[o] = sq_calloc(9 * (size_t)n, sizeof(double));
        for (int c = lod->lev[0].tab.node_tet_start[i]; c < lod->lev[0].tab.node_tet_start[i + 1]; c++) {
            int t = lod->lev[0].tab.node_tet[c];
            double a[4][3];
            double V = sq_tet_gradients(m, t, a);
            int p = 0;
            while (m->tets[4 * t + p] != i)
                p++;
            for (int q = 0; q < 4; q++) {
                int e = adj_find(m, i, m->tets[4 * t + q]) - L->model.row_start[i];
                sq_level_tet_block((sq_operator_kind)o, V, a[p], a[q], mat->mu, mat->lambda, row[o] + 9 * e);
            }
        }
        for (int e = 0; e < 9 * n; e++)
            err[o] += fabs(row[o][e] - L->model.K[9 * L->model.row_start[i] + e]);
        free(row[o]);
    }
    return err[SQ_OPERATOR_PAPER] < err[SQ_OPERATOR_FEM] ? SQ_OPERATOR_PAPER : SQ_OPERATOR_FEM;
}

/* blocks of node list nodes[0..nn) of level k (aligned with their adjacency rows), summed
 * over their tets that touch an active node and have a ghost corner, times weight */
static void build_blocks(sq_lod *lod, int k, const int *nodes, int nn, int *off, int **cols, int *col_cap,
                         double **bk, int *bk_cap, double **bd, int *bd_cap, double weight)
{
    const sq_level *L = &lod->lv[k];
    const sq_material *mat = &lod->cpl.mat;
    int visc = mat->use_viscosity && L->model.D;
    int total = 0;
    for (int r = 0; r < nn; r++) {
        off[r] = total;
        total += L->model.row_start[nodes[r] + 1] - L->model.row_start[nodes[r]];
    }
    off[nn] = total;
    if (total > *bk_cap) {
        *bk_cap = SQ_MAX(total, 2 * *bk_cap);
        *bk = sq_realloc(*bk, sizeof(double) * 9 * (size_t)*bk_cap);
    }
    if (total > 0)
        memset(*bk, 0, sizeof(double) * 9 * (size_t)total);
    if (visc) {
        if (total > *bd_cap) {
            *bd_cap = SQ_MAX(total, 2 * *bd_cap);
            *bd = sq_realloc(*bd, sizeof(double) * 9 * (size_t)*bd_cap);
        }
        if (total > 0)
            memset(*bd, 0, sizeof(double) * 9 * (size_t)total);
    }
    for (int r = 0; r < nn; r++) {
        int j = nodes[r];
        double *B = *bk + 9 * (size_t)off[r];
        double *Bd = visc ? *bd + 9 * (size_t)off[r] : NULL;
        row_blocks(lod, k, lod->lev[k].tab.node_tet_start[j], lod->lev[k].tab.node_tet_start[j + 1], weight, B, Bd);
    }
    /* keep the non-zero blocks only, with their column (the array only grows: a shrunk one
     * would be mapped again, page by page, by a later pass) */
    if (total > *col_cap || !*cols) {
        *col_cap = SQ_MAX(SQ_MAX(total, 2 * *col_cap), 1);
        *cols = sq_realloc(*cols, sizeof(int) * (size_t)*col_cap);
    }
    int *col = *cols;
    int w = 0;
    for (int r = 0; r < nn; r++) {
        int j = nodes[r], start = off[r];
        off[r] = w;
        for (int q = L->model.row_start[j], e = 0; q < L->model.row_start[j + 1]; q++, e++) {
            const double *B = *bk + 9 * (size_t)(start + e);
            int nz = 0;
            for (int c = 0; c < 9 && !nz; c++)
                nz = B[c] != 0 || (visc && (*bd)[9 * (size_t)(start + e) + c] != 0);
            if (!nz)
                continue;
            /* w <= start + e: moving down in place, block by block */
            for (int x = 0; x < 9; x++)
                (*bk)[9 * (size_t)w + x] = B[x];
            if (visc)
                for (int x = 0; x < 9; x++)
                    (*bd)[9 * (size_t)w + x] = (*bd)[9 * (size_t)(start + e) + x];
            col[w++] = L->model.col[q];
        }
    }
    off[nn] = w;
}

/* the rows of node list nodes[0..nn) as build_blocks makes them, into the spare arrays (off,
 * cols, bk, bd), with the rows of the nodes that were in the previous list pnodes[0..pn) (both
 * increasing) and have no changed node in their tets (dirty[j] == 0) copied from the previous
 * arrays (poff, pcol, pk, pd): a row's blocks depend only on the active flags of its tets'
 * corners, so the copy is what build_blocks would compute. from[r]: the previous row copied
 * into row r, or -1 if it was computed; returns the rows computed. */
static int build_blocks_incr(sq_lod *lod, int k, const int *nodes, int nn, const int *pnodes, int pn,
                             const unsigned char *dirty, const int *poff, const int *pcol, const double *pk,
                             const double *pd, int *off, int **cols, int *col_cap, double **bk, int *bk_cap,
                             double **bd, int *bd_cap, double weight, int *from)
{
    const sq_level *L = &lod->lv[k];
    const sq_material *mat = &lod->cpl.mat;
    int visc = mat->use_viscosity && L->model.D;
    int total = 0, maxlen = 0;
    for (int r = 0; r < nn; r++) {
        int len = L->model.row_start[nodes[r] + 1] - L->model.row_start[nodes[r]];
        total += len;
        maxlen = SQ_MAX(maxlen, len);
    }
    if (total > *bk_cap) {
        *bk_cap = SQ_MAX(total, 2 * *bk_cap);
        *bk = sq_realloc(*bk, sizeof(double) * 9 * (size_t)*bk_cap);
    }
    if (visc && total > *bd_cap) {
        *bd_cap = SQ_MAX(total, 2 * *bd_cap);
        *bd = sq_realloc(*bd, sizeof(double) * 9 * (size_t)*bd_cap);
    }
    if (total > *col_cap || !*cols) {
        *col_cap = SQ_MAX(SQ_MAX(total, 2 * *col_cap), 1);
        *cols = sq_realloc(*cols, sizeof(int) * (size_t)*col_cap);
    }
    double *tk = sq_malloc(sizeof(double) * 9 * (size_t)SQ_MAX(maxlen, 1) * (visc ? 2 : 1));
    double *td = visc ? tk + 9 * (size_t)SQ_MAX(maxlen, 1) : NULL;
    int *col = *cols, w = 0, p = 0, computed = 0;
    double *K = *bk, *D = visc ? *bd : NULL;
    for (int r = 0; r < nn; r++) {
        int j = nodes[r];
        off[r] = w;
        while (p < pn && pnodes[p] < j)
            p++;
        if (p < pn && pnodes[p] == j && !dirty[j]) {
            int b0 = poff[p], nb = poff[p + 1] - b0;
            memcpy(col + w, pcol + b0, sizeof(int) * (size_t)nb);
            memcpy(K + 9 * (size_t)w, pk + 9 * (size_t)b0, sizeof(double) * 9 * (size_t)nb);
            if (visc)
                memcpy(D + 9 * (size_t)w, pd + 9 * (size_t)b0, sizeof(double) * 9 * (size_t)nb);
            w += nb;
            from[r] = p;
            continue;
        }
        from[r] = -1;
        computed++;
        int q0 = L->model.row_start[j], len = L->model.row_start[j + 1] - q0;
        memset(tk, 0, sizeof(double) * 9 * (size_t)len);
        if (visc)
            memset(td, 0, sizeof(double) * 9 * (size_t)len);
        row_blocks(lod, k, lod->lev[k].tab.node_tet_start[j], lod->lev[k].tab.node_tet_start[j + 1], weight, tk, td);
        for (int e = 0; e < len; e++) {
            const double *B = tk + 9 * (size_t)e;
            int nz = 0;
            for (int c = 0; c < 9 && !nz; c++)
                nz = B[c] != 0 || (visc && td[9 * (size_t)e + c] != 0);
            if (!nz)
                continue;
            memcpy(K + 9 * (size_t)w, B, sizeof(double) * 9);
            if (visc)
                memcpy(D + 9 * (size_t)w, td + 9 * (size_t)e, sizeof(double) * 9);
            col[w++] = L->model.col[q0 + e];
        }
    }
    off[nn] = w;
    free(tk);
    return computed;
}

/* merged frontier row r of level k (node i): the level's row less the correction */
static void merged_row(const sq_lod *lod, int k, int r, int i, double *M)
{
    const sq_lod_level *lk = &lod->lev[k];
    const sq_level *L = &lod->lv[k];
    int q0 = L->model.row_start[i], len = L->model.row_start[i + 1] - q0;
    memcpy(M, L->model.K + 9 * (size_t)q0, sizeof(double) * 9 * (size_t)len);
    for (int e = lk->cpl.front_off[r]; e < lk->cpl.front_off[r + 1]; e++) {
        int pos = adj_find(L->model.mesh, i, lk->cpl.front_col[e]) - q0;
        for (int x = 0; x < 9; x++)
            M[9 * pos + x] -= lk->cpl.front_K[9 * (size_t)e + x];
    }
}

/* room for nb blocks in column form (12 doubles each) in *dst */
static double *col_room(double **dst, int *cap, int nb)
{
    if (nb > *cap || !*dst) {
        *cap = SQ_MAX(SQ_MAX(nb, 2 * *cap), 1);
        *dst = sq_realloc(*dst, sizeof(double) * 12 * (size_t)*cap);
    }
    return *dst;
}

#define to_columns sq_lodx_to_columns

static void transpose_blocks(const double *src, int nb, double **dst, int *cap)
{
    to_columns(src, nb, col_room(dst, cap, nb));
}

#define SWAP(T, a, b)                                                                                              \
    do {                                                                                                           \
        T swap_tmp_ = (a);                                                                                         \
        (a) = (b);                                                                                                 \
        (b) = swap_tmp_;                                                                                           \
    } while (0)

/* ring rows (half of the mixed tets) and frontier corrections (the other half of the mixed
 * tets, given back) of level k, and the merged frontier rows: every row (the first build for a
 * material, lod->test.full_rebuild, or many changed nodes), else only the rows with a changed node
 * in their tets, the others copied (build_blocks_incr); the same arrays either way */
static void build_ring_blocks(sq_lod *lod, int k)
{
    sq_lod_level *lk = &lod->lev[k];
    const sq_level *L = &lod->lv[k];
    const sq_mesh *mesh = L->model.mesh;
    int n = L->model.n;
    int incr = lk->cpl.blocks_valid && lk->cpl.prev_saved && !lod->test.full_rebuild && (long)lk->cpl.nchg * 8 < n;
    lk->cpl.rows_built += lk->lay.nring + lk->lay.nfrontier;
    if (!incr) {
        build_blocks(lod, k, lk->lay.ring, lk->lay.nring, lk->cpl.ring_off, &lk->cpl.ring_col, &lk->cpl.ring_col_cap, &lk->cpl.ring_K,
                     &lk->cpl.ring_K_cap, &lk->cpl.ring_D, &lk->cpl.ring_D_cap, MIXED_WEIGHT);
        build_blocks(lod, k, lk->lay.frontier, lk->lay.nfrontier, lk->cpl.front_off, &lk->cpl.front_col, &lk->cpl.front_col_cap,
                     &lk->cpl.front_K, &lk->cpl.front_K_cap, &lk->cpl.front_D, &lk->cpl.front_D_cap, 1.0 - MIXED_WEIGHT);
        lk->cpl.rows_computed += lk->lay.nring + lk->lay.nfrontier;
    } else {
        /* rows with a tet that became mixed or stopped being mixed (a row sums the blocks of
         * its mixed tets in incidence order, so with the same mixed tets it is the same row):
         * only tets around a changed node can */
        unsigned char *dirty = lk->lists.mark;
        const unsigned char *act = lk->lay.active, *was = lk->cpl.blk_active;
        for (int c = 0; c < lk->cpl.nchg; c++) {
            int i = lk->cpl.chg[c];
            for (int e = lk->tab.node_tet_start[i]; e < lk->tab.node_tet_start[i + 1]; e++) {
                const int *tv = mesh->tets + 4 * lk->tab.node_tet[e];
                int na = act[tv[0]] + act[tv[1]] + act[tv[2]] + act[tv[3]];
                int nw = was[tv[0]] + was[tv[1]] + was[tv[2]] + was[tv[3]];
                if ((na > 0 && na < 4) != (nw > 0 && nw < 4))
                    dirty[tv[0]] = dirty[tv[1]] = dirty[tv[2]] = dirty[tv[3]] = 1;
            }
        }
        int *from = sq_malloc(sizeof(int) * (size_t)SQ_MAX(SQ_MAX(lk->lay.nring, lk->lay.nfrontier), 1));
        int redone = build_blocks_incr(lod, k, lk->lay.ring, lk->lay.nring, lk->cpl.prev_ring, lk->cpl.nprev_ring, dirty,
                                       lk->cpl.ring_off, lk->cpl.ring_col, lk->cpl.ring_K, lk->cpl.ring_D, lk->cpl.ring_off2,
                                       &lk->cpl.ring_col2, &lk->cpl.ring_col2_cap, &lk->cpl.ring_K2, &lk->cpl.ring_K2_cap,
                                       &lk->cpl.ring_D2, &lk->cpl.ring_D2_cap, MIXED_WEIGHT, from);
        SWAP(int *, lk->cpl.ring_off, lk->cpl.ring_off2);
        SWAP(int *, lk->cpl.ring_col, lk->cpl.ring_col2);
        SWAP(int, lk->cpl.ring_col_cap, lk->cpl.ring_col2_cap);
        SWAP(double *, lk->cpl.ring_K, lk->cpl.ring_K2);
        SWAP(int, lk->cpl.ring_K_cap, lk->cpl.ring_K2_cap);
        SWAP(double *, lk->cpl.ring_D, lk->cpl.ring_D2);
        SWAP(int, lk->cpl.ring_D_cap, lk->cpl.ring_D2_cap);
        /* the column forms likewise: a copied row's from the previous ones (ring_off2 now) */
        {
            double *T = col_room(&lk->cpl.ring_T2, &lk->cpl.ring_T2_cap, lk->cpl.ring_off[lk->lay.nring]);
            for (int r = 0; r < lk->lay.nring; r++) {
                int b0 = lk->cpl.ring_off[r], nb = lk->cpl.ring_off[r + 1] - b0;
                if (from[r] >= 0)
                    memcpy(T + 12 * (size_t)b0, lk->cpl.ring_T + 12 * (size_t)lk->cpl.ring_off2[from[r]],
                           sizeof(double) * 12 * (size_t)nb);
                else
                    to_columns(lk->cpl.ring_K + 9 * (size_t)b0, nb, T + 12 * (size_t)b0);
            }
            SWAP(double *, lk->cpl.ring_T, lk->cpl.ring_T2);
            SWAP(int, lk->cpl.ring_T_cap, lk->cpl.ring_T2_cap);
        }
        redone += build_blocks_incr(lod, k, lk->lay.frontier, lk->lay.nfrontier, lk->cpl.prev_frontier, lk->cpl.nprev_frontier,
                                    dirty, lk->cpl.front_off, lk->cpl.front_col, lk->cpl.front_K, lk->cpl.front_D, lk->cpl.front_off2,
                                    &lk->cpl.front_col2, &lk->cpl.front_col2_cap, &lk->cpl.front_K2, &lk->cpl.front_K2_cap,
                                    &lk->cpl.front_D2, &lk->cpl.front_D2_cap, 1.0 - MIXED_WEIGHT, from);
        SWAP(int *, lk->cpl.front_off, lk->cpl.front_off2);
        SWAP(int *, lk->cpl.front_col, lk->cpl.front_col2);
        SWAP(int, lk->cpl.front_col_cap, lk->cpl.front_col2_cap);
        SWAP(double *, lk->cpl.front_K, lk->cpl.front_K2);
        SWAP(int, lk->cpl.front_K_cap, lk->cpl.front_K2_cap);
        SWAP(double *, lk->cpl.front_D, lk->cpl.front_D2);
        SWAP(int, lk->cpl.front_D_cap, lk->cpl.front_D2_cap);
        lk->cpl.rows_computed += redone;
        for (int c = 0; c < lk->cpl.nchg; c++) {
            int i = lk->cpl.chg[c];
            for (int q = mesh->adj_start[i]; q < mesh->adj_start[i + 1]; q++)
                dirty[mesh->adj[q]] = 0; /* every corner of the tets around i */
        }
        /* merged rows: the copied frontier rows from the previous merged rows */
        int total = 0;
        for (int r = 0; r < lk->lay.nfrontier; r++) {
            int i = lk->lay.frontier[r];
            total += L->model.row_start[i + 1] - L->model.row_start[i];
        }
        if (total > lk->cpl.front_merged2_cap) {
            lk->cpl.front_merged2_cap = SQ_MAX(total, 2 * lk->cpl.front_merged2_cap);
            lk->cpl.front_merged2 = sq_realloc(lk->cpl.front_merged2, sizeof(double) * 9 * (size_t)lk->cpl.front_merged2_cap);
        }
        int *poff = sq_malloc(sizeof(int) * (size_t)(lk->cpl.nprev_frontier + 1));
        poff[0] = 0;
        for (int p = 0; p < lk->cpl.nprev_frontier; p++) {
            int i = lk->cpl.prev_frontier[p];
            poff[p + 1] = poff[p] + L->model.row_start[i + 1] - L->model.row_start[i];
        }
        double *M = lk->cpl.front_merged2;
        double *T = col_room(&lk->cpl.front_T2, &lk->cpl.front_T2_cap, total);
        for (int r = 0; r < lk->lay.nfrontier; r++) {
            int i = lk->lay.frontier[r], len = L->model.row_start[i + 1] - L->model.row_start[i];
            if (from[r] >= 0) {
                memcpy(M, lk->cpl.front_merged + 9 * (size_t)poff[from[r]], sizeof(double) * 9 * (size_t)len);
                memcpy(T, lk->cpl.front_T + 12 * (size_t)poff[from[r]], sizeof(double) * 12 * (size_t)len);
            } else {
                merged_row(lod, k, r, i, M);
                to_columns(M, len, T);
            }
            M += 9 * (size_t)len;
            T += 12 * (size_t)len;
        }
        SWAP(double *, lk->cpl.front_merged, lk->cpl.front_merged2);
        SWAP(int, lk->cpl.front_merged_cap, lk->cpl.front_merged2_cap);
        SWAP(double *, lk->cpl.front_T, lk->cpl.front_T2);
        SWAP(int, lk->cpl.front_T_cap, lk->cpl.front_T2_cap);
        free(poff);
        free(from);
        lk->cpl.blocks_dirty = 0;
        lk->cpl.blocks_valid = 1;
        lk->cpl.prev_saved = 0;
        for (int c = 0; c < lk->cpl.nchg; c++) {
            lk->cpl.chg_mark[lk->cpl.chg[c]] = 0;
            lk->cpl.blk_active[lk->cpl.chg[c]] = lk->lay.active[lk->cpl.chg[c]];
        }
        lk->cpl.nchg = 0;
        return;
    }
    /* merged frontier rows: the level's row less the correction the frontier pass adds back
     * (sq_lodx_front_correct adds front_K w; the force pass subtracts K w) */
    int total = 0;
    for (int r = 0; r < lk->lay.nfrontier; r++) {
        int i = lk->lay.frontier[r];
        total += L->model.row_start[i + 1] - L->model.row_start[i];
    }
    if (total > lk->cpl.front_merged_cap) {
        lk->cpl.front_merged_cap = SQ_MAX(total, 2 * lk->cpl.front_merged_cap);
        lk->cpl.front_merged = sq_realloc(lk->cpl.front_merged, sizeof(double) * 9 * (size_t)lk->cpl.front_merged_cap);
    }
    double *M = lk->cpl.front_merged;
    for (int r = 0; r < lk->lay.nfrontier; r++) {
        int i = lk->lay.frontier[r];
        merged_row(lod, k, r, i, M);
        M += 9 * (size_t)(L->model.row_start[i + 1] - L->model.row_start[i]);
    }
    /* the column forms the tick's kernels read */
    transpose_blocks(lk->cpl.ring_K, lk->cpl.ring_off[lk->lay.nring], &lk->cpl.ring_T, &lk->cpl.ring_T_cap);
    transpose_blocks(lk->cpl.front_merged, total, &lk->cpl.front_T, &lk->cpl.front_T_cap);
    lk->cpl.blocks_dirty = 0;
    lk->cpl.blocks_valid = 1;
    lk->cpl.prev_saved = 0;
    for (int c = 0; c < lk->cpl.nchg; c++)
        lk->cpl.chg_mark[lk->cpl.chg[c]] = 0;
    lk->cpl.nchg = 0;
    memcpy(lk->cpl.blk_active, lk->lay.active, (size_t)n);
}


/* ring blocks up to date for material mat (NULL: the last one seen) */
/* largest absolute row sum of a 3x3 block */
static double block_norm(const double *B)
{
    double m = 0;
    for (int r = 0; r < 3; r++) {
        double x = fabs(B[3 * r]) + fabs(B[3 * r + 1]) + fabs(B[3 * r + 2]);
        m = x > m ? x : m; /* fmax without the call (a NaN row is skipped, as fmax does) */
    }
    return m;
}

/* Gershgorin row sums of each level's own operator (material dependent); a level over the same
 * operator blocks as lod->like's (sq_lod_set_loads_like: a scratch copy) takes like's sums */
static void own_rows(sq_lod *lod)
{
    for (int k = 0; k < lod->L; k++) {
        const sq_level *L = &lod->lv[k];
        if (!lod->lev[k].rate.own_rowsum)
            lod->lev[k].rate.own_rowsum = sq_malloc(sizeof(double) * (size_t)L->model.n);
        const sq_lod *like = lod->like;
        if (like && k < like->L && like->lv[k].model.K == L->model.K && like->lv[k].model.n == L->model.n &&
            like->lv[k].model.mass == L->model.mass && like->lev[k].rate.own_rowsum) {
            memcpy(lod->lev[k].rate.own_rowsum, like->lev[k].rate.own_rowsum, sizeof(double) * (size_t)L->model.n);
            lod->lev[k].rate.own_rate = like->lev[k].rate.own_rate;
            continue;
        }
        for (int i = 0; i < L->model.n; i++) {
            double s = 0;
            for (int q = L->model.row_start[i]; q < L->model.row_start[i + 1]; q++)
                s += block_norm(L->model.K + 9 * (size_t)q);
            lod->lev[k].rate.own_rowsum[i] = s;
        }
        double own = 0;
        for (int i = 0; i < L->model.n; i++)
            if (L->model.fixed[i] != 7)
                own = fmax(own, lod->lev[k].rate.own_rowsum[i] / L->model.mass[i]);
        lod->lev[k].rate.own_rate = own;
    }
}

/* the coupling hands a ring ghost's stiffness to its sources: near an interface a node can
 * be stiffer than anything in its own level (a coarse tet acting on a light fine node through
 * the interpolation). Bound the coupled operator row by row (Gershgorin on W^T B W plus the
 * own row) and give each level the extra substeps that keep its step within the same fraction
 * of the bound its own step was chosen at. */
static void coupling_bound(sq_lod *lod)
{
    int L = lod->L;
    for (int k = 0; k < L; k++) {
        if (!lod->lev[k].rate.coupled_rowsum)
            lod->lev[k].rate.coupled_rowsum = sq_malloc(sizeof(double) * (size_t)lod->lv[k].model.n);
        memset(lod->lev[k].rate.coupled_rowsum, 0, sizeof(double) * (size_t)lod->lv[k].model.n);
    }
    for (int m = 0; m < L; m++) {
        /* level m's lists in locals (the row-sum stores would make the compiler reload them) */
        const sq_lod_level *lm = &lod->lev[m];
        const int nring = lm->lay.nring, *src_start = lm->lay.src_start, *ring_off = lm->cpl.ring_off;
        const int *ring_col = lm->cpl.ring_col, *ring_index = lm->lay.ring_index;
        const int *src_level = lm->lay.src_level, *src_node = lm->lay.src_node;
        const unsigned char *active = lm->lay.active;
        const double *src_weight = lm->lay.src_weight, *ring_K = lm->cpl.ring_K;
        double *rowsum[SQ_MAX_LEVELS];
        for (int k = 0; k < L; k++)
            rowsum[k] = lod->lev[k].rate.coupled_rowsum;
        /* the sum of |weights| of each ring ghost's sources, once per ghost (a ghost is a column
         * of about ten ring rows) */
        if (nring > lod->cpl.abs_cap) {
            lod->cpl.abs_cap = SQ_MAX(nring, 2 * lod->cpl.abs_cap);
            lod->cpl.abs_sum = sq_realloc(lod->cpl.abs_sum, sizeof(double) * (size_t)lod->cpl.abs_cap);
        }
        double *abs_sum = lod->cpl.abs_sum;
        for (int r = 0; r < nring; r++) {
            double sc = 0;
            for (int q = src_start[r]; q < src_start[r + 1]; q++)
                sc += fabs(src_weight[q]);
            abs_sum[r] = sc;
        }
        for (int r = 0; r < nring; r++) {
            int a = src_start[r], b = src_start[r + 1];
            if (a == b)
                continue;
            double R = 0;
            for (int e = ring_off[r]; e < ring_off[r + 1]; e++) {
                int l = ring_col[e];
                double scale = 1;
                if (!active[l]) {
                    int rl = ring_index[l];
                    scale = rl >= 0 ? abs_sum[rl] : 0;
                }
                R += block_norm(ring_K + 9 * (size_t)e) * scale;
            }
            for (int q = a; q < b; q++)
                rowsum[src_level[q]][src_node[q]] += fabs(src_weight[q]) * R;
        }
    }
    for (int k = 0; k < L; k++) {
        const sq_level *Lk = &lod->lv[k];
        double own = lod->lev[k].rate.own_rate, coupled = 0;
        for (int a = 0; a < lod->lev[k].lay.nactive; a++) {
            int i = lod->lev[k].lists.active_list[a];
            if (Lk->model.fixed[i] == 7)
                continue;
            coupled = fmax(coupled, (lod->lev[k].rate.own_rowsum[i] + lod->lev[k].rate.coupled_rowsum[i]) / Lk->model.mass[i]);
        }
        int extra = 0;
        if (own > 0 && coupled > own)
            extra = (int)ceil(0.5 * log2(coupled / own) - 1e-12);
        lod->lev[k].rate.extra_log2 = SQ_MIN(SQ_MAX(extra, 0), 6);
    }
    sq_lodx_sharp_bound(lod); /* with "step_bound": "sharp", the Lanczos substeps instead */
}

void sq_lodx_coupling_bound(sq_lod *lod)
{
    coupling_bound(lod);
}

void sq_lodx_update_ring_blocks(sq_lod *lod, const sq_material *mat)
{
    int first = 0;
    int changed = 0;
    if (mat && (!lod->cpl.have_mat || memcmp(mat, &lod->cpl.mat, sizeof(*mat)) != 0 || lod->lv[0].model.K != lod->cpl.k_seen)) {
        lod->cpl.mat = *mat;
        lod->cpl.have_mat = 1;
        lod->cpl.k_seen = lod->lv[0].model.K;
        lod->cpl.op = infer_op(lod, mat);
        drop_tet_blocks(lod);
        own_rows(lod);
        first = 1;
        for (int k = 0; k < lod->L; k++) {
            lod->lev[k].cpl.blocks_dirty = 1;
            lod->lev[k].cpl.blocks_valid = 0; /* every row again for the new material */
        }
    }
    if (!lod->cpl.have_mat)
        return;
    double c = sq_thread_cpu();
    for (int k = 0; k < lod->L; k++) {
        lod->lev[k].cpl.blocks_cpu = 0;
        if (lod->lev[k].cpl.blocks_dirty) {
            build_ring_blocks(lod, k);
            sq_lodx_tick_hot_stale(lod, k);
            changed = 1;
            double t = sq_thread_cpu();
            lod->lev[k].cpl.blocks_cpu = t - c; /* the guard's cost model (pass.c, guard.c) */
            c = t;
        }
    }
    lod->cpl.bound_cpu = 0;
    if (changed) {
        coupling_bound(lod);
        lod->cpl.bound_cpu = sq_thread_cpu() - c;
    }
    if (first && lod->reserve.reserve_live) /* a new material under a budget: every array reserved and
                                     * mapped, whatever it costs (first budgeted frame: pass.c) */
        sq_lodx_reserve_blocks(lod, 1e9, SQ_RESERVE_LOAD_CHUNKS);
}

void sq_lod_set_material(sq_lod *lod, const sq_material *mat)
{
    sq_lodx_update_ring_blocks(lod, mat);
}
