/* state.c - stage: the adaptive state itself (sections 4.2-4.3 of the paper).
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
 * Here: creation (with the criterion's weights) and destruction, the definition (set_def) and
 * reset, one split or merge of a node (the states and start values criterion.c and guard.c
 * decide), the bookkeeping of a level's states (its ghost, ring and frontier lists), ghost values brought up to date from
 * the active nodes (pull, push, cascade, sync), and the consistency check of the tree.
 */
#include "lod/lod.h"
#include "lod/activeset.h"
#include "lod/bound.h"
#include "lod/corotational.h"
#include "lod/surface.h"
#include "lod/coupling.h"
#include "lod/lod_vec.h"
#include "lod/ring.h"
#include "lod/state.h"
#include "lod/tick.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>


/* ---------------------------------------------------------------- state bookkeeping */

/* recompute the active mask, the ghost lists and the integration mask of level k */
void sq_lodx_rebuild_level(sq_lod *lod, int k)
{
    sq_lod_level *lk = &lod->lev[k];
    int n = lod->lv[k].model.n;
    int na = 0, nf = 0, nc = 0;
    lk->tk.hot_valid = 0; /* the ring changes: its hot list is made again (ring.c) */
    /* the first rebuild since the blocks were built keeps the lists they were built for, and
     * every rebuild records the nodes whose active flag changes: the next block build redoes
     * only the rows next to those (coupling.c) */
    if (!lk->cpl.blocks_dirty && lk->cpl.blocks_valid && !lk->cpl.prev_saved) {
        memcpy(lk->cpl.prev_ring, lk->lay.ring, sizeof(int) * (size_t)lk->lay.nring);
        lk->cpl.nprev_ring = lk->lay.nring;
        memcpy(lk->cpl.prev_frontier, lk->lay.frontier, sizeof(int) * (size_t)lk->lay.nfrontier);
        lk->cpl.nprev_frontier = lk->lay.nfrontier;
        lk->cpl.prev_saved = 1;
    }
    for (int i = 0; i < n; i++) {
        unsigned char s = lk->lay.state[i];
        unsigned char a = (s == ST_ACTIVE);
        if (a != lk->lay.active[i] && !lk->cpl.chg_mark[i]) {
            lk->cpl.chg_mark[i] = 1;
            lk->cpl.chg[lk->cpl.nchg++] = i;
        }
        lk->lay.active[i] = a;
        if (s != lk->lists.seed_state[i] && !lk->lists.schg_mark[i]) {
            lk->lists.schg_mark[i] = 1;
            lk->lists.schg[lk->lists.nschg++] = i;
        }
        lk->lay.integrated[i] = (s == ST_ACTIVE);
        if (s == ST_ACTIVE)
            lk->lists.active_list[na++] = i;
        else if (s == ST_SPLIT)
            lk->lay.split_ghost[nf++] = i;
        else
            lk->lay.coarse_ghost[nc++] = i;
    }
    lk->lay.nactive = na;
    lk->lay.nsplit_ghost = nf;
    lk->lay.ncoarse_ghost = nc;
    /* the ring (ghosts with an active neighbour) and the frontier (active nodes with a ghost
     * neighbour), found from the active nodes' rows, so the cost follows the active set; the
     * ring is kept in increasing node order */
    const sq_level *Lk = &lod->lv[k];
    const unsigned char *act = lk->lay.active;
    for (int r = 0; r < lk->lay.nring; r++)
        lk->lay.ring_index[lk->lay.ring[r]] = -1;
    int nr = 0, nfr = 0;
    for (int a = 0; a < na; a++) {
        int i = lk->lists.active_list[a], front = 0;
        for (int q = Lk->model.row_start[i]; q < Lk->model.row_start[i + 1]; q++) {
            int j = Lk->model.col[q];
            if (act[j])
                continue;
            front = 1;
            if (lk->lay.ring_index[j] < 0) {
                lk->lay.ring_index[j] = 0;
                lk->lay.ring[nr++] = j;
            }
        }
        if (front)
            lk->lay.frontier[nfr++] = i;
    }
    if ((long)nr * 32 > n) { /* a sizeable ring: a scan of the marks beats a sort */
        nr = 0;
        for (int i = 0; i < n; i++)
            if (lk->lay.ring_index[i] >= 0)
                lk->lay.ring[nr++] = i;
    } else {
        sq_lodx_sort_ints(lk->lay.ring, nr);
    }
    for (int r = 0; r < nr; r++)
        lk->lay.ring_index[lk->lay.ring[r]] = r;
    lk->lay.nring = nr;
    lk->lay.nfrontier = nfr;
    memcpy(lk->lay.inner, lk->lay.active, (size_t)SQ_MAX(n, 0));
    for (int r = 0; r < nfr; r++)
        lk->lay.inner[lk->lay.frontier[r]] = 0;
    lk->cpl.blocks_dirty = 1;
    /* held nodes are prescribed, not integrated */
    int nm = na;
    for (int e = 0; e < lod->holds.nhe; e++)
        if (lod->holds.he[e].level == k && lod->holds.he[e].count > 0 && lk->lay.integrated[lod->holds.he[e].node]) {
            lk->lay.integrated[lod->holds.he[e].node] = 0;
            nm--;
        }
    lk->lay.nintegrated = nm;
    sq_lodx_level_lists(lod, k);
}

/* all levels below s split, level s active, finer levels coarse ghosts */
static void set_uniform_level(sq_lod *lod, int s)
{
    for (int k = 0; k < lod->L; k++) {
        unsigned char st = k < s ? ST_SPLIT : (k == s ? ST_ACTIVE : ST_COARSE);
        memset(lod->lev[k].lay.state, st, (size_t)lod->lv[k].model.n);
    }
    for (int k = 0; k < lod->L; k++)
        sq_lodx_rebuild_level(lod, k);
}

/* ---------------------------------------------------------------- ghost interpolation */

/* split ghosts of level k from their child tets in level k+1 */
void sq_lodx_pull_level(sq_lod *lod, int k)
{
    if (k + 1 >= lod->L)
        return;
    const sq_lod_link *ln = &lod->h.link[k];
    sq_level *dst = &lod->lv[k];
    for (int g = 0; g < lod->lev[k].lay.nsplit_ghost; g++) {
        int i = lod->lev[k].lay.split_ghost[g];
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
    for (int g = 0; g < lod->lev[k].lay.ncoarse_ghost; g++) {
        int j = lod->lev[k].lay.coarse_ghost[g];
        interp_node(dst, j, src, ln->up_tet[j], ln->up_bary + 4 * j);
    }
}

/* every ghost value from the active nodes: split ghosts pulled fine to coarse, coarse ghosts
 * pushed coarse to fine (the rendered finest level included), then the ring ghosts as their
 * exact combinations of active nodes */
static void cascade(sq_lod *lod)
{
    for (int k = lod->L - 2; k >= 0; k--)
        sq_lodx_pull_level(lod, k);
    for (int k = 1; k < lod->L; k++)
        push_level(lod, k);
    lod->push.stale = 0;
    lod->push.full_no = ++lod->push.cascade_no;
    for (int k = 0; k < lod->L; k++)
        sq_lodx_eval_ring(lod, k, lod->lev[k].tk.step_start + lod->lev[k].tk.step_len);
}

/* the end-of-frame cascade: as cascade(), but coarse ghosts are pushed only where something
 * reads them (the needed set, activeset.c); the others are pushed on demand */
void sq_lodx_cascade_needed(sq_lod *lod)
{
    for (int k = lod->L - 2; k >= 0; k--)
        sq_lodx_pull_level(lod, k);
    if (lod->push.lists_dirty)
        sq_lodx_refresh_lists(lod);
    sq_lodx_push_needed(lod);
    sq_lodx_save_cascade(lod);
    for (int k = 0; k < lod->L; k++)
        sq_lodx_eval_ring(lod, k, lod->lev[k].tk.step_start + lod->lev[k].tk.step_len);
}

void sq_lod_sync(sq_lod *lod)
{
    for (int k = 0; k < lod->L; k++) {
        lod->lev[k].tk.step_start = -1;
        lod->lev[k].tk.step_len = 1;
        size_t n3 = 3 * (size_t)lod->lv[k].model.n;
        memcpy(lod->lev[k].tk.d_start, lod->lv[k].state.d, n3 * sizeof(double));
        memcpy(lod->lev[k].tk.v_start, lod->lv[k].state.v, n3 * sizeof(double));
    }
    sq_lodx_build_sources(lod);
    sq_lodx_update_ring_blocks(lod, NULL);
    cascade(lod);
}

/* ---------------------------------------------------------------- creation */

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
    if (def->adapt_every < 0 || def->adapt_every > SQ_LOD_ADAPT_EVERY_MAX)
        return sq_err_set(err, "lod.adapt_every = %d: must be a number of frames in 1..%d (1: a split/merge "
                          "pass every frame)", def->adapt_every, SQ_LOD_ADAPT_EVERY_MAX);
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

/* ---------------------------------------------------------------- a node split or merged
 *
 * the node states a split/merge decision changes (criterion.c's pass, guard.c's merges), the
 * values the changed nodes start from; the lists follow in sq_lodx_rebuild_level */

/* split node p of level k: its children become active and start from their d and v
 * interpolated from the parent tet (values now); p is fresh (not merged back in this pass) */
void sq_lodx_split_node(sq_lod *lod, int k, int i)
{
    sq_lod_level *lk = &lod->lev[k];
    const sq_lod_link *ln = &lod->h.link[k];
    sq_level *Lf = &lod->lv[k + 1];
    /* children start from their interpolated d and v (parent tet, values now) */
    lk->lay.state[i] = ST_SPLIT;
    lk->lay.fresh[i] = 1;
    for (int c = ln->child_start[i]; c < ln->child_start[i + 1]; c++) {
        int j = ln->child[c];
        lod->lev[k + 1].lay.state[j] = ST_ACTIVE;
        sq_lodx_interp(lod, Lf, j, k, ln->up_tet[j], ln->up_bary + 4 * j);
        sq_lodx_tick_start_node(lod, k + 1, j);
    }
}

void sq_lodx_fresh_clear(sq_lod *lod, int k)
{
    for (int i = 0; i < lod->lv[k].model.n; i++)
        lod->lev[k].lay.fresh[i] = 0;
}

/* merge node p of level k: it starts from its value interpolated from its child tet, its
 * children become coarse ghosts at their parent-tet values (the criterion's and the guard's merges) */
void sq_lodx_merge_node(sq_lod *lod, int k, int p)
{
    sq_lod_level *lk = &lod->lev[k];
    const sq_lod_link *ln = &lod->h.link[k];
    lk->lay.state[p] = ST_ACTIVE;
    /* the merged node starts from its interpolated value (pulled from its child tet) */
    sq_lodx_interp(lod, &lod->lv[k], p, k + 1, ln->down_tet[p], ln->down_bary + 4 * p);
    for (int c = ln->child_start[p]; c < ln->child_start[p + 1]; c++)
        lod->lev[k + 1].lay.state[ln->child[c]] = ST_COARSE;
    sq_lodx_tick_start_node(lod, k, p);
    /* children become coarse ghosts and take their parent-tet value at once */
    for (int c = ln->child_start[p]; c < ln->child_start[p + 1]; c++) {
        int j = ln->child[c];
        sq_lodx_interp(lod, &lod->lv[k + 1], j, k, ln->up_tet[j], ln->up_bary + 4 * j);
    }
}

/* ---------------------------------------------------------------- criterion weights
 *
 * the criterion's Laplacian weights, a const table of each level (tab.crit_weight), made here at
 * creation; criterion.c reads them */

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

/* weights w_ij (CSR of the mesh adjacency) with Lap(d)_i = -(1/vol_i) sum_j w_ij d_j.
 * Interior rows are the lumped FEM Laplacian sum_T V a_i . a_j. On boundary rows that
 * operator also holds the boundary flux (a linear field gets a Laplacian of order
 * |grad d| / h there, which would split every surface node of a body that merely sags),
 * so the flux of the tet's own gradient through the node's boundary faces is removed:
 * for the face opposite q of tet T, A n = -3 V a_q, and each of its three nodes i gets
 * (A/3) (grad d . n) = -V sum_m (a_m . a_q) d_m. A linear field then has zero Laplacian at
 * every node, and the criterion measures only curvature, as the paper intends. */
double *sq_lodx_criterion_weights(const sq_mesh *m)
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


/* like (may be NULL): a state over the same meshes whose hierarchy and mesh-derived per-level
 * tables this one borrows instead of building them (sq_lod_create_like) */
static sq_lod *create(sq_level *levels, int nlevels, const sq_lod_def *def, const sq_lod *like, sq_err *err)
{
    if (nlevels < 1 || nlevels > SQ_MAX_LEVELS) {
        sq_err_set(err, "lod: %d levels given, need 1 to %d", nlevels, SQ_MAX_LEVELS);
        return NULL;
    }
    if (check_def(def, nlevels, err))
        return NULL;
    const sq_mesh *meshes[SQ_MAX_LEVELS];
    for (int k = 0; k < nlevels; k++) {
        meshes[k] = levels[k].model.mesh;
        if (!meshes[k] || levels[k].model.n != meshes[k]->nnodes) {
            sq_err_set(err, "lod: level %d has no mesh or a node count that does not match it", k);
            return NULL;
        }
    }
    sq_lod *lod = sq_calloc(1, sizeof(*lod));
    lod->lv = levels;
    lod->L = nlevels;
    lod->def = *def;
    lod->top = top_of(def, nlevels);
    lod->view.nl_gen = -1;
    lod->surf.gen = -1;
    int share = like && like->L == nlevels;
    for (int k = 0; share && k < nlevels; k++)
        share = like->h.mesh[k] == meshes[k];
    if (share) {
        lod->h = like->h; /* read only after sq_hierarchy_build */
        lod->shared = 1;
    } else if (sq_hierarchy_build(&lod->h, meshes, nlevels, err)) {
        free(lod);
        return NULL;
    }
    size_t nmax_nodes = 1;
    for (int k = 0; k < nlevels; k++) {
        size_t n = (size_t)levels[k].model.n;
        lod->lev[k].lay.state = sq_calloc(n, 1);
        lod->lev[k].lay.active = sq_calloc(n, 1);
        lod->lev[k].lay.integrated = sq_calloc(n, 1);
        lod->lev[k].lay.fresh = sq_calloc(n, 1);
        lod->lev[k].lists.active_list = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->lev[k].lists.inner_list = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->lev[k].lists.integrated_list = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->lev[k].lists.read_list = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->lev[k].lists.needed = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->lev[k].lists.in_needed = sq_calloc(SQ_MAX(n, 1), 1);
        lod->lev[k].lists.mark = sq_calloc(SQ_MAX(n, 1), 1);
        lod->lev[k].lists.push_stamp = sq_calloc(SQ_MAX(n, 1), sizeof(unsigned));
        nmax_nodes = SQ_MAX(nmax_nodes, n);
        lod->lev[k].lay.split_ghost = sq_malloc(sizeof(int) * n);
        lod->lev[k].lay.coarse_ghost = sq_malloc(sizeof(int) * n);
        lod->lev[k].lay.hold_of = sq_malloc(sizeof(int) * n);
        if (!share)
            lod->lev[k].tab.crit_weight = sq_lodx_criterion_weights(levels[k].model.mesh);
        lod->lev[k].lay.ring = sq_malloc(sizeof(int) * n);
        /* one spare double: the ring kernels load 4 lanes per node */
        lod->lev[k].tk.d_start = sq_calloc(3 * n + 1, sizeof(double));
        lod->lev[k].tk.v_start = sq_calloc(3 * n + 1, sizeof(double));
        lod->lev[k].lay.src_start = sq_calloc(n + 1, sizeof(int));
        lod->lev[k].lay.src_levels = sq_calloc(n + 1, 1);
        lod->lev[k].cpl.ring_off = sq_calloc(n + 1, sizeof(int));
        lod->lev[k].lay.ring_index = sq_malloc(sizeof(int) * n);
        for (size_t i = 0; i < n; i++)
            lod->lev[k].lay.ring_index[i] = -1;
        lod->lev[k].lay.frontier = sq_malloc(sizeof(int) * n);
        lod->lev[k].cpl.prev_ring = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->lev[k].cpl.prev_frontier = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->lev[k].cpl.chg = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->lev[k].cpl.chg_mark = sq_calloc(SQ_MAX(n, 1), 1);
        lod->lev[k].cpl.blk_active = sq_calloc(SQ_MAX(n, 1), 1);
        lod->lev[k].lists.ncnt = sq_calloc(SQ_MAX(n, 1), sizeof(int));
        lod->lev[k].lists.seed_state = sq_calloc(SQ_MAX(n, 1), 1);
        lod->lev[k].lists.schg = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->lev[k].lists.schg_mark = sq_calloc(SQ_MAX(n, 1), 1);
        lod->lev[k].lists.seed_ring = sq_malloc(sizeof(int) * SQ_MAX(n, 1));
        lod->lev[k].cpl.ring_off2 = sq_calloc(n + 1, sizeof(int));
        lod->lev[k].cpl.front_off2 = sq_calloc(n + 1, sizeof(int));
        lod->lev[k].lay.inner = sq_calloc(n, 1);
        lod->lev[k].cpl.front_off = sq_calloc(n + 1, sizeof(int));
        const sq_mesh *mm = levels[k].model.mesh;
        /* the element-block cache (written by the frames): always the state's own */
        lod->lev[k].cpl.blocks_slot = sq_malloc(sizeof(int) * (size_t)SQ_MAX(mm->ntets, 1));
        for (int t = 0; t < mm->ntets; t++)
            lod->lev[k].cpl.blocks_slot[t] = -1;
        if (share) {
            /* the tables below depend on the mesh alone and are read only once made */
            const sq_lod_level *lk = &like->lev[k];
            lod->lev[k].tab.crit_weight = lk->tab.crit_weight;
            lod->lev[k].tab.node_tet_start = lk->tab.node_tet_start;
            lod->lev[k].tab.node_tet = lk->tab.node_tet;
            lod->lev[k].tab.inc_corner = lk->tab.inc_corner;
            lod->lev[k].tab.inc_block = lk->tab.inc_block;
            lod->lev[k].tab.tet_geom = lk->tab.tet_geom;
        } else {
            node_tets(mm, &lod->lev[k].tab.node_tet_start, &lod->lev[k].tab.node_tet);
            int ninc = lod->lev[k].tab.node_tet_start[n];
            lod->lev[k].tab.inc_corner = sq_malloc((size_t)SQ_MAX(ninc, 1));
            lod->lev[k].tab.inc_block = sq_malloc(sizeof(int) * 4 * (size_t)SQ_MAX(ninc, 1));
            for (int j = 0; j < (int)n; j++)
                for (int c = lod->lev[k].tab.node_tet_start[j]; c < lod->lev[k].tab.node_tet_start[j + 1]; c++) {
                    const int *tv = mm->tets + 4 * lod->lev[k].tab.node_tet[c];
                    int p = 0;
                    while (tv[p] != j)
                        p++;
                    lod->lev[k].tab.inc_corner[c] = (unsigned char)p;
                    for (int q = 0; q < 4; q++)
                        lod->lev[k].tab.inc_block[4 * (size_t)c + q] = adj_find(mm, j, tv[q]) - mm->adj_start[j];
                }
            lod->lev[k].tab.tet_geom = sq_malloc(sizeof(double) * 13 * (size_t)mm->ntets);
            for (int t = 0; t < mm->ntets; t++) {
                double a[4][3];
                double *g = lod->lev[k].tab.tet_geom + 13 * (size_t)t;
                g[0] = sq_tet_gradients(mm, t, a);
                memcpy(g + 1, a, sizeof(a));
            }
        }
        for (size_t i = 0; i < n; i++)
            lod->lev[k].lay.hold_of[i] = -1;
    }
    lod->view.nlv[0] = sq_malloc(SQ_MAX(nmax_nodes, (size_t)1));
    lod->view.nlv[1] = sq_malloc(SQ_MAX(nmax_nodes, (size_t)1));
    set_uniform_level(lod, start_level(lod));
    sq_lod_sync(lod);
    return lod;
}

sq_lod *sq_lod_create(sq_level *levels, int nlevels, const sq_lod_def *def, sq_err *err)
{
    return create(levels, nlevels, def, NULL, err);
}

sq_lod *sq_lod_create_like(sq_level *levels, int nlevels, const sq_lod_def *def, const sq_lod *like, sq_err *err)
{
    return create(levels, nlevels, def, like, err);
}

void sq_lod_destroy(sq_lod *lod)
{
    if (!lod)
        return;
    sq_lodx_sharp_free(lod);
    for (int k = 0; k < lod->L; k++) {
        free(lod->lev[k].lay.state);
        free(lod->lev[k].lay.active);
        free(lod->lev[k].lay.integrated);
        free(lod->lev[k].lay.fresh);
        sq_lodx_free(lod, k);
        sq_lodx_corot_free(lod, k);
        free(lod->lev[k].lay.split_ghost);
        free(lod->lev[k].lay.coarse_ghost);
        free(lod->lev[k].lay.hold_of);
        free(lod->lev[k].lay.ring);
        free(lod->lev[k].tk.d_start);
        free(lod->lev[k].tk.v_start);
        free(lod->lev[k].lay.src_start);
        free(lod->lev[k].lay.src_levels);
        free(lod->lev[k].cpl.ring_off);
        free(lod->lev[k].lay.ring_index);
        free(lod->lev[k].rate.own_rowsum);
        free(lod->lev[k].rate.coupled_rowsum);
        free(lod->lev[k].cpl.ring_col);
        free(lod->lev[k].cpl.front_col);
        free(lod->lev[k].lay.frontier);
        free(lod->lev[k].cpl.prev_ring);
        free(lod->lev[k].cpl.prev_frontier);
        free(lod->lev[k].cpl.chg);
        free(lod->lev[k].cpl.chg_mark);
        free(lod->lev[k].cpl.blk_active);
        free(lod->lev[k].lists.ncnt);
        free(lod->lev[k].lists.seed_state);
        free(lod->lev[k].lists.schg);
        free(lod->lev[k].lists.schg_mark);
        free(lod->lev[k].lists.seed_ring);
        free(lod->lev[k].cpl.ring_off2);
        free(lod->lev[k].cpl.ring_col2);
        free(lod->lev[k].cpl.ring_K2);
        free(lod->lev[k].cpl.ring_D2);
        free(lod->lev[k].cpl.front_off2);
        free(lod->lev[k].cpl.front_col2);
        free(lod->lev[k].cpl.front_K2);
        free(lod->lev[k].cpl.front_D2);
        free(lod->lev[k].cpl.front_merged2);
        free(lod->lev[k].lay.inner);
        free(lod->lev[k].cpl.front_merged);
        free(lod->lev[k].cpl.ring_T);
        free(lod->lev[k].cpl.ring_T2);
        free(lod->lev[k].cpl.front_T2);
        free(lod->lev[k].cpl.front_T);
        free(lod->lev[k].cpl.front_off);
        free(lod->lev[k].cpl.front_K);
        free(lod->lev[k].cpl.front_D);
        free(lod->lev[k].cpl.ring_K);
        free(lod->lev[k].cpl.ring_D);
        free(lod->lev[k].cpl.blocks_slot);
        for (int c = 0; c < lod->lev[k].cpl.blocks_nchunk; c++)
            free(lod->lev[k].cpl.blocks_chunk[c]);
        free(lod->lev[k].cpl.blocks_chunk);
        if (!lod->shared) {
            free(lod->lev[k].tab.crit_weight);
            free(lod->lev[k].tab.node_tet_start);
            free(lod->lev[k].tab.node_tet);
            free(lod->lev[k].tab.inc_corner);
            free(lod->lev[k].tab.inc_block);
            free(lod->lev[k].tab.tet_geom);
        }
        free(lod->lev[k].lay.src_level);
        free(lod->lev[k].lay.src_rend);
        free(lod->lev[k].tk.hot);
        free(lod->lev[k].lay.src_node);
        free(lod->lev[k].lay.src_weight);
    }
    free(lod->view.nlv[0]);
    free(lod->view.nlv[1]);
    sq_lodx_surface_free(lod);
    free(lod->cpl.abs_sum);
    free(lod->holds.he);
    free(lod->holds.hold_entry_of);
    if (!lod->shared)
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
            for (int i = 0; i < lod->lv[k].model.n; i++)
                if (k == lod->top && lod->lev[k].lay.state[i] == ST_SPLIT)
                    lod->lev[k].lay.state[i] = ST_ACTIVE;
                else if (k > lod->top)
                    lod->lev[k].lay.state[i] = ST_COARSE;
        for (int k = lod->top; k < lod->L; k++)
            sq_lodx_rebuild_level(lod, k);
        sq_lod_sync(lod);
    }
    lod->guard.last_time = 0;
    return 0;
}

void sq_lod_reset(sq_lod *lod)
{
    set_uniform_level(lod, start_level(lod));
    lod->guard.last_time = 0;
    sq_lod_sync(lod);
}

int sq_lod_check(const sq_lod *lod, sq_err *err)
{
    for (int k = 0; k < lod->L; k++) {
        int na = 0;
        for (int i = 0; i < lod->lv[k].model.n; i++) {
            unsigned char s = lod->lev[k].lay.state[i];
            if (s > ST_SPLIT)
                return sq_err_set(err, "lod: level %d node %d has state %d", k, i, s);
            if (k == 0 && s == ST_COARSE)
                return sq_err_set(err, "lod: level-0 node %d is a coarse ghost", i);
            if (k >= lod->top && s == ST_SPLIT)
                return sq_err_set(err, "lod: node %d of level %d (top %d) is split", i, k, lod->top);
            if (k > 0) {
                int p = lod->h.link[k - 1].parent[i];
                int parent_split = lod->lev[k - 1].lay.state[p] == ST_SPLIT;
                if (parent_split != (s != ST_COARSE))
                    return sq_err_set(err, "lod: level %d node %d has state %d but its parent %d has "
                                      "state %d", k, i, s, p, lod->lev[k - 1].lay.state[p]);
            }
            if (lod->lev[k].lay.active[i] != (s == ST_ACTIVE))
                return sq_err_set(err, "lod: level %d node %d: active mask out of date", k, i);
            na += s == ST_ACTIVE;
        }
        if (na != lod->lev[k].lay.nactive)
            return sq_err_set(err, "lod: level %d counts %d active nodes, has %d", k, lod->lev[k].lay.nactive, na);
    }
    return 0;
}
