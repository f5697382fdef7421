/* activeset.c - per-level index lists of the adaptive state and the kernels that run over them,
 * so the cost of a frame follows the active set, not the size of the body (docs/lod.md,
 * "Cost that follows the active set").
 *
 * Lists, rebuilt only when a level's states change (a split or merge):
 *   active_list      active nodes, increasing;
 *   inner_list       inner active nodes (no ghost neighbour), whose rows are the level's own rows;
 *   integrated_list  active nodes integrated this frame (the held ones left out);
 *   read_list        nodes whose values at the start of their level's step are read between two of
 *           its steps (sources of ring ghosts, active columns of ring rows): only those are
 *           saved before a step, not the whole level;
 *   needed           coarse ghosts something reads every frame: the rendered (finest) surface, ring
 *           ghosts, the corners split ghosts are pulled from and split or merged nodes start
 *           from, and the parent corners of all of those. The end-of-frame push updates these
 *           only; the rest are pushed on demand (sq_lod_flush, sq_lodx_value), with the same
 *           interpolation, when something outside the frame reads the whole field.
 * The row and integration kernels repeat the arithmetic of level/level.c's masked passes
 * (same operations in the same order), so trajectories are unchanged.
 */
#include "lod/activeset.h"
#include "lod/lod_vec.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static int cmp_int(const void *a, const void *b)
{
    int x = *(const int *)a, y = *(const int *)b;
    return (x > y) - (x < y);
}

void sq_lodx_sort_ints(int *a, int n)
{
    qsort(a, (size_t)n, sizeof(int), cmp_int);
}

/* the distinct nodes list[0..cnt) of a level of n nodes, each with mark[i] != 0, in increasing
 * order: a scan of the marks when the list is a sizeable part of the level (qsort cost
 * ~cnt log cnt compares, the scan n byte tests), else a sort */
static void sort_marked(int *list, int cnt, const unsigned char *mark, int n)
{
    if ((long)cnt * 32 > n) {
        int w = 0;
        for (int i = 0; i < n; i++)
            if (mark[i])
                list[w++] = i;
    } else {
        qsort(list, (size_t)cnt, sizeof(int), cmp_int);
    }
}

/* after sq_lodx_rebuild_level filled active_list (active nodes, increasing) and the inner mask */
void sq_lodx_level_lists(sq_lod *lod, int k)
{
    sq_lod_level *lk = &lod->lev[k];
    int ni = 0;
    const unsigned char *inner = lk->lay.inner;
    for (int r = 0; r < lk->lay.nactive; r++) {
        int i = lk->lists.active_list[r];
        if (inner[i])
            lk->lists.inner_list[ni++] = i;
    }
    lk->lists.ninner_list = ni;
    lod->push.lists_dirty = 1;
    lod->view.gen++;
    sq_lodx_mask_list(lod, k);
}

void sq_lodx_mask_list(sq_lod *lod, int k)
{
    sq_lod_level *lk = &lod->lev[k];
    int nm = 0;
    const unsigned char *mask = lk->lay.integrated;
    for (int r = 0; r < lk->lay.nactive; r++) {
        int i = lk->lists.active_list[r];
        if (mask[i])
            lk->lists.integrated_list[nm++] = i;
    }
    lk->lists.nintegrated_list = nm;
}

/* add node i of level k to a list once (marks in lod->lev[k].lists.mark) */
static inline void add_once(sq_lod *lod, int k, int i, int *list, int *n)
{
    if (!lod->lev[k].lists.mark[i]) {
        lod->lev[k].lists.mark[i] = 1;
        list[(*n)++] = i;
    }
}

/* coarse ghost j of level k into the needed set (with its parent corners, recursively) */
static void need_node(sq_lod *lod, int k, int j)
{
    sq_lod_level *lk;
    while (k >= 1 && (lk = &lod->lev[k])->lay.state[j] == ST_COARSE && !lk->lists.in_needed[j]) {
        lk->lists.in_needed[j] = 1;
        lk->lists.needed[lk->lists.nneeded++] = j;
        const int *tn = lod->lv[k - 1].model.mesh->tets + 4 * lod->h.link[k - 1].up_tet[j];
        for (int q = 0; q < 3; q++)
            need_node(lod, k - 1, tn[q]);
        j = tn[3];
        k--;
    }
}

/* corners of tet t of level m into the needed set */
static void need_tet(sq_lod *lod, int m, int t)
{
    const int *tn = lod->lv[m].model.mesh->tets + 4 * t;
    for (int q = 0; q < 4; q++)
        need_node(lod, m, tn[q]);
}

static void needed_full(sq_lod *lod);
static void needed_counted(sq_lod *lod);

void sq_lodx_refresh_lists(sq_lod *lod)
{
    int L = lod->L;
    /* read_list: sources of every ring ghost (any level), active columns of each level's ring rows */
    for (int m = 0; m < L; m++)
        lod->lev[m].lists.nread_list = 0;
    for (int k = 0; k < L; k++) {
        int ns = lod->lev[k].lay.src_start[lod->lev[k].lay.nring];
        for (int q = 0; q < ns; q++) {
            int m = lod->lev[k].lay.src_level[q];
            add_once(lod, m, lod->lev[k].lay.src_node[q], lod->lev[m].lists.read_list, &lod->lev[m].lists.nread_list);
        }
        if (!lod->lev[k].cpl.blocks_dirty && lod->lev[k].cpl.ring_col) {
            int ne = lod->lev[k].cpl.ring_off[lod->lev[k].lay.nring];
            for (int e = 0; e < ne; e++) {
                int l = lod->lev[k].cpl.ring_col[e];
                if (lod->lev[k].lay.active[l])
                    add_once(lod, k, l, lod->lev[k].lists.read_list, &lod->lev[k].lists.nread_list);
            }
        }
    }
    for (int m = 0; m < L; m++) {
        sort_marked(lod->lev[m].lists.read_list, lod->lev[m].lists.nread_list, lod->lev[m].lists.mark, lod->lv[m].model.n);
        for (int r = 0; r < lod->lev[m].lists.nread_list; r++)
            lod->lev[m].lists.mark[lod->lev[m].lists.read_list[r]] = 0;
    }

    if (lod->test.full_rebuild)
        needed_full(lod);
    else
        needed_counted(lod);
    lod->push.lists_dirty = 0;
}

/* the needed set from scratch, by a walk from everything that is read (the reference the
 * counted maintenance below is checked against) */
static void needed_full(sq_lod *lod)
{
    int L = lod->L, F = L - 1;
    /* clear the previous set, then mark what is read */
    for (int k = 0; k < L; k++) {
        for (int r = 0; r < lod->lev[k].lists.nneeded; r++)
            lod->lev[k].lists.in_needed[lod->lev[k].lists.needed[r]] = 0;
        lod->lev[k].lists.nneeded = 0;
    }
    const sq_mesh *fm = lod->lv[F].model.mesh;
    for (int s = 0; s < fm->nsurf; s++)
        need_node(lod, F, fm->surf_nodes[s]); /* the rendered surface, tool holds */
    for (int k = 0; k < L; k++)
        for (int r = 0; r < lod->lev[k].lay.nring; r++)
            need_node(lod, k, lod->lev[k].lay.ring[r]); /* a ring ghost without sources keeps its push */
    for (int k = 0; k + 1 < L; k++) {
        const sq_lod_link *ln = &lod->h.link[k];
        /* split ghosts are pulled from their child tets; active nodes may split (their child
         * tets are read then, and their children start from their parent tets) */
        for (int r = 0; r < lod->lev[k].lay.nsplit_ghost; r++) {
            int i = lod->lev[k].lay.split_ghost[r];
            need_tet(lod, k + 1, ln->down_tet[i]);
            for (int c = ln->child_start[i]; c < ln->child_start[i + 1]; c++)
                need_tet(lod, k, ln->up_tet[ln->child[c]]);
            if (ln->child_start[i + 1] == ln->child_start[i]) {
                /* a childless split node is judged on its own field: its neighbours */
                const sq_level *Lk = &lod->lv[k];
                for (int q = Lk->model.row_start[i]; q < Lk->model.row_start[i + 1]; q++)
                    need_node(lod, k, Lk->model.col[q]);
            }
        }
        if (k < lod->top)
            for (int r = 0; r < lod->lev[k].lay.nactive; r++) {
                int i = lod->lev[k].lists.active_list[r];
                need_tet(lod, k + 1, ln->down_tet[i]);
                for (int c = ln->child_start[i]; c < ln->child_start[i + 1]; c++)
                    need_tet(lod, k, ln->up_tet[ln->child[c]]);
            }
    }
    for (int k = 0; k < L; k++)
        sort_marked(lod->lev[k].lists.needed, lod->lev[k].lists.nneeded, lod->lev[k].lists.in_needed, lod->lv[k].model.n);
    /* the counts no longer describe this set */
    lod->push.needed_valid = 0;
    for (int k = 0; k < L; k++) {
        for (int c = 0; c < lod->lev[k].lists.nschg; c++)
            lod->lev[k].lists.schg_mark[lod->lev[k].lists.schg[c]] = 0;
        lod->lev[k].lists.nschg = 0;
    }
}

/* ---- the needed set maintained by counts: node j of level k is needed iff it is a coarse
 * ghost (k >= 1) with ncnt > 0, ncnt counting its seeds (the finest surface, ring ghosts, the
 * corners a split or active node reads) and the needed coarse ghosts of level k + 1 whose parent
 * tet has j as a corner. Links go from level k + 1 to level k only, so the set is the one the
 * walk from the seeds finds (needed_full); after a split/merge pass only the seeds of the nodes
 * whose state changed and of the old and new rings are counted in or out, and a change of a
 * node's status passes to its parent corners. */

static void count_node(sq_lod *lod, int k, int j, int d);

/* node j of level k: needed status from its state and count, passed on to its parent corners */
static void fix_node(sq_lod *lod, int k, int j)
{
    sq_lod_level *lk = &lod->lev[k];
    unsigned char want = lk->lay.state[j] == ST_COARSE && lk->lists.ncnt[j] > 0;
    if (want == lk->lists.in_needed[j])
        return;
    lk->lists.in_needed[j] = want;
    lk->lists.nneeded += want ? 1 : -1;
    const int *tn = lod->lv[k - 1].model.mesh->tets + 4 * lod->h.link[k - 1].up_tet[j];
    for (int q = 0; q < 4; q++)
        count_node(lod, k - 1, tn[q], want ? 1 : -1);
}

static void count_node(sq_lod *lod, int k, int j, int d)
{
    if (k < 1)
        return; /* level 0 has no coarse ghosts */
    lod->lev[k].lists.ncnt[j] += d;
    fix_node(lod, k, j);
}

static void count_tet(sq_lod *lod, int m, int t, int d)
{
    const int *tn = lod->lv[m].model.mesh->tets + 4 * t;
    for (int q = 0; q < 4; q++)
        count_node(lod, m, tn[q], d);
}

/* the seeds of node i of level k in state st (as needed_full finds them) counted d times */
static void count_seeds(sq_lod *lod, int k, int i, unsigned char st, int d)
{
    if (!((st == ST_SPLIT && k + 1 < lod->L) || (st == ST_ACTIVE && k + 1 < lod->L && k < lod->top)))
        return;
    const sq_lod_link *ln = &lod->h.link[k];
    count_tet(lod, k + 1, ln->down_tet[i], d);
    for (int c = ln->child_start[i]; c < ln->child_start[i + 1]; c++)
        count_tet(lod, k, ln->up_tet[ln->child[c]], d);
    if (st == ST_SPLIT && ln->child_start[i + 1] == ln->child_start[i]) {
        const sq_level *Lk = &lod->lv[k];
        for (int q = Lk->model.row_start[i]; q < Lk->model.row_start[i + 1]; q++)
            count_node(lod, k, Lk->model.col[q], d);
    }
}

static void needed_counted(sq_lod *lod)
{
    int L = lod->L, F = L - 1;
    long nchg = 0, ntot = 0;
    for (int k = 0; k < L; k++) {
        nchg += lod->lev[k].lists.nschg;
        ntot += lod->lv[k].model.n;
    }
    if (!lod->push.needed_valid || lod->push.needed_top != lod->top || nchg * 8 > ntot) {
        /* from scratch: every seed counted once */
        lod->push.needed_counts[0]++;
        for (int k = 0; k < L; k++) {
            sq_lod_level *lk = &lod->lev[k];
            int n = lod->lv[k].model.n;
            memset(lk->lists.ncnt, 0, sizeof(int) * (size_t)n);
            memset(lk->lists.in_needed, 0, (size_t)n);
            lk->lists.nneeded = 0;
        }
        const sq_mesh *fm = lod->lv[F].model.mesh;
        for (int s = 0; s < fm->nsurf; s++)
            count_node(lod, F, fm->surf_nodes[s], 1);
        for (int k = 0; k < L; k++) {
            sq_lod_level *lk = &lod->lev[k];
            for (int r = 0; r < lk->lay.nsplit_ghost; r++)
                count_seeds(lod, k, lk->lay.split_ghost[r], ST_SPLIT, 1);
            for (int r = 0; r < lk->lay.nactive; r++)
                count_seeds(lod, k, lk->lists.active_list[r], ST_ACTIVE, 1);
        }
    } else {
        /* the new seeds in first, then the old ones out (no count drops to zero on the way
         * when a seed stays) */
        lod->push.needed_counts[1]++;
        for (int k = 0; k < L; k++) {
            sq_lod_level *lk = &lod->lev[k];
            for (int c = 0; c < lk->lists.nschg; c++)
                count_seeds(lod, k, lk->lists.schg[c], lk->lay.state[lk->lists.schg[c]], 1);
            for (int r = 0; r < lk->lay.nring; r++)
                count_node(lod, k, lk->lay.ring[r], 1);
        }
        for (int k = 0; k < L; k++) {
            sq_lod_level *lk = &lod->lev[k];
            for (int c = 0; c < lk->lists.nschg; c++)
                count_seeds(lod, k, lk->lists.schg[c], lk->lists.seed_state[lk->lists.schg[c]], -1);
            for (int r = 0; r < lk->lists.nseed_ring; r++)
                count_node(lod, k, lk->lists.seed_ring[r], -1);
            /* a change of state alone (coarse ghost or not) changes the status */
            for (int c = 0; c < lk->lists.nschg; c++)
                if (k >= 1)
                    fix_node(lod, k, lk->lists.schg[c]);
        }
        /* the ring seeds were counted above; fall through to the common end */
        goto lists;
    }
    for (int k = 0; k < L; k++)
        for (int r = 0; r < lod->lev[k].lay.nring; r++)
            count_node(lod, k, lod->lev[k].lay.ring[r], 1); /* a ring ghost without sources keeps its push */
lists:
    for (int k = 0; k < L; k++) {
        sq_lod_level *lk = &lod->lev[k];
        int n = lod->lv[k].model.n;
        if (lod->push.needed_valid && lod->push.needed_top == lod->top && nchg * 8 <= ntot)
            for (int c = 0; c < lk->lists.nschg; c++)
                lk->lists.seed_state[lk->lists.schg[c]] = lk->lay.state[lk->lists.schg[c]];
        else
            memcpy(lk->lists.seed_state, lk->lay.state, (size_t)n);
        for (int c = 0; c < lk->lists.nschg; c++)
            lk->lists.schg_mark[lk->lists.schg[c]] = 0;
        lk->lists.nschg = 0;
        memcpy(lk->lists.seed_ring, lk->lay.ring, sizeof(int) * (size_t)lk->lay.nring);
        lk->lists.nseed_ring = lk->lay.nring;
        /* the list in increasing order, from the marks */
        int w = 0;
        for (int i = 0; i < n && w < lk->lists.nneeded; i++)
            if (lk->lists.in_needed[i])
                lk->lists.needed[w++] = i;
    }
    lod->push.needed_valid = 1;
    lod->push.needed_top = lod->top;
}


void sq_lodx_push_needed(sq_lod *lod)
{
    int stale = 0;
    unsigned no = ++lod->push.cascade_no;
    for (int k = 1; k < lod->L; k++) {
        const sq_lod_link *ln = &lod->h.link[k - 1];
        sq_level *dst = &lod->lv[k];
        const sq_level *src = &lod->lv[k - 1];
        for (int r = 0; r < lod->lev[k].lists.nneeded; r++) {
            int j = lod->lev[k].lists.needed[r];
            interp_node(dst, j, src, ln->up_tet[j], ln->up_bary + 4 * j);
            lod->lev[k].lists.push_stamp[j] = no;
        }
        stale |= lod->lev[k].lists.nneeded < lod->lev[k].lay.ncoarse_ghost;
    }
    lod->push.stale = stale;
}

void sq_lodx_save_cascade(sq_lod *lod)
{
    for (int k = 0; k < lod->L; k++) {
        int nr = lod->lev[k].lay.nring;
        if (nr > lod->lev[k].lists.cascade_value_cap) {
            lod->lev[k].lists.cascade_value_cap = SQ_MAX(nr, 2 * lod->lev[k].lists.cascade_value_cap);
            lod->lev[k].lists.cascade_value = sq_realloc(lod->lev[k].lists.cascade_value,
                                                   sizeof(double) * 6 * (size_t)lod->lev[k].lists.cascade_value_cap);
        }
        const double *d = lod->lv[k].state.d, *v = lod->lv[k].state.v;
        for (int r = 0; r < nr; r++) {
            size_t j = 3 * (size_t)lod->lev[k].lay.ring[r];
            double *c = lod->lev[k].lists.cascade_value + 6 * (size_t)r;
            c[0] = d[j];
            c[1] = d[j + 1];
            c[2] = d[j + 2];
            c[3] = v[j];
            c[4] = v[j + 1];
            c[5] = v[j + 2];
        }
    }
}

/* the full push of the coarse ghosts outside the needed set, as the cascade would have done it:
 * a ring ghost among the corners is read at its cascade value (the push ran before the ring
 * values), the other corners are current (nothing changed them since the cascade) */
void sq_lod_flush(sq_lod *lod)
{
    if (!lod || !lod->push.stale)
        return;
    for (int k = 1; k < lod->L; k++) {
        const sq_lod_link *ln = &lod->h.link[k - 1];
        sq_level *dst = &lod->lv[k];
        const sq_level *src = &lod->lv[k - 1];
        const int *ri = lod->lev[k - 1].lay.ring_index;
        for (int r = 0; r < lod->lev[k].lay.ncoarse_ghost; r++) {
            int j = lod->lev[k].lay.coarse_ghost[r];
            if (lod->lev[k].lists.push_stamp[j] == lod->push.cascade_no)
                continue;
            const int *tn = src->model.mesh->tets + 4 * ln->up_tet[j];
            const double *b = ln->up_bary + 4 * j;
            double d[3] = {0, 0, 0}, v[3] = {0, 0, 0};
            for (int m = 0; m < 4; m++) {
                const double *sd = src->state.d + 3 * tn[m], *sv = src->state.v + 3 * tn[m];
                if (ri[tn[m]] >= 0) {
                    sd = lod->lev[k - 1].lists.cascade_value + 6 * (size_t)ri[tn[m]];
                    sv = sd + 3;
                }
                for (int a = 0; a < 3; a++) {
                    d[a] += b[m] * sd[a];
                    v[a] += b[m] * sv[a];
                }
            }
            unsigned char fx = dst->model.fixed[j];
            for (int a = 0; a < 3; a++) {
                int free_axis = !(fx & (1u << a));
                dst->state.d[3 * j + a] = free_axis ? d[a] : 0.0;
                dst->state.v[3 * j + a] = free_axis ? v[a] : 0.0;
            }
        }
    }
    lod->push.stale = 0;
}

void sq_lod_flushed_d(const sq_lod *lod, int k, int j, double d[3])
{
    const sq_level *Lk = &lod->lv[k];
    /* what sq_lod_flush leaves as it is: everything when nothing is stale, a node that is not a
     * coarse ghost, one the last cascade pushed */
    if (!lod->push.stale || k == 0 || lod->lev[k].lay.state[j] != ST_COARSE || lod->lev[k].lists.push_stamp[j] == lod->push.cascade_no) {
        memcpy(d, Lk->state.d + 3 * (size_t)j, 3 * sizeof(double));
        return;
    }
    /* what it writes: the parent tet's corners as the flush of level k - 1 left them, a ring
     * ghost among them at its cascade value; the same sums in the same order */
    const sq_lod_link *ln = &lod->h.link[k - 1];
    const int *tn = lod->lv[k - 1].model.mesh->tets + 4 * ln->up_tet[j];
    const double *b = ln->up_bary + 4 * j;
    const int *ri = lod->lev[k - 1].lay.ring_index;
    double s[3] = {0, 0, 0};
    for (int m = 0; m < 4; m++) {
        double c[3];
        const double *sd = c;
        if (ri[tn[m]] >= 0)
            sd = lod->lev[k - 1].lists.cascade_value + 6 * (size_t)ri[tn[m]];
        else
            sq_lod_flushed_d(lod, k - 1, tn[m], c);
        for (int a = 0; a < 3; a++)
            s[a] += b[m] * sd[a];
    }
    unsigned char fx = Lk->model.fixed[j];
    for (int a = 0; a < 3; a++)
        d[a] = !(fx & (1u << a)) ? s[a] : 0.0;
}

void sq_lodx_value(const sq_lod *lod, int k, int j, double d[3], double v[3])
{
    const sq_level *Lk = &lod->lv[k];
    /* a coarse ghost the last cascade did not push is always interpolated afresh (whether or
     * not a flush brought its stored value up to date), so a flush never changes the trajectory */
    if (k == 0 || lod->lev[k].lay.state[j] != ST_COARSE || lod->push.full_no == lod->push.cascade_no ||
        lod->lev[k].lists.push_stamp[j] == lod->push.cascade_no) {
        memcpy(d, Lk->state.d + 3 * (size_t)j, 3 * sizeof(double));
        memcpy(v, Lk->state.v + 3 * (size_t)j, 3 * sizeof(double));
        return;
    }
    const sq_lod_link *ln = &lod->h.link[k - 1];
    const int *tn = lod->lv[k - 1].model.mesh->tets + 4 * ln->up_tet[j];
    const double *b = ln->up_bary + 4 * j;
    double sd[4][3], sv[4][3];
    for (int m = 0; m < 4; m++)
        sq_lodx_value(lod, k - 1, tn[m], sd[m], sv[m]);
    double dd[3] = {0, 0, 0}, vv[3] = {0, 0, 0};
    for (int m = 0; m < 4; m++)
        for (int a = 0; a < 3; a++) {
            dd[a] += b[m] * sd[m][a];
            vv[a] += b[m] * sv[m][a];
        }
    unsigned char fx = Lk->model.fixed[j];
    for (int a = 0; a < 3; a++) {
        int free_axis = !(fx & (1u << a));
        d[a] = free_axis ? dd[a] : 0.0;
        v[a] = free_axis ? vv[a] : 0.0;
    }
}

void sq_lodx_interp(sq_lod *lod, sq_level *dst, int i, int src_level, int t, const double *b)
{
    const sq_level *src = &lod->lv[src_level];
    const int *tn = src->model.mesh->tets + 4 * t;
    double sd[4][3], sv[4][3];
    for (int m = 0; m < 4; m++)
        sq_lodx_value(lod, src_level, tn[m], sd[m], sv[m]);
    double d[3] = {0, 0, 0}, v[3] = {0, 0, 0};
    for (int m = 0; m < 4; m++)
        for (int a = 0; a < 3; a++) {
            d[a] += b[m] * sd[m][a];
            v[a] += b[m] * sv[m][a];
        }
    unsigned char fx = dst->model.fixed[i];
    for (int a = 0; a < 3; a++) {
        int free_axis = !(fx & (1u << a));
        dst->state.d[3 * i + a] = free_axis ? d[a] : 0.0;
        dst->state.v[3 * i + a] = free_axis ? v[a] : 0.0;
    }
}

void sq_lodx_free(sq_lod *lod, int k)
{
    sq_lod_level *lk = &lod->lev[k];
    free(lk->cpl.krow_at);
    free(lk->tk.w_tick);
    for (int c = 0; c < lk->cpl.krow_nchunk; c++)
        free(lk->cpl.krow_chunk[c]);
    free(lk->cpl.krow_chunk);
    free(lk->lists.active_list);
    free(lk->lists.inner_list);
    free(lk->lists.integrated_list);
    free(lk->lists.read_list);
    free(lk->lists.needed);
    free(lk->lists.in_needed);
    free(lk->lists.mark);
    free(lk->lists.cascade_value);
    free(lk->lists.push_stamp);
    free(lk->d_static);
    free(lod->guard.guard_hold[k]);
    lod->guard.guard_hold[k] = NULL;
    free(lk->lay.limited);
}
