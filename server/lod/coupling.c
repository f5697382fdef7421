/* adaptive.c - the paper's adaptive multi-level step (sections 4.2-4.3).
 *
 * Every node of every level is in one of three states:
 *   active        integrated at its level's own step;
 *   split ghost   its region is simulated finer: value interpolated from its child tet;
 *   coarse ghost  its region is simulated coarser: value interpolated from its parent tet.
 * A level-0 node is active unless split; a level-(k+1) node is a coarse ghost exactly when
 * its parent is not split. Splitting an active node makes it a split ghost and its children
 * active (they start from their interpolated displacement and velocity); merging does the
 * reverse when all children are calm.
 *
 * A frame runs the finest substep clock (2^nmax ticks); level k is due every 2^(nmax - n_k)
 * ticks. At a tick, each due level (coarse to fine) integrates its active nodes, then pushes
 * the new values to the coarse ghosts of the next finer level. At the end of the tick, the
 * split ghosts of the levels due next are pulled from finer levels (fine to coarse), and each
 * pair of levels that is synchronized in time adapts (split/merge).
 */
#include "lod/lod.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lod/lod_internal.h"

#include <time.h>

/* CPU time of the calling thread (s): what the frame costs on an idle core */
static double thread_cpu(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ---------------------------------------------------------------- state bookkeeping */

/* substep exponent a level runs at in the adaptive frame */
static int sub_log2(const sq_lod *lod, int k)
{
    return lod->lv[k].substeps_log2 + lod->extra[k];
}

/* recompute the active mask, the ghost lists and the integration mask of level k */
static void rebuild_level(sq_lod *lod, int k)
{
    int n = lod->lv[k].n;
    int na = 0, nf = 0, nc = 0;
    for (int i = 0; i < n; i++) {
        unsigned char s = lod->state[k][i];
        lod->active[k][i] = (s == ST_ACTIVE);
        lod->mask[k][i] = (s == ST_ACTIVE);
        if (s == ST_ACTIVE)
            lod->alist[k][na++] = i;
        else if (s == ST_SPLIT)
            lod->gf[k][nf++] = i;
        else
            lod->gc[k][nc++] = i;
    }
    lod->nactive[k] = na;
    lod->ngf[k] = nf;
    lod->ngc[k] = nc;
    /* the ring (ghosts with an active neighbour) and the frontier (active nodes with a ghost
     * neighbour), found from the active nodes' rows, so the cost follows the active set; the
     * ring is kept in increasing node order */
    const sq_level *Lk = &lod->lv[k];
    const unsigned char *act = lod->active[k];
    for (int r = 0; r < lod->nring[k]; r++)
        lod->ring_index[k][lod->ring[k][r]] = -1;
    int nr = 0, nfr = 0;
    for (int a = 0; a < na; a++) {
        int i = lod->alist[k][a], front = 0;
        for (int q = Lk->row_start[i]; q < Lk->row_start[i + 1]; q++) {
            int j = Lk->col[q];
            if (act[j])
                continue;
            front = 1;
            if (lod->ring_index[k][j] < 0) {
                lod->ring_index[k][j] = 0;
                lod->ring[k][nr++] = j;
            }
        }
        if (front)
            lod->front[k][nfr++] = i;
    }
    if ((long)nr * 32 > n) { /* a sizeable ring: a scan of the marks beats a sort */
        nr = 0;
        for (int i = 0; i < n; i++)
            if (lod->ring_index[k][i] >= 0)
                lod->ring[k][nr++] = i;
    } else {
        sq_lodx_sort_ints(lod->ring[k], nr);
    }
    for (int r = 0; r < nr; r++)
        lod->ring_index[k][lod->ring[k][r]] = r;
    lod->nring[k] = nr;
    lod->nfront[k] = nfr;
    memcpy(lod->inner[k], lod->active[k], (size_t)SQ_MAX(n, 0));
    for (int r = 0; r < nfr; r++)
        lod->inner[k][lod->front[k][r]] = 0;
    lod->rk_dirty[k] = 1;
    /* held nodes are prescribed, not integrated */
    int nm = na;
    for (int e = 0; e < lod->nhe; e++)
        if (lod->he[e].level == k && lod->he[e].count > 0 && lod->mask[k][lod->he[e].node]) {
            lod->mask[k][lod->he[e].node] = 0;
            nm--;
        }
    lod->nmask[k] = nm;
    sq_lodx_level_lists(lod, k);
}

/* all levels below s split, level s active, finer levels coarse ghosts */
static void set_uniform_level(sq_lod *lod, int s)
{
    for (int k = 0; k < lod->L; k++) {
        unsigned char st = k < s ? ST_SPLIT : (k == s ? ST_ACTIVE : ST_COARSE);
        memset(lod->state[k], st, (size_t)lod->lv[k].n);
    }
    for (int k = 0; k < lod->L; k++)
        rebuild_level(lod, k);
}

/* ---------------------------------------------------------------- ghost interpolation */

/* split ghosts of level k from their child tets in level k+1 */
static void pull_level(sq_lod *lod, int k)
{
    if (k + 1 >= lod->L)
        return;
    const sq_lod_link *ln = &lod->h.link[k];
    sq_level *dst = &lod->lv[k];
    for (int g = 0; g < lod->ngf[k]; g++) {
        int i = lod->gf[k][g];
        sq_lodx_interp(lod, dst, i, k + 1, ln->down_tet[i], ln->down_bary + 4 * i);
    }
}

/* coarse ghosts of level k from their parent tets in level k-1 */
static void push_level(sq_lod *lod, int k)
{
    if (k < 1 || k >= lod->L)
        return;
    const sq_lod_link *ln = &lod->h.link[k - 1];
    sq_level *dst = &lod->lv[k];
    const sq_level *src = &lod->lv[k - 1];
    for (int g = 0; g < lod->ngc[k]; g++) {
        int j = lod->gc[k][g];
        interp_node(dst, j, src, ln->up_tet[j], ln->up_bary + 4 * j);
    }
}

static void build_sources(sq_lod *lod);
static void update_ring_blocks(sq_lod *lod, const sq_material *mat);
static void eval_ring(sq_lod *lod, int k, long t);

/* every ghost value from the active nodes: split ghosts pulled fine to coarse, coarse ghosts
 * pushed coarse to fine (the rendered finest level included), then the ring ghosts as their
 * exact combinations of active nodes */
static void cascade(sq_lod *lod)
{
    for (int k = lod->L - 2; k >= 0; k--)
        pull_level(lod, k);
    for (int k = 1; k < lod->L; k++)
        push_level(lod, k);
    lod->stale = 0;
    lod->full_no = ++lod->cascade_no;
    for (int k = 0; k < lod->L; k++)
        eval_ring(lod, k, lod->step_t0[k] + lod->step_len[k]);
}

/* the end-of-frame cascade: as cascade(), but coarse ghosts are pushed only where something
 * reads them (the needed set, activeset.c); the others are pushed on demand */
static void cascade_needed(sq_lod *lod)
{
    for (int k = lod->L - 2; k >= 0; k--)
        pull_level(lod, k);
    if (lod->lists_dirty)
        sq_lodx_refresh_lists(lod);
    sq_lodx_push_needed(lod);
    sq_lodx_save_cascade(lod);
    for (int k = 0; k < lod->L; k++)
        eval_ring(lod, k, lod->step_t0[k] + lod->step_len[k]);
}

void sq_lod_sync(sq_lod *lod)
{
    for (int k = 0; k < lod->L; k++) {
        lod->step_t0[k] = -1;
        lod->step_len[k] = 1;
        size_t n3 = 3 * (size_t)lod->lv[k].n;
        memcpy(lod->dprev[k], lod->lv[k].d, n3 * sizeof(double));
        memcpy(lod->vprev[k], lod->lv[k].v, n3 * sizeof(double));
    }
    build_sources(lod);
    update_ring_blocks(lod, NULL);
    cascade(lod);
}

/* ---------------------------------------------------------------- criterion operator */

static int cmp_tri(const void *pa, const void *pb)
{
    const int *a = pa, *b = pb;
    for (int c = 0; c < 3; c++)
        if (a[c] != b[c])
            return a[c] < b[c] ? -1 : 1;
    return 0;
}

static void sort3(int *t)
{
    int a;
    if (t[0] > t[1]) { a = t[0]; t[0] = t[1]; t[1] = a; }
    if (t[1] > t[2]) { a = t[1]; t[1] = t[2]; t[2] = a; }
    if (t[0] > t[1]) { a = t[0]; t[0] = t[1]; t[1] = a; }
}

/* position of column j in CSR row i of the mesh adjacency (sorted), or -1 */
static int adj_find(const sq_mesh *m, int i, int j)
{
    int lo = m->adj_start[i], hi = m->adj_start[i + 1] - 1;
    while (lo <= hi) {
        int mid = (lo + hi) / 2;
        if (m->adj[mid] == j)
            return mid;
        if (m->adj[mid] < j)
            lo = mid + 1;
        else
            hi = mid - 1;
    }
    return -1;
}

/* weights w_ij (CSR of the mesh adjacency) with Lap(d)_i = -(1/vol_i) sum_j w_ij d_j.
 * Interior rows are the lumped FEM Laplacian sum_T V a_i . a_j. On boundary rows that
 * operator also holds the boundary flux (a linear field gets a Laplacian of order
 * |grad d| / h there, which would split every surface node of a body that merely sags),
 * so the flux of the tet's own gradient through the node's boundary faces is removed:
 * for the face opposite q of tet T, A n = -3 V a_q, and each of its three nodes i gets
 * (A/3) (grad d . n) = -V sum_m (a_m . a_q) d_m. A linear field then has zero Laplacian at
 * every node, and the criterion measures only curvature, as the paper intends. */
static double *criterion_weights(const sq_mesh *m)
{
    int nnz = m->adj_start[m->nnodes];
    double *w = sq_calloc((size_t)SQ_MAX(nnz, 1), sizeof(double));
    int *keys = sq_malloc(sizeof(int) * 3 * (size_t)SQ_MAX(m->ntris, 1));
    for (int t = 0; t < m->ntris; t++) {
        memcpy(keys + 3 * t, m->tris + 3 * t, 3 * sizeof(int));
        sort3(keys + 3 * t);
    }
    qsort(keys, (size_t)m->ntris, 3 * sizeof(int), cmp_tri);
    for (int t = 0; t < m->ntets; t++) {
        const int *tn = m->tets + 4 * t;
        double a[4][3];
        double V = fabs(sq_tet_gradients(m, t, a));
        for (int i = 0; i < 4; i++)
            for (int j = 0; j < 4; j++) {
                int s = adj_find(m, tn[i], tn[j]);
                if (s >= 0)
                    w[s] += V * (a[i][0] * a[j][0] + a[i][1] * a[j][1] + a[i][2] * a[j][2]);
            }
        for (int q = 0; q < 4; q++) {
            int face[3], nf = 0;
            for (int i = 0; i < 4; i++)
                if (i != q)
                    face[nf++] = tn[i];
            if (!m->on_boundary[face[0]] || !m->on_boundary[face[1]] || !m->on_boundary[face[2]])
                continue;
            sort3(face);
            if (!bsearch(face, keys, (size_t)m->ntris, 3 * sizeof(int), cmp_tri))
                continue;
            for (int i = 0; i < 4; i++) {
                if (i == q)
                    continue;
                for (int mm = 0; mm < 4; mm++) {
                    int s = adj_find(m, tn[i], tn[mm]);
                    if (s >= 0)
                        w[s] += V * (a[mm][0] * a[q][0] + a[mm][1] * a[q][1] + a[mm][2] * a[q][2]);
                }
            }
        }
    }
    free(keys);
    return w;
}

/* ---------------------------------------------------------------- ring blocks */

/* weight of a tet with both active and ghost corners in its level's energy: the band where
 * two levels meet is covered by the mixed tets of both, so each counts half */
#define MIXED_WEIGHT 0.5

/* tets around each node (CSR) */
static void node_tets(const sq_mesh *m, int **start, int **list)
{
    int *st = sq_calloc((size_t)m->nnodes + 1, sizeof(int));
    for (int t = 0; t < 4 * m->ntets; t++)
        st[m->tets[t] + 1]++;
    for (int i = 0; i < m->nnodes; i++)
        st[i + 1] += st[i];
    int *fill = sq_malloc(sizeof(int) * (size_t)SQ_MAX(m->nnodes, 1));
    memcpy(fill, st, sizeof(int) * (size_t)m->nnodes);
    int *ls = sq_malloc(sizeof(int) * 4 * (size_t)m->ntets);
    for (int t = 0; t < m->ntets; t++)
        for (int q = 0; q < 4; q++)
            ls[fill[m->tets[4 * t + q]]++] = t;
    free(fill);
    *start = st;
    *list = ls;
}

/* block (i, j) of one tet's operator (level/level.c, PHYSICS.md section 2) with shear-like
 * coefficient s and volume-like l, added to B */
static void add_block(sq_operator_kind op, double V, const double *ai, const double *aj, double s,
                      double l, double *B)
{
    double dot = ai[0] * aj[0] + ai[1] * aj[1] + ai[2] * aj[2];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            double v = (r == c ? s * dot : 0);
            if (op == SQ_OPERATOR_PAPER)
                v += (l + s) * ai[r] * aj[c];
            else
                v += s * aj[r] * ai[c] + l * ai[r] * aj[c];
            B[3 * r + c] += V * v;
        }
}

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
    int sl = lod->ke_slot[k][t];
    size_t per = visc ? 288 : 144;
    if (sl >= 0)
        return lod->ke[k] + per * (size_t)sl;
    if (lod->ke_n[k] == lod->ke_cap[k]) {
        lod->ke_cap[k] = lod->ke_cap[k] ? 2 * lod->ke_cap[k] : 256;
        lod->ke[k] = sq_realloc(lod->ke[k], sizeof(double) * per * (size_t)lod->ke_cap[k]);
    }
    sl = lod->ke_n[k]++;
    lod->ke_slot[k][t] = sl;
    double *E = lod->ke[k] + per * (size_t)sl;
    memset(E, 0, sizeof(double) * per);
    const double *g = lod->tet_geom[k] + 13 * (size_t)t;
    const sq_material *mat = &lod->mat;
    for (int p = 0; p < 4; p++)
        for (int q = 0; q < 4; q++) {
            add_block(lod->op, g[0], g + 1 + 3 * p, g + 1 + 3 * q, mat->mu, mat->lambda, E + 9 * (4 * p + q));
            if (visc)
                add_block(lod->op, g[0], g + 1 + 3 * p, g + 1 + 3 * q, mat->phi, mat->psi,
                          E + 144 + 9 * (4 * p + q));
        }
    return E;
}

/* forget the cached element blocks (material or operator changed) */
static void drop_tet_blocks(sq_lod *lod)
{
    for (int k = 0; k < lod->L; k++) {
        for (int t = 0; t < lod->lv[k].mesh->ntets && lod->ke_n[k] > 0; t++)
            lod->ke_slot[k][t] = -1;
        lod->ke_n[k] = 0;
    }
}

/* the mixed-tet blocks of row j (incidences c0..c1) into B (and Bd), times weight (a power
 * of two, so the products equal those of the blocks built with weight * V) */
static inline void row_blocks(sq_lod *lod, int k, int c0, int c1, double weight, double *restrict B,
                              double *restrict Bd)
{
    const sq_mesh *m = lod->lv[k].mesh;
    const unsigned char *act = lod->active[k];
    int visc = Bd != NULL;
    for (int c = c0; c < c1; c++) {
        int t = lod->node_tet[k][c];
        const int *tv = m->tets + 4 * t;
        int na = act[tv[0]] + act[tv[1]] + act[tv[2]] + act[tv[3]];
        if (na == 0 || na == 4)
            continue;
        const double *E = tet_blocks(lod, k, t, visc) + 36 * lod->nt_p[k][c];
        const int *ev = lod->nt_e[k] + 4 * (size_t)c;
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
    const sq_mesh *m = L->mesh;
    /* a boundary node: the two operators differ there */
    int i = 0;
    while (i < m->nnodes && !m->on_boundary[i])
        i++;
    if (i == m->nnodes)
        return SQ_OPERATOR_FEM;
    int n = L->row_start[i + 1] - L->row_start[i];
    double *row[2];
    double err[2] = {0, 0};
    for (int o = 0; o < 2; o++) {
        row[o] = sq_calloc(9 * (size_t)n, sizeof(double));
        for (int c = lod->node_tet_start[0][i]; c < lod->node_tet_start[0][i + 1]; c++) {
            int t = lod->node_tet[0][c];
            double a[4][3];
            double V = sq_tet_gradients(m, t, a);
            int p = 0;
            while (m->tets[4 * t + p] != i)
                p++;
            for (int q = 0; q < 4; q++) {
                int e = adj_find(m, i, m->tets[4 * t + q]) - L->row_start[i];
                add_block((sq_operator_kind)o, V, a[p], a[q], mat->mu, mat->lambda, row[o] + 9 * e);
            }
        }
        for (int e = 0; e < 9 * n; e++)
            err[o] += fabs(row[o][e] - L->K[9 * L->row_start[i] + e]);
        free(row[o]);
    }
    return err[SQ_OPERATOR_PAPER] < err[SQ_OPERATOR_FEM] ? SQ_OPERATOR_PAPER : SQ_OPERATOR_FEM;
}

/* blocks of node list nodes[0..nn) of level k (aligned with their adjacency rows), summed
 * over their tets that touch an active node and have a ghost corner, times weight */
static void build_blocks(sq_lod *lod, int k, const int *nodes, int nn, int *off, int **cols, double **bk,
                         int *bk_cap, double **bd, int *bd_cap, double weight)
{
    const sq_level *L = &lod->lv[k];
    const sq_material *mat = &lod->mat;
    int visc = mat->use_viscosity && L->D;
    int total = 0;
    for (int r = 0; r < nn; r++) {
        off[r] = total;
        total += L->row_start[nodes[r] + 1] - L->row_start[nodes[r]];
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
        row_blocks(lod, k, lod->node_tet_start[k][j], lod->node_tet_start[k][j + 1], weight, B, Bd);
    }
    /* keep the non-zero blocks only, with their column */
    int *col = sq_realloc(*cols, sizeof(int) * (size_t)SQ_MAX(total, 1));
    *cols = col;
    int w = 0;
    for (int r = 0; r < nn; r++) {
        int j = nodes[r], start = off[r];
        off[r] = w;
        for (int q = L->row_start[j], e = 0; q < L->row_start[j + 1]; q++, e++) {
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
            col[w++] = L->col[q];
        }
    }
    off[nn] = w;
}

/* ring rows (half of the mixed tets) and frontier corrections (the other half of the mixed
 * tets, given back) of level k */
static void build_ring_blocks(sq_lod *lod, int k)
{
    build_blocks(lod, k, lod->ring[k], lod->nring[k], lod->rk_off[k], &lod->rk_col[k], &lod->rk[k], &lod->rk_cap[k],
                 &lod->rd[k], &lod->rd_cap[k], MIXED_WEIGHT);
    build_blocks(lod, k, lod->front[k], lod->nfront[k], lod->fk_off[k], &lod->fk_col[k], &lod->fk[k], &lod->fk_cap[k],
                 &lod->fd[k], &lod->fd_cap[k], 1.0 - MIXED_WEIGHT);
    /* merged frontier rows: the level's row less the correction the frontier pass adds back
     * (front_correct adds fk w; the force pass subtracts K w) */
    const sq_level *L = &lod->lv[k];
    int total = 0;
    for (int r = 0; r < lod->nfront[k]; r++) {
        int i = lod->front[k][r];
        total += L->row_start[i + 1] - L->row_start[i];
    }
    if (total > lod->fm_cap[k]) {
        lod->fm_cap[k] = SQ_MAX(total, 2 * lod->fm_cap[k]);
        lod->fm[k] = sq_realloc(lod->fm[k], sizeof(double) * 9 * (size_t)lod->fm_cap[k]);
    }
    double *M = lod->fm[k];
    for (int r = 0; r < lod->nfront[k]; r++) {
        int i = lod->front[k][r], q0 = L->row_start[i], len = L->row_start[i + 1] - q0;
        memcpy(M, L->K + 9 * (size_t)q0, sizeof(double) * 9 * (size_t)len);
        for (int e = lod->fk_off[k][r]; e < lod->fk_off[k][r + 1]; e++) {
            int pos = adj_find(L->mesh, i, lod->fk_col[k][e]) - q0;
            for (int x = 0; x < 9; x++)
                M[9 * pos + x] -= lod->fk[k][9 * (size_t)e + x];
        }
        M += 9 * (size_t)len;
    }
    lod->rk_dirty[k] = 0;
}

/* frontier correction of level k after its full-row forces: f_i += (1 - w) sum over mixed
 * tets of K^T (d + b v) (+ D^T v) */
static void front_correct(sq_lod *lod, const sq_material *mat, int k)
{
    sq_level *L = &lod->lv[k];
    double b = mat->use_viscosity ? 0 : mat->rayleigh_stiffness;
    int visc = mat->use_viscosity && lod->fd[k];
    for (int r = 0; r < lod->nfront[k]; r++) {
        int i = lod->front[k][r];
        const double *B = lod->fk[k];
        const double *Bd = visc ? lod->fd[k] : NULL;
        double *fi = L->f + 3 * i;
        for (int e = lod->fk_off[k][r]; e < lod->fk_off[k][r + 1]; e++) {
            int l = lod->fk_col[k][e];
            const double *dl = L->d + 3 * l, *vl = L->v + 3 * l, *K = B + 9 * e;
            double w[3] = {dl[0] + b * vl[0], dl[1] + b * vl[1], dl[2] + b * vl[2]};
            for (int rr = 0; rr < 3; rr++)
                fi[rr] += K[3 * rr] * w[0] + K[3 * rr + 1] * w[1] + K[3 * rr + 2] * w[2];
            if (Bd) {
                const double *D = Bd + 9 * e;
                for (int rr = 0; rr < 3; rr++)
                    fi[rr] += D[3 * rr] * vl[0] + D[3 * rr + 1] * vl[1] + D[3 * rr + 2] * vl[2];
            }
        }
    }
}

/* forces of the frontier nodes of level k from their merged rows (the masked force pass
 * having skipped them): f_i = m_i (g - a v_i) - sum_j M_ij (d_j + b v_j); no viscosity */
static void front_rows(sq_lod *lod, const sq_material *mat, const double gravity[3], int k)
{
    sq_level *L = &lod->lv[k];
    const double b = mat->rayleigh_stiffness, a = mat->rayleigh_mass;
    const double *restrict d = L->d, *restrict v = L->v;
    const double *M = lod->fm[k];
    for (int r = 0; r < lod->nfront[k]; r++) {
        int i = lod->front[k][r];
        double f0 = 0, f1 = 0, f2 = 0;
        for (int q = L->row_start[i]; q < L->row_start[i + 1]; q++, M += 9) {
            const size_t j = 3 * (size_t)L->col[q];
            const double w0 = d[j] + b * v[j], w1 = d[j + 1] + b * v[j + 1], w2 = d[j + 2] + b * v[j + 2];
            f0 += M[0] * w0 + M[1] * w1 + M[2] * w2;
            f1 += M[3] * w0 + M[4] * w1 + M[5] * w2;
            f2 += M[6] * w0 + M[7] * w1 + M[8] * w2;
        }
        double m = L->mass[i], *fi = L->f + 3 * (size_t)i;
        fi[0] = m * (gravity[0] - a * v[3 * i]) - f0;
        fi[1] = m * (gravity[1] - a * v[3 * i + 1]) - f1;
        fi[2] = m * (gravity[2] - a * v[3 * i + 2]) - f2;
    }
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

/* Gershgorin row sums of each level's own operator (material dependent) */
static void own_rows(sq_lod *lod)
{
    for (int k = 0; k < lod->L; k++) {
        const sq_level *L = &lod->lv[k];
        if (!lod->rowk[k])
            lod->rowk[k] = sq_malloc(sizeof(double) * (size_t)L->n);
        for (int i = 0; i < L->n; i++) {
            double s = 0;
            for (int q = L->row_start[i]; q < L->row_start[i + 1]; q++)
                s += block_norm(L->K + 9 * (size_t)q);
            lod->rowk[k][i] = s;
        }
        double own = 0;
        for (int i = 0; i < L->n; i++)
            if (L->fixed[i] != 7)
                own = fmax(own, lod->rowk[k][i] / L->mass[i]);
        lod->own_max[k] = own;
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
        if (!lod->cpl[k])
            lod->cpl[k] = sq_malloc(sizeof(double) * (size_t)lod->lv[k].n);
        memset(lod->cpl[k], 0, sizeof(double) * (size_t)lod->lv[k].n);
    }
    for (int m = 0; m < L; m++) {
        for (int r = 0; r < lod->nring[m]; r++) {
            int a = lod->fs_start[m][r], b = lod->fs_start[m][r + 1];
            if (a == b)
                continue;
            double R = 0;
            for (int e = lod->rk_off[m][r]; e < lod->rk_off[m][r + 1]; e++) {
                int l = lod->rk_col[m][e];
                double scale = 1;
                if (!lod->active[m][l]) {
                    int rl = lod->ring_index[m][l];
                    scale = 0;
                    if (rl >= 0)
                        for (int q = lod->fs_start[m][rl]; q < lod->fs_start[m][rl + 1]; q++)
                            scale += fabs(lod->fs_w[m][q]);
                }
                R += block_norm(lod->rk[m] + 9 * (size_t)e) * scale;
            }
            for (int q = a; q < b; q++)
                lod->cpl[lod->fs_level[m][q]][lod->fs_node[m][q]] += fabs(lod->fs_w[m][q]) * R;
        }
    }
    for (int k = 0; k < L; k++) {
        const sq_level *Lk = &lod->lv[k];
        double own = lod->own_max[k], coupled = 0;
        for (int a = 0; a < lod->nactive[k]; a++) {
            int i = lod->alist[k][a];
            if (Lk->fixed[i] == 7)
                continue;
            coupled = fmax(coupled, (lod->rowk[k][i] + lod->cpl[k][i]) / Lk->mass[i]);
        }
        int extra = 0;
        if (own > 0 && coupled > own)
            extra = (int)ceil(0.5 * log2(coupled / own) - 1e-12);
        lod->extra[k] = SQ_MIN(SQ_MAX(extra, 0), 6);
    }
}

static void update_ring_blocks(sq_lod *lod, const sq_material *mat)
{
    int changed = 0;
    if (mat && (!lod->have_mat || memcmp(mat, &lod->mat, sizeof(*mat)) != 0 || lod->lv[0].K != lod->k_seen)) {
        lod->mat = *mat;
        lod->have_mat = 1;
        lod->k_seen = lod->lv[0].K;
        lod->op = infer_op(lod, mat);
        drop_tet_blocks(lod);
        own_rows(lod);
        for (int k = 0; k < lod->L; k++)
            lod->rk_dirty[k] = 1;
    }
    if (!lod->have_mat)
        return;
    for (int k = 0; k < lod->L; k++)
        if (lod->rk_dirty[k]) {
            build_ring_blocks(lod, k);
            changed = 1;
        }
    if (changed)
        coupling_bound(lod);
}

void sq_lod_set_material(sq_lod *lod, const sq_material *mat)
{
    update_ring_blocks(lod, mat);
}

/* ---------------------------------------------------------------- creation */


/* effective top level of a definition over L levels (max_level beyond the last = every level) */
static int top_of(const sq_lod_def *def, int L)
{
    if (def->max_level >= 0 && def->max_level < L - 1)
        return def->max_level;
    return L - 1;
}

static int check_def(const sq_lod_def *def, int L, sq_err *err)
{
    if (isnan(def->split) || def->split < 0)
        return sq_err_set(err, "lod.split = %g: must be >= 0 (0 forces the finest level, a huge value "
                          "keeps the coarsest)", def->split);
    if (!isfinite(def->merge) || def->merge < 0)
        return sq_err_set(err, "lod.merge = %g: must be a finite value >= 0", def->merge);
    if (def->split > 0 && !(def->merge < def->split))
        return sq_err_set(err, "lod.merge = %g must be below lod.split = %g (hysteresis); "
                          "try merge = split / 8", def->merge, def->split);
    if (!isfinite(def->budget) || def->budget <= 0 || def->budget > 1)
        return sq_err_set(err, "lod.budget = %g: must be a fraction of the frame period in (0, 1] "
                          "(0.95 is usual)", def->budget);
    if (def->max_node_updates < 0)
        return sq_err_set(err, "lod.max_node_updates = %ld: must be >= 0 (0 = no cap)",
                          def->max_node_updates);
    if (def->level < 0 || def->level > top_of(def, L))
        return sq_err_set(err, "lod.level = %d: the starting level must be in [0, %d]", def->level,
                          top_of(def, L));
    return 0;
}

/* the starting layout of a definition: forced finest (split 0) starts at the top level */
static int start_level(const sq_lod *lod)
{
    return lod->def.split <= 0 ? lod->top : lod->def.level;
}

sq_lod *sq_lod_create(sq_level *levels, int nlevels, const sq_lod_def *def, sq_err *err)
{
    if (nlevels < 1 || nlevels > SQ_MAX_LEVELS) {
        sq_err_set(err, "lod: %d levels given, need 1 to %d", nlevels, SQ_MAX_LEVELS);
        return NULL;
    }
    if (check_def(def, nlevels, err))
        return NULL;
    const sq_mesh *meshes[SQ_MAX_LEVELS];
    for (int k = 0; k < nlevels; k++) {
        meshes[k] = levels[k].mesh;
        if (!meshes[k] || levels[k].n != meshes[k]->nnodes) {
            sq_err_set(err, "lod: level %d has no mesh or a node count that does not match it", k);
            return NULL;
        }
    }
    sq_lod *lod = sq_calloc(1, sizeof(*lod));
    lod->lv = levels;
    lod->L = nlevels;
    lod->def = *def;
    lod->top = top_of(def, nlevels);
    lod->nl_gen = -1;
    if (sq_hierarchy_build(&lod->h, meshes, nlevels, err)) {
        free(lod);
        return NULL;
    }
    size_t nmax_nodes = 1;
    for (int k = 0; k < nlevels; k++) {
        size_t n = (size_t)levels[k].n;
        lod->state[k] = sq_calloc(n, 1);
        lod->active[k] = sq_calloc(n, 1);
        lod->mask[k] = sq_calloc(n, 1);
        lod->fresh[k] = sq_calloc(n, 1);
        lod->alist[k] = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->ilist[k] = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->mlist[k] = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->plist[k] = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->need[k] = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->inneed[k] = sq_calloc(SQ_MAX(n, 1), 1);
        lod->mark[k] = sq_calloc(SQ_MAX(n, 1), 1);
        lod->pstamp[k] = sq_calloc(SQ_MAX(n, 1), sizeof(unsigned));
        nmax_nodes = SQ_MAX(nmax_nodes, n);
        lod->gf[k] = sq_malloc(sizeof(int) * n);
        lod->gc[k] = sq_malloc(sizeof(int) * n);
        lod->slot[k] = sq_malloc(sizeof(int) * n);
        lod->clap[k] = criterion_weights(levels[k].mesh);
        lod->ring[k] = sq_malloc(sizeof(int) * n);
        lod->dprev[k] = sq_calloc(3 * n, sizeof(double));
        lod->vprev[k] = sq_calloc(3 * n, sizeof(double));
        lod->fs_start[k] = sq_calloc(n + 1, sizeof(int));
        lod->fs_levels[k] = sq_calloc(n + 1, 1);
        lod->rk_off[k] = sq_calloc(n + 1, sizeof(int));
        lod->ring_index[k] = sq_malloc(sizeof(int) * n);
        for (size_t i = 0; i < n; i++)
            lod->ring_index[k][i] = -1;
        lod->front[k] = sq_malloc(sizeof(int) * n);
        lod->inner[k] = sq_calloc(n, 1);
        lod->fk_off[k] = sq_calloc(n + 1, sizeof(int));
        node_tets(levels[k].mesh, &lod->node_tet_start[k], &lod->node_tet[k]);
        {
            const sq_mesh *mm = levels[k].mesh;
            int ninc = lod->node_tet_start[k][n];
            lod->ke_slot[k] = sq_malloc(sizeof(int) * (size_t)SQ_MAX(mm->ntets, 1));
            for (int t = 0; t < mm->ntets; t++)
                lod->ke_slot[k][t] = -1;
            lod->nt_p[k] = sq_malloc((size_t)SQ_MAX(ninc, 1));
            lod->nt_e[k] = sq_malloc(sizeof(int) * 4 * (size_t)SQ_MAX(ninc, 1));
            for (int j = 0; j < (int)n; j++)
                for (int c = lod->node_tet_start[k][j]; c < lod->node_tet_start[k][j + 1]; c++) {
                    const int *tv = mm->tets + 4 * lod->node_tet[k][c];
                    int p = 0;
                    while (tv[p] != j)
                        p++;
                    lod->nt_p[k][c] = (unsigned char)p;
                    for (int q = 0; q < 4; q++)
                        lod->nt_e[k][4 * (size_t)c + q] = adj_find(mm, j, tv[q]) - mm->adj_start[j];
                }
        }
        const sq_mesh *mk = levels[k].mesh;
        lod->tet_geom[k] = sq_malloc(sizeof(double) * 13 * (size_t)mk->ntets);
        for (int t = 0; t < mk->ntets; t++) {
            double a[4][3];
            double *g = lod->tet_geom[k] + 13 * (size_t)t;
            g[0] = sq_tet_gradients(mk, t, a);
            memcpy(g + 1, a, sizeof(a));
        }
        for (size_t i = 0; i < n; i++)
            lod->slot[k][i] = -1;
    }
    lod->nlv[0] = sq_malloc(SQ_MAX(nmax_nodes, (size_t)1));
    lod->nlv[1] = sq_malloc(SQ_MAX(nmax_nodes, (size_t)1));
    set_uniform_level(lod, start_level(lod));
    sq_lod_sync(lod);
    return lod;
}

void sq_lod_destroy(sq_lod *lod)
{
    if (!lod)
        return;
    for (int k = 0; k < lod->L; k++) {
        free(lod->state[k]);
        free(lod->active[k]);
        free(lod->mask[k]);
        free(lod->fresh[k]);
        sq_lodx_free(lod, k);
        free(lod->gf[k]);
        free(lod->gc[k]);
        free(lod->slot[k]);
        free(lod->clap[k]);
        free(lod->ring[k]);
        free(lod->dprev[k]);
        free(lod->vprev[k]);
        free(lod->fs_start[k]);
        free(lod->fs_levels[k]);
        free(lod->rk_off[k]);
        free(lod->ring_index[k]);
        free(lod->rowk[k]);
        free(lod->cpl[k]);
        free(lod->rk_col[k]);
        free(lod->fk_col[k]);
        free(lod->front[k]);
        free(lod->inner[k]);
        free(lod->fm[k]);
        free(lod->fk_off[k]);
        free(lod->fk[k]);
        free(lod->fd[k]);
        free(lod->rk[k]);
        free(lod->rd[k]);
        free(lod->node_tet_start[k]);
        free(lod->node_tet[k]);
        free(lod->nt_p[k]);
        free(lod->ke_slot[k]);
        free(lod->ke[k]);
        free(lod->nt_e[k]);
        free(lod->tet_geom[k]);
        free(lod->fs_level[k]);
        free(lod->fs_node[k]);
        free(lod->fs_w[k]);
    }
    free(lod->nlv[0]);
    free(lod->nlv[1]);
    free(lod->he);
    free(lod->hold_entry_of);
    sq_hierarchy_free(&lod->h);
    free(lod);
}

int sq_lod_set_def(sq_lod *lod, const sq_lod_def *def, sq_err *err)
{
    if (check_def(def, lod->L, err))
        return -1;
    int old_top = lod->top;
    int was_forced = lod->def.split <= 0;
    lod->def = *def;
    lod->top = top_of(def, lod->L);
    if (def->split <= 0) {
        /* forced finest: every region to the top level at once */
        if (!was_forced || old_top != lod->top) {
            set_uniform_level(lod, lod->top);
            sq_lod_sync(lod);
        }
    } else if (lod->top < old_top) {
        /* levels above the new top: merge their regions back down to it */
        for (int k = lod->top; k < lod->L; k++)
            for (int i = 0; i < lod->lv[k].n; i++)
                if (k == lod->top && lod->state[k][i] == ST_SPLIT)
                    lod->state[k][i] = ST_ACTIVE;
                else if (k > lod->top)
                    lod->state[k][i] = ST_COARSE;
        for (int k = lod->top; k < lod->L; k++)
            rebuild_level(lod, k);
        sq_lod_sync(lod);
    }
    lod->last_time = 0;
    return 0;
}

void sq_lod_reset(sq_lod *lod)
{
    set_uniform_level(lod, start_level(lod));
    lod->last_time = 0;
    sq_lod_sync(lod);
}

const sq_hierarchy *sq_lod_hierarchy(const sq_lod *lod)
{
    return &lod->h;
}

const unsigned char *sq_lod_active(const sq_lod *lod, int level)
{
    if (level < 0 || level >= lod->L)
        return NULL;
    return lod->active[level];
}

const int *sq_lod_active_list(const sq_lod *lod, int level, int *n)
{
    if (level < 0 || level >= lod->L) {
        *n = 0;
        return NULL;
    }
    *n = lod->nactive[level];
    return lod->alist[level];
}

long sq_lod_projected_updates(const sq_lod *lod)
{
    long u = 0;
    for (int k = 0; k < lod->L; k++)
        u += (long)lod->nactive[k] << sub_log2(lod, k);
    return u;
}

/* ---------------------------------------------------------------- split / merge */

/* delta_i = hbar_i^2 |Lap(d)_i| at node i of level k (boundary-corrected Laplacian) */
static double delta_at(const sq_lod *lod, int k, int i)
{
    const sq_level *L = &lod->lv[k];
    const double *w = lod->clap[k];
    double s[3] = {0, 0, 0};
    const unsigned char *st = lod->state[k];
    const unsigned *ps = lod->pstamp[k];
    int all_valid = lod->full_no == lod->cascade_no;
    const double *ds = lod->dstat[k];
    for (int q = L->row_start[i]; q < L->row_start[i + 1]; q++) {
        int j = L->col[q];
        const double *dj = L->d + 3 * j;
        double fresh[3], fv[3];
        if (k > 0 && st[j] == ST_COARSE && !all_valid && ps[j] != lod->cascade_no) {
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
    double h2 = L->hbar[i] * L->hbar[i];
    return h2 / L->vol[i] * sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
}

double sq_lod_delta(const sq_lod *lod, int level, int node)
{
    if (level < 0 || level >= lod->L || node < 0 || node >= lod->lv[level].n)
        return 0;
    sq_lod_flush((sq_lod *)lod); /* ghost values pushed on demand are part of the state */
    return delta_at(lod, level, node);
}

/* counters of one frame's adaptation */
typedef struct adapt_out {
    int splits, merges, refused;
    int changed[SQ_MAX_LEVELS];
} adapt_out;

static void merge_node(sq_lod *lod, int k, int p)
{
    const sq_lod_link *ln = &lod->h.link[k];
    lod->state[k][p] = ST_ACTIVE;
    /* the merged node starts from its interpolated value (pulled from its child tet) */
    sq_lodx_interp(lod, &lod->lv[k], p, k + 1, ln->down_tet[p], ln->down_bary + 4 * p);
    for (int c = ln->child_start[p]; c < ln->child_start[p + 1]; c++)
        lod->state[k + 1][ln->child[c]] = ST_COARSE;
    memcpy(lod->dprev[k] + 3 * p, lod->lv[k].d + 3 * p, 3 * sizeof(double));
    memcpy(lod->vprev[k] + 3 * p, lod->lv[k].v + 3 * p, 3 * sizeof(double));
    /* children become coarse ghosts and take their parent-tet value at once */
    for (int c = ln->child_start[p]; c < ln->child_start[p + 1]; c++) {
        int j = ln->child[c];
        sq_lodx_interp(lod, &lod->lv[k + 1], j, k, ln->up_tet[j], ln->up_bary + 4 * j);
    }
}

/* split/merge between levels k and k+1 (both at the same time); `allow_split` from the
 * budget; the node-update cap refuses splits that would exceed it */
static void adapt_pair(sq_lod *lod, int k, int allow_split, long *projected, adapt_out *out)
{
    if (k >= lod->top)
        return;
    const sq_lod_def *def = &lod->def;
    const sq_lod_link *ln = &lod->h.link[k];
    sq_level *Lk = &lod->lv[k], *Lf = &lod->lv[k + 1];
    int forced = def->split <= 0;
    long cost_k = 1L << sub_log2(lod, k), cost_f = 1L << sub_log2(lod, k + 1);
    int changed = 0;

    /* splits: active nodes of level k above the threshold */
    if (def->split < INFINITY) {
        for (int i = 0; i < Lk->n; i++) {
            if (lod->state[k][i] != ST_ACTIVE)
                continue;
            if (!forced && !(delta_at(lod, k, i) > def->split))
                continue;
            int nch = ln->child_start[i + 1] - ln->child_start[i];
            long extra = nch * cost_f - cost_k;
            if (!allow_split || (def->max_node_updates > 0 && *projected + extra > def->max_node_updates)) {
                out->refused = 1;
                continue;
            }
            /* children start from their interpolated d and v (parent tet, values now) */
            lod->state[k][i] = ST_SPLIT;
            lod->fresh[k][i] = 1;
            for (int c = ln->child_start[i]; c < ln->child_start[i + 1]; c++) {
                int j = ln->child[c];
                lod->state[k + 1][j] = ST_ACTIVE;
                sq_lodx_interp(lod, Lf, j, k, ln->up_tet[j], ln->up_bary + 4 * j);
                memcpy(lod->dprev[k + 1] + 3 * j, Lf->d + 3 * j, 3 * sizeof(double));
                memcpy(lod->vprev[k + 1] + 3 * j, Lf->v + 3 * j, 3 * sizeof(double));
            }
            *projected += extra;
            out->splits++;
            changed = 1;
        }
    }

    /* merges: split nodes of level k whose children are all active and calm */
    if (!forced) {
        for (int p = 0; p < Lk->n; p++) {
            if (lod->state[k][p] != ST_SPLIT || lod->fresh[k][p])
                continue;
            int ok = 1;
            int c0 = ln->child_start[p], c1 = ln->child_start[p + 1];
            for (int c = c0; c < c1 && ok; c++)
                if (lod->state[k + 1][ln->child[c]] != ST_ACTIVE)
                    ok = 0;
            if (!ok)
                continue;
            if (c1 == c0) {
                /* no child: judge the node on its own (interpolated) field */
                if (!(delta_at(lod, k, p) < def->merge))
                    continue;
            } else {
                for (int c = c0; c < c1 && ok; c++)
                    if (!(delta_at(lod, k + 1, ln->child[c]) < def->merge))
                        ok = 0;
                if (!ok)
                    continue;
            }
            merge_node(lod, k, p);
            *projected -= (long)(c1 - c0) * cost_f - cost_k;
            out->merges++;
            changed = 1;
        }
    }
    for (int i = 0; i < Lk->n; i++)
        lod->fresh[k][i] = 0;
    if (changed) {
        out->changed[k] = out->changed[k + 1] = 1;
    }
}

/* hard cap: merge the finest mergeable regions until the projected cost fits */
static void enforce_cap(sq_lod *lod, long *projected, adapt_out *out)
{
    long cap = lod->def.max_node_updates;
    if (cap <= 0 || *projected <= cap)
        return;
    for (int k = lod->top - 1; k >= 0 && *projected > cap; k--) {
        const sq_lod_link *ln = &lod->h.link[k];
        long cost_k = 1L << sub_log2(lod, k), cost_f = 1L << sub_log2(lod, k + 1);
        for (int p = 0; p < lod->lv[k].n && *projected > cap; p++) {
            if (lod->state[k][p] != ST_SPLIT)
                continue;
            int ok = 1;
            for (int c = ln->child_start[p]; c < ln->child_start[p + 1] && ok; c++)
                if (lod->state[k + 1][ln->child[c]] != ST_ACTIVE)
                    ok = 0;
            if (!ok)
                continue;
            merge_node(lod, k, p);
            *projected -= (long)(ln->child_start[p + 1] - ln->child_start[p]) * cost_f - cost_k;
            out->merges++;
            out->changed[k] = out->changed[k + 1] = 1;
        }
    }
}

/* ---------------------------------------------------------------- tool holds */

/* the active node standing for finest node j: itself or its active ancestor; -1 if none */
static int active_of_finest(const sq_lod *lod, int j, int *level)
{
    int k = lod->L - 1, a = j;
    while (lod->state[k][a] != ST_ACTIVE) {
        if (k == 0)
            return -1;
        a = lod->h.link[k - 1].parent[a];
        k--;
    }
    *level = k;
    return a;
}

/* map hold h (at time t_now within the frame) onto its active node; adds to that node's entry */
static void map_hold(sq_lod *lod, const sq_hold *hd, int h, double t_now)
{
    int F = lod->L - 1, k;
    int a = active_of_finest(lod, hd->node, &k);
    if (a < 0) {
        lod->hold_entry_of[h] = -1;
        return;
    }
    sq_level *Lk = &lod->lv[k];
    const double *dj = lod->lv[F].d + 3 * hd->node;
    int e = lod->slot[k][a];
    if (e < 0) {
        if (lod->nhe == lod->cap_he) {
            lod->cap_he = lod->cap_he ? 2 * lod->cap_he : 64;
            lod->he = sq_realloc(lod->he, sizeof(hold_entry) * (size_t)lod->cap_he);
        }
        e = lod->nhe++;
        hold_entry *E = &lod->he[e];
        memset(E, 0, sizeof(*E));
        E->level = k;
        E->node = a;
        E->t_from = t_now;
        memcpy(E->from, Lk->d + 3 * a, sizeof(E->from));
        lod->slot[k][a] = e;
        if (lod->mask[k][a]) {
            lod->mask[k][a] = 0;
            lod->nmask[k]--;
        }
    }
    hold_entry *E = &lod->he[e];
    /* the hold node itself takes its target; an ancestor the same translation */
    for (int c = 0; c < 3; c++)
        E->gsum[c] += (k == F && a == hd->node) ? hd->target[c]
                                                : Lk->d[3 * a + c] + (hd->target[c] - dj[c]);
    E->count++;
    E->pending = 1;
    lod->hold_entry_of[h] = e;
}

/* prescribe the nodes whose targets changed: d = mean target, v = (d - from) / time left */
static void start_holds(sq_lod *lod, double T)
{
    for (int e = 0; e < lod->nhe; e++) {
        hold_entry *E = &lod->he[e];
        if (!E->pending || E->count == 0)
            continue;
        E->pending = 0;
        sq_level *Lk = &lod->lv[E->level];
        double span = T - E->t_from;
        unsigned char fx = Lk->fixed[E->node];
        for (int c = 0; c < 3; c++) {
            if (fx & (1u << c))
                continue;
            double goal = E->gsum[c] / E->count;
            Lk->d[3 * E->node + c] = goal;
            Lk->v[3 * E->node + c] = span > 0 ? (goal - E->from[c]) / span : 0.0;
            lod->dprev[E->level][3 * E->node + c] = Lk->d[3 * E->node + c];
            lod->vprev[E->level][3 * E->node + c] = Lk->v[3 * E->node + c];
        }
    }
}

static void clear_holds(sq_lod *lod)
{
    for (int e = 0; e < lod->nhe; e++)
        if (lod->slot[lod->he[e].level][lod->he[e].node] == e)
            lod->slot[lod->he[e].level][lod->he[e].node] = -1;
    lod->nhe = 0;
}

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
    unsigned char st = lod->state[lev][j];
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
    const int *tn = lod->lv[m].mesh->tets + 4 * t;
    for (int q = 0; q < 4; q++)
        if (b[q] != 0)
            expand(lod, m, tn[q], w * b[q], depth + 1, buf, n, cap);
}

/* the active sources of every ring ghost of every level */
static void build_sources(sq_lod *lod)
{
    src_item *buf = NULL;
    int cap = 0;
    for (int k = 0; k < lod->L; k++) {
        int total = 0;
        lod->fs_start[k][0] = 0;
        for (int r = 0; r < lod->nring[k]; r++) {
            int n = 0;
            expand(lod, k, lod->ring[k][r], 1.0, 0, &buf, &n, &cap);
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
            if (total + u > lod->fs_cap[k]) {
                lod->fs_cap[k] = SQ_MAX(2 * lod->fs_cap[k], total + u + 1024);
                lod->fs_level[k] = sq_realloc(lod->fs_level[k], sizeof(int) * (size_t)lod->fs_cap[k]);
                lod->fs_node[k] = sq_realloc(lod->fs_node[k], sizeof(int) * (size_t)lod->fs_cap[k]);
                lod->fs_w[k] = sq_realloc(lod->fs_w[k], sizeof(double) * (size_t)lod->fs_cap[k]);
            }
            for (int i = 0; i < u; i++) {
                lod->fs_level[k][total + i] = buf[i].level;
                lod->fs_node[k][total + i] = buf[i].node;
                lod->fs_w[k][total + i] = buf[i].w / sum;
            }
            unsigned char bits = 0;
            for (int i = 0; i < u; i++)
                bits |= (unsigned char)(1u << buf[i].level);
            lod->fs_levels[k][r] = bits;
            total += u;
            lod->fs_start[k][r + 1] = total;
        }
    }
    free(buf);
}

/* the ring ghosts of level k at tick t: sources of a level between two of its steps are
 * taken linearly in time over that step */
static void eval_ring(sq_lod *lod, int k, long t)
{
    sq_level *Lk = &lod->lv[k];
    double fr[SQ_MAX_LEVELS];
    const double *dcur[SQ_MAX_LEVELS], *vcur[SQ_MAX_LEVELS];
    for (int m = 0; m < lod->L; m++) {
        double f = (double)(t - lod->step_t0[m]) / (double)lod->step_len[m];
        fr[m] = f < 0 ? 0 : (f > 1 ? 1 : f);
        dcur[m] = lod->lv[m].d;
        vcur[m] = lod->lv[m].v;
    }
    for (int r = 0; r < lod->nring[k]; r++) {
        int j = lod->ring[k][r];
        int a = lod->fs_start[k][r], b = lod->fs_start[k][r + 1];
        if (a == b)
            continue;
        double d[3] = {0, 0, 0}, v[3] = {0, 0, 0};
        const int *fl = lod->fs_level[k], *fn = lod->fs_node[k];
        const double *fw = lod->fs_w[k];
        /* the sources are sorted by level: one run per level, its time fraction hoisted */
        for (int q = a; q < b;) {
            int m = fl[q];
            double f = fr[m];
            const double *D1 = dcur[m], *V1 = vcur[m];
            if (f == 1) {
                /* a source level at the end of its step (the common case): its values */
                for (; q < b && fl[q] == m; q++) {
                    const double w = fw[q];
                    const double *d1 = D1 + 3 * fn[q], *v1 = V1 + 3 * fn[q];
                    for (int c = 0; c < 3; c++) {
                        d[c] += w * d1[c];
                        v[c] += w * v1[c];
                    }
                }
                continue;
            }
            const double *D0 = lod->dprev[m], *V0 = lod->vprev[m];
            for (; q < b && fl[q] == m; q++) {
                const double w = fw[q];
                const double *d1 = D1 + 3 * fn[q], *v1 = V1 + 3 * fn[q];
                const double *d0 = D0 + 3 * fn[q], *v0 = V0 + 3 * fn[q];
                for (int c = 0; c < 3; c++) {
                    d[c] += w * (d0[c] + f * (d1[c] - d0[c]));
                    v[c] += w * (v0[c] + f * (v1[c] - v0[c]));
                }
            }
        }
        unsigned char fx = Lk->fixed[j];
        for (int c = 0; c < 3; c++) {
            int free_axis = !(fx & (1u << c));
            Lk->d[3 * j + c] = free_axis ? d[c] : 0.0;
            Lk->v[3 * j + c] = free_axis ? v[c] : 0.0;
        }
    }
}

/* force on ring ghost r (node j) of level k from the tets touching active nodes, -(K w)_j -
 * (D v)_j, with the active nodes of level k taken at fraction fr of its current step */
static void ring_force(const sq_lod *lod, const sq_material *mat, int k, int r, double fr, double g[3])
{
    const sq_level *L = &lod->lv[k];
    const unsigned char *act = lod->active[k];
    double b = mat->use_viscosity ? 0 : mat->rayleigh_stiffness;
    const double *Bd = mat->use_viscosity ? lod->rd[k] : NULL;
    g[0] = g[1] = g[2] = 0;
    if (fr >= 1 && !Bd) {
        /* the level at the end of its step (the common case): its current values, same sums */
        const double *restrict d = L->d, *restrict v = L->v;
        double g0 = 0, g1 = 0, g2 = 0;
        for (int e = lod->rk_off[k][r]; e < lod->rk_off[k][r + 1]; e++) {
            const size_t j = 3 * (size_t)lod->rk_col[k][e];
            const double *K = lod->rk[k] + 9 * (size_t)e;
            const double w0 = d[j] + b * v[j], w1 = d[j + 1] + b * v[j + 1], w2 = d[j + 2] + b * v[j + 2];
            g0 -= K[0] * w0 + K[1] * w1 + K[2] * w2;
            g1 -= K[3] * w0 + K[4] * w1 + K[5] * w2;
            g2 -= K[6] * w0 + K[7] * w1 + K[8] * w2;
        }
        g[0] = g0;
        g[1] = g1;
        g[2] = g2;
        return;
    }
    for (int e = lod->rk_off[k][r]; e < lod->rk_off[k][r + 1]; e++) {
        int l = lod->rk_col[k][e];
        double dl[3], vl[3];
        for (int c = 0; c < 3; c++) {
            dl[c] = L->d[3 * l + c];
            vl[c] = L->v[3 * l + c];
        }
        if (fr < 1 && act[l])
            for (int c = 0; c < 3; c++) {
                double d0 = lod->dprev[k][3 * l + c], v0 = lod->vprev[k][3 * l + c];
                dl[c] = d0 + fr * (dl[c] - d0);
                vl[c] = v0 + fr * (vl[c] - v0);
            }
        const double *K = lod->rk[k] + 9 * (size_t)e;
        double w[3] = {dl[0] + b * vl[0], dl[1] + b * vl[1], dl[2] + b * vl[2]};
        for (int rr = 0; rr < 3; rr++)
            g[rr] -= K[3 * rr] * w[0] + K[3 * rr + 1] * w[1] + K[3 * rr + 2] * w[2];
        if (Bd) {
            const double *D = Bd + 9 * (size_t)e;
            for (int rr = 0; rr < 3; rr++)
                g[rr] -= D[3 * rr] * vl[0] + D[3 * rr + 1] * vl[1] + D[3 * rr + 2] * vl[2];
        }
    }
}

/* the ring reactions of level k at tick t go back to their active sources, into the force of
 * the levels that step at this tick. A level between two of its steps (a coarser one) still
 * hands its reactions to the finer levels stepping now, from its values at this tick: those
 * reactions depend on the finer nodes themselves, so they must follow them step by step.
 * Reactions for a coarser level are sampled at its own steps. */
static void couple_out(sq_lod *lod, const sq_material *mat, int k, long t)
{
    const sq_level *Lk = &lod->lv[k];
    double fr = (double)(t - lod->step_t0[k]) / (double)lod->step_len[k];
    fr = fr < 0 ? 0 : (fr > 1 ? 1 : fr);
    unsigned due_bits = 0;
    for (int m = 0; m < lod->L; m++)
        due_bits |= lod->due[m] ? 1u << m : 0u;
    for (int r = 0; r < lod->nring[k]; r++) {
        int j = lod->ring[k][r];
        int a = lod->fs_start[k][r], b = lod->fs_start[k][r + 1];
        if (!(lod->fs_levels[k][r] & due_bits))
            continue;
        double g[3];
        ring_force(lod, mat, k, r, fr, g);
        unsigned char fx = Lk->fixed[j];
        for (int c = 0; c < 3; c++)
            if (fx & (1u << c))
                g[c] = 0; /* a constrained axis of a ghost does not follow its sources */
        /* one run of sources per level (sorted by level); levels not stepping now skipped */
        const int *fl = lod->fs_level[k], *fn = lod->fs_node[k];
        const double *fw = lod->fs_w[k];
        for (int q = a; q < b;) {
            int m = fl[q];
            if (!(due_bits & (1u << m))) {
                while (q < b && fl[q] == m)
                    q++;
                continue;
            }
            double *F = lod->lv[m].f;
            for (; q < b && fl[q] == m; q++) {
                double w = fw[q], *dst = F + 3 * fn[q];
                dst[0] += w * g[0];
                dst[1] += w * g[1];
                dst[2] += w * g[2];
            }
        }
    }
}

/* ---------------------------------------------------------------- the frame */

void sq_lod_frame(sq_lod *lod, const sq_material *mat, const double gravity[3], double frame_dt,
                  const sq_hold *holds, int nholds, int ntools, double (*force)[3],
                  sq_frame_profile *prof, double budget_s)
{
    double t_start = sq_now(), c_start = thread_cpu();
    int L = lod->L, F = L - 1;
    double t_pull = 0, t_int = 0, t_push = 0, t_adapt = 0;
    long updates = 0;
    adapt_out ao;
    memset(&ao, 0, sizeof(ao));
    for (int t = 0; force && t < ntools; t++)
        force[t][0] = force[t][1] = force[t][2] = 0;

    sq_lodx_static_loads(lod, gravity); /* no-op unless gravity or material changed */
    /* guaranteed frame rate: no splitting after a frame over budget (merging still allowed) */
    double prev_time = lod->last_time;
    int over_budget = budget_s > 0 && prev_time > lod->def.budget * budget_s;
    /* ... and the next frame predicted from its node updates times the CPU cost of one update
     * measured on the last frame that had any: above budget x period, the node-update cap of
     * this frame is what fits, so the finest mergeable regions merge first and splits that
     * would exceed it are refused (the user's cap, if lower, still holds) */
    long cap_user = lod->def.max_node_updates, cap_guard = 0;
    double coarse_ms = 0;
    if (budget_s > 0 && lod->cost_update > 0) {
        double fit = (lod->def.budget * budget_s - lod->cost_fixed) / lod->cost_update;
        cap_guard = fit > 1e15 ? (long)1e15 : SQ_MAX((long)fit, 1L);
        if (cap_user <= 0 || cap_guard < cap_user)
            lod->def.max_node_updates = cap_guard;
        else
            cap_guard = 0;
        /* the cheapest layout: every region at level 0 */
        coarse_ms = 1e3 * lod->cost_update * (double)((long)lod->lv[0].nfree << sub_log2(lod, 0));
    }
    /* coupling blocks and the substeps they need (which may push the cost over the cap:
     * merge first then), then the substep clock of the finest step */
    update_ring_blocks(lod, mat);
    long projected = sq_lod_projected_updates(lod);
    if (lod->def.max_node_updates > 0 && projected > lod->def.max_node_updates) {
        enforce_cap(lod, &projected, &ao);
        for (int k = 0; k < L; k++)
            if (ao.changed[k]) {
                rebuild_level(lod, k);
                ao.changed[k] = 0;
            }
        build_sources(lod);
        update_ring_blocks(lod, mat);
        projected = sq_lod_projected_updates(lod);
    }
    int nmax = 0;
    for (int k = 0; k < L; k++)
        nmax = SQ_MAX(nmax, sub_log2(lod, k));
    long nticks = 1L << nmax;
    long stride[SQ_MAX_LEVELS];
    for (int k = 0; k < L; k++)
        stride[k] = 1L << (nmax - sub_log2(lod, k));

    /* tool holds onto active nodes */
    clear_holds(lod);
    if (nholds > lod->cap_holds) {
        lod->cap_holds = nholds;
        lod->hold_entry_of = sq_realloc(lod->hold_entry_of, sizeof(int) * (size_t)nholds);
    }
    for (int k = 0; k < L; k++) {
        lod->nmask[k] = lod->nactive[k];
        memcpy(lod->mask[k], lod->active[k], (size_t)lod->lv[k].n);
    }
    for (int h = 0; h < nholds; h++) {
        lod->hold_entry_of[h] = -1;
        if (holds[h].node < 0 || holds[h].node >= lod->lv[F].n || holds[h].tool < 0 ||
            holds[h].tool >= ntools)
            continue; /* the body validates holds; ignore any that are out of range */
        map_hold(lod, &holds[h], h, 0.0);
    }
    start_holds(lod, frame_dt);
    for (int k = 0; k < L; k++)
        sq_lodx_mask_list(lod, k);
    if (lod->lists_dirty)
        sq_lodx_refresh_lists(lod);

    for (int k = 0; k < L; k++) {
        lod->step_t0[k] = -stride[k]; /* the previous frame's last step ended at tick 0 */
        lod->step_len[k] = stride[k];
    }
    for (long t = 0; t < nticks; t++) {
        if ((t & 15) == 15 && sq_cancelled())
            break; /* the server is stopping: the frame is abandoned */
        /* (1) ghost values of every due level at this tick (ring ghosts from the active
         * nodes, finest simulated level included) */
        double t0 = sq_now();
        for (int k = 0; k < L; k++) {
            lod->due[k] = t % stride[k] == 0;
            if (lod->due[k] && lod->nactive[k] > 0)
                eval_ring(lod, k, t);
        }
        double t1 = sq_now();
        t_pull += t1 - t0;
        /* (2) forces of every due level from the state at this tick, the coupling reactions
         * between levels, then integration of the free active nodes */
        for (int k = 0; k < L; k++)
            if (lod->due[k] && lod->nactive[k] > 0) {
                /* the all-nodes force pass is vectorised, faster per node than the masked
                 * one, but computes ghost rows nobody reads and needs the frontier correction
                 * pass: use it once 60% of the level is active (with the frontier rows folded,
                 * 60% beat 40% by 5-8% CPU on the organ and 3.6% instructions on cube-poke) */
                if (5 * lod->nactive[k] >= 3 * lod->lv[k].n) {
                    sq_level_forces(&lod->lv[k], mat, gravity, NULL);
                    front_correct(lod, mat, k);
                } else if (mat->use_viscosity) {
                    sq_level_forces(&lod->lv[k], mat, gravity, lod->active[k]);
                    front_correct(lod, mat, k);
                } else {
                    /* interior rows by the level's pass, frontier rows with their
                     * correction folded in */
                    sq_lodx_rows(lod, mat, gravity, k);
                    front_rows(lod, mat, gravity, k);
                }
            }
        for (int k = 0; k < L; k++)
            if (lod->nactive[k] > 0 && lod->nring[k] > 0) {
                if (!lod->due[k])
                    eval_ring(lod, k, t);
                couple_out(lod, mat, k, t);
            }
        for (int k = 0; k < L; k++) {
            if (!lod->due[k])
                continue;
            sq_level *Lk = &lod->lv[k];
            lod->step_t0[k] = t;
            if (lod->nactive[k] == 0)
                continue;
            /* feedback of the held nodes */
            for (int e = 0; e < lod->nhe; e++) {
                hold_entry *E = &lod->he[e];
                if (E->level != k || E->count == 0)
                    continue;
                int i = E->node;
                for (int c = 0; c < 3; c++)
                    E->fsum[c] += Lk->f[3 * i + c] - Lk->mass[i] * gravity[c];
                E->nf++;
            }
            /* finer levels read this level between its steps */
            sq_lodx_save_prev(lod, k);
            if (lod->nmask[k] > 0) {
                double dtk = lod->extra[k] ? frame_dt / (double)(1L << sub_log2(lod, k)) : Lk->dt;
                if (lod->nmask[k] == Lk->n)
                    sq_level_integrate(Lk, dtk, NULL);
                else
                    sq_lodx_integrate(lod, k, dtk);
            }
            updates += lod->nmask[k];
        }
        double t2 = sq_now();
        t_int += t2 - t1;
        /* (4) split/merge at the end of the frame, when every level is at the same time
         * (see docs/lod.md: a region changes level at most once per frame, and the coupling
         * is rebuilt once), on fresh ring values */
        long next = t + 1;
        int any = 0;
        if (next == nticks) {
            for (int k = 0; k < L; k++)
                eval_ring(lod, k, next);
            for (int k = 0; k + 1 < L && k < lod->top; k++)
                adapt_pair(lod, k, !over_budget, &projected, &ao);
            enforce_cap(lod, &projected, &ao);
        }
        for (int k = 0; k < L; k++)
            if (ao.changed[k]) {
                rebuild_level(lod, k);
                ao.changed[k] = 0;
                any = 1;
            }
        if (any) {
            /* (holds are mapped again onto the new active nodes at the next frame) */
            build_sources(lod);
            update_ring_blocks(lod, mat);
            sq_lodx_refresh_lists(lod);
        }
        t_adapt += sq_now() - t2;
    }
    /* (3) every ghost from the active nodes at the end of the frame: the rendered finest
     * level, probes and the next frame start from consistent values */
    double t3 = sq_now();
    cascade_needed(lod);
    t_push += sq_now() - t3;

    /* feedback: mean internal force on the held nodes, shared among the holds mapped there */
    for (int h = 0; force && h < nholds; h++) {
        int e = lod->hold_entry_of[h];
        if (e < 0 || lod->he[e].count == 0 || lod->he[e].nf == 0)
            continue;
        const hold_entry *E = &lod->he[e];
        for (int c = 0; c < 3; c++)
            force[holds[h].tool][c] += E->fsum[c] / E->nf / E->count;
    }
    clear_holds(lod);
    for (int k = 0; k < L; k++)
        if (lod->nmask[k] != lod->nactive[k]) {
            memcpy(lod->mask[k], lod->active[k], (size_t)lod->lv[k].n);
            lod->nmask[k] = lod->nactive[k];
        }

    double t_end = sq_now(), c_end = thread_cpu();
    lod->last_time = c_end - c_start;
    if (updates > 0) {
        /* a decaying maximum: a frame with a rebuild costs more per update than a quiet one,
         * and the next frame may have one */
        /* split the frame's CPU time into the part that scales with node updates (ghost
         * values, forces, integration) and the rest (split/merge and rebuilds, end-of-frame
         * ghosts), in the proportions of the stage wall times */
        double cpu = c_end - c_start, wall = t_end - t_start;
        double share = wall > 0 ? fmin(1.0, (t_pull + t_int) / wall) : 1.0;
        double c = cpu * share / (double)updates;
        lod->cost_update = fmax(c, 0.9 * lod->cost_update);
        lod->cost_fixed = fmax(cpu * (1 - share), 0.9 * lod->cost_fixed);
    }
    long cap_used = lod->def.max_node_updates;
    lod->def.max_node_updates = cap_user;
    if (prof) {
        prof->t_pull = t_pull;
        prof->t_integrate = t_int;
        prof->t_push = t_push;
        prof->t_adapt = t_adapt;
        prof->t_total = t_end - t_start;
        prof->node_updates = updates;
        for (int k = 0; k < SQ_MAX_LEVELS; k++) {
            prof->active[k] = k < L ? lod->nactive[k] : 0;
            prof->substeps[k] = k < L ? 1 << sub_log2(lod, k) : 0;
        }
        prof->splits = ao.splits;
        prof->merges = ao.merges;
        prof->splits_refused = over_budget || ao.refused;
        if (coarse_ms > lod->def.budget * budget_s * 1e3)
            snprintf(prof->event, sizeof(prof->event),
                     "warning: cannot run in real time even fully coarse: level 0 needs %.2f ms "
                     "(%d nodes x %d steps), budget %.2f ms; splitting refused", coarse_ms,
                     lod->lv[0].nfree, 1 << sub_log2(lod, 0), lod->def.budget * budget_s * 1e3);
        else if (over_budget)
            snprintf(prof->event, sizeof(prof->event),
                     "warning: frame compute %.2f ms over %.0f%% of the %.2f ms budget: splitting "
                     "refused, merging allowed", prev_time * 1e3, lod->def.budget * 100,
                     budget_s * 1e3);
        else if (ao.refused && cap_guard > 0 && cap_used == cap_guard)
            snprintf(prof->event, sizeof(prof->event),
                     "warning: next frame predicted over %.0f%% of %.2f ms (%ld node updates fit): "
                     "finest regions merged, splitting refused", lod->def.budget * 100, budget_s * 1e3,
                     cap_guard);
        else if (ao.refused)
            snprintf(prof->event, sizeof(prof->event),
                     "warning: node-update cap %ld per frame reached: splitting refused", cap_user);
    }
}

int sq_lod_adapt(sq_lod *lod, int allow_split, int *splits, int *merges)
{
    adapt_out ao;
    memset(&ao, 0, sizeof(ao));
    long projected = sq_lod_projected_updates(lod);
    for (int k = lod->L - 2; k >= 0; k--)
        pull_level(lod, k);
    for (int k = 0; k + 1 < lod->L; k++)
        adapt_pair(lod, k, allow_split, &projected, &ao);
    enforce_cap(lod, &projected, &ao);
    for (int k = 0; k < lod->L; k++)
        if (ao.changed[k])
            rebuild_level(lod, k);
    sq_lod_sync(lod);
    if (splits)
        *splits = ao.splits;
    if (merges)
        *merges = ao.merges;
    return ao.refused;
}

/* ---------------------------------------------------------------- views */

void sq_lod_node_levels(sq_lod *lod, unsigned char *out)
{
    /* the states change only at a rebuild: the same buffer needs no new walk before then */
    if (lod->nl_gen == lod->gen && lod->nl_out == out)
        return;
    lod->nl_gen = lod->gen;
    lod->nl_out = out;
    /* level by level, coarse to fine: a node's level is its own if active, else its parent's
     * (the walk up from each finest node to its active ancestor, without repeating it) */
    int F = lod->L - 1;
    if (F == 0) {
        memset(out, 0, (size_t)lod->lv[0].n);
        return;
    }
    unsigned char *prev = lod->nlv[0], *cur = lod->nlv[1];
    memset(prev, 0, (size_t)lod->lv[0].n);
    for (int k = 1; k <= F; k++) {
        unsigned char *dst = k == F ? out : cur;
        const unsigned char *st = lod->state[k];
        const int *par = lod->h.link[k - 1].parent;
        for (int j = 0; j < lod->lv[k].n; j++)
            dst[j] = st[j] == ST_ACTIVE ? (unsigned char)k : prev[par[j]];
        unsigned char *t = prev;
        prev = cur;
        cur = t;
    }
}

double sq_lod_energy(const sq_lod *lod, double *kinetic, double *elastic)
{
    double ek = 0, ee = 0;
    for (int k = 0; k < lod->L; k++) {
        const sq_level *Lk = &lod->lv[k];
        /* sum over the tets touching active nodes of their weighted elastic energy: full
         * rows on active nodes less the frontier correction, ring rows from the ring blocks */
        for (int i = 0; i < Lk->n; i++) {
            if (lod->state[k][i] != ST_ACTIVE)
                continue;
            const double *v = Lk->v + 3 * i, *d = Lk->d + 3 * i;
            ek += 0.5 * Lk->mass[i] * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
            double f[3] = {0, 0, 0};
            for (int q = Lk->row_start[i]; q < Lk->row_start[i + 1]; q++) {
                const double *K = Lk->K + 9 * q, *dl = Lk->d + 3 * Lk->col[q];
                for (int r = 0; r < 3; r++)
                    f[r] += K[3 * r] * dl[0] + K[3 * r + 1] * dl[1] + K[3 * r + 2] * dl[2];
            }
            ee += 0.5 * (d[0] * f[0] + d[1] * f[1] + d[2] * f[2]);
        }
        if (!lod->have_mat || lod->rk_dirty[k])
            continue;
        for (int r = 0; r < lod->nfront[k]; r++) {
            int i = lod->front[k][r];
            const double *d = Lk->d + 3 * i;
            double f[3] = {0, 0, 0};
            for (int e = lod->fk_off[k][r]; e < lod->fk_off[k][r + 1]; e++) {
                const double *K = lod->fk[k] + 9 * (size_t)e, *dl = Lk->d + 3 * lod->fk_col[k][e];
                for (int rr = 0; rr < 3; rr++)
                    f[rr] += K[3 * rr] * dl[0] + K[3 * rr + 1] * dl[1] + K[3 * rr + 2] * dl[2];
            }
            ee -= 0.5 * (d[0] * f[0] + d[1] * f[1] + d[2] * f[2]);
        }
        for (int r = 0; r < lod->nring[k]; r++) {
            int j = lod->ring[k][r];
            const double *d = Lk->d + 3 * j;
            double f[3] = {0, 0, 0};
            for (int e = lod->rk_off[k][r]; e < lod->rk_off[k][r + 1]; e++) {
                const double *K = lod->rk[k] + 9 * (size_t)e, *dl = Lk->d + 3 * lod->rk_col[k][e];
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

int sq_lod_check(const sq_lod *lod, sq_err *err)
{
    for (int k = 0; k < lod->L; k++) {
        int na = 0;
        for (int i = 0; i < lod->lv[k].n; i++) {
            unsigned char s = lod->state[k][i];
            if (s > ST_SPLIT)
                return sq_err_set(err, "lod: level %d node %d has state %d", k, i, s);
            if (k == 0 && s == ST_COARSE)
                return sq_err_set(err, "lod: level-0 node %d is a coarse ghost", i);
            if (k >= lod->top && s == ST_SPLIT)
                return sq_err_set(err, "lod: node %d of level %d (top %d) is split", i, k, lod->top);
            if (k > 0) {
                int p = lod->h.link[k - 1].parent[i];
                int parent_split = lod->state[k - 1][p] == ST_SPLIT;
                if (parent_split != (s != ST_COARSE))
                    return sq_err_set(err, "lod: level %d node %d has state %d but its parent %d has "
                                      "state %d", k, i, s, p, lod->state[k - 1][p]);
            }
            if (lod->active[k][i] != (s == ST_ACTIVE))
                return sq_err_set(err, "lod: level %d node %d: active mask out of date", k, i);
            na += s == ST_ACTIVE;
        }
        if (na != lod->nactive[k])
            return sq_err_set(err, "lod: level %d counts %d active nodes, has %d", k, lod->nactive[k], na);
    }
    return 0;
}
